#pragma once
// File descriptors: every connection holds one, so --max-connections must be
// reached before the process runs out (else accept fails with EMFILE).
#include <cstddef>

namespace tally {

// Raises the soft RLIMIT_NOFILE to the hard limit; returns the resulting soft limit.
size_t raise_fd_soft_limit();

// Largest number of connections `fd_soft_limit` descriptors can serve, keeping
// `reserve` for the database, files, the listener and the process. At least 1.
size_t connections_for_fd_limit(size_t requested, size_t fd_soft_limit, size_t reserve = 64);

}  // namespace tally
