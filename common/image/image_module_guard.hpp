#pragma once
// For the image modules (image_module_oiio.cpp, image_module_openexr.cpp): each entry
// point of the C interface (image_module_abi.hpp) runs its work through guarded(), so
// nothing unwinds across the C boundary.
#include <exception>
#include <string>

#include "common/image/image_module_abi.hpp"

namespace tally {

// Runs `f`; returns 0, or 1 after passing any exception's message to `error`.
template <class F>
int guarded(F&& f, tally_image_sink error, void* error_context) {
  try {
    f();
    return 0;
  } catch (const std::exception& e) {
    const std::string m = e.what();
    error(error_context, m.data(), m.size());
  } catch (...) {
    const std::string m = "unknown exception in the image module";
    error(error_context, m.data(), m.size());
  }
  return 1;
}

}  // namespace tally
