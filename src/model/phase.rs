//! The insertion phase machine and the surface positions it finds (the
//! paper's Figure 4):
//!
//! ```text
//! out ──contact (x_s1)──> loading ──puncture (x_s2)──> inserted ⇄ withdrawal ──x ≤ x_s3, let go──> out
//!  ^                         │ x < x_s1 (backed off)                  (v ≷ ∓ withdrawal speed)
//!  └─────────────────────────┘
//! ```
//!
//! At puncture the surface relaxes to x_s3 = x_s1 + ρ·(x_s2 − x_s1), and
//! the length of needle in tissue is l = x − x_s3 from then on.
//!
//! A withdrawing needle drags the tissue out with it: real recordings pull
//! on the needle until 1.5–9 mm *before* x_s1 (book, *What real
//! recordings look like*). So behind x_s3 a withdrawal only ends once the
//! tissue lets go — the pull falls under the contact threshold — or the tip is further before x_s1 than the
//! capsule was pushed in before it gave way (x_s2 − x_s1): a tissue cannot
//! be drawn out further than it was pushed in, and a pull beyond that is a
//! fault for the contact detector to find.

use super::fixed::FractionQ16;
use crate::insertion::{EventKind, Phase};
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Phase machine configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct PhaseConfig {
    /// Surface relaxation ρ.
    pub relaxation: FractionQ16,
    /// Outward speed that turns `inserted` into `withdrawal` (and inward
    /// speed that turns it back).
    pub withdrawal_speed: NanometresPerSecond,
    /// A pull on the needle beyond this means the tissue still holds it.
    pub hold_force: MicroNewtons,
}

/// Phase and the surface positions found so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct PhaseState {
    /// Current phase.
    pub phase: Phase,
    /// x_s1: where the tip met the surface.
    pub surface: Nanometres,
    /// x_s2: where the capsule gave way.
    pub puncture: Nanometres,
    /// x_s3: the relaxed surface after puncture.
    pub relaxed_surface: Nanometres,
    /// Deepest tip position since puncture: tissue beyond it is uncut.
    pub deepest: Nanometres,
}

impl Default for PhaseState {
    fn default() -> Self {
        Self {
            phase: Phase::Out,
            surface: Nanometres::ZERO,
            puncture: Nanometres::ZERO,
            relaxed_surface: Nanometres::ZERO,
            deepest: Nanometres::ZERO,
        }
    }
}

impl PhaseState {
    /// Length of needle in tissue after puncture, l = x − x_s3 (≥ 0).
    pub fn length_in_tissue(&self, x: Nanometres) -> Nanometres {
        Nanometres(x.sub(self.relaxed_surface).0.max(0))
    }

    /// Deformation of the capsule before puncture, x − x_s1.
    pub fn deformation(&self, x: Nanometres) -> Nanometres {
        x.sub(self.surface)
    }
}

impl PhaseConfig {
    /// Whether the tissue still holds a needle at `x` behind x_s3 pulled
    /// by `force` (see the module notes).
    fn dragged(&self, s: &PhaseState, x: Nanometres, force: MicroNewtons) -> bool {
        let furthest = s.surface.sub(s.puncture.sub(s.surface));
        force.0 < self.hold_force.0.saturating_neg() && x > furthest
    }

    /// Advance by one sample. `event` is what the detectors fired this
    /// sample (kind and where it places the surface or puncture); `force`
    /// the measured force.
    pub fn update(
        &self,
        s: &mut PhaseState,
        event: Option<(EventKind, Nanometres)>,
        x: Nanometres,
        v: NanometresPerSecond,
        force: MicroNewtons,
    ) {
        match (s.phase, event) {
            (Phase::Out, Some((EventKind::Contact, x_s1))) => {
                s.phase = Phase::Loading;
                s.surface = x_s1;
            }
            (Phase::Loading, Some((EventKind::Puncture, x_s2))) => {
                s.phase = Phase::Inserted;
                s.puncture = x_s2;
                s.relaxed_surface = s
                    .surface
                    .add(Nanometres(self.relaxation.of(x_s2.sub(s.surface).0)));
                s.deepest = x;
            }
            (Phase::Loading, _) if x < s.surface => s.phase = Phase::Out,
            (Phase::Inserted | Phase::Withdrawal, _) if x <= s.relaxed_surface => {
                s.phase = if self.dragged(s, x, force) {
                    Phase::Withdrawal
                } else {
                    Phase::Out
                }
            }
            (Phase::Inserted, _) if v.0 <= self.withdrawal_speed.0.saturating_neg() => {
                s.phase = Phase::Withdrawal
            }
            (Phase::Withdrawal, _) if v.0 >= self.withdrawal_speed.0 => s.phase = Phase::Inserted,
            _ => {}
        }
        if matches!(s.phase, Phase::Inserted | Phase::Withdrawal) && x > s.deepest {
            s.deepest = x;
        }
    }
}
