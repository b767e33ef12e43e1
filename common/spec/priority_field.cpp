#include "common/spec/priority_field.hpp"

#include <fmt/format.h>

#include "common/spec/spec_reader.hpp"

namespace tally {

int read_priority_change(const nlohmann::json& body) {
  SpecReader rd(body, "");
  if (!rd.has("priority")) throw SpecError("", "the body must set \"priority\" (an integer in [-5, 5])");
  const nlohmann::json& v = rd.at("priority");
  const std::string at = rd.pointer_of("priority");
  if (!v.is_number_integer()) {
    throw SpecError(at, fmt::format("must be an integer in [{}, {}], got {}", kMinPriority, kMaxPriority,
                                    v.is_number() ? v.dump() : json_type_name(v)));
  }
  const int64_t p = v.get<int64_t>();
  // A huge unsigned value reads as negative through int64: compare it as what it is.
  if (v.is_number_unsigned() ? v.get<uint64_t>() > static_cast<uint64_t>(kMaxPriority)
                             : (p < kMinPriority || p > kMaxPriority)) {
    throw SpecError(at, fmt::format("must be in [{}, {}], got {}", kMinPriority, kMaxPriority, v.dump()));
  }
  rd.finish();  // the only field a job takes after submit
  return static_cast<int>(p);
}

}  // namespace tally
