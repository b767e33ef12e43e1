# shellcheck shell=bash
# Shared by docker/test-image.sh, test-compose.sh and test-cluster-compose.sh (sourced,
# not run): PASS/FAIL bookkeeping, containers.conf beside the checkout, a free loopback
# port, the tally CLI copied out of an image, and throw-away secrets for the server.

passed=0
failed=0
log() { printf '[%s] %s\n' "$(date +%H:%M:%S)" "$*"; }
pass() { passed=$((passed + 1)); log "PASS $*"; }
fail() { failed=$((failed + 1)); log "FAIL $*"; }
die() { log "FATAL $*"; exit 1; }

# Exports CONTAINERS_CONF (unless set) from ../shared/containers beside the checkout
# $1, or ../../shared/containers beside a worktree in wt/.
use_shared_containers_conf() {
  local d
  for d in "$1/../shared/containers" "$1/../../shared/containers"; do
    if [ -z "${CONTAINERS_CONF:-}" ] && [ -f "$d/containers.conf" ]; then
      CONTAINERS_CONF=$(cd "$d" && pwd)/containers.conf
      export CONTAINERS_CONF
    fi
  done
}

# Prints the first port from $1 on that nothing accepts on at 127.0.0.1 (100 tries).
free_port() {
  local port=$1
  for _ in $(seq 1 100); do
    (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null || break
    port=$((port + 1))
  done
  echo "$port"
}

# The environment docker/compose.yaml reads in the compose tests: CONTAINERS_CONF
# (use_shared_containers_conf for the checkout $1), TALLY_IMAGE (default
# localhost/tally:test) and TALLY_PORT, the first free port from TALLY_TEST_PORT or $2
# (also set as `port`); TALLY_BIND unset (loopback).
compose_test_env() {
  use_shared_containers_conf "$1"
  export TALLY_IMAGE=${TALLY_IMAGE:-localhost/tally:test}
  port=$(free_port "${TALLY_TEST_PORT:-$2}")
  export TALLY_PORT=$port
  unset TALLY_BIND
}

# Copies the tally CLI out of image $1 to the file $2 (the host has its libraries).
copy_cli_from_image() {
  local cid
  cid=$(podman create --no-healthcheck "$1")
  podman cp "$cid:/usr/local/bin/tally" "$2" >/dev/null
  podman rm -v "$cid" >/dev/null
}

# Throw-away secrets in the new directory $1, readable by the containers' uid 10001: a
# bearer token for the principal $2 with role $3 (auth.json) and a self-signed
# certificate for localhost and 127.0.0.1. Sets `token` and exports TALLY_SECRETS,
# TALLY_TOKEN and TALLY_CA_FILE (what docker/compose.yaml reads).
make_secrets() {
  local dir=$1 hash
  mkdir -p "$dir"
  token=tly_$(openssl rand -base64 32 | tr '+/' '-_' | tr -d '=\n')
  hash=$(printf '%s' "$token" | sha256sum | cut -d' ' -f1)
  printf '{"principals": [{"name": "%s", "role": "%s", "token_sha256": "%s"}]}\n' "$2" "$3" "$hash" >"$dir/auth.json"
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 1 -subj /CN=localhost \
    -addext subjectAltName=DNS:localhost,IP:127.0.0.1 -keyout "$dir/key.pem" -out "$dir/cert.pem" 2>/dev/null
  chmod 755 "$dir" && chmod 644 "$dir"/*
  export TALLY_SECRETS=$dir TALLY_TOKEN=$token TALLY_CA_FILE=$dir/cert.pem
}
