#pragma once
// A base for SAX handlers of nlohmann's parser (which does not recurse) that only need to
// know where values are: every scalar calls value(); the subclass handles containers
// and keys. Used by the JSON pointer of a parse error (json_depth.cpp) and by the glTF
// census (common/lighting/gltf_census.cpp).
#include <nlohmann/json.hpp>

namespace tally {

class JsonValueSax : public nlohmann::json_sax<nlohmann::json> {
 public:
  bool null() override { return value(); }
  bool boolean(bool) override { return value(); }
  bool number_integer(number_integer_t) override { return value(); }
  bool number_unsigned(number_unsigned_t) override { return value(); }
  bool number_float(number_float_t, const string_t&) override { return value(); }
  bool string(string_t&) override { return value(); }
  bool binary(binary_t&) override { return value(); }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception&) override { return false; }

 protected:
  virtual bool value() = 0;
};

}  // namespace tally
