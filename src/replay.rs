//! Replay input: recorded raw sensor readings fed to the device in place of
//! the ADC and encoder. QEMU reads it over semihosting; the host twin reads
//! the same bytes from memory; both call [`run`].
//!
//! File format (little-endian), written by `needle simulate`/`needle demo`:
//!
//! | bytes | field |
//! |---|---|
//! | 0..4 | magic `NHRP` |
//! | 4 | format version, 1 |
//! | 5 | tissue: 0 for the image's default, `i + 1` for library tissue `i` |
//! | 6..8 | sample rate, Hz, `u16` |
//! | then 6 per sample | ADC counts `i32`, encoder count `u16` |
//!
//! ADC counts of [`OVERRUN_MARK`] (`i32::MIN`, which a 24-bit converter
//! never returns) mark a sample the acquisition flagged as late: the ADC
//! reports its overrun flag for it.
//!
//! A file that ends inside a record raises `REPLAY_TRUNCATED` after the last
//! whole record; a bad header raises `REPLAY_BAD_HEADER` and nothing runs.

use core::convert::Infallible;

use embedded_hal::digital::OutputPin;
use embedded_io::{Read, Write};

use crate::config::DeviceConfig;
use crate::device::{Device, Summary};
use crate::faults::Faults;
use crate::hal::{AdcSample, EncoderCounter, LoadCellAdc};

/// First four bytes of a replay file.
pub const MAGIC: [u8; 4] = *b"NHRP";
/// Format version this code reads and writes.
pub const FORMAT_VERSION: u8 = 1;
/// Header length, bytes.
pub const HEADER_LEN: usize = 8;
/// Record length, bytes.
pub const RECORD_LEN: usize = 6;
/// ADC counts that mark a late (overrun) sample in a replay.
pub const OVERRUN_MARK: i32 = i32::MIN;

/// The replay header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct ReplayHeader {
    /// Sample rate of the recording, Hz.
    pub sample_rate_hz: u16,
    /// The library tissue (index into [`crate::model::params::LIBRARY`])
    /// the recording was made on, run in place of the image's default;
    /// `None`: the default.
    pub tissue: Option<u8>,
}

impl ReplayHeader {
    /// Serialise.
    pub fn to_bytes(self) -> [u8; HEADER_LEN] {
        let rate = self.sample_rate_hz.to_le_bytes();
        [
            MAGIC[0],
            MAGIC[1],
            MAGIC[2],
            MAGIC[3],
            FORMAT_VERSION,
            self.tissue.map_or(0, |i| i.saturating_add(1)),
            rate[0],
            rate[1],
        ]
    }

    /// Parse; `None` for a wrong magic, version, a zero rate or a tissue
    /// the library does not have.
    pub fn parse(bytes: &[u8; HEADER_LEN]) -> Option<Self> {
        let rate = u16::from_le_bytes([bytes[6], bytes[7]]);
        let tissue = bytes[5].checked_sub(1);
        let known = tissue.is_none_or(|i| usize::from(i) < crate::model::params::LIBRARY.len());
        (bytes[..4] == MAGIC && bytes[4] == FORMAT_VERSION && rate > 0 && known).then_some(Self {
            sample_rate_hz: rate,
            tissue,
        })
    }
}

/// One recorded sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Record {
    /// Raw load-cell ADC counts.
    pub adc_counts: i32,
    /// Raw wrapping encoder count.
    pub encoder_count: u16,
}

impl Record {
    /// Serialise.
    pub fn to_bytes(self) -> [u8; RECORD_LEN] {
        let a = self.adc_counts.to_le_bytes();
        let e = self.encoder_count.to_le_bytes();
        [a[0], a[1], a[2], a[3], e[0], e[1]]
    }

    /// Parse.
    pub fn from_bytes(b: &[u8; RECORD_LEN]) -> Self {
        Self {
            adc_counts: i32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            encoder_count: u16::from_le_bytes([b[4], b[5]]),
        }
    }
}

/// Why reading stopped early.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ReplayError {
    /// The input ended inside a header or record.
    Truncated,
    /// The reader failed.
    Io,
}

/// Fill `buf` from `reader`. `Ok(false)` at a clean end before any byte.
fn fill<R: Read>(reader: &mut R, buf: &mut [u8]) -> Result<bool, ReplayError> {
    let mut filled = 0;
    while filled < buf.len() {
        match reader.read(&mut buf[filled..]) {
            Ok(0) if filled == 0 => return Ok(false),
            Ok(0) => return Err(ReplayError::Truncated),
            Ok(n) => filled += n,
            Err(_) => return Err(ReplayError::Io),
        }
    }
    Ok(true)
}

/// Read the header.
pub fn read_header<R: Read>(reader: &mut R) -> Result<Option<ReplayHeader>, ReplayError> {
    let mut buf = [0; HEADER_LEN];
    if !fill(reader, &mut buf)? {
        return Err(ReplayError::Truncated);
    }
    Ok(ReplayHeader::parse(&buf))
}

/// Read the next record; `Ok(None)` at a clean end.
pub fn read_record<R: Read>(reader: &mut R) -> Result<Option<Record>, ReplayError> {
    let mut buf = [0; RECORD_LEN];
    Ok(fill(reader, &mut buf)?.then(|| Record::from_bytes(&buf)))
}

/// The load-cell ADC during a replay: returns the current record's counts,
/// reports saturation at the calibrated full scale and an overrun at
/// [`OVERRUN_MARK`].
#[derive(Clone, Copy, Debug)]
pub struct ReplayAdc {
    /// Counts returned by the next read.
    pub counts: i32,
    /// Full scale, counts.
    pub full_scale_counts: i32,
}

