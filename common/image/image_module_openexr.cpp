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
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStandardAttributes.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <OpenEXR/OpenEXRConfig.h>
#include <png.h>
#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <ctime>
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

const char* const kExrChannels[7] = {"R", "G", "B", "StdErr.R", "StdErr.G", "StdErr.B", "SampleCount"};

// encode_exr's and write_exr_file's header, as the OpenImageIO module writes it.
Imf::Header exr_header(const tally_image_view* im, const char* metadata_json) {
  const int fw = im->full_width > 0 ? im->full_width : im->width;
  const int fh = im->full_height > 0 ? im->full_height : im->height;
  const Imath::Box2i display(Imath::V2i(0, 0), Imath::V2i(fw - 1, fh - 1));
  const Imath::Box2i data(Imath::V2i(im->x0, im->y0), Imath::V2i(im->x0 + im->width - 1, im->y0 + im->height - 1));
  Imf::Header header(display, data, 1.0f, Imath::V2f(0, 0), 1.0f, Imf::INCREASING_Y, Imf::ZIP_COMPRESSION);
  Imf::addCapDate(header, cap_date());  // as OpenImageIO writes it
  for (const char* n : kExrChannels) header.channels().insert(n, Imf::Channel(Imf::FLOAT));
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
  return header;
}

// A frame buffer over `px`, 7 interleaved floats a pixel, `width` a row, holding the rows
// from data-window row `y` on (OpenEXR's convention: base = the address of pixel (0, 0)).
Imf::FrameBuffer exr_frame(const tally_image_view* im, float* px, int32_t y) {
  const size_t xs = 7 * sizeof(float), ys = xs * static_cast<size_t>(im->width);
  const std::ptrdiff_t origin = static_cast<std::ptrdiff_t>(im->x0) * static_cast<std::ptrdiff_t>(xs) +
                                static_cast<std::ptrdiff_t>(im->y0 + y) * static_cast<std::ptrdiff_t>(ys);
  Imf::FrameBuffer fb;
  for (size_t c = 0; c < 7; ++c) {
    char* base = reinterpret_cast<char*>(px + c) - origin;
    fb.insert(kExrChannels[c], Imf::Slice(Imf::FLOAT, base, xs, ys));
  }
  return fb;
}

int encode_exr(const tally_image_view* im, const char* metadata_json, tally_image_sink out, void* out_context,
               tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        const Imf::Header header = exr_header(im, metadata_json);
        // The planes as one interleaved buffer, 7 floats a pixel.
        const size_t w = static_cast<size_t>(im->width), h = static_cast<size_t>(im->height);
        std::vector<float> px(7 * w * h);
        tally::interleave_exr_pixels(im->rgb, im->stderr_rgb, im->samples, w * h, px.data());
        MemoryStream stream;
        {
          Imf::OutputFile file(stream, header, 1);
          file.setFrameBuffer(exr_frame(im, px.data(), 0));
          file.writePixels(im->height);
        }
        out(out_context, stream.bytes.data(), stream.bytes.size());
      },
      error, error_context);
}

