#!/usr/bin/env bash
# Runs the cluster topology of docker/compose.yaml for real with podman-compose
# (Debian's podman-compose 1.0.3, rootful podman, no Docker engine):
#   secrets (an admin token, auth.json, a self-signed certificate) -> up redis +
#   tally-server + `--scale worker=3` (no build: the image from docker/test-image.sh or
#   `podman build`) -> Redis publishes no port and sits only on the internal backend
#   network -> three workers in /v1/workers -> one job from the host CLI -> its result
#   equals `tally run` of the same spec (the image's own CLI, embedded, no network) bit
#   for bit (JSON doubles are round-trip exact) -> every worker computed blocks -> down -v.
# On-demand (not in make test). Bounded waits; removes the project and its volume.
# Usage: docker/test-cluster-compose.sh   Environment: TALLY_IMAGE (default
# localhost/tally:test), TALLY_TEST_PORT (first port tried, 18190), CONTAINERS_CONF.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/.." && pwd)
# shellcheck source=docker/test-lib.sh
. "$here/test-lib.sh"
compose_test_env "$repo" 18190
project=tallycluster$$
work=$(mktemp -d /tmp/tally-test-cluster-compose.XXXXXX)
url=https://127.0.0.1:$port
# Container DNS (service names such as "redis") needs the CNI dnsname plugin
# (golang-github-containernetworking-plugin-dnsname, in scripts/install-deps.sh containers).
# podman-compose 1.0.3 (Debian 12) parses `up --scale` but ignores it; it honours
# deploy.replicas. A copy of docker/compose.yaml gives the worker service 3 replicas (what
# `docker compose up --scale worker=3` does); --scale is passed as well for newer versions.
compose() {
  timeout 300 podman-compose -p "$project" -f "$work/compose.yaml" "$@" \
    >>"$work/compose.log" 2>&1
}

cleanup() {
  local rc=$?
  if [ "$rc" -ne 0 ] && [ -f "$work/compose.log" ]; then
    log "compose log (tail):"; tail -25 "$work/compose.log" | sed 's/^/    /'
    for c in $(podman ps -a --filter "label=io.podman.compose.project=$project" --format '{{.Names}}' 2>/dev/null); do
      log "logs of $c (tail):"; podman logs --tail 8 "$c" 2>&1 | sed 's/^/    /'
    done
  fi
  compose down -v >/dev/null 2>&1 || true
  podman volume rm -f "${project}_tally-data" >/dev/null 2>&1 || true
  podman network rm "${project}_backend" "${project}_default" >/dev/null 2>&1 || true  # 1.0.3's down leaves them
  rm -rf "$work"
  exit $rc
}
trap cleanup EXIT
trap 'exit 130' INT TERM

"$repo/scripts/install-deps.sh" containers
podman image exists "$TALLY_IMAGE" || die "$TALLY_IMAGE is missing: run docker/test-image.sh (or podman build) first"
log "image $TALLY_IMAGE: $(podman image inspect --format '{{.Size}}' "$TALLY_IMAGE" | awk '{printf "%.0f MB", $1/1e6}')"

copy_cli_from_image "$TALLY_IMAGE" "$work/tally"
cli=$work/tally

# Secrets readable by the containers' uid 10001 (a throwaway directory). The principal
# is an admin so that /v1/workers (which names every tenant's jobs) may be read.
secrets=$work/secrets
make_secrets "$secrets" cluster-test admin
api() { curl -fsS -m 5 --cacert "$secrets/cert.pem" -H "Authorization: Bearer $token" "$url$1"; }

# (The worker's health check as a string: 1.0.3 pops "CMD-SHELL" off the list form while
# making the first replica, so the second fails with "unknown healthcheck test type"; and
# it cannot merge a string over a list from an override file, so this is a derived copy.)
backend=$(podman info --format '{{.Host.NetworkBackend}}')
python3 - "$repo/docker/compose.yaml" "$work/compose.yaml" "$backend" <<'PY'
import sys, yaml
c = yaml.safe_load(open(sys.argv[1]))
w = c["services"]["worker"]
w.setdefault("deploy", {})["replicas"] = 3
t = w["healthcheck"]["test"]
if isinstance(t, list) and t[0] == "CMD-SHELL":
    w["healthcheck"]["test"] = t[1]
# podman 4.3 with the CNI network backend (Debian 12's default) configures no DNS on an
# internal network ("dnsname and internal networks are incompatible"), so the service
# name "redis" would not resolve: this copy drops internal: true (the backend network
# still has no published port; docker and podman's netavark backend resolve names on
# internal networks, so docker/compose.yaml keeps it).
# With CNI the server, on two networks, gets both networks' dnsmasq in resolv.conf and
# the default network's answers NXDOMAIN for "redis" about half the time: this copy
# puts the server on backend only (its port is published from there).
if sys.argv[3] == "cni":
    c["networks"]["backend"].pop("internal", None)
    c["services"]["tally-server"]["networks"] = ["backend"]
    c["networks"].pop("default", None)
