// libtally_image.so built on OpenImageIO (the default, -DTALLY_IMAGE_BACKEND=oiio).
// Opened with dlopen by common/image/image_io.cpp on the first image read or written;
// exports only tally_image_module_api() (built with hidden visibility).
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <exception>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/image/exr_pixels.hpp"
#include "common/image/image_module_abi.hpp"
#include "common/image/image_module_guard.hpp"

namespace {

using tally::guarded;

namespace OIIO = OIIO_NAMESPACE;

void add_metadata(OIIO::ImageSpec& spec, const nlohmann::json& metadata) {
  if (!metadata.is_object()) return;
  for (auto it = metadata.begin(); it != metadata.end(); ++it) {
    const std::string name = "tally:" + it.key();
    const nlohmann::json& v = it.value();
    if (v.is_number()) {
      // EXR has no 64-bit integers: integers are kept exact as double too.
      const double d = v.get<double>();
      spec.attribute(name, OIIO::TypeDesc::DOUBLE, &d);
    } else if (v.is_string()) {
      spec.attribute(name, v.get<std::string>());
    } else {
      spec.attribute(name, v.dump());
    }
  }
}

std::vector<unsigned char> write_to_memory(const char* fake_name, const OIIO::ImageSpec& spec, const void* data,
                                           OIIO::TypeDesc format) {
  std::vector<unsigned char> buffer;
  OIIO::Filesystem::IOVecOutput proxy(buffer);
  auto out = OIIO::ImageOutput::create(fake_name, &proxy);
  if (!out) throw std::runtime_error(std::string("OpenImageIO: no writer for ") + fake_name + ": " + OIIO::geterror());
  if (!out->open(fake_name, spec)) throw std::runtime_error("OpenImageIO open: " + out->geterror());
  if (!out->write_image(format, data)) throw std::runtime_error("OpenImageIO write: " + out->geterror());
  if (!out->close()) throw std::runtime_error("OpenImageIO close: " + out->geterror());
  out.reset();
  return buffer;
}

// encode_exr's and write_exr_file's header: 7 float channels, the data window at the
// view's place in the full image, zip compression, the metadata as attributes.
OIIO::ImageSpec exr_spec(const tally_image_view* im, const char* metadata_json) {
  OIIO::ImageSpec spec(im->width, im->height, 7, OIIO::TypeDesc::FLOAT);
  spec.channelnames = {"R", "G", "B", "StdErr.R", "StdErr.G", "StdErr.B", "SampleCount"};
  spec.alpha_channel = -1;
  spec.x = im->x0;
  spec.y = im->y0;
  spec.full_x = 0;
  spec.full_y = 0;
  spec.full_width = im->full_width > 0 ? im->full_width : im->width;
  spec.full_height = im->full_height > 0 ? im->full_height : im->height;
  spec.attribute("compression", "zip");
  add_metadata(spec, nlohmann::json::parse(metadata_json));
  return spec;
}

int encode_exr(const tally_image_view* im, const char* metadata_json, tally_image_sink out, void* out_context,
               tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        const OIIO::ImageSpec spec = exr_spec(im, metadata_json);
        const size_t n = static_cast<size_t>(im->width) * static_cast<size_t>(im->height);
        std::vector<float> interleaved(7 * n);
        tally::interleave_exr_pixels(im->rgb, im->stderr_rgb, im->samples, n, interleaved.data());
        const auto bytes = write_to_memory("image.exr", spec, interleaved.data(), OIIO::TypeDesc::FLOAT);
        out(out_context, reinterpret_cast<const char*>(bytes.data()), bytes.size());
      },
      error, error_context);
}

