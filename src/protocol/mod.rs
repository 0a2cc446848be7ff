//! The wire format as this core speaks it: [`needle_wire`]'s frames and
//! commands filled in with the core's configuration, pipeline state and
//! tissue model, and the conversions between the core's own vocabulary
//! ([`crate::insertion`], [`crate::faults`], [`crate::assist`],
//! [`crate::units`]) and its wire form. The conversions live here and
//! nowhere else; `needle_wire` knows nothing of the core.
//!
//! The stream, the framing and the sample coding are described in
//! [`needle_wire`]. Changing a type carried here (the configuration, any
//! detector's state) changes the bytes on the wire as surely as changing
//! one there: bump [`PROTOCOL_VERSION`] (the golden tests fail until you
//! do: `golden.rs` pins every frame and command kind, the snapshot's
//! whole state with it).

pub mod batch;
pub mod command;
mod convert;
#[cfg(test)]
mod golden;

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

pub use needle_wire::framing as wire;
pub use needle_wire::{
    BoardCounters, BoardFindings, DecodeError, Event, EventKind, FaultBits, Halt, HaltReason,
    Header, SelfTest, Status, PROTOCOL_VERSION, SCHEMA_PATH, STATUS_PERIOD_SAMPLES,
};

pub use self::batch::Batch;
pub use self::command::{Command, CommandError, CommandFrame, Reply};

pub use crate::calibration::MIN_GAIN_Q16;
pub use crate::config::TissueSource;

use crate::config::DeviceConfig;
use crate::pipeline::PipelineState;

/// The schema of everything on the wire, frames and commands alike:
/// postcard-schema's [`Key`](postcard_schema::key::Key), an FNV-1a hash
/// computed at compile time of every field's and variant's name and every
/// value's data-model type, down to each detector's state in the snapshot
/// (not the types' own names, nor a heapless capacity, which the crate
/// leaves out). The header and every status carry it; a host refuses a
/// stream whose key is not its own under the same [`PROTOCOL_VERSION`] —
/// a build that changed a type without a new version — and a golden test
/// pins it with the version.
pub const SCHEMA_KEY: [u8; 8] =
    postcard_schema::key::Key::for_path::<(Frame<'static>, CommandFrame)>(SCHEMA_PATH).to_bytes();

/// This build's header for a stream at `sample_rate_hz`.
pub const fn header(sample_rate_hz: u16) -> Header {
    Header::new(sample_rate_hz, SCHEMA_KEY)
}

/// What the device computes with, from the next sample on: sent after the
/// header, after every change, on request, and now and then for a host
/// that joined late. The same configuration always gives the same bytes,
/// and their hash seeds every batch's check ([`batch::BatchCheck::seed`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct ConfigFrame {
    /// Where the tissue model came from.
    pub tissue: TissueSource,
    /// What the board's settings store held at boot.
    pub stored: crate::persist::Loaded,
    /// The whole pipeline's configuration: load-cell tare and gain,
    /// encoder scale, rate, model, detectors, assist.
    pub config: DeviceConfig,
}

/// The pipeline's state before sample `next_index`.
pub type Snapshot = needle_wire::Snapshot<PipelineState>;

/// Everything the device sends.
pub type Frame<'a> = needle_wire::Frame<'a, ConfigFrame, PipelineState>;

/// Largest frame before COBS, CRC included: postcard's bound of the
/// largest kind (a full batch; the snapshot's state is the next).
pub const MAX_RAW_FRAME: usize = Frame::POSTCARD_MAX_SIZE + 2;

/// Bytes one encoded frame can take on the wire.
pub const MAX_ENCODED_FRAME: usize = wire::encoded_bound(MAX_RAW_FRAME);

/// The device's frame encoder.
pub type FrameEncoder = wire::Encoder<MAX_ENCODED_FRAME>;

