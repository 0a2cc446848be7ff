//! Frame stream decoding on the host: split at `0x00`, check and decode each
//! frame with the core's [`protocol::decode`] (COBS, CRC, exactly one
//! frame), track sample-index gaps, and refuse a mismatched protocol version.
//!
//! Written here rather than with postcard's `CobsAccumulator` because that
//! knows no CRC and does not say how many bytes it threw away; this decoder
//! counts every skipped byte.

use needle_holder::protocol::{self, DecodeError, Frame, MAX_ENCODED_FRAME, PROTOCOL_VERSION};

/// One thing found in the stream.
#[derive(Clone, Debug, PartialEq)]
pub enum Item {
    /// A frame that decoded cleanly.
    Frame(Frame),
    /// Bytes that did not form a frame (noise, a partial frame at the start
    /// or end, a corrupted frame), with why.
    Skipped { bytes: usize, reason: &'static str },
    /// Sample indices `first..=last` never arrived.
    Gap { first: u32, last: u32 },
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
}

/// The stream speaks another protocol version.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VersionMismatch {
    pub found: u16,
}

impl std::fmt::Display for VersionMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the device speaks protocol version {}, this needle speaks {}: rebuild one to match the other",
            self.found, PROTOCOL_VERSION
        )
    }
}

impl std::error::Error for VersionMismatch {}

/// Incremental decoder: feed bytes as they arrive.
#[derive(Debug, Default)]
pub struct StreamDecoder {
    pending: Vec<u8>,
    /// Bytes thrown away since the pending buffer overflowed.
    overflow: usize,
    next_index: Option<u32>,
    stats: StreamStats,
}

impl StreamDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// Decode what `bytes` completes; call `on_item` for each item.
    pub fn feed(
        &mut self,
        bytes: &[u8],
        mut on_item: impl FnMut(Item),
    ) -> Result<(), VersionMismatch> {
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
            match protocol::decode(&chunk) {
                Ok(frame) => self.accept(frame, &mut on_item)?,
                Err(DecodeError::Crc) => self.skip(chunk.len() + 1, "CRC mismatch", &mut on_item),
                Err(_) => self.skip(chunk.len() + 1, "undecodable frame", &mut on_item),
            }
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

    fn accept(
        &mut self,
        frame: Frame,
        on_item: &mut impl FnMut(Item),
    ) -> Result<(), VersionMismatch> {
        match frame {
            Frame::Header(h) if h.protocol_version != PROTOCOL_VERSION => {
                return Err(VersionMismatch {
                    found: h.protocol_version,
                })
            }
            Frame::Status(s) if s.protocol_version != PROTOCOL_VERSION => {
                return Err(VersionMismatch {
                    found: s.protocol_version,
                })
            }
            // A header means the device (re)started: indices begin again.
            Frame::Header(_) => self.next_index = None,
            Frame::Sample(s) => {
                if let Some(expected) = self.next_index {
                    if s.index > expected {
                        self.stats.gaps += 1;
                        self.stats.lost_samples += u64::from(s.index - expected);
                        on_item(Item::Gap {
                            first: expected,
                            last: s.index - 1,
                        });
                    }
                }
                self.next_index = Some(s.index.wrapping_add(1));
                self.stats.samples += 1;
            }
            Frame::Event(_) => self.stats.events += 1,
            Frame::Status(_) | Frame::Halt(_) => {}
        }
        self.stats.frames += 1;
        on_item(Item::Frame(frame));
        Ok(())
    }
}

