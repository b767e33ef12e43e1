#include "client/preview_command.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "client/exit_codes.hpp"
#include "client/api_request.hpp"
#include "client/http_client.hpp"
#include "client/sse_parser.hpp"
#include "client/tev_bridge.hpp"

namespace tally {

using nlohmann::json;

namespace {

using Clock = std::chrono::steady_clock;

struct PreviewFailure {
  int code;
};

[[noreturn]] void fail(int code, const std::string& msg) {
  fmt::print(stderr, "tally preview: {}\n", msg);
  throw PreviewFailure{code};
}

json get_json(HttpClient& c, const std::string& target) {
  return tally::get_json(c, target, [&](const ClientResponse& r) {
    if (r.status == 404) fail(exit_code::usage, fmt::format("{}: not found", target));
    fail(exit_code::connection, fmt::format("GET {} answered {}: {}", target, r.status, r.body));
  });
}

// "host:port", "[v6]:port".
bool split_host_port(const std::string& s, std::string& host, std::string& port) {
  const size_t colon = s.rfind(':');
  if (colon == std::string::npos || colon + 1 >= s.size()) return false;
  host = s.substr(0, colon);
  port = s.substr(colon + 1);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
  return !host.empty() && std::all_of(port.begin(), port.end(), [](char c) { return c >= '0' && c <= '9'; });
}

TilePixels parse_tile(const json& t) {
  TilePixels p;
  p.tile = t.at("tile").get<uint32_t>();
  p.x = t.at("x").get<int>();
  p.y = t.at("y").get<int>();
  p.w = t.at("w").get<int>();
  p.h = t.at("h").get<int>();
  p.pass = t.value("pass", uint64_t{0});
  // null (a non-finite value in JSON) becomes NaN, as tev shows it.
  auto floats = [](const json& a) {
    std::vector<float> v;
    v.reserve(a.size());
    for (const json& x : a) v.push_back(x.is_number() ? x.get<float>() : std::nanf(""));
    return v;
  };
  p.mean = floats(t.at("mean"));
  p.std_error = floats(t.at("std_error"));
  p.samples = floats(t.at("samples"));
  return p;
}

class Previewer {
 public:
  Previewer(const PreviewOptions& o, HttpClient& client, TevBridge& bridge)
      : o_(o), client_(client), bridge_(bridge), base_("/v1/jobs/" + o.job_id) {}

  void start(const json& status) {
    int w = 0, h = 0;
    const json* img = nullptr;
    if (status.contains("result") && status["result"].is_object() && status["result"].contains("image")) {
      img = &status["result"]["image"];
      w = img->value("width", 0);
      h = img->value("height", 0);
      tile_count_ = img->value("tiles", 0u);
    }
    if ((w <= 0 || h <= 0) && status.contains("spec")) {
      const json& spec = status["spec"];
      if (spec.contains("query") && spec["query"].value("type", "") == "image" && spec.contains("scene") &&
          spec["scene"].contains("camera")) {
        const json& res = spec["scene"]["camera"]["resolution"];
        w = res.at(0).get<int>();
        h = res.at(1).get<int>();
        const int ts = spec["query"].value("tile_size", 32);
        tile_count_ = static_cast<uint32_t>(((w + ts - 1) / ts) * ((h + ts - 1) / ts));
      }
    }
    if (w <= 0 || h <= 0) fail(exit_code::usage, fmt::format("job {} has no image to preview", o_.job_id));
    bridge_.begin(w, h);
    // What the job already has: every tile once.
    const uint64_t passes = status.value("passes", uint64_t{0});
    if (passes > 0) {
      for (uint32_t t = 0; t < tile_count_; ++t) dirty_[t] = passes;
    }
    if (!o_.quiet) fmt::print(stderr, "tally preview: mirroring job {} ({}x{}) into tev at {}\n", o_.job_id, w, h, o_.tev);
  }

