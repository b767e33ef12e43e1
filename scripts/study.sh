#!/usr/bin/env bash
# The accuracy-vs-time study (issue 5): builds tally-study, runs every section through
# the production engine, runs the SciPy peer on the same Genz instances, and writes
# docs/accuracy-vs-time.md with its plots and CSVs under docs/study/.
#   scripts/study.sh [BUILD_DIR]        (default build-study; QUICK=1 for a smoke run)
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build-study}
OUT=docs/study
PY=/usr/bin/python3   # Debian's python3-matplotlib / python3-scipy
[ -x "$PY" ] || PY=python3
if [ ! -f "$BUILD/build.ninja" ]; then
  cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release
fi
cmake --build "$BUILD" -j "${JOBS:-2}" --target tally-study
mkdir -p "$OUT"
ARGS=(--out "$OUT")
if [ "${QUICK:-0}" = 1 ]; then ARGS+=(--quick); fi
start=$(date +%s)
"$BUILD/bench/study/tally-study" "${ARGS[@]}"
"$PY" bench/peers/scipy_peer.py "$OUT"
"$PY" bench/study/plot.py "$OUT" docs/accuracy-vs-time.md
echo "study: done in $(( $(date +%s) - start )) s; see docs/accuracy-vs-time.md"
