//! Cutting that wanders along depth, differently in every insertion.
//!
//! A heterogeneous tissue (fat lobules, fascia, collagen bundles) meets
//! each needle with its own layers, so the force its tip cuts with
//! wanders along the path — a random walk more than a law — and no
//! parameter shared between trials predicts it on a withheld one. What
//! can be asked of a withheld trial is whether its residual, where the
//! tip cuts, is a function of depth: each cutting sample is predicted by
//! the mean residual of the *other* cutting samples of the same trial
//! within a depth window (leave-one-out, so the sample's own noise is
//! never fitted), the window chosen by that leave-one-out error over the
//! whole dataset among [`HALF_WINDOWS_M`] (the standard choice of a
//! kernel smoother's width; nothing here is tuned to a data set).
//!
//! Free along depth in every trial, such a profile takes up part of any
//! effect's residual along an insertion at steady speed (where depth and
//! time go together), so it is tried first only where no shared
//! candidate is significant and a gap is left, or after the shared
//! effects named on what they leave open, and named only if it takes
//! [`MOST_OF_GAP_ALONG_DEPTH`] of what it is tried on
//! (`super::diagnose`): an effect whose residual lies mostly where the
//! tip cuts, as a function of depth there.
//! Written here: a running mean over sorted depths is a few lines, no
//! smoothing crate fits the leave-one-out form.

use super::candidates::Candidate;
use super::crossval::folds;
use super::prepare::{Prepared, DWELL, PHASES};
use super::{
    add_terms, columns, grams, non_negative_columns, per_trial_fit, total, Scored, Supports,
};

/// Half-widths of the depth window tried, m: from a fraction of a
/// bevel's length to a few millimetres (a tissue's layers).
pub const HALF_WINDOWS_M: [f64; 6] = [0.000_05, 0.000_1, 0.000_2, 0.000_5, 0.001, 0.002];

/// Least share of the gap (its mean square above the noise floor) the
/// profile must take to be named: more than the half asked of a shared
/// effect ([`super::MOST_OF_GAP`]), as a profile free in every trial
/// takes part of any effect's residual along an insertion; all of it
/// less what a stop misplaced by a sample of a jittered clock leaves.
pub const MOST_OF_GAP_ALONG_DEPTH: f64 = 0.75;

/// The held-out residuals of the nominal with `set` as `scored` fitted
/// it (the baseline with none), scored as they are and with each trial's
/// cutting samples predicted from its other cutting samples nearby in
/// depth (the grid value the window's half-width, m). As they are, they
/// are `scored` itself where `set` is empty; with candidates, each
/// trial's residual refitted here (the shared terms of its fold, its own
/// spread on it) need not be their score to the per cent (a candidate's
/// columns made over its whole grid at once differ from the same made
/// alone, and were seen to by 0.2–7 %), so the profile is judged against
/// that.
pub fn cutting_along_depth_from(
    data: &[Prepared],
    scored: &Scored,
    set: &[(&Candidate, f64)],
) -> (Scored, Scored) {
    let trials = cuts(data, scored, set);
    let best = HALF_WINDOWS_M
        .iter()
        .copied()
        .min_by(|&a, &b| {
            let sse = |w: f64| trials.iter().map(|c| c.sse(w)).sum::<f64>();
            sse(a).total_cmp(&sse(b))
        })
        .unwrap_or(HALF_WINDOWS_M[0]);
    let before = rescored(data, trials.iter().map(|c| &c.residual_n[..]), scored);
    let after = Scored {
        grid_value: best,
        ..left_along_depth(data, &trials, best, scored)
    };
    (before, after)
}