  void on_event(const SseEvent& e) {
    if (e.event == "tile") {
      const json d = json::parse(e.data);
      mark(d.at("tile").get<uint32_t>(), d.value("pass", uint64_t{0}));
    } else if (e.event == "tiles") {
      // A pass that refined more tiles than the server announces one by one (a 4K
      // frame's 8,160): every tile from `first` to `last` is marked, a superset of them.
      const json d = json::parse(e.data);
      const uint32_t first = d.at("first").get<uint32_t>();
      const uint32_t last = std::min(d.at("last").get<uint32_t>(), tile_count_ ? tile_count_ - 1 : 0u);
      const uint64_t pass = d.value("pass", uint64_t{0});
      for (uint32_t t = first; t <= last; ++t) mark(t, pass);
    } else if (e.event == "progress") {
      const json d = json::parse(e.data);
      pass_ = d.value("pass", d.value("passes", pass_));
    } else if (e.event == "end") {
      ended_ = true;
    }
  }

  // Fetch period: 250 ms at first, growing like √time as the image converges (2 s at most).
  double interval() const {
    if (!first_tile_) return o_.min_interval_s;
    const double t = std::chrono::duration<double>(Clock::now() - *first_tile_).count();
    return std::clamp(o_.min_interval_s * std::sqrt(t / 4.0), o_.min_interval_s, 2.0);
  }

  void maybe_flush(bool force) {
    if (dirty_.empty()) return;
    if (!force && std::chrono::duration<double>(Clock::now() - last_flush_).count() < interval()) return;
    last_flush_ = Clock::now();
    // At most kMaxTilesPerFlush tiles a flush (all of them when forced, at the end),
    // taken round-robin from where the last flush stopped: a 4K frame's 8,160 tiles are
    // mirrored over several flushes and the bridge keeps up with the event stream.
    std::map<uint32_t, uint64_t> batch;
    if (force || dirty_.size() <= kMaxTilesPerFlush) {
      batch.swap(dirty_);
    } else {
      auto it = dirty_.lower_bound(next_tile_);
      while (batch.size() < kMaxTilesPerFlush) {
        if (it == dirty_.end()) it = dirty_.begin();
        next_tile_ = it->first + 1;
        batch.insert(*it);
        it = dirty_.erase(it);
      }
    }
    for (const auto& [t, pass] : batch) {
      const ClientResponse r = client_.request("GET", base_ + "/tiles/" + std::to_string(t));
      if (r.status != 200) {
        dirty_.emplace(t, pass);  // try again at the next flush
        continue;
      }
      bridge_.update_tile(parse_tile(json::parse(r.body)));
      ++tiles_sent_;
    }
    std::vector<uint32_t> refining;
    if (!ended_) {
      for (const auto& [t, p] : last_refined_) {
        if (p >= pass_) refining.push_back(t);
      }
    }
    bridge_.set_refining(refining);
  }

  // Tile t changed in `pass`: fetched at the next flush.
  void mark(uint32_t t, uint64_t pass) {
    dirty_[t] = pass;
    last_refined_[t] = pass;
    if (!first_tile_) first_tile_ = Clock::now();
  }

  bool ended() const { return ended_; }
  uint64_t tiles_sent() const { return tiles_sent_; }

