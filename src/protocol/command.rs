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

use super::wire::{encoded_bound, varint_len, DecodeError};
use super::HaltReason;
use crate::assist::AssistModes;
use crate::config::TissueModel;
use crate::units::{MicroNewtons, Nanometres};

/// What the host can ask.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize, Schema)]
pub enum Command {
    /// Make the load cell's present reading its zero (the mean of the last
    /// quarter second or so). Refused with the needle in tissue, or with
    /// more than 0.5 N on it ([`crate::calibration::MOST_TARE_OFFSET`]).
    Tare,
    /// Model and detectors from the on-device tissue library, by position
    /// (`needle device tissues` lists them).
    SelectTissue(u8),
    /// Model and detectors from a tissue the host converted to fixed point
    /// (from what `needle fit --toml` writes, say); the device checks it.
    UploadTissue(TissueModel),
    /// Robot-assist modes and the target depth past the surface.
    SetAssist {
        /// Modes, [`AssistModes`] bits.
        modes: AssistModes,
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
    /// stays the tare's. Kept in the settings. At least
    /// [`MIN_GAIN_Q16`] in magnitude; the sign is the wiring's.
    SetLoadCellGain(i32),
    /// Test the board: a [`crate::protocol::SelfTest`] frame follows the
    /// reply (the board reads its converter's registers, counts its
    /// data-ready edges, reads its encoder).
    SelfTest,
}

/// A command as it goes on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, MaxSize, Schema)]
pub struct CommandFrame {
    /// Sequence number (see the module's docs).
    pub seq: u32,
    /// What to do.
    pub command: Command,
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

pub use crate::calibration::MIN_GAIN_Q16;

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

/// Largest command frame before COBS, CRC included: the largest command
/// frame postcard can write (an upload: a tissue's fixed-point model and
/// thresholds), from the types themselves, and the CRC-16.
pub const MAX_RAW_COMMAND: usize = CommandFrame::POSTCARD_MAX_SIZE + 2;
/// Largest command frame on the wire.
pub const MAX_ENCODED_COMMAND: usize = encoded_bound(MAX_RAW_COMMAND);

/// Collects command bytes as they arrive (a byte at a time from a UART
/// interrupt, or a block at a time) into whole frames. Bounded: a run of
/// bytes longer than any command is thrown away up to its zero and
/// reported once as [`CommandError::Corrupted`].
#[derive(Clone, Debug)]
pub struct CommandReader {
    buf: [u8; MAX_ENCODED_COMMAND],
    len: usize,
    overflowed: bool,
}

impl Default for CommandReader {
    fn default() -> Self {
        Self {
            buf: [0; MAX_ENCODED_COMMAND],
            len: 0,
            overflowed: false,
        }
    }
}

impl CommandReader {
    /// Feed one byte; at a frame's end, the decoded frame (with its
    /// check, which tells a retry from a replay) or why it is none.
    /// Zeros with nothing before them (idle line, a host's resync) say
    /// nothing.
    pub fn push(&mut self, byte: u8) -> Option<Result<(CommandFrame, u16), CommandError>> {
        if byte != 0 {
            match self.buf.get_mut(self.len) {
                Some(slot) => {
                    *slot = byte;
                    self.len += 1;
                }
                None => self.overflowed = true,
            }
            return None;
        }
        let len = core::mem::take(&mut self.len);
        if core::mem::take(&mut self.overflowed) {
            return Some(Err(CommandError::Corrupted));
        }
        if len == 0 {
            return None;
        }
        let mut raw = [0u8; MAX_ENCODED_COMMAND];
        Some(
            super::wire::unframe(
                self.buf.get(..len).unwrap_or(&[]),
                &mut raw,
                crate::protocol::wire::frame_check,
            )
            .map_err(CommandError::from)
            .and_then(|body| {
                let check = crate::protocol::wire::frame_check(body);
                Ok((super::wire::parse::<CommandFrame>(body)?, check))
            }),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::LIBRARY_MODELS;
    use crate::model::stiffness::Stiffness;
    use crate::protocol::wire::Encoder;

    #[test]
    fn the_largest_command_fits_its_bound_and_every_command_reads_back() {
        let mut huge = LIBRARY_MODELS[0];
        huge.model.stiffness = Stiffness::Rational {
            a_q48: i64::MIN,
            b_q32: i64::MIN,
        };
        huge.model.cutting = MicroNewtons::MIN;
        huge.relaxation.branches = [crate::model::relax::Branch {
            gain: crate::model::fixed::FractionQ16(u32::MAX),
            tau_ms: u32::MAX,
        }; crate::model::relax::BRANCHES];
        huge.relaxation.hold_applied = true;
        let commands = [
            Command::Tare,
            Command::SelectTissue(u8::MAX),
            Command::UploadTissue(huge),
            Command::SetAssist {
                modes: AssistModes(u8::MAX),
                target_depth: Nanometres::MIN,
            },
            Command::Rearm,
            Command::Stream(false),
            Command::ReadConfig,
            Command::SetLoadCellGain(i32::MIN),
            Command::SelfTest,
        ];
        for command in commands {
            let frame = CommandFrame {
                seq: u32::MAX,
                command,
            };
            let mut encoder = Encoder::<MAX_ENCODED_COMMAND>::default();
            let bytes = encoder.encode(&frame).to_vec();
            assert!(!bytes.is_empty(), "{command:?} does not fit");
            let mut reader = CommandReader::default();
            let mut got = None;
            for &b in &bytes {
                got = reader.push(b).or(got);
            }
            assert_eq!(got.map(|r| r.map(|(f, _)| f)), Some(Ok(frame)));
        }
    }

    #[test]
    fn a_run_longer_than_any_command_is_one_corrupted_frame() {
        let mut reader = CommandReader::default();
        let answers: std::vec::Vec<_> = core::iter::repeat_n(0x55u8, 3 * MAX_ENCODED_COMMAND)
            .chain([0, 0, 0])
            .filter_map(|b| reader.push(b))
            .collect();
        assert_eq!(answers, [Err(CommandError::Corrupted)]);
    }
}
