//! Frame stream decoding on the host: split at `0x00`, check and decode
//! each frame (COBS, CRC, exactly one frame), turn batches back into
//! samples with the core's [`Reconstructor`], track sample-index gaps,
//! and refuse protocol versions other than 2 to 5 and this build's (6),
//! and a stream of this build's version but another schema.
//!
//! All five are read: a frame passes the CRC of exactly one of them
//! (versions 3 on cover an implied version byte, see
//! `needle_holder::protocol::wire`), so a capture of any decodes.
//!
//! Written here rather than with postcard's `CobsAccumulator` because that
//! knows no CRC and does not say how many bytes it threw away; this decoder
//! counts every skipped byte.

use needle_holder::insertion::{Event, Halt, Sample};
use needle_holder::protocol::wire::{self, DecodeError, FRAME_CRC};
use needle_holder::protocol::{
    self, ConfigFrame, Frame, Header, Reply, SelfTest, Snapshot, Status, MAX_ENCODED_FRAME,
    PROTOCOL_VERSION,
};
use needle_holder::stream::{Reconstructor, Withheld};

/// Frames of protocol version 2 (23-byte samples, one frame each): the
/// types as they were, so old captures still decode.
mod v2 {
    use needle_holder::insertion::Sample;
    use needle_holder::protocol::{Event, FaultBits as Faults, Halt};
    use serde::{Deserialize, Serialize};

    #[derive(Serialize, Deserialize)]
    pub struct Header {
        pub protocol_version: u16,
        pub sample_rate_hz: u16,
    }

    #[derive(Serialize, Deserialize)]
    pub struct Status {
        pub protocol_version: u16,
        pub sample_rate_hz: u16,
        pub samples: u32,
        pub frames_dropped: u32,
        pub faults: Faults,
        pub halt: bool,
    }

    #[derive(Serialize, Deserialize)]
    pub enum Frame {
        Header(Header),
        Sample(Sample),
        Event(Event),
        Status(Status),
        Halt(Halt),
    }
}

/// Frames of protocol versions 3 to 5: this build's, but for fields a
/// later version appended as the last of a frame — version 4 the tissue's
/// relaxation to the configuration and the pipeline's state, version 5
/// the board's counters to the status, version 6 the schema's key to the
/// header. An older body with the defaults appended (no relaxation,
/// nothing counted, a key of zeros, which no check reads) is this
/// version's body, so old captures decode with this build's types and
/// the core's reconstruction.
mod older {
    use needle_holder::model::relax::{RelaxState, Relaxation};
    use needle_holder::protocol::wire;
    use needle_holder::protocol::{BoardCounters, MAX_ENCODED_FRAME};

    /// The postcard tags of `Frame::Header`, `Frame::Config`,
    /// `Frame::Snapshot` and `Frame::Status`.
    const HEADER: u8 = 0;
    const CONFIG: u8 = 1;
    const SNAPSHOT: u8 = 3;
    const STATUS: u8 = 5;

    /// The versions read this way, newest first.
    pub const VERSIONS: [u16; 3] = [5, 4, 3];

    /// The version whose framing `chunk` passes, and its body as this
    /// version's.
    pub fn body(chunk: &[u8]) -> Option<(u16, Vec<u8>)> {
        VERSIONS
            .iter()
            .find_map(|&v| Some((v, as_current(v, unframed(chunk, v)?)?)))
    }

    fn unframed(chunk: &[u8], version: u16) -> Option<Vec<u8>> {
        let mut buffer = [0u8; MAX_ENCODED_FRAME];
        let check = |b: &[u8]| wire::frame_check_of_version(version, b);
        Some(wire::unframe(chunk, &mut buffer, check).ok()?.to_vec())
    }

    fn as_current(version: u16, mut body: Vec<u8>) -> Option<Vec<u8>> {
        let no_key = [0u8; 8];
        match body.first() {
            Some(&CONFIG) if version < 4 => {
                body.extend(postcard::to_allocvec(&Relaxation::default()).ok()?)
            }
            Some(&SNAPSHOT) if version < 4 => {
                body.extend(postcard::to_allocvec(&RelaxState::default()).ok()?)
            }
            Some(&STATUS) => {
                if version < 5 {
                    body.extend(postcard::to_allocvec(&BoardCounters::default()).ok()?);
                }
                if version < 6 {
                    body.extend(no_key);
                }
            }
            Some(&HEADER) if version < 6 => body.extend(no_key),
            _ => {}
        }
        Some(body)
    }
}

/// A frame other than a batch (batches become [`Item::Sample`]s).
#[derive(Clone, Debug)]
pub enum Message {
    Header(Header),
    Config(Box<ConfigFrame>),
    /// Boxed: a pipeline's state is large beside the other frames.
    Snapshot(Box<Snapshot>),
    Event(Event),
    Status(Status),
    Halt(Halt),
    Reply(Reply),
    SelfTest(SelfTest),
}

