#pragma once
// A JSON syntax error as a person reads it: "at line 3, column 1: syntax error while
// parsing object key - unexpected '}'; expected string literal", without nlohmann's
// "[json.exception.parse_error.101] parse error" prefix.
#include <nlohmann/json.hpp>
#include <string>

namespace tally {

std::string json_parse_error_text(const nlohmann::json::parse_error& e);

}  // namespace tally
