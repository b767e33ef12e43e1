#include "server/jobs/result_cache.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace tally {

using nlohmann::json;

namespace {

// Integral doubles within ±2^53 become integers; -0 becomes 0; unsigned and signed
// integers are one type.
json normalised(const json& j) {
  switch (j.type()) {
    case json::value_t::object: {
      json out = json::object();
      for (auto it = j.begin(); it != j.end(); ++it) out[it.key()] = normalised(it.value());
      return out;
    }
    case json::value_t::array: {
      json out = json::array();
      for (const json& x : j) out.push_back(normalised(x));
      return out;
    }
    case json::value_t::number_unsigned: {
      const auto u = j.get<uint64_t>();
      if (u <= static_cast<uint64_t>(INT64_MAX)) return json(static_cast<int64_t>(u));
      return j;
    }
    case json::value_t::number_float: {
      const double d = j.get<double>();
      if (std::isfinite(d) && std::trunc(d) == d && std::fabs(d) <= 9007199254740992.0) {
        return json(static_cast<int64_t>(d));
      }
      return j;
    }
    default: return j;
  }
}

}  // namespace

std::string ResultCache::canonical(const json& j) {
  // nlohmann's objects are ordered maps (sorted keys); its doubles print as the shortest
  // text that reads back the same.
  return normalised(j).dump(-1, ' ', false, json::error_handler_t::replace);
}

std::string ResultCache::key_of(const json& spec, uint64_t seed) {
  return fmt::format("{}\n{}", canonical(spec), seed);
}

void ResultCache::add(const std::string& key, const std::string& id, const std::string& owner, uint64_t samples) {
  if (key.empty()) return;
  std::lock_guard lock(mu_);
  if (key_by_id_.count(id)) return;
  by_key_[key].push_back(Source{id, owner, samples});
  key_by_id_[id] = key;
}

void ResultCache::erase(const std::string& id) {
  std::lock_guard lock(mu_);
  const auto k = key_by_id_.find(id);
  if (k == key_by_id_.end()) return;
  auto& v = by_key_[k->second];
  std::erase_if(v, [&](const Source& s) { return s.id == id; });
  if (v.empty()) by_key_.erase(k->second);
  key_by_id_.erase(k);
}

std::optional<std::string> ResultCache::find(const std::string& key, const std::string& owner, bool reads_all,
                                             uint64_t max_samples) const {
  std::lock_guard lock(mu_);
  if (const auto it = by_key_.find(key); it != by_key_.end()) {
    for (auto s = it->second.rbegin(); s != it->second.rend(); ++s) {
      if ((reads_all || s->owner == owner) && s->samples <= max_samples) return s->id;
    }
  }
  return std::nullopt;
}

void ResultCache::counted(bool hit) {
  std::lock_guard lock(mu_);
  ++(hit ? hits_ : misses_);
}

uint64_t ResultCache::hits() const {
  std::lock_guard lock(mu_);
  return hits_;
}

uint64_t ResultCache::misses() const {
  std::lock_guard lock(mu_);
  return misses_;
}

}  // namespace tally
