//! The compact sample stream: raw readings, batched and delta-coded.
//!
//! The device sends what its sensors gave (ADC counts, encoder count), not
//! what it computed from them: the host runs the same core on the same
//! readings from the same state and configuration and gets the same
//! force, position, velocity, model, residual and phase, bit for bit.
//! Each batch carries a [`BatchCheck`] of the samples the device computed,
//! so a host whose core, configuration or state differs from the device's
//! sees it at the first batch instead of misreading the stream.
//!
//! **Coding of one sample** (LEB128 varints, ZigZag for signed values):
//! the ADC token is the ZigZag of the counts' wrapping difference from the
//! previous sample's (from 0 for a batch's first sample, so each batch
//! decodes alone), then the encoder token, the ZigZag of the 16-bit count's
//! wrapping difference. A sample the converter flagged takes an escape
//! first: the varint `2^32 + flags` (never a difference's ZigZag, which is
//! below 2^32), then the counts' token unless the flags say there are none.
//!
//! Sizes: a still needle with a quiet bridge takes 2 bytes a sample; the
//! bench's liver insertion at its noise about 4 (the ADC noise sets it).

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::framing::varint_len;

/// One sample's readings, as the batch codes them: the converter's, and
/// the encoder's wrapping count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reading {
    /// The conversion, or `None` when the converter returned an error.
    pub adc: Option<AdcReading>,
    /// The encoder's wrapping count.
    pub encoder_count: u16,
}

/// One conversion of the load cell's converter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AdcReading {
    /// Signed counts.
    pub counts: i32,
    /// At full scale.
    pub saturated: bool,
    /// Came late (overrun).
    pub overrun: bool,
}

/// The words of one computed sample the check folds in: position,
/// velocity, force, model, phase (residual is force − model); the core
/// says how a sample gives them.
pub type CheckedWords = [i32; 5];

/// Bytes of coded samples one batch holds at most.
pub const BATCH_BYTES: usize = 512;
/// Samples one batch holds at most.
pub const MAX_BATCH_SAMPLES: usize = 100;
/// Bytes one sample takes at most: escape, counts, encoder.
const MAX_SAMPLE_BYTES: usize = 5 + 5 + 3;

/// Escape flags: the converter returned an error (no counts follow).
pub const FLAG_ERROR: u8 = 1 << 0;
/// Escape flags: the reading is at full scale.
pub const FLAG_SATURATED: u8 = 1 << 1;
/// Escape flags: the reading came late (overrun).
pub const FLAG_OVERRUN: u8 = 1 << 2;
const ESCAPE: u64 = 1 << 32;

/// Samples per batch at a rate: 50 ms of them (25 at 500 Hz, 100 at
/// 2 kHz), so a host shows the stream with a constant 50 ms delay, and
/// the per-batch bytes (about 12) stay under half a byte a sample.
pub const fn samples_per_batch(sample_rate_hz: u16) -> u8 {
    let n = sample_rate_hz as usize / 20;
    if n < 1 {
        1
    } else if n > MAX_BATCH_SAMPLES {
        MAX_BATCH_SAMPLES as u8
    } else {
        n as u8
    }
}

/// A check over the samples of a batch, as the device computed them:
/// FNV-1a over the words of position, velocity, force, model and phase
/// (residual is force − model). Not a cryptographic hash: it catches a
/// host that computes differently, which then differs in many samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BatchCheck(pub u32);

impl Default for BatchCheck {
    fn default() -> Self {
        Self(0x811C_9DC5)
    }
}

