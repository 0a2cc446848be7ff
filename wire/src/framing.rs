//! Bytes on the wire, both directions: postcard, then a CRC-16, the whole
//! COBS-framed and ending in a `0x00` byte.
//!
//! A reader that starts mid-stream or loses bytes resynchronises at the
//! next zero; the CRC catches the corrupted frames that would otherwise
//! still decode (postcard accepts almost any bytes as varints), so a line
//! error shows up as a lost frame, not as a wrong force.
//!
//! **The CRC covers an implied version byte.** It is computed over
//! [`PROTOCOL_VERSION`]'s low byte followed by the frame's bytes, but that
//! byte is never sent. A frame of another protocol version therefore fails
//! its check instead of being misread as this one (the role of
//! postcard-rpc's schema hash, for two bytes that are sent anyway). Version
//! 2 frames had no implied byte: the host tells the versions apart by
//! which check a frame passes.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::PROTOCOL_VERSION;

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
pub const fn crc16_update(crc: u16, byte: u8) -> u16 {
    CRC16_TABLE[((crc ^ byte as u16) & 0xFF) as usize] ^ (crc >> 8)
}

/// The running CRC after the implied version byte: where every frame's
/// check starts.
pub const CRC_START: u16 = crc16_update(0xFFFF, PROTOCOL_VERSION as u8);

/// The check of a frame's bytes, implied version byte included.
pub fn frame_check(body: &[u8]) -> u16 {
    frame_check_of_version(PROTOCOL_VERSION, body)
}

/// The check a build of protocol `version` gives a frame's bytes: what a
/// host reads older (and recognises newer) streams by.
pub fn frame_check_of_version(version: u16, body: &[u8]) -> u16 {
    let mut digest = FRAME_CRC.digest();
    digest.update(&[version as u8]);
    digest.update(body);
    digest.finalize()
}

/// Encodes messages into a buffer it keeps (so the per-sample path does
/// not clear a fresh one for every frame). `N` bounds the encoded frame,
/// COBS overhead and terminator included (see [`encoded_bound`]).
#[derive(Clone, Debug)]
pub struct Encoder<const N: usize> {
    out: [u8; N],
}

impl<const N: usize> Default for Encoder<N> {
    fn default() -> Self {
        Self { out: [0; N] }
    }
}

/// Bytes postcard's varint takes for a length or count of at most
/// `max_n`, for the [`MaxSize`] written out for types postcard knows no
/// bound of (its own is private).
pub const fn varint_len(max_n: usize) -> usize {
    let mut bytes = 1;
    let mut rest = max_n >> 7;
    while rest > 0 {
        bytes += 1;
        rest >>= 7;
    }
    bytes
}

/// Bytes a message of at most `raw` bytes (CRC included) takes on the
/// wire: COBS adds one byte per 254 and the leading code, then the zero.
pub const fn encoded_bound(raw: usize) -> usize {
    raw + raw / 254 + 2
}

impl<const N: usize> Encoder<N> {
    /// Encode one message; returns the bytes to send (ending in `0x00`).
    /// An empty slice means the message did not fit `N`: a bug in a size
    /// bound, which the caller counts as a dropped frame.
    ///
    /// Out of line, so that each message type's serialiser exists once
    /// rather than once in every place a frame is built (6 KiB of flash
    /// for the configuration, the snapshot and the status); a call per
    /// frame costs nothing measurable a sample.
    #[inline(never)]
    pub fn encode<T: Serialize + ?Sized>(&mut self, message: &T) -> &[u8] {
        let flavor = WireFlavor {
            out: &mut self.out,
            crc: CRC_START,
            code_at: 0,
            len: 1,
        };
        match postcard::serialize_with_flavor(message, flavor) {
            Ok(len) => self.out.get(..len).unwrap_or(&[]),
            Err(_) => &[],
        }
    }
}

