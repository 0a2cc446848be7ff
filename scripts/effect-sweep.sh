#!/usr/bin/env bash
# Every effect in every form, on this project's own simulator, through
# `needle diagnose`: liver 1, 10 trials, 15 % spread between trials, clock
# jitter; the paper's protocol at 250 Hz with a 3 mN load cell and
# insert–dwell–withdraw at 100 Hz with a 12 mN one (the rigs of
# book/src/physics.md). One line a case: ok or BAD (the first effect named
# is not the hidden one), protocol, effect, form, the verdict, the effects
# named in turn, held-out RMS before and after, the noise floor, and the
# effect's own size: the RMS over every sample of what it adds to the
# force, the case and a twin without the effect simulated from the same
# draws with a noiseless load cell (mN; `-` for no effect). An effect the nominal's fit takes up whole (a rate law at
# the one speed of insert–dwell–withdraw) leaves the nominal at the floor
# however large it is.
#
#   scripts/effect-sweep.sh SEED [OUT]      (about 3 minutes on two cores)
#
# Needs python3 (to read the JSON). The figures in the book's "Targets not
# met" are this script's output at seed 1.
set -euo pipefail
seed=${1:?usage: scripts/effect-sweep.sh SEED [OUT]}
out=${2:-/dev/stdout}
. "$(dirname "$0")/common.sh"
: > "$work/lines"
# One case's dataset in $1 with the effects $2 and a load cell of noise sd
# $3 ($proto, $rate and $form as the loops below set them).
sim() {
  "$needle" simulate --out "$1" --trials 10 --seed "$seed" --rate-hz "$rate" \
    --noise-n "$3" --protocol "$proto" --spread 0.15 --jitter \
    --effects "$2" --effect-form "$form" > /dev/null 2> "$work/err"
}
for proto in paper insert-dwell-withdraw; do
  if [ "$proto" = paper ]; then rate=250 noise=0.003; else rate=100 noise=0.012; fi
  for effect in none viscoelasticity rate_dependent_friction presliding_hysteresis \
      internal_structures depth_dependent_cutting holder_inertia sensor_drift tissue_motion; do
    for form in standard alternate literature; do
      [ "$effect" = none ] && [ "$form" != standard ] && continue
      d="$work/$proto-$effect-$form"
      hidden=$effect
      [ "$effect" = none ] && hidden=""
      # A case that fails is a line of its own, not the end of the sweep.
      if ! sim "$d" "$hidden" "$noise" || ! sim "$d.clean" "$hidden" 0 ||
        ! sim "$d.twin" "" 0 ||
        ! "$needle" diagnose "$d" > "$work/json" 2> "$work/err"; then
        echo "ERR $proto $effect $form: $(tail -1 "$work/err")" >> "$work/lines"
        continue
      fi
      python3 -c '
import csv, glob, json, math, os, sys
hidden, proto, form, with_dir, twin_dir = sys.argv[1:6]
d = json.load(sys.stdin)
def forces(path):
    with open(path) as f:
        return [float(r["f_n"]) for r in csv.DictReader(f)]
sq, n = 0.0, 0
for path in sorted(glob.glob(os.path.join(with_dir, "*.csv"))):
    a, b = forces(path), forces(os.path.join(twin_dir, os.path.basename(path)))
    sq += sum((x - y) ** 2 for x, y in zip(a, b))
    n += min(len(a), len(b))
size = round(math.sqrt(sq / n) * 1e3, 1) if hidden != "none" and n else "-"
v = d["verdict"]
mn = lambda x: "-" if x is None else round(x * 1e3, 1)
steps = ">".join(e["effect"] for e in v["effects"]) or "-"
ok = "ok" if v["effect"] == hidden else "BAD"
print(ok, proto, hidden, form, v["effect"], steps, mn(d["baseline"]["heldout_rms_n"]),
      mn(v["heldout_rms_after_n"]), mn(d["noise_floor_n"]), size)
' "$effect" "$proto" "$form" "$d.clean" "$d.twin" < "$work/json" >> "$work/lines"
    done
  done
done
{
  cat "$work/lines"
  echo "named right: $(grep -c '^ok' "$work/lines") of $(wc -l < "$work/lines")"
} > "$out"
