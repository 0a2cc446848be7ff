//! The withdrawal's stick: where a withdrawing needle dragged the tissue
//! along before the shaft slid through it.

use std::ops::Range;

use needle_io::trial::Trial;

use needle_holder::model::params::TissueParams;

use super::prepare::{odds_of_sliding, DWELL, WITHDRAWAL};
use crate::fit::lsq::Lsq;
use crate::fit::predict::Parts;
use crate::fit::TrialFit;

/// Where a withdrawing needle dragged the tissue along (the paper's
/// Karnopp band with a tissue of finite stiffness round the shaft): from
/// the needle's first step out ([`set_off`]) until the force snaps
/// back ([`crate::fit::trial::slipped`]), or, with no snap to find, until
/// the grip gave way ([`gave_way`]); none: no stick.
pub fn stick(
    trial: &Trial,
    phase: &[usize],
    (parts, params): (&Parts, &TissueParams),
    geometry: &TrialFit,
) -> Range<usize> {
    let Some(first) = phase.iter().position(|&p| p == WITHDRAWAL) else {
        return 0..0;
    };
    let end = (first..phase.len())
        .find(|&i| phase[i] != WITHDRAWAL)
        .unwrap_or(phase.len());
    let most_back = crate::fit::predict::window_samples(trial.rate_hz());
    let start = set_off(phase, (parts, params.half_band_mps), first, most_back);
    let deep = (
        geometry.puncture_x_m,
        crate::fit::trial::free_level_n(trial, geometry.contact_x_m),
    );
    let f = &trial.f_n[..end];
    crate::fit::trial::slipped(f, &trial.x_m, start, geometry.noise_n, deep)
        .or_else(|| gave_way(f, &trial.x_m, parts, start, geometry.noise_n))
        .map_or(0..0, |s| start..s)
}

/// Where the withdrawal starting at `first` set off: the dwell's last
/// samples before it where the nominal already pulls the needle out (it
/// sets off before the phases call it moving) and more likely has it
/// sliding than at rest, at most `most_back` of them: the samples the
/// velocity leaves to the force ([`crate::fit::predict::needle_velocity`]),
/// not a dwell entered by drifting back.
fn set_off(
    phase: &[usize],
    (parts, half_band_mps): (&Parts, f64),
    first: usize,
    most_back: usize,
) -> usize {
    let sliding = |i: usize| {
        parts.friction_n[i] < 0.0
            && odds_of_sliding(&parts.other_side, parts.v_mps[i], half_band_mps, i) > 0.5
    };
    let mut start = first;
    while start > 0 && first - start < most_back && phase[start - 1] == DWELL && sliding(start - 1)
    {
        start -= 1;
    }
    start
}

/// Where a withdrawing needle stopped dragging the tissue along with no
/// snap to show for it: a grip whose static force exceeds its kinetic one
/// by a few noise sd, or that gives way over several samples, leaves no
/// step [`crate::fit::trial::slipped`] can find, yet its tent pulled past
/// the sliding that follows. From where the tip has let its load go
/// ([`TIP_UNLOADING_M`] of travel from `start`) the tent (a force affine
/// in the needle's travel, as the stick's corrections have it) up to `e`
/// and sliding from `e` on (the nominal's friction line, scaled, and a
/// constant pull) are fitted by least squares for every `e`
/// ([`best_split`]); the best `e` ends a stick where the tent follows its
/// ramp ([`TENT_FIT_NOISE_SD`]) and there pulls as deep as a snap must
/// start from ([`crate::fit::trial::SNAP_NOISE_SD`]), deeper than the
/// sliding just after it by
/// [`OVERSHOOT_NOISE_SD`]. A presliding transition (Dahl's, LuGre's)
/// reaches the kinetic level without passing it and is no stick.
fn gave_way(f: &[f64], x: &[f64], parts: &Parts, start: usize, noise_n: f64) -> Option<usize> {
    let stop = f.len().min(x.len()).min(parts.friction_n.len());
    let from_m = x.get(start)?;
    let ramp_from = (start..stop).find(|&i| from_m - x[i] >= TIP_UNLOADING_M)?;
    let tent = |i: usize| [1.0, -(from_m - x[i])];
    let slide = |i: usize| [parts.friction_n[i], 1.0];
    let split = best_split(f, ramp_from..stop, tent, slide)?;
    let e = split.at;
    let value = |c: [f64; 2], col: [f64; 2]| c[0] * col[0] + c[1] * col[1];
    let held_n = value(split.tent, tent(e - 1));
    let sliding_n = value(split.slide, slide(e));
    let noise_n = noise_n.max(1e-4);
    let ramp = split.tent_rms_n <= TENT_FIT_NOISE_SD * noise_n;
    // An elastic tent pulls harder the further it is stretched; a pull
    // that eases with the travel is the shaft's friction over a length
    // that shortens, and a surface's grip beside it.
    let stretched = split.tent[1] >= 0.0;
    let pulled = held_n <= -crate::fit::trial::SNAP_NOISE_SD * noise_n;
    (ramp && stretched && pulled && sliding_n - held_n >= OVERSHOOT_NOISE_SD * noise_n).then_some(e)
}

