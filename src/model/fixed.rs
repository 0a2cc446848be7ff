//! Fixed-point coefficient formats of the model, and the one product they
//! all reduce to.
//!
//! | format | meaning | 1 LSB | range |
//! |---|---|---|---|
//! | [`PerLengthQ26`] | µN per nm in Q26 (stiffness, friction per length) | 1.49e-5 N/m | ±32 000 N/m (`i32`) |
//! | [`PerLength2Q48`] | µN per nm² (stiffness) or µN·s/nm² (damping) in Q48 | 3.55e-3 N/m² or N·s/m² | ±7.6e6 (`i32`) |
//! | [`FractionQ16`] | a ratio 0–1 in Q16 | 1.5e-5 | 0..=1 (`u32`) |
//!
//! Stiffness `a1 + a2·d` and friction `C + b·v` are both "a per-length
//! coefficient that grows linearly with something" multiplied by a length
//! (`d` or `l`): [`affine_times`] computes `(c0 + c1·u)·w` for both, in
//! `i64`, rounding to nearest and saturating every intermediate, so no
//! input can overflow or panic.

use crate::units::saturate_i32;
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// µN/nm in Q26: 1 N/m = 1e-3 µN/nm = 67 108.864 LSB.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct PerLengthQ26(pub i32);

/// µN/nm² (stiffness) or µN·s/nm² (damping) in Q48: 1 N/m² is
/// 2^48·1e-12 ≈ 281.47 LSB.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct PerLength2Q48(pub i32);

/// A fraction 0–1 in Q16.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct FractionQ16(pub u32);

/// LSB per N/m in [`PerLengthQ26`] (2^26 · 1e-3).
pub const Q26_PER_N_PER_M: f64 = 67_108.864;
/// LSB per N/m² (or N·s/m²) in [`PerLength2Q48`] (2^48 · 1e-12).
pub const Q48_PER_N_PER_M2: f64 = 281.474_976_710_656;

/// Round an `f64` to the nearest `i64`, saturating (and NaN to 0); `const`
/// so compiled-in parameters are converted at compile time.
pub const fn round_i64(v: f64) -> i64 {
    let r = if v >= 0.0 { v + 0.5 } else { v - 0.5 };
    r as i64
}

const fn round_i32(v: f64) -> i32 {
    saturate_i32(round_i64(v))
}

impl PerLengthQ26 {
    /// From N/m, rounded and saturated.
    pub const fn from_n_per_m(v: f64) -> Self {
        Self(round_i32(v * Q26_PER_N_PER_M))
    }
    /// In N/m.
    pub fn as_n_per_m(self) -> f64 {
        self.0 as f64 / Q26_PER_N_PER_M
    }
}

impl PerLength2Q48 {
    /// From N/m² (or N·s/m²), rounded and saturated.
    pub const fn from_si(v: f64) -> Self {
        Self(round_i32(v * Q48_PER_N_PER_M2))
    }
    /// In N/m² (or N·s/m²).
    pub fn as_si(self) -> f64 {
        self.0 as f64 / Q48_PER_N_PER_M2
    }
}

impl FractionQ16 {
    /// One.
    pub const ONE: Self = Self(1 << 16);
    /// From a ratio, clamped to 0..=1.
    pub const fn from_ratio(v: f64) -> Self {
        let clamped = if v > 1.0 {
            1.0
        } else if v >= 0.0 {
            v
        } else {
            0.0
        };
        Self(round_i64(clamped * 65536.0) as u32)
    }
    /// `self · x`, rounded.
    #[inline]
    pub fn of(self, x: i32) -> i32 {
        saturate_i32((x as i64 * self.0 as i64 + (1 << 15)) >> 16)
    }
}

/// Arithmetic shift right by `s` (1..=62) with rounding to nearest.
#[inline]
const fn shr_round(v: i64, s: u32) -> i64 {
    v.saturating_add(1 << (s - 1)) >> s
}

/// `(c0 + c1·u)·w` in µN, for `c0` in µN/nm (Q26), `c1` per unit of `u`
/// in Q48, `u` and `w` integers (nm or nm/s, and nm).
///
/// The coefficient `c0 + c1·u` is saturated to the `i32` range of Q26
/// (±32 000 N/m) before the product, which then fits `i64` exactly; the
/// result saturates at the [`crate::units::MicroNewtons`] range.
#[inline]
pub const fn affine_times(c0: PerLengthQ26, c1: PerLength2Q48, u: i32, w: i32) -> i32 {
    let slope_q26 = shr_round(c1.0 as i64 * u as i64, 48 - 26);
    let k_q26 = saturate_i32((c0.0 as i64).saturating_add(slope_q26));
    saturate_i32(shr_round(k_q26 as i64 * w as i64, 26))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_convert_si_values_and_round_trip() {
        assert_eq!(PerLengthQ26::from_n_per_m(1000.0).0, 67_108_864);
        assert!((PerLengthQ26::from_n_per_m(48.0).as_n_per_m() - 48.0).abs() < 1.5e-5);
        assert!((PerLength2Q48::from_si(5200.0).as_si() - 5200.0).abs() < 3.6e-3);
        assert_eq!(FractionQ16::from_ratio(0.5).of(1_000_000), 500_000);
        assert_eq!(FractionQ16::from_ratio(7.0), FractionQ16::ONE);
    }

    #[test]
    fn affine_times_reproduces_the_paper_puncture_force() {
        let a1 = PerLengthQ26::from_n_per_m(48.0);
        let a2 = PerLength2Q48::from_si(5200.0);
        let d_nm = 16_650_000;
        let f_un = affine_times(a1, a2, d_nm, d_nm);
        assert!((f_un - 2_240_757).abs() <= 2, "{f_un}");
    }

    #[test]
    fn extremes_saturate_without_overflow() {
        let big = PerLengthQ26(i32::MAX);
        let big2 = PerLength2Q48(i32::MAX);
        assert_eq!(affine_times(big, big2, i32::MAX, i32::MAX), i32::MAX);
        assert_eq!(affine_times(big, big2, i32::MIN, i32::MAX), i32::MIN);
        assert_eq!(
            affine_times(PerLengthQ26(i32::MIN), big2, i32::MIN, i32::MIN),
            i32::MAX
        );
    }
}
