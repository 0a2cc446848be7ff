//! Capsule stiffness before puncture: force against deformation `d` since
//! contact, by the paper's eq. 4 (polynomial) or eq. 3 (rational).

use super::fixed::{affine_times, round_i64, PerLength2Q48, PerLengthQ26};
use super::params::{StiffnessLaw, TissueParams};
use crate::units::{saturate_i32, MicroNewtons, Nanometres};
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Stiffness law in fixed point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub enum Stiffness {
    /// f = a1·d + a2·d², computed as (a1 + a2·d)·d.
    Polynomial {
        /// a1, µN/nm Q26.
        a1: PerLengthQ26,
        /// a2, µN/nm² Q48.
        a2: PerLength2Q48,
    },
    /// f = d/(a·d + b), computed as (d·2^32)/(b·2^32 + a·2^48·d/2^16).
    Rational {
        /// a, 1/µN in Q48 (1 LSB = 3.55e-9 1/N), `i64`.
        a_q48: i64,
        /// b, nm/µN in Q32 (1 LSB = 2.3e-13 m/N), `i64`.
        b_q32: i64,
    },
}

impl Stiffness {
    /// From SI parameters (compile time for the firmware's library).
    pub const fn from_params(p: &TissueParams) -> Self {
        match p.stiffness_law {
            StiffnessLaw::Polynomial => Self::Polynomial {
                a1: PerLengthQ26::from_n_per_m(p.a1_n_per_m),
                a2: PerLength2Q48::from_si(p.a2_n_per_m2),
            },
            // a [1/N] = a·1e-6 [1/µN]; b [m/N] = b·1e3 [nm/µN].
            StiffnessLaw::Rational => Self::Rational {
                a_q48: round_i64(p.rational_a_per_n * 1e-6 * 281_474_976_710_656.0),
                b_q32: round_i64(p.rational_b_m_per_n * 1e3 * 4_294_967_296.0),
            },
        }
    }

    /// Force at deformation `d` (zero for `d ≤ 0`). Past the pole of a
    /// rational law (denominator ≤ 0) the force saturates.
    pub const fn force(&self, d: Nanometres) -> MicroNewtons {
        if d.0 <= 0 {
            return MicroNewtons::ZERO;
        }
        match *self {
            Self::Polynomial { a1, a2 } => MicroNewtons(affine_times(a1, a2, d.0, d.0)),
            Self::Rational { a_q48, b_q32 } => {
                let den_q32 = b_q32.saturating_add(a_q48.saturating_mul(d.0 as i64) >> 16);
                if den_q32 <= 0 {
                    return MicroNewtons::MAX;
                }
                // d < 2^31, so d·2^32 < 2^63: no overflow. Rounded half up
                // from the remainder, because `num + den/2` overflows for a
                // deformation within den/2^33 of i32::MAX.
                let num = (d.0 as i64) << 32;
                let (quotient, remainder) = (num / den_q32, num % den_q32);
                let round_up = remainder >= den_q32 - remainder;
                MicroNewtons(saturate_i32(quotient + round_up as i64))
            }
        }
    }

    /// Smallest deformation at which the force reaches `force` (bisection
    /// over the fixed-point law itself, so it matches what the device
    /// computes), searched up to 1 m; used to back the contact point off
    /// by the deformation the contact threshold needs.
    pub const fn deformation_at(&self, force: MicroNewtons) -> Nanometres {
        let (mut lo, mut hi) = (0i32, 1_000_000_000i32);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if self.force(Nanometres(mid)).0 >= force.0 {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        Nanometres(lo)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Found by CI's proptest: at the largest deformation the rounding
    /// addition overflowed. The quotient must still round half up.
    #[test]
    fn a_rational_law_at_the_largest_deformation_rounds_without_overflow() {
        let law = Stiffness::Rational {
            a_q48: 1 << 34,
            b_q32: 1 << 42,
        };
        let f = law.force(Nanometres(i32::MAX));
        // den = 2^42 + (i64::MAX >> 16) = 2^42 + 2^47 - 1: f = d·2^32/den rounded.
        let den = (1i128 << 42) + (i64::MAX as i128 >> 16);
        let exact = ((i32::MAX as i128) << 32) as f64 / den as f64;
        assert_eq!(f.0, exact.round() as i32);
        let small = Stiffness::Rational {
            a_q48: 0,
            b_q32: 3 << 32,
        };
        // 7/3 = 2.33 → 2, 8/3 = 2.67 → 3.
        assert_eq!(small.force(Nanometres(7)).0, 2);
        assert_eq!(small.force(Nanometres(8)).0, 3);
        let two = Stiffness::Rational {
            a_q48: 0,
            b_q32: 2 << 32,
        };
        assert_eq!(two.force(Nanometres(3)).0, 2, "1.5 rounds half up");
    }
}
