#!/usr/bin/env bash
# Offline checks of the deployment files; no container engine or cluster needed.
#   1. yamllint on compose.yaml and k8s/*.yaml
#   2. docker-compose config: the compose file parses, and the port binds to 127.0.0.1
#   3. the Kustomize base renders (kubectl kustomize, else kustomize build)
#   4. the rendered objects pass the Kubernetes schemas (npm kubernetes-models) and the
#      deployment policy (docker/validate-k8s.mjs)
#   5. the Dockerfile has what docs/deployment.md promises (static greps)
# Installs what is missing: Debian packages by name (yamllint docker-compose nodejs
# npm), npm packages into docker/.tools/npm (git-ignored).
# Usage: docker/validate-manifests.sh        exit 0 when every check passed
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/.." && pwd)
tools="$here/.tools/npm"
passed=0
failed=0
pass() { passed=$((passed + 1)); echo "PASS $*"; }
fail() { failed=$((failed + 1)); echo "FAIL $*"; }

apt_install() {
  local missing=()
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  [ ${#missing[@]} -eq 0 ] && return 0
  echo "validate-manifests: installing ${missing[*]}" >&2
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo=sudo
  export DEBIAN_FRONTEND=noninteractive
  timeout 600 $sudo apt-get update -qq
  timeout 900 $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

command -v yamllint >/dev/null || apt_install yamllint
command -v docker-compose >/dev/null || apt_install docker-compose
command -v node >/dev/null && command -v npm >/dev/null || apt_install nodejs npm
if [ ! -d "$tools/node_modules/kubernetes-models" ] || [ ! -d "$tools/node_modules/yaml" ]; then
  mkdir -p "$tools"
  echo "validate-manifests: npm install into $tools" >&2
  (cd "$tools" && timeout 600 npm install --no-audit --no-fund --silent \
    kubernetes-models@5 @kubernetes-models/validate@5 yaml@2 >/dev/null)
fi

cd "$repo"
yaml_files=(docker/compose.yaml docker/k8s/*.yaml docker/k8s-cluster/*.yaml)

# 1. YAML style and syntax.
yamllint_conf='{extends: default, rules: {line-length: {max: 120}, document-start: disable, truthy: {check-keys: false}}}'
if out=$(yamllint -f parsable -d "$yamllint_conf" "${yaml_files[@]}" 2>&1); then
  pass "yamllint: ${#yaml_files[@]} files"
else
  fail "yamllint:"; echo "$out"
fi

# 2. Compose: parses, and by default publishes on loopback only.
if rendered=$(env -u TALLY_BIND -u TALLY_PORT docker-compose -f docker/compose.yaml config 2>&1); then
  pass "docker-compose config: docker/compose.yaml is valid"
  if echo "$rendered" | grep -Eq '^\s*-\s*127\.0\.0\.1:8080:8080(/tcp)?\s*$'; then
    pass "compose: port published on 127.0.0.1:8080 by default"
  else
    fail "compose: port not bound to 127.0.0.1 by default"; echo "$rendered" | grep -A3 'ports:'
  fi
  for key in 'tally-data:/var/lib/tally' 'read_only: true' 'stop_grace_period: 30s' 'user: 10001:10001'; do
    if echo "$rendered" | grep -q -- "$key"; then pass "compose: $key"; else fail "compose: missing $key"; fi
  done
else
  fail "docker-compose config:"; echo "$rendered"
fi

# 3. Kustomize render.
render=$(mktemp)
if command -v kubectl >/dev/null && kubectl kustomize docker/k8s >"$render" 2>/dev/null; then
  pass "kubectl kustomize docker/k8s: $(grep -c '^kind:' "$render") objects"
elif command -v kustomize >/dev/null && kustomize build docker/k8s >"$render"; then
  pass "kustomize build docker/k8s: $(grep -c '^kind:' "$render") objects"
else
  # No renderer here: check the resources one by one (each file is complete on its own).
  echo "validate-manifests: no kubectl/kustomize; checking the base's resources unrendered" >&2
  for f in $(sed -n '/^resources:/,/^[a-z]/s/^  - //p' docker/k8s/kustomization.yaml); do
    cat "docker/k8s/$f"; echo "---"
  done >"$render"
  pass "kustomization resources concatenated (render skipped: no kubectl/kustomize)"
fi

# 4. Schemas and policy.
if out=$(TALLY_NODE_MODULES="$tools/node_modules" node docker/validate-k8s.mjs <"$render" 2>&1); then
  pass "kubernetes-models schemas + policy: $(echo "$out" | tail -1)"
else
  fail "kubernetes-models schemas + policy:"; echo "$out" | grep -v '^ok '
fi

# 4b. The cluster overlay (docs/cluster.md): rendered, schemas, cluster policy.
crender=$(mktemp)
trap 'rm -f "$render" "$crender"' EXIT
if command -v kubectl >/dev/null && kubectl kustomize docker/k8s-cluster >"$crender" 2>/dev/null; then
  pass "kubectl kustomize docker/k8s-cluster: $(grep -c '^kind:' "$crender") objects"
else
  fail "kubectl kustomize docker/k8s-cluster (kubectl needed to render the overlay)"
fi
if out=$(TALLY_NODE_MODULES="$tools/node_modules" node docker/validate-k8s-cluster.mjs <"$crender" 2>&1); then
  pass "cluster overlay schemas + policy: $(echo "$out" | tail -1)"
else
  fail "cluster overlay schemas + policy:"; echo "$out" | grep -v '^ok '
fi
# Compose: Redis is on the internal network and not published; workers scale.
if [ -n "${rendered:-}" ]; then
  if echo "$rendered" | awk '/^  redis:/{r=1;next} /^  [a-z]/{r=0} r' | grep -q 'ports:'; then
    fail "compose: redis publishes a port"
  else
    pass "compose: redis not published to the host"
  fi
  if echo "$rendered" | awk '/^  worker:/{r=1;next} /^  [a-z]/{r=0} r' | grep -Eq 'container_name|ports:'; then
    fail "compose: worker has a container_name or ports (--scale worker=N would conflict)"
  else
    pass "compose: worker scales (no container_name, no ports)"
  fi
  if echo "$rendered" | grep -q 'internal: true'; then pass "compose: backend network is internal"; else fail "compose: backend network not internal"; fi
fi

# 5. Dockerfile promises.
df=docker/Dockerfile
check_df() {
  local what=$1 re=$2
  if grep -Eq "$re" "$df"; then pass "Dockerfile: $what"; else fail "Dockerfile: $what"; fi
}
check_df "ARG BASE before the first FROM" '^ARG BASE=debian:bookworm-slim'
check_df "FROM \${BASE} for both stages" '^FROM \$\{BASE\} AS runtime'
check_df "numeric non-root USER" '^USER 10001(:10001)?$'
check_df "tini as PID 1" '^ENTRYPOINT \["/usr/bin/tini", "--"'
check_df "VOLUME /var/lib/tally" '^VOLUME \["/var/lib/tally"\]'
check_df "EXPOSE 8080" '^EXPOSE 8080$'
check_df "HEALTHCHECK" '^HEALTHCHECK '
check_df "health check runs the tally binary" '^  CMD \["/usr/local/bin/tally", "health"'
check_df "listens on 0.0.0.0:8080" '"--listen", "0.0.0.0:8080"'
if awk '/^FROM .* AS runtime/{r=1} r' "$df" | grep -Eq '(^|[ \\])(g\+\+|gcc|clang|cmake|curl|wget|build-essential)( |$)'; then
  fail "Dockerfile: runtime stage installs a compiler or curl"
else
  pass "Dockerfile: no compiler or curl in the runtime stage"
fi

echo "validate-manifests: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