/// Decode one device frame from the bytes between two `0x00` delimiters
/// into `buffer` (a batch borrows its bytes from it).
pub fn decode<'b>(cobs_bytes: &[u8], buffer: &'b mut [u8]) -> Result<Frame<'b>, DecodeError> {
    needle_wire::frame::decode(cobs_bytes, buffer)
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_wire::{MicroNewtons, Nanometres};

    fn decode_owned(bytes: &[u8]) -> std::string::String {
        let mut buf = [0u8; MAX_ENCODED_FRAME];
        std::format!("{:?}", decode(&bytes[..bytes.len() - 1], &mut buf))
    }

    fn batch_frame() -> Frame<'static> {
        Frame::Batch(Batch {
            first_index: 1234,
            samples: 2,
            check: [1, 2, 3, 4],
            raw: &[0x80, 0x01, 0x02, 0x03, 0x04],
        })
    }

    /// Pins the wire format. If this fails you changed the bytes on the
    /// wire: bump PROTOCOL_VERSION and update the expectation.
    #[test]
    fn golden_bytes_pin_the_wire_format() {
        let mut encoder = FrameEncoder::default();
        let bytes = encoder.encode(&batch_frame());
        assert_eq!(PROTOCOL_VERSION, 6);
        // COBS code, tag 2, index 1234, 2 samples, the check, 5 raw bytes,
        // the CRC (0xa0b0, checked against a bitwise CRC-16/X.25 over the
        // implied version byte 6 and the body), the zero.
        assert_eq!(
            bytes,
            &[
                0x11, 0x02, 0xd2, 0x09, 0x02, 0x01, 0x02, 0x03, 0x04, 0x05, 0x80, 0x01, 0x02, 0x03,
                0x04, 0xb0, 0xa0, 0x00
            ][..]
        );
    }

    #[test]
    fn any_single_bit_error_is_caught() {
        let good = FrameEncoder::default().encode(&batch_frame()).to_vec();
        let body = &good[..good.len() - 1];
        for bit in 0..body.len() * 8 {
            let mut bad = body.to_vec();
            bad[bit / 8] ^= 1 << (bit % 8);
            let mut buf = [0u8; MAX_ENCODED_FRAME];
            assert!(
                decode(&bad, &mut buf).is_err(),
                "bit {bit} flipped went unnoticed"
            );
        }
    }

    #[test]
    fn every_variant_round_trips_within_the_size_bound() {
        let full = [0xffu8; batch::BATCH_BYTES];
        let mut state = PipelineState::default();
        let mut config = crate::config::DEFAULT;
        // The largest a tissue's relaxation can write.
        config.relaxation.branches = [crate::model::relax::Branch {
            gain: crate::model::fixed::FractionQ16(u32::MAX),
            tau_ms: u32::MAX,
        }; crate::model::relax::BRANCHES];
        for i in 0..40 {
            config.step(
                &mut state,
                crate::pipeline::RawSample {
                    adc: Some(crate::hal::AdcSample {
                        counts: i32::MIN + i,
                        saturated: false,
                        overrun: false,
                    }),
                    encoder_count: (i * 150) as u16,
                },
            );
        }
        let frames = [
            Frame::Header(header(500)),
            Frame::Config(ConfigFrame {
                tissue: TissueSource::Library(u8::MAX),
                stored: crate::persist::Loaded::SavedBeforeTorn,
                config,
            }),
            Frame::Batch(Batch {
                first_index: u32::MAX,
                samples: u8::MAX,
                check: [0xff; 4],
                raw: &full,
            }),
            Frame::Snapshot(Snapshot {
                next_index: u32::MAX,
                state,
            }),
            Frame::Event(Event {
                index: u32::MAX,
                kind: EventKind::Puncture,
                x: Nanometres(i32::MIN),
                force: MicroNewtons(i32::MAX),
                confidence_permille: 1000,
            }),
            Frame::Status(Status {
                protocol_version: PROTOCOL_VERSION,
                sample_rate_hz: u16::MAX,
                samples: u32::MAX,
                frames_dropped: u32::MAX,
                faults: FaultBits(u16::MAX),
                halt: true,
                streaming: true,
                next_command_seq: u32::MAX,
                board: BoardCounters {
                    conversions_lost: u32::MAX,
                    line_errors: u32::MAX,
                },
                schema_key: [0xff; 8],
            }),
            Frame::Halt(Halt {
                index: u32::MAX,
                reason: HaltReason::SpeedLimit,
                x: Nanometres(i32::MAX),
                hold_x: Nanometres(i32::MIN),
            }),
            Frame::Reply(Reply {
                seq: u32::MAX,
                result: Err(CommandError::InvalidTissue {
                    field: command::text(&"x".repeat(60)),
                    problem: command::text(&"é".repeat(60)),
                }),
            }),
        ];
        for frame in frames {
            let mut encoder = FrameEncoder::default();
            let bytes = encoder.encode(&frame);
            assert!(
                !bytes.is_empty() && bytes.len() <= MAX_ENCODED_FRAME,
                "{frame:?}"
            );
            assert_eq!(
                bytes.iter().filter(|&&b| b == 0).count(),
                1,
                "only the terminator is zero"
            );
            assert_eq!(
                decode_owned(bytes),
                std::format!("{:?}", Ok::<_, DecodeError>(frame))
            );
        }
    }

    /// The velocity state's bound, written out (postcard knows no bound
    /// of its window), is what its largest value encodes to.
    #[test]
    fn the_velocity_states_bound_is_its_largest_encoding() {
        fn len(value: &impl Serialize) -> usize {
            let mut buf = [0u8; 1024];
            postcard::to_slice(value, &mut buf).unwrap().len()
        }
        let mut velocity = crate::kinematics::VelocityState::default();
        let config = crate::kinematics::VelocityConfig {
            sample_rate_hz: 500,
            window: u8::MAX,
        };
        for _ in 0..100 {
            velocity.update(&config, crate::units::Nanometres::MIN);
        }
        assert_eq!(
            len(&velocity),
            crate::kinematics::VelocityState::POSTCARD_MAX_SIZE
        );
    }
}