/// Decode a whole byte slice; returns the items and the counters.
pub fn decode_all(bytes: &[u8]) -> Result<(Vec<Item>, StreamStats), VersionMismatch> {
    let mut items = Vec::new();
    let mut decoder = StreamDecoder::new();
    decoder.feed(bytes, |item| items.push(item))?;
    let stats = decoder.finish(|item| items.push(item));
    Ok((items, stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_holder::protocol::{FrameEncoder, Header, Phase, Sample};
    use needle_holder::units::{MicroNewtons, Nanometres, NanometresPerSecond};

    fn bytes_of(frame: Frame) -> Vec<u8> {
        FrameEncoder::default().encode(&frame).to_vec()
    }

    fn sample(index: u32) -> Frame {
        Frame::Sample(Sample {
            index,
            x: Nanometres(index as i32 * 6000),
            v: NanometresPerSecond(3_000_000),
            force: MicroNewtons(1000),
            model: MicroNewtons::ZERO,
            residual: MicroNewtons(1000),
            phase: Phase::Out,
        })
    }

    fn header(version: u16) -> Frame {
        Frame::Header(Header {
            protocol_version: version,
            sample_rate_hz: 500,
        })
    }

    #[test]
    fn gaps_are_reported_with_the_lost_indices() {
        let mut stream = bytes_of(header(PROTOCOL_VERSION));
        for i in [0, 1, 2, 5, 6, 10] {
            stream.extend(bytes_of(sample(i)));
        }
        let (items, stats) = decode_all(&stream).unwrap();
        let gaps: Vec<_> = items
            .iter()
            .filter(|i| matches!(i, Item::Gap { .. }))
            .collect();
        assert_eq!(
            gaps,
            [
                &Item::Gap { first: 3, last: 4 },
                &Item::Gap { first: 7, last: 9 }
            ]
        );
        assert_eq!((stats.samples, stats.gaps, stats.lost_samples), (6, 2, 5));
    }

    #[test]
    fn resynchronises_after_noise_and_counts_every_skipped_byte() {
        let mut stream = vec![0x13, 0x37, 0x42, 0x00]; // tail of a frame we joined late
        stream.extend(bytes_of(sample(0)));
        let mut corrupted = bytes_of(sample(1));
        corrupted[3] ^= 0x01; // x changes by a few nm: only the CRC can tell
        let corrupted_len = corrupted.len();
        stream.extend(corrupted);
        stream.extend(bytes_of(sample(2)));
        stream.extend([7, 7]); // a frame cut short at the end
        let (items, stats) = decode_all(&stream).unwrap();
        let frames = items.iter().filter(|i| matches!(i, Item::Frame(_))).count();
        assert_eq!(frames, 2, "{items:?}");
        assert_eq!(stats.skipped_bytes, 4 + corrupted_len as u64 + 2);
        // The corrupted frame also shows up as a lost sample.
        assert_eq!(stats.lost_samples, 1);
    }

    #[test]
    fn a_run_longer_than_any_frame_is_skipped_once_then_decoding_resumes() {
        let mut stream = vec![0x55; 3 * MAX_ENCODED_FRAME];
        stream.push(0);
        stream.extend(bytes_of(sample(0)));
        let (items, stats) = decode_all(&stream).unwrap();
        assert_eq!(
            items[0],
            Item::Skipped {
                bytes: 3 * MAX_ENCODED_FRAME + 1,
                reason: "longer than any frame"
            }
        );
        assert_eq!((stats.skipped_runs, stats.frames), (1, 1));
    }

    #[test]
    fn a_frame_with_trailing_bytes_is_not_accepted() {
        let mut raw = postcard::to_stdvec(&sample(0)).unwrap();
        raw.push(0x01);
        raw.extend(protocol::FRAME_CRC.checksum(&raw).to_le_bytes());
        let mut stream = cobs::encode_vec(&raw);
        stream.push(0);
        let (items, stats) = decode_all(&stream).unwrap();
        assert_eq!(stats.frames, 0);
        assert!(matches!(
            items[0],
            Item::Skipped {
                reason: "undecodable frame",
                ..
            }
        ));
    }

    #[test]
    fn another_protocol_version_is_refused() {
        let err = decode_all(&bytes_of(header(PROTOCOL_VERSION + 1))).unwrap_err();
        assert_eq!(err.found, PROTOCOL_VERSION + 1);
    }
}
