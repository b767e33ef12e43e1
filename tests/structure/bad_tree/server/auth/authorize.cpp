// A deliberate violation: auth taking the error vocabulary from server/api.
#include "server/api/problem.hpp"
