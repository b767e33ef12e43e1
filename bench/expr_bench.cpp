// Evaluations per second of user expressions: muParser one point at a time, muParser's
// bulk mode, and our compiled batches, in one run so the ratios compare like with like.
//   expr_bench [points=16777216]
// Then a vector integrand's components: one template at 1,000 parameter values evaluated
// one by one and together (CompiledExpressionSet: the shared part once), interleaved.
// muParser's bulk mode uses OpenMP threads (Debian builds it with MUP_USE_OPENMP): its
// wall-clock rate counts every thread, so the per-CPU-second rate is printed as well; run
// with OMP_NUM_THREADS=1 for a single-thread comparison.
#include <muParser.h>
#include <time.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "common/expr/compiled_expression.hpp"
#include "common/expr/expr_parameters.hpp"

namespace {

struct Timer {
  std::chrono::steady_clock::time_point wall = std::chrono::steady_clock::now();
  double cpu0 = cpu_now();
  static double cpu_now() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
  }
  double wall_seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - wall).count();
  }
  double cpu_seconds() const { return cpu_now() - cpu0; }
};

struct Result {
  double wall_rate = 0;  // evaluations per wall second
  double cpu_rate = 0;   // evaluations per CPU second (all threads)
  double checksum = 0;
};

constexpr size_t kDims = 2;
constexpr size_t kChunk = 1 << 16;  // points held in memory, reused (fits in L2)

std::vector<std::vector<double>> make_points() {
  std::vector<std::vector<double>> cols(kDims, std::vector<double>(kChunk));
  uint64_t s = 42;
  for (size_t i = 0; i < kChunk; ++i) {
    for (size_t v = 0; v < kDims; ++v) {
      s = s * 6364136223846793005ULL + 1442695040888963407ULL;
      cols[v][i] = static_cast<double>(s >> 11) * 0x1.0p-53 * 2.0 - 1.0;
    }
  }
  return cols;
}

Result muparser_scalar(const std::string& text, const std::vector<std::vector<double>>& cols,
                       size_t total) {
  double v[kDims] = {};
  mu::Parser p;
  p.DefineVar("x0", &v[0]);
  p.DefineVar("x1", &v[1]);
  p.SetExpr(text);
  Result r;
  Timer t;
  for (size_t done = 0; done < total; done += kChunk) {
    for (size_t i = 0; i < kChunk; ++i) {
      v[0] = cols[0][i];
      v[1] = cols[1][i];
      r.checksum += p.Eval();
    }
  }
  r.wall_rate = static_cast<double>(total) / t.wall_seconds();
  r.cpu_rate = static_cast<double>(total) / t.cpu_seconds();
  return r;
}

Result muparser_bulk(const std::string& text, const std::vector<std::vector<double>>& cols,
                     size_t total) {
  std::vector<std::vector<double>> in = cols;  // bulk mode reads variable[i] by offset
  std::vector<double> out(kChunk);
  mu::Parser p;
  p.DefineVar("x0", in[0].data());
  p.DefineVar("x1", in[1].data());
  p.SetExpr(text);
  Result r;
  Timer t;
  for (size_t done = 0; done < total; done += kChunk) {
    p.Eval(out.data(), static_cast<int>(kChunk));
    for (size_t i = 0; i < kChunk; ++i) r.checksum += out[i];
  }
  r.wall_rate = static_cast<double>(total) / t.wall_seconds();
  r.cpu_rate = static_cast<double>(total) / t.cpu_seconds();
  return r;
}

Result ours_batch(const tally::CompiledExpression& e, const std::vector<std::vector<double>>& cols,
                  size_t total, size_t batch) {
  std::vector<double> out(kChunk);
  Result r;
  Timer t;
  for (size_t done = 0; done < total; done += kChunk) {
    for (size_t start = 0; start < kChunk; start += batch) {
      const double* xs[kDims] = {cols[0].data() + start, cols[1].data() + start};
      e.evaluate_batch(xs, std::min(batch, kChunk - start), out.data() + start);
    }
    for (size_t i = 0; i < kChunk; ++i) r.checksum += out[i];
  }
  r.wall_rate = static_cast<double>(total) / t.wall_seconds();
  r.cpu_rate = static_cast<double>(total) / t.cpu_seconds();
  return r;
}

Result ours_point(const tally::CompiledExpression& e, const std::vector<std::vector<double>>& cols,
                  size_t total) {
  Result r;
  Timer t;
  for (size_t done = 0; done < total; done += kChunk) {
    for (size_t i = 0; i < kChunk; ++i) {
      const double x[kDims] = {cols[0][i], cols[1][i]};
      r.checksum += e.evaluate(x);
    }
  }
  r.wall_rate = static_cast<double>(total) / t.wall_seconds();
  r.cpu_rate = static_cast<double>(total) / t.cpu_seconds();
  return r;
}

