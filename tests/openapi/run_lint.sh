#!/usr/bin/env bash
# ctest entry: lints docs/openapi.json with Redocly CLI and fails on any error
# (warnings are printed). Installs @redocly/cli from package-lock.json into
# tests/openapi/node_modules when missing, from the machine's npm configuration.
# Exits 77 (ctest SKIP) only when node or npm is missing.
set -u
here=$(cd "$(dirname "$0")" && pwd)
doc="$here/../../docs/openapi.json"

if ! command -v node >/dev/null 2>&1; then
  echo "SKIP: node is not installed (scripts/install-deps.sh test installs nodejs)"; exit 77
fi
if [ ! -f "$here/node_modules/@redocly/cli/package.json" ]; then
  if ! command -v npm >/dev/null 2>&1; then
    echo "SKIP: npm is not installed, so @redocly/cli cannot be installed"; exit 77
  fi
  (cd "$here" && npm ci --no-audit --no-fund --loglevel=error) || {
    echo "FAIL: npm ci could not install @redocly/cli"; exit 1; }
fi
cd "$here" && exec node node_modules/@redocly/cli/bin/cli.js lint --format=stylish "$doc"
