// Deliberate violation: the cluster executor reaching up into the routes.
#include "server/api/metrics.hpp"
#include "server/http/prometheus.hpp"
#include "server/cli/job_limit_flags.hpp"
