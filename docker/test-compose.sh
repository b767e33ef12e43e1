#!/usr/bin/env bash
# Runs docker/compose.yaml for real with Debian's docker-compose against podman's
# Docker-compatible API socket (no Docker engine here), on a loopback port:
#   secrets (a token, auth.json, a self-signed certificate) -> up (no build: the image
#   from docker/test-image.sh) -> /readyz over HTTPS -> health check -> no token: 401 ->
#   a job from the host CLI with --token and --ca-file -> compose stop (SIGTERM, exit 0)
#   -> compose start -> the job is still there -> down -v.
# Bounded waits; removes the project, its volume and the API service it started.
# Usage: docker/test-compose.sh     (after docker/test-image.sh; TALLY_IMAGE as there)
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/.." && pwd)
# shellcheck source=docker/test-lib.sh
. "$here/test-lib.sh"
compose_test_env "$repo" 18090
project=tallycompose$$
work=$(mktemp -d /tmp/tally-test-compose.XXXXXX)
export DOCKER_HOST=unix://$work/podman.sock
url=https://127.0.0.1:$port
compose() { timeout 120 docker-compose -p "$project" -f "$repo/docker/compose.yaml" "$@" 2>>"$work/compose.err"; }

service_pid=
cleanup() {
  local rc=$?
  compose down -v >/dev/null 2>&1 || true
  [ -n "$service_pid" ] && kill "$service_pid" 2>/dev/null || true
  rm -rf "$work"
  exit $rc
}
trap cleanup EXIT
trap 'exit 130' INT TERM

command -v docker-compose >/dev/null || { DEBIAN_FRONTEND=noninteractive timeout 900 apt-get install -y -qq docker-compose >/dev/null; }
podman image exists "$TALLY_IMAGE" || die "$TALLY_IMAGE is missing: run docker/test-image.sh first"

podman system service --time=0 "$DOCKER_HOST" >"$work/service.log" 2>&1 &
service_pid=$!
for _ in $(seq 1 100); do [ -S "$work/podman.sock" ] && break; sleep 0.1; done
[ -S "$work/podman.sock" ] || die "podman API socket did not appear"

copy_cli_from_image "$TALLY_IMAGE" "$work/tally"
cli=${TALLY_CLI:-$work/tally}

# Secrets, readable by the container's uid 10001 (a throwaway directory).
secrets=$work/secrets
make_secrets "$secrets" compose-test user

wait_ready() {
  for _ in $(seq 1 120); do
    curl -fsS -m 1 --cacert "$secrets/cert.pem" -o /dev/null "$url/readyz" 2>/dev/null && return 0
    sleep 0.5
  done
  return 1
}

compose up -d --no-build >/dev/null || { cat "$work/compose.err"; die "compose up failed"; }
container=$(podman ps -a --filter "label=com.docker.compose.project=$project" --format '{{.Names}}' | head -1)
wait_ready && pass "compose up: $container ready on $url" || die "not ready within 60 s"
ports=$(podman port "$container" | tr '\n' ' ')
case "$ports" in *"127.0.0.1:$port"*) pass "published on loopback only: $ports" ;; *) fail "ports: $ports" ;; esac
ok=0
for _ in $(seq 1 20); do podman healthcheck run "$container" >/dev/null 2>&1 && { ok=1; break; }; sleep 1; done
[ "$ok" = 1 ] && pass "health check (tally health) passes" || fail "health check did not pass within 20 s"
sec=$(podman inspect --format 'user={{.Config.User}} read_only={{.HostConfig.ReadonlyRootfs}} security_opt={{.HostConfig.SecurityOpt}}' "$container")
case "$sec" in *user=10001:10001*read_only=true*no-new-privileges*) pass "$sec" ;; *) fail "$sec" ;; esac

code=$(curl -sS -m 5 --cacert "$secrets/cert.pem" -o /dev/null -w '%{http_code}' "$url/v1/jobs")
[ "$code" = 401 ] && pass "no token: 401" || fail "no token: $code"
echo '{"kind":"integrate","integrand":{"builtin":"unit_disk"},"seed":3,"stop":{"max_samples":20000000}}' >"$work/job.json"
timeout 120 "$cli" submit "$work/job.json" --watch --server "$url" >"$work/submit.out" 2>"$work/submit.err" ||
  { tail -3 "$work/submit.err"; die "submit failed"; }
job=$(head -1 "$work/submit.out")
"$cli" get "$job" --json --server "$url" >"$work/a.json"
pass "job $job: $(python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(d["state"], d["estimate"]["mean"], "+-", d["estimate"]["std_error"])' "$work/a.json")"

t0=$(date +%s.%N)
compose stop >/dev/null
took=$(python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.2f}')" "$t0" "$(date +%s.%N)")
code=$(podman inspect --format '{{.State.ExitCode}}' "$container")
[ "$code" = 0 ] && pass "compose stop: exit 0 after ${took}s" || fail "compose stop: exit $code after ${took}s"
compose start >/dev/null
wait_ready || die "not ready again within 60 s"
"$cli" get "$job" --json --server "$url" >"$work/b.json" || die "job gone after compose stop/start"
if python3 -c 'import json,sys; a,b=(json.load(open(p)) for p in sys.argv[1:3]); sys.exit(0 if all(a[k]==b[k] for k in ("state","samples","estimate")) else 1)' "$work/a.json" "$work/b.json"; then
  pass "job $job unchanged after compose stop/start (volume kept)"
else
  fail "job $job changed after compose stop/start"
fi
compose down -v >/dev/null
podman volume exists "${project}_tally-data" && fail "volume left behind" || pass "compose down -v removed the container and the volume"
log "test-compose: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
