#pragma once
// Image textures of a lighting scene (glTF baseColor / metallicRoughness / emissive
// textures, OBJ .mtl map_Kd): decoded once when the job is compiled, through the image
// module (common/image/image_decode.hpp), into linear RGB floats.
//
// Thread-safety: a TexelGrid and a Texture are immutable after they are built; the
// compiled scene holds them (through Scene::textures) and every worker thread reads
// them concurrently without locks. lookup() is a pure function of (texture, uv), so
// renders stay bit-identical for any thread count.
//
// Conventions (glTF 2.0): uv (0, 0) is the top-left corner of the image, u grows to the
// right and v downwards; texel (i, j) has its centre at ((i + 0.5) / W, (j + 0.5) / H).
// Filtering is bilinear between the four nearest texel centres, or nearest (the texel
// whose cell holds uv: glTF's NEAREST sampler filter); the wrap mode of each axis (glTF
// sampler wrapS / wrapT) decides which texel lies beyond an edge.
#include <cstdint>
#include <memory>
#include <string_view>
#include <vector>

#include "common/engine/limits.hpp"
#include "common/image/image_decode.hpp"
#include "common/math/vec3.hpp"

namespace tally {

struct Material;
struct Scene;
using Rgb = Vec3;

enum class TextureWrap { repeat, clamp_to_edge, mirrored_repeat };
enum class TextureFilter { linear, nearest };

// Linear RGB texels, 3 floats each, rows from the top of the image.
struct TexelGrid {
  int width = 0, height = 0;
  std::vector<float> rgb;
  uint64_t bytes() const { return rgb.size() * sizeof(float); }
  Rgb at(int64_t i, int64_t j) const {
    const float* p = &rgb[3 * (static_cast<size_t>(j) * static_cast<size_t>(width) + static_cast<size_t>(i))];
    return {static_cast<double>(p[0]), static_cast<double>(p[1]), static_cast<double>(p[2])};
  }
};

inline constexpr uint64_t kTexelBytes = 3 * sizeof(float);

// The sRGB electro-optical transfer function (IEC 61966-2-1): an encoded value in
// [0, 1] -> linear: c / 12.92 up to 0.04045, ((c + 0.055) / 1.055)^2.4 above.
double srgb_eotf(double encoded);

// A decoded file as texels. Channels: 1 grey, 2 grey + alpha, 3 RGB, 4 or more RGB +
// the rest (alpha is ignored: tally renders opaque surfaces). Integer codes are
// normalised (code / (2^bits - 1)) and, with `srgb`, decoded by srgb_eotf; float
// files are taken as linear. Throws std::runtime_error on a non-finite or negative
// float texel.
std::shared_ptr<const TexelGrid> make_texels(const DecodedImage& image, bool srgb);

// Decodes an encoded file (PNG or JPEG; common/image) into texels within `limits`
// (kept_bytes_per_pixel is set to kTexelBytes here); `*charged` (if given) receives the
// bytes the decode was charged. Throws std::runtime_error (what() says why) or
// ImageModuleUnavailable.
std::shared_ptr<const TexelGrid> decode_texels(std::string_view bytes, bool srgb, ImageDecodeLimits limits,
                                               uint64_t* charged = nullptr);
inline std::shared_ptr<const TexelGrid> decode_texels(std::string_view bytes, bool srgb, uint64_t max_texels) {
  return decode_texels(bytes, srgb, ImageDecodeLimits{max_texels});
}

// What one more texture of `scene` may take: the texels left of
// limits.max_texture_bytes, the channels, and the bytes left of limits.max_decode_bytes.
ImageDecodeLimits texture_decode_limits(const Scene& scene, const JobLimits& limits);

struct Texture {
  std::shared_ptr<const TexelGrid> texels;
  TextureWrap wrap_s = TextureWrap::repeat, wrap_t = TextureWrap::repeat;
  TextureFilter filter = TextureFilter::linear;

  // Lookup at any finite uv. Bilinear: between four equal texels it returns exactly that
  // texel's value (each step is a + t (b - a)), so a constant texture equals its value.
  // Nearest: the texel (floor(u W), floor(v H)), wrapped; exactly one texel's value.
  Rgb lookup(Vec2 uv) const;
};

// The texel index that lies at integer position i (may be outside [0, n)) under `wrap`.
int64_t wrap_texel(int64_t i, int64_t n, TextureWrap wrap);

// The material as seen at texture coordinates `uv`: `scene.materials[index]` itself when
// it has no texture, else a copy in `scratch` with each factor multiplied by its
// texture as glTF says: base colour (or the Lambertian albedo of diffuse/Phong
// materials, OBJ map_Kd) x the texture's RGB; roughness x G, metallic x B of the
// metallic-roughness texture; emission x the emissive texture's RGB.
const Material& textured_material(const Scene& scene, uint32_t index, Vec2 uv, Material& scratch);

// The material's emission at `uv` (the emission factor times its emissive texture).
Rgb textured_emission(const Scene& scene, const Material& m, Vec2 uv);

}  // namespace tally
