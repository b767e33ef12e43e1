#pragma once
// A deliberate violation: tests/structure checks that its check catches this file.
#include <nlohmann/json.hpp>
