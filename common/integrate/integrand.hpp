#pragma once
// f in the integral of f over a domain. Integrands are evaluated in batches of
// structure-of-arrays points (xs[dimension][i]) so that both built-ins and compiled
// user expressions run as tight, vectorizable loops.
#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace tally {

inline constexpr size_t kIntegrandBatch = 256;

// What an integrand is, for plans and results (common/protocol writes it as JSON).
// Fields not set are absent.
struct IntegrandInfo {
  // Every member has a default initializer: describe() sets only the ones that apply, by
  // designated initializer (GCC 12's -Wmissing-field-initializers names the rest otherwise).
  std::string builtin{};                    // "unit_disk" | "inv_sqrt" | "genz"; empty for expressions
  std::optional<std::string> expression{};  // a scalar user expression
  std::vector<std::string> expressions{};   // a vector of user expressions
  std::string family{};                     // genz: one family ...
  std::vector<std::string> families{};      // ... or several (a vector integrand)
  std::vector<double> a{}, u{};             // genz parameters
  // A parameterized expression (`expression` is its template): name, one value per component.
  std::vector<std::pair<std::string, std::vector<double>>> parameters{};
};

class Integrand {
 public:
  virtual ~Integrand() = default;
  virtual size_t dimensions() const = 0;
  // xs[k] holds n <= kIntegrandBatch values of coordinate k; writes n values to out.
  virtual void evaluate_batch(const double* const* xs, size_t n, double* out) const = 0;
  // Vector integrands (several functions at the same points): components() values per
  // point, component c's n values to out[c]. Default: one component, evaluate_batch.
  virtual size_t components() const { return 1; }
  virtual void evaluate_components(const double* const* xs, size_t n, double* const* out) const {
    evaluate_batch(xs, n, out[0]);
  }
  // Components [first, first + count) (n values of component first + k to out[k]), for
  // callers that consume a few at a time and so need count batch buffers, not
  // components() of them. Default: one component, evaluate_batch.
  virtual void evaluate_component_range(size_t /*first*/, size_t /*count*/, const double* const* xs, size_t n,
                                   double* const* out) const {
    evaluate_batch(xs, n, out[0]);
  }
  virtual IntegrandInfo describe() const = 0;
};

// The lecture's first example: 1 inside the unit disk, 0 outside (2-D).
std::unique_ptr<Integrand> make_unit_disk_indicator();
// 1/sqrt(x0) (1-D): infinite variance under uniform sampling on (0, 1].
std::unique_ptr<Integrand> make_inv_sqrt();
// A user expression in muParser syntax over x0..x{d-1}; throws ExprError.
std::unique_ptr<Integrand> make_expression_integrand(const std::string& text, size_t dimensions,
                                                     size_t max_length);

}  // namespace tally
