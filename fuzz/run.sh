#!/usr/bin/env bash
# fuzz/run.sh SECONDS TARGET...: run each libFuzzer target (build/fuzz/NAME) for SECONDS on its
# seed corpus (fuzz/*/corpus/NAME without its prefix) and print one line each: executions and
# crashes. New inputs go to build/fuzz/work/NAME, a crash to build/fuzz/crash-NAME-*; the exit
# status is 1 when any target crashed.
set -uo pipefail
seconds=$1
shift
status=0
for binary in "$@"; do
  name=$(basename "$binary")
  work=build/fuzz/work/$name
  log=build/fuzz/$name.log
  mkdir -p "$work"
  # dxl_reader's seeds are in fuzz/dynamixel/corpus/reader
  seeds=$(ls -d fuzz/*/corpus/"${name#*_}" 2>/dev/null | head -n 1)
  "$binary" -max_total_time="$seconds" -print_final_stats=1 -timeout=10 -rss_limit_mb=1024 \
    -artifact_prefix="build/fuzz/crash-$name-" "$work" ${seeds:+"$seeds"} >"$log" 2>&1
  rc=$?
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
  if [ $rc -eq 0 ]; then
    printf '   %-16s %12s executions in %s s, 0 crashes\n' "$name" "${runs:-?}" "$seconds"
  else
    status=1
    artifact=$(sed -n 's/.*Test unit written to //p' "$log" | tail -n 1)
    printf '   %-16s %12s executions, 1 crash: %s (log %s)\n' "$name" "${runs:-?}" \
      "${artifact:-no input saved}" "$log"
    grep -m 3 -E 'check failed|ERROR: |runtime error' "$log" | sed 's/^/      /'
  fi
done
exit $status
