// Deliberate violation: shared flags that know the job manager.
#include "server/jobs/job_manager.hpp"
#include "server/host/memory_budget.hpp"
