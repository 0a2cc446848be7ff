//! The wire protocol, defined once and used by the firmware and the host
//! alike: the frames the device sends ([`Frame`]), the commands it takes
//! ([`command`]), and how both are framed on the wire ([`wire`]).
//!
//! **The stream (version 6).** After boot the device sends a [`Header`]
//! (with the [`SCHEMA_KEY`] of its frame and command types),
//! a [`ConfigFrame`] (everything the pipeline computes with: calibration,
//! tissue model, detectors, assist) and a [`Snapshot`] of the pipeline's
//! state; then the samples as [`batch`]es of raw readings, which the host
//! turns into force, model, residual and phase with the same core. Events
//! and halts go at once, unbatched (the batch in hand is sent first, so
//! frames stay in sample order); a [`Status`] heartbeat with a fresh
//! snapshot follows every [`STATUS_PERIOD_SAMPLES`] samples, so a host that
//! lost a batch or joined late is back in step within half a second at
//! 500 Hz. Every change of configuration or state by a command is followed
//! by a new config frame or snapshot. Loss is visible: batches carry their
//! first sample's index, and each frame its CRC.
//!
//! Changing any type here changes the bytes on the wire: bump
//! [`PROTOCOL_VERSION`] (the golden tests fail until you do: `golden.rs`
//! pins every frame and command kind, the snapshot's whole state with it).

pub mod batch;
pub mod command;
#[cfg(test)]
mod golden;
pub mod wire;

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

pub use self::batch::Batch;
pub use self::command::{Command, CommandError, CommandFrame, Reply};
pub use self::wire::DecodeError;

pub use crate::calibration::MIN_GAIN_Q16;
pub use crate::config::TissueSource;
pub use crate::insertion::{Event, EventKind, Halt, HaltReason, Phase, Sample};

use crate::config::DeviceConfig;
use crate::faults::Faults;
use crate::pipeline::PipelineState;

/// Version of the frame format; the host refuses other versions.
pub const PROTOCOL_VERSION: u16 = 6;

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

/// The name [`SCHEMA_KEY`] is hashed under, with the version (a test
/// checks they agree).
pub const SCHEMA_PATH: &str = "needle-holder/6";

/// Samples between two status heartbeats.
pub const STATUS_PERIOD_SAMPLES: u32 = 250;

/// Sent once at boot: what the stream is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Header {
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u16,
    /// Sample rate, Hz: sample index / rate = time since boot.
    pub sample_rate_hz: u16,
    /// [`SCHEMA_KEY`] of the sender. Last: a protocol-5 header is this
    /// one without it.
    pub schema_key: [u8; 8],
}

impl Header {
    /// This build's header for a stream at `sample_rate_hz`.
    pub const fn new(sample_rate_hz: u16) -> Self {
        Self {
            protocol_version: PROTOCOL_VERSION,
            sample_rate_hz,
            schema_key: SCHEMA_KEY,
        }
    }
}

/// Heartbeat with counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Status {
    /// [`PROTOCOL_VERSION`] again, so a host that missed the header can check.
    pub protocol_version: u16,
    /// Sample rate again, for a host that joined mid-stream.
    pub sample_rate_hz: u16,
    /// Samples processed since boot.
    pub samples: u32,
    /// Frames that the sink refused since boot.
    pub frames_dropped: u32,
    /// Faults raised since boot or the last re-arm (latched).
    pub faults: Faults,
    /// Halt line asserted.
    pub halt: bool,
    /// Samples are being sent.
    pub streaming: bool,
    /// Sequence number the device takes for the next command.
    pub next_command_seq: u32,
    /// What the board counts below the core. A protocol-4 status is
    /// this one without it and the key.
    pub board: BoardCounters,
    /// [`SCHEMA_KEY`] again, for a host that joined mid-stream. Last: a
    /// protocol-5 status is this one without it.
    pub schema_key: [u8; 8],
}

/// What a board counts below the core, since boot: zero on a board that
/// has neither (the QEMU boards, whose converter is a replay and whose
/// link cannot err).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct BoardCounters {
    /// Conversions whose data-ready fell but that were never read (the
    /// sample task held off past a period): each made its sample
    /// `sample_overrun`.
    pub conversions_lost: u32,
    /// Receive errors on the command line (overrun, noise, framing);
    /// the frames they fell in failed their CRC and were answered so.
    pub line_errors: u32,
}

