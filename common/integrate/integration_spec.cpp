#include "common/integrate/integration_spec.hpp"

#include <bit>
#include <cmath>
#include <fmt/format.h>
#include <numbers>
#include <optional>
#include <string_view>

#include "common/engine/component_targets.hpp"
#include "common/engine/job_state.hpp"
#include "common/expr/compiled_expression.hpp"
#include "common/expr/expr_parameters.hpp"
#include "common/integrate/domain.hpp"
#include "common/integrate/estimators.hpp"
#include "common/integrate/genz.hpp"
#include "common/integrate/integrand.hpp"
#include "common/integrate/vector_integrand.hpp"
#include "common/integrate/auto_estimator.hpp"
#include "common/integrate/cone_rule.hpp"
#include "common/integrate/cubature.hpp"
#include "common/integrate/vegas.hpp"
#include "common/sampling/qmc.hpp"
#include "common/spec/pool_field.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/spec/state_limit_error.hpp"
#include "common/spec/stop_rule_json.hpp"
#include "common/sampling/ball_simplex.hpp"

namespace tally {

using nlohmann::json;

namespace {



struct ParsedIntegrand {
  std::shared_ptr<const Integrand> f;
  std::optional<GenzParams> genz;
  std::string builtin;  // empty for expressions
  std::string expression;
  std::vector<std::string> expressions;  // a vector integrand
  // A parameterized expression: one component per position of the value lists.
  std::vector<std::pair<std::string, std::vector<double>>> parameters;
  std::optional<bool> covariance;  // as asked; default: m <= kDefaultCovarianceComponents
  size_t dims = 0;  // 0: take the domain's
};

// Vector integrands up to this many components keep the covariance of their means
// unless told otherwise (m (m - 1) / 2 pair channels: 2,016 at 64); larger ones only
// when asked, so that memory stays linear in the component count.
constexpr size_t kDefaultCovarianceComponents = 64;
constexpr size_t kMaxVegasComponents = 64;

// "parameters": {"a": [...], "b": [...]}: names the grammar leaves free, lists of one
// common length (the component count), finite values.
void parse_parameters(SpecReader& r, const JobLimits& limits, ParsedIntegrand& out) {
  const json& obj = r.at("parameters");
  const std::string ptr = r.pointer_of("parameters");
  SpecReader pr(obj, ptr);
  if (obj.empty()) throw SpecError(ptr, "must name at least one parameter");
  if (obj.size() > 16) throw SpecError(ptr, "may name at most 16 parameters");
  size_t count = 0;
  for (const auto& [name, values] : obj.items()) {
    const std::string why = expr::check_parameter_name(name);
    if (!why.empty()) throw SpecError(json_pointer_append(ptr, name), "parameter name " + why);
    std::vector<double> v = pr.numbers(name, 1, limits.max_components, -1e300, 1e300);
    if (count != 0 && v.size() != count) {
      throw SpecError(json_pointer_append(ptr, name),
                      fmt::format("has {} values; every parameter needs the same count ({})", v.size(), count));
    }
    count = v.size();
    out.parameters.emplace_back(name, std::move(v));
  }
  pr.finish();
}

ParsedIntegrand parse_integrand(SpecReader r, const JobLimits& limits) {
  ParsedIntegrand out;
  const bool has_expr = r.has("expression");
  const bool has_exprs = r.has("expressions");
  const bool has_builtin = r.has("builtin");
  if (int{has_expr} + int{has_exprs} + int{has_builtin} != 1) {
    throw SpecError(r.pointer(), "needs exactly one of \"expression\", \"expressions\" or \"builtin\"");
  }
  if (r.has("covariance")) out.covariance = r.boolean_or("covariance", false);
  if (r.has("parameters") && !has_expr) {
    throw SpecError(r.pointer_of("parameters"), "applies to one \"expression\" (the template it binds)");
  }
  const size_t max_components = limits.max_components;
  if (has_exprs) {
    const json& a = r.at("expressions");
    const std::string ptr = r.pointer_of("expressions");
    if (!a.is_array() || a.empty() || a.size() > max_components) {
      throw SpecError(ptr, fmt::format("must be an array of 1 to {} expression strings", max_components));
    }
    for (size_t i = 0; i < a.size(); ++i) {
      if (!a[i].is_string()) throw SpecError(json_pointer_append(ptr, i), "must be a string");
      std::string t = a[i].get<std::string>();
      if (t.size() > limits.max_expression_length) {
        throw SpecError(json_pointer_append(ptr, i),
                        fmt::format("is longer than {} characters", limits.max_expression_length));
      }
      out.expressions.push_back(std::move(t));
    }
    r.finish();
    return out;  // compiled once the domain fixes the dimension
  }
  if (has_expr) {
    out.expression = r.string("expression", limits.max_expression_length);
    if (r.has("parameters")) parse_parameters(r, limits, out);
    r.finish();
    return out;  // compiled once the domain fixes the dimension
  }
  out.builtin = r.enumeration("builtin", {"unit_disk", "inv_sqrt", "genz"});
  if (out.builtin == "unit_disk") {
    out.f = make_unit_disk_indicator();
    out.dims = 2;
  } else if (out.builtin == "inv_sqrt") {
    out.f = make_inv_sqrt();
    out.dims = 1;
  } else if (r.has("families")) {
    // A built-in vector integrand: several Genz families sharing a and u.
    const json& fams = r.at("families");
    const std::string ptr = r.pointer_of("families");
    if (!fams.is_array() || fams.empty() || fams.size() > max_components) {
      throw SpecError(ptr, fmt::format("must be an array of 1 to {} Genz family names", max_components));
    }
    GenzParams p;
    p.a = r.numbers("a", 1, limits.max_dimensions, 1e-9, 1e6);
    p.u = r.has("u") ? r.numbers("u", 1, limits.max_dimensions, 0.0, 1.0) : std::vector<double>(p.a.size(), 0.5);
    if (p.u.size() != p.a.size()) {
      throw SpecError(r.pointer_of("u"), fmt::format("must have as many entries as a ({}), got {}",
                                                     p.a.size(), p.u.size()));
    }
    std::vector<GenzParams> members;
    for (size_t i = 0; i < fams.size(); ++i) {
      const auto f = fams[i].is_string() ? parse_genz_family(fams[i].get<std::string>()) : std::nullopt;
      if (!f) {
        throw SpecError(json_pointer_append(ptr, i),
                        fmt::format("must be one of {}", fmt::join(genz_family_names(), ", ")));
      }
      if (*f == GenzFamily::corner_peak && p.a.size() > 20) {
        throw SpecError(r.pointer_of("a"), "corner_peak supports at most 20 dimensions");
      }
      p.family = *f;
      members.push_back(p);
    }
    out.dims = p.a.size();
    out.f = make_genz_set(members);
  } else {
    GenzParams p;
    p.family = *parse_genz_family(r.enumeration("family", genz_family_names()));
    p.a = r.numbers("a", 1, limits.max_dimensions, 1e-9, 1e6);
    if (r.has("u")) {
      p.u = r.numbers("u", 1, limits.max_dimensions, 0.0, 1.0);
    } else {
      p.u.assign(p.a.size(), 0.5);
    }
    if (p.u.size() != p.a.size()) {
      throw SpecError(r.pointer_of("u"), fmt::format("must have as many entries as a ({}), got {}",
                                                     p.a.size(), p.u.size()));
    }
    if (p.family == GenzFamily::corner_peak && p.a.size() > 20) {
      throw SpecError(r.pointer_of("a"), "corner_peak supports at most 20 dimensions");
    }
    out.dims = p.a.size();
    out.f = make_genz(p);
    out.genz = p;
  }
  r.finish();
  return out;
}

std::shared_ptr<const Domain> parse_domain(const json* node, const std::string& pointer,
                                           const ParsedIntegrand& in, const JobLimits& limits) {
  if (node == nullptr) {
    // Defaults that make the built-ins mean what their names say.
    if (in.builtin == "unit_disk") return make_box({-1.0, -1.0}, {1.0, 1.0});
    if (in.builtin == "inv_sqrt") return make_box({0.0}, {1.0});
    if (in.builtin == "genz") return make_box(std::vector<double>(in.dims, 0.0), std::vector<double>(in.dims, 1.0));
    throw SpecError(pointer, "is required for an expression integrand");
  }
  SpecReader r(*node, pointer);
  const std::string type =
      r.enumeration("type", {"interval", "box", "disk", "ball", "sphere", "hemisphere", "simplex"});
  constexpr double kBig = 1e150;
  std::shared_ptr<const Domain> d;
  if (type == "interval") {
    const double lo = r.number("lower", -kBig, kBig);
    const double hi = r.number("upper", -kBig, kBig);
    if (!(hi > lo)) throw SpecError(r.pointer_of("upper"), "must be greater than lower");
    d = make_box({lo}, {hi});
  } else if (type == "box") {
    auto lo = r.numbers("lower", 1, limits.max_dimensions, -kBig, kBig);
    auto hi = r.numbers("upper", 1, limits.max_dimensions, -kBig, kBig);
    if (lo.size() != hi.size()) {
      throw SpecError(r.pointer_of("upper"), fmt::format("must have as many entries as lower ({})", lo.size()));
    }
    for (size_t k = 0; k < lo.size(); ++k) {
      if (!(hi[k] > lo[k])) {
        throw SpecError(json_pointer_append(r.pointer_of("upper"), k), "must be greater than lower");
      }
    }
    d = make_box(std::move(lo), std::move(hi));
  } else if (type == "disk") {
    auto c = r.has("center") ? r.numbers("center", 2, 2, -kBig, kBig) : std::vector<double>{0.0, 0.0};
    const double radius = r.number_or("radius", 1.0, 1e-300, kBig);
    d = make_disk(c[0], c[1], radius);
  } else if (type == "ball") {
    const size_t dims = r.integer_or("dimensions", 3, 1, std::min<size_t>(limits.max_dimensions, kMaxBallSimplexDim));
    auto c = r.has("center") ? r.numbers("center", dims, dims, -kBig, kBig) : std::vector<double>(dims, 0.0);
    d = make_ball(std::move(c), r.number_or("radius", 1.0, 1e-300, kBig));
  } else if (type == "sphere" || type == "hemisphere") {
    auto c = r.has("center") ? r.numbers("center", 3, 3, -kBig, kBig) : std::vector<double>(3, 0.0);
    d = make_sphere_surface(std::move(c), r.number_or("radius", 1.0, 1e-300, kBig), type == "hemisphere");
  } else {
    const size_t dims = r.integer("dimensions", 1, std::min<size_t>(limits.max_dimensions, kMaxBallSimplexDim));
    d = make_simplex(dims);
  }
  r.finish();
  if (in.dims != 0 && in.dims != d->dimensions()) {
    throw SpecError(pointer, fmt::format("has {} dimensions but the built-in integrand {} takes {}",
                                         d->dimensions(), in.builtin, in.dims));
  }
  return d;
}

struct EstimatorChoice {
  std::shared_ptr<const Kernel> kernel;
  EstimatorPlan plan;
  bool sweep = false;   // one sample = one point set
  bool deterministic = false;
};

// The qmc and lattice estimators with their plans (from their own spec fields or from auto).
void use_qmc(EstimatorChoice& c, const IntegrationProblem& prob, uint32_t points, const std::string& scramble,
             uint32_t interlacing = 1) {
  c.plan.sequence = scramble == "owen" ? "sobol (nested uniform Owen scramble, Joe-Kuo directions)"
                                       : "sobol (random linear scramble + digital shift, Joe-Kuo directions)";
  if (interlacing > 1) {
    c.plan.sequence = fmt::format(
        "interlaced sobol of order {0} (the digits of {0} x d dimensions of a random linear scramble + digital "
        "shift, Joe-Kuo directions, taken in turn)",
        interlacing);
    c.plan.interlacing = interlacing;
  }
  c.plan.scramble = scramble;
  c.plan.points_per_sample = points;
  c.kernel = make_qmc_kernel(prob, points, scramble == "owen", interlacing);
  c.sweep = true;
}

// The cone rule's options from the stop rule (both forms): a scalar integrand, the
// evaluation cap max_samples within [2^m_min, most] (the largest 2^m within it), the targets.
ConeRuleOptions cone_options(SpecReader& r, const IntegrationProblem& prob, const StopRule& stop,
                             bool stop_has_max_samples, uint64_t most, std::string_view why_most) {
  if (prob.integrand->components() > 1) {
    throw SpecError(r.pointer_of("error"), fmt::format("the cone rule takes a scalar integrand, not {} components; "
                                                       "vector integrands use the randomizations' error bar",
                                                       prob.integrand->components()));
  }
  ConeRuleOptions o;
  o.m_max = static_cast<uint32_t>(std::min<int>(static_cast<int>(o.m_max), std::bit_width(most) - 1));
  if (stop_has_max_samples) {
    if (stop.max_samples < (uint64_t{1} << o.m_min) || stop.max_samples > most) {
      throw SpecError("/stop/max_samples", fmt::format("the cone rule evaluates between {} and {} points ({}); got {}",
                                                       uint64_t{1} << o.m_min, most, why_most, stop.max_samples));
    }
    o.m_max = static_cast<uint32_t>(std::bit_width(stop.max_samples) - 1);  // the largest 2^m within the cap
  }
  o.abs_error = stop.abs_error;
  o.rel_error = stop.rel_error;
  return o;
}

// `"error": "cone"`: one scrambled Sobol' sequence, points doubling until the cone rule's
// bound (cone_rule.hpp) meets the stop rule's abs_error or rel_error, up to max_samples
// evaluations (one block: bounded like cubature's).
void use_cone_rule(EstimatorChoice& c, SpecReader& r, const IntegrationProblem& prob, const StopRule& stop,
                   bool stop_has_max_samples) {
  for (const char* field : {"points", "scramble", "interlacing"}) {
    if (r.has(field)) {
      throw SpecError(r.pointer_of(field),
                      "the cone rule takes no points, scramble or interlacing: it doubles one affinely scrambled "
                      "Sobol' sequence from 1024 points up to the stop rule's max_samples");
    }
  }
  ConeRuleOptions o = cone_options(r, prob, stop, stop_has_max_samples, kMaxConeEvaluations,
                                   "one block, 12 bytes a point, so that cancel stays prompt and memory bounded");
  if (prob.domain->uniforms() > kRqmcMaxDimensions) {
    throw SpecError(r.pointer_of("type"), fmt::format("qmc supports at most {} dimensions", kRqmcMaxDimensions));
  }
  c.plan.sequence = "sobol (random linear scramble + digital shift, Joe-Kuo directions), natural order";
  c.plan.scramble = "affine";
  c.plan.rule = fmt::format(
      "cone rule (Hickernell & Jimenez Rugama, cubSobol_g): one randomization, 2^{}..2^{} points doubling until "
      "{} * 2^-m * (sum of |Walsh coefficients| {} levels below) meets the target",
      o.m_min, o.m_max, o.fudge, o.lag);
  c.plan.max_evaluations = uint64_t{1} << o.m_max;
  c.plan.error = "bound from the Walsh coefficients, guaranteed for integrands in the cone (not a confidence "
                 "interval; whether an integrand is in the cone is not checked)";
  c.kernel = make_cone_kernel(prob, o);
  c.deterministic = true;
}

// `"type": "lattice", "error": "cone"`: the embedded lattice (built for 2^20 points),
// points doubling until the cone rule's Fourier bound meets the target, up to max_samples.
void use_lattice_cone_rule(EstimatorChoice& c, SpecReader& r, const IntegrationProblem& prob, const StopRule& stop,
                           bool stop_has_max_samples, const std::vector<double>& weights, const std::string& per,
                           size_t max_dimensions) {
  if (r.has("points")) {
    throw SpecError(r.pointer_of("points"),
                    "the lattice cone rule takes no points: it doubles one embedded lattice from 1024 points up to "
                    "the stop rule's max_samples");
  }
  ConeRuleOptions o = cone_options(r, prob, stop, stop_has_max_samples, uint64_t{1} << kLatticeConeLog2,
                                   fmt::format("one embedded lattice of 2^{}", kLatticeConeLog2));
  o.basis = ConeBasis::fourier;
  if (prob.domain->uniforms() > max_dimensions) {
    throw SpecError(r.pointer_of("error"),
                    fmt::format("the lattice cone rule supports at most {} dimensions (its embedded CBC costs about "
                                "0.1 s of CPU a dimension); got {}",
                                max_dimensions, prob.domain->uniforms()));
  }
  // Always the 2^20 rule, whatever the cap: a smaller cap takes its first points.
  const auto rule = embedded_lattice_rule_remembered(o.m_min, kLatticeConeLog2, weights);
  c.plan.construction = fmt::format(
      "embedded rank-1 lattice, 2^{}..2^{} points in radical-inverse order, generating vector by fast "
      "component-by-component construction (Cools-Kuo-Nuyens) minimising the worst ratio of P_2 to the best at "
      "each 2^m, for product weights; one uniform shift",
      o.m_min, kLatticeConeLog2);
  c.plan.periodize = per;
  c.plan.generating_vector.assign(rule->z.begin(), rule->z.end());
  c.plan.weights = weights;
  c.plan.worst_case_error = rule->worst_case_error.back();
  c.plan.rule = fmt::format(
      "cone rule (Jimenez Rugama & Hickernell, cubLattice_g): one shift, 2^{}..2^{} points doubling until "
      "{} * 2^-m * (sum of |Fourier coefficients| {} levels below) meets the target",
      o.m_min, o.m_max, o.fudge, o.lag);
  c.plan.max_evaluations = uint64_t{1} << o.m_max;
  c.plan.error = "bound from the Fourier coefficients, guaranteed for integrands in the cone (not a confidence "
                 "interval; whether an integrand is in the cone is not checked)";
  c.kernel = make_lattice_cone_kernel(prob, *rule,
                                      per == "none" ? Periodization::none
                                                    : (per == "baker" ? Periodization::baker : Periodization::cubic),
                                      o);
  c.deterministic = true;
}

// `rule`: one already built for (n, weights) (the auto pilot's), else CBC builds it.
void use_lattice(EstimatorChoice& c, const IntegrationProblem& prob, uint32_t n, const std::vector<double>& weights,
                 const std::string& per, std::optional<LatticeRule> rule = std::nullopt) {
  if (!rule) rule = cbc_lattice_rule(n, weights);
  c.plan.construction =
      "rank-1 lattice, prime n, generating vector by fast component-by-component construction (Nuyens-Cools) "
      "minimising P_2 for product weights; one independent uniform shift per sample";
  c.plan.periodize = per;
  c.plan.points_per_sample = n;
  c.plan.generating_vector.assign(rule->z.begin(), rule->z.end());
  c.plan.weights = weights;
  c.plan.worst_case_error = rule->worst_case_error;
  c.kernel = make_lattice_kernel(prob, std::move(*rule),
                                 per == "none" ? Periodization::none
                                               : (per == "baker" ? Periodization::baker : Periodization::cubic));
  c.sweep = true;
}

// `spec` is the whole job spec (auto's pilot memo is keyed by it).
EstimatorChoice parse_estimator(const json& spec, const json* node, const std::string& pointer,
                                IntegrationProblem prob, const JobLimits& limits, const StopRule& stop,
                                bool stop_has_max_samples) {
  const Domain& D = *prob.domain;
  EstimatorChoice c;
  const bool vector = prob.integrand->components() > 1;
  // Vector integrands run on the VEGAS kernel (all components at the same points);
  // "uniform" is that kernel with its grid frozen uniform.
  auto frozen_uniform = [&](const std::string& where) {
    if (!D.is_box()) {
      throw SpecError(where, fmt::format("vector integrands need an interval or box domain, not {}", D.type()));
    }
    VegasOptions vo;
    vo.bins = 2;
    vo.alpha = 0.0;
    vo.warmup_passes = 0;
    vo.weighted = false;  // one fixed grid: every sample has the same distribution
    c.kernel = make_vegas_kernel(prob, vo);
    c.plan.type = "uniform";
    c.plan.components = prob.integrand->components();
  };
  if (node == nullptr) {
    if (vector) {
      frozen_uniform("/domain");
      return c;
    }
    c.kernel = make_uniform_kernel(prob);
    c.plan.type = "uniform";
    return c;
  }
  SpecReader r(*node, pointer);
  const std::string type =
      r.enumeration("type", {"uniform", "importance", "stratified", "qmc", "lattice", "auto", "rejection", "quadrature",
                              "vegas", "cubature"});
  c.plan.type = type;
  auto need_box = [&](const char* what) {
    if (!D.is_box()) {
      throw SpecError(r.pointer_of("type"),
                      fmt::format("{} needs an interval or box domain, not {}", what, D.type()));
    }
  };
  if (vector && type != "uniform" && type != "vegas" && type != "cubature" && type != "qmc" && type != "lattice" &&
      type != "auto") {
    throw SpecError(r.pointer_of("type"), fmt::format("vector integrands support the uniform, qmc, lattice, auto, "
                                                      "vegas and cubature estimators, not {}", type));
  }
  const size_t m = prob.integrand->components();
  if (type == "vegas" && m > kMaxVegasComponents) {
    // The grid is steered by per-component bin sums: m x dimensions x bins doubles a block.
    throw SpecError(r.pointer_of("type"),
                    fmt::format("vegas steers its grid with every component's bin sums and supports at most {} "
                                "components; {} components run with uniform, qmc or lattice",
                                kMaxVegasComponents, m));
  }
  if (vector) c.plan.components = m;
  if (type == "uniform" && vector) {
    frozen_uniform(r.pointer_of("type"));
  } else if (type == "uniform") {
    c.kernel = make_uniform_kernel(prob);
  } else if (type == "importance") {
    SpecReader dr = r.object("density");
    const std::string dt = dr.enumeration("type", {"power", "tabulated", "cosine"});
    if (dt == "power") {
      need_box("importance sampling with a power density");
      PowerDensity pd;
      const json& e = dr.at("exponent");
      if (e.is_array()) {
        pd.exponents = dr.numbers("exponent", D.dimensions(), D.dimensions(), -0.999, 1e3);
      } else {
        pd.exponents.assign(D.dimensions(), dr.number("exponent", -0.999, 1e3));
      }
      c.plan.density = DensityPlan{.type = "power", .exponent = pd.exponents, .cells = std::nullopt};
      c.kernel = make_power_importance_kernel(prob, std::move(pd));
    } else if (dt == "tabulated") {
      need_box("importance sampling with a tabulated density");
      if (D.dimensions() > 2) {
        throw SpecError(dr.pointer_of("type"), "tabulated densities are 1-D or 2-D");
      }
      TabulatedDensity td;
      td.values = dr.numbers("values", 1, limits.max_table_size, 0.0, 1e300);
      if (D.dimensions() == 2) {
        td.nu = dr.integer("nu", 1, limits.max_table_size);
        td.nv = td.values.size() / td.nu;
        if (td.nu * td.nv != td.values.size()) {
          throw SpecError(dr.pointer_of("values"),
                          fmt::format("must have nu * nv entries; {} is not a multiple of nu = {}",
                                      td.values.size(), td.nu));
        }
      } else {
        td.nu = td.values.size();
      }
      double sum = 0.0;
      for (double v : td.values) sum += v;
      if (!(sum > 0.0)) throw SpecError(dr.pointer_of("values"), "must be positive somewhere");
      c.plan.density = DensityPlan{.type = "tabulated", .exponent = {}, .cells = td.values.size()};
      c.kernel = make_tabulated_importance_kernel(prob, std::move(td));
    } else {
      if (D.type() != "hemisphere") {
        throw SpecError(dr.pointer_of("type"), "the cosine density needs a hemisphere domain");
      }
      c.plan.density = DensityPlan{.type = "cosine", .exponent = {}, .cells = std::nullopt};
      c.kernel = make_cosine_importance_kernel(prob);
    }
    dr.finish();
  } else if (type == "stratified") {
    need_box("stratified sampling");
    const uint32_t k = static_cast<uint32_t>(r.integer_or("strata_per_dim", 4, 2, 1024));
    // Stratify as many leading dimensions as keep a sweep at most 2^16 points.
    uint32_t s_max = 0;
    uint64_t pts = 1;
    while (s_max < D.dimensions() && pts * k <= (uint64_t{1} << 16)) {
      pts *= k;
      ++s_max;
    }
    const uint32_t s = static_cast<uint32_t>(r.integer_or("stratified_dims", s_max, 1, s_max));
    uint64_t points = 1;
    for (uint32_t i = 0; i < s; ++i) points *= k;
    c.plan.strata_per_dim = k;
    c.plan.stratified_dims = s;
    c.plan.points_per_sample = points;
    c.kernel = make_stratified_kernel(prob, k, s);
    c.sweep = true;
  } else if (type == "qmc" && r.enumeration_or("error", "randomizations", {"randomizations", "cone"}) == "cone") {
    use_cone_rule(c, r, prob, stop, stop_has_max_samples);
  } else if (type == "qmc") {
    const uint32_t points = static_cast<uint32_t>(r.integer_or("points", 1024, 1, kMaxQmcPoints));
    if (D.uniforms() > 1024) throw SpecError(pointer, "qmc supports at most 1024 dimensions");
    const std::string scramble = r.enumeration_or("scramble", "affine", {"affine", "owen"});
    const auto interlacing = static_cast<uint32_t>(r.integer_or("interlacing", 1, 1, 3));
    if (interlacing > 1 && scramble == "owen") {
      throw SpecError(r.pointer_of("interlacing"), "interlacing needs the affine scramble, not owen");
    }
    if (static_cast<uint64_t>(interlacing) * D.uniforms() > kRqmcMaxDimensions) {
      throw SpecError(r.pointer_of("interlacing"),
                      fmt::format("interlacing {} x {} dimensions exceeds the {} Sobol' dimensions", interlacing,
                                  D.uniforms(), kRqmcMaxDimensions));
    }
    // One sample is one whole point set, computed by one block: bound its work so
    // cancel and shutdown (which act between blocks) stay prompt (an interlaced set
    // draws interlacing x dimensions Sobol' coordinates a point).
    const uint64_t coordinates = static_cast<uint64_t>(interlacing) * D.uniforms();
    if (static_cast<uint64_t>(points) * coordinates > kMaxSweepCoordinates) {
      throw SpecError(r.pointer_of("points"),
                      fmt::format("points x dimensions = {} x {} exceeds {} coordinates per point set", points,
                                  coordinates, kMaxSweepCoordinates));
    }
    use_qmc(c, prob, points, scramble, interlacing);
  } else if (type == "lattice") {
    const uint32_t U = D.uniforms();
    const bool cone = r.enumeration_or("error", "randomizations", {"randomizations", "cone"}) == "cone";
    std::vector<double> weights(U, kDefaultLatticeWeight);
    if (r.has("weights")) {
      if (r.at("weights").is_array()) {
        weights = r.numbers("weights", U, U, 1e-12, 1e3);
      } else {
        weights.assign(U, r.number("weights", 1e-12, 1e3));
      }
    }
    const std::string per = r.enumeration_or("periodize", "baker", {"none", "baker", "cubic"});
    if (cone) {
      use_lattice_cone_rule(c, r, prob, stop, stop_has_max_samples, weights, per,
                            std::min<size_t>(limits.max_embedded_lattice_dimensions, kMaxLatticeConeDimensions));
    } else {
      const auto requested = static_cast<uint32_t>(r.integer_or("points", 1021, 5, kMaxLatticePoints));
      const uint32_t n = largest_prime_at_most(requested);
      if (static_cast<uint64_t>(n) * U > kMaxSweepCoordinates) {
        throw SpecError(r.pointer_of("points"),
                        fmt::format("points x dimensions = {} x {} exceeds {} coordinates per point set", n, U,
                                    kMaxSweepCoordinates));
      }
      use_lattice(c, prob, n, weights, per);
    }
  } else if (type == "auto") {
    if (vector) need_box("auto with a vector integrand");
    if (D.uniforms() > 1024) throw SpecError(r.pointer_of("type"), "auto supports at most 1024 dimensions");
    PilotLatticeRules pilot_rules;
    // The spec determines the problem (no file is read) and, with the parsed targets
    // (limits may fill them), the stop rule: the pilot's answer is remembered by both.
    const std::string key = fmt::format("{}|{:a}|{:a}|{:a}", spec.dump(), stop.abs_error, stop.rel_error,
                                        stop.confidence);
    AutoSelection sel = select_estimator_remembered(key, prob, stop, &pilot_rules);
    const AutoCandidate& w = sel.candidates[sel.chosen];
    if (w.estimator == "uniform" && vector) {
      frozen_uniform(r.pointer_of("type"));
    } else if (w.estimator == "uniform") {
      c.kernel = make_uniform_kernel(prob);
    } else if (w.estimator == "qmc") {
      use_qmc(c, prob, static_cast<uint32_t>(w.points), "affine");
    } else {
      const auto n = static_cast<uint32_t>(w.points);
      std::optional<LatticeRule> built;
      if (auto it = pilot_rules.find(n); it != pilot_rules.end()) built = std::move(it->second);
      use_lattice(c, prob, n, std::vector<double>(D.uniforms(), kDefaultLatticeWeight), w.periodize, std::move(built));
    }
    c.plan.type = w.estimator;
    c.plan.selection = std::move(sel);
  } else if (type == "vegas") {
    need_box("vegas");
    VegasOptions vo;
    vo.bins = static_cast<uint32_t>(r.integer_or("bins", vo.bins, 2, 4096));
    vo.alpha = r.number_or("alpha", vo.alpha, 0.0, 10.0);
    vo.warmup_passes = static_cast<uint32_t>(r.integer_or("warmup_passes", vo.warmup_passes, 0, 64));
    vo.max_pass_samples = r.integer_or("max_pass_samples", vo.max_pass_samples, 4096, uint64_t{1} << 26);
    vo.weighted = r.enumeration_or("combine", "weighted", {"weighted", "pooled"}) == "weighted";
    vo.stratify = r.boolean_or("stratify", vo.stratify);
    vo.beta = r.number_or("beta", vo.beta, 0.0, 1.0);
    if (vo.stratify && !vo.weighted) {
      throw SpecError(r.pointer_of("combine"), "stratify needs the weighted combination (a stratified pass's samples "
                                               "do not all have the same distribution)");
    }
    if (!vo.stratify && r.has("beta")) throw SpecError(r.pointer_of("beta"), "applies only with \"stratify\": true");
    c.plan.stratify = vo.stratify;
    if (vo.stratify) {
      c.plan.beta = vo.beta;
      const uint32_t ns = vegas_strata_per_axis(D.dimensions());
      c.plan.strata_per_axis = ns;
      c.plan.stratification = fmt::format(
          "VEGAS+: {}^{} hypercubes; each round of {} samples gives every hypercube 2 samples plus a share of the "
          "rest proportional to sigma_h^beta from the previous pass",
          ns, D.dimensions(), kVegasRound);
    }
    c.plan.bins = vo.bins;
    c.plan.alpha = vo.alpha;
    c.plan.warmup_passes = vo.warmup_passes;
    c.plan.max_pass_samples = vo.max_pass_samples;
    c.plan.combine = vo.weighted ? "weighted" : "pooled";
    c.plan.combination = vo.weighted ? "inverse-variance weighted mean of the passes after the warm-up; "
                                          "chi^2/dof across them checked"
                                        : "samples of the passes after the warm-up pooled with equal weight; "
                                          "chi^2/dof across passes checked";
    if (vector) {
      c.plan.components = prob.integrand->components();
      c.plan.steering = "sum over components of each one's per-bin (f/p)^2, normalized to 1 per component";
    }
    c.kernel = make_vegas_kernel(prob, vo);
  } else if (type == "cubature") {
    need_box("cubature");
    if (D.dimensions() > kMaxCubatureDimensions) {
      throw SpecError(r.pointer_of("type"), fmt::format("cubature supports at most {} dimensions, the domain has {}",
                                                        kMaxCubatureDimensions, D.dimensions()));
    }
    CubatureOptions co;
    co.p_adaptive = r.enumeration_or("rule", "h", {"h", "p"}) == "p";
    // One evaluation of the integrand is one "sample" of the stop rule's max_samples.
    if (stop_has_max_samples) {
      if (stop.max_samples > kMaxCubatureEvaluations) {
        throw SpecError("/stop/max_samples",
                        fmt::format("cubature runs at most {} evaluations (one block, so that cancel stays "
                                    "prompt); got {}", kMaxCubatureEvaluations, stop.max_samples));
      }
      co.max_evaluations = stop.max_samples;
    }
    co.abs_error = stop.abs_error;
    co.rel_error = stop.rel_error;
    c.plan.rule = co.p_adaptive ? "pcubature (p-adaptive nested Clenshaw-Curtis)"
                                : "hcubature (h-adaptive Genz-Malik degree 7/5)";
    c.plan.max_evaluations = co.max_evaluations;
    c.plan.error = "error estimate of the rule (not a confidence interval)";
    if (vector) c.plan.components = prob.integrand->components();
    c.kernel = make_cubature_kernel(prob, co);
    c.deterministic = true;
  } else if (type == "rejection") {
    if (D.is_box() || !D.is_solid()) {
      throw SpecError(r.pointer_of("type"),
                      fmt::format("rejection sampling needs a disk, ball or simplex domain, not {}", D.type()));
    }
    const uint32_t cap = static_cast<uint32_t>(r.integer_or("max_attempts", 1000, 1, 1000000));
    c.plan.max_attempts = cap;
    c.kernel = make_rejection_kernel(prob, cap);
  } else {
    need_box("quadrature");
    r.enumeration_or("rule", "trapezoid", {"trapezoid"});
    const uint64_t n = r.integer_or("points_per_dim", 65, 3, 1u << 24);
    double total = 1.0;
    for (size_t k = 0; k < D.dimensions(); ++k) total *= static_cast<double>(n);
    if (total > static_cast<double>(limits.max_quadrature_points)) {
      throw SpecError(r.pointer_of("points_per_dim"),
                      fmt::format("{}^{} = {:.3g} points exceeds the limit of {}", n, D.dimensions(),
                                  total, limits.max_quadrature_points));
    }
    c.plan.rule = "trapezoid";
    c.plan.points_per_dim = n;
    c.plan.points = total;
    c.kernel = make_trapezoid_kernel(prob, static_cast<uint32_t>(n));
    c.deterministic = true;
  }
  r.finish();
  return c;
}

// Closed forms for the built-ins on their natural domains (tests, study, result).
std::optional<double> reference_value(const ParsedIntegrand& in, const Domain& D) {
  if (in.builtin == "genz" && in.genz && D.is_box()) {
    for (size_t k = 0; k < D.dimensions(); ++k) {
      if (D.lower()[k] != 0.0 || D.upper()[k] != 1.0) return std::nullopt;
    }
    return genz_exact(*in.genz);
  }
  if (in.builtin == "unit_disk" && D.is_box()) {
    if (D.lower()[0] <= -1 && D.lower()[1] <= -1 && D.upper()[0] >= 1 && D.upper()[1] >= 1) {
      return std::numbers::pi;
    }
  }
  if (in.builtin == "inv_sqrt" && D.is_box() && D.lower()[0] >= 0.0) {
    return 2.0 * (std::sqrt(D.upper()[0]) - std::sqrt(D.lower()[0]));
  }
  return std::nullopt;
}

// The stop rule's per-component targets fit the integrand: one entry per component, on a
// vector integrand, with an estimator that samples (cubature runs one rule for all).
void check_component_targets(const StopRule& stop, size_t m, bool deterministic) {
  if (!stop.component_targets) return;
  const std::string where = "/stop/component_targets";
  if (m == 1) {
    throw SpecError(where, "needs a vector integrand (expressions, parameters or families); a scalar one has "
                           "abs_error and rel_error");
  }
  if (deterministic) {
    throw SpecError(where, "cubature runs one rule with one abs_error and rel_error for every component; "
                           "per-component targets need a sampling estimator");
  }
  const ComponentTargets& t = *stop.component_targets;
  for (const auto& [key, list] : {std::pair{"abs_error", &t.abs_error}, std::pair{"rel_error", &t.rel_error}}) {
    if (!list->empty() && list->size() != m) {
      throw SpecError(json_pointer_append(where, key),
                      fmt::format("has {} entries; the integrand has {} components", list->size(), m));
    }
  }
}

}  // namespace

std::unique_ptr<IntegrationJob> compile_integration_job(const json& spec, const JobLimits& limits) {
  SpecReader top(spec, "");
  top.string("kind");
  top.string_or("name", "", 200);
  read_pool(top);  // every kind takes a worker pool (cluster mode)
  IntegrationJob::Setup job;
  job.seed = top.integer_or("seed", 1, 0, std::numeric_limits<uint64_t>::max());

  ParsedIntegrand in = parse_integrand(top.object("integrand"), limits);
  const json* dom = top.find("domain");
  std::shared_ptr<const Domain> domain = parse_domain(dom, "/domain", in, limits);
  if (domain->dimensions() > limits.max_dimensions) {
    throw SpecError("/domain", fmt::format("has {} dimensions; the limit is {}", domain->dimensions(),
                                           limits.max_dimensions));
  }
  if (!in.f && !in.expressions.empty()) {
    ExprLimits el;
    el.max_length = limits.max_expression_length;
    std::vector<CompiledExpression> compiled;
    compiled.reserve(in.expressions.size());
    for (size_t i = 0; i < in.expressions.size(); ++i) {
      try {
        compiled.push_back(CompiledExpression::compile(in.expressions[i], domain->dimensions(), el));
      } catch (const ExprError& e) {
        throw SpecError(json_pointer_append("/integrand/expressions", i), e.what());
      }
    }
    in.f = make_vector_expression_integrand(std::move(compiled));
  }
  if (!in.f && !in.parameters.empty()) {
    try {
      in.f = make_parameterized_integrand(in.expression, in.parameters, domain->dimensions(),
                                          limits.max_expression_length);
    } catch (const ExprError& e) {
      throw SpecError("/integrand/expression", e.what());
    }
  }
  if (!in.f) {
    try {
      in.f = make_expression_integrand(in.expression, domain->dimensions(), limits.max_expression_length);
    } catch (const ExprError& e) {
      throw SpecError("/integrand/expression", e.what());
    }
  }
  const size_t m = in.f->components();
  const bool covariance = m > 1 && in.covariance.value_or(m <= kDefaultCovarianceComponents);
  if (covariance && job_state_bytes(m + m * (m - 1) / 2, 1) > limits.max_state_bytes) {
    throw StateLimitError("/integrand/covariance",
                          fmt::format("the covariance of {} components needs {} channels, {} bytes of job state; the "
                                "limit is {} bytes",
                                m, m + m * (m - 1) / 2, job_state_bytes(m + m * (m - 1) / 2, 1),
                                limits.max_state_bytes));
  }
  IntegrationProblem prob{in.f, domain, job.seed, covariance};
  SpecReader stop = top.object("stop");
  job.stop = parse_stop_rule(stop, limits);
  EstimatorChoice est =
      parse_estimator(spec, top.find("estimator"), "/estimator", prob, limits, job.stop, stop.has("max_samples"));
  check_component_targets(job.stop, m, est.deterministic);
  if (est.deterministic) {
    job.stop.max_samples = 1;
    job.stop.min_samples = 1;  // one rule: its error estimate decides at once
  } else if (est.sweep && !stop.has("min_samples")) {
    job.stop.min_samples = 16;  // point sets, not points: 16 randomizations suffice for a t interval
  }
  top.finish();

  job.kernel = est.kernel;
  job.integrand = in.f;
  job.domain = domain;
  job.estimator = std::move(est.plan);
  job.sweep = est.sweep;
  job.deterministic = est.deterministic;
  job.reference = reference_value(in, *domain);
  return std::make_unique<IntegrationJob>(std::move(job));
}

}  // namespace tally
