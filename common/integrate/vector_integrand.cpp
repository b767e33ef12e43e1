#include "common/integrate/vector_integrand.hpp"

#include <cstdint>

#include "common/expr/compiled_expression.hpp"
#include "common/expr/expr_parameters.hpp"

namespace tally {

namespace {

class VectorExpressionIntegrand final : public Integrand {
 public:
  using Parameters = std::vector<std::pair<std::string, std::vector<double>>>;
  // Keeps component 0 (evaluate_batch) and the set; the other compiled expressions are
  // dropped once the set is built (its programs are theirs or their residuals), and their
  // texts kept only when there is no template to describe them.
  explicit VectorExpressionIntegrand(std::vector<CompiledExpression> e, std::string tmpl = {},
                                     Parameters parameters = {})
      : first_(e.front()), together_(e), template_(std::move(tmpl)), parameters_(std::move(parameters)) {
    if (parameters_.empty()) {
      for (const auto& x : e) texts_.push_back(x.text());
    }
  }
  size_t dimensions() const override { return first_.dimensions(); }
  size_t components() const override { return together_.size(); }
  void evaluate_batch(const double* const* xs, size_t n, double* out) const override {
    first_.evaluate_batch(xs, n, out);
  }
  void evaluate_components(const double* const* xs, size_t n, double* const* out) const override {
    together_.evaluate_batch(xs, n, out);  // what the components share runs once
  }
  void evaluate_component_range(size_t first, size_t count, const double* const* xs, size_t n,
                                double* const* out) const override {
    together_.evaluate_batch(first, count, xs, n, out);
  }
  IntegrandInfo describe() const override {
    IntegrandInfo info;
    if (!parameters_.empty()) {  // the template and its values, not m bound texts
      info.expression = template_;
      info.parameters = parameters_;
      return info;
    }
    info.expressions = texts_;
    return info;
  }

 private:
  CompiledExpression first_;
  CompiledExpressionSet together_;  // every component, evaluated together
  std::vector<std::string> texts_;  // without a template: each component's text
  std::string template_;
  Parameters parameters_;
};

class GenzSet final : public Integrand {
 public:
  explicit GenzSet(const std::vector<GenzParams>& members) {
    for (const GenzParams& p : members) {
      fs_.push_back(make_genz(p));
      names_.emplace_back(genz_family_name(p.family));
    }
    a_ = members[0].a;
    u_ = members[0].u;
  }
  size_t dimensions() const override { return fs_[0]->dimensions(); }
  size_t components() const override { return fs_.size(); }
  void evaluate_batch(const double* const* xs, size_t n, double* out) const override {
    fs_[0]->evaluate_batch(xs, n, out);
  }
  void evaluate_components(const double* const* xs, size_t n, double* const* out) const override {
    for (size_t c = 0; c < fs_.size(); ++c) fs_[c]->evaluate_batch(xs, n, out[c]);
  }
  void evaluate_component_range(size_t first, size_t count, const double* const* xs, size_t n,
                           double* const* out) const override {
    for (size_t k = 0; k < count; ++k) fs_[first + k]->evaluate_batch(xs, n, out[k]);
  }
  IntegrandInfo describe() const override {
    return {.builtin = "genz", .families = names_, .a = a_, .u = u_};
  }

 private:
  std::vector<std::unique_ptr<Integrand>> fs_;
  std::vector<std::string> names_;
  std::vector<double> a_, u_;
};

}  // namespace

std::unique_ptr<Integrand> make_vector_expression_integrand(const std::vector<std::string>& texts,
                                                            size_t dimensions, size_t max_length) {
  ExprLimits limits;
  limits.max_length = max_length;
  std::vector<CompiledExpression> e;
  for (const std::string& t : texts) e.push_back(CompiledExpression::compile(t, dimensions, limits));
  return std::make_unique<VectorExpressionIntegrand>(std::move(e));
}

std::unique_ptr<Integrand> make_vector_expression_integrand(std::vector<CompiledExpression> compiled) {
  return std::make_unique<VectorExpressionIntegrand>(std::move(compiled));
}

std::unique_ptr<Integrand> make_parameterized_integrand(
    const std::string& text, const std::vector<std::pair<std::string, std::vector<double>>>& parameters,
    size_t dimensions, size_t max_length) {
  ExprLimits limits;
  limits.max_length = max_length;
  if (text.size() > max_length) {
    throw ExprError(ExprErrorKind::limit, "the expression is longer than " + std::to_string(max_length) + " characters");
  }
  // The template with every parameter bound to 1: names the grammar does not know and
  // syntax errors are reported once, at the template's own positions.
  // Bound texts are longer than the template (a literal per use): the template's own
  // length was checked by the spec reader; the bound texts' is not limited again.
  ExprLimits bound_limits = limits;
  bound_limits.max_length = SIZE_MAX;
  std::vector<expr::Parameter> bound;
  for (const auto& [name, values] : parameters) bound.push_back({name, 1.0});
  CompiledExpression::compile(expr::bind_parameters(text, bound), dimensions, bound_limits);
  const size_t m = parameters.front().second.size();
  std::vector<CompiledExpression> e;
  e.reserve(m);
  for (size_t c = 0; c < m; ++c) {
    for (size_t p = 0; p < parameters.size(); ++p) bound[p].value = parameters[p].second[c];
    e.push_back(CompiledExpression::compile(expr::bind_parameters(text, bound), dimensions, bound_limits));
  }
  return std::make_unique<VectorExpressionIntegrand>(std::move(e), text, parameters);
}

std::unique_ptr<Integrand> make_genz_set(const std::vector<GenzParams>& members) {
  return std::make_unique<GenzSet>(members);
}

std::vector<double> component_mean_covariance(const JobState& st, size_t m) {
  std::vector<double> cov(m * m, 0.0);
  if (st.channels.size() < m + m * (m - 1) / 2) return cov;
  auto var = [](const Tally& t) { return t.n > 1 ? t.variance() : 0.0; };
  for (size_t a = 0; a < m; ++a) {
    const double n = static_cast<double>(std::max<uint64_t>(1, st.channels[a].n));
    cov[a * m + a] = var(st.channels[a]) / n;
  }
  size_t ch = m;
  for (size_t a = 0; a < m; ++a) {
    for (size_t c = a + 1; c < m; ++c, ++ch) {
      const double n = static_cast<double>(std::max<uint64_t>(1, st.channels[ch].n));
      const double v = 0.5 * (var(st.channels[ch]) - var(st.channels[a]) - var(st.channels[c])) / n;
      cov[a * m + c] = cov[c * m + a] = v;
    }
  }
  return cov;
}

}  // namespace tally
