// Deliberate violations: the transport naming the application.
#include "server/api/request_handler.hpp"
#include "server/jobs/job_manager.hpp"
#include "server/http/http_types.hpp"
#include "common/log/log.hpp"
struct Principal;
