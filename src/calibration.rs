//! Raw counts to physical units: load-cell tare and gain, encoder scale.

use crate::units::{saturate_i32, MicroNewtons, Nanometres};
use serde::{Deserialize, Serialize};

/// Load-cell calibration: `force = (counts − tare) · gain`.
///
/// `gain_q16` is the gain in µN per ADC count in Q16.16 (resolution
/// 1/65536 µN per count, range up to 32767 µN per count). The product is
/// formed in `i64` and saturates at the [`MicroNewtons`] range.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LoadCell {
    /// ADC counts at zero force.
    pub tare_counts: i32,
    /// µN per count, Q16.16.
    pub gain_q16: i32,
    /// Converter full scale in counts: a reading at or beyond ±this is saturated.
    pub full_scale_counts: i32,
}

impl LoadCell {
    /// A 10 N load cell on a 24-bit converter whose ±full scale spans ±10 N:
    /// 10 N / 2^23 counts = 1.1921 µN per count, exactly 78125 in Q16.16.
    pub const TEN_NEWTON_24_BIT: Self = Self {
        tare_counts: 0,
        gain_q16: 78_125,
        full_scale_counts: (1 << 23) - 1,
    };

    /// Calibrated force for a raw reading.
    #[inline]
    pub fn force(&self, counts: i32) -> MicroNewtons {
        let net = counts as i64 - self.tare_counts as i64;
        MicroNewtons(saturate_i32((net * self.gain_q16 as i64) >> 16))
    }

    /// Raw counts that read as `force` (inverse of [`Self::force`], rounded),
    /// for generating replays on the host.
    pub fn counts_for(&self, force: MicroNewtons) -> i32 {
        let scaled = ((force.0 as i64) << 16) + self.gain_q16 as i64 / 2;
        saturate_i32(scaled.div_euclid(self.gain_q16 as i64) + self.tare_counts as i64)
    }
}

/// The load cell's zero found at boot: the mean of the first
/// [`BootTare::SAMPLES`] readings with the needle at rest and unloaded.
/// A mean further from the converter's zero than `max_offset_counts` is a
/// load on the needle (or a broken bridge), not an offset to tare away.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BootTare {
    sum: i64,
    taken: u32,
    /// Largest plausible offset of an unloaded bridge, counts.
    pub max_offset_counts: i32,
}

/// What a finished [`BootTare`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TareResult {
    /// Still collecting.
    Collecting,
    /// The zero, in counts.
    Zero(i32),
    /// A load at boot: the mean reading, in counts.
    Loaded(i32),
}

impl BootTare {
    /// Readings averaged (a quarter of a second at 1 kSPS; the mean's noise
    /// is a sixteenth of one reading's).
    pub const SAMPLES: u32 = 256;

    /// Start collecting.
    pub const fn new(max_offset_counts: i32) -> Self {
        Self {
            sum: 0,
            taken: 0,
            max_offset_counts,
        }
    }

    /// Add one reading; the result once [`Self::SAMPLES`] are in.
    pub fn add(&mut self, counts: i32) -> TareResult {
        if self.taken < Self::SAMPLES {
            self.sum += i64::from(counts);
            self.taken += 1;
        }
        if self.taken < Self::SAMPLES {
            return TareResult::Collecting;
        }
        // |sum| ≤ 256 · 2^31, and the mean (rounded to nearest) is within
        // i32 but for the top half-count, which saturates.
        let n = i64::from(Self::SAMPLES);
        let mean = saturate_i32((self.sum + n / 2).div_euclid(n));
        if mean.unsigned_abs() > self.max_offset_counts.unsigned_abs() {
            TareResult::Loaded(mean)
        } else {
            TareResult::Zero(mean)
        }
    }
}

/// The load cell's recent zero for a tare on command: an exponential
/// average of the raw counts with a time constant of 128 samples (a
/// quarter second at 500 Hz), in Q4 counts. Counts are clamped to
/// ±(2^26 − 1), beyond any 24-bit converter, so that the average and the
/// difference between a reading and it (at most 2^31 − 32) fit `i32`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ZeroTracker {
    mean_q4: i32,
    primed: bool,
}

