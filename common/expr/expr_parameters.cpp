#include "common/expr/expr_parameters.hpp"

#include <fmt/format.h>

#include <cmath>

#include "common/expr/expr_parser.hpp"
#include "common/expr/expr_tokenizer.hpp"

namespace tally::expr {

std::string check_parameter_name(std::string_view name) {
  if (name.empty() || name.size() > 32) return "must have 1 to 32 characters";
  const auto letter = [](char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); };
  const auto digit = [](char c) { return c >= '0' && c <= '9'; };
  if (!letter(name[0])) return "must start with a letter";
  for (char c : name) {
    if (!letter(c) && !digit(c) && c != '_') return "may hold only letters, digits and '_'";
  }
  if (is_reserved_name(name)) return "is a function, constant or variable name of the expression grammar";
  return {};
}

std::string bind_parameters(std::string_view text, const std::vector<Parameter>& parameters) {
  const std::vector<Token> tokens = tokenize(text);
  std::string out;
  out.reserve(text.size() + 16);
  size_t copied = 0;
  for (const Token& t : tokens) {
    if (t.kind != TokenKind::identifier) continue;
    for (const Parameter& p : parameters) {
      if (t.text != p.name) continue;
      out.append(text.substr(copied, t.position - copied));
      // Non-finite values never reach here (the spec reader refuses them); {:.17g}
      // round-trips every finite double.
      out += fmt::format("({:.17g})", p.value);
      copied = t.position + t.text.size();
      break;
    }
  }
  out.append(text.substr(copied));
  return out;
}

}  // namespace tally::expr
