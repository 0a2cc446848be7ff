//! The layer beneath a ruptured capsule loaded again: a column of each
//! trial's nominal corrections ([`super::SPREAD`]).
//!
//! When a capsule ruptures the tissue ahead of the tip springs back, and
//! the layer beneath must be compressed to its own cutting force before
//! it cuts. Every real recording shows it: the force falls to 20–45 % of
//! the peak and climbs 1.2–3.3× within the next 3 mm, by a different
//! amount in each insertion. The paper's model cuts at its full force
//! from the fall on; so judged, the reload's misfit (0.7–2.2 N at the
//! fall of a skin phantom written apart) was read as a cutting that
//! depends on depth in every recording. It is each insertion's own, as the capsule's
//! yield before it tears is, and the nominal reads it off the trial.

use super::prepare::{Prepared, LOADING};
use crate::fit::lsq::Lsq;

/// The force's shortfall below its steady course after the puncture, per
/// sample from the first past the loading curve: −Δ·e^{−s/λ} times the
/// share of the cutting force the nominal has on, s the tip's deepest
/// advance past the bottom of the fall, none before it (a length, since
/// the tip must advance to load the layer however long that takes). The
/// steady course is the straight line through the force the advancing
/// needle cuts with 3–6 mm past the fall ([`RELOADED_FROM_M`]), carried
/// back to the fall where it rises with depth ([`Fall::course_n`]); Δ is
/// how far the bottom of the fall lies below it, and λ the length of
/// [`reload_lengths_m`] that follows the record from the fall to the
/// steady stretch best — both the trial's own reading, the withheld
/// trial's too, by this rule fixed before any effect is looked at. Its
/// gain is 1 where the law holds. Zero in a trial that does not cut
/// along 1.5 mm of that stretch.
///
/// A wall breaks or tears: where its fall's bottom lies within three
/// noise sd of the course (or above it) the trial's second column is
/// the capsule's tear (`super::tear`), read over the same course. A wall
/// that tears can still leave the layer beneath to load again: where the
/// force less the tear sinks more than three noise sd below the course
/// within 3 mm (an artery's roll-over that eases off below it, then
/// climbs back), the reload is read from that dip, and the tear again
/// beside it. Returns `[reload, tear]`.
pub(super) fn after_the_fall(p: &Prepared) -> [Vec<f64>; 2] {
    let n = p.trial.len();
    let cuts: Vec<bool> = (0..n).map(|i| p.cuts(i)).collect();
    match (
        Record::of(p, &cuts),
        p.trial.x_m.get(p.geometry.puncture_index),
    ) {
        (Some(record), Some(&peak_x_m)) => record.after_the_fall(peak_x_m),
        _ => [vec![0.0; n], vec![0.0; n]],
    }
}

/// What [`after_the_fall`] reads of one trial.
pub(super) struct Record<'a> {
    pub(super) x_m: &'a [f64],
    pub(super) f_n: &'a [f64],
    /// The share of the cutting force the nominal has on, each sample.
    pub(super) cutting: &'a [f64],
    /// Whether the needle cuts at each sample ([`Prepared::cuts`]).
    pub(super) cuts: &'a [bool],
    /// The first sample past the loading curve.
    pub(super) fallen: usize,
    pub(super) noise_n: f64,
}

impl<'a> Record<'a> {
    /// `p`'s record past its loading curve, with `cuts` its
    /// [`Prepared::cuts`] at every sample; `None` with no loading curve.
    fn of(p: &'a Prepared, cuts: &'a [bool]) -> Option<Self> {
        let last_loading = (0..p.trial.len()).rev().find(|&i| p.phase[i] == LOADING)?;
        Some(Record {
            x_m: &p.trial.x_m,
            f_n: &p.trial.f_n,
            cutting: &p.cutting,
            cuts,
            fallen: last_loading + 1,
            noise_n: p.noise_n,
        })
    }

    /// [`after_the_fall`]'s columns for this record, whose capsule
    /// peaked at `peak_x_m`.
    pub(super) fn after_the_fall(&self, peak_x_m: f64) -> [Vec<f64>; 2] {
        let zeros = || vec![0.0; self.x_m.len()];
        match self.course() {
            Some(fall) if fall.broke(self.noise_n) => [self.shortfall(&fall, &zeros()), zeros()],
            Some(fall) => self.torn(&fall, peak_x_m),
            None => [zeros(), zeros()],
        }
    }

