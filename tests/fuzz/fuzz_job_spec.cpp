// libFuzzer: the job spec compilers (integrate and lighting) on arbitrary JSON.
// Every input either compiles or throws SpecError; anything else (another
// exception, a crash, a sanitizer report) is a finding. The first byte picks which
// kind the document is forced to, so both compilers see every shape of input.
#include <nlohmann/json.hpp>

#include "common/protocol/job_kinds.hpp"
#include "common/spec/spec_reader.hpp"
#include "fuzz_support.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const std::string text(reinterpret_cast<const char*>(data) + 1, size - 1);
  nlohmann::json spec = nlohmann::json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (spec.is_discarded()) return 0;
  if (spec.is_object()) {
    switch (data[0] % 4) {
      case 0: spec["kind"] = "integrate"; break;
      case 1: spec["kind"] = "lighting"; break;
      default: break;  // as given
    }
  }
  tally::JobLimits limits;  // small, so a valid spec cannot allocate much
  limits.max_pixels = 64 * 64;
  limits.max_table_size = 4096;
  limits.max_quadrature_points = 1 << 12;
  limits.max_embedded_lattice_dimensions = 2;  // the lattice cone rule's CBC: about 1.5 s a dimension under ASan
  try {
    const auto def = tally::compile_job(spec, limits);
    (void)plan_json(*def).dump();
  } catch (const tally::SpecError&) {
    return 0;
  } catch (const std::exception& e) {
    tally::fuzz::fail("compile_job threw something other than SpecError", e.what(), text);
  }
  return 0;
}
