// libFuzzer: the readers of the files a lighting scene names (issue 27): glTF (.gltf and
// .glb), OBJ with its .mtl, and images (PNG, JPEG, OpenEXR, Radiance HDR) as a texture
// and as an environment map. Byte 0 picks the reader; the rest is split at the first
// NUL: before it the file the scene names, after it the bytes every other name reads (a
// glTF's .bin or image, an OBJ's .mtl or map_Kd texture). Every input either loads
// within the limits or throws SpecError (readers) / std::runtime_error (images);
// anything else, a crash, a sanitizer report or more than -rss_limit_mb is a finding.
// The limits are small, so a file within them cannot allocate much: a reader that
// allocates before checking is what the memory limit finds.
#include <stdexcept>
#include <string>

#include "common/image/image_decode.hpp"
#include "common/image/image_io.hpp"
#include "common/lighting/gltf_scene.hpp"
#include "common/lighting/obj_scene.hpp"
#include "common/lighting/texture.hpp"
#include "common/spec/spec_reader.hpp"
#include "fuzz_support.hpp"

namespace {

tally::JobLimits small_limits() {
  tally::JobLimits l;
  l.max_triangles = 1 << 14;
  l.max_vertices = 1 << 15;
  l.max_shapes = 256;
  l.max_gltf_nodes = 1024;
  l.max_texture_bytes = 16u << 20;
  l.max_decode_bytes = 64u << 20;
  l.max_pixels = 1 << 16;
  return l;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const std::string all(reinterpret_cast<const char*>(data) + 1, size - 1);
  const size_t nul = all.find('\0');
  const std::string main_file = all.substr(0, nul);
  const std::string other = nul == std::string::npos ? std::string() : all.substr(nul + 1);
  const tally::JobLimits limits = small_limits();
  const int reader = data[0] % 5;
  const std::string name = reader == 0 ? "s.gltf" : reader == 1 ? "s.glb" : reader == 2 ? "s.obj" : "i.img";
  // A .glb is binary: the whole input after byte 0 is the file.
  const std::string& file = reader == 1 ? all : main_file;
  const tally::AssetReader read = [&](const std::string& rel, const std::string& pointer) -> std::string {
    if (rel == name) return file;
    if (other.empty()) throw tally::SpecError(pointer, "no such asset");
    return other;
  };
  try {
    tally::Scene scene;
    switch (reader) {
      case 0:
      case 1: {
        tally::GltfRequest req;
        req.file = name;
        req.pointer = "/scene/shapes/0/file";
        tally::load_gltf(scene, req, read, limits);
        break;
      }
      case 2: {
        scene.materials.push_back(tally::Material{});
        (void)tally::load_obj(name, "/scene/shapes/0/obj", read, limits, std::nullopt, scene);
        break;
      }
      case 3: (void)tally::decode_texels(file, true, tally::texture_decode_limits(scene, limits)); break;
      default: {
        tally::ImageDecodeLimits dl;
        dl.max_pixels = limits.max_pixels;
        dl.max_bytes = limits.max_decode_bytes;
        dl.kept_bytes_per_pixel = 82;
        (void)tally::decode_image(file, dl);
        break;
      }
    }
  } catch (const tally::SpecError&) {
    return 0;
  } catch (const tally::ImageModuleUnavailable& e) {
    tally::fuzz::fail("the image module is not there", e.what(), all);
  } catch (const std::runtime_error& e) {
    if (reader >= 3) return 0;  // the image readers' refusals
    tally::fuzz::fail("a scene file reader threw something other than SpecError", e.what(), all);
  } catch (const std::exception& e) {
    tally::fuzz::fail("a scene file reader threw something other than SpecError", e.what(), all);
  }
  return 0;
}