/// Why samples are missing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Missing {
    /// Their frames never arrived.
    Lost,
    /// They arrived but could not be given: see [`Withheld`].
    Withheld(Withheld),
}

/// One thing found in the stream.
#[derive(Clone, Debug)]
pub enum Item {
    /// A sample, as the device computed it.
    Sample(Sample),
    /// A frame that decoded cleanly.
    Frame(Message),
    /// Bytes that did not form a frame (noise, a partial frame at the start
    /// or end, a corrupted frame), with why.
    Skipped { bytes: usize, reason: &'static str },
    /// Samples `first..=last` are missing.
    Gap { first: u32, last: u32, why: Missing },
    /// The sample index went back after sample `last` (the device
    /// restarted, or a stretch of the stream came twice): what follows is
    /// a new segment, its indices (and times) from their own start.
    Restart { last: u32 },
}

/// Counters over a whole stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamStats {
    pub frames: u64,
    pub samples: u64,
    pub events: u64,
    pub skipped_bytes: u64,
    pub skipped_runs: u64,
    pub gaps: u64,
    pub lost_samples: u64,
    /// Samples that arrived but were withheld (out of step, or failing
    /// the device's check).
    pub withheld_samples: u64,
    /// Bytes of the stream, delimiters included.
    pub bytes: u64,
    /// Times the sample index went back (new segments).
    pub restarts: u64,
}

/// The stream speaks a protocol version this needle cannot read,
/// contradicts itself about its version, or is of this build's version
/// but another schema ([`protocol::SCHEMA_KEY`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VersionMismatch {
    /// The version a header or status names (or whose framing a newer
    /// device's frames pass).
    pub found: u16,
    /// The version whose framing the frame passed.
    pub framed_as: u16,
    /// The schema key of a header of this build's version that is not
    /// this build's ([`protocol::SCHEMA_KEY`]).
    pub schema_key: Option<[u8; 8]>,
}

impl std::fmt::Display for VersionMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(key) = self.schema_key {
            return write!(
                f,
                "the device's frames are of schema {} and this needle's of schema {}, both under protocol version {} ({}): one of the two was built with a frame or command type changed and no new PROTOCOL_VERSION — build both from one checkout",
                hex(&key),
                hex(&protocol::SCHEMA_KEY),
                self.found,
                protocol::SCHEMA_PATH
            );
        }
        let readable = self.found == 2
            || older::VERSIONS.contains(&self.found)
            || self.found == PROTOCOL_VERSION;
        if readable && self.found != self.framed_as {
            write!(
                f,
                "a frame of protocol version {} says version {}: the stream contradicts itself (a corrupt capture, or a build that changed its frames without a new PROTOCOL_VERSION)",
                self.framed_as, self.found
            )
        } else {
            write!(
                f,
                "the device speaks protocol version {}, this needle reads versions 2 to 5 and {}: rebuild one to match the other",
                self.found, PROTOCOL_VERSION
            )
        }
    }
}

/// Frames in a row that must pass a newer version's framing before the
/// stream is taken for that version's: a run of bytes passes one of
/// [`NEWER_VERSIONS`] CRCs by chance once in 4 000 frames.
const NEWER_IN_A_ROW: u32 = 3;
/// Versions past this build's tried on a frame no known version reads.
const NEWER_VERSIONS: u16 = 16;

impl std::error::Error for VersionMismatch {}

/// A schema key (or any bytes) as lowercase hex, as `needle` prints it.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Incremental decoder: feed bytes as they arrive.
#[derive(Debug, Default)]
pub struct StreamDecoder {
    pending: Vec<u8>,
    /// Bytes thrown away since the pending buffer overflowed.
    overflow: usize,
    next_index: Option<u32>,
    /// Where the segment before a restart stopped: a later jump forward
    /// to it is that segment going on (a stretch of the stream came
    /// twice), not samples lost.
    resume_at: Option<u32>,
    reconstructor: Reconstructor,
    stats: StreamStats,
    /// A newer version whose framing the last frames passed, and how many
    /// in a row.
    newer: Option<(u16, u32)>,
}

