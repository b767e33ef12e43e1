#include "common/image/image_header.hpp"

#include <fmt/format.h>

#include <cstdio>
#include <cstring>
#include <limits>
#include <stdexcept>

#include "common/image/image_decode.hpp"

namespace tally {

namespace {

[[noreturn]] void bad(const std::string& format, const std::string& what) {
  throw std::runtime_error(fmt::format("bad {} header: {}", format, what));
}

uint32_t be32(std::string_view b, size_t at) {
  return (uint32_t{static_cast<unsigned char>(b[at])} << 24) | (uint32_t{static_cast<unsigned char>(b[at + 1])} << 16) |
         (uint32_t{static_cast<unsigned char>(b[at + 2])} << 8) | uint32_t{static_cast<unsigned char>(b[at + 3])};
}
uint32_t be16(std::string_view b, size_t at) {
  return (uint32_t{static_cast<unsigned char>(b[at])} << 8) | uint32_t{static_cast<unsigned char>(b[at + 1])};
}
int32_t le32(std::string_view b, size_t at) {
  const uint32_t u = uint32_t{static_cast<unsigned char>(b[at])} | (uint32_t{static_cast<unsigned char>(b[at + 1])} << 8) |
                     (uint32_t{static_cast<unsigned char>(b[at + 2])} << 16) |
                     (uint32_t{static_cast<unsigned char>(b[at + 3])} << 24);
  int32_t s;
  std::memcpy(&s, &u, 4);
  return s;
}

ImageHeader png_header(std::string_view b) {
  // Signature (8), then the IHDR chunk: length 13, "IHDR", width, height, depth, colour type.
  if (b.size() < 8 + 8 + 13 || be32(b, 8) != 13 || b.substr(12, 4) != "IHDR") bad("png", "no IHDR chunk first");
  ImageHeader h;
  h.format = "png";
  h.width = be32(b, 16);
  h.height = be32(b, 20);
  const unsigned depth = static_cast<unsigned char>(b[24]), type = static_cast<unsigned char>(b[25]);
  switch (type) {
    case 0: h.channels = 1; break;
    case 2: h.channels = 3; break;
    case 3: h.channels = 4; break;  // palette: expanded to RGB, or RGBA with transparency
    case 4: h.channels = 2; break;
    case 6: h.channels = 4; break;
    default: bad("png", fmt::format("colour type {}", type));
  }
  h.sample_bytes = depth == 16 ? 2 : 1;
  return h;
}

ImageHeader jpeg_header(std::string_view b) {
  // Marker segments after SOI until a start-of-frame (SOF0..SOF15 but DHT, JPG and DAC).
  size_t at = 2;
  while (at + 4 <= b.size()) {
    if (static_cast<unsigned char>(b[at]) != 0xFF) bad("jpeg", fmt::format("no marker at byte {}", at));
    const unsigned m = static_cast<unsigned char>(b[at + 1]);
    if (m == 0xFF) {  // fill byte
      ++at;
      continue;
    }
    if (m == 0xD8 || (m >= 0xD0 && m <= 0xD7) || m == 0x01) {  // no length
      at += 2;
      continue;
    }
    if (m == 0xD9 || m == 0xDA) bad("jpeg", "no frame header before the image data");
    const size_t len = be16(b, at + 2);
    if (len < 2 || at + 2 + len > b.size()) bad("jpeg", fmt::format("segment at byte {} runs past the file", at));
    if (m >= 0xC0 && m <= 0xCF && m != 0xC4 && m != 0xC8 && m != 0xCC) {
      if (len < 8) bad("jpeg", "short frame header");
      ImageHeader h;
      h.format = "jpeg";
      h.sample_bytes = static_cast<unsigned char>(b[at + 4]) > 8 ? 2 : 1;
      h.height = be16(b, at + 5);
      h.width = be16(b, at + 7);
      h.channels = static_cast<unsigned char>(b[at + 9]);
      return h;
    }
    at += 2 + len;
  }
  bad("jpeg", "no frame header");
}

ImageHeader exr_header(std::string_view b) {
  // Magic (4), version and flags (4), then attributes: name\0 type\0 int32 size, value;
  // an empty name ends the header (https://openexr.com/en/latest/OpenEXRFileLayout.html).
  if (b.size() < 8) bad("openexr", "truncated");
  const uint32_t flags = static_cast<uint32_t>(le32(b, 4));
  if ((flags & 0xFF) != 2) bad("openexr", fmt::format("version {}", flags & 0xFF));
  if (flags & 0x1800) bad("openexr", "multi-part and deep files are not supported");
  size_t at = 8;
  auto cstring = [&](const char* what) {
    const size_t end = b.find('\0', at);
    if (end == std::string_view::npos || end - at > 255) bad("openexr", fmt::format("unterminated {} at byte {}", what, at));
    const std::string_view s = b.substr(at, end - at);
    at = end + 1;
    return s;
  };
  ImageHeader h;
  h.format = "openexr";
  bool have_window = false, have_channels = false;
  for (;;) {
    const std::string_view name = cstring("attribute name");
    if (name.empty()) break;
    const std::string_view type = cstring("attribute type");
    if (at + 4 > b.size()) bad("openexr", "truncated attribute");
    const int32_t size = le32(b, at);
    at += 4;
    if (size < 0 || static_cast<uint64_t>(size) > b.size() - at) {
      bad("openexr", fmt::format("attribute \"{}\" declares {} bytes, the file has {} left", name, size, b.size() - at));
    }
    const std::string_view value = b.substr(at, static_cast<size_t>(size));
    at += static_cast<size_t>(size);
    if (name == "dataWindow") {
      if (type != "box2i" || size != 16) bad("openexr", "dataWindow is not a box2i");
      const int64_t w = int64_t{le32(value, 8)} - le32(value, 0) + 1, ht = int64_t{le32(value, 12)} - le32(value, 4) + 1;
      if (w <= 0 || ht <= 0) bad("openexr", "empty data window");
      h.width = static_cast<uint64_t>(w);
      h.height = static_cast<uint64_t>(ht);
      have_window = true;
    } else if (name == "channels") {
      if (type != "chlist") bad("openexr", "channels is not a chlist");
      size_t c = 0;
      h.channels = 0;
      h.sample_bytes = 2;
      while (c < value.size() && value[c] != '\0') {
        const size_t end = value.find('\0', c);
        if (end == std::string_view::npos || end + 1 + 16 > value.size()) bad("openexr", "truncated channel list");
        const int32_t pixel_type = le32(value, end + 1);  // 0 uint, 1 half, 2 float
        if (pixel_type < 0 || pixel_type > 2) bad("openexr", fmt::format("channel pixel type {}", pixel_type));
        if (pixel_type != 1) h.sample_bytes = 4;
        ++h.channels;
        c = end + 1 + 16;
      }
      have_channels = true;
    }
  }
  if (!have_window || !have_channels) bad("openexr", "no dataWindow or no channels");
  if (h.channels == 0) bad("openexr", "no channels");
  return h;
}

ImageHeader hdr_header(std::string_view b) {
  // Text lines up to an empty one, then the resolution: "-Y <height> +X <width>" (or
  // another of the eight orientations).
  const size_t blank = b.find("\n\n");
  if (blank == std::string_view::npos) bad("hdr", "no end of the header");
  const size_t start = blank + 2, end = b.find('\n', start);
  if (end == std::string_view::npos || end - start > 64) bad("hdr", "no resolution line");
  const std::string line(b.substr(start, end - start));
  char s1 = 0, a1 = 0, s2 = 0, a2 = 0;
  unsigned long long n1 = 0, n2 = 0;
  if (std::sscanf(line.c_str(), "%c%c %llu %c%c %llu", &s1, &a1, &n1, &s2, &a2, &n2) != 6 ||
      (s1 != '-' && s1 != '+') || (s2 != '-' && s2 != '+') || !((a1 == 'Y' && a2 == 'X') || (a1 == 'X' && a2 == 'Y'))) {
    bad("hdr", "bad resolution line");
  }
  ImageHeader h;
  h.format = "hdr";
  h.height = a1 == 'Y' ? n1 : n2;
  h.width = a1 == 'Y' ? n2 : n1;
  h.channels = 3;
  h.sample_bytes = 4;
  return h;
}

uint64_t saturating_mul(uint64_t a, uint64_t b) {
  if (a != 0 && b > std::numeric_limits<uint64_t>::max() / a) return std::numeric_limits<uint64_t>::max();
  return a * b;
}

}  // namespace

uint64_t ImageHeader::decode_bytes() const {
  // The module decodes 8- and 16-bit files as such, everything else as 32-bit floats;
  // the copy handed back holds 16-bit codes or floats.
  const uint64_t module = sample_bytes <= 2 && format != "openexr" ? sample_bytes : 4;
  const uint64_t copy = module <= 2 ? 2 : 4;
  return saturating_mul(saturating_mul(width, height), saturating_mul(channels, module + copy));
}

ImageHeader read_image_header(std::string_view bytes) {
  const auto format = sniff_image_format(bytes);
  if (!format) throw std::runtime_error("not a PNG, JPEG, OpenEXR or Radiance HDR file");
  ImageHeader h = *format == "png"   ? png_header(bytes)
                  : *format == "jpeg" ? jpeg_header(bytes)
                  : *format == "hdr"  ? hdr_header(bytes)
                                      : exr_header(bytes);
  if (h.width == 0 || h.height == 0 || h.channels == 0) throw std::runtime_error("the image has no pixels");
  return h;
}

}  // namespace tally
