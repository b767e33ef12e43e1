#!/usr/bin/env bash
# make bench: scripts/bench.sh BUILD_DIR [NAME ...]
# Runs the benchmarks in bench/ one after another; each prints its own figures (ratios
# measured in one run, never a lone absolute time: docs/performance.md). With no NAME it
# runs the default set below; NAME picks from every benchmark (`scripts/bench.sh build
# list` lists them). A benchmark that fails is reported and the others still run; the exit
# status is 1 if any failed. Some need tools the tests do not (blender for the Cycles
# columns, wrk, redis-server); they say so and skip what they cannot measure.
set -u
build=${1:?usage: scripts/bench.sh BUILD_DIR [NAME ...]}
shift
root=$(cd "$(dirname "$0")/.." && pwd)
b=$build/bench

# name | what it measures | command (run from the repository root)
benches=(
  "integrate|samples/s of the unit-disk integral vs GSL plain|$b/integrate_bench 16777216 5"
  "expr|user expressions vs muParser|$b/expr_bench"
  "vector|10,000 integrands as one job vs a loop of jobs|$b/vector_bench 10000 200 3"
  "lighting|direct-lighting rate vs bare Embree; estimators|$b/lighting_bench"
  "frame_memory|bytes per pixel of an image job vs Cycles|$b/frame_memory_bench"
  "server|requests/s vs a bare Beast server; watchers|$b/server_bench $build/server/tally-server"
  "assets|1M-triangle upload and render through the server|$b/assets/asset_bench 5"
  "cluster|in-process vs Redis workers at equal cores|$b/cluster/cluster_bench"
  "farm|preemption latency and result-cache latency|$b/farm/farm_bench"
  "frame_4k|a 4K frame through the server: kill -9, resume, EXR|python3 $root/bench/frame_4k_e2e.py --build $build"
  "boundary_stall|request latency while a 1080p frame merges its passes|python3 $root/bench/boundary_stall.py --build $build"
  "auto_pilot_memo|a 1,000-component auto spec: validate, then submit (pilot remembered)|python3 $root/bench/auto_pilot_memo.py --build $build"
  "higher_order_nets|interlaced vs plain scrambled Sobol' sd, d 2-16|python3 $root/bench/higher_order_nets.py --build $build"
  "scene_suite|tally vs Cycles on the five suite scenes, depths 1/4/8 (~20-30 min)|python3 $root/bench/scene_suite/suite.py --build $build"
  "scene_suite_quick|the scene suite at 64x48, depth 4, 16/64 spp (~1-3 min)|python3 $root/bench/scene_suite/suite.py --build $build --quick"
)
default=(integrate expr vector lighting frame_memory scene_suite_quick)

if [ "${1:-}" = "list" ]; then
  for e in "${benches[@]}"; do IFS='|' read -r n what _ <<<"$e"; printf '%-14s %s\n' "$n" "$what"; done
  exit 0
fi
want=("$@")
[ ${#want[@]} -eq 0 ] && want=("${default[@]}")

cd "$root" || exit 1
failed=()
for n in "${want[@]}"; do
  found=
  for e in "${benches[@]}"; do
    IFS='|' read -r name what cmd <<<"$e"
    [ "$name" = "$n" ] || continue
    found=1
    printf '\n== %s: %s\n$ %s\n' "$name" "$what" "$cmd"
    # shellcheck disable=SC2086  # the command line is split on spaces on purpose
    if ! $cmd; then failed+=("$name"); fi
  done
  if [ -z "$found" ]; then
    echo "scripts/bench.sh: no benchmark named '$n' (scripts/bench.sh $build list)" >&2
    failed+=("$n")
  fi
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "scripts/bench.sh: failed: ${failed[*]}" >&2
  exit 1
fi
