//! The wire protocol: frames the device sends, defined once and used by the
//! firmware and the host alike.
//!
//! Each frame is a [`Frame`] serialised with postcard (varint integers),
//! followed by a CRC-16 of those bytes (little-endian), the whole COBS-framed
//! and ending in a `0x00` byte. A reader that starts mid-stream or loses
//! bytes resynchronises at the next zero; the CRC catches the corrupted
//! frames that would otherwise still decode (postcard accepts almost any
//! bytes as varints), so a line error shows up as a lost frame, not as a
//! wrong force. The first frame after
//! boot is a [`Header`]; sample frames carry the sample index, so a gap in
//! the indices is a lost frame; a [`Status`] heartbeat with counters follows
//! every [`STATUS_PERIOD_SAMPLES`] samples, on every new fault, and at the end.
//!
//! Changing any type here changes the bytes on the wire: bump
//! [`PROTOCOL_VERSION`] (the golden-bytes test below fails until you do).

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::faults::Faults;
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// Version of the frame format; the host refuses other versions.
pub const PROTOCOL_VERSION: u16 = 2;

/// Samples between two status heartbeats.
pub const STATUS_PERIOD_SAMPLES: u32 = 250;

/// Where the needle is in the insertion, as the device tracks it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Phase {
    /// Tip outside the tissue.
    Out,
    /// Tip pressing on the capsule, before puncture.
    Loading,
    /// Tip inside the tissue, after puncture.
    Inserted,
    /// Needle moving out of the tissue.
    Withdrawal,
}

/// What a detector saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
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

/// Sent once at boot: what the stream is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Header {
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u16,
    /// Sample rate, Hz: sample index / rate = time since boot.
    pub sample_rate_hz: u16,
}

/// One processed sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Sample {
    /// Sample index since boot.
    pub index: u32,
    /// Needle position.
    pub x: Nanometres,
    /// Needle velocity (windowed difference, see `kinematics`).
    pub v: NanometresPerSecond,
    /// Measured force.
    pub force: MicroNewtons,
    /// Force the model expects here.
    pub model: MicroNewtons,
    /// `force − model`, saturating.
    pub residual: MicroNewtons,
    /// Phase at this sample.
    pub phase: Phase,
}

/// A detected event.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
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

/// Heartbeat with counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
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
    /// Faults raised since boot (latched).
    pub faults: Faults,
    /// Halt line asserted.
    pub halt: bool,
}

/// Why the device asserted the halt line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
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

impl From<EventKind> for HaltReason {
    fn from(kind: EventKind) -> Self {
        match kind {
            EventKind::Contact => Self::Contact,
            EventKind::Puncture => Self::Puncture,
            EventKind::Structure => Self::Structure,
            EventKind::Exit => Self::Exit,
            EventKind::Fault => Self::Fault,
        }
    }
}

/// Sent when the halt line goes up: why, and where the robot should hold
/// the tip (behind it when the device asks for a back-off).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
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

/// Everything the device sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Frame {
    /// Stream header.
    Header(Header),
    /// Processed sample.
    Sample(Sample),
    /// Detected event.
    Event(Event),
    /// Heartbeat.
    Status(Status),
    /// The halt line went up.
    Halt(Halt),
}

impl MaxSize for Faults {
    const POSTCARD_MAX_SIZE: usize = u16::POSTCARD_MAX_SIZE;
}
macro_rules! max_size_i32 {
    ($($t:ty),*) => {$(impl MaxSize for $t { const POSTCARD_MAX_SIZE: usize = i32::POSTCARD_MAX_SIZE; })*};
}
max_size_i32!(MicroNewtons, Nanometres, NanometresPerSecond);

/// The frame check: CRC-16/IBM-SDLC (the X.25/HDLC CRC). The host checks
/// frames with the `crc` crate through this; the device computes the same
/// CRC with [`crc16_update`] (see there why).
pub const FRAME_CRC: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_SDLC);

/// Table of the reflected CRC-16/IBM-SDLC polynomial (0x8408), one entry
/// per byte value, built at compile time.
const CRC16_TABLE: [u16; 256] = {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = i as u16;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x8408
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
};

/// Fold one byte into a running CRC-16/IBM-SDLC (start at 0xFFFF, finish
/// with `!crc`). Written here rather than through the `crc` crate's
/// `Digest`, whose per-call dispatch on the algorithm's reflection costs
/// about as much again as the table lookup when fed a byte at a time, as
/// the serializer does; a test checks the two agree.
#[inline(always)]
pub fn crc16_update(crc: u16, byte: u8) -> u16 {
    CRC16_TABLE[((crc ^ byte as u16) & 0xFF) as usize] ^ (crc >> 8)
}

