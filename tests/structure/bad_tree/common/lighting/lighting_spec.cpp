// A deliberate violation: a spec reader (allowed JSON) that includes a JSON view.
#include "common/protocol/lighting_json.hpp"
