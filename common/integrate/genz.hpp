#pragma once
// The six Genz test families on [0,1]^d with their closed-form integrals
// (../shared/references/genz.md; Genz 1984, Cuba's test suite).
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "common/integrate/integrand.hpp"

namespace tally {

enum class GenzFamily { oscillatory, product_peak, corner_peak, gaussian, continuous, discontinuous };

std::string_view genz_family_name(GenzFamily f);
// nullopt for an unknown name.
std::optional<GenzFamily> parse_genz_family(std::string_view name);
const std::vector<std::string>& genz_family_names();

struct GenzParams {
  GenzFamily family = GenzFamily::oscillatory;
  std::vector<double> a;  // difficulty, a_i > 0
  std::vector<double> u;  // shift, u_i in [0, 1]
};

std::unique_ptr<Integrand> make_genz(const GenzParams& p);
// Exact integral over [0,1]^d (corner peak summed in long double; keep d <= 10).
double genz_exact(const GenzParams& p);
// Direct evaluation of one point (tests, reference).
double genz_value(const GenzParams& p, const double* x);

// Cuba's benchmark convention: u ~ U(0,1)^d, w ~ U(0,1)^d, a = w * h / sum(w) with the
// family difficulty h = (6.0, 18.0, 2.2, 15.2, 16.1, 16.4).
GenzParams genz_random_instance(GenzFamily f, size_t d, uint64_t seed);

}  // namespace tally