/// `scored` with its squared errors, by trial and by phase, those of
/// each trial's `residuals`.
fn rescored<'a>(
    data: &[Prepared],
    residuals: impl Iterator<Item = &'a [f64]>,
    scored: &Scored,
) -> Scored {
    let mut per_trial = Vec::with_capacity(data.len());
    let mut per_trial_dwell = Vec::with_capacity(data.len());
    let mut by_phase = [(0.0, 0); PHASES.len()];
    for (p, left) in data.iter().zip(residuals) {
        let mut dwell = (0.0, 0);
        for (i, e) in left.iter().enumerate() {
            let ph = p.protocol_phase[i];
            by_phase[ph].0 += e * e;
            by_phase[ph].1 += 1;
            if ph == DWELL {
                dwell = (dwell.0 + e * e, dwell.1 + 1);
            }
        }
        per_trial.push((left.iter().map(|e| e * e).sum(), left.len()));
        per_trial_dwell.push(dwell);
    }
    Scored {
        per_trial,
        by_phase,
        per_trial_dwell,
        ..scored.clone()
    }
}

/// `scored` (the held-out score of the nominal with `set`) with each
/// trial's cutting samples then predicted from its other cutting samples
/// within `half_m` in depth, as [`cutting_along_depth_from`] does: an effect beside a profile free along depth, which
/// takes what lies along the insertion as a function of depth and
/// leaves the effect what it adds elsewhere (a dwell's relaxation).
pub fn beside_profile(
    data: &[Prepared],
    scored: &Scored,
    set: &[(&Candidate, f64)],
    half_m: f64,
) -> Scored {
    left_along_depth(data, &cuts(data, scored, set), half_m, scored)
}

/// Each trial's held-out residual under `set`, as `scored` fitted it,
/// with its cutting samples by depth.
fn cuts(data: &[Prepared], scored: &Scored, set: &[(&Candidate, f64)]) -> Vec<Cut> {
    data.iter()
        .enumerate()
        .map(|(j, p)| {
            let residual_n = heldout_residual(data, scored, j, set);
            // The baseline's residual is the one it scored (with a
            // candidate, see `cutting_along_depth_from`).
            debug_assert!(
                !set.is_empty() || {
                    let sse: f64 = residual_n.iter().map(|r| r * r).sum();
                    (sse - scored.per_trial[j].0).abs() <= 1e-6 * sse.max(1e-12)
                }
            );
            Cut::of(p, residual_n)
        })
        .collect()
}

/// `scored` with the trials' residuals those `trials` leave at `half_m`.
fn left_along_depth(data: &[Prepared], trials: &[Cut], half_m: f64, scored: &Scored) -> Scored {
    let left: Vec<Vec<f64>> = trials.iter().map(|c| c.left(half_m)).collect();
    rescored(data, left.iter().map(|l| &l[..]), scored)
}

/// The profile along depth of one trial whose residual is `residual_n`:
/// at each cutting sample, the mean residual of the other cutting samples
/// within `half_m` of its depth; 0 elsewhere.
pub fn profile(p: &Prepared, residual_n: Vec<f64>, half_m: f64) -> Vec<f64> {
    let cut = Cut::of(p, residual_n);
    let left = cut.left(half_m);
    cut.residual_n
        .iter()
        .zip(left)
        .map(|(r, l)| r - l)
        .collect()
}

/// Trial `j`'s residual as `scored` (the nominal with `set`) scored it
/// withheld: the shared terms from the other trials (its fold's), its
/// own spread fitted on it.
fn heldout_residual(
    data: &[Prepared],
    scored: &Scored,
    j: usize,
    set: &[(&Candidate, f64)],
) -> Vec<f64> {
    let trial = std::slice::from_ref(&data[j]);
    let cols = vec![columns(&data[j], set)];
    let sums = total(&grams(trial, &cols, &Supports::all(trial, &cols))[0]);
    let signed = non_negative_columns(set.iter().map(|(c, _)| *c));
    let per = per_trial_fit(&signed);
    let shared = &scored.fold_theta[j % folds(data.len())];
    let theta = per.for_trial(&sums, shared);
    let mut fitted = vec![0.0; data[j].trial.len()];
    add_terms(&mut fitted, &cols[0], &theta);
    data[j]
        .residual_n
        .iter()
        .zip(fitted)
        .map(|(r, f)| r - f)
        .collect()
}

