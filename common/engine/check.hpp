#pragma once
// Invariant checks in pbrt's CHECK style: a failed check names the condition,
// the file and line, and the values of both operands. It throws CheckFailure (a
// std::logic_error), so a broken invariant fails one job (the server logs it
// with the job id) instead of taking the process down. Not for bad input: that
// is a SpecError / HttpError with a clear message. Header-only; cheap when true.
#include <fmt/format.h>

#include <stdexcept>
#include <string>

namespace tally {

class CheckFailure : public std::logic_error {
 public:
  using std::logic_error::logic_error;
};

[[noreturn]] inline void check_failed(const char* file, int line, const char* condition, const std::string& values) {
  throw CheckFailure(fmt::format("CHECK failed at {}:{}: {}{}{}", file, line, condition, values.empty() ? "" : " with ",
                                 values));
}

}  // namespace tally

#define TALLY_CHECK(cond)                                                   \
  do {                                                                      \
    if (!(cond)) ::tally::check_failed(__FILE__, __LINE__, #cond, {});      \
  } while (false)

// TALLY_CHECK_MSG(cond, "fmt", args...): adds a formatted explanation.
#define TALLY_CHECK_MSG(cond, ...)                                                        \
  do {                                                                                    \
    if (!(cond)) ::tally::check_failed(__FILE__, __LINE__, #cond, fmt::format(__VA_ARGS__)); \
  } while (false)

#define TALLY_CHECK_OP_(a, op, b)                                                                        \
  do {                                                                                                   \
    const auto& tally_check_a_ = (a);                                                                    \
    const auto& tally_check_b_ = (b);                                                                    \
    if (!(tally_check_a_ op tally_check_b_)) {                                                           \
      ::tally::check_failed(__FILE__, __LINE__, #a " " #op " " #b,                                       \
                            fmt::format("{} = {}, {} = {}", #a, tally_check_a_, #b, tally_check_b_));    \
    }                                                                                                    \
  } while (false)

#define TALLY_CHECK_EQ(a, b) TALLY_CHECK_OP_(a, ==, b)
#define TALLY_CHECK_NE(a, b) TALLY_CHECK_OP_(a, !=, b)
#define TALLY_CHECK_LT(a, b) TALLY_CHECK_OP_(a, <, b)
#define TALLY_CHECK_LE(a, b) TALLY_CHECK_OP_(a, <=, b)
#define TALLY_CHECK_GT(a, b) TALLY_CHECK_OP_(a, >, b)
#define TALLY_CHECK_GE(a, b) TALLY_CHECK_OP_(a, >=, b)