yaml.safe_dump(c, open(sys.argv[2], "w"), sort_keys=False)
PY
t0=$(date +%s)
compose up -d --scale worker=3 || die "podman-compose up failed"
names=$(podman ps -a --filter "label=io.podman.compose.project=$project" --format '{{.Names}}' | sort | tr '\n' ' ')
log "containers: $names"
ready=0
for _ in $(seq 1 120); do api /readyz >/dev/null 2>&1 && { ready=1; break; }; sleep 0.5; done
[ "$ready" = 1 ] && pass "tally-server ready on $url after $(( $(date +%s) - t0 )) s" || die "not ready within 60 s"

redis_c=$(podman ps --filter "label=io.podman.compose.project=$project" --filter "label=com.docker.compose.service=redis" --format '{{.Names}}' | head -1)
[ -n "$redis_c" ] || die "no redis container"
rports=$(podman port "$redis_c" 2>/dev/null | tr '\n' ' ')
[ -z "$rports" ] && pass "redis publishes no port to the host" || fail "redis publishes: $rports"
rnets=$(podman inspect --format '{{range $k, $v := .NetworkSettings.Networks}}{{$k}} {{end}}' "$redis_c")
case "$rnets" in *backend*) ;; *) fail "redis networks: $rnets" ;; esac
backend_net=$(podman network ls --format '{{.Name}}' | grep "${project}_backend" | head -1)
internal=$(podman network inspect --format '{{.Internal}}' "$backend_net" 2>/dev/null || echo '?')
if [ "$backend" = cni ]; then
  [ "$rnets" = "${project}_backend " ] && pass "redis only on ${project}_backend (internal=$internal: CNI has no DNS on internal networks, see above)" ||
    fail "redis networks: $rnets"
else
  [ "$internal" = true ] && pass "redis only on $rnets(internal=$internal)" || fail "backend network internal=$internal ($rnets)"
fi

nworkers=0
for _ in $(seq 1 60); do
  nworkers=$(api /v1/workers | python3 -c 'import json,sys; print(len(json.load(sys.stdin)["workers"]))' 2>/dev/null || echo 0)
  [ "$nworkers" = 3 ] && break
  sleep 0.5
done
[ "$nworkers" = 3 ] && pass "three workers registered in /v1/workers" || die "workers in /v1/workers: $nworkers"

echo '{"kind":"integrate","integrand":{"builtin":"unit_disk"},"domain":{"type":"box","lower":[-1,-1],"upper":[1,1]},"seed":42,"stop":{"max_samples":60000000}}' >"$work/job.json"
chmod 644 "$work/job.json"
t1=$(date +%s)
timeout 300 "$cli" submit "$work/job.json" --watch --server "$url" >"$work/submit.out" 2>"$work/submit.err" ||
  { tail -3 "$work/submit.err"; die "submit failed"; }
job=$(head -1 "$work/submit.out")
api "/v1/jobs/$job" >"$work/cluster.json"
log "cluster job $job took $(( $(date +%s) - t1 )) s"
timeout 300 podman run --rm --network none --no-healthcheck -v "$work/job.json:/tmp/job.json:ro" \
  --entrypoint /usr/local/bin/tally "$TALLY_IMAGE" run /tmp/job.json --json >"$work/embedded.json" ||
  die "embedded tally run failed"
if python3 - "$work/cluster.json" "$work/embedded.json" <<'PY'; then
import json, sys
c, e = (json.load(open(p)) for p in sys.argv[1:3])
assert c["state"] == "succeeded", c["state"]
pairs = [("samples", c["samples"], e["samples"]),
         ("mean", c["estimate"]["mean"], e["estimate"]["mean"]),
         ("std_error", c["estimate"]["std_error"], e["estimate"]["std_error"])]
for name, a, b in pairs:
    print(f"    {name}: cluster {a!r}  embedded {b!r}")
sys.exit(0 if all(a == b and repr(a) == repr(b) for _, a, b in pairs) else 1)
PY
  pass "job $job: cluster result equals the embedded tally run bit for bit (bits $(python3 -c 'import json,sys; b=json.load(open(sys.argv[1]))["bits"]; print(b["mean"], b["m2"])' "$work/cluster.json"))"
else
  fail "job $job: cluster result differs from the embedded tally run"
fi
sleep 2  # heartbeats carry blocks_done once a second
api /v1/workers >"$work/workers.json"
if python3 - "$work/workers.json" <<'PY'; then
import json, sys
w = json.load(open(sys.argv[1]))
done = {x["name"]: x["blocks_done"] for x in w["workers"]}
print("    blocks per worker:", done, " results:", w["results"])
r = w["results"]
sys.exit(0 if len(done) == 3 and all(v > 0 for v in done.values()) and r["first"] == r["blocks_merged"] and r["duplicates_different"] == 0 else 1)
PY
  pass "every worker computed blocks; no block stored twice"
else
  fail "worker participation or result counts"
fi
compose down -v
podman volume exists "${project}_tally-data" && fail "volume left behind" || pass "podman-compose down -v removed the containers and the volume"
log "test-cluster-compose: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