/// One trial's held-out residual and its cutting samples by depth.
struct Cut {
    residual_n: Vec<f64>,
    /// (depth, sample) of every sample where the nominal cuts, by depth.
    by_depth: Vec<(f64, usize)>,
}

impl Cut {
    fn of(p: &Prepared, residual_n: Vec<f64>) -> Self {
        // Where the needle cuts: a dwell's samples are no profile.
        let mut by_depth: Vec<(f64, usize)> = (0..p.trial.len())
            .filter(|&i| p.cuts(i))
            .map(|i| (p.trial.x_m[i], i))
            .collect();
        by_depth.sort_by(|a, b| a.0.total_cmp(&b.0));
        Self {
            residual_n,
            by_depth,
        }
    }

    /// Every sample's residual, the cutting ones less the mean of the
    /// other cutting samples within `half_m` of their depth.
    fn left(&self, half_m: f64) -> Vec<f64> {
        let mut left = self.residual_n.clone();
        let d = &self.by_depth;
        // Prefix sums of the residual in depth order.
        let mut sum = vec![0.0; d.len() + 1];
        for (k, &(_, i)) in d.iter().enumerate() {
            sum[k + 1] = sum[k] + self.residual_n[i];
        }
        let (mut lo, mut hi) = (0, 0);
        for (k, &(x, i)) in d.iter().enumerate() {
            while d[lo].0 < x - half_m {
                lo += 1;
            }
            while hi < d.len() && d[hi].0 <= x + half_m {
                hi += 1;
            }
            let others = hi - lo - 1;
            if others > 0 {
                let mean = (sum[hi] - sum[lo] - self.residual_n[i]) / others as f64;
                left[i] -= mean;
            }
            debug_assert!(lo <= k && k < hi);
        }
        left
    }

    /// Squared error of the cutting samples after [`Self::left`].
    fn sse(&self, half_m: f64) -> f64 {
        let left = self.left(half_m);
        self.by_depth.iter().map(|&(_, i)| left[i] * left[i]).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cut(depths: &[f64], residual_n: &[f64]) -> Cut {
        let mut by_depth: Vec<(f64, usize)> = depths.iter().copied().zip(0..).collect();
        by_depth.sort_by(|a, b| a.0.total_cmp(&b.0));
        Cut {
            residual_n: residual_n.to_vec(),
            by_depth,
        }
    }

    /// A residual that is a step in depth is taken away but at the step;
    /// each sample is predicted by the others only (a lone sample keeps
    /// its residual: nothing else says what it should be).
    #[test]
    fn the_profile_is_the_other_samples_nearby() {
        let depths: Vec<f64> = (0..20).map(|k| f64::from(k) * 0.000_1).collect();
        let step: Vec<f64> = (0..20).map(|k| if k < 10 { 0.1 } else { -0.1 }).collect();
        let left = cut(&depths, &step).left(0.000_15);
        for (k, e) in left.iter().enumerate() {
            let at_step = k == 9 || k == 10;
            assert_eq!(e.abs() < 1e-12, !at_step, "{k}: {e}");
        }
        let lone = cut(&[0.0, 0.01], &[0.3, -0.2]).left(0.000_15);
        assert_eq!(lone, vec![0.3, -0.2]);
    }

    /// Leave-one-out: white noise is not fitted at any window (what is
    /// left is no smaller than the noise itself).
    #[test]
    fn noise_is_not_taken_away() {
        let depths: Vec<f64> = (0..2000).map(|k| f64::from(k) * 0.000_01).collect();
        // A fixed pseudo-random sequence of ±1.
        let noise: Vec<f64> = (0..2000u32)
            .map(|k| {
                if (k.wrapping_mul(2_654_435_761) >> 16) & 1 == 0 {
                    1.0
                } else {
                    -1.0
                }
            })
            .collect();
        let c = cut(&depths, &noise);
        let before = c.sse(0.0);
        for w in HALF_WINDOWS_M {
            assert!(c.sse(w) >= 0.99 * before, "{w}: {} vs {before}", c.sse(w));
        }
    }
}