impl LoadCellAdc for ReplayAdc {
    type Error = Infallible;
    fn read(&mut self) -> Result<AdcSample, Infallible> {
        let overrun = self.counts == OVERRUN_MARK;
        let saturated =
            !overrun && self.counts.unsigned_abs() >= self.full_scale_counts.unsigned_abs();
        Ok(AdcSample {
            counts: self.counts,
            saturated,
            overrun,
        })
    }
}

/// The encoder counter during a replay.
#[derive(Clone, Copy, Debug, Default)]
pub struct ReplayEncoder {
    /// Count returned by the next read.
    pub count: u16,
}

impl EncoderCounter for ReplayEncoder {
    fn count(&mut self) -> u16 {
        self.count
    }
}

/// Hooks around each sample's processing. The firmware uses them to mark
/// the per-sample path for the instruction-count benchmark; `()` does
/// nothing.
pub trait TickProbe {
    /// Just before [`Device::tick`].
    fn before_tick(&mut self) {}
    /// Just after [`Device::tick`].
    fn after_tick(&mut self) {}
}

impl TickProbe for () {}

/// Run a whole replay through a [`Device`] built from `config` (its sample
/// rate replaced by the replay's), sending frames to `sink`.
pub fn run<R: Read, W: Write, H: OutputPin>(
    reader: R,
    config: DeviceConfig,
    sink: W,
    halt: H,
) -> Summary {
    run_probed(reader, config, sink, halt, &mut ())
}

/// [`run`], calling `probe` around every sample.
pub fn run_probed<R: Read, W: Write, H: OutputPin, P: TickProbe>(
    reader: R,
    config: DeviceConfig,
    sink: W,
    halt: H,
    probe: &mut P,
) -> Summary {
    match Replayer::start(reader, config, sink, halt) {
        Err(summary) => summary,
        Ok(mut replay) => {
            while replay.step(probe) {}
            replay.finish()
        }
    }
}

/// A replay in progress, a record at a time: [`run`] loops over it (the
/// QEMU boards, the host twin); the real board's replay image steps it
/// from its sample timer. One piece of code, so both feed the device alike.
pub struct Replayer<R: Read, W: Write, H: OutputPin> {
    reader: R,
    device: Device<W, H>,
    adc: ReplayAdc,
    encoder: ReplayEncoder,
    sample_rate_hz: u16,
}

impl<R: Read, W: Write, H: OutputPin> Replayer<R, W, H> {
    /// Read the header and build the device from `config` at the replay's
    /// rate, with the replay's tissue if it names one. A bad header raises
    /// `REPLAY_BAD_HEADER` (at `config`'s rate) and leaves nothing to
    /// replay: its final summary is the `Err`.
    pub fn start(mut reader: R, config: DeviceConfig, sink: W, halt: H) -> Result<Self, Summary> {
        let header = read_header(&mut reader);
        let (sample_rate_hz, tissue) = match header {
            Ok(Some(h)) => (h.sample_rate_hz, h.tissue),
            _ => (config.velocity.sample_rate_hz, None),
        };
        let named =
            tissue.and_then(|i| Some((i, crate::config::LIBRARY_MODELS.get(usize::from(i))?)));
        let config = named.map_or(config, |(_, model)| config.with_tissue(model));
        let mut device = match named {
            Some((i, _)) => Device::restored(
                config.with_sample_rate(sample_rate_hz),
                crate::protocol::TissueSource::Library(i),
                crate::persist::Loaded::NotKept,
                sink,
                halt,
            ),
            None => Device::new(config.with_sample_rate(sample_rate_hz), sink, halt),
        };
        if !matches!(header, Ok(Some(_))) {
            device.raise(Faults::REPLAY_BAD_HEADER);
            return Err(device.finish());
        }
        Ok(Self {
            reader,
            device,
            adc: ReplayAdc {
                counts: 0,
                full_scale_counts: config.load_cell.full_scale_counts,
            },
            encoder: ReplayEncoder::default(),
            sample_rate_hz,
        })
    }

    /// The replay's sample rate, Hz.
    pub fn sample_rate_hz(&self) -> u16 {
        self.sample_rate_hz
    }

    /// Feed the next record to the device, `probe` around it; `false` once
    /// the replay has ended (a record cut short raises `REPLAY_TRUNCATED`).
    pub fn step<P: TickProbe>(&mut self, probe: &mut P) -> bool {
        match read_record(&mut self.reader) {
            Ok(Some(record)) => {
                self.adc.counts = record.adc_counts;
                self.encoder.count = record.encoder_count;
                probe.before_tick();
                self.device.tick(&mut self.adc, &mut self.encoder);
                probe.after_tick();
                true
            }
            Ok(None) => false,
            Err(_) => {
                self.device.raise(Faults::REPLAY_TRUNCATED);
                false
            }
        }
    }

    /// Commands from the host, between samples (see [`Device::receive`]);
    /// a self-test is answered at once: no converter, nothing measured,
    /// the replay's rate and encoder count.
    pub fn receive(&mut self, bytes: &[u8]) {
        self.device.receive(bytes);
        if self.device.self_test_asked() {
            self.device.send_self_test(crate::protocol::BoardFindings {
                adc_registers: None,
                data_ready_per_s: None,
                data_ready_expected_per_s: u32::from(self.sample_rate_hz),
                encoder_count: Some(self.encoder.count),
            });
        }
    }

    /// Send the final status and return the counters.
    pub fn finish(&mut self) -> Summary {
        self.device.finish()
    }
}
