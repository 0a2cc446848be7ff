//! The force the tissue should produce at the needle's current state: the
//! paper's model (eqs. 1–4) in fixed point, every sample.
//!
//! f = stiffness(x − x_s1) while loading the capsule; after puncture
//! f = friction(v, l) + cutting, with l = x − x_s3 the needle length in
//! tissue (Karnopp friction per unit length, see [`friction`]) and cutting
//! a constant while the tip advances into uncut tissue. Zero out of tissue.
//! While the needle is still, the pipeline relaxes this force ([`relax`]).
//!
//! Configuration ([`ModelConfig`], built from [`params::TissueParams`] at
//! compile time for the firmware) is apart from state ([`ModelState`]).
//! The `f64` twin in [`reference`](mod@reference) is the test oracle; the fixed-point
//! error against it is bounded by the property tests in `tests/integration/model.rs`.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

pub mod fixed;
pub mod friction;
pub mod params;
pub mod phase;
pub mod reference;
pub mod relax;
pub mod stiffness;

use self::fixed::FractionQ16;
use self::friction::{Friction, FrictionState};
use self::params::{ParamError, TissueParams};
use self::phase::{PhaseConfig, PhaseState};
use self::stiffness::Stiffness;
use crate::insertion::Phase;
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// The model's parameters in fixed point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct ModelConfig {
    /// Capsule stiffness.
    pub stiffness: Stiffness,
    /// Friction along the needle.
    pub friction: Friction,
    /// Cutting force.
    pub cutting: MicroNewtons,
    /// Phase machine.
    pub phase: PhaseConfig,
}

/// Model state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct ModelState {
    /// Karnopp memory.
    pub friction: FrictionState,
}

/// Outward speed that marks a withdrawal: 0.5 mm/s, well above the
/// velocity noise (20 µm/s at 500 Hz) and below the slowest insertions.
pub const WITHDRAWAL_SPEED: NanometresPerSecond = NanometresPerSecond(500_000);

impl ModelConfig {
    /// Convert and check SI parameters. `const`: the firmware's defaults
    /// are converted by the compiler, so no float code reaches the chip.
    pub const fn from_params(p: &TissueParams) -> Result<Self, ParamError> {
        if let Err(e) = p.validate() {
            return Err(e);
        }
        Ok(Self {
            stiffness: Stiffness::from_params(p),
            friction: Friction::from_params(p),
            cutting: MicroNewtons::from_n(p.cutting_force_n),
            phase: PhaseConfig {
                relaxation: FractionQ16::from_ratio(p.relaxation),
                withdrawal_speed: WITHDRAWAL_SPEED,
                hold_force: MicroNewtons::from_n(p.contact_force_n),
            },
        })
    }

    /// Expected force for the needle at `x` moving at `v`, given the phase
    /// and surface positions, before relaxation ([`relax`]).
    pub fn expected(
        &self,
        state: &mut ModelState,
        phase: &PhaseState,
        x: Nanometres,
        v: NanometresPerSecond,
    ) -> MicroNewtons {
        match phase.phase {
            Phase::Out => MicroNewtons::ZERO,
            Phase::Loading => self.stiffness.force(phase.deformation(x)),
            Phase::Inserted | Phase::Withdrawal => {
                let l = phase.length_in_tissue(x);
                let friction = self.friction.force(&mut state.friction, v, l);
                friction.add(self.cutting_now(phase, x, v))
            }
        }
    }

    /// Whether a needle at rest in `phase` is held by the tissue's static
    /// band ([`static_band`](Self::static_band)): in the tissue past the
    /// capsule. Out of it, or on the capsule, the stiffness law gives the
    /// force at rest too.
    pub fn holds_at_rest(phase: &PhaseState) -> bool {
        matches!(phase.phase, Phase::Inserted | Phase::Withdrawal)
    }

    /// The static band at `x` for a needle at rest in the tissue
    /// ([`holds_at_rest`](Self::holds_at_rest)): the force the tissue can
    /// hold on it, from D_n·l (pulling) to D_p·l plus the cutting force at
    /// the cutting front (the tissue ahead of a stopped tip stays
    /// compressed).
    pub fn static_band(&self, phase: &PhaseState, x: Nanometres) -> (MicroNewtons, MicroNewtons) {
        let (lower, upper) = self.friction.band(phase.length_in_tissue(x));
        let tip = if x >= phase.deepest {
            self.cutting
        } else {
            MicroNewtons::ZERO
        };
        (lower, upper.add(tip))
    }

    /// Whether the needle at `v` slides (outside the Karnopp band): what
    /// renews the tissue's relaxation.
    pub fn sliding(&self, v: NanometresPerSecond) -> bool {
        v.0 >= self.friction.half_band.0 || v.0 <= self.friction.half_band.0.saturating_neg()
    }

    /// Cutting force now: only while advancing (v ≥ Δv/2) at the deepest
    /// point reached, i.e. into tissue not cut before.
    fn cutting_now(
        &self,
        phase: &PhaseState,
        x: Nanometres,
        v: NanometresPerSecond,
    ) -> MicroNewtons {
        if v.0 >= self.friction.half_band.0 && x >= phase.deepest {
            self.cutting
        } else {
            MicroNewtons::ZERO
        }
    }
}