impl StreamDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// The device's configuration, once a config frame has arrived.
    pub fn config(&self) -> Option<&needle_holder::config::DeviceConfig> {
        self.reconstructor.config()
    }

    /// The bytes of the frame being read, since the last delimiter (none
    /// when what came since is longer than any frame): what a capture
    /// begun now starts with, so that it starts with a whole frame.
    pub fn partial_frame(&self) -> Option<&[u8]> {
        (self.overflow == 0).then_some(self.pending.as_slice())
    }

    /// Decode what `bytes` completes; call `on_item` for each item.
    pub fn feed(
        &mut self,
        bytes: &[u8],
        mut on_item: impl FnMut(Item),
    ) -> Result<(), VersionMismatch> {
        self.stats.bytes += bytes.len() as u64;
        for &byte in bytes {
            if byte != 0 {
                if self.pending.len() < MAX_ENCODED_FRAME {
                    self.pending.push(byte);
                } else {
                    self.overflow += 1;
                }
                continue;
            }
            let chunk = std::mem::take(&mut self.pending);
            let overflow = std::mem::take(&mut self.overflow);
            if overflow > 0 {
                self.skip(
                    chunk.len() + overflow + 1,
                    "longer than any frame",
                    &mut on_item,
                );
                continue;
            }
            if chunk.is_empty() {
                continue;
            }
            self.chunk(&chunk, &mut on_item)?;
        }
        Ok(())
    }

    fn chunk(
        &mut self,
        chunk: &[u8],
        on_item: &mut impl FnMut(Item),
    ) -> Result<(), VersionMismatch> {
        let mut buffer = [0u8; MAX_ENCODED_FRAME];
        match protocol::decode(chunk, &mut buffer) {
            Ok(frame) => {
                self.newer = None;
                return self.accept(frame, chunk, PROTOCOL_VERSION, on_item);
            }
            Err(DecodeError::Crc) => {}
            Err(_) => {
                self.newer = None;
                self.skip(chunk.len() + 1, "undecodable frame", on_item);
                return Ok(());
            }
        }
        if let Some((version, body)) = older::body(chunk) {
            self.newer = None;
            return match wire::parse::<Frame>(&body) {
                Ok(frame) => self.accept(frame, chunk, version, on_item),
                Err(_) => {
                    self.skip(chunk.len() + 1, "undecodable frame", on_item);
                    Ok(())
                }
            };
        }
        let mut buffer = [0u8; MAX_ENCODED_FRAME];
        match wire::unframe(chunk, &mut buffer, |b| FRAME_CRC.checksum(b)) {
            Ok(body) => {
                self.newer = None;
                match wire::parse::<v2::Frame>(body) {
                    Ok(frame) => self.accept_v2(frame, on_item),
                    Err(_) => {
                        self.skip(chunk.len() + 1, "undecodable frame", on_item);
                        Ok(())
                    }
                }
            }
            Err(_) => {
                self.newer_version(chunk)?;
                self.skip(chunk.len() + 1, "CRC mismatch", on_item);
                Ok(())
            }
        }
    }

    /// A newer device's frames fail every CRC this build knows: after
    /// [`NEWER_IN_A_ROW`] frames in a row that pass one newer version's,
    /// the stream is that version's (not noise, nor a wrong baud rate).
    fn newer_version(&mut self, chunk: &[u8]) -> Result<(), VersionMismatch> {
        match newer_framing(chunk) {
            Some(v) => {
                let run = match self.newer {
                    Some((seen, n)) if seen == v => n + 1,
                    _ => 1,
                };
                self.newer = Some((v, run));
                if run >= NEWER_IN_A_ROW {
                    return Err(VersionMismatch {
                        found: v,
                        framed_as: v,
                        schema_key: None,
                    });
                }
            }
            None => self.newer = None,
        }
        Ok(())
    }

    /// End of stream: whatever is pending is an incomplete frame.
    pub fn finish(&mut self, mut on_item: impl FnMut(Item)) -> StreamStats {
        let n = std::mem::take(&mut self.pending).len() + std::mem::take(&mut self.overflow);
        if n > 0 {
            self.skip(n, "incomplete frame at end of stream", &mut on_item);
        }
        self.stats
    }

    fn skip(&mut self, bytes: usize, reason: &'static str, on_item: &mut impl FnMut(Item)) {
        self.stats.skipped_bytes += bytes as u64;
        self.stats.skipped_runs += 1;
        on_item(Item::Skipped { bytes, reason });
    }

    /// Samples up to `index` (exclusive) that should have come and did not.
    fn missing_before(&mut self, index: u32, why: Missing, on_item: &mut impl FnMut(Item)) {
        if let (Some(expected), Some(resume)) = (self.next_index, self.resume_at) {
            if expected < resume && index >= resume {
                // Back where the earlier segment stopped: it goes on.
                self.stats.restarts += 1;
                on_item(Item::Restart {
                    last: expected.wrapping_sub(1),
                });
                self.next_index = Some(resume);
                self.resume_at = None;
                self.reconstructor.lose_step();
            }
        }
        if let Some(expected) = self.next_index {
            if index > expected {
                self.gap(expected, index - 1, why, on_item);
            }
        }
    }

    fn gap(&mut self, first: u32, last: u32, why: Missing, on_item: &mut impl FnMut(Item)) {
        let n = u64::from(last - first) + 1;
        self.stats.gaps += 1;
        match why {
            Missing::Lost => self.stats.lost_samples += n,
            Missing::Withheld(_) => self.stats.withheld_samples += n,
        }
        on_item(Item::Gap { first, last, why });
    }

    /// The index goes back to `index`: a new segment.
    fn went_back(&mut self, index: u32, on_item: &mut impl FnMut(Item)) -> bool {
        match self.next_index {
            Some(expected) if index < expected => {
                self.stats.restarts += 1;
                on_item(Item::Restart {
                    last: expected.wrapping_sub(1),
                });
                self.resume_at = Some(expected);
                self.next_index = None;
                true
            }
            _ => false,
        }
    }

    fn sample(&mut self, s: Sample, on_item: &mut impl FnMut(Item)) {
        self.went_back(s.index, on_item);
        self.missing_before(s.index, Missing::Lost, on_item);
        self.next_index = Some(s.index.wrapping_add(1));
        self.stats.samples += 1;
        on_item(Item::Sample(s));
    }

    fn message(&mut self, message: Message, on_item: &mut impl FnMut(Item)) {
        if matches!(message, Message::Event(_)) {
            self.stats.events += 1;
        }
        self.stats.frames += 1;
        on_item(Item::Frame(message));
    }

    /// A frame of this build's protocol (or of version 3 to 5, read as one:
    /// `version` says which); `chunk` is its bytes as received (a config
    /// frame's seed the batch checks).
    fn accept(
        &mut self,
        frame: Frame<'_>,
        chunk: &[u8],
        version: u16,
        on_item: &mut impl FnMut(Item),
    ) -> Result<(), VersionMismatch> {
        let message = match frame {
            Frame::Header(h) => {
                check_version(h.protocol_version, version)?;
                check_schema(h.protocol_version, h.schema_key, version)?;
                // The device (re)started: indices begin again.
                self.went_back(0, on_item);
                self.next_index = None;
                self.resume_at = None;
                self.reconstructor.restart();
                Message::Header(h)
            }
            Frame::Status(s) => {
                check_version(s.protocol_version, version)?;
                check_schema(s.protocol_version, s.schema_key, version)?;
                if !s.streaming {
                    // Paused on request: what does not come is not lost.
                    self.next_index = None;
                }
                Message::Status(s)
            }
            Frame::Config(c) => {
                self.reconstructor.config_frame(&c, chunk);
                Message::Config(Box::new(c))
            }
            Frame::Snapshot(snapshot) => {
                self.went_back(snapshot.next_index, on_item);
                self.missing_before(snapshot.next_index, Missing::Lost, on_item);
                self.next_index = Some(snapshot.next_index);
                self.reconstructor.snapshot(snapshot.clone());
                Message::Snapshot(Box::new(snapshot))
            }
            Frame::Batch(batch) => {
                self.stats.frames += 1;
                self.batch(&batch, on_item);
                return Ok(());
            }
            Frame::Event(e) => Message::Event(e.into()),
            Frame::Halt(h) => Message::Halt(h.into()),
            Frame::Reply(r) => Message::Reply(r),
            Frame::SelfTest(t) => Message::SelfTest(t),
        };
        self.message(message, on_item);
        Ok(())
    }

    fn batch(&mut self, batch: &protocol::Batch<'_>, on_item: &mut impl FnMut(Item)) {
        if self.went_back(batch.first_index, on_item) {
            self.reconstructor.lose_step();
        }
        if self.next_index.is_some_and(|e| batch.first_index > e) {
            self.missing_before(batch.first_index, Missing::Lost, on_item);
            self.reconstructor.lose_step();
        }
        let mut samples = Vec::with_capacity(usize::from(batch.samples));
        match self.reconstructor.batch(batch, |s| samples.push(s)) {
            Ok(()) => samples.into_iter().for_each(|s| self.sample(s, on_item)),
            Err(why) if batch.samples > 0 => {
                let last = batch.first_index.wrapping_add(u32::from(batch.samples) - 1);
                self.gap(batch.first_index, last, Missing::Withheld(why), on_item);
                self.next_index = Some(last.wrapping_add(1));
            }
            Err(_) => {}
        }
    }

    fn accept_v2(
        &mut self,
        frame: v2::Frame,
        on_item: &mut impl FnMut(Item),
    ) -> Result<(), VersionMismatch> {
        let message = match frame {
            v2::Frame::Header(h) => {
                check_version(h.protocol_version, 2)?;
                self.went_back(0, on_item);
                self.next_index = None;
                self.resume_at = None;
                Message::Header(Header {
                    protocol_version: h.protocol_version,
                    sample_rate_hz: h.sample_rate_hz,
                    schema_key: [0; 8],
                })
            }
            v2::Frame::Status(s) => {
                check_version(s.protocol_version, 2)?;
                Message::Status(Status {
                    protocol_version: s.protocol_version,
                    sample_rate_hz: s.sample_rate_hz,
                    samples: s.samples,
                    frames_dropped: s.frames_dropped,
                    faults: s.faults,
                    halt: s.halt,
                    streaming: true,
                    next_command_seq: 0,
                    board: Default::default(),
                    schema_key: [0; 8],
                })
            }
            v2::Frame::Sample(s) => {
                self.stats.frames += 1;
                self.sample(s, on_item);
                return Ok(());
            }
            v2::Frame::Event(e) => Message::Event(e.into()),
            v2::Frame::Halt(h) => Message::Halt(h.into()),
        };
        self.message(message, on_item);
        Ok(())
    }
}

