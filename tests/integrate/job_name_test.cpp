// docs/jobs.md: every job kind takes an optional `name` (a string of at most 200
// characters). Checked on every example spec, so a new kind cannot forget it.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <unistd.h>

#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"

namespace tally {
namespace {

using nlohmann::json;

// The examples that name files (the glTF demo scene) read them from an asset
// directory: scripts/gltf_example.py writes them, as `make demo` does.
struct ExampleAssets {
  std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("tally_job_name_assets_" + std::to_string(::getpid()));
  JobLimits limits;
  ExampleAssets() {
    std::filesystem::create_directories(dir);
    const std::string cmd =
        std::string("python3 ") + TALLY_SOURCE_DIR + "/scripts/gltf_example.py " + dir.string() + " > /dev/null";
    if (std::system(cmd.c_str()) != 0) ADD_FAILURE() << "failed: " << cmd;
    limits.asset_dir = dir.string();
  }
  ~ExampleAssets() {
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
  }
};

const JobLimits& example_limits() {
  static const ExampleAssets assets;
  return assets.limits;
}

std::vector<std::pair<std::string, json>> example_specs() {
  std::vector<std::pair<std::string, json>> out;
  for (const auto& e : std::filesystem::directory_iterator(std::filesystem::path(TALLY_SOURCE_DIR) / "examples")) {
    if (e.path().extension() != ".json") continue;
    std::ifstream f(e.path());
    out.emplace_back(e.path().filename().string(), json::parse(f));
  }
  return out;
}

TEST(JobName, AcceptedOnEveryKind) {
  const auto specs = example_specs();
  std::set<std::string> kinds;
  for (auto [file, spec] : specs) {
    spec["name"] = "a run with a name";
    EXPECT_NO_THROW(compile_job(spec, example_limits())) << file;
    kinds.insert(spec["kind"].get<std::string>());
  }
  // The examples cover both kinds, so the loop above checked both.
  EXPECT_EQ(kinds, (std::set<std::string>{"integrate", "lighting"}));
}

TEST(JobName, WrongTypeOrTooLongNamesThePointer) {
  for (auto [file, spec] : example_specs()) {
    for (const json& bad : {json(42), json::array({"x"}), json(std::string(201, 'n'))}) {
      spec["name"] = bad;
      try {
        compile_job(spec, example_limits());
        ADD_FAILURE() << file << ": name " << bad.dump().substr(0, 20) << " was accepted";
      } catch (const SpecError& e) {
        EXPECT_EQ(e.pointer(), "/name") << file << ": " << e.what();
      }
    }
    spec["name"] = std::string(200, 'n');
    EXPECT_NO_THROW(compile_job(spec, example_limits())) << file;
  }
}

}  // namespace
}  // namespace tally
