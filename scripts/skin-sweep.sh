#!/usr/bin/env bash
# Relaxation among the other traits of real skin recordings, on this
# project's own simulator, through `needle diagnose`: the skin phantom on
# insert–dwell–withdraw at 100 Hz with a 12 mN load cell, clock jitter, a
# 4 mN tare and 15 % spread between trials, relaxation five times the
# standard branch (three beside presliding), alone and beside membranes
# (`--layers 2`), walls, cutting's literature form, drift, presliding and
# tissue motion. One line a case: ok or BAD (relaxation not named),
# seed, effects, form, layers, the effects named in turn, held-out RMS
# before and after, and the noise floor (mN).
#
#   scripts/skin-sweep.sh [SEEDS] [OUT]      (SEEDS defaults to "1 2 3 4 5 6";
#                                            about 6 minutes on two cores)
#
# Needs python3 (to read the JSON). The book's *Sim-to-real gap
# diagnosis* gives this script's count.
set -euo pipefail
seeds=${1:-1 2 3 4 5 6}
out=${2:-/dev/stdout}
. "$(dirname "$0")/common.sh"
: > "$work/lines"
for seed in $seeds; do
  for case in "viscoelasticity=5:standard:0" "viscoelasticity=5:literature:0" \
      "viscoelasticity=5:standard:2" "viscoelasticity=5,internal_structures:standard:0" \
      "viscoelasticity=5,depth_dependent_cutting:literature:0" \
      "viscoelasticity=5,depth_dependent_cutting:literature:2" \
      "viscoelasticity=5,sensor_drift:standard:0" \
      "viscoelasticity=3,presliding_hysteresis=3:standard:0" \
      "viscoelasticity=5,tissue_motion:standard:0"; do
    IFS=: read -r effects form layers <<< "$case"
    d="$work/$seed-$effects-$form-$layers"
    # A case that fails is a line of its own, not the end of the sweep.
    if ! "$needle" simulate --out "$d" --tissue skin_phantom --protocol insert-dwell-withdraw \
        --jitter --rate-hz 100 --noise-n 0.012 --tare-n 0.004 --spread 0.15 --trials 10 \
        --seed "$seed" --effects "$effects" --effect-form "$form" --layers "$layers" \
        > /dev/null 2> "$work/err" ||
      ! "$needle" diagnose "$d" > "$work/json" 2> "$work/err"; then
      echo "ERR $seed $effects $form $layers: $(tail -1 "$work/err")" >> "$work/lines"
      continue
    fi
    python3 -c '
import json, sys
d = json.load(sys.stdin)
v = d["verdict"]
named = [e["effect"] for e in v["effects"]]
mn = lambda x: round(x * 1e3, 1)
ok = "ok" if "viscoelasticity" in named else "BAD"
print(ok, *sys.argv[1:], ">".join(named) or v["effect"], mn(d["baseline"]["heldout_rms_n"]),
      mn(v["heldout_rms_after_n"]), mn(d["noise_floor_n"]))
' "$seed" "$effects" "$form" "L$layers" < "$work/json" >> "$work/lines"
    rm -rf "$d"
  done
done
{
  cat "$work/lines"
  echo "relaxation named: $(grep -c '^ok' "$work/lines") of $(wc -l < "$work/lines")"
} > "$out"
