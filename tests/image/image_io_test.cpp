#include "common/image/image_io.hpp"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <unistd.h>

#include "common/engine/job_state.hpp"
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

// An image served from a whole snapshot, a rectangle at a time (as ImageKernel serves
// a job's state); `fail_at_row` >= 0: a request for a strip holding it throws.
class SnapshotSource final : public ImageSource {
 public:
  SnapshotSource(ImageSnapshot whole, int fail_at_row = -1) : whole_(std::move(whole)), fail_(fail_at_row) {}
  int width() const override { return whole_.width; }
  int height() const override { return whole_.height; }
  uint32_t tile_count() const override { return 1; }
  TileRect tile_rect(uint32_t) const override { return {0, 0, whole_.width, whole_.height}; }
  ImageSnapshot snapshot(const JobState&, const TileRect& r) const override {
    if (fail_ >= r.y && fail_ < r.y + r.h) throw std::runtime_error("row " + std::to_string(fail_) + " is unreadable");
    ImageSnapshot s;
    s.x0 = r.x, s.y0 = r.y, s.width = r.w, s.height = r.h;
    s.full_width = whole_.width, s.full_height = whole_.height;
    for (int y = r.y; y < r.y + r.h; ++y) {
      for (int x = r.x; x < r.x + r.w; ++x) {
        const size_t i = static_cast<size_t>(y) * static_cast<size_t>(whole_.width) + static_cast<size_t>(x);
        for (size_t c = 0; c < 3; ++c) {
          s.rgb.push_back(whole_.rgb[3 * i + c]);
          s.stderr_rgb.push_back(whole_.stderr_rgb[3 * i + c]);
        }
        s.samples.push_back(whole_.samples[i]);
      }
    }
    return s;
  }

 private:
  ImageSnapshot whole_;
  int fail_;
};

std::string read_bytes(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// write_exr_file streams strips of rows (3 here, the last one short) to the file: the
// bytes are encode_exr's of the whole snapshot (its capDate aside), with either module.
TEST(ImageIo, ExrFileWrittenByStripsIsEncodeExrsBytes) {
  const auto dir = std::filesystem::temp_directory_path() / ("tally_exr_strips_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const ImageSnapshot whole = make_snapshot(37, 20);
  const nlohmann::json meta = {{"samples", 16}, {"estimator", "mis"}};
  const SnapshotSource source(whole);
  write_exr_file(source, JobState{}, meta, dir / "a.exr", 3);
  EXPECT_FALSE(std::filesystem::exists(dir / "a.exr.part"));
  EXPECT_EQ(without_cap_date(read_bytes(dir / "a.exr")), without_cap_date(encode_exr(whole, meta)));
  // A strip that cannot be read: an error naming it, and no file, not a partial one.
  const SnapshotSource broken(whole, 10);
  try {
    write_exr_file(broken, JobState{}, meta, dir / "b.exr", 3);
    ADD_FAILURE() << "a failing strip was written";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("row 10 is unreadable"), std::string::npos) << e.what();
    EXPECT_EQ(std::string(e.what()).rfind("cannot write " + (dir / "b.exr").string() + ": ", 0), 0u) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "b.exr"));
  EXPECT_FALSE(std::filesystem::exists(dir / "b.exr.part"));
  // A path that cannot be written (its folder is missing): named as asked, not as .part.
  try {
    write_exr_file(source, JobState{}, meta, dir / "missing" / "c.exr", 3);
    ADD_FAILURE() << "a file was written into a missing folder";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()).rfind("cannot write " + (dir / "missing" / "c.exr").string() + ": ", 0), 0u)
        << e.what();
  }
  std::filesystem::remove_all(dir);
}

// image.<backend>_module: the module ctest asked for is the one loaded.
TEST(ImageModule, IsTheOneRequested) { test::expect_the_requested_image_module(); }

}  // namespace
}  // namespace tally
