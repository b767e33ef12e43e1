#include "server/http/fd_limit.hpp"

#include <sys/resource.h>

#include <algorithm>

namespace tally {

size_t raise_fd_soft_limit() {
  rlimit rl{};
  if (getrlimit(RLIMIT_NOFILE, &rl) != 0) return 1024;
  if (rl.rlim_cur < rl.rlim_max) {
    rlimit want = rl;
    want.rlim_cur = rl.rlim_max;
    if (setrlimit(RLIMIT_NOFILE, &want) == 0) rl = want;
  }
  return rl.rlim_cur == RLIM_INFINITY ? static_cast<size_t>(1) << 20 : static_cast<size_t>(rl.rlim_cur);
}

size_t connections_for_fd_limit(size_t requested, size_t fd_soft_limit, size_t reserve) {
  const size_t usable = fd_soft_limit > reserve + 1 ? fd_soft_limit - reserve : 1;
  return std::max<size_t>(1, std::min(requested, usable));
}

}  // namespace tally
