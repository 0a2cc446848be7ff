//! A capsule that tears rather than breaks: a column of each trial's
//! nominal corrections ([`super::SPREAD`]).
//!
//! A wall with no sharp fall — a 3 mm artery's, whose force rolls over
//! and eases off over a millimetre or two of advance — carries a
//! dwindling share of its peak force as the tip pushes through it. The
//! paper's model falls from the peak to the cutting force at once; so
//! judged, the tear's excess (hundreds of mN over the first millimetre
//! past the fall) is misfit that a cutting profile along depth takes,
//! or that nothing does. How far and in what way a wall tears is each
//! insertion's own, as the capsule's yield before it falls is, and the
//! nominal reads it off the trial.

use super::reload::{Fall, Record};

/// The force's excess over its steady course as the capsule tears, per
/// sample from the first past the loading curve: A·g(s/L), s the tip's
/// deepest advance past the peak (`needle fit`'s puncture), g one of
/// [`SHAPES`] falling from 1 at the peak to 0 at L, none before the
/// loading curve ends (the capsule's yield column takes the samples from
/// the peak to there). The course is the reload's (the line through the
/// force 3–6 mm past the fall, `super::reload`); A is fitted by least
/// squares to the force over it, less `less` (the reload's column where
/// the force sinks below the course as the tear ends), at the samples the needle cuts at up to
/// the steady stretch's end, and g and L are the pair of [`SHAPES`] ×
/// [`tear_lengths_m`] that leave least — the trial's own reading, the
/// withheld trial's too, by this rule fixed before any effect is looked
/// at. Its gain is 1 where the law holds; zero where A is under three
/// noise sd. Read only after a `fall` that is no break
/// (`super::reload::after_the_fall`): a wall tears or breaks, and after
/// a break the force's aftermath is the reload's — and a compliant
/// mount's ring, which rebounds above the course after its first
/// trough.
pub(super) fn excess(record: &Record, fall: &Fall, peak_x_m: f64, less: &[f64]) -> Vec<f64> {
    let (x, f) = (record.x_m, record.f_n);
    let n = x.len();
    let mut col = vec![0.0; n];
    let from = record.fallen;
    let deepest: Vec<f64> = x[from..]
        .iter()
        .scan(f64::MIN, |d, &xi| {
            *d = d.max(xi);
            Some(*d - peak_x_m)
        })
        .collect();
    let stretch: Vec<(f64, f64)> = (from..fall.steady_end.min(n))
        .filter(|&i| record.cuts[i])
        .map(|i| (deepest[i - from], f[i] - less[i] - fall.course_n(x[i])))
        .collect();
    let Some((a, shape, tear_m)) = best_tear(&stretch) else {
        return col;
    };
    if a <= 3.0 * record.noise_n {
        return col;
    }
    for (c, past_m) in col[from..].iter_mut().zip(&deepest) {
        *c = a * shape(past_m / tear_m);
    }
    col
}

/// The tear that leaves least of `stretch` (advance past the peak, m, not
/// falling from one sample to the next; excess over the course, N): its
/// size A (least squares, ≥ 0), shape and length.
fn best_tear(stretch: &[(f64, f64)]) -> Option<(f64, Shape, f64)> {
    let fit = |shape: Shape, tear_m: f64| {
        let (mut gg, mut gr) = (0.0, 0.0);
        // Past its length a tear carries nothing.
        for &(past_m, r) in stretch.iter().take_while(|(past_m, _)| *past_m < tear_m) {
            let g = shape(past_m / tear_m);
            gg += g * g;
            gr += g * r;
        }
        let a = if gg > 0.0 { (gr / gg).max(0.0) } else { 0.0 };
        // What is left, less the sum of squares every tear leaves alike.
        (-a * gr, (a, shape, tear_m))
    };
    SHAPES
        .iter()
        .flat_map(|&shape| tear_lengths_m().map(move |l| fit(shape, l)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, tear)| tear)
}

/// The share of its peak force a tearing wall carries at a fraction u of
/// its tear (1 at 0, 0 from 1 on).
type Shape = fn(f64) -> f64;

/// How a tear may go, none of them singled out: evenly (the share falling
/// as the torn length grows), flat at the peak and at the end (the force
/// rolls over and eases off: cos²), or slowly then at once (the wall holds
/// until it gives), or at once then slowly.
const SHAPES: [Shape; 4] = [
    |u| (1.0 - u).clamp(0.0, 1.0),
    |u| {
        (std::f64::consts::FRAC_PI_2 * u.clamp(0.0, 1.0))
            .cos()
            .powi(2)
    },
    |u| 1.0 - u.clamp(0.0, 1.0).powi(2),
    |u| (1.0 - u).clamp(0.0, 1.0).powi(2),
];

