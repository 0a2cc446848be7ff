//! Physical quantities as integer newtypes: the unit is in the type name.
//!
//! Every quantity in the per-sample path is an `i32` in a small SI-prefixed
//! unit, so the path is integer-only on Cortex-M0/M3, and arithmetic
//! saturates at the `i32` range instead of wrapping.
//!
//! | type | unit (resolution) | range |
//! |---|---|---|
//! | [`MicroNewtons`] | 1 µN | ±2147.48 N |
//! | [`Nanometres`] | 1 nm | ±2.147 m |
//! | [`NanometresPerSecond`] | 1 nm/s | ±2.147 m/s |
//!
//! The `*_f64` accessors exist for host tools and tests; the firmware never
//! calls them in the per-sample path.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Saturate an `i64` intermediate into the `i32` range.
#[inline]
pub const fn saturate_i32(v: i64) -> i32 {
    // In range exactly when the high word is the low word's sign: one
    // compare of 32-bit words on the M3, where two i64 range compares are
    // four instructions each, on every fixed-point product.
    let low = v as i32;
    if low as i64 == v {
        low
    } else if v < 0 {
        i32::MIN
    } else {
        i32::MAX
    }
}

macro_rules! quantity {
    ($(#[$doc:meta])* $name:ident, $per_si:expr, $si_fn:ident, $from_si:ident) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize, MaxSize, Schema)]
        #[cfg_attr(target_os = "none", derive(defmt::Format))]
        pub struct $name(pub i32);

        impl $name {
            /// Zero.
            pub const ZERO: Self = Self(0);
            /// Largest representable value (saturation point).
            pub const MAX: Self = Self(i32::MAX);
            /// Smallest representable value (saturation point).
            pub const MIN: Self = Self(i32::MIN);
            /// How many of this unit make one SI unit.
            pub const PER_SI: i64 = $per_si;

            /// Saturating sum.
            #[inline]
            pub const fn add(self, rhs: Self) -> Self {
                Self(self.0.saturating_add(rhs.0))
            }
            /// Saturating difference.
            #[inline]
            pub const fn sub(self, rhs: Self) -> Self {
                Self(self.0.saturating_sub(rhs.0))
            }
            /// Saturating absolute value.
            #[inline]
            pub const fn abs(self) -> Self {
                Self(self.0.saturating_abs())
            }
            /// Value in SI units, for host tools and tests.
            pub fn $si_fn(self) -> f64 {
                self.0 as f64 / $per_si as f64
            }
            /// From SI units, rounded to nearest and saturated (NaN to 0).
            /// Host side and configuration only (floating point); `const`
            /// so compiled-in parameters convert at compile time.
            pub const fn $from_si(si: f64) -> Self {
                let scaled = si * $per_si as f64;
                // `as` saturates and maps NaN to 0, which is what we want here.
                Self(if scaled >= 0.0 { scaled + 0.5 } else { scaled - 0.5 } as i32)
            }
        }
    };
}

quantity!(
    /// Force in micronewtons, positive when it resists insertion.
    MicroNewtons, 1_000_000, as_n, from_n
);
quantity!(
    /// Position along the insertion axis in nanometres, increasing into the tissue.
    Nanometres, 1_000_000_000, as_m, from_m
);
quantity!(
    /// Velocity along the insertion axis in nanometres per second, positive inserting.
    NanometresPerSecond, 1_000_000_000, as_mps, from_mps
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_saturates_instead_of_wrapping() {
        assert_eq!(MicroNewtons::MAX.add(MicroNewtons(1)), MicroNewtons::MAX);
        assert_eq!(Nanometres::MIN.sub(Nanometres(1)), Nanometres::MIN);
        assert_eq!(NanometresPerSecond::MIN.abs(), NanometresPerSecond::MAX);
        assert_eq!(saturate_i32(1 << 40), i32::MAX);
        assert_eq!(saturate_i32(-(1 << 40)), i32::MIN);
    }

    #[test]
    fn si_conversions_round_to_nearest_and_saturate() {
        assert_eq!(MicroNewtons::from_n(2.24), MicroNewtons(2_240_000));
        assert_eq!(MicroNewtons::from_n(-0.0000015), MicroNewtons(-2));
        assert_eq!(Nanometres::from_m(1e3), Nanometres::MAX);
        assert_eq!(Nanometres::from_m(f64::NAN), Nanometres::ZERO);
        assert!((Nanometres(16_650_000).as_m() - 0.01665).abs() < 1e-12);
    }
}
