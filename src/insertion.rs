//! An insertion as the pipeline sees it, sample by sample: where the
//! needle is in it ([`Phase`]), each processed [`Sample`], what the
//! detectors saw ([`Event`]) and why the halt line went up ([`Halt`]).
//! The core's own vocabulary: the model, the detectors and assist speak
//! it, and the wire protocol carries it as it is.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// Where the needle is in the insertion, as the device tracks it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Phase {
    /// Tip outside the tissue.
    Out,
    /// Tip pressing on the capsule, before puncture.
    Loading,
    /// Tip inside the tissue, after puncture.
    Inserted,
    /// Needle moving out of the tissue.
    Withdrawal,
}

/// What a detector saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum EventKind {
    /// The tip met the surface.
    Contact,
    /// The capsule gave way.
    Puncture,
    /// The tip struck and passed an interior structure (vessel).
    Structure,
    /// The tip left the tissue into another medium.
    Exit,
    /// A fault was raised (see the next status frame).
    Fault,
}

/// One processed sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Sample {
    /// Sample index since boot.
    pub index: u32,
    /// Needle position.
    pub x: Nanometres,
    /// Needle velocity (windowed difference, see `kinematics`).
    pub v: NanometresPerSecond,
    /// Measured force.
    pub force: MicroNewtons,
    /// Force the model expects here.
    pub model: MicroNewtons,
    /// `force − model`, saturating.
    pub residual: MicroNewtons,
    /// Phase at this sample.
    pub phase: Phase,
}

/// A detected event.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Event {
    /// Sample index at which it was flagged.
    pub index: u32,
    /// What it was.
    pub kind: EventKind,
    /// Needle position at the event.
    pub x: Nanometres,
    /// Force at the event (for a puncture: the peak before the drop).
    pub force: MicroNewtons,
    /// Detector's confidence figure, 0–1000 (per mille).
    pub confidence_permille: u16,
}

/// Why the device asserted the halt line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum HaltReason {
    /// A fault (see the status frame).
    Fault,
    /// Stop on contact.
    Contact,
    /// Stop on capsule puncture.
    Puncture,
    /// Stop on an interior structure.
    Structure,
    /// Stop on exit from the tissue.
    Exit,
    /// The target depth past the surface was reached.
    TargetDepth,
    /// Faster than the speed limit before puncture.
    SpeedLimit,
}

impl From<EventKind> for HaltReason {
    fn from(kind: EventKind) -> Self {
        match kind {
            EventKind::Contact => Self::Contact,
            EventKind::Puncture => Self::Puncture,
            EventKind::Structure => Self::Structure,
            EventKind::Exit => Self::Exit,
            EventKind::Fault => Self::Fault,
        }
    }
}

/// Sent when the halt line goes up: why, and where the robot should hold
/// the tip (behind it when the device asks for a back-off).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Halt {
    /// Sample index at which the line went up.
    pub index: u32,
    /// Why.
    pub reason: HaltReason,
    /// Needle position then.
    pub x: Nanometres,
    /// Position the robot should bring the needle to and hold.
    pub hold_x: Nanometres,
}
