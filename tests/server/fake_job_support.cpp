#include "fake_job.hpp"

#include <fmt/format.h>

#include <chrono>
#include <cmath>

#include "common/spec/spec_reader.hpp"
#include "common/spec/stop_rule_json.hpp"

namespace tally::test {

namespace {

uint64_t mix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

constexpr int kTile = 4, kTilesX = 2, kTilesY = 2;
constexpr int kPixelsPerTile = kTile * kTile;

class FakeKernel final : public Kernel {
 public:
  FakeKernel(uint64_t seed, uint64_t work, bool image, bool gated)
      : seed_(seed), work_(work), image_(image), gated_(gated) {}
  bool folds_passes() const override { return gated_; }
  void fold_pass(std::string_view, const std::vector<BlockResult>&, JobState&) const override {
    if (gated_) fold_gate().pass();
  }
  size_t channel_count() const override { return image_ ? kTilesX * kTilesY * kPixelsPerTile : 1; }
  uint32_t partition_count() const override { return image_ ? kTilesX * kTilesY : 1; }
  PassSchedule schedule() const override {
    PassSchedule s;
    s.first_pass_samples = 4096;
    s.max_pass_samples = 1 << 16;
    s.block_samples = 1024;
    return s;
  }
  std::span<const std::string_view> counter_names() const override {
    static constexpr std::string_view kNames[] = {"evaluations"};
    return kNames;
  }
  void run_block(const Block& b, BlockResult& out) const override {
    const size_t channels = image_ ? kPixelsPerTile : 1;
    out.first_channel = image_ ? b.partition * kPixelsPerTile : 0;
    out.tallies.assign(channels, Tally{});
    for (uint64_t i = 0; i < b.sample_count; ++i) {
      const uint64_t idx = b.first_sample + i;
      uint64_t h = mix(seed_ ^ mix(idx ^ (static_cast<uint64_t>(b.partition) << 48)));
      for (uint64_t k = 0; k < work_; ++k) h = mix(h);  // burn time deterministically
      const double u = static_cast<double>(h >> 11) * 0x1.0p-53;
      out.tallies[idx % channels].add(u);
    }
    out.counters.add(0, b.sample_count);  // "evaluations"
  }

 private:
  uint64_t seed_, work_;
  bool image_, gated_;
};

class FakeImage final : public ImageSource {
 public:
  int width() const override { return kTile * kTilesX; }
  int height() const override { return kTile * kTilesY; }
  uint32_t tile_count() const override { return kTilesX * kTilesY; }
  TileRect tile_rect(uint32_t t) const override {
    return TileRect{static_cast<int>(t % kTilesX) * kTile, static_cast<int>(t / kTilesX) * kTile, kTile, kTile};
  }
  ImageSnapshot snapshot(const JobState& state, const TileRect& r) const override {
    ImageSnapshot s;
    s.x0 = r.x;
    s.y0 = r.y;
    s.width = r.w;
    s.height = r.h;
    s.full_width = width();
    s.full_height = height();
    for (int y = r.y; y < r.y + r.h; ++y) {
      for (int x = r.x; x < r.x + r.w; ++x) {
        const int tile = (y / kTile) * kTilesX + x / kTile;
        const int local = (y % kTile) * kTile + x % kTile;
        const Tally& t = state.channels.at(static_cast<size_t>(tile * kPixelsPerTile + local));
        for (int c = 0; c < 3; ++c) {
          s.rgb.push_back(static_cast<float>(t.mean));
          s.stderr_rgb.push_back(static_cast<float>(t.n > 1 ? t.std_error() : 0.0));
        }
        s.samples.push_back(static_cast<float>(t.n));
      }
    }
    return s;
  }
};

class FakeJob final : public JobDefinition {
 public:
  FakeJob(uint64_t seed, uint64_t work, bool image, bool gated, StopRule rule)
      : seed_(seed), rule_(rule), kernel_(std::make_shared<FakeKernel>(seed, work, image, gated)) {
    if (image) image_ = std::make_unique<FakeImage>();
  }
  std::string_view kind() const override { return "fake"; }
  std::shared_ptr<const Kernel> kernel() const override { return kernel_; }
  StopRule stop_rule() const override { return rule_; }
  uint64_t seed() const override { return seed_; }
  const ImageSource* image() const override { return image_.get(); }

 private:
  uint64_t seed_;
  StopRule rule_;
  std::shared_ptr<const Kernel> kernel_;
  std::unique_ptr<FakeImage> image_;
};

}  // namespace

std::unique_ptr<JobDefinition> compile_fake_job(const nlohmann::json& spec, const JobLimits& limits) {
  SpecReader r(spec, "");
  const std::string kind = r.enumeration("kind", {"fake"});
  const uint64_t seed = r.integer_or("seed", 1, 0, UINT64_MAX);
  const uint64_t work = r.integer_or("work", 0, 0, 1'000'000);
  const bool image = r.boolean_or("image", false);
  const bool gated = r.boolean_or("fold_gate", false);
  SpecReader stop = r.object("stop");
  const StopRule rule = parse_stop_rule(stop, limits);
  r.finish();
  return std::make_unique<FakeJob>(seed, work, image, gated, rule);
}

void FoldGate::arm() {
  std::lock_guard lock(mu_);
  armed_ = true;
  entered_ = false;
}

bool FoldGate::wait_entered(double seconds) {
  std::unique_lock lock(mu_);
  return cv_.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return entered_; });
}

void FoldGate::release() {
  std::lock_guard lock(mu_);
  armed_ = false;
  cv_.notify_all();
}

void FoldGate::pass() {
  std::unique_lock lock(mu_);
  if (!armed_) return;
  entered_ = true;
  cv_.notify_all();
  cv_.wait_for(lock, std::chrono::seconds(60), [&] { return !armed_; });
}

FoldGate& fold_gate() {
  static FoldGate gate;
  return gate;
}

nlohmann::json fake_spec(uint64_t max_samples, uint64_t work, uint64_t seed, bool image) {
  nlohmann::json j = {{"kind", "fake"}, {"seed", seed}, {"stop", {{"max_samples", max_samples}}}};
  if (work > 0) j["work"] = work;
  if (image) j["image"] = true;
  return j;
}

}  // namespace tally::test
