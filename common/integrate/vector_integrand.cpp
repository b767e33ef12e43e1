#include "common/integrate/vector_integrand.hpp"

#include "common/expr/compiled_expression.hpp"

namespace tally {

namespace {

class VectorExpressionIntegrand final : public Integrand {
 public:
  explicit VectorExpressionIntegrand(std::vector<CompiledExpression> e) : exprs_(std::move(e)) {}
  size_t dimensions() const override { return exprs_[0].dimensions(); }
  size_t components() const override { return exprs_.size(); }
  void evaluate_batch(const double* const* xs, size_t n, double* out) const override {
    exprs_[0].evaluate_batch(xs, n, out);
  }
  void evaluate_components(const double* const* xs, size_t n, double* const* out) const override {
    for (size_t c = 0; c < exprs_.size(); ++c) exprs_[c].evaluate_batch(xs, n, out[c]);
  }
  IntegrandInfo describe() const override {
    IntegrandInfo info;
    for (const auto& e : exprs_) info.expressions.push_back(e.text());
    return info;
  }

 private:
  std::vector<CompiledExpression> exprs_;
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
