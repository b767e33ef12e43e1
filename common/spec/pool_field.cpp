#include "common/spec/pool_field.hpp"

#include <fmt/format.h>

namespace tally {

std::string pool_name_problem(std::string_view name) {
  if (name.empty()) return "must not be empty";
  if (name.size() > kMaxPoolName) return fmt::format("must be at most {} characters", kMaxPoolName);
  for (char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
                    c == '_' || c == '-';
    if (!ok) return "may hold only letters, digits, '.', '_' and '-'";
  }
  return {};
}

bool valid_pool_name(std::string_view name) { return pool_name_problem(name).empty(); }

std::string read_pool(SpecReader& root) {
  if (!root.has("pool")) return {};
  std::string pool = root.string("pool", 1024);
  if (std::string why = pool_name_problem(pool); !why.empty()) {
    throw SpecError(root.pointer_of("pool"), fmt::format("a worker pool's name {}, got \"{}\"", why, pool));
  }
  return pool;
}

std::string spec_pool(const nlohmann::json& spec) {
  if (!spec.is_object()) return {};
  const auto it = spec.find("pool");
  return it != spec.end() && it->is_string() ? it->get<std::string>() : std::string();
}

}  // namespace tally
