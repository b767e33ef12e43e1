#include "common/integrate/genz.hpp"

#include <cmath>
#include <numbers>
#include <stdexcept>

#include "common/rng/counter_rng.hpp"

namespace tally {

namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;

class Genz final : public Integrand {
 public:
  explicit Genz(GenzParams p) : p_(std::move(p)) {}
  size_t dimensions() const override { return p_.a.size(); }

  void evaluate_batch(const double* const* xs, size_t n, double* out) const override {
    const size_t d = p_.a.size();
    const auto& a = p_.a;
    const auto& u = p_.u;
    switch (p_.family) {
      case GenzFamily::oscillatory: {
        for (size_t i = 0; i < n; ++i) out[i] = kTwoPi * u[0];
        for (size_t k = 0; k < d; ++k)
          for (size_t i = 0; i < n; ++i) out[i] += a[k] * xs[k][i];
        for (size_t i = 0; i < n; ++i) out[i] = std::cos(out[i]);
        break;
      }
      case GenzFamily::product_peak: {
        for (size_t i = 0; i < n; ++i) out[i] = 1.0;
        for (size_t k = 0; k < d; ++k) {
          const double inv_a2 = 1.0 / (a[k] * a[k]);
          for (size_t i = 0; i < n; ++i) {
            const double t = xs[k][i] - u[k];
            out[i] /= inv_a2 + t * t;
          }
        }
        break;
      }
      case GenzFamily::corner_peak: {
        for (size_t i = 0; i < n; ++i) out[i] = 1.0;
        for (size_t k = 0; k < d; ++k)
          for (size_t i = 0; i < n; ++i) out[i] += a[k] * xs[k][i];
        const double e = -static_cast<double>(d + 1);
        for (size_t i = 0; i < n; ++i) out[i] = std::pow(out[i], e);
        break;
      }
      case GenzFamily::gaussian: {
        for (size_t i = 0; i < n; ++i) out[i] = 0.0;
        for (size_t k = 0; k < d; ++k) {
          const double a2 = a[k] * a[k];
          for (size_t i = 0; i < n; ++i) {
            const double t = xs[k][i] - u[k];
            out[i] -= a2 * t * t;
          }
        }
        for (size_t i = 0; i < n; ++i) out[i] = std::exp(out[i]);
        break;
      }
      case GenzFamily::continuous: {
        for (size_t i = 0; i < n; ++i) out[i] = 0.0;
        for (size_t k = 0; k < d; ++k)
          for (size_t i = 0; i < n; ++i) out[i] -= a[k] * std::fabs(xs[k][i] - u[k]);
        for (size_t i = 0; i < n; ++i) out[i] = std::exp(out[i]);
        break;
      }
      case GenzFamily::discontinuous: {
        for (size_t i = 0; i < n; ++i) out[i] = 0.0;
        for (size_t k = 0; k < d; ++k)
          for (size_t i = 0; i < n; ++i) out[i] += a[k] * xs[k][i];
        for (size_t i = 0; i < n; ++i) {
          const bool outside = xs[0][i] > u[0] || (d > 1 && xs[1][i] > u[1]);
          out[i] = outside ? 0.0 : std::exp(out[i]);
        }
        break;
      }
    }
  }

  IntegrandInfo describe() const override {
    return {.builtin = "genz", .family = std::string(genz_family_name(p_.family)), .a = p_.a, .u = p_.u};
  }

 private:
  GenzParams p_;
};

}  // namespace

std::string_view genz_family_name(GenzFamily f) {
  switch (f) {
    case GenzFamily::oscillatory: return "oscillatory";
    case GenzFamily::product_peak: return "product_peak";
    case GenzFamily::corner_peak: return "corner_peak";
    case GenzFamily::gaussian: return "gaussian";
    case GenzFamily::continuous: return "continuous";
    case GenzFamily::discontinuous: return "discontinuous";
  }
  return "unknown";
}

const std::vector<std::string>& genz_family_names() {
  static const std::vector<std::string> names = {"oscillatory", "product_peak", "corner_peak",
                                                 "gaussian",    "continuous",   "discontinuous"};
  return names;
}

