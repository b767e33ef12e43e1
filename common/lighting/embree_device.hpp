#pragma once
// One Embree device per process, created on first use (function-local static: C++
// guarantees thread-safe initialisation). Embree reports errors through a callback on
// the thread that made the failing call; we keep the first message per thread so that
// scene compilation can throw it and a kernel block can turn it into a SampleFault.
#include <embree3/rtcore.h>

#include <optional>
#include <string>

namespace tally {

RTCDevice embree_device();  // throws std::runtime_error if Embree cannot start

// The first Embree error raised on this thread since the last call, if any.
std::optional<std::string> take_embree_error();

}  // namespace tally