 private:
  const PreviewOptions& o_;
  HttpClient& client_;
  TevBridge& bridge_;
  std::string base_;
  static constexpr size_t kMaxTilesPerFlush = 256;
  uint32_t tile_count_ = 0;
  uint32_t next_tile_ = 0;                     // where the next capped flush starts
  std::map<uint32_t, uint64_t> dirty_;         // tile -> newest announced pass
  std::map<uint32_t, uint64_t> last_refined_;  // tile -> last pass that refined it
  uint64_t pass_ = 0;
  bool ended_ = false;
  std::optional<Clock::time_point> first_tile_;
  Clock::time_point last_flush_{};
  uint64_t tiles_sent_ = 0;
};

}  // namespace

int run_preview(const PreviewOptions& o) {
  try {
    const auto url = parse_http_url(o.server);
    if (!url) fail(exit_code::usage, fmt::format("--server must be an http:// or https:// URL, got \"{}\"", o.server));
    TevBridgeOptions to;
    if (!split_host_port(o.tev, to.host, to.port)) {
      fail(exit_code::usage, fmt::format("--tev must be HOST:PORT, got \"{}\"", o.tev));
    }
    to.image_name = o.image_name.empty() ? "tally-" + o.job_id : o.image_name;
    to.max_retries = o.tev_retries;
    HttpClient client(*url, 30.0, o.security);
    TevBridge bridge(to);
    Previewer p(o, client, bridge);
    p.start(get_json(client, "/v1/jobs/" + o.job_id));

    std::string last_id;
    int failures = 0;
    while (!p.ended()) {
      bool got_any = false;
      SseParser parser([&](const SseEvent& e) {
        got_any = true;
        p.on_event(e);
      });
      HeaderList h = {{"Accept", "text/event-stream"}};
      if (!last_id.empty()) h.emplace_back("Last-Event-ID", last_id);
      try {
        const ClientResponse r = client.stream(
            "/v1/jobs/" + o.job_id + "/events", h,
            [&](std::string_view bytes) {
              parser.feed(bytes);
              p.maybe_flush(false);
              return !p.ended();
            },
            120.0);
        if (r.status == 404) fail(exit_code::usage, fmt::format("job {} not found", o.job_id));
        if (r.status != 200) fail(exit_code::connection, fmt::format("the event stream answered {}", r.status));
      } catch (const ConnectionError& e) {
        if (got_any) failures = 0;
        if (++failures > 60) fail(exit_code::connection, e.what());
      }
      if (!parser.last_event_id().empty()) last_id = parser.last_event_id();
      if (!p.ended()) {
        p.maybe_flush(true);
        std::this_thread::sleep_for(std::chrono::seconds(1));
      }
    }
    p.maybe_flush(true);
    bridge.finish();
    if (!o.quiet) {
      fmt::print(stderr, "tally preview: job {} ended; {} tile updates, {} packets, {} tev reconnects\n", o.job_id,
                 p.tiles_sent(), bridge.packets_sent(), bridge.reconnects());
    }
    return exit_code::ok;
  } catch (const PreviewFailure& f) {
    return f.code;
  } catch (const ConnectionError& e) {
    fmt::print(stderr, "tally preview: {}\n", e.what());
    return exit_code::connection;
  } catch (const json::exception& e) {
    fmt::print(stderr, "tally preview: unexpected answer from the server: {}\n", e.what());
    return exit_code::connection;
  } catch (const std::runtime_error& e) {  // tev unreachable after the retries
    fmt::print(stderr, "tally preview: {}\n", e.what());
    return exit_code::connection;
  }
}

void add_preview_command(CLI::App& app, int& exit_code) {
  auto o = std::make_shared<PreviewOptions>();
  CLI::App* cmd = app.add_subcommand("preview", "Mirror a running image job into the tev viewer");
  cmd->add_option("id", o->job_id, "job id")->required();
  cmd->add_option("--tev", o->tev, "tev's HOST:PORT")->capture_default_str();
  cmd->add_option("--server", o->server, "server URL")->envname("TALLY_SERVER")->capture_default_str();
  add_security_options(cmd, o->security);
  cmd->add_option("--name", o->image_name, "image name in tev (default tally-<id>)");
  cmd->add_option("--tev-retries", o->tev_retries, "reconnect attempts when tev goes away")->capture_default_str();
  cmd->add_flag("--quiet,-q", o->quiet, "print nothing but errors");
  cmd->callback([o, &exit_code] { exit_code = run_preview(*o); });
}

}  // namespace tally