    /// `[reload, tear]` after `fall`, no break: the wall's excess as it
    /// tears, and where the force then sinks below the course (the layer
    /// beneath loaded again as the wall lets go of the tip), the reload
    /// from there, the tear read again beside it.
    fn torn(&self, fall: &Fall, peak_x_m: f64) -> [Vec<f64>; 2] {
        let zeros = vec![0.0; self.x_m.len()];
        let tear = super::tear::excess(self, fall, peak_x_m, &zeros);
        match self.sunk(fall, &tear) {
            Some(dip) => {
                let reload = self.shortfall(&dip, &tear);
                let tear = super::tear::excess(self, fall, peak_x_m, &reload);
                [reload, tear]
            }
            None => [zeros, tear],
        }
    }

    /// Where the force less `tear` sinks lowest below `fall`'s course
    /// within [`RELOADED_FROM_M`] past the loading curve, as the bottom of
    /// a fall to reload from, if more than three noise sd below it. Read
    /// on means of [`DIP_SAMPLES`] samples: over a few millimetres the
    /// least single sample of noise alone lies three sd low.
    fn sunk(&self, fall: &Fall, tear: &[f64]) -> Option<Fall> {
        let (x, f) = (self.x_m, self.f_n);
        let from = self.fallen;
        let cut: Vec<usize> = (from..fall.steady_end.min(x.len()))
            .filter(|&i| self.cuts[i] && x[i] - x[from] <= RELOADED_FROM_M)
            .collect();
        let below = |i: usize| f[i] - tear[i] - fall.course_n(x[i]);
        let (mean_n, at) = cut
            .windows(DIP_SAMPLES)
            .map(|w| {
                let mean_n = w.iter().map(|&i| below(i)).sum::<f64>() / DIP_SAMPLES as f64;
                (mean_n, w[DIP_SAMPLES / 2])
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        (-mean_n > 3.0 * self.noise_n).then(|| Fall {
            steady_end: fall.steady_end,
            at_bottom_n: fall.course_n(x[at]),
            slope_n_per_m: fall.slope_n_per_m,
            bottom_x_m: x[at],
            deficit_n: -mean_n,
        })
    }

    /// The reload's column after `fall`, read on the force less `less`
    /// (what another column of the trial's holds).
    fn shortfall(&self, fall: &Fall, less: &[f64]) -> Vec<f64> {
        let mut col = vec![0.0; self.x_m.len()];
        let x = self.x_m;
        // From the first sample past the loading curve: the samples of
        // the fall before its lowest one (which noise picks among them)
        // are as far short of the course.
        let deepest: Vec<f64> = x[self.fallen..]
            .iter()
            .scan(f64::MIN, |d, &xi| {
                *d = d.max(xi);
                Some((*d - fall.bottom_x_m).max(0.0))
            })
            .collect();
        let short = |i: usize, lambda_m: f64| {
            -fall.deficit_n * self.cutting[i] * (-deepest[i - self.fallen] / lambda_m).exp()
        };
        let sse = |lambda_m: f64| -> f64 {
            (self.fallen..fall.steady_end)
                .filter(|&i| self.cuts[i])
                .map(|i| (self.f_n[i] - less[i] - fall.course_n(x[i]) - short(i, lambda_m)).powi(2))
                .sum()
        };
        let Some(lambda_m) = reload_lengths_m().min_by(|&a, &b| sse(a).total_cmp(&sse(b))) else {
            return col;
        };
        for (i, c) in col.iter_mut().enumerate().skip(self.fallen) {
            *c = short(i, lambda_m);
        }
        col
    }

    /// The fall and the steady course past it, if a stretch 3–6 mm past
    /// the fall's bottom is cut along for at least 1.5 mm, however far
    /// the bottom lies below the course (or above it).
    fn course(&self) -> Option<Fall> {
        let (x, f, n) = (self.x_m, self.f_n, self.x_m.len());
        let fallen = self.fallen;
        if fallen >= n {
            return None;
        }
        // The bottom of the fall: the lowest force over the first
        // [`FALL_ADVANCE_M`] past the loading curve, at any sample rate.
        let fall_end = (fallen..n)
            .find(|&i| x[i] - x[fallen] > FALL_ADVANCE_M)
            .unwrap_or(n);
        let bottom = (fallen..fall_end).min_by(|&i, &j| f[i].total_cmp(&f[j]))?;
        let past_m = |i: usize| x[i] - x[bottom];
        let within = |i: usize| (RELOADED_FROM_M..=2.0 * RELOADED_FROM_M).contains(&past_m(i));
        let steady: Vec<usize> = (bottom..n).filter(|&i| self.cuts[i] && within(i)).collect();
        let (&first, &last) = (steady.first()?, steady.last()?);
        if past_m(last) - past_m(first) < 0.5 * RELOADED_FROM_M {
            return None;
        }
        let mut line = Lsq::<2>::default();
        for &i in &steady {
            line.add([1.0, past_m(i)], f[i]);
        }
        let [at_bottom_n, slope_n_per_m] = line.solve()?;
        let mut fall = Fall {
            steady_end: last + 1,
            at_bottom_n,
            slope_n_per_m,
            bottom_x_m: x[bottom],
            deficit_n: 0.0,
        };
        fall.deficit_n = fall.course_n(x[bottom]) - f[bottom];
        Some(fall)
    }
}

/// Reload lengths λ [`Record::shortfall`] chooses from, m: a geometric grid from
/// a quarter of a millimetre to about two and a half, each a quarter past
/// the one before. Real recordings reload within 3 mm (λ ≤ 1 mm); a
/// slower one is allowed for. A shorter one is not a layer loaded again:
/// what recovers within a tenth of a millimetre of advance (50 ms at
/// 2 mm/s) is the fall's own ring on a compliant mount, the holder's.
fn reload_lengths_m() -> impl Iterator<Item = f64> {
    (0..11).map(|k| 0.25e-3 * 1.25f64.powi(k))
}

/// A puncture's fall and the steady course the force climbs back to.
pub(super) struct Fall {
    /// The first sample past the steady stretch.
    pub(super) steady_end: usize,
    /// The steady course's force at the bottom's position, N, and its
    /// slope, N/m.
    at_bottom_n: f64,
    slope_n_per_m: f64,
    /// Where the fall's lowest sample lies, m.
    bottom_x_m: f64,
    /// How far that sample lies below the course, N.
    deficit_n: f64,
}

impl Fall {
    /// Whether the capsule broke: the fall's bottom lies more than three
    /// noise sd (`noise_n`) below the course.
    pub(super) fn broke(&self, noise_n: f64) -> bool {
        self.deficit_n > 3.0 * noise_n
    }

    /// The steady course's force at position `x_m`, N: the line through
    /// the steady stretch, carried back to the fall where it rises with
    /// depth (as the shaft's friction grows); where it falls with depth
    /// (a tissue whose cutting wanders along the path) it is no course to
    /// carry back, and is held at its level where the stretch begins —
    /// carried back, a line falling 1.4 N a millimetre put a course
    /// 4.5 N above a fall's bottom.
    pub(super) fn course_n(&self, x_m: f64) -> f64 {
        let mut past_m = x_m - self.bottom_x_m;
        if self.slope_n_per_m < 0.0 {
            past_m = past_m.max(RELOADED_FROM_M);
        }
        self.at_bottom_n + self.slope_n_per_m * past_m
    }
}

/// Past the fall by this much, a layer loaded again has reached its
/// steady course (the recordings: within 3 mm); [`Record::course`] reads the
/// course from here to twice as far.
const RELOADED_FROM_M: f64 = 0.003;

/// Samples [`Record::sunk`] averages to find a torn wall's dip below the
/// course.
const DIP_SAMPLES: usize = 5;

/// A puncture's fall takes two samples at a real rig's 100 Hz: at 2 mm/s
/// 40 µm of advance. Its bottom is looked for over this much, whatever
/// the sample rate.
const FALL_ADVANCE_M: f64 = 0.000_2;

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// 600 samples of an insertion at 20 µm a sample: positions (m) and
    /// forces (N), `force_n` of (sample, advance past sample 100) with
    /// noise of sd 10 mN (a fixed ±1 sequence).
    pub(in crate::diagnose) fn insertion(
        force_n: impl Fn(usize, f64) -> f64,
    ) -> (Vec<f64>, Vec<f64>) {
        let x: Vec<f64> = (0..600).map(|i| 2e-5 * i as f64).collect();
        let f = (0..600)
            .map(|i| {
                let noise = if (i as u32).wrapping_mul(2_654_435_761) >> 16 & 1 == 0 {
                    0.01
                } else {
                    -0.01
                };
                noise + force_n(i, x[i] - x[100])
            })
            .collect();
        (x, f)
    }

    /// An insertion ([`insertion`]) whose capsule gave way at sample
    /// 100: the force then follows `course_n` of the advance past the
    /// fall, `force_n` of (sample, advance) is what the samples read
    /// from the fall on. The needle cuts throughout with the nominal's
    /// cutting on.
    fn column(force_n: impl Fn(usize, f64) -> f64) -> Vec<f64> {
        let (x, f) = insertion(|i, past_m| if i < 100 { 3.0 } else { force_n(i, past_m) });
        let n = x.len();
        let (cutting, cuts) = (vec![1.0; n], vec![true; n]);
        let [reload, _] = Record {
            x_m: &x,
            f_n: &f,
            cutting: &cutting,
            cuts: &cuts,
            fallen: 100,
            noise_n: 0.01,
        }
        .after_the_fall(x[100]);
        reload
    }

    /// A layer loaded again: 0.6 N short of a course of 1 N rising 20 N/m
    /// at the fall, recovering over λ = 0.8 mm. The column is that
    /// shortfall (λ read within a step of the grid), from the first
    /// sample past the loading curve — the fall's samples before its
    /// lowest are as short, and a column starting at the lowest left
    /// them a step of the whole deficit.
    #[test]
    fn a_layer_loaded_again_is_read_off_the_trial() {
        let reload = |past_m: f64| 1.0 + 20.0 * past_m - 0.6 * (-past_m / 0.8e-3).exp();
        // The fall's first three samples at its bottom, the third 30 mN
        // the lowest.
        let at_bottom = |i: usize| [0.03, 0.03, 0.0][i - 100];
        let col = column(|i, past_m| {
            if i < 103 {
                reload(0.0) + at_bottom(i)
            } else {
                reload(past_m)
            }
        });
        for i in [100, 101, 102] {
            assert!((col[i] + 0.6).abs() < 0.05, "{i}: {}", col[i]);
        }
        for (i, c) in col.iter().enumerate().skip(103) {
            let past_m = 2e-5 * (i - 100) as f64;
            let want = -0.6 * (-past_m / 0.8e-3).exp();
            assert!((c - want).abs() < 0.04, "{i}: {c} against {want}");
        }
        assert!(col[..100].iter().all(|&c| c == 0.0));
    }

    /// A force that falls and rises again with no law of a layer's (a
    /// cutting that wanders): past the fall it climbs and then falls 1 N
    /// a millimetre through the stretch the course is read from. That
    /// line carried back would stand 6 N above the fall's bottom; the
    /// course is held at its level where the stretch begins, 3 N above
    /// it, no more than the record shows there.
    #[test]
    fn a_course_falling_with_depth_is_not_carried_back() {
        let wander = |past_m: f64| {
            if past_m < 3e-3 {
                1.0 + 1e3 * past_m
            } else {
                4.0 - 1e3 * (past_m - 3e-3)
            }
        };
        let col = column(|_, past_m| wander(past_m));
        let deepest = col.iter().fold(0.0f64, |a, &c| a.min(c));
        assert!((-3.1..=-2.9).contains(&deepest), "{deepest}");
    }

    /// A fall onto the course itself leaves nothing to reload: no column.
    #[test]
    fn a_fall_onto_its_course_is_no_reload() {
        let col = column(|_, past_m| 1.0 + 20.0 * past_m);
        assert!(col.iter().all(|&c| c == 0.0));
    }
}