/// A postcard flavor that computes the CRC and COBS-encodes in the same
/// pass in which the serializer emits each byte.
///
/// Written here rather than chaining postcard's `Cobs` and `Crc` flavors:
/// those go through the `cobs` crate's general encoder and a digest update
/// per byte, about 40 instructions a byte on Cortex-M3; this costs about a
/// third of that. The host decodes with the `cobs` and `crc` crates, so
/// every test that decodes a device frame checks this encoder against them.
struct WireFlavor<'a> {
    out: &'a mut [u8],
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

    /// A run of bytes — a batch's readings, most of what is sent — in one
    /// loop out of line, so that it is built as this crate is (for
    /// speed), whatever the crate that serialises the frame is built for.
    #[inline(never)]
    fn try_extend(&mut self, bytes: &[u8]) -> postcard::Result<()> {
        bytes.iter().try_for_each(|&byte| self.try_push(byte))
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum DecodeError {
    /// Not valid COBS, or longer than any message.
    Cobs,
    /// The check does not match: corrupted on the way, or another
    /// protocol version.
    Crc,
    /// The check matches but the bytes are not exactly one message.
    Postcard,
}

/// Undo COBS and check the CRC of the bytes between two `0x00`
/// delimiters, in place; returns the message's bytes.
///
/// `check` is the CRC the message must carry over its bytes: pass
/// [`frame_check`] for this version.
pub fn unframe<'b>(
    cobs_bytes: &[u8],
    buffer: &'b mut [u8],
    check: impl Fn(&[u8]) -> u16,
) -> Result<&'b [u8], DecodeError> {
    if cobs_bytes.len() > buffer.len() {
        return Err(DecodeError::Cobs);
    }
    let n = cobs::decode(cobs_bytes, buffer).map_err(|_| DecodeError::Cobs)?;
    if n < 3 {
        return Err(DecodeError::Crc);
    }
    let frame = buffer.get(..n).ok_or(DecodeError::Cobs)?;
    let (body, crc) = frame.split_at_checked(n - 2).ok_or(DecodeError::Crc)?;
    if check(body).to_le_bytes() != crc {
        return Err(DecodeError::Crc);
    }
    Ok(body)
}

/// Decode exactly one message from checked bytes.
pub fn parse<'b, T: Deserialize<'b>>(body: &'b [u8]) -> Result<T, DecodeError> {
    match postcard::take_from_bytes::<T>(body) {
        Ok((message, [])) => Ok(message),
        _ => Err(DecodeError::Postcard),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    /// postcard, CRC, COBS by the crates' own means: what the host does.
    pub(crate) fn reference_frame<T: Serialize>(
        message: &T,
        check: impl Fn(&[u8]) -> u16,
    ) -> Vec<u8> {
        let mut buf = [0u8; 2048];
        let mut raw = Vec::from(&*postcard::to_slice(message, &mut buf).unwrap());
        raw.extend(check(&raw).to_le_bytes());
        let mut framed = std::vec![0u8; cobs::max_encoding_length(raw.len())];
        let n = cobs::encode(&raw, &mut framed);
        framed.truncate(n);
        framed
    }

    #[test]
    fn the_device_crc_agrees_with_the_crc_crate() {
        let data: std::vec::Vec<u8> = (0..600u32).map(|i| (i * 7919 % 251) as u8).collect();
        for len in [0, 1, 2, 9, 25, 255, 600] {
            let ours = !data[..len]
                .iter()
                .fold(0xFFFF, |crc, &b| crc16_update(crc, b));
            assert_eq!(ours, FRAME_CRC.checksum(&data[..len]), "length {len}");
            let versioned = !data[..len]
                .iter()
                .fold(CRC_START, |crc, &b| crc16_update(crc, b));
            assert_eq!(versioned, frame_check(&data[..len]), "length {len}");
        }
    }

    #[test]
    fn the_fused_encoder_matches_postcard_crc_and_the_cobs_crate() {
        let message = (1234u32, -5i32, &[7u8; 300][..]);
        let mut expected = reference_frame(&message, frame_check);
        expected.push(0);
        let mut encoder = Encoder::<400>::default();
        assert_eq!(encoder.encode(&message), &expected[..]);
        let mut small = Encoder::<64>::default();
        assert!(
            small.encode(&message).is_empty(),
            "a message too big is refused"
        );
    }

    #[test]
    fn a_message_of_another_version_fails_the_check() {
        // No implied byte: version 2.
        let framed = reference_frame(&(3u8, 500u16), |b| FRAME_CRC.checksum(b));
        let mut buf = [0u8; 64];
        assert_eq!(
            unframe(&framed, &mut buf, frame_check),
            Err(DecodeError::Crc)
        );
        let mut buf = [0u8; 64];
        assert!(unframe(&framed, &mut buf, |b| FRAME_CRC.checksum(b)).is_ok());
    }
}
