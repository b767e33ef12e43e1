#!/usr/bin/env bash
# ctest entry for the browser tests: run_browser_tests.sh PATH/TO/tally-server [TEST_FILE]
# (TEST_FILE defaults to browser.test.mjs; auth_browser.test.mjs is the access-control one)
# Installs playwright-core from package-lock.json into tests/preview/node_modules
# when missing. Exits 77 (ctest SKIP) only when node, npm or chromium cannot be had.
set -u
here=$(cd "$(dirname "$0")" && pwd)
server=${1:?usage: run_browser_tests.sh PATH/TO/tally-server [TEST_FILE]}
test_file=${2:-browser.test.mjs}
chromium=${CHROMIUM:-/usr/bin/chromium}

if ! command -v node >/dev/null 2>&1; then
  echo "SKIP: node is not installed (scripts/install-deps.sh test installs nodejs)"; exit 77
fi
if [ ! -x "$chromium" ]; then
  echo "SKIP: $chromium is not installed (scripts/install-deps.sh test installs chromium)"; exit 77
fi
if [ ! -f "$here/node_modules/playwright-core/package.json" ]; then
  if ! command -v npm >/dev/null 2>&1; then
    echo "SKIP: npm is not installed, so playwright-core cannot be installed"; exit 77
  fi
  (cd "$here" && npm ci --no-audit --no-fund --loglevel=error) || {
    echo "SKIP: npm ci could not install playwright-core"; exit 77; }
fi
export TALLY_SERVER="$server" CHROMIUM="$chromium"
cd "$here" && exec node --test --test-concurrency=1 "$test_file"
