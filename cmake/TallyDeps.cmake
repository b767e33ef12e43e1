# Every dependency comes from a Debian 12 package (scripts/install-deps.sh installs them).
find_package(Threads REQUIRED)
find_package(fmt REQUIRED)
find_package(nlohmann_json 3.10 REQUIRED)
find_package(muparser REQUIRED)
find_package(CLI11 REQUIRED)
find_package(Boost 1.74 REQUIRED)
find_package(SQLiteCpp REQUIRED)
find_package(spdlog REQUIRED)
find_package(OpenSSL REQUIRED)  # TLS (Beast ssl_stream) and token hashing
find_package(embree 3 REQUIRED)
# Debian's OpenImageIO CMake config insists on the command-line tools of
# openimageio-tools; pkg-config needs only the library.
find_package(PkgConfig REQUIRED)
pkg_check_modules(OIIO REQUIRED IMPORTED_TARGET OpenImageIO)
find_package(tinyobjloader REQUIRED)
find_package(TinyGLTF REQUIRED)  # glTF scenes (common/lighting/gltf_scene.cpp)
if(TALLY_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(TALLY_BUILD_BENCH)
  find_package(benchmark REQUIRED)
  find_package(GSL REQUIRED)
endif()
