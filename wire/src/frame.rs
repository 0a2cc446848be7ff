//! The frames the device sends.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::batch::Batch;
use crate::command::Reply;
use crate::framing::{self, DecodeError};
use crate::record::{Event, FaultBits, Halt};

/// Sent once at boot: what the stream is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Header {
    /// [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION) of the sender.
    pub protocol_version: u16,
    /// Sample rate, Hz: sample index / rate = time since boot.
    pub sample_rate_hz: u16,
    /// the schema key of the sender. Last: a protocol-5 header is this
    /// one without it.
    pub schema_key: [u8; 8],
}

impl Header {
    /// This version's header for a stream at `sample_rate_hz` of the
    /// frames whose schema key is `schema_key`.
    pub const fn new(sample_rate_hz: u16, schema_key: [u8; 8]) -> Self {
        Self {
            protocol_version: crate::PROTOCOL_VERSION,
            sample_rate_hz,
            schema_key,
        }
    }
}

/// Heartbeat with counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Status {
    /// [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION) again, so a host that missed the header can check.
    pub protocol_version: u16,
    /// Sample rate again, for a host that joined mid-stream.
    pub sample_rate_hz: u16,
    /// Samples processed since boot.
    pub samples: u32,
    /// Frames that the sink refused since boot.
    pub frames_dropped: u32,
    /// Faults raised since boot or the last re-arm (latched).
    pub faults: FaultBits,
    /// Halt line asserted.
    pub halt: bool,
    /// Samples are being sent.
    pub streaming: bool,
    /// Sequence number the device takes for the next command.
    pub next_command_seq: u32,
    /// What the board counts below the core. A protocol-4 status is
    /// this one without it and the key.
    pub board: BoardCounters,
    /// the schema key again, for a host that joined mid-stream. Last: a
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
/// ([`Command::SelfTest`](crate::Command::SelfTest)): what a person bringing it up would check with
/// a probe, from the device's side.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct SelfTest {
    /// The board's own findings.
    pub board: BoardFindings,
    /// The halt line as the device drives it (true: high, stop).
    pub halt: bool,
    /// Latched faults.
    pub faults: FaultBits,
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

/// The pipeline's state before sample `next_index`: a host that lost
/// frames, or joined late, continues from here. `State` is the core's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema, MaxSize)]
pub struct Snapshot<State> {
    /// The next sample's index.
    pub next_index: u32,
    /// The state.
    pub state: State,
}

/// Everything the device sends. `Config` and `State` are the core's: its
/// configuration frame and its pipeline's state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema, MaxSize)]
pub enum Frame<'a, Config, State> {
    /// Stream header.
    Header(Header),
    /// The configuration.
    Config(Config),
    /// Samples, as raw readings.
    #[serde(borrow)]
    Batch(Batch<'a>),
    /// The pipeline's state.
    Snapshot(Snapshot<State>),
    /// Detected event.
    Event(Event),
    /// Heartbeat.
    Status(Status),
    /// The halt line went up.
    Halt(Halt),
    /// The answer to a command.
    Reply(Reply),
    /// The board's self-test, after the self-test command's reply.
    SelfTest(SelfTest),
}

/// Decode one device frame from the bytes between two `0x00` delimiters
/// into `buffer` (a batch borrows its bytes from it).
pub fn decode<'b, Config, State>(
    cobs_bytes: &[u8],
    buffer: &'b mut [u8],
) -> Result<Frame<'b, Config, State>, DecodeError>
where
    Config: Deserialize<'b>,
    State: Deserialize<'b>,
{
    let body = framing::unframe(cobs_bytes, buffer, framing::frame_check)?;
    framing::parse(body)
}
