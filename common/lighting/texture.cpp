#include "common/lighting/texture.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include "common/image/image_decode.hpp"
#include "common/lighting/scene.hpp"

namespace tally {

double srgb_eotf(double c) {
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

std::shared_ptr<const TexelGrid> make_texels(const DecodedImage& im, bool srgb) {
  if (im.width <= 0 || im.height <= 0 || im.channels <= 0) throw std::runtime_error("the image has no pixels");
  const size_t n = static_cast<size_t>(im.width) * static_cast<size_t>(im.height);
  const size_t nc = static_cast<size_t>(im.channels);
  const bool ints = im.bits == 8 || im.bits == 16;
  if ((ints ? im.codes.size() : im.floats.size()) != n * nc) throw std::runtime_error("the decoded image is incomplete");
  auto grid = std::make_shared<TexelGrid>();
  grid->width = im.width;
  grid->height = im.height;
  grid->rgb.resize(3 * n);
  // Integer codes through a table (8 bits: 256 entries; 16 bits: computed per code).
  const double max_code = im.bits == 8 ? 255.0 : 65535.0;
  std::array<float, 256> table8{};
  if (im.bits == 8) {
    for (int k = 0; k < 256; ++k) {
      const double c = k / 255.0;
      table8[static_cast<size_t>(k)] = static_cast<float>(srgb ? srgb_eotf(c) : c);
    }
  }
  auto from_code = [&](uint16_t code) {
    if (im.bits == 8) return table8[code & 0xFFu];
    const double c = code / max_code;
    return static_cast<float>(srgb ? srgb_eotf(c) : c);
  };
  for (size_t i = 0; i < n; ++i) {
    for (size_t c = 0; c < 3; ++c) {
      const size_t src = i * nc + (nc < 3 ? 0 : c);  // grey (+ alpha): the grey value in R, G and B
      float v;
      if (ints) {
        v = from_code(im.codes[src]);
      } else {
        v = im.floats[src];
        if (!std::isfinite(v) || v < 0) {
          throw std::runtime_error(fmt::format("texel ({}, {}) is negative or not finite", i % static_cast<size_t>(im.width),
                                               i / static_cast<size_t>(im.width)));
        }
      }
      grid->rgb[3 * i + c] = v;
    }
  }
  return grid;
}

std::shared_ptr<const TexelGrid> decode_texels(std::string_view bytes, bool srgb, ImageDecodeLimits limits,
                                               uint64_t* charged) {
  const auto format = sniff_image_format(bytes);
  if (!format || (*format != "png" && *format != "jpeg")) {
    throw std::runtime_error(format ? fmt::format("{} textures are not supported (PNG and JPEG are)", *format)
                                    : std::string("is not a PNG or JPEG image"));
  }
  limits.kept_bytes_per_pixel = kTexelBytes;
  const DecodedImage im = decode_image(bytes, limits);
  if (charged) *charged = im.charged_bytes;
  return make_texels(im, srgb);
}

ImageDecodeLimits texture_decode_limits(const Scene& scene, const JobLimits& limits) {
  ImageDecodeLimits d;
  d.max_pixels = (limits.max_texture_bytes > scene.texture_bytes ? limits.max_texture_bytes - scene.texture_bytes : 0) /
                 kTexelBytes;
  d.max_channels = static_cast<uint32_t>(std::min<size_t>(limits.max_image_channels, UINT32_MAX));
  d.max_bytes = limits.max_decode_bytes > scene.decode_bytes ? limits.max_decode_bytes - scene.decode_bytes : 0;
  return d;
}

int64_t wrap_texel(int64_t i, int64_t n, TextureWrap wrap) {
  switch (wrap) {
    case TextureWrap::clamp_to_edge: return std::clamp<int64_t>(i, 0, n - 1);
    case TextureWrap::mirrored_repeat: {
      const int64_t m = ((i % (2 * n)) + 2 * n) % (2 * n);
      return m < n ? m : 2 * n - 1 - m;
    }
    case TextureWrap::repeat: break;
  }
  return ((i % n) + n) % n;
}

namespace {

// The coordinate reduced to one period of the wrap (exact: x - floor(x) and
// x - 2 floor(x / 2) lose nothing), so texel positions stay small integers.
double reduce(double x, TextureWrap wrap) {
  switch (wrap) {
    case TextureWrap::repeat: return x - std::floor(x);
    case TextureWrap::mirrored_repeat: return x - 2.0 * std::floor(0.5 * x);
    case TextureWrap::clamp_to_edge: return std::clamp(x, -1.0, 2.0);
  }
  return x;
}

Rgb lerp(const Rgb& a, const Rgb& b, double t) { return a + (b - a) * t; }

}  // namespace

Rgb Texture::lookup(Vec2 uv) const {
  const TexelGrid& g = *texels;
  if (filter == TextureFilter::nearest) {
    const auto ix = static_cast<int64_t>(std::floor(reduce(uv.x, wrap_s) * g.width));
    const auto iy = static_cast<int64_t>(std::floor(reduce(uv.y, wrap_t) * g.height));
    return g.at(wrap_texel(ix, g.width, wrap_s), wrap_texel(iy, g.height, wrap_t));
  }
  const double x = reduce(uv.x, wrap_s) * g.width - 0.5;
  const double y = reduce(uv.y, wrap_t) * g.height - 0.5;
  const double x0 = std::floor(x), y0 = std::floor(y);
  const double fx = x - x0, fy = y - y0;
  const auto ix = static_cast<int64_t>(x0), iy = static_cast<int64_t>(y0);
  const int64_t i0 = wrap_texel(ix, g.width, wrap_s), i1 = wrap_texel(ix + 1, g.width, wrap_s);
  const int64_t j0 = wrap_texel(iy, g.height, wrap_t), j1 = wrap_texel(iy + 1, g.height, wrap_t);
  return lerp(lerp(g.at(i0, j0), g.at(i1, j0), fx), lerp(g.at(i0, j1), g.at(i1, j1), fx), fy);
}

const Material& textured_material(const Scene& scene, uint32_t index, Vec2 uv, Material& scratch) {
  const Material& m = scene.materials[index];
  if (!m.textured()) return m;
  scratch = m;
  if (m.base_color_texture >= 0) {
    const Rgb t = scene.textures[static_cast<size_t>(m.base_color_texture)].lookup(uv);
    if (m.type == MaterialType::metallic_roughness) {
      scratch.base_color = m.base_color * t;
    } else {
      scratch.albedo = m.albedo * t;
    }
  }
  if (m.metallic_roughness_texture >= 0) {
    const Rgb t = scene.textures[static_cast<size_t>(m.metallic_roughness_texture)].lookup(uv);
    scratch.roughness = m.roughness * t.y;
    scratch.metallic = m.metallic * t.z;
  }
  if (m.specular_color_texture >= 0) {
    scratch.specular_color = m.specular_color * scene.textures[static_cast<size_t>(m.specular_color_texture)].lookup(uv);
  }
  if (m.emission_texture >= 0) scratch.emission = textured_emission(scene, m, uv);
  return scratch;
}

Rgb textured_emission(const Scene& scene, const Material& m, Vec2 uv) {
  if (m.emission_texture < 0) return m.emission;
  return m.emission * scene.textures[static_cast<size_t>(m.emission_texture)].lookup(uv);
}

}  // namespace tally