int write_exr_file(const tally_image_view* im, const char* metadata_json, const char* path, int32_t strip_rows,
                   tally_image_rows rows, void* rows_context, tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        const Imf::Header header = exr_header(im, metadata_json);
        const int32_t strip = std::max<int32_t>(1, strip_rows);
        std::vector<float> px(7 * static_cast<size_t>(im->width) * static_cast<size_t>(strip));
        Imf::OutputFile file(path, header, 1);
        for (int32_t y = 0; y < im->height; y += strip) {
          const int32_t n = std::min(strip, im->height - y);
          if (rows(rows_context, y, n, px.data()) != 0) throw std::runtime_error("the image's rows could not be read");
          file.setFrameBuffer(exr_frame(im, px.data(), y));
          file.writePixels(n);
        }
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

// An OpenEXR input stream over bytes in memory.
class MemoryInput : public Imf::IStream {
 public:
  MemoryInput(const unsigned char* data, size_t size) : Imf::IStream("memory"), data_(data), size_(size) {}
  bool read(char c[], int n) override {
    if (n < 0 || pos_ > size_ || static_cast<size_t>(n) > size_ - pos_) throw std::runtime_error("the EXR data ends early");
    std::memcpy(c, data_ + pos_, static_cast<size_t>(n));
    pos_ += static_cast<size_t>(n);
    return pos_ < size_;
  }
  uint64_t tellg() override { return pos_; }
  void seekg(uint64_t pos) override { pos_ = static_cast<size_t>(pos); }

 private:
  const unsigned char* data_;
  size_t size_;
  size_t pos_ = 0;
};

// OpenEXR (environment maps): R, G, B as 32-bit floats (half and uint channels converted
// by OpenEXR), 3 channels; a file without R, G and B gives its Y channel (or its first)
// as 1 channel. The data window is the image.
void decode_exr(const unsigned char* bytes, size_t size, uint64_t max_pixels, tally_image_receiver receive,
                void* receive_context) {
  MemoryInput stream(bytes, size);
  Imf::InputFile file(stream, 1);
  const Imath::Box2i dw = file.header().dataWindow();
  const int64_t w = static_cast<int64_t>(dw.max.x) - dw.min.x + 1, h = static_cast<int64_t>(dw.max.y) - dw.min.y + 1;
  if (w <= 0 || h <= 0) throw std::runtime_error("the image has no pixels or is not a 2-D image");
  if (static_cast<uint64_t>(w) * static_cast<uint64_t>(h) > max_pixels) {
    throw std::runtime_error("the image has " + std::to_string(w) + "x" + std::to_string(h) +
                             " pixels, more than the limit of " + std::to_string(max_pixels));
  }
  const Imf::ChannelList& ch = file.header().channels();
  const bool rgb = ch.findChannel("R") && ch.findChannel("G") && ch.findChannel("B");
  const char* grey = rgb ? nullptr : (ch.findChannel("Y") ? "Y" : (ch.begin() != ch.end() ? ch.begin().name() : nullptr));
  if (!rgb && grey == nullptr) throw std::runtime_error("the image has no channels");
  const size_t nc = rgb ? 3 : 1;
  const size_t n = static_cast<size_t>(w) * static_cast<size_t>(h);
  std::vector<float> px(nc * n, 0.0f);
  const size_t xs = nc * sizeof(float), ys = xs * static_cast<size_t>(w);
  const std::ptrdiff_t origin = static_cast<std::ptrdiff_t>(dw.min.x) * static_cast<std::ptrdiff_t>(xs) +
                                static_cast<std::ptrdiff_t>(dw.min.y) * static_cast<std::ptrdiff_t>(ys);
  static const char* const names[3] = {"R", "G", "B"};
  Imf::FrameBuffer fb;
  for (size_t c = 0; c < nc; ++c) {
    fb.insert(rgb ? names[c] : grey, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(px.data() + c) - origin, xs, ys));
  }
  file.setFrameBuffer(fb);
  file.readPixels(dw.min.y, dw.max.y);
  const tally_decoded_image out{static_cast<int32_t>(w), static_cast<int32_t>(h), static_cast<int32_t>(nc), 32, px.data()};
  receive(receive_context, &out);
}

// PNG (libpng's simplified API, 8 bits a channel; 16-bit files are reduced to 8 bits by
// libpng) and OpenEXR (decode_exr). Other formats need the OpenImageIO module.
int decode(const unsigned char* bytes, size_t size, const char* format, uint64_t max_pixels,
           tally_image_receiver receive, void* receive_context, tally_image_sink error, void* error_context) {
  return guarded(
      [&] {
        if (std::string(format) == "openexr") {
          decode_exr(bytes, size, max_pixels, receive, receive_context);
          return;
        }
        if (std::string(format) != "png") {
          throw std::runtime_error(std::string("this image module (OpenEXR + libpng) decodes PNG and OpenEXR only, not ") +
                                   format + "; build the OpenImageIO module (-DTALLY_IMAGE_BACKEND=oiio)");
        }
        png_image image{};
        image.version = PNG_IMAGE_VERSION;
        if (!png_image_begin_read_from_memory(&image, bytes, size)) {
          throw std::runtime_error(std::string("cannot decode the png image: ") + image.message);
        }
        const uint64_t pixels = static_cast<uint64_t>(image.width) * static_cast<uint64_t>(image.height);
        if (pixels == 0 || pixels > max_pixels) {
          png_image_free(&image);
          throw std::runtime_error("the image has " + std::to_string(image.width) + "x" + std::to_string(image.height) +
                                   " pixels, more than the limit of " + std::to_string(max_pixels));
        }
        // RGBA keeps colours as stored (8-bit output is never premultiplied); without an
        // alpha channel in the request libpng would composite onto black.
        const bool alpha = (image.format & PNG_FORMAT_FLAG_ALPHA) != 0;
        image.format = alpha ? PNG_FORMAT_RGBA : PNG_FORMAT_RGB;
        std::vector<unsigned char> px(PNG_IMAGE_SIZE(image));
        if (!png_image_finish_read(&image, nullptr, px.data(), 0, nullptr)) {
          const std::string m = image.message;
          png_image_free(&image);
          throw std::runtime_error("cannot decode the png image: " + m);
        }
        const tally_decoded_image out{static_cast<int32_t>(image.width), static_cast<int32_t>(image.height),
                                      alpha ? 4 : 3, 8, px.data()};
        receive(receive_context, &out);
      },
      error, error_context);
}

constexpr tally_image_api kApi{tally::kTallyImageAbiVersion, "OpenEXR " OPENEXR_VERSION_STRING " + libpng " PNG_LIBPNG_VER_STRING,
                               &encode_exr, &encode_png_rgb8, &decode, &write_exr_file};

}  // namespace

extern "C" __attribute__((visibility("default"))) const tally_image_api* tally_image_module_api(void) {
  return &kApi;
}