/// Tear lengths L [`excess`] chooses from, m: a geometric grid from half
/// a millimetre to about three and a half, each 15 % past the one before
/// (a tear of 1.8 N read off the grid is then within 0.1 N of itself).
/// An artery's force eases off over 1–2.5 mm. A shorter ease is not a
/// tear: the capsule's yield before its fall takes the few samples a
/// wall flattens and eases over before it breaks, and what falls back
/// within a few tenths of a millimetre past the fall (0.1 s at 3 mm/s)
/// is a compliant mount's ring, the holder's.
fn tear_lengths_m() -> impl Iterator<Item = f64> {
    (0..15).map(|k| 0.5e-3 * 1.15f64.powi(k))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::reload::tests::insertion;

    /// An insertion at 20 µm a sample whose capsule peaked at sample 100
    /// (3 N) and is past its loading curve from sample 103: the force
    /// then follows a course of 1 N rising 20 N/m with `excess_n` of the
    /// advance past the peak on it, with noise of sd 10 mN (a fixed ±1
    /// sequence); the needle cuts throughout. The reload's column and
    /// the tear's.
    fn column(excess_n: impl Fn(f64) -> f64) -> (Vec<f64>, Vec<f64>) {
        let (x, f) = insertion(|i, past_m| {
            if i < 103 {
                3.0
            } else {
                1.0 + 20.0 * past_m + excess_n(past_m)
            }
        });
        let n = x.len();
        let (cutting, cuts) = (vec![1.0; n], vec![true; n]);
        let record = Record {
            x_m: &x,
            f_n: &f,
            cutting: &cutting,
            cuts: &cuts,
            fallen: 103,
            noise_n: 0.01,
        };
        let [reload, tear] = record.after_the_fall(x[100]);
        (reload, tear)
    }

    /// A wall tearing over 1.53 mm (a length of the grid) and over 1.62
    /// mm (between two), its force rolling over and easing off (1.8 N
    /// over the course at the peak, cos²): the column is that excess,
    /// from the first sample past the loading curve — off the grid,
    /// within what a step of length makes of it.
    #[test]
    fn a_tearing_wall_is_read_off_the_trial() {
        for (tear_m, within_n) in [(0.5e-3 * 1.15f64.powi(8), 0.03), (1.62e-3, 0.1)] {
            let tear = |past_m: f64| {
                let u = (past_m / tear_m).min(1.0);
                1.8 * (std::f64::consts::FRAC_PI_2 * u).cos().powi(2)
            };
            // Off the grid the tear's misfit can sink a few noise sd below
            // the course, which the reload's column then takes: the two
            // together are the excess.
            let (reload, col) = column(tear);
            assert!(col[..103].iter().all(|&c| c == 0.0));
            for (i, c) in col.iter().enumerate().skip(103) {
                let c = c + reload[i];
                let want = tear(2e-5 * (i - 100) as f64);
                assert!(
                    (c - want).abs() < within_n,
                    "{tear_m}, {i}: {c} against {want}"
                );
            }
        }
    }

    /// A wall that tears over a millimetre (1 N over the course at the
    /// peak, cos²) and leaves the force 0.3 N below the course as it lets
    /// go, climbing back over half a millimetre (the layer beneath loaded
    /// again): the tear's column holds the excess, the reload's the dip —
    /// where the reload alone, or the tear alone, left one of them.
    #[test]
    fn a_wall_that_tears_then_sinks_below_the_course_has_both() {
        let tear_m = 1.0e-3;
        let tear = |past_m: f64| {
            let u = (past_m / tear_m).min(1.0);
            (std::f64::consts::FRAC_PI_2 * u).cos().powi(2)
        };
        let dip = |past_m: f64| {
            let settled = (-(past_m - tear_m).max(0.0) / 0.5e-3).exp();
            -0.3 * (past_m / tear_m).min(1.0).powi(2) * settled
        };
        let (reload, torn) = column(|past_m| tear(past_m) + dip(past_m));
        let at = |past_m: f64| 100 + (past_m / 2e-5).round() as usize;
        let both = |i: usize| reload[i] + torn[i];
        let want = |i: usize| {
            let past_m = 2e-5 * (i - 100) as f64;
            tear(past_m) + dip(past_m)
        };
        for past_m in [0.2e-3, 0.6e-3, 1.0e-3, 1.4e-3, 3.0e-3] {
            let i = at(past_m);
            assert!(
                (both(i) - want(i)).abs() < 0.1,
                "{past_m} m past: {} against {}",
                both(i),
                want(i)
            );
        }
        assert!(reload[at(1.0e-3)] < -0.2, "{}", reload[at(1.0e-3)]);
        assert!(torn[at(0.2e-3)] > 0.7, "{}", torn[at(0.2e-3)]);
    }

    /// A wall that gives way at once leaves nothing over the course: no
    /// column. Nor does one that breaks, falling 0.6 N below the course
    /// and back within a tenth of a millimetre, however far the force
    /// then stands above the course (0.3 N easing off over 1.5 mm): a
    /// wall tears or breaks, and what follows a break is not the wall's.
    #[test]
    fn a_sharp_fall_is_no_tear() {
        let (reload, tear) = column(|_| 0.0);
        assert!(tear.iter().chain(&reload).all(|&c| c == 0.0));
        let broke = |past_m: f64| {
            let s = past_m - 6e-5;
            let above = 0.3
                * (std::f64::consts::FRAC_PI_2 * (s / 1.5e-3).min(1.0))
                    .cos()
                    .powi(2);
            above - 0.6 * (-s / 0.1e-3).exp()
        };
        assert!(column(broke).1.iter().all(|&c| c == 0.0));
    }
}
