#!/bin/sh
# Builds and runs bench/server_bench (wrk against tally-server and a minimal Beast
# server; 0 vs 100 event-stream watchers). Usage: bench/wrk/server_bench.sh [build-dir] [wrk-duration]
set -eu
build=${1:-build}
duration=${2:-5s}
command -v wrk >/dev/null || { echo "wrk is not installed (apt-get install wrk)"; exit 2; }
cmake --build "$build" --target tally-server server_bench -j2
cd "$build"
./bench/server_bench ./server/tally-server "$duration"
