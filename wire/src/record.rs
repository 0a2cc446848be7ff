//! What the link reports of the core's vocabulary, as it goes on the wire:
//! events, halts, fault and assist bits, and the two quantities they carry.
//!
//! Each mirrors a type of the core field for field (so the bytes and the
//! schema key are the core's), holding no behaviour: the core converts its
//! own types into these when it sends and back when a host replays, and
//! what a fault bit or an assist bit means is the core's to say.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// A force on the wire: an `i32` of micronewtons (±2147.48 N).
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    Schema,
    MaxSize,
)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct MicroNewtons(pub i32);

/// A position on the wire: an `i32` of nanometres (±2.147 m).
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    Schema,
    MaxSize,
)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Nanometres(pub i32);

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

/// The device's latched faults, a bit each (the core's `Faults` names
/// them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct FaultBits(pub u16);

impl FaultBits {
    /// No fault latched.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
}

/// Robot-assist modes, a bit each (the core's `AssistModes` names them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct AssistBits(pub u8);
