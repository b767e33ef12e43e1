#include "common/engine/checkpoint.hpp"

#include <algorithm>
#include <bit>
#include <cstring>
#include <fmt/format.h>
#include <iterator>

#include "common/engine/byte_codec.hpp"
#include "common/engine/check.hpp"
#include "common/hash/fnv1a.hpp"

namespace tally {

namespace {

constexpr char kMagic[8] = {'T', 'A', 'L', 'L', 'Y', 'C', 'K', '1'};
// Version 2 adds JobState::kernel_state; version 1 checkpoints still read (empty).
// Version 3 stores the counters with their names (kernels declare their own); versions
// 1 and 2 stored a fixed list of counters, named below.
// Version 4 adds JobState::results_version; earlier versions read as 0 (unknown).
// Version 5 adds JobState::sums (after the channels); earlier versions read none.
// Version 6 stores the sums as 4-byte floats (JobState::sums); version 5's doubles read
// rounded to float.
constexpr uint32_t kVersion = kCheckpointVersion;

// The counters of versions 1 and 2, in their order (the engine's enum of that time).
constexpr std::string_view kLegacyCounterNames[] = {
    "evaluations",   "nonfinite",        "rejection_attempts", "rejection_accepts", "rejection_failures",
    "camera_rays",   "shadow_rays",      "bounce_rays",        "sky_lookups",       "emission_lookups",
    "light_samples", "bsdf_samples",     "specular_events",    "roulette_terminations"};


using Reader = ByteReader<CheckpointError>;

}  // namespace

uint64_t checkpoint_checksum(std::string_view body) { return fnv1a64(body); }

namespace {

// A ByteWriter whose output goes to a sink in pieces of `piece` bytes as it grows,
// hashed on the way (the checksum that ends a checkpoint covers every byte before it).
class PieceWriter {
 public:
  // `expected`: about the bytes the whole checkpoint takes (no more is reserved).
  PieceWriter(const CheckpointSink& sink, size_t piece, uint64_t expected)
      : sink_(sink), piece_(std::max<size_t>(piece, 1)) {
    w_.reserve(static_cast<size_t>(std::min<uint64_t>({piece_, uint64_t{1} << 26, expected})) + 4096);
  }
  ByteWriter& w() { return w_; }
  // Hands on the whole pieces written so far; call after each item.
  void pass_on() {
    if (w_.str().size() >= piece_) emit(false);
  }
  // The rest, the checksum after it; returns the bytes written in all.
  uint64_t finish() {
    emit(false);
    w_.u64(fnv1a64_update(hash_, w_.str()));  // the checksum of every byte before it
    emit(true);
    return total_;
  }

 private:
  void emit(bool all) {
    const std::string_view b = w_.str();
    size_t at = 0;
    while (b.size() - at >= piece_ || (all && at < b.size())) {
      const std::string_view p = b.substr(at, std::min(piece_, b.size() - at));
      hash_ = fnv1a64_update(hash_, p);
      sink_(p);
      at += p.size();
    }
    total_ += at;
    w_.drop_front(at);
  }

