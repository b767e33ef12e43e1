#include "common/image/image_io.hpp"

#include "common/image/exr_pixels.hpp"

#include <dlfcn.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <stdexcept>
#include <system_error>
#include <vector>

#include "common/image/image_decode.hpp"
#include "common/image/image_header.hpp"
#include "common/image/image_module_abi.hpp"

namespace tally {

namespace {

constexpr const char* kModuleFile = "libtally_image.so";

struct LoadedModule {
  const tally_image_api* api = nullptr;
  std::string path;
  std::string error;  // why api is null
};

std::vector<std::filesystem::path> module_candidates() {
  std::vector<std::filesystem::path> out;
  if (const char* env = std::getenv("TALLY_IMAGE_MODULE"); env != nullptr && *env != '\0') {
    out.emplace_back(env);
    return out;  // an explicit choice is the only one tried
  }
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    out.push_back(exe.parent_path() / kModuleFile);                          // next to the binary
    out.push_back(exe.parent_path().parent_path() / "lib" / "tally" / kModuleFile);  // <prefix>/bin -> <prefix>/lib/tally
  }
#ifdef TALLY_IMAGE_MODULE_INSTALL_DIR
  out.push_back(std::filesystem::path(TALLY_IMAGE_MODULE_INSTALL_DIR) / kModuleFile);
#endif
#ifdef TALLY_IMAGE_MODULE_BUILD_DIR
  out.push_back(std::filesystem::path(TALLY_IMAGE_MODULE_BUILD_DIR) / kModuleFile);
#endif
  return out;
}

LoadedModule load_module() {
  LoadedModule m;
  std::string looked;
  for (const auto& path : module_candidates()) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      looked += (looked.empty() ? "" : ", ") + path.string();
      continue;
    }
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
      const char* why = dlerror();
      m.error = fmt::format("cannot load the image module {}: {}", path.string(), why ? why : "unknown error");
      return m;
    }
    using Entry = const tally_image_api* (*)();
    auto entry = reinterpret_cast<Entry>(dlsym(handle, kTallyImageModuleSymbol));
    const tally_image_api* api = entry ? entry() : nullptr;
    if (api == nullptr || api->abi_version != kTallyImageAbiVersion) {
      m.error = fmt::format("{} is not a compatible tally image module (wants ABI {})", path.string(),
                            kTallyImageAbiVersion);
      return m;  // the handle stays open: unloading code that may have run is not worth it
    }
    m.api = api;
    m.path = path.string();
    return m;
  }
  m.error = fmt::format("image support is not available: the image module {} was not found; looked in {} (set TALLY_IMAGE_MODULE to its path)",
                        kModuleFile, looked.empty() ? "no place" : looked);
  return m;
}

const LoadedModule& loaded_module() {
  static const LoadedModule m = load_module();  // once, thread-safe, on the first image
  return m;
}

const tally_image_api& api() {
  const LoadedModule& m = loaded_module();
  if (m.api == nullptr) throw ImageModuleUnavailable(m.error);
  return *m.api;
}

void append_to_string(void* context, const char* data, size_t size) {
  static_cast<std::string*>(context)->append(data, size);
}

void check_snapshot(const ImageSnapshot& im) {
  const size_t n = static_cast<size_t>(std::max(im.width, 0)) * static_cast<size_t>(std::max(im.height, 0));
  if (im.width <= 0 || im.height <= 0) throw std::runtime_error("image snapshot is empty");
  if (im.rgb.size() != 3 * n || im.stderr_rgb.size() != 3 * n || im.samples.size() != n) {
    throw std::runtime_error(fmt::format(
        "image snapshot {}x{} has {} rgb, {} stderr, {} sample values", im.width, im.height,
        im.rgb.size(), im.stderr_rgb.size(), im.samples.size()));
  }
}

void write_file(const std::filesystem::path& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) throw std::runtime_error(fmt::format("cannot open {} for writing", path.string()));
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!f) throw std::runtime_error(fmt::format("failed writing {}", path.string()));
}

}  // namespace

std::string image_module_path() {
  const LoadedModule& m = loaded_module();
  if (m.api == nullptr) throw ImageModuleUnavailable(m.error);
  return m.path;
}

std::string image_module_backend() { return api().backend; }

void preload_image_module() { (void)loaded_module(); }

double srgb_oetf(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1.0 / 2.4) - 0.055;
}

std::string encode_exr(const ImageSnapshot& im, const nlohmann::json& metadata) {
  check_snapshot(im);
  const tally_image_api& a = api();
  const tally_image_view view{im.x0, im.y0, im.width, im.height, im.full_width, im.full_height,
                              im.rgb.data(), im.stderr_rgb.data(), im.samples.data()};
  const std::string meta = metadata.is_object() ? metadata.dump() : std::string("{}");
  std::string out, error;
  if (a.encode_exr(&view, meta.c_str(), &append_to_string, &out, &append_to_string, &error) != 0) {
    throw std::runtime_error(error);
  }
  return out;
}

namespace {
struct StripSource {
  const ImageSource& source;
  const JobState& state;
  std::string error;  // why a strip could not be read
};

int fill_strip(void* context, int32_t y, int32_t rows, float* px) {
  auto& s = *static_cast<StripSource*>(context);
  try {
    const ImageSnapshot snap = s.source.snapshot(s.state, TileRect{0, y, s.source.width(), rows});
    check_snapshot(snap);
    interleave_exr_pixels(snap.rgb.data(), snap.stderr_rgb.data(), snap.samples.data(), snap.samples.size(), px);
    return 0;
  } catch (const std::exception& e) {
    s.error = e.what();
    return 1;
  }
}
}  // namespace

