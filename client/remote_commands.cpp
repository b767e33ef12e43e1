#include "client/remote_commands.hpp"

#include <fmt/format.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <optional>
#include <sstream>
#include <thread>

#include <cerrno>
#include <cstring>

#include "client/api_request.hpp"
#include "client/asset_upload.hpp"
#include "client/exit_codes.hpp"
#include "client/http_client.hpp"
#include "client/image_format.hpp"
#include "client/json_errors.hpp"
#include "client/progress_display.hpp"
#include "client/sse_parser.hpp"

namespace tally {

using nlohmann::json;

namespace {

struct RemoteOptions {
  std::string server = kDefaultServer;
  ClientSecurity security;
};

// A command that ends early with this exit code (the reason is printed already).
struct RemoteFailure {
  int code;
};

HttpClient make_client(const RemoteOptions& o) {
  const auto url = parse_http_url(o.server);
  if (!url) {
    fmt::print(stderr, "tally: --server must be an http:// or https:// URL, got \"{}\"\n", o.server);
    throw RemoteFailure{exit_code::usage};
  }
  return HttpClient(*url, 30.0, o.security);
}

// The exit code of a refused request: access (401/403); the request was wrong (bad spec,
// unknown job, wrong state): usage; else server trouble.
int exit_code_for_http(int status) {
  if (status == 401 || status == 403) return exit_code::auth;
  const bool ours = status == 400 || status == 404 || status == 405 || status == 409 || status == 413 ||
                    status == 415 || status == 422;
  return ours ? exit_code::usage : exit_code::connection;
}

// An HTTP answer we did not want: print the problem detail (with the user's file names
// in place of the hashes the packer gave them, when `paths` is given), map to an exit code.
[[noreturn]] void fail_response(const ClientResponse& r, const AssetUploadReport* paths = nullptr) {
  std::string detail = problem_detail(r);
  if (paths) detail = paths->with_user_paths(detail);
  if (r.status == 401) {
    fmt::print(stderr, "tally: the server wants a token (401: {}); pass --token TOKEN or set TALLY_TOKEN\n", detail);
    throw RemoteFailure{exit_code::auth};
  }
  if (r.status == 403) {
    fmt::print(stderr, "tally: not allowed with this token (403: {})\n", detail);
    throw RemoteFailure{exit_code::auth};
  }
  fmt::print(stderr, "tally: server answered {}: {}\n", r.status, detail);
  throw RemoteFailure{exit_code_for_http(r.status)};
}

// Waits out 503 + Retry-After (a recovering server, a full queue), saying so on stderr.
ClientResponse request(HttpClient& c, std::string_view method, std::string_view target, std::string_view body = {},
                       const HeaderList& headers = {}) {
  RetryPolicy policy;
  policy.on_retry = [](const ClientResponse& r, double wait) {
    fmt::print(stderr, "tally: server busy (503: {}); retrying in {:.1f} s\n", problem_detail(r), wait);
  };
  return request_retrying(c, method, target, body, headers, policy);
}

json get_json(HttpClient& c, const std::string& target) {
  return tally::get_json(c, target, [](const ClientResponse& r) { fail_response(r); });
}

std::string read_spec(const std::string& path) {
  if (path == "-") {
    std::stringstream ss;
    ss << std::cin.rdbuf();
    return ss.str();
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    fmt::print(stderr, "tally: cannot read {}: {}\n", path, std::strerror(errno));
    throw RemoteFailure{exit_code::usage};
  }
  std::stringstream ss;
  ss << in.rdbuf();
  if (in.bad()) {
    fmt::print(stderr, "tally: cannot read {}: {}\n", path, std::strerror(errno));
    throw RemoteFailure{exit_code::usage};
  }
  return ss.str();
}

// The spec file as JSON, or a usage error naming the file, line and column.
json parse_spec(const std::string& path, const std::string& text) {
  try {
    return json::parse(text);
  } catch (const json::parse_error& e) {
    fmt::print(stderr, "tally: {} is not valid JSON: {}\n", path == "-" ? "the spec on stdin" : path,
               json_parse_error_text(e));
    throw RemoteFailure{exit_code::usage};
  }
}

// A spec read from `path`, its scene's files uploaded and named by hash (unless `upload`
// is false). Returns the body to send and the packer's report (for naming files).
std::pair<std::string, AssetUploadReport> packed_spec(HttpClient& c, const std::string& path, bool upload) {
  json spec = parse_spec(path, read_spec(path));
  AssetUploadReport up;
  if (upload) {
    const std::filesystem::path base =
        path == "-" ? std::filesystem::current_path() : std::filesystem::path(path).parent_path();
    try {
      up = upload_scene_assets(c, spec, base.empty() ? "." : base);
    } catch (const PackError& e) {
      fmt::print(stderr, "tally: {}\n", e.what());
      throw RemoteFailure{exit_code::usage};
    } catch (const AssetRefused& e) {
      fmt::print(stderr, "tally: {}\n", e.what());
      throw RemoteFailure{exit_code_for_http(e.status)};
    }
    if (up.uploaded + up.present > 0) {
      fmt::print(stderr, "tally: assets: {} uploaded, {} already on the server\n", up.uploaded, up.present);
    }
  }
  return {spec.dump(), std::move(up)};
}

// The validate answer's prediction as one line ("" when there is none).
std::string prediction_text(const json& v) {
  const json p = v.value("prediction", json());
  if (!p.is_object()) {
    const json pilot = v.value("pilot", json::object());
    if (pilot.contains("error")) return "the pilot failed: " + pilot["error"].get<std::string>();
    if (pilot.contains("note")) return pilot["note"].get<std::string>();
    return "";
  }
  const json samples = p.value("samples", json()), seconds = p.value("seconds", json());
  std::string out = fmt::format("predicted: stops by {} after {} samples, {} compute", p.value("stops_by", "?"),
                                samples.is_number() ? format_count(samples.get<double>()) : "?",
                                seconds.is_number() ? format_duration(seconds.get<double>()) : "?");
  const json pilot = v.value("pilot", json::object());
  if (pilot.contains("job_samples_per_second") && pilot["job_samples_per_second"].is_number()) {
    out += fmt::format(" (at {}/s)", format_count(pilot["job_samples_per_second"].get<double>()));
  }
  if (!p.value("reliable", true)) out += "; unreliable: the variance may be infinite (heavy tail)";
  return out;
}

// The validate answer's suggested estimator as one line ("" when there is none).
std::string suggestion_text(const json& v) {
  const json s = v.value("suggestion", json());
  if (!s.is_object()) return "";
  const json w = s.value("would_choose", json::object());
  std::string out = fmt::format("faster: add \"estimator\": {{\"type\": \"auto\"}}; it would choose {}{}",
                                w.value("estimator", "?"),
                                w.contains("periodize") ? fmt::format(" ({})", w["periodize"].get<std::string>()) : "");
  const json fewer = s.value("fewer_evaluations", json()), evals = s.value("predicted_evaluations", json()),
             dflt = s.value("default_predicted_evaluations", json());
  if (fewer.is_number() && evals.is_number() && dflt.is_number()) {
    out += fmt::format(", about {}x fewer integrand evaluations ({} against the default's {})", format_count(fewer.get<double>()),
                       format_count(evals.get<double>()), format_count(dflt.get<double>()));
  }
  const json secs = s.value("predicted_seconds", json());
  if (secs.is_number()) out += fmt::format(", about {} of compute", format_duration(secs.get<double>()));
  return out;
}

// Seconds the validate answer predicts (nullopt when it has no prediction).
std::optional<double> predicted_seconds(const json& v) {
  const json p = v.value("prediction", json());
  const json seconds = p.is_object() ? p.value("seconds", json()) : json();
  if (!seconds.is_number()) return std::nullopt;
  return seconds.get<double>();
}

void print_status(const json& s) {
  fmt::print("job {}  {}", s.value("id", "?"), s.value("state", "?"));
  if (s.contains("stop_reason")) fmt::print("  (stop: {})", s.value("stop_reason", ""));
  fmt::print("\n");
  if (s.contains("summary") && s["summary"].is_string()) {
    fmt::print("{}\n", s["summary"].get<std::string>());
  } else {
    fmt::print("{}\n", estimate_text(s));
  }
  const double rate = s.value("samples_per_second", 0.0);
  fmt::print("{} samples in {} passes, {} compute, {}/s", format_count(s.value("samples", 0.0)), s.value("passes", 0),
             format_duration(s.value("compute_seconds", 0.0)), format_count(rate));
  if (s.contains("eta_seconds") && s["eta_seconds"].is_number() && s.value("state", "") == "running") {
    fmt::print(", ETA {}", format_duration(s["eta_seconds"].get<double>()));
  }
  fmt::print("\n");
  if (s.contains("error_message")) fmt::print("error: {}\n", s["error_message"].get<std::string>());
  if (s.contains("diagnostics")) {
    for (const auto& w : s["diagnostics"].value("warnings", json::array())) fmt::print("warning: {}\n", w.get<std::string>());
  }
}

template <class F>
void run_guarded(int& exit_code, F&& f) {
  try {
    exit_code = f();
  } catch (const RemoteFailure& e) {
    exit_code = e.code;
  } catch (const ConnectionError& e) {
    fmt::print(stderr, "tally: {}\n", e.what());
    exit_code = exit_code::connection;
  } catch (const json::exception& e) {
    fmt::print(stderr, "tally: unexpected answer from the server: {}\n", e.what());
    exit_code = exit_code::connection;
  }
}

void add_server_option(CLI::App* cmd, RemoteOptions& o) {
  cmd->add_option("--server", o.server, "server URL")->envname("TALLY_SERVER")->capture_default_str();
  add_security_options(cmd, o.security);
}

// A subcommand about one job: its id, then the options `add_options` adds (may be
// empty), then the server options; when chosen, `run(client, id)` under run_guarded.
void add_job_command(CLI::App& app, int& exit_code, const char* name, const char* help,
                     const std::function<void(CLI::App*)>& add_options,
                     std::function<int(HttpClient&, const std::string&)> run) {
  auto opt = std::make_shared<RemoteOptions>();
  auto id = std::make_shared<std::string>();
  CLI::App* cmd = app.add_subcommand(name, help);
  cmd->add_option("id", *id, "job id")->required();
  if (add_options) add_options(cmd);
  add_server_option(cmd, *opt);
  cmd->callback([=, &exit_code, run = std::move(run)] {
    run_guarded(exit_code, [&] {
      HttpClient c = make_client(*opt);
      return run(c, *id);
    });
  });
}

// "queued", "running" or a final state.
std::string job_state(HttpClient& c, const std::string& id) {
  return get_json(c, "/v1/jobs/" + id).value("state", "");
}

bool is_active(const std::string& state) { return state == "queued" || state == "running"; }

}  // namespace

int exit_code_for_status(const json& s) {
  const std::string state = s.value("state", "");
  if (state == "failed" || state == "cancelled") return exit_code::job_failed;
  if (state != "succeeded") return -1;
  const json rule = s.value("stop_rule", json::object());
  const bool has_target = rule.contains("abs_error") || rule.contains("rel_error");
  if (has_target && !s.value("target_met", false)) return exit_code::target_not_met;
  return exit_code::ok;
}

int watch_job(HttpClient& client, const std::string& id, bool quiet) {
  ProgressDisplay display(stderr, detect_display(stderr));
  {
    const json s = get_json(client, "/v1/jobs/" + id);
    display.set_stop_rule(s.value("stop_rule", json::object()));
  }
  std::string last_id;
  bool ended = false;
  int retries = 0;
  while (!ended) {
    bool got_any = false;
    SseParser parser([&](const SseEvent& e) {
      got_any = true;
      if (e.event == "progress") {
        if (!quiet) display.progress(json::parse(e.data));
      } else if (e.event == "state") {
        const json d = json::parse(e.data);
        if (!quiet && d.value("state", "") != "running") display.message("state: " + d.value("state", "?"));
      } else if (e.event == "end") {
        ended = true;
      } else if (e.event == "shutdown") {
        if (!quiet) display.message("the server is shutting down; reconnecting when it is back");
      }
    });
    HeaderList h = {{"Accept", "text/event-stream"}};
    if (!last_id.empty()) h.emplace_back("Last-Event-ID", last_id);
    try {
      const ClientResponse r = client.stream(
          "/v1/jobs/" + id + "/events", h,
          [&](std::string_view bytes) {
            parser.feed(bytes);
            return !ended;
          },
          120.0);
      if (r.status != 200) fail_response(r);
    } catch (const ConnectionError& e) {
      // Reconnect (the server may be restarting); give up after ~60 s of failures.
      if (got_any) retries = 0;
      if (++retries > 60) throw;
    }
    if (!parser.last_event_id().empty()) last_id = parser.last_event_id();
    if (!ended) std::this_thread::sleep_for(std::chrono::seconds(1));
  }
  display.finish();
  const json s = get_json(client, "/v1/jobs/" + id);
  if (!quiet) print_status(s);
  const int code = exit_code_for_status(s);
  return code < 0 ? exit_code::ok : code;
}

void add_remote_commands(CLI::App& app, int& exit_code) {
  // submit
  {
    auto opt = std::make_shared<RemoteOptions>();
    auto file = std::make_shared<std::string>();
    auto watch = std::make_shared<bool>(false);
    auto priority = std::make_shared<int>(0);
    auto warn_s = std::make_shared<double>(60.0);
    auto no_predict = std::make_shared<bool>(false);
    auto no_upload = std::make_shared<bool>(false);
    CLI::App* cmd = app.add_subcommand("submit", "Submit a job spec (JSON file, - for stdin) to the server");
    cmd->add_option("spec", *file, "job spec file")->required();
    cmd->add_flag("--watch,-w", *watch, "follow the job until it ends");
    cmd->add_option("--priority", *priority, "CPU share priority, -5..5")->check(CLI::Range(-5, 5));
    cmd->add_flag("--no-upload", *no_upload,
                  "send the spec as it is (by default every local file the scene names, and the files those name, "
                  "is uploaded to the server's asset store, only what it lacks, and named by its sha256)");
    cmd->add_option("--warn-seconds", *warn_s,
                    "warn when the predicted compute time exceeds this (seconds; the prediction is the server's "
                    "validate pilot)")
        ->check(CLI::NonNegativeNumber)
        ->capture_default_str();
    cmd->add_flag("--no-predict", *no_predict, "submit without asking the server for a prediction first");
    add_server_option(cmd, *opt);
    cmd->callback([=, &exit_code] {
      run_guarded(exit_code, [&] {
        HttpClient c = make_client(*opt);
        const auto [body, up] = packed_spec(c, *file, !*no_upload);
        const HeaderList json_type = {{"Content-Type", "application/json"}};
        if (!*no_predict) {
          const ClientResponse v = request(c, "POST", "/v1/jobs/validate", body, json_type);
          if (v.status == 200) {
            const json vj = json::parse(v.body);
            const std::string text = prediction_text(vj);
            if (!text.empty()) fmt::print(stderr, "tally: {}\n", text);
            if (const std::string faster = suggestion_text(vj); !faster.empty()) fmt::print(stderr, "tally: {}\n", faster);
            const auto secs = predicted_seconds(vj);
            if (secs && *secs > *warn_s) {
              fmt::print(stderr,
                         "tally: warning: the job is predicted to take {} of compute, more than --warn-seconds {}; "
                         "`tally cancel ID` stops it, a looser target or another estimator is cheaper "
                         "(`tally validate` shows the cost curve)\n",
                         format_duration(*secs), *warn_s);
            }
          } else if (v.status != 503) {
            fail_response(v, &up);  // the spec is refused: the submit would be too
          }
        }
        const ClientResponse r = request(c, "POST", fmt::format("/v1/jobs?priority={}", *priority), body, json_type);
        if (r.status != 202) fail_response(r, &up);
        const std::string id = json::parse(r.body).at("id").get<std::string>();
        fmt::print("{}\n", id);
        std::fflush(stdout);
        return *watch ? watch_job(c, id) : exit_code::ok;
      });
    });
  }
  // validate
  {
    auto opt = std::make_shared<RemoteOptions>();
    auto file = std::make_shared<std::string>();
    auto as_json = std::make_shared<bool>(false);
    auto no_upload = std::make_shared<bool>(false);
    CLI::App* cmd = app.add_subcommand(
        "validate", "Check a job spec on the server and predict its cost (samples, seconds) without running it");
    cmd->add_option("spec", *file, "job spec file (- for stdin)")->required();
    cmd->add_flag("--json", *as_json, "print the server's whole answer (plan, pilot, prediction, cost curve)");
    cmd->add_flag("--no-upload", *no_upload, "send the spec as it is (see submit)");
    add_server_option(cmd, *opt);
    cmd->callback([=, &exit_code] {
      run_guarded(exit_code, [&] {
        HttpClient c = make_client(*opt);
        const auto [body, up] = packed_spec(c, *file, !*no_upload);
        const ClientResponse r =
            request(c, "POST", "/v1/jobs/validate", body, {{"Content-Type", "application/json"}});
        if (r.status != 200) fail_response(r, &up);
        const json v = json::parse(r.body);
        if (*as_json) {
          fmt::print("{}\n", v.dump(2));
          return exit_code::ok;
        }
        fmt::print("valid\n");
        const std::string text = prediction_text(v);
        if (!text.empty()) fmt::print("{}\n", text);
        const json p = v.value("prediction", json());
        if (p.is_object() && p.contains("cost_curve") && p["cost_curve"].is_array()) {
          for (const auto& pt : p["cost_curve"]) {
            if (!pt["samples"].is_number() || !pt["seconds"].is_number()) continue;
            fmt::print("  rel. error {:g}: {} samples, {}\n", pt.value("rel_error", 0.0),
                       format_count(pt["samples"].get<double>()), format_duration(pt["seconds"].get<double>()));
          }
        }
        if (const std::string faster = suggestion_text(v); !faster.empty()) fmt::print("{}\n", faster);
        const json pilot = v.value("pilot", json::object());
        for (const auto& w : pilot.value("warnings", json::array())) {
          if (w.is_string()) fmt::print("warning: {}\n", w.get<std::string>());
        }
        return exit_code::ok;
      });
    });
  }
  // watch
  add_job_command(app, exit_code, "watch", "Follow a job's progress until it ends", {},
                  [](HttpClient& c, const std::string& id) { return watch_job(c, id); });
  // get
  {
    auto as_json = std::make_shared<bool>(false);
    auto image = std::make_shared<std::string>();
    add_job_command(
        app, exit_code, "get", "Show a job's status and result",
        [=](CLI::App* cmd) {
          cmd->add_flag("--json", *as_json, "print the full status document");
          cmd->add_option("--image", *image, "save the job's image (.exr or .png)");
        },
        [=](HttpClient& c, const std::string& id) {
          const auto format = image->empty() ? std::optional<ImageFormat>() : image_format_of(*image);
          if (!image->empty() && !format) {
            fmt::print(stderr, "tally: {}\n", unknown_image_format_message(*image));
            return exit_code::usage;
          }
          const ClientResponse r = request(c, "GET", "/v1/jobs/" + id);
          if (r.status != 200) fail_response(r);
          const json s = json::parse(r.body);
          if (*as_json) {
            fmt::print("{}\n", s.dump(2));
          } else {
            print_status(s);
          }
          if (!image->empty()) {
            const bool png = *format == ImageFormat::png;
            const ClientResponse img = request(c, "GET", "/v1/jobs/" + id + (png ? "/image.png" : "/image.exr"));
            if (img.status != 200) fail_response(img);
            std::ofstream out(*image, std::ios::binary);
            out.write(img.body.data(), static_cast<std::streamsize>(img.body.size()));
            if (!out) {
              fmt::print(stderr, "tally: cannot write {}: {}\n", *image, std::strerror(errno));
              return exit_code::usage;
            }
            fmt::print(stderr, "wrote {} ({} bytes)\n", *image, img.body.size());
          }
          const int code = exit_code_for_status(s);
          return code < 0 ? exit_code::ok : code;
        });
  }
  // list
  {
    auto opt = std::make_shared<RemoteOptions>();
    auto state = std::make_shared<std::string>();
    CLI::App* cmd = app.add_subcommand("list", "List the server's jobs");
    cmd->add_option("--state", *state, "only jobs in this state")
        ->check(CLI::IsMember({"queued", "running", "succeeded", "failed", "cancelled"}));
    add_server_option(cmd, *opt);
    cmd->callback([=, &exit_code] {
      run_guarded(exit_code, [&] {
        HttpClient c = make_client(*opt);
        bool header = false;  // printed with the first page: a refusal prints no table
        // Pages of up to 1000 jobs, each naming the next one (docs/api.md).
        std::string page = state->empty() ? std::string("/v1/jobs?limit=1000") : "/v1/jobs?limit=1000&state=" + *state;
        for (int pages = 0; !page.empty() && pages < 100000; ++pages) {
        const json j = get_json(c, page);
        page = j.contains("next") && j["next"].is_string() ? j["next"].get<std::string>() : std::string();
        if (!header) {
          fmt::print("{:<18} {:<10} {:<10} {:>10} {:>20} {:>12}  {}\n", "ID", "STATE", "KIND", "SAMPLES", "MEAN", "STDERR",
                     "NOTE");
          header = true;
        }
        for (const auto& s : j.at("jobs")) {
          auto num = [&](const char* k) {
            return s.contains(k) && s[k].is_number() ? fmt::format("{:.10g}", s[k].get<double>()) : std::string("-");
          };
          // Why a queued job waits (preempted, its owner's quota, its pool), or where a
          // result came from (the result cache).
          std::string note = s.value("waiting_reason", "");
          if (note.empty() && s.contains("cached_from") && s["cached_from"].is_string()) {
            note = "cached from " + s["cached_from"].get<std::string>();
          }
          fmt::print("{:<18} {:<10} {:<10} {:>10} {:>20} {:>12}  {}\n", s.value("id", ""), s.value("state", ""),
                     s.value("kind", ""), format_count(s.value("samples", 0.0)), num("mean"), num("std_error"), note);
        }
        }
        return exit_code::ok;
      });
    });
  }
  // cancel
  add_job_command(app, exit_code, "cancel", "Cancel a queued or running job", {},
                  [](HttpClient& c, const std::string& id) {
                    // DELETE of a finished job deletes it: cancel never sends it to one.
                    const std::string state = job_state(c, id);
                    if (!is_active(state)) {
                      fmt::print(stderr, "tally: job {} has already finished ({}); `tally delete {}` deletes it\n", id,
                                 state, id);
                      return exit_code::usage;
                    }
                    const ClientResponse r = request(c, "DELETE", "/v1/jobs/" + id);
                    if (r.status == 204) {  // it finished in between, and was deleted
                      fmt::print("{} deleted (it had just finished)\n", id);
                      return exit_code::ok;
                    }
                    if (r.status != 200 && r.status != 202) fail_response(r);
                    fmt::print("{} {}\n", id, r.status == 200 ? "cancelled" : "cancelling (stops at the next chunk)");
                    return exit_code::ok;
                  });
  // delete
  add_job_command(app, exit_code, "delete", "Delete a finished job and its stored state", {},
                  [](HttpClient& c, const std::string& id) {
                    const std::string state = job_state(c, id);
                    if (is_active(state)) {
                      fmt::print(stderr, "tally: job {} is still {}; `tally cancel {}` first\n", id, state, id);
                      return exit_code::usage;
                    }
                    const ClientResponse r = request(c, "DELETE", "/v1/jobs/" + id);
                    if (r.status != 204) fail_response(r);
                    fmt::print("{} deleted\n", id);
                    return exit_code::ok;
                  });
  // priority
  {
    auto priority = std::make_shared<int>(0);
    add_job_command(
        app, exit_code, "priority", "Change a queued or running job's priority (-5..5)",
        [=](CLI::App* cmd) {
          cmd->add_option("priority", *priority, "the new priority, -5 (last) .. 5 (first)")
              ->required()
              ->check(CLI::Range(-5, 5));
        },
        [=](HttpClient& c, const std::string& id) {
          const ClientResponse r = request(c, "PATCH", "/v1/jobs/" + id, json{{"priority", *priority}}.dump(),
                                           {{"Content-Type", "application/json"}});
          if (r.status != 200) fail_response(r);
          fmt::print("{} priority {}\n", id, *priority);
          return exit_code::ok;
        });
  }
  // extend
  {
    auto max_samples = std::make_shared<uint64_t>(0);
    auto abs_error = std::make_shared<double>(0);
    auto rel_error = std::make_shared<double>(0);
    auto budget = std::make_shared<double>(0);
    auto watch = std::make_shared<bool>(false);
    add_job_command(
        app, exit_code, "extend", "Reopen a finished job with more samples or a tighter target",
        [=](CLI::App* cmd) {
          auto* g = cmd->add_option_group("target", "the new stopping targets (at least one)");
          g->add_option("--max-samples", *max_samples, "total samples")->check(CLI::PositiveNumber);
          g->add_option("--abs-error", *abs_error, "target half-width of the interval")->check(CLI::PositiveNumber);
          g->add_option("--rel-error", *rel_error, "target half-width / |mean|")->check(CLI::PositiveNumber);
          g->add_option("--time-budget", *budget, "total compute seconds")->check(CLI::PositiveNumber);
          g->require_option(1, 0);
          cmd->add_flag("--watch,-w", *watch, "follow the job until it ends");
        },
        [=](HttpClient& c, const std::string& id) {
          json body = json::object();
          if (*max_samples > 0) body["max_samples"] = *max_samples;
          if (*abs_error > 0) body["abs_error"] = *abs_error;
          if (*rel_error > 0) body["rel_error"] = *rel_error;
          if (*budget > 0) body["time_budget_s"] = *budget;
          const ClientResponse r = request(c, "POST", "/v1/jobs/" + id + "/extend", body.dump(),
                                             {{"Content-Type", "application/json"}});
          if (r.status != 202) fail_response(r);
          fmt::print("{} extended\n", id);
          std::fflush(stdout);
          return *watch ? watch_job(c, id) : exit_code::ok;
        });
  }
}

}  // namespace tally