impl BatchCheck {
    /// The check a batch starts from after the config frame `wire_bytes`
    /// (as sent, COBS-encoded, without the closing zero): FNV-1a over them,
    /// so a host computing with another configuration fails every batch,
    /// even those whose samples would agree. The bytes of a config frame
    /// depend only on the configuration, so a lost repeat costs nothing.
    pub fn seed(wire_bytes: &[u8]) -> Self {
        Self(wire_bytes.iter().fold(Self::default().0, |h, &b| {
            (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
        }))
    }

    /// Fold one sample's words in.
    #[inline(always)]
    pub fn add(&mut self, words: CheckedWords) {
        let mut h = self.0;
        for word in words {
            h = (h ^ word as u32).wrapping_mul(0x0100_0193);
        }
        self.0 = h;
    }
}

/// A batch being filled on the device.
#[derive(Clone, Debug)]
pub struct BatchWriter {
    bytes: [u8; BATCH_BYTES],
    len: usize,
    samples: u8,
    capacity: u8,
    first_index: u32,
    previous_counts: i32,
    previous_encoder: u16,
    check: BatchCheck,
    seed: BatchCheck,
}

/// A batch as it goes on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Batch<'a> {
    /// Index of the batch's first sample.
    pub first_index: u32,
    /// Samples in it.
    pub samples: u8,
    /// [`BatchCheck`] of the samples, little-endian.
    pub check: [u8; 4],
    /// The coded readings.
    #[serde(borrow, serialize_with = "as_bytes")]
    pub raw: &'a [u8],
}

/// A byte slice as postcard's bytes — a length and the bytes, as a
/// sequence of `u8` is written, so neither the wire nor the schema
/// changes — which postcard hands to its flavor in one call, where a
/// sequence costs a call a byte.
fn as_bytes<S: serde::Serializer>(raw: &&[u8], serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_bytes(raw)
}

/// Written out: its readings are a borrowed slice, of at most
/// [`BATCH_BYTES`].
impl MaxSize for Batch<'_> {
    const POSTCARD_MAX_SIZE: usize = u32::POSTCARD_MAX_SIZE
        + u8::POSTCARD_MAX_SIZE
        + <[u8; 4]>::POSTCARD_MAX_SIZE
        + varint_len(BATCH_BYTES)
        + BATCH_BYTES;
}

impl BatchWriter {
    /// An empty batch of up to `capacity` samples (at least 1, at most
    /// [`MAX_BATCH_SAMPLES`]).
    pub fn new(capacity: u8) -> Self {
        Self {
            bytes: [0; BATCH_BYTES],
            len: 0,
            samples: 0,
            capacity: capacity.clamp(1, MAX_BATCH_SAMPLES as u8),
            first_index: 0,
            previous_counts: 0,
            previous_encoder: 0,
            check: BatchCheck::default(),
            seed: BatchCheck::default(),
        }
    }

    /// Start every batch's check from `seed` (see [`BatchCheck::seed`]);
    /// call on an empty batch.
    pub fn set_seed(&mut self, seed: BatchCheck) {
        self.seed = seed;
        self.check = seed;
    }

    /// No sample in it.
    pub fn is_empty(&self) -> bool {
        self.samples == 0
    }

    /// Add sample `index`'s readings and the words of what the device
    /// computed from them; `true` when the batch is full and must be sent
    /// (and then [`Self::clear`]ed). Offered for inlining: the core's one
    /// caller (`needle_holder::protocol::batch::push`) takes it in whole,
    /// out of line, so the sample's words go straight from the sample.
    #[inline]
    pub fn push(&mut self, raw: Reading, index: u32, checked: CheckedWords) -> bool {
        if self.samples == 0 {
            self.first_index = index;
        }
        match raw.adc {
            Some(AdcReading {
                counts,
                saturated: false,
                overrun: false,
            }) => self.counts(counts),
            Some(a) => {
                let flags = if a.saturated { FLAG_SATURATED } else { 0 }
                    | if a.overrun { FLAG_OVERRUN } else { 0 };
                self.varint(ESCAPE | flags as u64);
                self.counts(a.counts);
            }
            None => self.varint(ESCAPE | FLAG_ERROR as u64),
        }
        let delta = raw.encoder_count.wrapping_sub(self.previous_encoder) as i16;
        self.previous_encoder = raw.encoder_count;
        self.varint(u64::from(((delta << 1) ^ (delta >> 15)) as u16));
        self.check.add(checked);
        self.samples += 1;
        self.samples >= self.capacity || self.len + MAX_SAMPLE_BYTES > BATCH_BYTES
    }

