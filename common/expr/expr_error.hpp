#pragma once
// Errors and resource limits of the expression compiler. Every rejection of a user
// expression is an ExprError; callers map it to a 4xx response (kind internal to a 5xx).
#include <cstddef>
#include <stdexcept>
#include <string>

namespace tally {

enum class ExprErrorKind {
  syntax,    // the text is not a valid expression (also: muParser rejected it)
  limit,     // too long, nested too deeply, too many instructions, too many dimensions
  internal,  // our compiled form disagreed with muParser: a bug in the compiler
};

struct ExprError : std::runtime_error {
  static constexpr size_t npos = static_cast<size_t>(-1);

  ExprError(ExprErrorKind error_kind, const std::string& message, size_t char_position = npos)
      : std::runtime_error(message), kind(error_kind), position(char_position) {}

  ExprErrorKind kind;
  size_t position;  // character offset into the expression text, or npos
};

struct ExprLimits {
  size_t max_length = 4096;        // characters of text
  size_t max_depth = 64;           // nested (), calls, ?: branches and ^ chains; capped at 256
  size_t max_instructions = 4096;  // instructions of the compiled program
};

}  // namespace tally
