//! Capsule puncture: the force peaks after its steady rise and drops
//! sharply (paper §3.1). Confirmed against the model: the peak must reach
//! 30 % of the puncture force the tissue's model expects and the drop half
//! of the drop it expects, so noise and small dips do not fire it. The
//! event's position and force are the peak's (x_s2).
//!
//! Beside it, the stuck-encoder check: while the capsule is loaded, force
//! only rises when the tip advances, so a large rise with the encoder
//! standing still means the encoder has stopped counting.

use super::{confidence_permille, event, DetectConfig, DetectInput};
use crate::faults::Faults;
use crate::protocol::{Event, EventKind, Phase};
use crate::units::{MicroNewtons, Nanometres};
use serde::{Deserialize, Serialize};

/// Puncture detector state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PunctureState {
    peak_force: MicroNewtons,
    peak_x: Nanometres,
    /// Position and force when the encoder last moved.
    still_x: Nanometres,
    still_force: MicroNewtons,
}

impl PunctureState {
    /// Forget the running peak (the tip is out of the tissue).
    pub fn restart(&mut self) {
        self.peak_force = MicroNewtons::ZERO;
    }
}

/// One sample while loading the capsule.
pub fn update(c: &DetectConfig, st: &mut PunctureState, s: DetectInput) -> Option<Event> {
    if s.force > st.peak_force {
        st.peak_force = s.force;
        st.peak_x = s.x;
    }
    let drop = st.peak_force.sub(s.force);
    let punctured = drop >= c.puncture_drop && st.peak_force >= c.puncture_min_peak;
    punctured.then(|| {
        let confidence = confidence_permille(drop, c.puncture_drop);
        event(
            &s,
            EventKind::Puncture,
            st.peak_x,
            st.peak_force,
            confidence,
        )
    })
}

/// [`Faults::ENCODER_STUCK`] when the force has risen by `stuck_rise`
/// during loading since the encoder last moved.
pub fn stuck_encoder(c: &DetectConfig, st: &mut PunctureState, s: DetectInput) -> Faults {
    if s.x != st.still_x || s.phase != Phase::Loading {
        st.still_x = s.x;
        st.still_force = s.force;
        return Faults::NONE;
    }
    if s.force.sub(st.still_force) > c.stuck_rise {
        Faults::ENCODER_STUCK
    } else {
        Faults::NONE
    }
}