    #[inline(always)]
    fn counts(&mut self, counts: i32) {
        let delta = counts.wrapping_sub(self.previous_counts);
        self.previous_counts = counts;
        self.varint32(((delta << 1) ^ (delta >> 31)) as u32);
    }

    /// The common case in 32-bit arithmetic (64-bit shifts cost on M0/M3).
    #[inline(always)]
    fn varint32(&mut self, mut value: u32) {
        while value >= 0x80 {
            self.put(value as u8 | 0x80);
            value >>= 7;
        }
        self.put(value as u8);
    }

    /// Offered for inlining with [`Self::push`]: every sample's encoder
    /// token goes through it.
    #[inline]
    fn varint(&mut self, value: u64) {
        match u32::try_from(value) {
            Ok(v) => self.varint32(v),
            Err(_) => {
                let mut value = value;
                while value >= 0x80 {
                    self.put(value as u8 | 0x80);
                    value >>= 7;
                }
                self.put(value as u8);
            }
        }
    }

    #[inline(always)]
    fn put(&mut self, byte: u8) {
        // Cannot miss: `push` reports full while a whole sample still fits.
        if let Some(slot) = self.bytes.get_mut(self.len) {
            *slot = byte;
            self.len += 1;
        }
    }

    /// The batch as it goes on the wire.
    pub fn frame(&self) -> Batch<'_> {
        Batch {
            first_index: self.first_index,
            samples: self.samples,
            check: self.check.0.to_le_bytes(),
            raw: self.bytes.get(..self.len).unwrap_or(&[]),
        }
    }

    /// Start the next batch.
    pub fn clear(&mut self) {
        self.len = 0;
        self.samples = 0;
        self.previous_counts = 0;
        self.previous_encoder = 0;
        self.check = self.seed;
    }
}

/// Why a batch's bytes did not decode to its count of samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MalformedBatch;

/// Decode a batch's readings, calling `each` for every sample in order.
pub fn read_raw(batch: &Batch<'_>, mut each: impl FnMut(Reading)) -> Result<(), MalformedBatch> {
    let mut bytes = batch.raw;
    let mut counts: i32 = 0;
    let mut encoder: u16 = 0;
    for _ in 0..batch.samples {
        let mut token = take_varint(&mut bytes)?;
        let mut flags = 0u8;
        if token >= ESCAPE {
            flags = u8::try_from(token - ESCAPE).map_err(|_| MalformedBatch)?;
            if flags == 0 || flags & !(FLAG_ERROR | FLAG_SATURATED | FLAG_OVERRUN) != 0 {
                return Err(MalformedBatch);
            }
            if flags & FLAG_ERROR == 0 {
                token = take_varint(&mut bytes)?;
            }
        }
        let adc = if flags & FLAG_ERROR != 0 {
            None
        } else {
            let zz = u32::try_from(token).map_err(|_| MalformedBatch)?;
            counts = counts.wrapping_add(((zz >> 1) as i32) ^ -((zz & 1) as i32));
            Some(AdcReading {
                counts,
                saturated: flags & FLAG_SATURATED != 0,
                overrun: flags & FLAG_OVERRUN != 0,
            })
        };
        let zz = u16::try_from(take_varint(&mut bytes)?).map_err(|_| MalformedBatch)?;
        encoder = encoder.wrapping_add((((zz >> 1) as i16) ^ -((zz & 1) as i16)) as u16);
        each(Reading {
            adc,
            encoder_count: encoder,
        });
    }
    if bytes.is_empty() {
        Ok(())
    } else {
        Err(MalformedBatch)
    }
}

