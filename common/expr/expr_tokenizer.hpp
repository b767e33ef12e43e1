#pragma once
// Splits muParser-syntax text into tokens: numbers, identifiers, operators.
#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace tally::expr {

enum class TokenKind { number, identifier, op, end };

struct Token {
  TokenKind kind = TokenKind::end;
  std::string_view text;  // view into the expression text
  double value = 0;       // number only
  size_t position = 0;    // character offset
};

// Throws ExprError (syntax) on a character or literal that cannot start a token.
std::vector<Token> tokenize(std::string_view text);

// For messages: the token as the user wrote it, quoted ("'x5'", or "end of expression").
std::string describe(const Token& token);

}  // namespace tally::expr
