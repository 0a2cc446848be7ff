//! The needle holder's wire format, both directions, defined once for the
//! firmware and the host: the frames the device sends ([`Frame`]), the
//! commands it takes ([`Command`]), how both are framed on the wire
//! ([`framing`]) and how samples are coded into a batch ([`batch`]).
//!
//! **The bottom of the workspace.** This crate depends on no other crate of
//! it. What only the core defines — its configuration, its pipeline's
//! state, a tissue model — the frames and commands carry as type
//! parameters, laid out by serde as the core declares them; the core's
//! vocabulary that the link reports (events, halts, faults, quantities) has
//! its wire form here ([`record`]), and the conversion from the core's own
//! types sits in the core (`needle_holder::protocol`), which also names the
//! instantiated frame and pins its bytes with golden tests.
//!
//! **The stream (version 6).** After boot the device sends a [`Header`]
//! (with the schema key of its frame and command types), a config frame
//! (everything the pipeline computes with: calibration, tissue model,
//! detectors, assist) and a [`Snapshot`] of the pipeline's state; then the
//! samples as [`Batch`]es of raw readings, which the host turns into
//! force, model, residual and phase with the same core. Events and halts
//! go at once, unbatched (the batch in hand is sent first, so frames stay
//! in sample order); a [`Status`] heartbeat with a fresh snapshot follows
//! every [`STATUS_PERIOD_SAMPLES`] samples, so a host that lost a batch or
//! joined late is back in step within half a second at 500 Hz. Every
//! change of configuration or state by a command is followed by a new
//! config frame or snapshot. Loss is visible: batches carry their first
//! sample's index, and each frame its CRC.
//!
//! Changing any type here, or any type the core puts in a frame, changes
//! the bytes on the wire: bump [`PROTOCOL_VERSION`] (the core's golden
//! tests fail until you do: they pin every frame and command kind, the
//! snapshot's whole state with it, and the schema key).
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod batch;
pub mod command;
pub mod frame;
pub mod framing;
pub mod record;

pub use batch::Batch;
pub use command::{Command, CommandError, CommandFrame, Reply};
pub use frame::{BoardCounters, BoardFindings, Frame, Header, SelfTest, Snapshot, Status};
pub use framing::DecodeError;
pub use record::{
    AssistBits, Event, EventKind, FaultBits, Halt, HaltReason, MicroNewtons, Nanometres,
};

/// Version of the frame format; the host refuses other versions.
pub const PROTOCOL_VERSION: u16 = 6;

/// The name the schema key is hashed under (postcard-schema's
/// `Key::for_path`), with the version (a test checks they agree).
pub const SCHEMA_PATH: &str = "needle-holder/6";

/// Samples between two status heartbeats.
pub const STATUS_PERIOD_SAMPLES: u32 = 250;
