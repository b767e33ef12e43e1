#pragma once
// Vector integrands: several functions evaluated at the same points (Cuba's ncomp),
// one estimate per component. Integrand::components() says how many; component 0 is
// what evaluate_batch returns, so scalar code paths see the first function.
#include <memory>
#include <string>
#include <vector>

#include "common/engine/job_state.hpp"
#include "common/expr/compiled_expression.hpp"
#include "common/integrate/genz.hpp"
#include "common/integrate/integrand.hpp"

namespace tally {

// User expressions in muParser syntax over x0..x{d-1}; throws ExprError naming the
// failing one's text.
std::unique_ptr<Integrand> make_vector_expression_integrand(const std::vector<std::string>& texts,
                                                            size_t dimensions, size_t max_length);
// The same from expressions already compiled (at least one, all of one dimension).
std::unique_ptr<Integrand> make_vector_expression_integrand(std::vector<CompiledExpression> compiled);
// One expression over x0..x{d-1} and named parameters, component c binding every
// parameter to its c-th value (common/expr/expr_parameters.hpp); all value lists have
// the same length. Throws ExprError for the template (a syntax error, an unknown name).
std::unique_ptr<Integrand> make_parameterized_integrand(
    const std::string& text, const std::vector<std::pair<std::string, std::vector<double>>>& parameters,
    size_t dimensions, size_t max_length);
// Several Genz families sharing a and u (built-in vector integrand).
std::unique_ptr<Integrand> make_genz_set(const std::vector<GenzParams>& members);

// Covariance of the component means from the pair channels (channel m + index of the
// pair (a, c), a < c, in row order, holds f_a + f_c):
// cov(a, c) = (Var(f_a + f_c) - Var(f_a) - Var(f_c)) / 2 / n. Row-major m x m.
std::vector<double> component_mean_covariance(const JobState& state, size_t m);

}  // namespace tally
