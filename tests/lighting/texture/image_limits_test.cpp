// Image files a scene names are bounded from their header before any pixel is decoded
// (issue 27 N3; common/image/image_header.hpp, JobLimits::max_image_channels and
// max_decode_bytes): the header reader against files written by OpenImageIO, a 64-channel
// EXR and an EXR attribute larger than its file refused, and the decode charge (closed
// form: pixels x (channels x (stored + decoded bytes) + 12)) summed per job.
#include <gtest/gtest.h>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <cstring>
#include <string>
#include <vector>

#include "common/image/image_decode.hpp"
#include "common/image/image_header.hpp"
#include "common/lighting/scene_json.hpp"
#include "common/lighting/texture.hpp"
#include "lighting/lighting_test_support.hpp"

namespace tally {
namespace {

namespace OIIO = OIIO_NAMESPACE;
using json = nlohmann::json;

// A file OpenImageIO writes by the name's extension, every pixel value `v`.
std::string encode(const std::string& name, int w, int h, int nc, OIIO::TypeDesc type,
                   const std::vector<std::pair<std::string, std::string>>& attrs = {}) {
  std::vector<unsigned char> buf;
  OIIO::Filesystem::IOVecOutput proxy(buf);
  auto out = OIIO::ImageOutput::create(name, &proxy);
  EXPECT_TRUE(out) << OIIO::geterror();
  OIIO::ImageSpec spec(w, h, nc, type);
  for (const auto& [k, v] : attrs) spec.attribute(k, v);
  EXPECT_TRUE(out->open(name, spec)) << out->geterror();
  std::vector<float> px(static_cast<size_t>(w) * static_cast<size_t>(h) * static_cast<size_t>(nc), 0.5f);
  EXPECT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data())) << out->geterror();
  out->close();
  return {buf.begin(), buf.end()};
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}
bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

TEST(ImageLimits, HeadersAreReadWithoutDecoding) {
  const ImageHeader png = read_image_header(encode("a.png", 5, 3, 4, OIIO::TypeDesc::UINT8));
  EXPECT_EQ(png.format, "png");
  EXPECT_EQ(png.width, 5u);
  EXPECT_EQ(png.height, 3u);
  EXPECT_EQ(png.channels, 4u);
  EXPECT_EQ(png.sample_bytes, 1u);
  EXPECT_EQ(png.decode_bytes(), 5u * 3u * 4u * (1u + 2u));  // 8-bit buffer + 16-bit codes
  const ImageHeader png16 = read_image_header(encode("a.png", 2, 2, 1, OIIO::TypeDesc::UINT16));
  EXPECT_EQ(png16.channels, 1u);
  EXPECT_EQ(png16.sample_bytes, 2u);
  const ImageHeader jpg = read_image_header(encode("a.jpg", 8, 6, 3, OIIO::TypeDesc::UINT8));
  EXPECT_EQ(jpg.format, "jpeg");
  EXPECT_EQ(jpg.width, 8u);
  EXPECT_EQ(jpg.height, 6u);
  EXPECT_EQ(jpg.channels, 3u);
  const ImageHeader exr = read_image_header(encode("a.exr", 4, 2, 3, OIIO::TypeDesc::HALF));
  EXPECT_EQ(exr.format, "openexr");
  EXPECT_EQ(exr.width, 4u);
  EXPECT_EQ(exr.height, 2u);
  EXPECT_EQ(exr.channels, 3u);
  EXPECT_EQ(exr.sample_bytes, 2u);
  EXPECT_EQ(exr.decode_bytes(), 4u * 2u * 3u * (4u + 4u));  // decoded as floats, copied as floats
  const ImageHeader hdr = read_image_header(encode("a.hdr", 7, 5, 3, OIIO::TypeDesc::FLOAT));
  EXPECT_EQ(hdr.format, "hdr");
  EXPECT_EQ(hdr.width, 7u);
  EXPECT_EQ(hdr.height, 5u);
  EXPECT_EQ(hdr.channels, 3u);
  // Truncated headers are refused, not read past their end.
  const std::string whole = encode("a.exr", 4, 2, 3, OIIO::TypeDesc::HALF);
  for (size_t n : {size_t{4}, size_t{9}, size_t{40}, size_t{100}}) {
    EXPECT_TRUE(contains(error_of([&] { read_image_header(whole.substr(0, n)); }), "bad openexr header")) << n;
  }
}