/// What the board found when asked to test itself
/// ([`Command::SelfTest`]): what a person bringing it up would check with
/// a probe, from the device's side.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SelfTest {
    /// The board's own findings.
    pub board: BoardFindings,
    /// The halt line as the device drives it (true: high, stop).
    pub halt: bool,
    /// Latched faults.
    pub faults: Faults,
    /// The board's counters since boot.
    pub counters: BoardCounters,
}

/// What only the board can look at for a [`SelfTest`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct BoardFindings {
    /// The converter's configuration registers read back now, and as
    /// written at its start; `None` where they were not read: a board
    /// without a converter (the replay boards), one that did not start,
    /// or one that has stopped converting.
    pub adc_registers: Option<([u8; 4], [u8; 4])>,
    /// Data-ready edges over the last whole second; `None` where nothing
    /// counts them (the replay boards) or before a whole second was.
    pub data_ready_per_s: Option<u32>,
    /// How many the converter's configuration makes a second (the
    /// replay's rate on the replay boards).
    pub data_ready_expected_per_s: u32,
    /// The encoder's count now; `None` where the task that owns the
    /// encoder did not run (a silent converter stops it on the real
    /// board).
    pub encoder_count: Option<u16>,
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

/// The pipeline's state before sample `next_index`: a host that lost
/// frames, or joined late, continues from here.
#[derive(Clone, Debug, Serialize, Deserialize, Schema, MaxSize)]
pub struct Snapshot {
    /// The next sample's index.
    pub next_index: u32,
    /// The state.
    pub state: PipelineState,
}

/// Everything the device sends.
#[derive(Clone, Debug, Serialize, Deserialize, Schema, MaxSize)]
pub enum Frame<'a> {
    /// Stream header.
    Header(Header),
    /// The configuration.
    Config(ConfigFrame),
    /// Samples, as raw readings.
    #[serde(borrow)]
    Batch(Batch<'a>),
    /// The pipeline's state.
    Snapshot(Snapshot),
    /// Detected event.
    Event(Event),
    /// Heartbeat.
    Status(Status),
    /// The halt line went up.
    Halt(Halt),
    /// The answer to a command.
    Reply(Reply),
    /// The board's self-test, after [`Command::SelfTest`]'s reply.
    SelfTest(SelfTest),
}

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
    let body = wire::unframe(cobs_bytes, buffer, wire::frame_check)?;
    wire::parse(body)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::{MicroNewtons, Nanometres};

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
            Frame::Header(Header::new(500)),
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
                x: Nanometres::MIN,
                force: MicroNewtons::MAX,
                confidence_permille: 1000,
            }),
            Frame::Status(Status {
                protocol_version: PROTOCOL_VERSION,
                sample_rate_hz: u16::MAX,
                samples: u32::MAX,
                frames_dropped: u32::MAX,
                faults: Faults(u16::MAX),
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
                x: Nanometres::MAX,
                hold_x: Nanometres::MIN,
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

    /// The bounds written out by hand (where postcard knows no type's) are
    /// what the largest value of each encodes to: neither short, which
    /// would drop a frame, nor long.
    #[test]
    fn the_bounds_written_out_are_the_largest_values_encodings() {
        fn len(value: &impl Serialize) -> usize {
            let mut buf = [0u8; 1024];
            postcard::to_slice(value, &mut buf).unwrap().len()
        }
        let raw = [0x80u8; batch::BATCH_BYTES];
        let batch = Batch {
            first_index: u32::MAX,
            samples: u8::MAX,
            check: [0xff; 4],
            raw: &raw,
        };
        assert_eq!(len(&batch), Batch::POSTCARD_MAX_SIZE);
        let text = command::text(&"é".repeat(60));
        assert_eq!(text.len(), command::REPLY_TEXT_BYTES);
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
                force: MicroNewtons::MIN,
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
        let mut velocity = crate::kinematics::VelocityState::default();
        let config = crate::kinematics::VelocityConfig {
            sample_rate_hz: 500,
            window: u8::MAX,
        };
        for _ in 0..100 {
            velocity.update(&config, Nanometres::MIN);
        }
        assert_eq!(
            len(&velocity),
            crate::kinematics::VelocityState::POSTCARD_MAX_SIZE
        );
    }
}