fn check_version(found: u16, expected: u16) -> Result<(), VersionMismatch> {
    if found == expected {
        Ok(())
    } else {
        Err(VersionMismatch {
            found,
            framed_as: expected,
            schema_key: None,
        })
    }
}

/// A header or status of this build's version carries this build's
/// schema: a build that changed a type on the wire without a new version
/// is refused, not decoded into garbage.
fn check_schema(found: u16, key: [u8; 8], version: u16) -> Result<(), VersionMismatch> {
    if version != PROTOCOL_VERSION || key == protocol::SCHEMA_KEY {
        Ok(())
    } else {
        Err(VersionMismatch {
            found,
            framed_as: version,
            schema_key: Some(key),
        })
    }
}

/// The newer protocol version whose framing `chunk` passes, if any: the
/// implied version byte of a later build's CRC.
fn newer_framing(chunk: &[u8]) -> Option<u16> {
    (PROTOCOL_VERSION + 1..=PROTOCOL_VERSION + NEWER_VERSIONS).find(|&v| {
        let mut buffer = [0u8; MAX_ENCODED_FRAME];
        let check = |b: &[u8]| wire::frame_check_of_version(v, b);
        wire::unframe(chunk, &mut buffer, check).is_ok()
    })
}

/// Decode a whole byte slice; returns the items and the counters.
pub fn decode_all(bytes: &[u8]) -> Result<(Vec<Item>, StreamStats), VersionMismatch> {
    let mut items = Vec::new();
    let mut decoder = StreamDecoder::new();
    decoder.feed(bytes, |item| items.push(item))?;
    let stats = decoder.finish(|item| items.push(item));
    Ok((items, stats))
}

