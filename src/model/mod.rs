//! The force the tissue should produce at the needle's current state.
//!
//! Placeholder seam: the paper's model (capsule stiffness, Karnopp friction,
//! cutting) replaces [`ModelConfig::expected`] in the model issue. Until
//! then the model expects no force, so the residual is the measured force.

use crate::protocol::Phase;
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// Model parameters (none yet).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ModelConfig;

impl ModelConfig {
    /// Expected force for the needle at `x` moving at `v` in `phase`.
    pub fn expected(&self, _phase: Phase, _x: Nanometres, _v: NanometresPerSecond) -> MicroNewtons {
        MicroNewtons::ZERO
    }
}
