//! Stress relaxation of the tissue's force while the needle is held still:
//! a Prony series of up to [`BRANCHES`] branches, each a gain `g_k` and a
//! time constant `τ_k`.
//!
//! σ = F − Σ g_k·(F − r_k), where F is the force the model computes (the
//! capsule's while loading, the shaft's friction and the tip's after the
//! puncture) and `r_k` the part of it branch `k` still holds: equal to F
//! while the needle moves; while it rests, decaying by
//! `a_k = exp(−1/(rate·τ_k))` a sample and following each change of F at
//! once (the hereditary integral over F's increments, so a force that
//! steps at the stop — the cutting force gone — steps in σ too). A force
//! held at a stop therefore falls as F·(1 − Σ g_k·(1 − e^(−t/τ_k))), to
//! F·(1 − Σ g_k) — the 34–41 % fall in a 5 s dwell, τ about 1.5 s, that
//! every real tissue recorded shows.
//!
//! Why only at rest: a sliding needle shears fresh tissue, so the force
//! it meets is unrelaxed, and the friction and stiffness coefficients are
//! fitted on moving samples, where relaxation is part of them already.
//! `needle diagnose` reads relaxation the same way.
//!
//! The decay factors are computed from `τ_k` and the sample rate with
//! micromath's `exp` in `f32`, on the device as on the host (the same
//! bits: software `f32` arithmetic), at the first sample at rest after
//! either changes, and kept in the state; the per-sample work is integer
//! only.
//!
//! | quantity | format | 1 LSB | range |
//! |---|---|---|---|
//! | gain `g_k` | [`FractionQ16`] | 1.5e-5 | 0..=1, Σ ≤ 1 |
//! | `τ_k` | ms, `u32` | 1 ms | 0 (branch off) ..= [`MOST_TAU_MS`] |
//! | `a_k` | Q32, `u32` | 2.3e-10 | 0..1 (saturating at `u32::MAX`) |
//! | `r_k` | µN, `i32` | 1 µN | ±2147 N, saturating |

use micromath::F32Ext;
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use super::fixed::FractionQ16;
use super::params::TissueParams;
use crate::units::MicroNewtons;

/// Samples at the start of a rest whose measured force the hold averages.
pub const HOLD_SAMPLES: u8 = 16;

/// Branches of the Prony series the device computes.
pub const BRANCHES: usize = 2;

/// The longest time constant, ms (1000 s): beyond it a branch is a
/// permanent set, not relaxation, and `a_k` rounds to one.
pub const MOST_TAU_MS: u32 = 1_000_000;

/// One branch: its gain and time constant.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct Branch {
    /// Share of the held force this branch relaxes away, 0..=1.
    pub gain: FractionQ16,
    /// Time constant, ms; 0 turns the branch off.
    pub tau_ms: u32,
}

/// The tissue at rest: whether the needle holds the force it was applied
/// with, and the relaxation spectrum of that force (all gains zero: none).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct Relaxation {
    /// The branches, in any order.
    pub branches: [Branch; BRANCHES],
    /// At rest in the tissue the model holds the force the needle was
    /// applied with (the measured force at the rest's start, within the
    /// static band). Off (the default, and what a protocol-3 stream's
    /// missing field reads as): the friction of the last sliding sample,
    /// clamped to the band, protocol 3's model. Every tissue made from
    /// parameters has it on.
    pub hold_applied: bool,
}

/// Relaxation state: each branch's unrelaxed force and its decay factor
/// for the rate it was computed at.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct RelaxState {
    /// The force the needle was held with since it came to rest in the
    /// tissue (while the first samples are averaged, their running mean);
    /// `None` while it slides.
    hold: Option<MicroNewtons>,
    /// How many of the rest's first samples the hold has averaged (up to
    /// [`HOLD_SAMPLES`]).
    hold_count: u8,
    held: [MicroNewtons; BRANCHES],
    /// F at the last sample.
    last: MicroNewtons,
    /// σ at the last sample at rest.
    last_out: MicroNewtons,
    decay_q32: [u32; BRANCHES],
    /// (rate, τ of each branch) the decay factors are for; recomputed
    /// when the configuration differs.
    decay_for: (u16, [u32; BRANCHES]),
}

