#include "common/spec/spec_reader.hpp"

#include <cmath>
#include <fmt/format.h>

namespace tally {

using nlohmann::json;

std::string json_pointer_append(const std::string& base, std::string_view key) {
  std::string out = base;
  out += '/';
  for (char c : key) {
    if (c == '~') {
      out += "~0";
    } else if (c == '/') {
      out += "~1";
    } else {
      out += c;
    }
  }
  return out;
}

std::string json_pointer_append(const std::string& base, size_t index) {
  return base + "/" + std::to_string(index);
}

const char* json_type_name(const json& j) {
  switch (j.type()) {
    case json::value_t::null: return "null";
    case json::value_t::object: return "an object";
    case json::value_t::array: return "an array";
    case json::value_t::string: return "a string";
    case json::value_t::boolean: return "a boolean";
    case json::value_t::number_integer:
    case json::value_t::number_unsigned:
    case json::value_t::number_float: return "a number";
    default: return "an unsupported value";
  }
}

SpecReader::SpecReader(const json& j, std::string pointer) : j_(j), pointer_(std::move(pointer)) {
  if (!j_.is_object()) {
    throw SpecError(pointer_, fmt::format("must be an object, got {}", json_type_name(j_)));
  }
}

bool SpecReader::has(std::string_view key) const { return j_.contains(key); }

const json* SpecReader::find(std::string_view key) {
  auto it = j_.find(key);
  if (it == j_.end()) return nullptr;
  known_.emplace(key);
  return &*it;
}

const json& SpecReader::at(std::string_view key) {
  const json* v = find(key);
  if (v == nullptr) throw SpecError(pointer_of(key), "is required");
  return *v;
}

double spec_number(const json& j, const std::string& pointer, double lo, double hi) {
  if (!j.is_number()) {
    throw SpecError(pointer, fmt::format("must be a number, got {}", json_type_name(j)));
  }
  const double v = j.get<double>();
  if (!std::isfinite(v)) throw SpecError(pointer, "must be a finite number");
  if (v < lo || v > hi) {
    throw SpecError(pointer, fmt::format("must be in [{}, {}], got {}", lo, hi, v));
  }
  return v;
}

double SpecReader::number(std::string_view key, double lo, double hi) {
  return spec_number(at(key), pointer_of(key), lo, hi);
}

double SpecReader::number_or(std::string_view key, double fallback, double lo, double hi) {
  return has(key) ? number(key, lo, hi) : fallback;
}

uint64_t SpecReader::integer(std::string_view key, uint64_t lo, uint64_t hi) {
  const json& v = at(key);
  const std::string p = pointer_of(key);
  if (v.is_number_unsigned()) {
    const uint64_t x = v.get<uint64_t>();
    if (x < lo || x > hi) throw SpecError(p, fmt::format("must be in [{}, {}], got {}", lo, hi, x));
    return x;
  }
  if (v.is_number_integer()) {
    const int64_t x = v.get<int64_t>();
    if (x < 0 || static_cast<uint64_t>(x) < lo || static_cast<uint64_t>(x) > hi) {
      throw SpecError(p, fmt::format("must be in [{}, {}], got {}", lo, hi, x));
    }
    return static_cast<uint64_t>(x);
  }
  if (v.is_number_float()) {
    const double d = v.get<double>();
    // Accept 1e6 written as a float when it is an exact integer.
    if (std::isfinite(d) && d == std::floor(d) && d >= 0 && d <= 1.8e19) {
      const auto x = static_cast<uint64_t>(d);
      if (x < lo || x > hi) {
        throw SpecError(p, fmt::format("must be in [{}, {}], got {}", lo, hi, d));
      }
      return x;
    }
    throw SpecError(p, fmt::format("must be a whole number, got {}", d));
  }
  throw SpecError(p, fmt::format("must be a whole number, got {}", json_type_name(v)));
}

uint64_t SpecReader::integer_or(std::string_view key, uint64_t fallback, uint64_t lo, uint64_t hi) {
  return has(key) ? integer(key, lo, hi) : fallback;
}

bool SpecReader::boolean_or(std::string_view key, bool fallback) {
  const json* v = find(key);
  if (v == nullptr) return fallback;
  if (!v->is_boolean()) {
    throw SpecError(pointer_of(key), fmt::format("must be a boolean, got {}", json_type_name(*v)));
  }
  return v->get<bool>();
}

std::string SpecReader::string(std::string_view key, size_t max_length) {
  const json& v = at(key);
  if (!v.is_string()) {
    throw SpecError(pointer_of(key), fmt::format("must be a string, got {}", json_type_name(v)));
  }
  const auto& s = v.get_ref<const std::string&>();
  if (s.size() > max_length) {
    throw SpecError(pointer_of(key),
                    fmt::format("is too long ({} bytes, at most {})", s.size(), max_length));
  }
  return s;
}

std::string SpecReader::string_or(std::string_view key, std::string fallback, size_t max_length) {
  return has(key) ? string(key, max_length) : fallback;
}

std::string SpecReader::enumeration(std::string_view key, const std::vector<std::string>& allowed) {
  std::string s = string(key);
  for (const auto& a : allowed) {
    if (a == s) return s;
  }
  throw SpecError(pointer_of(key),
                  fmt::format("must be one of {}, got \"{}\"", fmt::join(allowed, ", "), s));
}

std::string SpecReader::enumeration_or(std::string_view key, std::string fallback,
                                       const std::vector<std::string>& allowed) {
  return has(key) ? enumeration(key, allowed) : fallback;
}

std::vector<double> SpecReader::numbers(std::string_view key, size_t min_count, size_t max_count,
                                        double lo, double hi) {
  const json& v = at(key);
  const std::string p = pointer_of(key);
  if (!v.is_array()) throw SpecError(p, fmt::format("must be an array, got {}", json_type_name(v)));
  if (v.size() < min_count || v.size() > max_count) {
    throw SpecError(p, fmt::format("must have {} to {} numbers, got {}", min_count, max_count,
                                   v.size()));
  }
  std::vector<double> out;
  out.reserve(v.size());
  for (size_t i = 0; i < v.size(); ++i) {
    out.push_back(spec_number(v[i], json_pointer_append(p, i), lo, hi));
  }
  return out;
}

SpecReader SpecReader::object(std::string_view key) { return SpecReader(at(key), pointer_of(key)); }

void SpecReader::finish() const {
  for (auto it = j_.begin(); it != j_.end(); ++it) {
    if (!known_.contains(it.key())) throw SpecError(pointer_of(it.key()), "unknown field");
  }
}

}  // namespace tally
