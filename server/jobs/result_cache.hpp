#pragma once
// The result cache: finished jobs whose result a new submit of the same spec would
// compute again, bit for bit. A job's key is its canonical spec (the JSON with keys in
// order and numbers in one form: 1, 1.0 and 1e0 are one number) and its seed; a job
// is a source once it succeeded for a reason that does not depend on the clock (its
// max_samples or error target reached). A lookup finds the newest source the
// submitter may read whose samples its sample cap allows. Thread-safe (its own lock).
#include <cstdint>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common/engine/stop_rule.hpp"

namespace tally {

class ResultCache {
 public:
  // The spec's key: canonical text and seed.
  static std::string key_of(const nlohmann::json& spec, uint64_t seed);
  // The canonical text alone (sorted keys; an integral number written as an integer,
  // any other as the shortest double that reads back the same).
  static std::string canonical(const nlohmann::json& j);
  // Whether a job that ended so can answer later submits.
  static bool reusable(StopReason reason) {
    return reason == StopReason::max_samples || reason == StopReason::error_target;
  }

  // A finished job (id, owner, samples computed) may answer submits with `key`.
  void add(const std::string& key, const std::string& id, const std::string& owner, uint64_t samples);
  void erase(const std::string& id);  // deleted or reopened (extend)
  // The newest source for `key` readable by `owner` (any owner if `reads_all`) within
  // `max_samples`; the caller counts what came of it (counted).
  std::optional<std::string> find(const std::string& key, const std::string& owner, bool reads_all,
                                  uint64_t max_samples) const;
  void counted(bool hit);

  uint64_t hits() const;
  uint64_t misses() const;

 private:
  struct Source {
    std::string id, owner;
    uint64_t samples = 0;
  };
  mutable std::mutex mu_;
  std::map<std::string, std::vector<Source>> by_key_;  // oldest first
  std::map<std::string, std::string> key_by_id_;
  uint64_t hits_ = 0, misses_ = 0;
};

}  // namespace tally
