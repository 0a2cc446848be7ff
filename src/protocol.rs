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
pub const PROTOCOL_VERSION: u16 = 1;

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
}

impl MaxSize for Faults {
    const POSTCARD_MAX_SIZE: usize = u16::POSTCARD_MAX_SIZE;
}
macro_rules! max_size_i32 {
    ($($t:ty),*) => {$(impl MaxSize for $t { const POSTCARD_MAX_SIZE: usize = i32::POSTCARD_MAX_SIZE; })*};
}
max_size_i32!(MicroNewtons, Nanometres, NanometresPerSecond);

/// The frame check: CRC-16/IBM-SDLC (the X.25/HDLC CRC), table-driven.
pub const FRAME_CRC: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_SDLC);

/// Largest frame before COBS: postcard's bound plus the 2-byte CRC.
pub const MAX_RAW_FRAME: usize = Frame::POSTCARD_MAX_SIZE + 2;

/// Bytes one encoded frame can take on the wire: the raw bound plus COBS
/// overhead (one byte per 254, and the leading code) and the trailing zero.
pub const MAX_ENCODED_FRAME: usize = MAX_RAW_FRAME + MAX_RAW_FRAME / 254 + 2;

/// Buffer for one encoded frame.
pub type FrameBuffer = [u8; MAX_ENCODED_FRAME];

/// Encode one frame into `buf`; returns the bytes to send (ending in `0x00`).
/// Cannot fail: `buf` is sized by [`MAX_ENCODED_FRAME`]. An empty slice
/// would mean a bug in that bound; the caller counts it as a dropped frame.
pub fn encode<'a>(frame: &Frame, buf: &'a mut FrameBuffer) -> &'a [u8] {
    let mut raw = [0u8; MAX_RAW_FRAME];
    let Ok(body) = postcard::to_slice(frame, &mut raw[..Frame::POSTCARD_MAX_SIZE]) else {
        return &[];
    };
    let n = body.len();
    let crc = FRAME_CRC.checksum(&raw[..n]).to_le_bytes();
    raw[n..n + 2].copy_from_slice(&crc);
    let Ok(len) = cobs::try_encode(&raw[..n + 2], &mut buf[..MAX_ENCODED_FRAME - 1]) else {
        return &[];
    };
    buf[len] = 0;
    &buf[..=len]
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
        let mut buf = [0; MAX_ENCODED_FRAME];
        let bytes = encode(&sample(), &mut buf);
        assert_eq!(PROTOCOL_VERSION, 1);
        assert_eq!(
            bytes,
            &[
                0x1a, 0x01, 0xd2, 0x09, 0xa0, 0xbc, 0xf0, 0x0f, 0x80, 0x9b, 0xee, 0x02, 0x80, 0xb8,
                0x91, 0x02, 0x80, 0xc7, 0x8c, 0x02, 0x80, 0xf1, 0x04, 0x01, 0xc9, 0x55, 0x00
            ][..]
        );
    }

    #[test]
    fn any_single_bit_error_is_caught() {
        let mut buf = [0; MAX_ENCODED_FRAME];
        let good = encode(&sample(), &mut buf).to_vec();
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
        ];
        for frame in frames {
            let mut buf = [0; MAX_ENCODED_FRAME];
            let bytes = encode(&frame, &mut buf);
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
