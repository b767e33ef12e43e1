#include "common/expr/expr_tokenizer.hpp"

#include <charconv>
#include <cstdint>

#include "common/expr/expr_error.hpp"

namespace tally::expr {
namespace {

bool is_digit(char c) {
  return c >= '0' && c <= '9';
}
bool is_ident_start(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_';
}
bool is_ident_char(char c) {
  return is_ident_start(c) || is_digit(c);
}
bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f';
}

[[noreturn]] void fail(const std::string& what, size_t pos) {
  throw ExprError(ExprErrorKind::syntax, what + " at position " + std::to_string(pos), pos);
}

// Decimal exponent of the leading significant digit of a literal (digits, '.', exponent):
// used only to tell overflow from underflow when from_chars reports out of range.
int64_t leading_exponent(std::string_view lit) {
  int64_t exp = 0;
  size_t e = lit.find_first_of("eE");
  if (e != std::string_view::npos) {
    std::string_view ex = lit.substr(e + 1);
    bool neg = !ex.empty() && ex[0] == '-';
    if (!ex.empty() && (ex[0] == '-' || ex[0] == '+')) ex.remove_prefix(1);
    for (char c : ex) exp = std::min<int64_t>(exp * 10 + (c - '0'), 100000);
    if (neg) exp = -exp;
    lit = lit.substr(0, e);
  }
  size_t point = lit.find('.');
  if (point == std::string_view::npos) point = lit.size();
  size_t first = lit.find_first_of("123456789");
  if (first == std::string_view::npos) return 0;
  int64_t lead = first < point ? static_cast<int64_t>(point - first - 1)
                               : -static_cast<int64_t>(first - point);
  return lead + exp;
}

size_t scan_number(std::string_view text, size_t i) {
  size_t j = i;
  while (j < text.size() && is_digit(text[j])) ++j;
  if (j < text.size() && text[j] == '.') {
    ++j;
    while (j < text.size() && is_digit(text[j])) ++j;
  }
  if (j < text.size() && (text[j] == 'e' || text[j] == 'E')) {
    size_t k = j + 1;
    if (k < text.size() && (text[k] == '+' || text[k] == '-')) ++k;
    if (k < text.size() && is_digit(text[k])) {
      while (k < text.size() && is_digit(text[k])) ++k;
      j = k;
    } else {
      fail(
          "malformed number '" + std::string(text.substr(i, k - i)) + "' (exponent without digits)",
          i);
    }
  }
  return j;
}

}  // namespace

std::vector<Token> tokenize(std::string_view text) {
  std::vector<Token> tokens;
  size_t i = 0;
  while (true) {
    while (i < text.size() && is_space(text[i])) ++i;
    if (i >= text.size()) break;
    const char c = text[i];
    Token t;
    t.position = i;
    if (is_digit(c) || (c == '.' && i + 1 < text.size() && is_digit(text[i + 1]))) {
      size_t j = scan_number(text, i);
      t.kind = TokenKind::number;
      t.text = text.substr(i, j - i);
      auto [ptr, ec] = std::from_chars(t.text.data(), t.text.data() + t.text.size(), t.value);
      if (ec == std::errc::result_out_of_range && leading_exponent(t.text) < 0) {
        t.value = 0;  // underflow: muParser reads such literals as 0 too
      } else if (ec != std::errc() || ptr != t.text.data() + t.text.size()) {
        fail("number '" + std::string(t.text) + "' is out of range", i);
      }
      i = j;
    } else if (is_ident_start(c)) {
      size_t j = i + 1;
      while (j < text.size() && is_ident_char(text[j])) ++j;
      t.kind = TokenKind::identifier;
      t.text = text.substr(i, j - i);
      i = j;
    } else {
      const char n = i + 1 < text.size() ? text[i + 1] : '\0';
      size_t len = 0;
      if ((c == '<' || c == '>' || c == '=' || c == '!') && n == '=') {
        len = 2;
      } else if ((c == '&' && n == '&') || (c == '|' && n == '|')) {
        len = 2;
      } else if (std::string_view("+-*/^<>?:(),").find(c) != std::string_view::npos) {
        len = 1;
      } else if (c == '=') {
        fail("assignment '=' is not supported (use '==' to compare)", i);
      } else if (c == '"') {
        fail("string literals are not supported", i);
      } else if (static_cast<unsigned char>(c) >= 0x21 && static_cast<unsigned char>(c) < 0x7f) {
        fail(std::string("unexpected character '") + c + "'", i);
      } else {
        static constexpr char kHex[] = "0123456789abcdef";
        const auto b = static_cast<unsigned char>(c);
        fail(std::string("unexpected byte 0x") + kHex[b >> 4] + kHex[b & 15] + " (only ASCII)", i);
      }
      t.kind = TokenKind::op;
      t.text = text.substr(i, len);
      i += len;
    }
    tokens.push_back(t);
  }
  Token end;
  end.kind = TokenKind::end;
  end.position = text.size();
  tokens.push_back(end);
  return tokens;
}

std::string describe(const Token& token) {
  if (token.kind == TokenKind::end) return "end of expression";
  return "'" + std::string(token.text) + "'";
}

}  // namespace tally::expr