std::optional<GenzFamily> parse_genz_family(std::string_view name) {
  for (int i = 0; i < 6; ++i) {
    const auto f = static_cast<GenzFamily>(i);
    if (genz_family_name(f) == name) return f;
  }
  return std::nullopt;
}

std::unique_ptr<Integrand> make_genz(const GenzParams& p) {
  if (p.a.empty() || p.a.size() != p.u.size()) throw std::invalid_argument("genz: a and u must have the same, non-zero length");
  return std::make_unique<Genz>(p);
}

double genz_value(const GenzParams& p, const double* x) {
  Genz g(p);
  std::vector<const double*> xs(p.a.size());
  for (size_t k = 0; k < xs.size(); ++k) xs[k] = x + k;
  double out = 0.0;
  g.evaluate_batch(xs.data(), 1, &out);
  return out;
}

double genz_exact(const GenzParams& p) {
  const size_t d = p.a.size();
  const auto& a = p.a;
  const auto& u = p.u;
  switch (p.family) {
    case GenzFamily::oscillatory: {
      double sum_a = 0.0, prod = 1.0;
      for (size_t i = 0; i < d; ++i) {
        sum_a += a[i];
        prod *= 2.0 * std::sin(a[i] / 2.0) / a[i];
      }
      return std::cos(kTwoPi * u[0] + 0.5 * sum_a) * prod;
    }
    case GenzFamily::product_peak: {
      double prod = 1.0;
      for (size_t i = 0; i < d; ++i) prod *= a[i] * (std::atan(a[i] * (1.0 - u[i])) + std::atan(a[i] * u[i]));
      return prod;
    }
    case GenzFamily::corner_peak: {
      // Alternating sum over the 2^d cube vertices; long double limits the cancellation.
      long double sum = 0.0L;
      for (uint64_t v = 0; v < (uint64_t{1} << d); ++v) {
        long double s = 1.0L;
        int bits = 0;
        for (size_t i = 0; i < d; ++i) {
          if (v & (uint64_t{1} << i)) {
            s += static_cast<long double>(a[i]);
            ++bits;
          }
        }
        sum += ((bits & 1) ? -1.0L : 1.0L) / s;
      }
      long double denom = 1.0L;
      for (size_t i = 0; i < d; ++i) denom *= static_cast<long double>(i + 1) * static_cast<long double>(a[i]);
      return static_cast<double>(sum / denom);
    }
    case GenzFamily::gaussian: {
      double prod = 1.0;
      for (size_t i = 0; i < d; ++i) {
        prod *= std::sqrt(std::numbers::pi) / (2.0 * a[i]) *
                (std::erf(a[i] * (1.0 - u[i])) + std::erf(a[i] * u[i]));
      }
      return prod;
    }
    case GenzFamily::continuous: {
      double prod = 1.0;
      for (size_t i = 0; i < d; ++i) {
        prod *= (2.0 - std::exp(-a[i] * u[i]) - std::exp(-a[i] * (1.0 - u[i]))) / a[i];
      }
      return prod;
    }
    case GenzFamily::discontinuous: {
      double prod = 1.0;
      for (size_t i = 0; i < d; ++i) {
        const double upper = i < 2 ? u[i] : 1.0;
        prod *= std::expm1(a[i] * upper) / a[i];
      }
      return prod;
    }
  }
  return 0.0;
}

GenzParams genz_random_instance(GenzFamily f, size_t d, uint64_t seed) {
  static constexpr double kDifficulty[6] = {6.0, 18.0, 2.2, 15.2, 16.1, 16.4};
  GenzParams p;
  p.family = f;
  p.a.resize(d);
  p.u.resize(d);
  const uint64_t key = stream_key(seed, 0x6e7a + static_cast<uint64_t>(f));
  SampleRng rng(key, d);
  double sum_w = 0.0;
  for (size_t i = 0; i < d; ++i) {
    p.u[i] = rng.uniform(static_cast<uint32_t>(2 * i));
    p.a[i] = rng.open_uniform(static_cast<uint32_t>(2 * i + 1));
    sum_w += p.a[i];
  }
  for (double& w : p.a) w *= kDifficulty[static_cast<int>(f)] / sum_w;
  return p;
}

}  // namespace tally
