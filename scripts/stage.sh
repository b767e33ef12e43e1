#!/usr/bin/env bash
# Runs one stage of `make test` (CI) and prints its wall time and the load average, so a
# CI log says where the time went. With STAGE_LOG set, the summary line is appended there
# too (`make test` prints that file at the end).
# Usage: scripts/stage.sh NAME COMMAND...
set -uo pipefail
name=$1
shift
start=$(date +%s)
echo "== stage $name: start $(date -u +%H:%M:%S) UTC, load $(cut -d' ' -f1-3 /proc/loadavg)"
"$@"
rc=$?
secs=$(($(date +%s) - start))
line=$(printf '== stage %-16s %5d s = %5.1f min  exit %d  (load at end: %s)' "$name" "$secs" \
  "$(awk "BEGIN{print $secs/60}")" "$rc" "$(cut -d' ' -f1-3 /proc/loadavg)")
echo "$line"
[ -n "${STAGE_LOG:-}" ] && echo "$line" >>"$STAGE_LOG"
exit $rc
