//! Event detectors.
//!
//! - contact: the force rising above a threshold, placed back along the
//!   stiffness curve by the deformation that threshold needs;
//! - puncture: a drop of the size the tissue's model expects below the
//!   running peak of the loading phase;
//! - structure: after the capsule, while the needle advances, a rise of the
//!   force of at least `structure_rise` above a slowly following baseline,
//!   built over at least 10 samples, then a sharp fall of at least
//!   `structure_drop` below the highest of the last 3 samples — a vessel wall loading
//!   up and giving way. The baseline follows the force upwards with a time
//!   constant of 2^10 samples, so the slow growth of friction with depth is
//!   not a wall; a stop (the encoder no longer advancing) restarts it, so
//!   the cutting force vanishing at a stop is not a wall either; the 10
//!   samples of rise reject one-sample spikes (an acceleration of the
//!   holder).

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
    /// Least rise of the force that can be an interior structure.
    pub structure_rise: MicroNewtons,
    /// Least fall after it.
    pub structure_drop: MicroNewtons,
}

/// Samples over which a structure's fall must come.
const STRUCTURE_SHARP_SAMPLES: usize = 3;
/// Samples a structure's rise must take at least.
const STRUCTURE_RISE_SAMPLES: u32 = 10;
/// The structure baseline follows the force upwards by 2^-this per sample.
const STRUCTURE_BASELINE_SHIFT: u32 = 10;

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
            // Vessel walls in liver give way at 0.15 N and more (paper §3,
            // Figs. 2–3); 16× the 5 mN noise this is tuned for.
            structure_rise: MicroNewtons(100_000),
            structure_drop: MicroNewtons(80_000),
        }
    }
}

/// Detector state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DetectState {
    peak_force: MicroNewtons,
    peak_x: Nanometres,
    peak_index: u32,
    trough_force: MicroNewtons,
    trough_index: u32,
    /// Positions of the last two samples, newest first.
    previous_x: [Nanometres; 2],
    /// Forces of the last samples while advancing, newest first.
    recent_force: [MicroNewtons; STRUCTURE_SHARP_SAMPLES],
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
        // Moving inwards over the last two samples (encoder counts, no lag).
        let advancing = s.x > state.previous_x[1];
        state.previous_x = [s.x, state.previous_x[0]];
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
                let punctured = dropped && state.peak_force >= self.puncture_min_peak;
                let found =
                    punctured.then(|| event(EventKind::Puncture, state.peak_x, state.peak_force));
                if punctured {
                    state.restart_structure(s);
                }
                found
            }
            Phase::Inserted if advancing => self.structure(state, s),
            Phase::Inserted => {
                state.restart_structure(s);
                None
            }
            _ => None,
        }
    }

    /// Rise-then-sharp-fall of the force while advancing after puncture.
    fn structure(&self, state: &mut DetectState, s: DetectInput) -> Option<Event> {
        let before = state.recent_force.iter().copied().max().unwrap_or(s.force);
        let rise = before.sub(state.trough_force);
        let fall = before.sub(s.force);
        let wall = rise >= self.structure_rise
            && fall >= self.structure_drop
            && state.peak_index.wrapping_sub(state.trough_index) >= STRUCTURE_RISE_SAMPLES;
        if wall {
            let found = Event {
                index: s.index,
                kind: EventKind::Structure,
                x: state.peak_x,
                force: state.peak_force,
                confidence_permille: (fall.0 as i64 * 1000 / rise.0.max(1) as i64).clamp(0, 1000)
                    as u16,
            };
            state.restart_structure(s);
            return Some(found);
        }
        if s.force < state.trough_force {
            state.restart_structure(s);
            return None;
        }
        // The baseline creeps up towards the force (rounding up, so it moves).
        let gap = s.force.sub(state.trough_force).0;
        state.trough_force.0 +=
            (gap + (1 << STRUCTURE_BASELINE_SHIFT) - 1) >> STRUCTURE_BASELINE_SHIFT;
        if s.force > state.peak_force {
            state.peak_force = s.force;
            state.peak_x = s.x;
            state.peak_index = s.index;
        }
        state.recent_force.rotate_right(1);
        state.recent_force[0] = s.force;
        None
    }
}

impl DetectState {
    /// Start looking for a structure afresh from this sample.
    fn restart_structure(&mut self, s: DetectInput) {
        self.trough_force = s.force;
        self.trough_index = s.index;
        self.recent_force = [s.force; STRUCTURE_SHARP_SAMPLES];
        self.peak_force = s.force;
        self.peak_x = s.x;
        self.peak_index = s.index;
    }
}