void write_exr_file(const ImageSource& source, const JobState& state, const nlohmann::json& metadata,
                    const std::filesystem::path& path, int strip_rows) {
  const tally_image_api& a = api();
  const tally_image_view window{0, 0, source.width(), source.height(), source.width(), source.height(),
                                nullptr, nullptr, nullptr};
  const std::string meta = metadata.is_object() ? metadata.dump() : std::string("{}");
  const std::filesystem::path part = path.string() + ".part";
  StripSource strips{source, state, {}};
  std::string error;
  if (a.write_exr_file(&window, meta.c_str(), part.c_str(), strip_rows, &fill_strip, &strips, &append_to_string,
                       &error) != 0) {
    std::error_code ignored;
    std::filesystem::remove(part, ignored);
    // Named by the path asked for: the .part file is this function's own business.
    throw std::runtime_error("cannot write " + path.string() + ": " +
                             (strips.error.empty() ? error : error + ": " + strips.error));
  }
  std::error_code ec;
  std::filesystem::rename(part, path, ec);
  if (ec) {
    std::error_code ignored;
    std::filesystem::remove(part, ignored);
    throw std::runtime_error("cannot write " + path.string() + ": " + ec.message());
  }
}

std::string encode_png(const ImageSnapshot& im) {
  check_snapshot(im);
  const tally_image_api& a = api();
  const size_t n = static_cast<size_t>(im.width) * static_cast<size_t>(im.height);
  std::vector<unsigned char> px(3 * n);
  for (size_t i = 0; i < 3 * n; ++i) {
    const double v = static_cast<double>(im.rgb[i]);
    // NaN (no samples yet) shows as black.
    px[i] = static_cast<unsigned char>(std::lround(255.0 * srgb_oetf(std::isnan(v) ? 0.0 : v)));
  }
  std::string out, error;
  if (a.encode_png_rgb8(im.width, im.height, px.data(), &append_to_string, &out, &append_to_string, &error) != 0) {
    throw std::runtime_error(error);
  }
  return out;
}

std::optional<std::string> sniff_image_format(std::string_view b) {
  auto starts = [&](std::string_view magic) { return b.substr(0, magic.size()) == magic; };
  if (starts("\x89PNG\r\n\x1a\n")) return "png";
  if (starts("\xff\xd8\xff")) return "jpeg";
  if (starts("\x76\x2f\x31\x01")) return "openexr";
  if (starts("#?RADIANCE") || starts("#?RGBE")) return "hdr";
  return std::nullopt;
}

namespace {
void receive_decoded(void* context, const tally_decoded_image* im) {
  auto* out = static_cast<DecodedImage*>(context);
  out->width = im->width;
  out->height = im->height;
  out->channels = im->channels;
  out->bits = im->bits;
  const size_t n = static_cast<size_t>(im->width) * static_cast<size_t>(im->height) * static_cast<size_t>(im->channels);
  if (im->bits == 8) {
    const auto* p = static_cast<const uint8_t*>(im->pixels);
    out->codes.assign(p, p + n);
  } else if (im->bits == 16) {
    const auto* p = static_cast<const uint16_t*>(im->pixels);
    out->codes.assign(p, p + n);
  } else {
    const auto* p = static_cast<const float*>(im->pixels);
    out->floats.assign(p, p + n);
  }
}
}  // namespace

DecodedImage decode_image(std::string_view bytes, const ImageDecodeLimits& limits) {
  const ImageHeader h = read_image_header(bytes);
  if (h.pixels() > limits.max_pixels) {
    throw std::runtime_error(fmt::format("the image has {}x{} pixels, more than the limit of {}", h.width, h.height,
                                         limits.max_pixels));
  }
  if (h.channels > limits.max_channels) {
    throw std::runtime_error(fmt::format("the image has {} channels, more than the limit of {} (max_image_channels)",
                                         h.channels, limits.max_channels));
  }
  const uint64_t kept = h.pixels() > UINT64_MAX / std::max<uint64_t>(limits.kept_bytes_per_pixel, 1)
                            ? UINT64_MAX
                            : h.pixels() * limits.kept_bytes_per_pixel;
  const uint64_t charge = kept > UINT64_MAX - h.decode_bytes() ? UINT64_MAX : kept + h.decode_bytes();
  if (charge > limits.max_bytes) {
    throw std::runtime_error(fmt::format("decoding the {}x{} image of {} channels takes {} bytes, more than the {} left "
                                         "of the job's limit (max_decode_bytes)",
                                         h.width, h.height, h.channels, charge, limits.max_bytes));
  }
  const tally_image_api& a = api();
  DecodedImage out;
  std::string error;
  if (a.decode(reinterpret_cast<const unsigned char*>(bytes.data()), bytes.size(), h.format.c_str(), limits.max_pixels,
               &receive_decoded, &out, &append_to_string, &error) != 0) {
    throw std::runtime_error(error);
  }
  if (out.width <= 0 || out.height <= 0 || out.channels <= 0) throw std::runtime_error("the image has no pixels");
  out.charged_bytes = charge;
  return out;
}

void write_image_files(const ImageSnapshot& image, const nlohmann::json& metadata,
                       const std::filesystem::path& exr_path, const std::filesystem::path& png_path) {
  if (!exr_path.empty()) write_file(exr_path, encode_exr(image, metadata));
  if (!png_path.empty()) write_file(png_path, encode_png(image));
}

}  // namespace tally
