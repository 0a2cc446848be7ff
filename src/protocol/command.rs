//! Commands, host → device, and the device's replies
//! ([`needle_wire::command`]) with the core's tissue model, and the reader
//! that takes them off the line byte by byte on the device.

use postcard::experimental::max_size::MaxSize;

use super::wire::encoded_bound;
use crate::assist::AssistModes;
use crate::config::TissueModel;
use crate::units::Nanometres;

pub use crate::calibration::MIN_GAIN_Q16;
pub use needle_wire::command::{
    text, CommandError, Reply, ReplyText, NO_READING_YET, REPLY_TEXT_BYTES,
};

/// What the host can ask.
pub type Command = needle_wire::Command<TissueModel>;

/// A command as it goes on the wire.
pub type CommandFrame = needle_wire::CommandFrame<TissueModel>;

/// [`Command::SetAssist`] of the core's modes and depth.
pub fn set_assist(modes: AssistModes, target_depth: Nanometres) -> Command {
    Command::SetAssist {
        modes: modes.into(),
        target_depth: target_depth.into(),
    }
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
        huge.model.cutting = crate::units::MicroNewtons::MIN;
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
                modes: needle_wire::AssistBits(u8::MAX),
                target_depth: needle_wire::Nanometres(i32::MIN),
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
