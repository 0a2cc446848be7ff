//! Raw counts to physical units: load-cell tare and gain, encoder scale.

use crate::units::{saturate_i32, MicroNewtons, Nanometres};
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Load-cell calibration: `force = (counts − tare) · gain`.
///
/// `gain_q16` is the gain in µN per ADC count in Q16.16 (resolution
/// 1/65536 µN per count, range up to 32767 µN per count). The product is
/// formed in `i64` and saturates at the [`MicroNewtons`] range.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
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

    /// A full-bridge cell rated `rated_n` with `output_mv_per_v` of
    /// signal per volt of excitation at that load, on a 24-bit converter
    /// at PGA gain `pga_gain` whose reference is the excitation
    /// (ratiometric: the excitation cancels), saturating at
    /// `saturation_counts`. The rated load reads output · gain of full
    /// scale (2 mV/V at gain 128: 0.256 of it, 2.15 M counts).
    pub const fn ratiometric_bridge(
        rated_n: f64,
        output_mv_per_v: f64,
        pga_gain: u32,
        saturation_counts: i32,
    ) -> Self {
        let rated_counts = output_mv_per_v / 1000.0 * pga_gain as f64 * (1u32 << 23) as f64;
        Self {
            tare_counts: 0,
            gain_q16: crate::model::fixed::round_i64(rated_n * 1e6 * 65536.0 / rated_counts) as i32,
            full_scale_counts: saturation_counts,
        }
    }

    /// The bill of materials' cell on the real board: a 2 lb (8.90 N)
    /// FUTEK LSB200 at its 2 mV/V, on the ADS1220 at gain 128 with the
    /// excitation as reference, saturating where the PGA leaves its linear
    /// range (7/8 of full scale, 30 N): 4.142 µN a count. A cell of
    /// another output or range is set by `needle device calibrate`.
    pub const LSB200_2LB_ADS1220: Self =
        Self::ratiometric_bridge(8.896_443, 2.0, 128, crate::ads1220::LINEAR_LIMIT_HIGH_GAIN);

    /// The most the load cell may read at zero for a tare (at boot or on
    /// command) to take it as an offset rather than a load on the needle:
    /// 0.5 N, in counts of this calibration.
    pub fn most_tare_offset_counts(&self) -> u32 {
        // A gain of zero (which no check lets through) allows any offset.
        let scaled = (MOST_TARE_OFFSET.0 as u64) << 16;
        let counts = scaled
            .checked_div(u64::from(self.gain_q16.unsigned_abs()))
            .unwrap_or(u64::MAX);
        u32::try_from(counts).unwrap_or(u32::MAX)
    }

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

/// The most a load cell may read at zero and still be tared: 0.5 N, a
/// bridge's offset is far less, and a needle resting on something more.
pub const MOST_TARE_OFFSET: MicroNewtons = MicroNewtons(500_000);

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
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
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

/// The smallest load-cell gain a command or the settings may set, in
/// magnitude: 0.01 µN a count (Q16.16), far finer than any cell on a
/// 24-bit converter; a gain near zero would read every load as none.
pub const MIN_GAIN_Q16: u32 = 656;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_boms_cell_reads_its_rated_load_and_a_tare_stops_at_half_a_newton() {
        // 2 mV/V at gain 128: the rated 8.90 N is 0.256 of full scale.
        let cell = LoadCell::LSB200_2LB_ADS1220;
        assert_eq!(cell.gain_q16, 271_498); // 4.1427 µN a count
        let rated_counts = (0.002 * 128.0 * f64::from(1 << 23)) as i32;
        assert!((cell.force(rated_counts).as_n() - 8.896_443).abs() < 1e-5);
        // It saturates where the PGA leaves its linear range: 30.4 N.
        assert_eq!(cell.full_scale_counts, 7_340_032);
        assert!((cell.force(cell.full_scale_counts).as_n() - 30.41).abs() < 0.01);
        // 0.5 N of offset is the most either cell tares.
        for cell in [LoadCell::TEN_NEWTON_24_BIT, LoadCell::LSB200_2LB_ADS1220] {
            let most = cell.most_tare_offset_counts() as i32;
            let at_zero = LoadCell {
                tare_counts: 0,
                ..cell
            };
            assert!(at_zero.force(most).0 <= 500_000, "{cell:?}");
            assert!(at_zero.force(most + 1).0 > 500_000 - 5, "{cell:?}");
        }
        assert_eq!(
            LoadCell::TEN_NEWTON_24_BIT.most_tare_offset_counts(),
            419_430
        );
        let no_gain = LoadCell {
            gain_q16: 0,
            ..LoadCell::TEN_NEWTON_24_BIT
        };
        assert_eq!(no_gain.most_tare_offset_counts(), u32::MAX);
    }

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
