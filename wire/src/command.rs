//! Commands, host → device, and the device's replies.
//!
//! A command travels like a device frame (postcard, CRC with the implied
//! version byte, COBS, `0x00`), as a [`CommandFrame`]: a sequence number
//! and the command. The device answers every frame that ends in a zero
//! with a [`Reply`] frame: the sequence number and `Ok` or the reason it
//! refused. A refused command changes nothing.
//!
//! **Sequence numbers** rise by one per command, from the device's
//! `next_command_seq` (in every status frame and in a stale reply). The
//! device acts on a number above the last it took; the same frame again
//! (a host retrying after a lost reply) gets the same reply without
//! acting twice; anything else at or below the last is refused as
//! [`CommandError::Stale`], so a captured command replayed later does
//! nothing.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::framing::{varint_len, DecodeError};
use crate::record::{AssistBits, HaltReason, MicroNewtons, Nanometres};

/// What the host can ask. `Tissue` is the core's fixed-point tissue model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize, Schema)]
pub enum Command<Tissue> {
    /// Make the load cell's present reading its zero (the mean of the last
    /// quarter second or so). Refused with the needle in tissue, or with
    /// more than 0.5 N on it.
    Tare,
    /// Model and detectors from the on-device tissue library, by position
    /// (`needle device tissues` lists them).
    SelectTissue(u8),
    /// Model and detectors from a tissue the host converted to fixed point
    /// (from what `needle fit --toml` writes, say); the device checks it.
    UploadTissue(Tissue),
    /// Robot-assist modes and the target depth past the surface.
    SetAssist {
        /// Modes, a bit each.
        modes: AssistBits,
        /// Target depth, 0.1–100 mm.
        target_depth: Nanometres,
    },
    /// Release the halt line; refused while what raised it persists.
    Rearm,
    /// Start (`true`) or stop the sample stream; events, halts, status
    /// and replies go on regardless.
    Stream(bool),
    /// Send the configuration (a config frame) now.
    ReadConfig,
    /// The load cell's gain, µN per count in Q16.16, as a calibration
    /// with a known mass found it (`needle device calibrate`); the zero
    /// stays the tare's. Kept in the settings. At least the core's
    /// `MIN_GAIN_Q16` in magnitude; the sign is the wiring's.
    SetLoadCellGain(i32),
    /// Test the board: a [`SelfTest`](crate::SelfTest) frame follows the
    /// reply (the board reads its converter's registers, counts its
    /// data-ready edges, reads its encoder).
    SelfTest,
}

/// A command as it goes on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize, Schema)]
pub struct CommandFrame<Tissue> {
    /// Sequence number (see the module's docs).
    pub seq: u32,
    /// What to do.
    pub command: Command<Tissue>,
}

/// A short text carried in a reply (a tissue parameter's name, a problem).
pub type ReplyText = heapless::String<REPLY_TEXT_BYTES>;

/// Bytes a [`ReplyText`] holds.
pub const REPLY_TEXT_BYTES: usize = 48;

/// Why the device refused a command.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum CommandError {
    /// The frame was not one: bad COBS, bad CRC (corrupted, truncated, or
    /// another protocol version), or longer than any command.
    Corrupted,
    /// The CRC matched but the bytes are no command this device knows.
    Unknown,
    /// The sequence number was used before: send `next_seq`.
    Stale {
        /// The number the device takes next.
        next_seq: u32,
    },
    /// No tissue at this position in the library.
    NoSuchTissue {
        /// Entries in the library.
        library_len: u8,
    },
    /// A tissue parameter fails its check.
    InvalidTissue {
        /// The parameter, as in the TOML file.
        field: ReplyText,
        /// What is wrong with it.
        problem: ReplyText,
    },
    /// A parameter of the command is out of its range.
    OutOfRange {
        /// Which.
        field: ReplyText,
    },
    /// Taring or setting the gain with the needle in tissue would move
    /// the tissue's force under it.
    NeedleInTissue,
    /// More than 0.5 N on the load cell: a load, not an offset.
    LoadOnNeedle {
        /// The force the present zero reads.
        force: MicroNewtons,
    },
    /// The halt cannot be released: its cause is still there.
    HaltCausePersists {
        /// What would halt the robot again at once.
        reason: HaltReason,
    },
}

/// Written out: postcard knows heapless 0.7's `String`, not this 0.8's.
/// The largest variant is [`CommandError::InvalidTissue`]'s two texts
/// (a test encodes every variant at its largest and fails to compile
/// when one is added without it).
impl MaxSize for CommandError {
    const POSTCARD_MAX_SIZE: usize = 1 + 2 * (varint_len(REPLY_TEXT_BYTES) + REPLY_TEXT_BYTES);
}

impl From<DecodeError> for CommandError {
    fn from(e: DecodeError) -> Self {
        match e {
            DecodeError::Postcard => Self::Unknown,
            DecodeError::Cobs | DecodeError::Crc => Self::Corrupted,
        }
    }
}

/// The [`CommandError::OutOfRange`] field of a tare asked for before the
/// load cell's first readings: nothing is out of range, there is nothing
/// yet to make the zero of.
pub const NO_READING_YET: &str = "no reading yet";

impl CommandError {
    /// An [`Self::OutOfRange`] naming `field`.
    pub fn out_of_range(field: &str) -> Self {
        Self::OutOfRange { field: text(field) }
    }
}

/// `s` cut to fit a [`ReplyText`] at a character boundary.
pub fn text(s: &str) -> ReplyText {
    let mut out = ReplyText::new();
    for c in s.chars() {
        if out.push(c).is_err() {
            break;
        }
    }
    out
}

/// The device's answer to one command frame.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct Reply {
    /// The command's sequence number; 0 when the frame was too damaged to
    /// read one.
    pub seq: u32,
    /// Done, or why not.
    pub result: Result<(), CommandError>,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bounds written out by hand (where postcard knows no type's) are
    /// what the largest value of each encodes to: neither short, which
    /// would drop a frame, nor long.
    #[test]
    fn the_reply_errors_bound_is_its_largest_encoding() {
        fn len(value: &impl Serialize) -> usize {
            let mut buf = [0u8; 1024];
            postcard::to_slice(value, &mut buf).unwrap().len()
        }
        let text = text(&"é".repeat(60));
        assert_eq!(text.len(), REPLY_TEXT_BYTES);
        // Every reason at its largest; the match fails to compile when a
        // reason is added, until it is here.
        let errors = [
            CommandError::Corrupted,
            CommandError::Unknown,
            CommandError::Stale { next_seq: u32::MAX },
            CommandError::NoSuchTissue {
                library_len: u8::MAX,
            },
            CommandError::InvalidTissue {
                field: text.clone(),
                problem: text.clone(),
            },
            CommandError::OutOfRange { field: text },
            CommandError::NeedleInTissue,
            CommandError::LoadOnNeedle {
                force: MicroNewtons(i32::MIN),
            },
            CommandError::HaltCausePersists {
                reason: HaltReason::SpeedLimit,
            },
        ];
        for error in &errors {
            match error {
                CommandError::Corrupted
                | CommandError::Unknown
                | CommandError::Stale { .. }
                | CommandError::NoSuchTissue { .. }
                | CommandError::InvalidTissue { .. }
                | CommandError::OutOfRange { .. }
                | CommandError::NeedleInTissue
                | CommandError::LoadOnNeedle { .. }
                | CommandError::HaltCausePersists { .. } => {}
            }
        }
        let largest = errors.iter().map(len).max();
        assert_eq!(largest, Some(CommandError::POSTCARD_MAX_SIZE));
    }
}
