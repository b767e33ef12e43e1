#pragma once
// The default error summary (Kernel::error_summary) over any span of channels, for
// kernels whose state holds more than the channels a stop rule should look at (e.g. a
// vector integrand's pair channels, kept only for the covariance of the means).
#include <span>

#include "common/engine/kernel.hpp"

namespace tally {

// The worst half-width and the worst relative half-width, each at the channel's own
// critical value (Student t with n - 1 degrees of freedom); infinite while a channel
// has fewer than 2 samples.
ErrorSummary worst_channel_summary(std::span<const Tally> channels, double confidence);
// Each channel's half-width (the same critical value; infinite below 2 samples) and mean.
std::vector<ComponentError> channel_errors(std::span<const Tally> channels, double confidence);

}  // namespace tally
