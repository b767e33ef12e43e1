#include "client/json_errors.hpp"

namespace tally {

std::string json_parse_error_text(const nlohmann::json::parse_error& e) {
  std::string text = e.what();
  if (text.rfind("[json.exception.", 0) == 0) {
    const size_t close = text.find("] ");
    if (close != std::string::npos) text.erase(0, close + 2);
  }
  if (text.rfind("parse error ", 0) == 0) text.erase(0, 12);
  return text;
}

}  // namespace tally
