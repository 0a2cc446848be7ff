#!/usr/bin/env bash
# Trial-to-trial spread alone, across the library and the rigs, through
# `needle diagnose`: every tissue of the built-in library, 100, 250 and
# 1000 Hz, a 3 and a 12 mN load cell, both protocols (60 datasets of ten
# trials, 20 % spread, clock jitter, a 3 mN tare). No effect is hidden, so
# every verdict should be `none`. One line a dataset: ok or BAD, tissue,
# rate, noise, protocol, the verdict, held-out RMS before and after and
# the noise floor (mN).
#
#   scripts/no-effect-grid.sh SEED [OUT]      (about 3 minutes on two cores)
#
# Needs python3 (to read the JSON). The book's "Targets not met" gives
# this script's count at seeds 3, 4 and 5.
set -euo pipefail
seed=${1:?usage: scripts/no-effect-grid.sh SEED [OUT]}
out=${2:-/dev/stdout}
. "$(dirname "$0")/common.sh"
: > "$work/lines"
for tissue in liver1 liver1_journal skin_phantom liver1_rational liver2; do
  for rate in 100 250 1000; do
    for noise in 0.003 0.012; do
      for proto in paper insert-dwell-withdraw; do
        d="$work/$tissue-$rate-$noise-$proto"
        # A dataset that fails is a line of its own, not the end of the grid.
        if ! "$needle" simulate --out "$d" --tissue "$tissue" --trials 10 --seed "$seed" \
            --rate-hz "$rate" --noise-n "$noise" --protocol "$proto" --spread 0.2 \
            --jitter --tare-n 0.003 > /dev/null 2> "$work/err" ||
          ! "$needle" diagnose "$d" > "$work/json" 2> "$work/err"; then
          echo "ERR $tissue $rate $noise $proto: $(tail -1 "$work/err")" >> "$work/lines"
          continue
        fi
        python3 -c '
import json, sys
d = json.load(sys.stdin)
v = d["verdict"]
mn = lambda x: round(x * 1e3, 1)
ok = "ok" if v["effect"] == "none" else "BAD"
print(ok, *sys.argv[1:], v["effect"], mn(d["baseline"]["heldout_rms_n"]),
      mn(v["heldout_rms_after_n"]), mn(d["noise_floor_n"]))
' "$tissue" "$rate" "$noise" "$proto" < "$work/json" >> "$work/lines"
        rm -rf "$d"
      done
    done
  done
done
{
  cat "$work/lines"
  echo "none: $(grep -c '^ok' "$work/lines") of $(wc -l < "$work/lines")"
} > "$out"
