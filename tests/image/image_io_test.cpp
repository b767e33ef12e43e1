#include "common/image/image_io.hpp"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include "support/requested_image_module.hpp"

namespace tally {
namespace {

constexpr size_t kReferenceExrSize = 1022;
constexpr uint64_t kReferenceExrHash = 17768501710167138508ULL;  // capDate zeroed
constexpr size_t kReferencePngSize = 146;
constexpr uint64_t kReferencePngHash = 3936969893568565922ULL;

ImageSnapshot make_snapshot(int w, int h) {
  ImageSnapshot s;
  s.width = w;
  s.height = h;
  s.full_width = w;
  s.full_height = h;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        s.rgb.push_back(0.25f * static_cast<float>(c + 1) + 0.01f * static_cast<float>(x + w * y));
        s.stderr_rgb.push_back(1e-4f * static_cast<float>(x + 1 + c));
      }
      s.samples.push_back(static_cast<float>(16 + x + y));
    }
  }
  return s;
}

TEST(ImageIo, ExrRoundTripByChannelName) {
  const ImageSnapshot s = make_snapshot(7, 5);
  const std::string bytes = encode_exr(s, {{"spp", 16}, {"estimator", "mis"}, {"seed", 42}});
  ASSERT_GT(bytes.size(), 100u);
  std::vector<unsigned char> buf(bytes.begin(), bytes.end());
  OIIO::Filesystem::IOMemReader reader(buf.data(), buf.size());
  auto in = OIIO::ImageInput::open("image.exr", nullptr, &reader);
  ASSERT_TRUE(in) << OIIO::geterror();
  const OIIO::ImageSpec& spec = in->spec();
  ASSERT_EQ(spec.width, 7);
  ASSERT_EQ(spec.height, 5);
  ASSERT_EQ(spec.nchannels, 7);
  std::vector<float> data(static_cast<size_t>(7 * 5 * spec.nchannels));
  ASSERT_TRUE(in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, data.data()));
  auto channel = [&](const std::string& name) {
    const int c = spec.channelindex(name);
    EXPECT_GE(c, 0) << name;
    return c;
  };
  const int r = channel("R"), g = channel("G"), b = channel("B");
  const int er = channel("StdErr.R"), eb = channel("StdErr.B"), n = channel("SampleCount");
  for (size_t i = 0; i < 35; ++i) {
    const float* px = &data[i * static_cast<size_t>(spec.nchannels)];
    EXPECT_EQ(px[r], s.rgb[3 * i]);
    EXPECT_EQ(px[g], s.rgb[3 * i + 1]);
    EXPECT_EQ(px[b], s.rgb[3 * i + 2]);
    EXPECT_EQ(px[er], s.stderr_rgb[3 * i]);
    EXPECT_EQ(px[eb], s.stderr_rgb[3 * i + 2]);
    EXPECT_EQ(px[n], s.samples[i]);
  }
  EXPECT_EQ(spec.get_string_attribute("tally:estimator"), "mis");
  EXPECT_DOUBLE_EQ(spec.get_float_attribute("tally:spp"), 16.0f);
}

TEST(ImageIo, PngIsToneMapped) {
  ImageSnapshot s = make_snapshot(4, 3);
  s.rgb[0] = 2.0f;   // clamps to 255
  s.rgb[1] = -1.0f;  // clamps to 0
  const std::string bytes = encode_png(s);
  std::vector<unsigned char> buf(bytes.begin(), bytes.end());
  OIIO::Filesystem::IOMemReader reader(buf.data(), buf.size());
  auto in = OIIO::ImageInput::open("image.png", nullptr, &reader);
  ASSERT_TRUE(in) << OIIO::geterror();
  std::vector<unsigned char> px(4 * 3 * 3);
  ASSERT_TRUE(in->read_image(0, 0, 0, 3, OIIO::TypeDesc::UINT8, px.data()));
  EXPECT_EQ(px[0], 255);
  EXPECT_EQ(px[1], 0);
  EXPECT_EQ(px[2], static_cast<unsigned char>(std::lround(255 * srgb_oetf(s.rgb[2]))));
  EXPECT_NEAR(srgb_oetf(0.5), 0.7353569830524495, 1e-12);
}

TEST(ImageIo, WriteFiles) {
  const auto dir = std::filesystem::temp_directory_path() / "tally_image_io_test";
  std::filesystem::create_directories(dir);
  const ImageSnapshot s = make_snapshot(3, 2);
  write_image_files(s, {{"spp", 1}}, dir / "a.exr", dir / "a.png");
  EXPECT_GT(std::filesystem::file_size(dir / "a.exr"), 0u);
  EXPECT_GT(std::filesystem::file_size(dir / "a.png"), 0u);
  std::filesystem::remove_all(dir);
}

// OpenImageIO stamps EXR files with the time they were written ("capDate", local time
// "YYYY:MM:DD HH:MM:SS"): zero it so equal images hash equal.
std::string without_cap_date(std::string exr) {
  const std::string key("capDate\0string\0", 15);
  const size_t at = exr.find(key);
  if (at != std::string::npos && at + key.size() + 4 + 19 <= exr.size()) {
    exr.replace(at + key.size() + 4, 19, std::string(19, '0'));
  }
  return exr;
}

uint64_t fnv1a(const std::string& bytes) {
  uint64_t h = 14695981039346656037ULL;
  for (const unsigned char c : bytes) h = (h ^ c) * 1099511628211ULL;
  return h;
}

// Same formats after OpenImageIO moved into the dlopen'ed image module: the bytes equal
// those of the statically linked encoder of main a314575 (OpenImageIO 2.4, Debian 12),
// with either module (ctest runs this file once per backend: image.*_module).
TEST(ImageIo, BytesUnchangedByTheImageModule) {
  const ImageSnapshot s = make_snapshot(7, 5);
  const std::string exr = encode_exr(s, {{"spp", 16}, {"estimator", "mis"}, {"seed", 42}});
  const std::string png = encode_png(s);
  SCOPED_TRACE("image module: " + image_module_backend() + " at " + image_module_path());
  EXPECT_EQ(exr.size(), kReferenceExrSize);
  EXPECT_EQ(fnv1a(without_cap_date(exr)), kReferenceExrHash);
  EXPECT_EQ(png.size(), kReferencePngSize);
  EXPECT_EQ(fnv1a(png), kReferencePngHash);
}

TEST(ImageIo, RejectsInconsistentSnapshot) {
  ImageSnapshot s = make_snapshot(3, 2);
  s.samples.pop_back();
  EXPECT_THROW(encode_exr(s, {}), std::runtime_error);
}

// image.<backend>_module: the module ctest asked for is the one loaded.
TEST(ImageModule, IsTheOneRequested) { test::expect_the_requested_image_module(); }

}  // namespace
}  // namespace tally
