#!/usr/bin/env bash
# ctest entry for the browser tests: run_browser_tests.sh PATH/TO/tally-server [TEST_FILE]
# (TEST_FILE defaults to browser.test.mjs; auth_browser.test.mjs is the access-control one)
# Installs playwright-core from package-lock.json into tests/preview/node_modules
# when missing. Exits 77 (ctest SKIP) only when node, npm or chromium is not installed,
# and never in CI (CI=true: a browser test that cannot run is a failure there). A failed
# `npm ci` is a failure, not a skip: the tools are there and something is broken.
set -u
here=$(cd "$(dirname "$0")" && pwd)
server=${1:?usage: run_browser_tests.sh PATH/TO/tally-server [TEST_FILE]}
test_file=${2:-browser.test.mjs}
chromium=${CHROMIUM:-/usr/bin/chromium}

skip() {
  if [ "${CI:-}" = "true" ]; then
    echo "FAIL (CI=true, so not skipped): $1"; exit 1
  fi
  echo "SKIP: $1"; exit 77
}

if ! command -v node >/dev/null 2>&1; then
  skip "node is not installed (scripts/install-deps.sh test installs nodejs)"
fi
if [ ! -x "$chromium" ]; then
  skip "$chromium is not installed (scripts/install-deps.sh test installs chromium)"
fi
if [ ! -f "$here/node_modules/playwright-core/package.json" ]; then
  if ! command -v npm >/dev/null 2>&1; then
    skip "npm is not installed, so playwright-core cannot be installed"
  fi
  (cd "$here" && npm ci --no-audit --no-fund --loglevel=error) || {
    echo "FAIL: npm ci could not install playwright-core from tests/preview/package-lock.json"; exit 1; }
fi
export TALLY_SERVER="$server" CHROMIUM="$chromium"
cd "$here" && exec node --test --test-concurrency=1 "$test_file"
