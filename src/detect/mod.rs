//! Event detectors and the phase they imply.
//!
//! Placeholder seam, replaced by the event-detection issue: contact is the
//! force rising above a threshold; puncture is a drop of a configured size
//! below the running peak of the loading phase; withdrawal is the needle
//! moving outwards, and the tip is out again once behind the contact point.

use crate::protocol::{Event, EventKind, Phase};
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// Detector thresholds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DetectConfig {
    /// Force above which the tip is taken to touch the surface.
    pub contact_force: MicroNewtons,
    /// Smallest peak that counts as a capsule puncture.
    pub puncture_min_peak: MicroNewtons,
    /// Fall below the running peak that confirms a puncture.
    pub puncture_drop: MicroNewtons,
    /// Outward speed that marks a withdrawal.
    pub withdrawal_speed: NanometresPerSecond,
}

impl Default for DetectConfig {
    fn default() -> Self {
        Self {
            contact_force: MicroNewtons(50_000),
            puncture_min_peak: MicroNewtons(300_000),
            puncture_drop: MicroNewtons(300_000),
            withdrawal_speed: NanometresPerSecond(500_000),
        }
    }
}

/// Detector state.
#[derive(Clone, Debug)]
pub struct DetectState {
    phase: Phase,
    surface_x: Nanometres,
    peak_force: MicroNewtons,
    peak_x: Nanometres,
}

impl Default for DetectState {
    fn default() -> Self {
        Self {
            phase: Phase::Out,
            surface_x: Nanometres::ZERO,
            peak_force: MicroNewtons::ZERO,
            peak_x: Nanometres::ZERO,
        }
    }
}

impl DetectState {
    /// Current phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }
}

/// One sample as the detectors see it.
#[derive(Clone, Copy, Debug)]
pub struct DetectInput {
    /// Sample index.
    pub index: u32,
    /// Position.
    pub x: Nanometres,
    /// Velocity.
    pub v: NanometresPerSecond,
    /// Measured force.
    pub force: MicroNewtons,
}

impl DetectConfig {
    /// Advance the phase by one sample; returns the event it fired, if any.
    pub fn update(&self, state: &mut DetectState, s: DetectInput) -> Option<Event> {
        let event = |kind, x, force| Event {
            index: s.index,
            kind,
            x,
            force,
            confidence_permille: 1000,
        };
        match state.phase {
            Phase::Out if s.force > self.contact_force => {
                state.phase = Phase::Loading;
                state.surface_x = s.x;
                state.peak_force = s.force;
                state.peak_x = s.x;
                Some(event(EventKind::Contact, s.x, s.force))
            }
            Phase::Loading => {
                if s.force > state.peak_force {
                    state.peak_force = s.force;
                    state.peak_x = s.x;
                }
                let dropped = state.peak_force.sub(s.force) >= self.puncture_drop;
                if dropped && state.peak_force >= self.puncture_min_peak {
                    state.phase = Phase::Inserted;
                    Some(event(EventKind::Puncture, state.peak_x, state.peak_force))
                } else {
                    if s.x < state.surface_x {
                        state.phase = Phase::Out;
                    }
                    None
                }
            }
            Phase::Inserted if s.v.0 < -self.withdrawal_speed.0 => {
                state.phase = Phase::Withdrawal;
                None
            }
            Phase::Withdrawal if s.x < state.surface_x => {
                state.phase = Phase::Out;
                None
            }
            _ => None,
        }
    }
}
