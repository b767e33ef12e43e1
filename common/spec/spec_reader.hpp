#pragma once
// Reading job specs: every accessor knows the JSON pointer of what it reads, so a
// bad value is reported as "<pointer>: <what is wrong>", and finish() turns every
// field nobody asked for into an error (unknown fields are never ignored).
#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace tally {

// Bad input in a job spec. `pointer` is an RFC 6901 JSON pointer ("" = the whole spec).
class SpecError : public std::runtime_error {
 public:
  SpecError(std::string pointer, const std::string& detail)
      : std::runtime_error(pointer.empty() ? detail : pointer + ": " + detail),
        pointer_(std::move(pointer)),
        detail_(detail) {}
  const std::string& pointer() const noexcept { return pointer_; }
  const std::string& detail() const noexcept { return detail_; }

 private:
  std::string pointer_;
  std::string detail_;
};

std::string json_pointer_append(const std::string& base, std::string_view key);
std::string json_pointer_append(const std::string& base, size_t index);
const char* json_type_name(const nlohmann::json& j);

class SpecReader {
 public:
  // Throws SpecError unless `j` is an object.
  SpecReader(const nlohmann::json& j, std::string pointer);

  const std::string& pointer() const { return pointer_; }
  std::string pointer_of(std::string_view key) const { return json_pointer_append(pointer_, key); }
  bool has(std::string_view key) const;

  // Raw access (marks the key as known). Throws if missing.
  const nlohmann::json& at(std::string_view key);
  const nlohmann::json* find(std::string_view key);

  double number(std::string_view key, double lo, double hi);
  double number_or(std::string_view key, double fallback, double lo, double hi);
  uint64_t integer(std::string_view key, uint64_t lo, uint64_t hi);
  uint64_t integer_or(std::string_view key, uint64_t fallback, uint64_t lo, uint64_t hi);
  bool boolean_or(std::string_view key, bool fallback);
  std::string string(std::string_view key, size_t max_length = 256);
  std::string string_or(std::string_view key, std::string fallback, size_t max_length = 256);
  // One of `allowed`, reported with the list when not.
  std::string enumeration(std::string_view key, const std::vector<std::string>& allowed);
  std::string enumeration_or(std::string_view key, std::string fallback,
                             const std::vector<std::string>& allowed);
  std::vector<double> numbers(std::string_view key, size_t min_count, size_t max_count,
                              double lo, double hi);
  SpecReader object(std::string_view key);

  // Throws SpecError naming the first field that no accessor read.
  void finish() const;

 private:
  const nlohmann::json& j_;
  std::string pointer_;
  std::set<std::string, std::less<>> known_;
};

// Free helpers for values that are not object members (array elements).
double spec_number(const nlohmann::json& j, const std::string& pointer, double lo, double hi);

}  // namespace tally
