#include "common/image/image_io.hpp"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <stdexcept>
#include <vector>

namespace tally {

namespace {

namespace OIIO = OIIO_NAMESPACE;

void check_snapshot(const ImageSnapshot& im) {
  const size_t n = static_cast<size_t>(std::max(im.width, 0)) * static_cast<size_t>(std::max(im.height, 0));
  if (im.width <= 0 || im.height <= 0) throw std::runtime_error("image snapshot is empty");
  if (im.rgb.size() != 3 * n || im.stderr_rgb.size() != 3 * n || im.samples.size() != n) {
    throw std::runtime_error(fmt::format(
        "image snapshot {}x{} has {} rgb, {} stderr, {} sample values", im.width, im.height,
        im.rgb.size(), im.stderr_rgb.size(), im.samples.size()));
  }
}

void add_metadata(OIIO::ImageSpec& spec, const nlohmann::json& metadata) {
  if (!metadata.is_object()) return;
  for (auto it = metadata.begin(); it != metadata.end(); ++it) {
    const std::string name = "tally:" + it.key();
    const nlohmann::json& v = it.value();
    if (v.is_number_integer() || v.is_number_unsigned()) {
      // EXR has no 64-bit integers: keep exact values as double.
      const double d = v.get<double>();
      spec.attribute(name, OIIO::TypeDesc::DOUBLE, &d);
    } else if (v.is_number()) {
      const double d = v.get<double>();
      spec.attribute(name, OIIO::TypeDesc::DOUBLE, &d);
    } else if (v.is_string()) {
      spec.attribute(name, v.get<std::string>());
    } else {
      spec.attribute(name, v.dump());
    }
  }
}

std::string write_to_memory(const char* fake_name, const OIIO::ImageSpec& spec, const void* data,
                            OIIO::TypeDesc format) {
  std::vector<unsigned char> buffer;
  OIIO::Filesystem::IOVecOutput proxy(buffer);
  auto out = OIIO::ImageOutput::create(fake_name, &proxy);
  if (!out) throw std::runtime_error(fmt::format("OpenImageIO: no writer for {}: {}", fake_name, OIIO::geterror()));
  if (!out->open(fake_name, spec)) throw std::runtime_error("OpenImageIO open: " + out->geterror());
  if (!out->write_image(format, data)) throw std::runtime_error("OpenImageIO write: " + out->geterror());
  if (!out->close()) throw std::runtime_error("OpenImageIO close: " + out->geterror());
  out.reset();
  return std::string(reinterpret_cast<const char*>(buffer.data()), buffer.size());
}

void write_file(const std::filesystem::path& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) throw std::runtime_error(fmt::format("cannot open {} for writing", path.string()));
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!f) throw std::runtime_error(fmt::format("failed writing {}", path.string()));
}

}  // namespace

double srgb_oetf(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1.0 / 2.4) - 0.055;
}

std::string encode_exr(const ImageSnapshot& im, const nlohmann::json& metadata) {
  check_snapshot(im);
  OIIO::ImageSpec spec(im.width, im.height, 7, OIIO::TypeDesc::FLOAT);
  spec.channelnames = {"R", "G", "B", "StdErr.R", "StdErr.G", "StdErr.B", "SampleCount"};
  spec.alpha_channel = -1;
  spec.x = im.x0;
  spec.y = im.y0;
  spec.full_x = 0;
  spec.full_y = 0;
  spec.full_width = im.full_width > 0 ? im.full_width : im.width;
  spec.full_height = im.full_height > 0 ? im.full_height : im.height;
  spec.attribute("compression", "zip");
  add_metadata(spec, metadata);
  const size_t n = static_cast<size_t>(im.width) * static_cast<size_t>(im.height);
  std::vector<float> interleaved(7 * n);
  for (size_t i = 0; i < n; ++i) {
    float* px = &interleaved[7 * i];
    for (int c = 0; c < 3; ++c) {
      px[c] = im.rgb[3 * i + static_cast<size_t>(c)];
      px[3 + c] = im.stderr_rgb[3 * i + static_cast<size_t>(c)];
    }
    px[6] = im.samples[i];
  }
  return write_to_memory("image.exr", spec, interleaved.data(), OIIO::TypeDesc::FLOAT);
}

std::string encode_png(const ImageSnapshot& im) {
  check_snapshot(im);
  OIIO::ImageSpec spec(im.width, im.height, 3, OIIO::TypeDesc::UINT8);
  const size_t n = static_cast<size_t>(im.width) * static_cast<size_t>(im.height);
  std::vector<unsigned char> px(3 * n);
  for (size_t i = 0; i < 3 * n; ++i) {
    const double v = static_cast<double>(im.rgb[i]);
    // NaN (no samples yet) shows as black.
    px[i] = static_cast<unsigned char>(std::lround(255.0 * srgb_oetf(std::isnan(v) ? 0.0 : v)));
  }
  return write_to_memory("image.png", spec, px.data(), OIIO::TypeDesc::UINT8);
}

void write_image_files(const ImageSnapshot& image, const nlohmann::json& metadata,
                       const std::filesystem::path& exr_path, const std::filesystem::path& png_path) {
  if (!exr_path.empty()) write_file(exr_path, encode_exr(image, metadata));
  if (!png_path.empty()) write_file(png_path, encode_png(image));
}

}  // namespace tally
