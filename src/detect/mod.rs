//! Event detectors.
//!
//! Placeholder seam, replaced by the event-detection issue: contact is the
//! force rising above a threshold, placed back along the stiffness curve by
//! the deformation that threshold needs; puncture is a drop of a configured
//! size below the running peak of the loading phase.

use crate::model::params::TissueParams;
use crate::model::stiffness::Stiffness;
use crate::protocol::{Event, EventKind, Phase};
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// Detector thresholds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DetectConfig {
    /// Force above which the tip is taken to touch the surface.
    pub contact_force: MicroNewtons,
    /// Deformation the stiffness law needs to reach `contact_force`: the
    /// surface is that far behind the position where the threshold is met.
    pub contact_offset: Nanometres,
    /// Smallest peak that counts as a capsule puncture.
    pub puncture_min_peak: MicroNewtons,
    /// Fall below the running peak that confirms a puncture.
    pub puncture_drop: MicroNewtons,
}

impl DetectConfig {
    /// Thresholds for a tissue: contact at its `contact_force_n`; puncture
    /// once the force has peaked above 30 % of the expected puncture force
    /// and fallen by half the expected drop.
    pub const fn for_tissue(p: &TissueParams) -> Self {
        let contact_force = MicroNewtons::from_n(p.contact_force_n);
        Self {
            contact_force,
            contact_offset: Stiffness::from_params(p).deformation_at(contact_force),
            puncture_min_peak: MicroNewtons::from_n(0.3 * p.puncture_force_n),
            puncture_drop: MicroNewtons::from_n(0.5 * (p.puncture_force_n - p.puncture_drop_to_n)),
        }
    }
}

/// Detector state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DetectState {
    peak_force: MicroNewtons,
    peak_x: Nanometres,
}

/// One sample as the detectors see it.
#[derive(Clone, Copy, Debug)]
pub struct DetectInput {
    /// Sample index.
    pub index: u32,
    /// Phase before this sample.
    pub phase: Phase,
    /// Position.
    pub x: Nanometres,
    /// Velocity.
    pub v: NanometresPerSecond,
    /// Measured force.
    pub force: MicroNewtons,
}

impl DetectConfig {
    /// Look at one sample; returns the event it fires, if any. A contact
    /// event's `x` is the estimated surface x_s1; a puncture's is the peak
    /// position x_s2 and its force the peak force.
    pub fn update(&self, state: &mut DetectState, s: DetectInput) -> Option<Event> {
        let event = |kind, x, force| Event {
            index: s.index,
            kind,
            x,
            force,
            confidence_permille: 1000,
        };
        match s.phase {
            Phase::Out => {
                state.peak_force = MicroNewtons::ZERO;
                (s.force > self.contact_force)
                    .then(|| event(EventKind::Contact, s.x.sub(self.contact_offset), s.force))
            }
            Phase::Loading => {
                if s.force > state.peak_force {
                    state.peak_force = s.force;
                    state.peak_x = s.x;
                }
                let dropped = state.peak_force.sub(s.force) >= self.puncture_drop;
                (dropped && state.peak_force >= self.puncture_min_peak)
                    .then(|| event(EventKind::Puncture, state.peak_x, state.peak_force))
            }
            _ => None,
        }
    }
}
