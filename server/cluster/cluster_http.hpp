#pragma once
// What cluster mode adds to the HTTP API: the GET /v1/workers document and the
// cluster lines of /metrics, built from a RedisExecutor's snapshot.
#include <nlohmann/json.hpp>
#include <string>

#include "server/cluster/redis_executor.hpp"

namespace tally::cluster {

nlohmann::json workers_json(const RedisExecutor& executor);
std::string cluster_metrics(const RedisExecutor& executor);

}  // namespace tally::cluster