  const CheckpointSink& sink_;
  const size_t piece_;
  ByteWriter w_;
  uint64_t hash_ = kFnv1a64Basis;
  uint64_t total_ = 0;
};

}  // namespace

uint64_t write_checkpoint(const JobState& s, const CheckpointSink& sink, size_t piece_bytes) {
  PieceWriter out(sink, piece_bytes, checkpoint_size_hint(s));
  ByteWriter& w = out.w();
  w.raw(std::string_view(kMagic, sizeof kMagic));
  w.u64(kVersion);
  w.u64(s.passes);
  w.u64(s.samples);
  w.u64(s.partition_samples.size());
  for (uint64_t v : s.partition_samples) {
    w.u64(v);
    out.pass_on();
  }
  w.u64(s.channels.size());
  for (const Tally& t : s.channels) {
    w.tally(t);
    out.pass_on();
  }
  w.u64(s.sums.size());
  for (float v : s.sums) {
    w.f32(v);
    out.pass_on();
  }
  TALLY_CHECK_LE(s.counters.values.size(), s.counter_names.size());  // every counter has a name
  w.u64(s.counter_names.size());
  for (size_t i = 0; i < s.counter_names.size(); ++i) {
    w.bytes(s.counter_names[i]);
    w.u64(s.counters[i]);
  }
  w.tail(s.tail);
  w.weights(s.weights);
  w.u64(s.fault ? 1 : 0);
  if (s.fault) w.fault(*s.fault);
  w.f64(s.compute_seconds);
  w.u64(s.trace.size());
  for (const TracePoint& p : s.trace) {
    w.f64(p.time_s);
    w.u64(p.samples);
    w.f64(p.mean);
    w.f64(p.std_error);
  }
  out.pass_on();
  w.bytes(s.kernel_state);
  w.u64(s.results_version);
  return out.finish();
}

uint64_t checkpoint_size_hint(const JobState& s) {
  uint64_t names = 0;
  for (const std::string& n : s.counter_names) names += 16 + n.size();
  return 72 + 8 * s.partition_samples.size() + 24 * s.channels.size() + 4 * s.sums.size() + 32 * s.trace.size() +
         8 * s.tail.heap().size() + s.kernel_state.size() + names + 1024;
}

std::string encode_checkpoint(const JobState& s) {
  std::string out;
  out.reserve(checkpoint_size_hint(s));
  write_checkpoint(s, [&](std::string_view piece) { out.append(piece); });
  return out;
}

JobState decode_checkpoint(std::string_view bytes) {
  if (bytes.size() < sizeof kMagic + 16 || std::memcmp(bytes.data(), kMagic, sizeof kMagic) != 0) {
    throw CheckpointError("not a tally checkpoint (bad magic or too short)");
  }
  const std::string_view body = bytes.substr(0, bytes.size() - 8);
  Reader tail_reader(bytes.substr(bytes.size() - 8), "checkpoint");
  if (tail_reader.u64() != fnv1a64(body)) {
    throw CheckpointError("checkpoint checksum mismatch (truncated or corrupt)");
  }
  Reader r(body.substr(sizeof kMagic), "checkpoint");
  const uint64_t version = r.u64();
  if (version < 1 || version > kVersion) {
    throw CheckpointError(fmt::format("unsupported checkpoint version {}", version));
  }
  JobState s;
  s.passes = r.u64();
  s.samples = r.u64();
  s.partition_samples.resize(r.count(8));
  for (auto& v : s.partition_samples) v = r.u64();
  s.channels.resize(r.count(24));
  for (Tally& t : s.channels) t = r.tally();
  if (version >= 6) {
    s.sums.resize(r.count(4));
    for (float& v : s.sums) v = r.f32();
  } else if (version == 5) {
    s.sums.resize(r.count(8));
    for (float& v : s.sums) v = static_cast<float>(r.f64());
  }
  if (version >= 3) {
    const uint64_t nc = r.count(16);  // a name's length and a value
    if (nc > Counters::kMaxCounters) throw CheckpointError(fmt::format("checkpoint has {} counters", nc));
    for (uint64_t i = 0; i < nc; ++i) {
      s.counter_names.push_back(r.bytes());
      s.counters.values.push_back(r.u64());
    }
  } else {
    const uint64_t nc = r.count(8);
    if (nc != std::size(kLegacyCounterNames)) throw CheckpointError("checkpoint counter layout differs");
    for (std::string_view name : kLegacyCounterNames) {
      s.counter_names.emplace_back(name);
      s.counters.values.push_back(r.u64());
    }
  }
  s.tail = r.tail();
  s.weights = r.weights();
  const uint64_t has_fault = r.u64();
  if (has_fault > 1) throw CheckpointError(fmt::format("checkpoint fault flag is {}, not 0 or 1", has_fault));
  if (has_fault == 1) s.fault = r.fault();
  s.compute_seconds = r.f64();
  s.trace.resize(r.count(32));
  for (TracePoint& p : s.trace) {
    p.time_s = r.f64();
    p.samples = r.u64();
    p.mean = r.f64();
    p.std_error = r.f64();
  }
  if (version >= 2) s.kernel_state = r.bytes();
  s.results_version = 0;
  if (version >= 4) {
    const uint64_t v = r.u64();
    // A newer build's version is kept as it is (a downgraded server reads its jobs and
    // only their cache use differs); one beyond 32 bits is corruption.
    if (v > UINT32_MAX) throw CheckpointError(fmt::format("checkpoint results version {} is out of range", v));
    s.results_version = static_cast<uint32_t>(v);
  }
  if (!r.done()) {
    throw CheckpointError(fmt::format("checkpoint has {} bytes after its last field", body.size() - sizeof kMagic - r.pos()));
  }
  return s;
}

}  // namespace tally
