#!/usr/bin/env bash
# Builds the tally-server image with podman and checks it end to end, on loopback only:
#   build (multi-stage, tests in the build stage) -> image size, no compiler inside
#   run with a named volume -> start-up time to /readyz -> HEALTHCHECK (tally health)
#   submit an integration job with the CLI from the host -> mean within 4 stderr of pi
#   submit a long job -> SIGTERM (podman stop -t 30) -> clean exit 0, checkpoint logged
#   new container on the same volume -> the finished job is there with a bit-identical
#   result, the long job resumed from its checkpoint (samples kept) -> cancel it
# Every wait is bounded; the containers and volume it made are removed on exit.
#
# Usage: docker/test-image.sh [--no-build] [--tests fast|all|none] [--keep]
# Environment: TALLY_IMAGE (default localhost/tally:test), TALLY_CLI (host CLI binary;
# default: the one in the image, copied out), TALLY_TEST_PORT (first port tried, 18080),
# JOBS (build parallelism, 2), CONTAINERS_CONF (default ../shared/containers/containers.conf).
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/.." && pwd)
build=1
tests=fast
keep=0
while [ $# -gt 0 ]; do
  case "$1" in
    --no-build) build=0 ;;
    --tests) tests=$2; shift ;;
    --keep) keep=1 ;;
    -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
    *) echo "test-image: unknown argument $1" >&2; exit 2 ;;
  esac
  shift
done

# shellcheck source=docker/test-lib.sh
. "$here/test-lib.sh"
use_shared_containers_conf "$repo"
image=${TALLY_IMAGE:-localhost/tally:test}
base_image=localhost/debian-min:bookworm
jobs=${JOBS:-2}
run_id=$$
name1=tally-test-$run_id-a
name2=tally-test-$run_id-b
volume=tally-test-data-$run_id
work=$(mktemp -d /tmp/tally-test-image.XXXXXX)

now() { date +%s.%N; }
elapsed() { python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.2f}')" "$1" "$2"; }

