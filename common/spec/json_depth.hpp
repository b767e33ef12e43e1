#pragma once
// A cheap pre-scan of a JSON text's nesting depth, run before the (recursive)
// parser sees it, so a depth bomb of 100,000 '[' is refused without deep recursion;
// and the JSON pointer of the value where a parse failed.
#include <cstddef>
#include <string>
#include <string_view>

namespace tally {

// Largest nesting depth of arrays/objects, ignoring brackets inside strings.
// Stops counting once `limit` is exceeded (returns limit + 1).
size_t json_nesting_depth(std::string_view text, size_t limit);

// JSON pointer (RFC 6901) of the value at which parsing `text` fails (e.g. a number
// out of double range, "1e400"): "" for the document, "/stop/max_samples", "/a/2".
// Call only after a parse failure; `text` must be within the depth limit.
std::string json_pointer_at_error(std::string_view text);

}  // namespace tally