impl ZeroTracker {
    /// Fold in one reading.
    #[inline]
    pub fn add(&mut self, counts: i32) {
        const LIMIT: i32 = (1 << 26) - 1;
        let c_q4 = counts.clamp(-LIMIT, LIMIT) << 4;
        if !self.primed {
            self.mean_q4 = c_q4;
            self.primed = true;
        }
        self.mean_q4 += (c_q4 - self.mean_q4) >> 7;
    }

    /// The average, counts (rounded); `None` before any reading.
    pub fn mean_counts(&self) -> Option<i32> {
        self.primed.then_some((self.mean_q4 + 8) >> 4)
    }
}

/// Encoder scale: nanometres of needle travel per count.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Encoder {
    /// Travel per count, nm (1000 for a 1 µm linear scale).
    pub nm_per_count: i32,
    /// Largest count change between two samples that the mechanics allow;
    /// a larger jump is a glitch and raises [`crate::faults::Faults::ENCODER_JUMP`].
    pub max_counts_per_sample: u16,
}

impl Encoder {
    /// A 1 µm linear encoder on a drive that moves at most 100 mm/s; at the
    /// slowest supported rate (500 Hz) that is 200 counts per sample.
    pub const ONE_MICRON: Self = Self {
        nm_per_count: 1_000,
        max_counts_per_sample: 200,
    };

    /// Position for an unwrapped count, saturating.
    #[inline]
    pub fn position(&self, counts: i32) -> Nanometres {
        Nanometres(saturate_i32(counts as i64 * self.nm_per_count as i64))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_scale_reads_ten_newtons_and_inverse_round_trips() {
        let cell = LoadCell::TEN_NEWTON_24_BIT;
        assert_eq!(cell.force(1 << 23), MicroNewtons(10_000_000));
        assert_eq!(cell.force(-(1 << 23)), MicroNewtons(-10_000_000));
        for f in [-2_000_000, -1, 0, 1, 940_000, 2_240_000] {
            let back = cell.force(cell.counts_for(MicroNewtons(f)));
            assert!((back.0 - f).abs() <= 1, "{f} -> {back:?}");
        }
    }

    #[test]
    fn extreme_inputs_saturate() {
        let cell = LoadCell {
            tare_counts: i32::MIN,
            gain_q16: i32::MAX,
            full_scale_counts: 1,
        };
        assert_eq!(cell.force(i32::MAX), MicroNewtons::MAX);
        let enc = Encoder {
            nm_per_count: i32::MAX,
            max_counts_per_sample: 1,
        };
        assert_eq!(enc.position(i32::MIN), Nanometres::MIN);
    }

    #[test]
    fn boot_tare_zeroes_an_offset_and_refuses_a_load() {
        // An unloaded bridge 1500 counts off zero, ±3 counts of noise.
        let mut tare = BootTare::new(50_000);
        let mut result = TareResult::Collecting;
        for k in 0..BootTare::SAMPLES {
            assert_eq!(result, TareResult::Collecting);
            result = tare.add(1500 + (k % 7) as i32 - 3);
        }
        assert_eq!(result, TareResult::Zero(1500));
        // Half a newton on the needle at boot (10 N full scale on 2^23).
        let mut tare = BootTare::new(50_000);
        let loaded = (0..BootTare::SAMPLES).map(|_| tare.add(-419_430)).last();
        assert_eq!(loaded, Some(TareResult::Loaded(-419_430)));
        // Saturated readings do not overflow the mean.
        let mut tare = BootTare::new(50_000);
        let full = (0..BootTare::SAMPLES).map(|_| tare.add(i32::MIN)).last();
        assert_eq!(full, Some(TareResult::Loaded(i32::MIN)));
    }

    /// A reading at one end of `i32` after one at the other: the step
    /// toward it (once 2^31, past `i32`) stays in range, and the mean
    /// heads for the clamp without wrapping.
    #[test]
    fn the_zero_tracker_takes_readings_from_end_to_end_of_i32() {
        let mut zero = ZeroTracker::default();
        zero.add(i32::MIN);
        assert_eq!(zero.mean_counts(), Some(-((1 << 26) - 1)));
        let mut last = i32::MIN;
        for _ in 0..4000 {
            zero.add(i32::MAX);
            let mean = zero.mean_counts().unwrap();
            assert!(mean >= last && mean < (1 << 26), "{last} then {mean}");
            last = mean;
        }
        assert!(last > (1 << 26) - 64, "{last}");
    }
}