// Ratios use the per-CPU-second rates: the machines are shared, and wall time counts the
// time other processes hold the cores.
void report(const char* name, const Result& r, const Result& scalar, const Result& bulk) {
  std::printf(
      "  %-32s %7.1f M/s wall %7.1f M/s per CPU-s   x%5.1f vs Eval  x%5.1f vs bulk  (sum %.0f)\n",
      name, r.wall_rate * 1e-6, r.cpu_rate * 1e-6, r.cpu_rate / scalar.cpu_rate,
      r.cpu_rate / bulk.cpu_rate, r.checksum);
}

}  // namespace

// exp(s*(sum_j sin(2 pi x_j)/(j+1))) over 16 dimensions at s = 0.001 .. 1 (the spec of
// examples/vector_parameters_16d.json): component evaluations per CPU second, one by one
// and together, over `rounds` interleaved rounds of 64 batches of 256 points.
void components_together(int rounds) {
  constexpr size_t kD = 16, kM = 1000, kN = 256, kBatches = 64;
  std::string sum;
  for (size_t j = 0; j < kD; ++j) {
    sum += (j ? "+" : "") + std::to_string(1.0 / static_cast<double>(j + 1)) + "*sin(2*_pi*x" + std::to_string(j) + ")";
  }
  const std::string text = "exp(s*(" + sum + "))";
  std::vector<tally::CompiledExpression> exprs;
  for (size_t c = 1; c <= kM; ++c) {
    exprs.push_back(tally::CompiledExpression::compile(
        tally::expr::bind_parameters(text, {{"s", static_cast<double>(c) / 1000.0}}), kD));
  }
  const tally::CompiledExpressionSet set(exprs);
  std::vector<std::vector<double>> x(kD, std::vector<double>(kN));
  uint64_t state = 12345;
  for (auto& col : x) {
    for (double& v : col) {
      state = state * 6364136223846793005ULL + 1442695040888963407ULL;
      v = static_cast<double>(state >> 11) * 0x1.0p-53;
    }
  }
  std::vector<const double*> xs;
  for (auto& col : x) xs.push_back(col.data());
  std::vector<std::vector<double>> out(kM, std::vector<double>(kN));
  std::vector<double*> outs;
  for (auto& o : out) outs.push_back(o.data());
  double alone_cpu = 0, together_cpu = 0, check_alone = 0, check_together = 0;
  for (int r = 0; r < rounds; ++r) {
    {
      const Timer t;
      for (size_t b = 0; b < kBatches; ++b) {
        for (size_t c = 0; c < kM; ++c) exprs[c].evaluate_batch(xs.data(), kN, outs[c]);
      }
      alone_cpu += t.cpu_seconds();
      for (const auto& o : out) check_alone += o[0];
    }
    {
      const Timer t;
      for (size_t b = 0; b < kBatches; ++b) set.evaluate_batch(xs.data(), kN, outs.data());
      together_cpu += t.cpu_seconds();
      for (const auto& o : out) check_together += o[0];
    }
  }
  const double evals = static_cast<double>(rounds) * kBatches * kN * kM;
  std::printf("\n%zu components of exp(s*(16 sines)), d = %zu: %zu instructions a batch one by one, %zu together\n",
              kM, kD, set.instructions_alone(), set.instructions_together());
  std::printf("  one by one: %.3g component evaluations per CPU second\n", evals / alone_cpu);
  std::printf("  together  : %.3g component evaluations per CPU second\n", evals / together_cpu);
  std::printf("  speed-up together / one by one: %.2fx (%d interleaved rounds; results %s)\n", alone_cpu / together_cpu,
              rounds, check_alone == check_together ? "bit-identical" : "DIFFER");
}

int main(int argc, char** argv) {
  size_t total = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : (size_t{1} << 24);
  total = (total + kChunk - 1) / kChunk * kChunk;
  const auto cols = make_points();
  const char* const expressions[] = {"x0*x0 + x1*x1 < 1 ? 4 : 0", "exp(-(x0*x0 + x1*x1))"};
  std::printf("expr_bench: %zu evaluations per measurement, %zu-point working set\n", total,
              kChunk);
  for (const char* text : expressions) {
    const auto e = tally::CompiledExpression::compile(text, kDims);
    std::printf("%s   (%zu instructions)\n", text, e.instruction_count());
    const Result scalar = muparser_scalar(text, cols, total / 4);
    const Result bulk = muparser_bulk(text, cols, total);
    report("muParser Eval() one point", scalar, scalar, bulk);
    report("muParser bulk Eval(out, 65536)", bulk, scalar, bulk);
    report("tally evaluate() one point", ours_point(e, cols, total / 4), scalar, bulk);
    for (size_t batch : {size_t{16}, size_t{64}, size_t{256}}) {
      const std::string name = "tally evaluate_batch(" + std::to_string(batch) + ")";
      report(name.c_str(), ours_batch(e, cols, total, batch), scalar, bulk);
    }
  }
  components_together(5);
  return 0;
}