fn take_varint(bytes: &mut &[u8]) -> Result<u64, MalformedBatch> {
    let mut value = 0u64;
    for shift in (0..64).step_by(7) {
        let (&byte, rest) = bytes.split_first().ok_or(MalformedBatch)?;
        *bytes = rest;
        value |= u64::from(byte & 0x7F) << shift;
        if byte & 0x80 == 0 {
            return Ok(value);
        }
    }
    Err(MalformedBatch)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const WORDS: CheckedWords = [0; 5];

    fn adc_strategy() -> impl Strategy<Value = Option<AdcReading>> {
        prop_oneof![
            8 => any::<i32>().prop_map(|counts| Some(AdcReading { counts, saturated: false, overrun: false })),
            4 => (-100i32..100).prop_map(|counts| Some(AdcReading { counts, saturated: false, overrun: false })),
            2 => (any::<i32>(), any::<bool>(), any::<bool>()).prop_map(|(counts, saturated, overrun)| Some(AdcReading { counts, saturated, overrun })),
            1 => Just(None),
        ]
    }

    proptest! {
        #[test]
        fn any_readings_round_trip(raws in proptest::collection::vec((adc_strategy(), any::<u16>()), 1..150)) {
            let mut writer = BatchWriter::new(MAX_BATCH_SAMPLES as u8);
            let mut decoded = std::vec::Vec::new();
            let mut sent = std::vec::Vec::new();
            for (i, (adc, encoder_count)) in raws.iter().enumerate() {
                let raw = Reading { adc: *adc, encoder_count: *encoder_count };
                sent.push(raw);
                if writer.push(raw, i as u32, WORDS) {
                    read_raw(&writer.frame(), |r| decoded.push(r)).unwrap();
                    writer.clear();
                }
            }
            if !writer.is_empty() {
                read_raw(&writer.frame(), |r| decoded.push(r)).unwrap();
            }
            prop_assert_eq!(decoded, sent);
        }
    }

    #[test]
    fn a_quiet_sample_takes_two_bytes_and_a_truncated_batch_is_refused() {
        let mut writer = BatchWriter::new(25);
        let raw = Reading {
            adc: Some(AdcReading {
                counts: 10,
                saturated: false,
                overrun: false,
            }),
            encoder_count: 3,
        };
        writer.push(raw, 0, WORDS);
        let first = writer.frame().raw.len();
        writer.push(raw, 1, WORDS);
        assert_eq!(writer.frame().raw.len() - first, 2);
        let batch = writer.frame();
        let short = Batch {
            raw: &batch.raw[..batch.raw.len() - 1],
            ..batch
        };
        assert_eq!(read_raw(&short, |_| {}), Err(MalformedBatch));
        let more = Batch {
            samples: 3,
            ..batch
        };
        assert_eq!(read_raw(&more, |_| {}), Err(MalformedBatch));
    }

    /// The bound written out is what the largest batch encodes to:
    /// neither short, which would drop a frame, nor long.
    #[test]
    fn the_batchs_bound_is_its_largest_encoding() {
        let raw = [0x80u8; BATCH_BYTES];
        let batch = Batch {
            first_index: u32::MAX,
            samples: u8::MAX,
            check: [0xff; 4],
            raw: &raw,
        };
        let mut buf = [0u8; 1024];
        let len = postcard::to_slice(&batch, &mut buf).unwrap().len();
        assert_eq!(len, Batch::POSTCARD_MAX_SIZE);
    }

    #[test]
    fn the_check_sees_every_word_and_its_place() {
        let check = |words: CheckedWords| {
            let mut c = BatchCheck::default();
            c.add(words);
            c.0
        };
        let base = check(WORDS);
        for at in 0..5 {
            let mut words = WORDS;
            words[at] = 1;
            assert_ne!(check(words), base, "word {at}");
            let mut other = WORDS;
            other[(at + 1) % 5] = 1;
            assert_ne!(check(words), check(other), "word {at} against the next");
        }
    }
}