cleanup() {
  local rc=$?
  if [ "$keep" -eq 0 ]; then
    for c in "$name1" "$name2"; do timeout 60 podman rm -f -v -t 5 "$c" >/dev/null 2>&1 || true; done
    timeout 60 podman volume rm -f "$volume" >/dev/null 2>&1 || true
  else
    log "kept: containers $name1 $name2, volume $volume"
  fi
  rm -rf "$work"
  exit $rc
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# --- tools -------------------------------------------------------------------------
need=()
for p in podman buildah runc debootstrap uidmap fuse-overlayfs slirp4netns curl python3; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || need+=("$p")
done
if [ ${#need[@]} -gt 0 ]; then
  log "installing ${need[*]}"
  export DEBIAN_FRONTEND=noninteractive
  timeout 600 apt-get update -qq
  timeout 1200 apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi
log "podman $(podman --version | awk '{print $3}'), CONTAINERS_CONF=${CONTAINERS_CONF:-unset}"

# --- base image (no registry here: debootstrap from the Debian mirror) -------------
if ! podman image exists "$base_image"; then
  # The Debian mirror this machine's apt already uses (deb822 .sources or one-line .list files).
  mirror=$(cat /etc/apt/sources.list.d/debian.sources /etc/apt/sources.list.d/*.sources 2>/dev/null | awk '/^URIs:/{print $2; exit}' || true)
  [ -n "$mirror" ] || mirror=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null |
    awk '$1 == "deb" {for (i = 2; i <= NF; i++) if ($i ~ /^[a-z+]+:\/\//) {print $i; exit}}' || true)
  [ -n "$mirror" ] || die "no Debian mirror in /etc/apt/sources.list{,.d}: configure apt first"
  log "creating $base_image with debootstrap from $mirror"
  timeout 1200 debootstrap --variant=minbase bookworm "$work/rootfs" "$mirror" >"$work/debootstrap.log" 2>&1 ||
    { tail -20 "$work/debootstrap.log"; die "debootstrap failed"; }
  # Package lists and caches would stay in the lowest layer of every image: drop them.
  rm -rf "$work/rootfs/var/lib/apt/lists/"* "$work/rootfs/var/cache/apt/"*.bin "$work/rootfs/var/cache/apt/archives/"*.deb
  tar -C "$work/rootfs" -c . | timeout 600 podman import - "$base_image" >/dev/null
  rm -rf "$work/rootfs"
fi

# --- build -------------------------------------------------------------------------
if [ "$build" -eq 1 ]; then
  log "building $image (TESTS=$tests, JOBS=$jobs); log in $work/build.log"
  t0=$(now)
  if ! timeout 5400 nice -n 10 podman build --format docker --layers \
      --build-arg BASE="$base_image" --build-arg TESTS="$tests" --build-arg JOBS="$jobs" \
      -f "$repo/docker/Dockerfile" -t "$image" "$repo" >"$work/build.log" 2>&1; then
    tail -40 "$work/build.log"
    die "podman build failed"
  fi
  build_s=$(elapsed "$t0" "$(now)")
  grep -E 'tests passed|Test #|tests failed|^building:' "$work/build.log" | tail -3 | sed 's/^/    /'
  pass "image built in ${build_s}s"
else
  podman image exists "$image" || die "$image does not exist (drop --no-build)"
fi

size_bytes=$(podman image inspect --format '{{.Size}}' "$image")
size_mb=$((size_bytes / 1000 / 1000))
base_mb=$(( $(podman image inspect --format '{{.Size}}' "$base_image") / 1000 / 1000 ))
log "image size: ${size_mb} MB (base image ${base_mb} MB)"

cfg=$(podman image inspect --format '{{.Config.User}}|{{json .Config.Entrypoint}}|{{json .Config.ExposedPorts}}|{{json .Config.Volumes}}' "$image")
hc=$(podman image inspect --format '{{json .Config.Healthcheck}}' "$image" 2>/dev/null || echo null)
log "image config: $cfg"
case "$cfg" in 10001:10001\|*tini*) pass "non-root user 10001 and tini entrypoint" ;; *) fail "user/entrypoint: $cfg" ;; esac
if echo "$hc" | grep -q 'tally","health"'; then pass "HEALTHCHECK kept (docker format): $hc"; else fail "no HEALTHCHECK in image config: $hc"; fi
if found=$(timeout 60 podman run --rm --no-healthcheck --entrypoint /bin/sh "$image" -c \
    'for t in gcc g++ cc c++ clang cmake ld curl wget; do command -v $t; done; true'); [ -z "$found" ]; then
  pass "no compiler, linker or curl in the runtime image"
else
  fail "tools in the runtime image: $found"
fi

# --- the CLI on the host -----------------------------------------------------------
cli=${TALLY_CLI:-}
if [ -z "$cli" ]; then
  # The CLI that was built with this image, copied out (the host has the libraries).
  copy_cli_from_image "$image" "$work/tally"
  cli=$work/tally
fi
"$cli" --help >/dev/null || die "host CLI $cli does not run"
"$cli" --help | grep -q ' submit' || die "host CLI $cli has no submit command"
log "host CLI: $cli"

# --- run ---------------------------------------------------------------------------
port=$(free_port "${TALLY_TEST_PORT:-18080}")
url=http://127.0.0.1:$port
podman volume create "$volume" >/dev/null

# podman's periodic health checks need systemd timers, which this sandbox lacks: its
# complaints go to $work/podman.err, and the check runs with `podman healthcheck run`.
# The port is published on host loopback only, so this test runs the server without
# tokens (--insecure-no-auth); docker/test-compose.sh runs it with tokens and TLS.
create() {  # name -> container created (not started), hardened as in compose.yaml
  podman create --name "$1" -p "127.0.0.1:$port:8080" -v "$volume:/var/lib/tally" \
    --read-only --tmpfs /tmp --cap-drop ALL --security-opt no-new-privileges \
    --stop-timeout 30 "$image" --listen 0.0.0.0:8080 --data-dir /var/lib/tally --workers 2 --insecure-no-auth \
    >/dev/null 2>>"$work/podman.err"
}
wait_ready() {  # name -> prints "ready_s start_s": seconds from `podman start` to /readyz 200,
  # and to `podman start` returning (runtime and network set-up); bounded by 60 s
  local t0 t1 ts
  t0=$(now)
  podman start "$1" >/dev/null 2>>"$work/podman.err"
  ts=$(now)
  for _ in $(seq 1 1200); do
    if curl -fsS -m 1 -o /dev/null "$url/readyz" 2>/dev/null; then
      t1=$(now); echo "$(elapsed "$t0" "$t1") $(elapsed "$t0" "$ts")"; return 0
    fi
    [ "$(podman inspect --format '{{.State.Running}}' "$1")" = true ] || break
    sleep 0.05
  done
  podman logs "$1" | tail -20 >&2
  return 1
}
wait_healthy() {  # name -> 0 when the image's HEALTHCHECK passes; bounded by 30 s
  for _ in $(seq 1 30); do
    if podman healthcheck run "$1" >/dev/null 2>&1; then return 0; fi
    sleep 1
  done
  return 1
}
server_rss() {  # name -> VmRSS of tally-server in the container, kB
  podman exec "$1" sh -c 'for p in /proc/[0-9]*; do [ "$(cat $p/comm 2>/dev/null)" = tally-server ] && grep VmRSS $p/status; done' 2>/dev/null | awk '{print $2}'
}
status_json() { "$cli" get "$1" --json --server "$url"; }
field() {  # json-file path.to.field
  python3 -c 'import json,sys
v=json.load(open(sys.argv[1]))
for k in sys.argv[2].split("."): v=v[k] if isinstance(v,dict) else None
print(json.dumps(v) if isinstance(v,(dict,list)) else v)' "$1" "$2"
}

create "$name1"
read -r startup1 podstart1 < <(wait_ready "$name1") || true
[ -n "${startup1:-}" ] || die "container did not become ready within 60 s"
pass "start-up: ${startup1}s from podman start to /readyz 200 (podman start itself: ${podstart1}s; port $port, loopback only)"
log "server log: $(podman logs "$name1" 2>&1 | head -1)"
log "idle tally-server RSS: $(server_rss "$name1") kB"
if ! podman exec "$name1" /usr/local/bin/tally --help 2>&1 | grep -q ' health'; then
  fail "HEALTHCHECK: the image's CLI has no 'health' command (client/main.cpp must call add_health_command)"
elif wait_healthy "$name1"; then
  pass "HEALTHCHECK healthy: $(podman inspect --format '{{.State.Health.Status}}' "$name1" 2>/dev/null || true)"
else
  fail "HEALTHCHECK (tally health) did not pass within 30 s: $(podman exec "$name1" /usr/local/bin/tally health 2>&1 | head -2)"
fi
uid=$(podman exec "$name1" sh -c 'id -u' 2>/dev/null || true)
[ "$uid" = 10001 ] && pass "server runs as uid 10001" || fail "server uid: $uid"
pid1=$(podman exec "$name1" sh -c 'cat /proc/1/comm' 2>/dev/null || true)
[ "$pid1" = tini ] && pass "PID 1 is tini" || fail "PID 1 is '$pid1'"

# A job to completion, watched from the host.
cat >"$work/disk.json" <<'EOF'
{"kind": "integrate", "integrand": {"builtin": "unit_disk"}, "seed": 7, "stop": {"max_samples": 50000000}}
EOF
t0=$(now)
if ! timeout 300 "$cli" submit "$work/disk.json" --watch --server "$url" >"$work/submit.out" 2>"$work/submit.err"; then
  cat "$work/submit.err" | tail -5
  die "tally submit --watch failed"
fi
job=$(head -1 "$work/submit.out")
log "job $job finished in $(elapsed "$t0" "$(now)")s: $(tail -1 "$work/submit.err" | tr -d '\r' | cut -c1-160)"
status_json "$job" >"$work/job1.json"
state=$(field "$work/job1.json" state)
mean=$(field "$work/job1.json" estimate.mean)
se=$(field "$work/job1.json" estimate.std_error)
n=$(field "$work/job1.json" samples)
log "result: state=$state mean=$mean std_error=$se samples=$n"
if [ "$state" = succeeded ] && python3 -c 'import math,sys; m,s=map(float,sys.argv[1:3]); sys.exit(0 if s>0 and abs(m-math.pi)<=4*s else 1)' "$mean" "$se"; then
  pass "mean $mean within 4 stderr of pi (|mean-pi|/stderr = $(python3 -c 'import math,sys; print(f"{abs(float(sys.argv[1])-math.pi)/float(sys.argv[2]):.2f}")' "$mean" "$se"))"
else
  fail "job result: state=$state mean=$mean std_error=$se"
fi

# An image job: its EXR and PNG come from the image module, loaded on this first image.
python3 - "$repo/examples/lecture_lighting_image.json" >"$work/image.json" <<'EOF'
import json, sys
spec = json.load(open(sys.argv[1]))
spec["scene"]["camera"]["resolution"] = [32, 24]
spec["query"] = {"type": "image", "max_depth": 2, "tile_size": 16}
spec["stop"] = {"max_samples": 8}
print(json.dumps(spec))
EOF
if timeout 300 "$cli" submit "$work/image.json" --watch --server "$url" >"$work/image.out" 2>/dev/null &&
   ijob=$(head -1 "$work/image.out") &&
   timeout 60 "$cli" get "$ijob" --image "$work/out.exr" --server "$url" >/dev/null &&
   timeout 60 "$cli" get "$ijob" --image "$work/out.png" --server "$url" >/dev/null &&
   img=$(PYTHONPATH="$repo/client/python" python3 -c 'import sys; from tally_client import decode_exr
im = decode_exr(open(sys.argv[1], "rb").read()); png = open(sys.argv[2], "rb").read(8)
assert png == b"\x89PNG\r\n\x1a\n", png
assert (im.width, im.height) == (32, 24) and set(im.samples_flat) == {8.0} and sum(im.mean_flat) > 0
print(f"{im.width}x{im.height}, 8 spp, mean radiance {sum(im.mean_flat) / len(im.mean_flat):.4f}")' "$work/out.exr" "$work/out.png"); then
  pass "image job $ijob: EXR ($img) and PNG written by the image module"
else
  fail "image job: EXR/PNG output failed: $(tail -3 "$work/image.out" 2>/dev/null)"
fi
log "tally-server RSS after an integration and an image job: $(server_rss "$name1") kB"

# A long job that is still running when the container stops.
cat >"$work/long.json" <<'EOF'
{"kind": "integrate", "integrand": {"builtin": "unit_disk"}, "seed": 11, "stop": {"max_samples": 50000000000}}
EOF
timeout 30 "$cli" submit "$work/long.json" --server "$url" >"$work/long.out" || die "submitting the long job failed"
long=$(head -1 "$work/long.out")
long_before=0
for _ in $(seq 1 60); do
  status_json "$long" >"$work/long0.json"
  long_before=$(field "$work/long0.json" samples)
  [ "${long_before:-0}" -gt 0 ] && [ "$(field "$work/long0.json" state)" = running ] && break
  sleep 0.5
done
sleep 4
status_json "$long" >"$work/long0.json"
long_before=$(field "$work/long0.json" samples)
log "long job $long: $(field "$work/long0.json" state), $long_before samples before the stop"

# SIGTERM: tini forwards it, the server checkpoints and exits 0 well inside 30 s.
t0=$(now)
timeout 90 podman stop -t 30 "$name1" >/dev/null 2>>"$work/podman.err"
stop_s=$(elapsed "$t0" "$(now)")
code=$(podman inspect --format '{{.State.ExitCode}}' "$name1")
podman logs "$name1" >"$work/server1.log" 2>&1 || true
if [ "$code" = 0 ] && python3 -c 'import sys; sys.exit(0 if float(sys.argv[1]) < 25 else 1)' "$stop_s"; then
  pass "podman stop -t 30: exit code 0 after ${stop_s}s (SIGTERM, not SIGKILL)"
else
  fail "podman stop: exit code $code after ${stop_s}s"
fi
if grep -q 'checkpointing jobs' "$work/server1.log"; then
  pass "server logged: $(grep 'checkpointing jobs' "$work/server1.log" | head -1)"
else
  fail "no shutdown message in the server log"; tail -5 "$work/server1.log"
fi

# A new container on the same volume.
create "$name2"
read -r startup2 podstart2 < <(wait_ready "$name2") || true
[ -n "${startup2:-}" ] || die "second container did not become ready within 60 s"
pass "restart on the same volume: ${startup2}s from podman start to /readyz 200 (podman start itself: ${podstart2}s)"
t_ready2=$(now)
status_json "$long" >"$work/long1.json" || die "long job $long is gone after the restart"
since_start2=$(python3 -c 'import sys; print(f"{float(sys.argv[1]) + float(sys.argv[3]) - float(sys.argv[2]):.2f}")' "$startup2" "$t_ready2" "$(now)")
status_json "$job" >"$work/job2.json" || die "job $job is gone after the restart"
same=$(python3 - "$work/job1.json" "$work/job2.json" <<'EOF'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
keys = ["state", "samples", "estimate", "bits"]
print("yes" if all(a.get(k) == b.get(k) for k in keys) else
      "no: " + "; ".join(f"{k}: {a.get(k)} != {b.get(k)}" for k in keys if a.get(k) != b.get(k)))
EOF
)
if [ "$same" = yes ]; then
  pass "job $job still there after the restart, same state/samples/estimate/bits (mean $(field "$work/job2.json" estimate.mean))"
else
  fail "job $job changed across the restart: $same"
fi
# Resumed, not restarted: samples and compute time carry on from the checkpoint, and
# the compute time is more than the new container has been up.
long_state=$(field "$work/long1.json" state)
long_after=$(field "$work/long1.json" samples)
cs_before=$(field "$work/long0.json" compute_seconds)
cs_after=$(field "$work/long1.json" compute_seconds)
if [ "$long_state" != failed ] && python3 -c 'import sys
nb, na, cb, ca, up = map(float, sys.argv[1:6])
sys.exit(0 if na >= nb and ca >= cb > up else 1)' "$long_before" "$long_after" "$cs_before" "$cs_after" "$since_start2"; then
  pass "long job resumed from its checkpoint: $long_state, $long_after samples (>= $long_before before the stop), compute ${cs_after}s (>= ${cs_before}s before; container up ${since_start2}s)"
else
  fail "long job after restart: state=$long_state samples=$long_after compute=${cs_after}s (before: $long_before, ${cs_before}s; container up ${since_start2}s)"
fi
timeout 30 "$cli" cancel "$long" --server "$url" >/dev/null 2>&1 || true
timeout 30 "$cli" list --server "$url" >"$work/list.out" 2>&1 || true
log "tally list after the restart:"; sed 's/^/    /' "$work/list.out" | head -5

timeout 90 podman stop -t 30 "$name2" >/dev/null 2>>"$work/podman.err"
code2=$(podman inspect --format '{{.State.ExitCode}}' "$name2")
[ "$code2" = 0 ] && pass "second container stopped cleanly (exit 0)" || fail "second container exit code $code2"

log "summary: image ${size_mb} MB; start-up ${startup1}s (empty volume), ${startup2}s (restart with 2 jobs); stop ${stop_s}s"
log "test-image: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
