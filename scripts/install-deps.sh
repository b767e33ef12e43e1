#!/usr/bin/env bash
# Installs the Debian 12 packages tally needs, only those that are missing.
# Usage: scripts/install-deps.sh [build|demo|test|bench|all|containers]   (default: all)
# demo: what `make demo` needs, the build set and python3 (scripts/gltf_example.py); no
# browser, clang, Redis, scipy or wrk.
# containers: podman and friends for the on-demand image/compose tests in docker/
# (test-image.sh, test-compose.sh, test-cluster-compose.sh); not part of all / make test.
set -euo pipefail
want=${1:-all}

build_pkgs=(cmake g++ make ninja-build pkg-config
  libboost-dev libboost-system-dev nlohmann-json3-dev libmuparser-dev libfmt-dev libcli11-dev
  libsqlite3-dev libsqlitecpp-dev libembree-dev libopenimageio-dev libopenexr-dev libpng-dev libtinyobjloader-dev libtinygltf-dev
  libgtest-dev libgmock-dev libbenchmark-dev libgsl-dev libspdlog-dev libcubature-dev
  libhiredis-dev libssl-dev)
# clang-14 + libclang-rt-14-dev: the sanitizer tree and the libFuzzer targets (make test runs both);
# llvm-14: llvm-symbolizer, so sanitizer reports name file:line
test_pkgs=(python3 python3-pip python3-numpy python3-mypy openssl curl chromium nodejs redis-server clang-14 libclang-rt-14-dev llvm-14)
command -v npm >/dev/null 2>&1 || test_pkgs+=(npm)  # nodesource's nodejs bundles npm
bench_pkgs=(wrk python3-matplotlib python3-scipy python3-numpy python3-openimageio)  # openimageio: the scene suite reads EXRs
container_pkgs=(podman buildah runc debootstrap uidmap fuse-overlayfs slirp4netns docker-compose podman-compose
  golang-github-containernetworking-plugin-dnsname curl python3 openssl)

pkgs=("${build_pkgs[@]}")
case "$want" in
  build) ;;
  demo) pkgs+=(python3) ;;
  test) pkgs+=("${test_pkgs[@]}") ;;
  bench|all) pkgs+=("${test_pkgs[@]}" "${bench_pkgs[@]}") ;;
  containers) pkgs=("${container_pkgs[@]}") ;;
  *) echo "install-deps: unknown set '$want'" >&2; exit 2 ;;
esac

missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
echo "install-deps: installing ${missing[*]}" >&2
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO=sudo
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