/// The best split of `f` over `range` into a `tent` (two columns) up to
/// `at` and a `slide` (two columns) from it, by least squares: prefix and
/// suffix sums, so every split is a pair of 2×2 solves.
struct Split {
    at: usize,
    /// The tent's and the slide's coefficients.
    tent: [f64; 2],
    slide: [f64; 2],
    /// What the tent leaves of `f` before `at`, RMS.
    tent_rms_n: f64,
}

fn best_split(
    f: &[f64],
    range: Range<usize>,
    tent: impl Fn(usize) -> [f64; 2],
    slide: impl Fn(usize) -> [f64; 2],
) -> Option<Split> {
    let (from, stop) = (range.start, range.end);
    if stop < from + MIN_TENT_SAMPLES + MIN_SLIDE_SAMPLES {
        return None;
    }
    let tents = running(range.clone(), f, tent);
    let slides = running(range.rev(), f, slide);
    let (at, _) = (from + MIN_TENT_SAMPLES..=stop - MIN_SLIDE_SAMPLES)
        .map(|e| {
            (
                e,
                explained(&tents[e - from]).0 + explained(&slides[stop - e]).0,
            )
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let (tent_sums, slide_sums) = (&tents[at - from], &slides[stop - at]);
    let tent = explained(tent_sums).1;
    Some(Split {
        at,
        tent,
        slide: explained(slide_sums).1,
        tent_rms_n: (tent_sums.sse(&tent) / (at - from) as f64).sqrt(),
    })
}

/// Least-squares sums of `f` on two columns over the first k samples of
/// `order`, for every k.
pub(super) fn running(
    order: impl Iterator<Item = usize>,
    f: &[f64],
    col: impl Fn(usize) -> [f64; 2],
) -> Vec<Lsq<2>> {
    let mut sums = Lsq::default();
    let mut out = vec![sums.clone()];
    for i in order {
        sums.add(col(i), f[i]);
        out.push(sums.clone());
    }
    out
}

/// What a fit takes of Σf² (the more, the less it leaves), and its
/// coefficients; none where its columns are one.
fn explained(sums: &Lsq<2>) -> (f64, [f64; 2]) {
    match sums.solve() {
        Some(c) => (sums.sse(&[0.0; 2]) - sums.sse(&c), c),
        None => (0.0, [0.0; 2]),
    }
}

/// How much deeper than the sliding after it a tent must pull where it
/// gives way, in noise sd, to be a grip rather than a noisy bend in the
/// friction line: the fitted values at the ends of lines of ten samples
/// or more have standard errors of 2/√10 of a noise sd or less, so this
/// is six of them or more.
const OVERSHOOT_NOISE_SD: f64 = 4.0;

/// Travel from the set-off past which a tent without a snap is read: the
/// widest compliance the tip may let its load go over (0.41 mm,
/// `super::tip`), with a tenth of a millimetre to spare; its unloading is
/// no tent.
const TIP_UNLOADING_M: f64 = 0.5e-3;

/// How closely a tent without a snap follows its ramp, RMS in noise sd:
/// a dragged tent is elastic, its force affine in the travel; a step
/// inside it (a tip letting go at once, a turn) is something else.
const TENT_FIT_NOISE_SD: f64 = 3.0;

/// Least samples of a tent without a snap, and of sliding after it: a
/// count, for the fitted values' standard errors (0.1 and 0.2 s at
/// 100 Hz).
const MIN_TENT_SAMPLES: usize = 10;
const MIN_SLIDE_SAMPLES: usize = 20;

#[cfg(test)]
mod tests {
    use super::*;

    /// A withdrawal from 50 mm at 20 µm a sample, the shaft 30 mm in
    /// tissue at its start, a kinetic friction of −10 N/m along it, with
    /// `force_n` of (sample, travel, kinetic force) and noise of sd 10 mN
    /// (a fixed ±1 sequence). The force, positions and the nominal's parts.
    fn withdrawal(force_n: impl Fn(usize, f64, f64) -> f64) -> (Vec<f64>, Vec<f64>, Parts) {
        let n = 400;
        let x: Vec<f64> = (0..n).map(|i| 0.05 - 2e-5 * i as f64).collect();
        let length_m: Vec<f64> = x.iter().map(|x| x - 0.02).collect();
        let friction_n: Vec<f64> = length_m.iter().map(|l| -10.0 * l).collect();
        let f = (0..n)
            .map(|i| {
                let noise = if (i as u32).wrapping_mul(2_654_435_761) >> 16 & 1 == 0 {
                    0.01
                } else {
                    -0.01
                };
                force_n(i, 0.05 - x[i], friction_n[i]) + noise
            })
            .collect();
        let parts = Parts {
            friction_n,
            length_m,
            ..Parts::default()
        };
        (f, x, parts)
    }

    /// A tent pulling from the rest's 0.2 N to −0.45 N over 100 samples,
    /// then easing onto the kinetic friction (−0.3 N) over ten, 15 mN a
    /// sample: no snap `slipped` can find, and the stick ends where the
    /// grip gave way.
    #[test]
    fn a_grip_that_gives_way_without_a_snap_ends_the_stick() {
        let eased = |i: usize, kinetic_n: f64| {
            let tent_n = 0.2 - 0.65 * (i.min(100) as f64) / 100.0;
            let share = ((i as f64 - 100.0) / 10.0).clamp(0.0, 1.0);
            tent_n + share * (kinetic_n - tent_n)
        };
        let (f, x, parts) = withdrawal(|i, _, kinetic_n| eased(i, kinetic_n));
        let deep = (0.03, 0.0);
        assert_eq!(crate::fit::trial::slipped(&f, &x, 0, 0.01, deep), None);
        let e = gave_way(&f, &x, &parts, 0, 0.01).expect("a stick");
        assert!((103..=107).contains(&e), "{e}");
    }

    /// The shaft's friction over the length left, one and a half times
    /// the nominal's, and a surface's grip of 0.15 N beside it, until the
    /// tissue lets go at sample 300 (over three samples, onto zero): the
    /// pull eases as the needle comes out, where a tent's would grow. No
    /// stick, though a tent's line up to the let-go fits it as well.
    #[test]
    fn a_pull_that_eases_as_the_needle_comes_out_is_no_tent() {
        let gripped = |i: usize, _, kinetic_n: f64| {
            let pull_n = 1.5 * kinetic_n - 0.15;
            pull_n * (1.0 - ((i as f64 - 299.0) / 3.0).clamp(0.0, 1.0))
        };
        let (f, x, parts) = withdrawal(gripped);
        assert_eq!(gave_way(&f, &x, &parts, 0, 0.01), None);
    }

    /// The dwell's last three samples before a withdrawal at sample 10,
    /// the nominal pulling in all three (its velocity's window reaches
    /// into them) but likely at rest in the first two by the encoder's
    /// odds: the withdrawal sets off at the third.
    #[test]
    fn a_withdrawal_sets_off_where_the_nominal_likely_slides() {
        let phase: Vec<usize> = (0..20)
            .map(|i| if i < 10 { DWELL } else { WITHDRAWAL })
            .collect();
        let parts = Parts {
            friction_n: vec![-0.3; 20],
            v_mps: vec![-0.002; 20],
            other_side: vec![(7, 0.9), (8, 0.8), (9, 0.2)],
            ..Parts::default()
        };
        assert_eq!(set_off(&phase, (&parts, 1e-4), 10, 3), 9);
        let sliding = Parts {
            other_side: Vec::new(),
            ..parts
        };
        assert_eq!(set_off(&phase, (&sliding, 1e-4), 10, 3), 7);
    }

    /// Presliding (Dahl's law): from the rest's 0.2 N the friction
    /// approaches the kinetic level over 0.3 mm of travel and never
    /// passes it. No stick.
    #[test]
    fn presliding_onto_the_kinetic_friction_is_no_stick() {
        let dahl = |_, travel_m: f64, kinetic_n: f64| {
            kinetic_n + (0.2 - kinetic_n) * (-travel_m / 0.3e-3).exp()
        };
        let (f, x, parts) = withdrawal(dahl);
        assert_eq!(gave_way(&f, &x, &parts, 0, 0.01), None);
    }

    /// The tent is read past the widest compliance the tip's unloading
    /// may take.
    #[test]
    fn the_tent_is_read_past_the_tips_unloading() {
        assert!(TIP_UNLOADING_M > super::super::tip::widest_compliance_m());
    }
}