// N3: a 4096x2048 EXR of 64 half channels took 16.8 s and 4.3 GB to validate.
TEST(ImageLimits, ChannelsAreBoundedBeforeDecoding) {
  const std::string exr = encode("c.exr", 4, 4, 64, OIIO::TypeDesc::HALF);
  EXPECT_EQ(error_of([&] { decode_image(exr, ImageDecodeLimits{1000}); }),
            "the image has 64 channels, more than the limit of 8 (max_image_channels)");
  ImageDecodeLimits wide{1000};
  wide.max_channels = 64;
  EXPECT_EQ(error_of([&] { decode_image(exr, wide); }), "");
}

// N3: a 560-byte EXR whose string attribute declares 1.76 GB made OpenEXR allocate it.
TEST(ImageLimits, ExrAttributeLongerThanTheFileIsRefused) {
  std::string exr = encode("s.exr", 4, 4, 3, OIIO::TypeDesc::HALF, {{"comments", "x"}});
  const std::string key = std::string("comments\0string\0", 16);
  const size_t at = exr.find(key);
  ASSERT_NE(at, std::string::npos);
  const int32_t huge = 1'760'000'000;
  std::memcpy(exr.data() + at + key.size(), &huge, 4);
  const std::string left = std::to_string(exr.size() - (at + key.size() + 4));
  const std::string want = "bad openexr header: attribute \"comments\" declares 1760000000 bytes, the file has " + left + " left";
  EXPECT_EQ(error_of([&] { read_image_header(exr); }), want);
  EXPECT_EQ(error_of([&] { decode_image(exr, ImageDecodeLimits{1000}); }), want);
}

// N3: a 307 KB 9000^2 RGBA PNG under the texel cap peaked at 1.7 GB. Its header alone is
// enough to refuse it: 81e6 pixels x (4 x (1 + 2) + 12) = 1.944e9 bytes > 2^30.
TEST(ImageLimits, DecodeBytesAreChargedFromTheHeader) {
  std::string png = encode("p.png", 16, 16, 4, OIIO::TypeDesc::UINT8);
  const uint32_t side = __builtin_bswap32(9000);
  std::string big = png.substr(0, 33);  // signature + IHDR: no pixel data follows
  std::memcpy(big.data() + 16, &side, 4);
  std::memcpy(big.data() + 20, &side, 4);
  const Scene empty;
  const JobLimits defaults;
  EXPECT_EQ(error_of([&] { decode_texels(big, true, texture_decode_limits(empty, defaults)); }),
            "decoding the 9000x9000 image of 4 channels takes 1944000000 bytes, more than the 1073741824 left of the "
            "job's limit (max_decode_bytes)");
  // A real 16x16 RGBA PNG is charged 256 x 24 = 6144 bytes, at the limit and not over it.
  ImageDecodeLimits l{1 << 20};
  l.max_bytes = 6144;
  uint64_t charged = 0;
  const auto grid = decode_texels(png, true, l, &charged);
  EXPECT_EQ(charged, 6144u);
  EXPECT_EQ(grid->width, 16);
  l.max_bytes = 6143;
  EXPECT_TRUE(contains(error_of([&] { decode_texels(png, true, l); }), "takes 6144 bytes, more than the 6143 left"));
}

// The charge is per job: two .mtl textures of 6144 bytes each fit 12288 and not 12287,
// and the refusal names the texture that crossed the limit.
TEST(ImageLimits, DecodeBytesAddUpOverTheJob) {
  test::AssetSandbox d("tally_image_limits_job");
  d.write("assets/t.png", encode("t.png", 16, 16, 4, OIIO::TypeDesc::UINT8));
  d.write("assets/u.png", encode("u.png", 16, 16, 4, OIIO::TypeDesc::UINT8));
  d.write("assets/two.mtl", "newmtl a\nKd 1 1 1\nmap_Kd t.png\nnewmtl b\nKd 1 1 1\nmap_Kd u.png\n");
  d.write("assets/two.obj",
          "mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
          "usemtl a\nf 1/1 2/2 3/3\nusemtl b\nf 1/1 3/3 2/2\n");
  const json scene = {{"shapes", json::array({{{"type", "mesh"}, {"obj", "two.obj"}}})}};
  JobLimits l = d.limits();
  l.max_decode_bytes = 12288;
  const Scene s = test::parse_scene_json(scene, l);
  EXPECT_EQ(s.decode_bytes, 12288u);
  l.max_decode_bytes = 12287;
  const std::string err = test::scene_error(scene, l);
  EXPECT_TRUE(contains(err, "map_Kd \"u.png\"")) << err;
  EXPECT_TRUE(contains(err, "takes 6144 bytes, more than the 6143 left of the job's limit (max_decode_bytes)")) << err;
}

}  // namespace
}  // namespace tally
