// A deliberate violation: a spec reader (allowed JSON) that includes a JSON view.
#include "common/protocol/integration_json.hpp"