int write_exr_file(const tally_image_view* im, const char* metadata_json, const char* path, int32_t strip_rows,
                   tally_image_rows rows, void* rows_context, tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        const OIIO::ImageSpec spec = exr_spec(im, metadata_json);
        auto out = OIIO::ImageOutput::create("openexr");  // by format name: the path may end in anything (".part")
        if (!out) throw std::runtime_error("OpenImageIO: no OpenEXR writer: " + OIIO::geterror());
        if (!out->open(path, spec)) throw std::runtime_error("OpenImageIO open: " + out->geterror());
        const int32_t strip = std::max<int32_t>(1, strip_rows);
        std::vector<float> px(7 * static_cast<size_t>(im->width) * static_cast<size_t>(strip));
        for (int32_t y = 0; y < im->height; y += strip) {
          const int32_t n = std::min(strip, im->height - y);
          if (rows(rows_context, y, n, px.data()) != 0) throw std::runtime_error("the image's rows could not be read");
          if (!out->write_scanlines(spec.y + y, spec.y + y + n, 0, OIIO::TypeDesc::FLOAT, px.data())) {
            throw std::runtime_error("OpenImageIO write: " + out->geterror());
          }
        }
        if (!out->close()) throw std::runtime_error("OpenImageIO close: " + out->geterror());
      },
      error, error_context);
}

int encode_png_rgb8(int32_t width, int32_t height, const unsigned char* rgb8, tally_image_sink out,
                    void* out_context, tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::UINT8);
        const auto bytes = write_to_memory("image.png", spec, rgb8, OIIO::TypeDesc::UINT8);
        out(out_context, reinterpret_cast<const char*>(bytes.data()), bytes.size());
      },
      error, error_context);
}

int decode(const unsigned char* bytes, size_t size, const char* format, uint64_t max_pixels,
           tally_image_receiver receive, void* receive_context, tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        // The format is chosen by the caller (from the bytes' magic): the fake name's
        // extension picks the reader, so OpenImageIO never guesses from content.
        const std::string name = std::string("image.") + (std::string(format) == "jpeg" ? "jpg"
                                                          : std::string(format) == "openexr" ? "exr"
                                                                                            : format);
        OIIO::Filesystem::IOMemReader proxy(bytes, size);
        OIIO::ImageSpec config;
        config.attribute("oiio:UnassociatedAlpha", 1);  // the stored colours, never premultiplied by alpha
        OIIO::Filesystem::IOProxy* proxy_ptr = &proxy;  // with a config, the reader takes the proxy from it
        config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &proxy_ptr);
        auto in = OIIO::ImageInput::open(name, &config, &proxy);
        if (!in) throw std::runtime_error("cannot decode the " + std::string(format) + " image: " + OIIO::geterror());
        const OIIO::ImageSpec& spec = in->spec();
        if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0 || spec.depth != 1) {
          throw std::runtime_error("the image has no pixels or is not a 2-D image");
        }
        const uint64_t pixels = static_cast<uint64_t>(spec.width) * static_cast<uint64_t>(spec.height);
        if (pixels > max_pixels) {
          throw std::runtime_error("the image has " + std::to_string(spec.width) + "x" + std::to_string(spec.height) +
                                   " pixels, more than the limit of " + std::to_string(max_pixels));
        }
        const int bits = spec.format == OIIO::TypeDesc::UINT8 ? 8 : spec.format == OIIO::TypeDesc::UINT16 ? 16 : 32;
        const OIIO::TypeDesc type = bits == 8 ? OIIO::TypeDesc::UINT8 : bits == 16 ? OIIO::TypeDesc::UINT16
                                                                                  : OIIO::TypeDesc::FLOAT;
        std::vector<unsigned char> px(static_cast<size_t>(pixels) * static_cast<size_t>(spec.nchannels) *
                                      static_cast<size_t>(bits / 8));
        if (!in->read_image(0, 0, 0, spec.nchannels, type, px.data())) {
          throw std::runtime_error("cannot decode the " + std::string(format) + " image: " + in->geterror());
        }
        const tally_decoded_image out{spec.width, spec.height, spec.nchannels, bits, px.data()};
        receive(receive_context, &out);
      },
      error, error_context);
}

constexpr tally_image_api kApi{tally::kTallyImageAbiVersion, "OpenImageIO " OIIO_VERSION_STRING, &encode_exr,
                               &encode_png_rgb8, &decode, &write_exr_file};

}  // namespace

extern "C" __attribute__((visibility("default"))) const tally_image_api* tally_image_module_api(void) {
  return &kApi;
}
