// libtally_image.so built on OpenEXR and libpng directly (-DTALLY_IMAGE_BACKEND=openexr):
// the same C interface and the same formats as the OpenImageIO module
// (image_module_oiio.cpp) with a few megabytes of dependencies instead of OpenImageIO's
// few hundred. The container image uses it; tests/image checks that its files decode to
// the same channels, pixels, windows and attributes as the OpenImageIO module's.
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfCompression.h>
#include <OpenEXR/ImfDoubleAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfIO.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStandardAttributes.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <OpenEXR/OpenEXRConfig.h>
#include <png.h>
#include <zlib.h>

#include <cstring>
#include <ctime>
#include <exception>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/image/image_module_abi.hpp"
#include "common/image/image_module_guard.hpp"

namespace {

using tally::guarded;

// An OpenEXR output stream into memory (OutputFile seeks back to write the offset table).
class MemoryStream : public Imf::OStream {
 public:
  MemoryStream() : Imf::OStream("memory") {}
  void write(const char c[], int n) override {
    const size_t end = pos_ + static_cast<size_t>(n);
    if (end > bytes.size()) bytes.resize(end);
    std::memcpy(bytes.data() + pos_, c, static_cast<size_t>(n));
    pos_ = end;
  }
  uint64_t tellp() override { return pos_; }
  void seekp(uint64_t pos) override { pos_ = static_cast<size_t>(pos); }

  std::string bytes;

 private:
  size_t pos_ = 0;
};

// Local time "YYYY:MM:DD HH:MM:SS", the capDate OpenImageIO stamps its EXR files with.
std::string cap_date() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  localtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y:%m:%d %H:%M:%S", &tm);
  return buf;
}

int encode_exr(const tally_image_view* im, const char* metadata_json, tally_image_sink out, void* out_context,
               tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        const int fw = im->full_width > 0 ? im->full_width : im->width;
        const int fh = im->full_height > 0 ? im->full_height : im->height;
        const Imath::Box2i display(Imath::V2i(0, 0), Imath::V2i(fw - 1, fh - 1));
        const Imath::Box2i data(Imath::V2i(im->x0, im->y0),
                                Imath::V2i(im->x0 + im->width - 1, im->y0 + im->height - 1));
        Imf::Header header(display, data, 1.0f, Imath::V2f(0, 0), 1.0f, Imf::INCREASING_Y, Imf::ZIP_COMPRESSION);
        Imf::addCapDate(header, cap_date());  // as OpenImageIO writes it
        static const char* const names[7] = {"R", "G", "B", "StdErr.R", "StdErr.G", "StdErr.B", "SampleCount"};
        for (const char* n : names) header.channels().insert(n, Imf::Channel(Imf::FLOAT));
        // Attributes as the OpenImageIO module writes them: numbers as double, strings
        // as strings, anything else as its JSON text.
        const nlohmann::json metadata = nlohmann::json::parse(metadata_json);
        for (auto it = metadata.begin(); it != metadata.end(); ++it) {
          const std::string name = "tally:" + it.key();
          const nlohmann::json& v = it.value();
          if (v.is_number()) {
            header.insert(name, Imf::DoubleAttribute(v.get<double>()));
          } else if (v.is_string()) {
            header.insert(name, Imf::StringAttribute(v.get<std::string>()));
          } else {
            header.insert(name, Imf::StringAttribute(v.dump()));
          }
        }
        // The planes as one interleaved buffer, 7 floats a pixel, addressed in data-window
        // coordinates (OpenEXR's convention: base = pointer to pixel (0, 0)).
        const size_t w = static_cast<size_t>(im->width), h = static_cast<size_t>(im->height);
        std::vector<float> px(7 * w * h);
        for (size_t i = 0; i < w * h; ++i) {
          for (size_t c = 0; c < 3; ++c) {
            px[7 * i + c] = im->rgb[3 * i + c];
            px[7 * i + 3 + c] = im->stderr_rgb[3 * i + c];
          }
          px[7 * i + 6] = im->samples[i];
        }
        const size_t xs = 7 * sizeof(float), ys = xs * w;
        const std::ptrdiff_t origin = static_cast<std::ptrdiff_t>(im->x0) * static_cast<std::ptrdiff_t>(xs) +
                                      static_cast<std::ptrdiff_t>(im->y0) * static_cast<std::ptrdiff_t>(ys);
        Imf::FrameBuffer fb;
        for (size_t c = 0; c < 7; ++c) {
          char* base = reinterpret_cast<char*>(px.data() + c) - origin;
          fb.insert(names[c], Imf::Slice(Imf::FLOAT, base, xs, ys));
        }
        MemoryStream stream;
        {
          Imf::OutputFile file(stream, header, 1);
          file.setFrameBuffer(fb);
          file.writePixels(im->height);
        }
        out(out_context, stream.bytes.data(), stream.bytes.size());
      },
      error, error_context);
}

struct PngState {
  std::string bytes;
  std::string error;
};

void png_append(png_structp png, png_bytep data, png_size_t size) {
  static_cast<PngState*>(png_get_io_ptr(png))->bytes.append(reinterpret_cast<const char*>(data), size);
}
void png_flush(png_structp) {}
void png_fail(png_structp png, png_const_charp message) {
  static_cast<PngState*>(png_get_error_ptr(png))->error = message;
  png_longjmp(png, 1);
}
void png_warn(png_structp, png_const_charp) {}

// libpng reports errors by longjmp: nothing with a destructor lives in this frame.
bool write_png(PngState& st, int32_t width, int32_t height, const unsigned char* rgb8) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &st, &png_fail, &png_warn);
  if (png == nullptr) return false;
  png_infop info = png_create_info_struct(png);
  if (info == nullptr || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  png_set_write_fn(png, &st, &png_append, &png_flush);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8, PNG_COLOR_TYPE_RGB,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  // As OpenImageIO writes it: an oFFs chunk, zlib level 6 with the default strategy.
  png_set_oFFs(png, info, 0, 0, PNG_OFFSET_PIXEL);
  png_set_compression_level(png, 6);
  png_set_compression_strategy(png, Z_DEFAULT_STRATEGY);
  png_write_info(png, info);
  for (int32_t y = 0; y < height; ++y) {
    png_write_row(png, rgb8 + static_cast<size_t>(y) * 3 * static_cast<size_t>(width));
  }
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return true;
}

int encode_png_rgb8(int32_t width, int32_t height, const unsigned char* rgb8, tally_image_sink out,
                    void* out_context, tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        PngState st;
        if (!write_png(st, width, height, rgb8)) {
          throw std::runtime_error("libpng: " + (st.error.empty() ? std::string("out of memory") : st.error));
        }
        out(out_context, st.bytes.data(), st.bytes.size());
      },
      error, error_context);
}

constexpr tally_image_api kApi{tally::kTallyImageAbiVersion, "OpenEXR " OPENEXR_VERSION_STRING " + libpng " PNG_LIBPNG_VER_STRING,
                               &encode_exr, &encode_png_rgb8};

}  // namespace

extern "C" __attribute__((visibility("default"))) const tally_image_api* tally_image_module_api(void) {
  return &kApi;
}
