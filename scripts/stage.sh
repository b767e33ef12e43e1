#!/usr/bin/env bash
# Runs one stage of `make test` (CI) and prints its wall time, the CPU time of everything
# it ran (user + sys: on a shared machine, CPU/2 estimates the wall time on 2 idle cores)
# and the load average, so a CI log says where the time went. With STAGE_LOG set, the
# summary line is appended there too (`make test` prints that file at the end).
# Usage: scripts/stage.sh NAME COMMAND...
set -uo pipefail
name=$1
shift
start=$(date +%s)
echo "== stage $name: start $(date -u +%H:%M:%S) UTC, load $(cut -d' ' -f1-3 /proc/loadavg)"
"$@"
rc=$?
secs=$(($(date +%s) - start))
# `times` (run in this shell, not in a $(...) subshell, which has no children), second
# line: user and sys time of the finished children, e.g. "12m3.456s 0m40.100s".
tfile=$(mktemp)
times >"$tfile"
cpu=$(sed -n 2p "$tfile" | awk '{
  t = 0
  for (i = 1; i <= 2; i++) { split($i, p, "m"); sub("s", "", p[2]); t += p[1] * 60 + p[2] }
  printf "%d", t }')
rm -f "$tfile"
line=$(printf '== stage %-15s wall %5d s = %5.1f min, CPU %5d s, exit %d (load at end: %s)' "$name" "$secs" \
  "$(awk "BEGIN{print $secs/60}")" "$cpu" "$rc" "$(cut -d' ' -f1-3 /proc/loadavg)")
echo "$line"
[ -n "${STAGE_LOG:-}" ] && echo "$line" >>"$STAGE_LOG"
exit $rc