impl Relaxation {
    /// From SI parameters (a branch without both keys is off).
    pub const fn from_params(p: &TissueParams) -> Self {
        let pairs = [
            (p.relax_gain_1, p.relax_tau_1_s),
            (p.relax_gain_2, p.relax_tau_2_s),
        ];
        let mut branches = [Branch {
            gain: FractionQ16(0),
            tau_ms: 0,
        }; BRANCHES];
        let mut k = 0;
        while k < BRANCHES {
            if let (Some(gain), Some(tau_s)) = pairs[k] {
                let ms = super::fixed::round_i64(tau_s * 1000.0);
                branches[k] = Branch {
                    gain: FractionQ16::from_ratio(gain),
                    tau_ms: if ms < 0 {
                        0
                    } else if ms > MOST_TAU_MS as i64 {
                        MOST_TAU_MS
                    } else {
                        ms as u32
                    },
                };
            }
            k += 1;
        }
        Self {
            branches,
            hold_applied: true,
        }
    }

    /// The sum of the gains, Q16 (≤ 1 in a valid tissue).
    pub fn total_gain(&self) -> u32 {
        self.branches
            .iter()
            .fold(0u32, |s, b| s.saturating_add(b.gain.0))
    }

    /// The force `force` the tissue exerts on a sliding needle: whole, and
    /// every branch holds it again.
    #[inline(always)]
    pub fn slide(&self, state: &mut RelaxState, force: MicroNewtons) -> MicroNewtons {
        state.last = force;
        state.held = [force; BRANCHES];
        state.hold = None;
        force
    }

    /// The force `force` held by the tissue, relaxed for how long the
    /// needle has been still; `rate_hz` is the sample rate.
    #[inline(always)]
    pub fn at_rest(
        &self,
        state: &mut RelaxState,
        force: MicroNewtons,
        rate_hz: u16,
    ) -> MicroNewtons {
        let [b0, b1] = self.branches;
        let step = force.0.saturating_sub(state.last.0);
        state.last = force;
        state.last_out = force;
        if (b0.gain.0 | b1.gain.0) == 0 {
            state.held = [force; BRANCHES];
            return force;
        }
        if state.decay_for != (rate_hz, [b0.tau_ms, b1.tau_ms]) {
            state.set_decay(self, rate_hz);
        }
        let mut relaxed = force.0 as i64;
        for k in 0..BRANCHES {
            let gain = self.branches[k].gain.0;
            // |decayed| ≤ |held|: the product fits i32 again.
            let decayed = (state.held[k].0 as i64 * state.decay_q32[k] as i64 + (1 << 31)) >> 32;
            let held = (decayed as i32).saturating_add(step);
            state.held[k] = MicroNewtons(held);
            let gone = force.0.saturating_sub(held) as i64;
            relaxed -= (gone * gain as i64 + (1 << 15)) >> 16;
        }
        state.last_out = MicroNewtons(crate::units::saturate_i32(relaxed));
        state.last_out
    }
}

impl RelaxState {
    /// Forget the hold (the needle left the tissue's static band: out of
    /// it, or on the capsule).
    pub fn release(&mut self) {
        self.hold = None;
    }

    /// The force held at rest: the mean measured force over the rest's
    /// first [`HOLD_SAMPLES`] samples, each with what the model had
    /// relaxed away by then added back (one sample's noise held for a
    /// whole dwell was a residual of a noise sd), within the static band
    /// `band()` gives, kept through the rest. The band is asked for only
    /// while the mean is still forming: the needle is still, and the
    /// rest of the dwell costs the sample path nothing for it.
    pub fn hold(
        &mut self,
        measured: MicroNewtons,
        band: impl FnOnce() -> (MicroNewtons, MicroNewtons),
    ) -> MicroNewtons {
        if let (Some(held), HOLD_SAMPLES) = (self.hold, self.hold_count) {
            return held;
        }
        // Each sample as the force it would be unrelaxed: plus what the
        // model relaxed away by the sample before (none at the first). A
        // running mean in i32 (a hardware divide; an i64 one is a library
        // call on the M3).
        let (mean, lost) = match self.hold {
            None => {
                self.hold_count = 0;
                (0, 0)
            }
            Some(mean) => (mean.0, self.last.0.saturating_sub(self.last_out.0)),
        };
        // At most HOLD_SAMPLES: a full hold returned above.
        self.hold_count = self.hold_count.saturating_add(1);
        let delta = measured.0.saturating_add(lost).saturating_sub(mean);
        let mean = mean.saturating_add(delta / i32::from(self.hold_count));
        let (lower, upper) = band();
        let held = MicroNewtons(mean.max(lower.0).min(upper.0));
        self.hold = Some(if self.hold_count == HOLD_SAMPLES {
            held
        } else {
            MicroNewtons(mean)
        });
        held
    }