/// Largest frame before COBS: postcard's bound plus the 2-byte CRC.
pub const MAX_RAW_FRAME: usize = Frame::POSTCARD_MAX_SIZE + 2;

/// Bytes one encoded frame can take on the wire: the raw bound plus COBS
/// overhead (one byte per 254, and the leading code) and the trailing zero.
pub const MAX_ENCODED_FRAME: usize = MAX_RAW_FRAME + MAX_RAW_FRAME / 254 + 2;

/// Encodes frames into a buffer it keeps (so the per-sample path does not
/// clear a fresh one for every frame).
#[derive(Clone, Debug)]
pub struct FrameEncoder {
    out: [u8; MAX_ENCODED_FRAME],
}

impl Default for FrameEncoder {
    fn default() -> Self {
        Self {
            out: [0; MAX_ENCODED_FRAME],
        }
    }
}

impl FrameEncoder {
    /// Encode one frame; returns the bytes to send (ending in `0x00`).
    /// Cannot fail: the buffer is sized by [`MAX_ENCODED_FRAME`]. An empty
    /// slice would mean a bug in that bound; the caller counts it as a
    /// dropped frame.
    pub fn encode(&mut self, frame: &Frame) -> &[u8] {
        let flavor = WireFlavor {
            out: &mut self.out,
            crc: 0xFFFF,
            code_at: 0,
            len: 1,
        };
        match postcard::serialize_with_flavor(frame, flavor) {
            Ok(len) => &self.out[..len],
            Err(_) => &[],
        }
    }
}

/// A postcard flavor that computes the CRC and COBS-encodes in the same
/// pass in which the serializer emits each byte.
///
/// Written here rather than chaining postcard's `Cobs` and `Crc` flavors:
/// those go through the `cobs` crate's general encoder and a digest update
/// per byte, about 40 instructions a byte on Cortex-M3, which alone would
/// eat the per-sample budget; this costs about a third of that. The host
/// decodes with the `cobs` and `crc` crates, so every test that decodes a
/// device frame checks this encoder against them.
struct WireFlavor<'a> {
    out: &'a mut [u8; MAX_ENCODED_FRAME],
    crc: u16,
    /// Index of the current COBS block's code byte.
    code_at: usize,
    /// Bytes written so far, code bytes included.
    len: usize,
}

impl WireFlavor<'_> {
    #[inline(always)]
    fn put(&mut self, at: usize, byte: u8) -> postcard::Result<()> {
        *self
            .out
            .get_mut(at)
            .ok_or(postcard::Error::SerializeBufferFull)? = byte;
        Ok(())
    }

    /// COBS: a zero ends the current block (its code byte is the distance
    /// to it); a block of 254 non-zero bytes ends with code 0xFF.
    #[inline(always)]
    fn push_cobs(&mut self, byte: u8) -> postcard::Result<()> {
        if byte == 0 {
            self.close_block()?;
        } else {
            self.put(self.len, byte)?;
            self.len += 1;
            if self.len - self.code_at == 0xFF {
                self.close_block()?;
            }
        }
        Ok(())
    }

    #[inline(always)]
    fn close_block(&mut self) -> postcard::Result<()> {
        self.put(self.code_at, (self.len - self.code_at) as u8)?;
        self.code_at = self.len;
        self.len += 1;
        Ok(())
    }
}

impl postcard::ser_flavors::Flavor for WireFlavor<'_> {
    type Output = usize;

    #[inline(always)]
    fn try_push(&mut self, byte: u8) -> postcard::Result<()> {
        self.crc = crc16_update(self.crc, byte);
        self.push_cobs(byte)
    }

    fn finalize(mut self) -> postcard::Result<usize> {
        for byte in (!self.crc).to_le_bytes() {
            self.push_cobs(byte)?;
        }
        self.put(self.code_at, (self.len - self.code_at) as u8)?;
        self.put(self.len, 0)?;
        Ok(self.len + 1)
    }
}

/// Why a received frame was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// Not valid COBS, or too long.
    Cobs,
    /// The CRC does not match: corrupted on the way.
    Crc,
    /// The CRC matches but the bytes are not exactly one frame of this
    /// protocol version.
    Postcard,
}

