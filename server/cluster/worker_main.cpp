// tally-worker: a stateless compute process for cluster mode. See docs/cluster.md.
#include "server/cluster/worker.hpp"

int main(int argc, char** argv) { return tally::cluster::worker_main(argc, argv); }
