#pragma once
// A cheap pre-scan of a JSON text's nesting depth, run before the (recursive)
// parser sees it, so a depth bomb of 100,000 '[' is refused without deep recursion.
#include <cstddef>
#include <string_view>

namespace tally {

// Largest nesting depth of arrays/objects, ignoring brackets inside strings.
// Stops counting once `limit` is exceeded (returns limit + 1).
size_t json_nesting_depth(std::string_view text, size_t limit);

}  // namespace tally
