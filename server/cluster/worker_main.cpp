// tally-worker: a stateless compute process for cluster mode. See docs/cluster.md.
#include <malloc.h>

#include "server/cluster/worker.hpp"

int main(int argc, char** argv) {
  // Every entry's results (~100-600 KB) and hiredis's buffers for them are allocated and
  // freed again: with glibc's defaults each came from a fresh mmap or a trimmed arena,
  // and was page-faulted in page by page (perf: ~10 % of the worker's CPU in faults and
  // copies). Keep them in the arenas instead: a worker's memory is bounded by a few
  // entries per thread anyway.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
  return tally::cluster::worker_main(argc, argv);
}
