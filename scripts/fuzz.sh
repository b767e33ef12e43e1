#!/usr/bin/env bash
# Runs each libFuzzer target for a bounded time from the seed corpus (make fuzz, CI).
# Usage: scripts/fuzz.sh BUILD_DIR SECONDS TARGET...
# A finding (crash, sanitizer report, leak, an input slower than 20 s, more than 2 GB)
# stops with the target's non-zero exit: the input is saved as BUILD_DIR/fuzz/<target>-*
# (turn it into a unit test, tests/fuzz/README.md). The sanitizer options come from the
# environment (the Makefile exports them); the defaults below are for a run by hand.
set -euo pipefail
build=$1 seconds=$2
shift 2
root=$(cd "$(dirname "$0")/.." && pwd)
out="$build/fuzz"
mkdir -p "$out"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:halt_on_error=1:abort_on_error=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$root/tests/sanitize/lsan.supp:print_suppressions=0}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1:suppressions=$root/tests/sanitize/ubsan.supp}
for t in "$@"; do
  name=${t#fuzz_}
  seeds="$root/tests/fuzz/corpus/$name"
  work="$out/corpus/$name"
  mkdir -p "$work"
  echo "fuzz: $t for ${seconds}s (seeds: tests/fuzz/corpus/$name)"
  # -rss_limit_mb: a valid input may not need more; -timeout: one input, seconds.
  "$build/tests/fuzz/$t" "$work" "$seeds" -max_total_time="$seconds" -max_len=8192 -timeout=20 \
    -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="$out/$t-" 2>"$out/$t.log" ||
    { tail -n 60 "$out/$t.log"; echo "fuzz: $t found a problem (log: $out/$t.log)" >&2; exit 1; }
  grep -E "stat::number_of_executed_units|stat::peak_rss_mb" "$out/$t.log" | tr '\n' ' '
  grep -E "^#[0-9]+.*(DONE|cov:)" "$out/$t.log" | tail -n 1
done
