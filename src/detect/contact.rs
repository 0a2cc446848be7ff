//! Contact: the force rising above a threshold while the needle advances,
//! held for [`CONTACT_CONFIRM_SAMPLES`] samples so that a one-sample spike
//! (the holder accelerating) is not a surface. The event's position is
//! placed back along the stiffness curve by the deformation the threshold
//! needs, so it estimates x_s1 itself.
//!
//! A force above the threshold (either sign) that persists for
//! [`NO_CONTACT_FAULT_SAMPLES`] while the needle is not advancing cannot
//! come from the tissue, which only pushes back on an advancing tip before
//! puncture: it is a drifting or bumped load cell, or a stuck encoder, and
//! raises [`Faults::FORCE_WITHOUT_CONTACT`]. A pull on a needle being
//! withdrawn is the one exception: tissue dragged out with it lets go a
//! few millimetres later (book, *What real recordings look like*), and the phase machine's own
//! judgement of where it let go is only as good as one noisy sample.

use super::{confidence_permille, event, DetectConfig, DetectInput};
use crate::faults::Faults;
use crate::insertion::{Event, EventKind};
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Samples the force must stay above the threshold, advancing, for contact.
pub const CONTACT_CONFIRM_SAMPLES: u16 = 3;
/// Samples of unexplained force before the fault.
pub const NO_CONTACT_FAULT_SAMPLES: u16 = 32;

/// Contact detector state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct ContactState {
    touching_samples: u16,
    unexplained_samples: u16,
}

/// One sample while out of the tissue.
pub fn update(c: &DetectConfig, st: &mut ContactState, s: DetectInput) -> (Option<Event>, Faults) {
    let above = s.force.abs() > c.contact_force;
    let touching = s.force > c.contact_force && s.v.0 > 0;
    let dragged = s.force.0 < 0 && s.v.0 < 0;
    st.touching_samples = if touching {
        st.touching_samples.saturating_add(1)
    } else {
        0
    };
    st.unexplained_samples = if above && !touching && !dragged {
        st.unexplained_samples.saturating_add(1)
    } else {
        0
    };
    let faults = if st.unexplained_samples >= NO_CONTACT_FAULT_SAMPLES {
        Faults::FORCE_WITHOUT_CONTACT
    } else {
        Faults::NONE
    };
    if st.touching_samples < CONTACT_CONFIRM_SAMPLES {
        return (None, faults);
    }
    st.touching_samples = 0;
    let confidence = confidence_permille(s.force, c.contact_force);
    let surface = s.x.sub(c.contact_offset);
    let found = event(&s, EventKind::Contact, surface, s.force, confidence);
    (Some(found), faults)
}
