//! Robot assist: when the device asserts the halt line for the robot, and
//! what it asks of it then.
//!
//! The halt line means "do not advance"; it is asserted in the same sample
//! as the cause and stays asserted (latched, like faults) until reset.
//! With each assertion the device sends a [`Halt`] frame with the reason and
//! the position the robot should hold, which is behind the tip when it
//! asks for a back-off.
//!
//! Modes, any combination ([`AssistModes`]):
//! - stop on an event: contact, puncture, structure, exit;
//! - stop at a target depth past the surface x_s1;
//! - back off after a puncture stop by the relaxation distance x_s2 − x_s3
//!   (where the tissue surface settled after the capsule gave way);
//! - before puncture, a speed limit that falls linearly from `max_speed` at
//!   no force to `min_speed` at the puncture force the tissue's model
//!   expects: slow down as the capsule nears giving way, so the stop after
//!   the puncture comes within a short overshoot.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::insertion::{EventKind, Halt, HaltReason, Phase, Sample};
use crate::model::params::TissueParams;
use crate::model::phase::PhaseState;
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// A set of assist modes, one bit each.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct AssistModes(pub u8);

impl AssistModes {
    /// No assist: the halt line follows faults only.
    pub const NONE: Self = Self(0);
    /// Stop when the tip meets the surface.
    pub const STOP_ON_CONTACT: Self = Self(1 << 0);
    /// Stop when the capsule gives way.
    pub const STOP_ON_PUNCTURE: Self = Self(1 << 1);
    /// Stop at an interior structure (vessel).
    pub const STOP_ON_STRUCTURE: Self = Self(1 << 2);
    /// Stop when the tip leaves the tissue.
    pub const STOP_ON_EXIT: Self = Self(1 << 3);
    /// Stop at the target depth past the surface.
    pub const TARGET_DEPTH: Self = Self(1 << 4);
    /// After a puncture stop, ask for a retraction by x_s2 − x_s3.
    pub const BACK_OFF: Self = Self(1 << 5);
    /// Before puncture, stop when faster than the force-dependent limit.
    pub const SPEED_LIMIT: Self = Self(1 << 6);
    /// Names, for configuration and display.
    pub const NAMES: [(Self, &'static str); 7] = [
        (Self::STOP_ON_CONTACT, "contact"),
        (Self::STOP_ON_PUNCTURE, "puncture"),
        (Self::STOP_ON_STRUCTURE, "structure"),
        (Self::STOP_ON_EXIT, "exit"),
        (Self::TARGET_DEPTH, "depth"),
        (Self::BACK_OFF, "back-off"),
        (Self::SPEED_LIMIT, "speed-limit"),
    ];

    /// Every mode this firmware knows.
    pub const ALL: Self = Self((1 << Self::NAMES.len()) - 1);

    /// True when no bit names a mode this firmware does not know.
    pub const fn is_known(self) -> bool {
        self.0 & !Self::ALL.0 == 0
    }

    /// Union of two sets.
    pub const fn union(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }

    /// True when every mode of `other` is on.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }
}

/// Shallowest target depth a command (or a saved setting) may set.
pub const MIN_TARGET_DEPTH: Nanometres = Nanometres::from_m(0.0001);
/// Deepest target depth a command (or a saved setting) may set.
pub const MAX_TARGET_DEPTH: Nanometres = Nanometres::from_m(0.1);

/// True for a target depth within [`MIN_TARGET_DEPTH`]..=[`MAX_TARGET_DEPTH`].
pub const fn target_depth_is_valid(depth: Nanometres) -> bool {
    depth.0 >= MIN_TARGET_DEPTH.0 && depth.0 <= MAX_TARGET_DEPTH.0
}

/// Assist configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct AssistConfig {
    /// Modes in force.
    pub modes: AssistModes,
    /// Depth past the surface x_s1 to stop at ([`AssistModes::TARGET_DEPTH`]).
    pub target_depth: Nanometres,
    /// Speed limit with no force on the tip.
    pub max_speed: NanometresPerSecond,
    /// Speed limit at the expected puncture force.
    pub min_speed: NanometresPerSecond,
    /// Puncture force the tissue's model expects.
    pub expected_peak: MicroNewtons,
}

impl AssistConfig {
    /// `modes` for a tissue: the speed limit scales with its puncture
    /// force, from 10 mm/s down to 1 mm/s; target depth 30 mm.
    pub const fn for_tissue(p: &TissueParams, modes: AssistModes) -> Self {
        Self::for_peak(MicroNewtons::from_n(p.puncture_force_n), modes)
    }

    /// [`Self::for_tissue`] for a tissue whose puncture force is
    /// `expected_peak`.
    pub const fn for_peak(expected_peak: MicroNewtons, modes: AssistModes) -> Self {
        Self {
            modes,
            target_depth: Nanometres::from_m(0.03),
            max_speed: NanometresPerSecond::from_mps(0.010),
            min_speed: NanometresPerSecond::from_mps(0.001),
            expected_peak,
        }
    }

    /// The speed limit at `force`: linear from `max_speed` at zero to
    /// `min_speed` at the expected peak, and `min_speed` beyond it.
    pub fn speed_limit(&self, force: MicroNewtons) -> NanometresPerSecond {
        let peak = i64::from(self.expected_peak.0.max(1));
        let f = i64::from(force.0).clamp(0, peak);
        let (hi, lo) = (i64::from(self.max_speed.0), i64::from(self.min_speed.0));
        NanometresPerSecond((hi - (hi - lo) * f / peak) as i32)
    }

    /// Whether this sample halts the robot, and why. `phase` is the phase
    /// state after the sample; `event` what the detectors flagged in it.
    /// Inlined into the per-sample step, where most modes are off and the
    /// call cost more than the checks.
    #[inline]
    pub fn check(&self, phase: &PhaseState, s: &Sample, event: Option<EventKind>) -> Option<Halt> {
        let m = self.modes;
        let halt = |reason, hold_x| Halt {
            index: s.index,
            reason,
            x: s.x,
            hold_x,
        };
        let stop_on = match event {
            Some(EventKind::Contact) => m.contains(AssistModes::STOP_ON_CONTACT),
            Some(EventKind::Puncture) => m.contains(AssistModes::STOP_ON_PUNCTURE),
            Some(EventKind::Structure) => m.contains(AssistModes::STOP_ON_STRUCTURE),
            Some(EventKind::Exit) => m.contains(AssistModes::STOP_ON_EXIT),
            _ => false,
        };
        if let Some(kind) = event.filter(|_| stop_on) {
            let back = if kind == EventKind::Puncture && m.contains(AssistModes::BACK_OFF) {
                phase.puncture.sub(phase.relaxed_surface)
            } else {
                Nanometres::ZERO
            };
            return Some(halt(HaltReason::from(kind), s.x.sub(back)));
        }
        if m.contains(AssistModes::TARGET_DEPTH)
            && s.phase != Phase::Out
            && phase.deformation(s.x) >= self.target_depth
        {
            return Some(halt(
                HaltReason::TargetDepth,
                phase.surface.add(self.target_depth),
            ));
        }
        // The limit (a 64-bit division) only when the mode is on: this runs
        // every sample.
        if m.contains(AssistModes::SPEED_LIMIT)
            && s.phase == Phase::Loading
            && s.v > self.speed_limit(s.force)
        {
            return Some(halt(HaltReason::SpeedLimit, s.x));
        }
        None
    }
}