    /// The decay factors for `relaxation` at `rate_hz`: once per tissue or
    /// rate, out of the per-sample code.
    #[cold]
    #[inline(never)]
    fn set_decay(&mut self, relaxation: &Relaxation, rate_hz: u16) {
        let taus = relaxation.branches.map(|b| b.tau_ms);
        self.decay_q32 = taus.map(|tau_ms| decay_q32(tau_ms, rate_hz));
        self.decay_for = (rate_hz, taus);
    }
}

/// `exp(−1/(rate·τ))` in Q32: the share of a branch's held force left one
/// sample later. 0 for a branch that is off or a rate of zero (nothing is
/// held), `u32::MAX` where it rounds to one. Never inlined: the one
/// float computation on the device stays out of the sample path's code
/// (the firmware-image test finds it by name).
#[inline(never)]
pub fn decay_q32(tau_ms: u32, rate_hz: u16) -> u32 {
    if tau_ms == 0 || rate_hz == 0 {
        return 0;
    }
    let samples = tau_ms as f32 * rate_hz as f32 / 1000.0;
    // micromath by name: on the host `f32::exp` (the platform's libm)
    // would shadow it, and the two sides would differ in the last bits.
    let a = F32Ext::exp(-1.0 / samples);
    let q = a * 4_294_967_296.0;
    if q >= 4_294_967_295.0 {
        u32::MAX
    } else if q > 0.0 {
        q as u32
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spectrum(branches: [(f64, u32); BRANCHES]) -> Relaxation {
        Relaxation {
            branches: branches.map(|(g, tau_ms)| Branch {
                gain: FractionQ16::from_ratio(g),
                tau_ms,
            }),
            hold_applied: true,
        }
    }

    #[test]
    fn decay_factors_are_pinned() {
        // The same bits on the host and the device: these values are what
        // the firmware's micromath computes too (the twin test compares
        // every sample's model force).
        assert_eq!(decay_q32(1500, 500), 4_289_244_416);
        assert_eq!(decay_q32(1500, 100), 4_266_429_440);
        assert_eq!(decay_q32(0, 500), 0);
        assert_eq!(decay_q32(1500, 0), 0);
        // 1000 s at 2 kHz: 1 − 5e-7, which f32 holds to about 10 %; a
        // branch that slow barely moves within a trial.
        assert_eq!(decay_q32(MOST_TAU_MS, 2000), 4_294_965_248);
        // Within f32's precision of the exact factor.
        let exact = (-1.0f64 / 750.0).exp() * 4_294_967_296.0;
        assert!((decay_q32(1500, 500) as f64 - exact).abs() < 1e-6 * exact);
    }

    #[test]
    fn a_held_force_relaxes_as_the_prony_series_and_motion_renews_it() {
        let r = spectrum([(0.25, 500), (0.15, 3000)]);
        let mut s = RelaxState::default();
        let f = MicroNewtons(1_600_000);
        assert_eq!(r.slide(&mut s, f), f);
        // 5 s at rest at 500 Hz.
        let mut last = f;
        for _ in 0..2500 {
            last = r.at_rest(&mut s, f, 500);
        }
        let exact =
            1.6e6 * (1.0 - 0.25 * (1.0 - (-10.0f64).exp()) - 0.15 * (1.0 - (-5.0f64 / 3.0).exp()));
        assert!(
            (last.0 as f64 - exact).abs() < 1e-4 * exact,
            "{last:?} {exact}"
        );
        // Moving again: the whole force.
        assert_eq!(r.slide(&mut s, f), f);
        // A force that steps down at the stop steps down in full, then
        // relaxes from there: one sample's relaxation of the 1.6 N held
        // (0.25·(1 − e^(−1/250)) + 0.15·(1 − e^(−1/1500)) of it, 1.76 mN).
        let lower = MicroNewtons(1_000_000);
        let at_stop = r.at_rest(&mut s, lower, 500);
        assert!((at_stop.0 - (1_000_000 - 1_757)).abs() < 5, "{at_stop:?}");
    }

    #[test]
    fn none_leaves_the_force_and_extremes_saturate() {
        let off = Relaxation::default();
        let mut s = RelaxState::default();
        assert_eq!(
            off.at_rest(&mut s, MicroNewtons(123), 500),
            MicroNewtons(123)
        );
        let full = spectrum([(1.0, 1), (1.0, 1)]);
        for f in [i32::MAX, i32::MIN, 0] {
            full.slide(&mut s, MicroNewtons(f));
            let out = full.at_rest(&mut s, MicroNewtons(f), 65_535);
            assert!(
                out.0 == f || (out.0 as i64).abs() <= (f as i64).abs(),
                "{f}: {out:?}"
            );
        }
    }
}
