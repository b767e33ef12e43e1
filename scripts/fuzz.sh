#!/usr/bin/env bash
# Runs each libFuzzer target for a bounded time from the seed corpus.
# Usage: scripts/fuzz.sh BUILD_DIR SECONDS TARGET...
# A finding stops with the target's non-zero exit: the input is saved as
# BUILD_DIR/fuzz/<target>-crash-* (turn it into a unit test, tests/fuzz/README.md).
set -euo pipefail
build=$1 seconds=$2
shift 2
root=$(cd "$(dirname "$0")/.." && pwd)
out="$build/fuzz"
mkdir -p "$out"
for t in "$@"; do
  name=${t#fuzz_}
  seeds="$root/tests/fuzz/corpus/$name"
  work="$out/corpus/$name"
  mkdir -p "$work"
  echo "fuzz: $t for ${seconds}s (seeds: tests/fuzz/corpus/$name)"
  # -rss_limit_mb: a valid input may not need more; -timeout: one input, seconds.
  ASAN_OPTIONS=detect_leaks=0:abort_on_error=1 UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
    "$build/tests/fuzz/$t" "$work" "$seeds" -max_total_time="$seconds" -max_len=8192 -timeout=20 \
    -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="$out/$t-" 2>"$out/$t.log" ||
    { tail -n 60 "$out/$t.log"; echo "fuzz: $t found a problem (log: $out/$t.log)" >&2; exit 1; }
  grep -E "stat::number_of_executed_units|cov:" "$out/$t.log" | tail -n 2
done