/// The samples of a stream, in order.
pub fn samples(items: &[Item]) -> Vec<Sample> {
    items
        .iter()
        .filter_map(|i| match i {
            Item::Sample(s) => Some(*s),
            _ => None,
        })
        .collect()
}

/// The frames of a stream other than samples, in order.
pub fn messages(items: &[Item]) -> Vec<Message> {
    items
        .iter()
        .filter_map(|i| match i {
            Item::Frame(m) => Some(m.clone()),
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_holder::config::DeviceConfig;
    use needle_holder::device::Device;
    use needle_holder::insertion::Phase;
    use needle_holder::protocol::FrameEncoder;
    use needle_holder::replay::{ReplayAdc, ReplayEncoder};
    use needle_holder::units::{MicroNewtons, Nanometres, NanometresPerSecond};

    /// A device run over `n` samples of a slow approach with noise: its
    /// bytes, and the samples the device computed.
    fn device_stream(config: DeviceConfig, n: u32) -> (Vec<u8>, Vec<Sample>) {
        let mut sink = Vec::new();
        let mut device = Device::new(config, &mut sink, crate::twin::RecordingPin::default());
        let mut adc = ReplayAdc {
            counts: 0,
            full_scale_counts: config.load_cell.full_scale_counts,
        };
        let mut encoder = ReplayEncoder::default();
        let mut state = needle_holder::pipeline::PipelineState::default();
        let mut expected = Vec::new();
        for i in 0..n {
            adc.counts = ((i * 7919) % 20_000) as i32 - 10_000;
            encoder.count = (i * 6) as u16;
            let raw = needle_holder::pipeline::RawSample {
                adc: Some(needle_holder::hal::LoadCellAdc::read(&mut adc).unwrap()),
                encoder_count: encoder.count,
            };
            expected.push(config.step(&mut state, raw).sample);
            device.tick(&mut adc, &mut encoder);
        }
        device.finish();
        (sink, expected)
    }

    fn split(stream: &[u8]) -> Vec<Vec<u8>> {
        stream
            .split_inclusive(|&b| b == 0)
            .map(<[u8]>::to_vec)
            .collect()
    }

    fn is_batch(frame: &[u8]) -> bool {
        let mut buf = [0u8; MAX_ENCODED_FRAME];
        matches!(
            protocol::decode(&frame[..frame.len() - 1], &mut buf),
            Ok(Frame::Batch(_))
        )
    }

    #[test]
    fn a_version_3_stream_gives_the_devices_samples_bit_for_bit() {
        let (stream, expected) = device_stream(DeviceConfig::default(), 1000);
        let (items, stats) = decode_all(&stream).unwrap();
        assert_eq!(samples(&items), expected);
        assert_eq!(
            (stats.gaps, stats.skipped_bytes, stats.withheld_samples),
            (0, 0, 0)
        );
        let per_sample = stream.len() as f64 / 1000.0;
        assert!(per_sample < 6.0, "{per_sample} bytes a sample");
    }

    #[test]
    fn a_lost_batch_is_a_gap_and_samples_resume_at_the_next_snapshot() {
        let (stream, expected) = device_stream(DeviceConfig::default(), 1000);
        let frames = split(&stream);
        let lost = frames.iter().position(|f| is_batch(f)).unwrap() + 1; // the second batch
        assert!(is_batch(&frames[lost]));
        let cut: Vec<u8> = frames
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != lost)
            .flat_map(|(_, f)| f.clone())
            .collect();
        let (items, stats) = decode_all(&cut).unwrap();
        let got = samples(&items);
        // 25 samples lost; the rest of the status period withheld; from
        // the snapshot at 250 on, every sample again.
        assert!(got[..25] == expected[..25]);
        assert!(got[25..] == expected[250..]);
        assert_eq!(stats.lost_samples, 25);
        assert_eq!(stats.withheld_samples, 200);
        assert!(items.iter().any(|i| matches!(
            i,
            Item::Gap {
                first: 50,
                last: 74,
                why: Missing::Withheld(Withheld::OutOfStep)
            }
        )));
    }

    #[test]
    fn a_host_with_another_configuration_withholds_every_sample() {
        let liver2 = needle_holder::model::params::LIVER2;
        let liver2 = needle_holder::config::TissueModel::from_params(&liver2).unwrap();
        let device_config = DeviceConfig::default().with_tissue(&liver2);
        let (stream, _) = device_stream(device_config, 300);
        // Swap the config frame for the default's: the host now computes
        // with parameters the device does not use.
        let mut encoder = FrameEncoder::default();
        let doctored: Vec<u8> = split(&stream)
            .into_iter()
            .flat_map(|f| {
                let mut buf = [0u8; MAX_ENCODED_FRAME];
                match protocol::decode(&f[..f.len() - 1], &mut buf) {
                    Ok(Frame::Config(mut c)) => {
                        c.config = DeviceConfig::default();
                        encoder.encode(&Frame::Config(c)).to_vec()
                    }
                    _ => f,
                }
            })
            .collect();
        let (items, stats) = decode_all(&doctored).unwrap();
        // Out of tissue the model is zero for either tissue; the detectors'
        // thresholds differ, and the check catches it all the same.
        assert!(
            samples(&items).is_empty(),
            "samples computed with the wrong tissue were given"
        );
        assert_eq!(stats.withheld_samples, 300);
        assert!(items.iter().any(|i| matches!(
            i,
            Item::Gap {
                why: Missing::Withheld(Withheld::CheckMismatch),
                ..
            }
        )));
    }

    #[test]
    fn resynchronises_after_noise_and_counts_every_skipped_byte() {
        let (stream, expected) = device_stream(DeviceConfig::default(), 100);
        let frames = split(&stream);
        let mut noisy = vec![0x13, 0x37, 0x42, 0x00]; // tail of a frame we joined late
        let mut corrupted_len = 0;
        for (i, f) in frames.iter().enumerate() {
            let mut f = f.clone();
            if i == 5 {
                f[3] ^= 0x01;
                corrupted_len = f.len();
            }
            noisy.extend(f);
        }
        noisy.extend([7, 7]); // a frame cut short at the end
        let (items, stats) = decode_all(&noisy).unwrap();
        assert_eq!(stats.skipped_bytes, 4 + corrupted_len as u64 + 2);
        assert!(samples(&items).len() < expected.len());
        assert!(stats.lost_samples > 0);
    }

    #[test]
    fn a_run_longer_than_any_frame_is_skipped_once_then_decoding_resumes() {
        let (stream, _) = device_stream(DeviceConfig::default(), 10);
        let mut noisy = vec![0x55; 3 * MAX_ENCODED_FRAME];
        noisy.push(0);
        noisy.extend(stream);
        let (items, stats) = decode_all(&noisy).unwrap();
        assert!(
            matches!(items[0], Item::Skipped { bytes, reason: "longer than any frame" } if bytes == 3 * MAX_ENCODED_FRAME + 1)
        );
        assert_eq!(stats.skipped_runs, 1);
        assert_eq!(stats.samples, 10);
    }

    fn v2_bytes(frame: &v2::Frame) -> Vec<u8> {
        let mut raw = postcard::to_stdvec(frame).unwrap();
        raw.extend(FRAME_CRC.checksum(&raw).to_le_bytes());
        let mut out = cobs::encode_vec(&raw);
        out.push(0);
        out
    }

    fn v2_sample(index: u32) -> v2::Frame {
        v2::Frame::Sample(Sample {
            index,
            x: Nanometres(index as i32 * 6000),
            v: NanometresPerSecond(3_000_000),
            force: MicroNewtons(1000),
            model: MicroNewtons::ZERO,
            residual: MicroNewtons(1000),
            phase: Phase::Out,
        })
    }

    #[test]
    fn a_version_2_capture_still_decodes_with_its_gaps() {
        let mut stream = v2_bytes(&v2::Frame::Header(v2::Header {
            protocol_version: 2,
            sample_rate_hz: 500,
        }));
        for i in [0, 1, 2, 5, 6, 10] {
            stream.extend(v2_bytes(&v2_sample(i)));
        }
        let (items, stats) = decode_all(&stream).unwrap();
        let gaps: Vec<_> = items
            .iter()
            .filter_map(|i| match i {
                Item::Gap { first, last, .. } => Some((*first, *last)),
                _ => None,
            })
            .collect();
        assert_eq!(gaps, [(3, 4), (7, 9)]);
        assert_eq!((stats.samples, stats.gaps, stats.lost_samples), (6, 2, 5));
        assert!(matches!(
            items[0],
            Item::Frame(Message::Header(Header {
                protocol_version: 2,
                sample_rate_hz: 500,
                ..
            }))
        ));
    }

    /// `frame` as a build of protocol `version` frames it (its CRC over
    /// that implied version byte).
    fn bytes_of_version(frame: &Frame<'_>, version: u8) -> Vec<u8> {
        let mut raw = postcard::to_stdvec(frame).unwrap();
        let mut digest = FRAME_CRC.digest();
        digest.update(&[version]);
        digest.update(&raw);
        raw.extend(digest.finalize().to_le_bytes());
        let mut framed = cobs::encode_vec(&raw);
        framed.push(0);
        framed
    }

    #[test]
    fn a_newer_devices_stream_is_named_as_one_not_as_noise() {
        // Every frame fails this build's CRC; three in a row pass version
        // 7's. Two do not yet decide it.
        let frame = Frame::Header(Header {
            protocol_version: 7,
            ..needle_holder::protocol::header(500)
        });
        let two: Vec<u8> = (0..2).flat_map(|_| bytes_of_version(&frame, 7)).collect();
        assert!(decode_all(&two).is_ok());
        // This build's own frame between them: not three in a row.
        let own = FrameEncoder::default()
            .encode(&Frame::Header(needle_holder::protocol::header(500)))
            .to_vec();
        let broken: Vec<u8> = [two.clone(), own, bytes_of_version(&frame, 7)].concat();
        assert!(decode_all(&broken).is_ok());
        let three: Vec<u8> = (0..3).flat_map(|_| bytes_of_version(&frame, 7)).collect();
        let err = decode_all(&three).unwrap_err();
        assert_eq!((err.found, err.framed_as), (7, 7));
        assert!(
            err.to_string().contains("speaks protocol version 7"),
            "{err}"
        );
    }

    #[test]
    fn version_3_to_5_captures_still_decode_to_the_same_samples() {
        for version in older::VERSIONS {
            let (old, expected) = older_capture(version);
            let (items, stats) = decode_all(&old).unwrap();
            assert_eq!(stats.skipped_bytes, 0, "version {version}");
            assert_eq!(samples(&items), expected, "version {version}");
            let said = |m: &Message| match m {
                Message::Header(h) => h.protocol_version == version,
                Message::Status(s) => {
                    s.protocol_version == version && s.board == Default::default()
                }
                _ => false,
            };
            assert!(messages(&items).iter().filter(|m| said(m)).count() > 1);
        }
    }

    /// What a device of protocol `version` (3 to 5) sent for a whole
    /// insertion (contact, puncture, a 2 s dwell, withdrawal), and the
    /// samples in it: this build's frames less what later versions
    /// appended — version 6 the schema key at the end of the header and
    /// of a status, version 5 the board's counters before it in a status,
    /// version 4 the relaxation at the end of the configuration and state
    /// (run with protocol 3's model at rest: no hold, no relaxation) —
    /// framed over that version byte, so its batch checks seeded from
    /// those config bytes.
    fn older_capture(version: u16) -> (Vec<u8>, Vec<Sample>) {
        use needle_holder::model::params::LIVER1;
        use needle_holder::model::relax::Relaxation;
        use needle_holder::protocol::batch::BatchCheck;
        let (trial, _) =
            needle_analysis::sim::insertion(&LIVER1, &needle_analysis::sim::Plan::PAPER);
        let config = DeviceConfig {
            relaxation: Relaxation::default(),
            ..DeviceConfig::default()
        };
        let replay =
            needle_analysis::sim::to_replay(&trial, 500, &config.load_cell, &config.encoder);
        let mut stream = Vec::new();
        let mut halt = crate::twin::RecordingPin::default();
        needle_holder::replay::run(&replay[..], config, &mut stream, &mut halt);
        let (items, _) = decode_all(&stream).unwrap();
        let expected = samples(&items);
        assert_eq!(expected.len(), trial.len());
        let rests = expected
            .iter()
            .filter(|s| s.phase == Phase::Inserted && s.v.0 == 0)
            .count();
        assert!(rests > 500, "a dwell in the tissue: {rests} samples");
        let framed_as = |raw: &mut Vec<u8>| {
            let mut digest = FRAME_CRC.digest();
            digest.update(&[version as u8]);
            digest.update(raw);
            raw.extend(digest.finalize().to_le_bytes());
            cobs::encode_vec(raw)
        };
        let (mut old, mut seed) = (Vec::new(), BatchCheck::default());
        for frame in split(&stream) {
            let mut buf = [0u8; MAX_ENCODED_FRAME];
            let body = wire::unframe(&frame[..frame.len() - 1], &mut buf, |b| {
                let mut digest = FRAME_CRC.digest();
                digest.update(&[PROTOCOL_VERSION as u8]);
                digest.update(b);
                digest.finalize()
            })
            .unwrap();
            let parsed = wire::parse::<Frame>(body).unwrap();
            let len = |bytes: postcard::Result<Vec<u8>>| bytes.unwrap().len();
            let tail = match &parsed {
                Frame::Config(c) if version < 4 => len(postcard::to_stdvec(&c.config.relaxation)),
                Frame::Snapshot(s) if version < 4 => len(postcard::to_stdvec(s.state.relax())),
                Frame::Status(s) if version < 5 => {
                    len(postcard::to_stdvec(&s.board)) + len(postcard::to_stdvec(&s.schema_key))
                }
                Frame::Status(s) if version < 6 => len(postcard::to_stdvec(&s.schema_key)),
                Frame::Header(h) if version < 6 => len(postcard::to_stdvec(&h.schema_key)),
                _ => 0,
            };
            let mut raw = body[..body.len() - tail].to_vec();
            match parsed {
                Frame::Header(_) | Frame::Status(_) => raw[1] = version as u8,
                Frame::Batch(batch) => {
                    let mut check = seed;
                    let first = batch.first_index as usize;
                    for s in &expected[first..first + usize::from(batch.samples)] {
                        check.add(needle_holder::protocol::batch::checked_words(s));
                    }
                    let rechecked = Frame::Batch(protocol::Batch {
                        check: check.0.to_le_bytes(),
                        ..batch
                    });
                    raw = postcard::to_stdvec(&rechecked).unwrap();
                }
                _ => {}
            }
            let framed = framed_as(&mut raw);
            if body[0] == 1 {
                seed = BatchCheck::seed(&framed);
            }
            old.extend(framed);
            old.push(0);
        }
        (old, expected)
    }

    #[test]
    fn a_stream_of_this_version_but_another_schema_is_refused_by_its_key() {
        let mut other = needle_holder::protocol::header(500);
        other.schema_key[0] ^= 1;
        let err = decode_all(FrameEncoder::default().encode(&Frame::Header(other))).unwrap_err();
        assert_eq!(err.schema_key, Some(other.schema_key));
        let text = err.to_string();
        assert!(text.contains(&hex(&other.schema_key)), "{text}");
        assert!(text.contains(&hex(&protocol::SCHEMA_KEY)), "{text}");
        assert!(text.contains(protocol::SCHEMA_PATH), "{text}");
        // This build's own key passes.
        assert!(decode_all(
            FrameEncoder::default().encode(&Frame::Header(needle_holder::protocol::header(500)))
        )
        .is_ok());
        // A host that joined after the header reads the key in a status.
        let status = Status {
            protocol_version: PROTOCOL_VERSION,
            sample_rate_hz: 500,
            samples: 0,
            frames_dropped: 0,
            faults: Default::default(),
            halt: false,
            streaming: true,
            next_command_seq: 0,
            board: Default::default(),
            schema_key: other.schema_key,
        };
        let err = decode_all(FrameEncoder::default().encode(&Frame::Status(status))).unwrap_err();
        assert_eq!(err.schema_key, Some(other.schema_key));
    }

    #[test]
    fn another_protocol_version_is_refused() {
        let header = |v| {
            Frame::Header(Header {
                protocol_version: v,
                ..needle_holder::protocol::header(500)
            })
        };
        let err = decode_all(FrameEncoder::default().encode(&header(9))).unwrap_err();
        assert_eq!(err.found, 9);
        assert!(
            err.to_string().contains("reads versions 2 to 5 and"),
            "{err}"
        );
        // A version this needle reads, named in another's frame.
        let err = decode_all(FrameEncoder::default().encode(&header(2))).unwrap_err();
        assert!(err.to_string().contains("contradicts itself"), "{err}");
        let v1 = v2_bytes(&v2::Frame::Header(v2::Header {
            protocol_version: 1,
            sample_rate_hz: 500,
        }));
        assert_eq!(decode_all(&v1).unwrap_err().found, 1);
    }
}
