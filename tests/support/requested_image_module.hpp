#pragma once
// ctest's <area>.<backend>_module entries run a test binary once more with
// TALLY_IMAGE_MODULE set to the other backend's image module and
// TALLY_EXPECT_IMAGE_BACKEND to that backend's name ("OpenImageIO", "OpenEXR"; see
// tests/CMakeLists.txt). This checks that exactly that module was loaded, so such an
// entry cannot pass on the default module (issue 27). Skipped when the variable is unset.
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include "common/image/image_io.hpp"

namespace tally::test {

inline void expect_the_requested_image_module() {
  const char* backend = std::getenv("TALLY_EXPECT_IMAGE_BACKEND");
  if (backend == nullptr || *backend == '\0') GTEST_SKIP() << "not a <backend>_module run";
  const char* path = std::getenv("TALLY_IMAGE_MODULE");
  ASSERT_NE(path, nullptr) << "TALLY_EXPECT_IMAGE_BACKEND without TALLY_IMAGE_MODULE";
  EXPECT_EQ(image_module_path(), std::string(path));
  EXPECT_EQ(image_module_backend().rfind(backend, 0), 0u)
      << "loaded " << image_module_backend() << ", expected " << backend;
}

}  // namespace tally::test