/// Decode one frame from the bytes between two `0x00` delimiters.
pub fn decode(cobs_bytes: &[u8]) -> Result<Frame, DecodeError> {
    let mut raw = [0u8; MAX_ENCODED_FRAME];
    if cobs_bytes.len() > raw.len() {
        return Err(DecodeError::Cobs);
    }
    let n = cobs::decode(cobs_bytes, &mut raw).map_err(|_| DecodeError::Cobs)?;
    if n < 3 {
        return Err(DecodeError::Crc);
    }
    let (body, crc) = raw[..n].split_at(n - 2);
    if FRAME_CRC.checksum(body).to_le_bytes() != crc {
        return Err(DecodeError::Crc);
    }
    match postcard::take_from_bytes::<Frame>(body) {
        Ok((frame, [])) => Ok(frame),
        _ => Err(DecodeError::Postcard),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Frame {
        Frame::Sample(Sample {
            index: 1234,
            x: Nanometres(16_650_000),
            v: NanometresPerSecond(3_000_000),
            force: MicroNewtons(2_240_000),
            model: MicroNewtons(2_200_000),
            residual: MicroNewtons(40_000),
            phase: Phase::Loading,
        })
    }

    /// Pins the wire format. If this fails you changed the bytes on the
    /// wire: bump PROTOCOL_VERSION and update the expectation. The CRC bytes
    /// (0xc9, 0x55) were checked against an independent bitwise CRC-16/X.25.
    #[test]
    fn golden_bytes_pin_the_wire_format() {
        let mut encoder = FrameEncoder::default();
        let bytes = encoder.encode(&sample());
        // Version 2 added the `Halt` frame; a sample's bytes did not change.
        assert_eq!(PROTOCOL_VERSION, 2);
        assert_eq!(
            bytes,
            &[
                0x1a, 0x01, 0xd2, 0x09, 0xa0, 0xbc, 0xf0, 0x0f, 0x80, 0x9b, 0xee, 0x02, 0x80, 0xb8,
                0x91, 0x02, 0x80, 0xc7, 0x8c, 0x02, 0x80, 0xf1, 0x04, 0x01, 0xc9, 0x55, 0x00
            ][..]
        );
    }

    #[test]
    fn the_fused_encoder_matches_postcard_crc_and_the_cobs_crate() {
        for frame in [
            sample(),
            Frame::Header(Header {
                protocol_version: 1,
                sample_rate_hz: 0,
            }),
        ] {
            let mut raw =
                std::vec::Vec::from(postcard::to_slice(&frame, &mut [0u8; 64]).unwrap() as &[u8]);
            raw.extend(FRAME_CRC.checksum(&raw).to_le_bytes());
            let mut expected = std::vec![0; cobs::max_encoding_length(raw.len())];
            let n = cobs::encode(&raw, &mut expected);
            expected.truncate(n);
            expected.push(0);
            assert_eq!(FrameEncoder::default().encode(&frame), &expected[..]);
        }
    }

    #[test]
    fn the_device_crc_agrees_with_the_crc_crate() {
        let data: std::vec::Vec<u8> = (0..600u32).map(|i| (i * 7919 % 251) as u8).collect();
        for len in [0, 1, 2, 9, 25, 255, 600] {
            let ours = !data[..len]
                .iter()
                .fold(0xFFFF, |crc, &b| crc16_update(crc, b));
            assert_eq!(ours, FRAME_CRC.checksum(&data[..len]), "length {len}");
        }
    }

    #[test]
    fn any_single_bit_error_is_caught() {
        let good = FrameEncoder::default().encode(&sample()).to_vec();
        let body = &good[..good.len() - 1];
        for bit in 0..body.len() * 8 {
            let mut bad = body.to_vec();
            bad[bit / 8] ^= 1 << (bit % 8);
            assert!(decode(&bad).is_err(), "bit {bit} flipped went unnoticed");
        }
    }

    #[test]
    fn every_variant_round_trips_within_the_size_bound() {
        let frames = [
            Frame::Header(Header {
                protocol_version: PROTOCOL_VERSION,
                sample_rate_hz: 500,
            }),
            sample(),
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
            }),
            Frame::Halt(Halt {
                index: u32::MAX,
                reason: HaltReason::SpeedLimit,
                x: Nanometres::MAX,
                hold_x: Nanometres::MIN,
            }),
        ];
        for frame in frames {
            let mut encoder = FrameEncoder::default();
            let bytes = encoder.encode(&frame);
            assert!(!bytes.is_empty() && bytes.len() <= MAX_ENCODED_FRAME);
            assert_eq!(
                bytes.iter().filter(|&&b| b == 0).count(),
                1,
                "only the terminator is zero"
            );
            assert_eq!(decode(&bytes[..bytes.len() - 1]), Ok(frame));
        }
    }
}
