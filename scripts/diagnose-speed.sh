#!/usr/bin/env bash
# The issue's speed figure: `needle diagnose` on 10 trials of 14 997
# samples (liver 1, the paper's protocol at 661 Hz, seed 7) on one core,
# with no effect and with each of the costliest effects to search for.
# Prints, a line each, the least user + system time of RUNS runs (this
# kind of machine varies by 10–30 % from run to run) and the verdict.
#
#   scripts/diagnose-speed.sh [RUNS]      (RUNS defaults to 3)
#
# Needs python3 (to read the JSON); pins to CPU 0 with taskset where there
# is one.
set -euo pipefail
runs=${1:-3}
. "$(dirname "$0")/common.sh"
pin=()
if command -v taskset > /dev/null; then pin=(taskset -c 0); fi
# `time` prints seconds with a point for awk to read.
export LC_ALL=C
TIMEFORMAT='%U %S'
for effect in none presliding_hysteresis viscoelasticity tissue_motion; do
  hidden=$effect
  [ "$effect" = none ] && hidden=""
  d="$work/$effect"
  "$needle" simulate --out "$d" --trials 10 --seed 7 --rate-hz 661 \
    --effects "$hidden" > /dev/null 2> "$work/err" || { cat "$work/err" >&2; exit 1; }
  best=""
  for _ in $(seq "$runs"); do
    # Bash's own `time`: user and system seconds of the run.
    { time ${pin[@]+"${pin[@]}"} "$needle" diagnose "$d" > "$work/json" 2> "$work/err"; } 2> "$work/time" ||
      { cat "$work/err" >&2; exit 1; }
    t=$(awk '{ print $1 + $2 }' "$work/time")
    if [ -z "$best" ] || awk -v a="$t" -v b="$best" 'BEGIN { exit !(a < b) }'; then
      best=$t
    fi
  done
  verdict=$(python3 -c 'import json, sys; print(json.load(sys.stdin)["verdict"]["effect"])' < "$work/json")
  printf '%-24s %5.2f s  (least of %s; verdict %s)\n' "$effect" "$best" "$runs" "$verdict"
done
