//! Friction along the needle: the paper's modified Karnopp model (§3.2,
//! Figure 6), every coefficient per unit length of needle in tissue and
//! multiplied by that length `l`.
//!
//! | velocity | force |
//! |---|---|
//! | v ≥ Δv/2 | (C_p + b_p·v)·l |
//! | v ≤ −Δv/2 | (C_n + b_n·v)·l |
//! | \|v\| < Δv/2 | the last sliding value, clamped to [D_n·l, D_p·l] |
//!
//! Reading of the paper's F_a inside the band: the paper writes
//! max(D_n, F_a) / min(D_p, F_a) with F_a "the sum of non-frictional
//! forces". The device cannot measure F_a separately from friction, so it
//! holds the friction of the last sliding sample (what the tissue was
//! carrying when the needle stopped) and clamps it to the static band: a
//! needle that stops after inserting keeps its drag up to D_p·l, one that
//! stops after withdrawing keeps its pull down to D_n·l. That is the
//! model at rest of protocol 3 and of a configuration without
//! `hold_applied`; since protocol 4 the pipeline holds the force the
//! needle was applied with instead (`model::relax`), which the load cell
//! measures.

use super::fixed::{affine_times, PerLength2Q48, PerLengthQ26};
use super::params::TissueParams;
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Karnopp coefficients in fixed point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct Friction {
    /// C_p, µN/nm Q26.
    pub cp: PerLengthQ26,
    /// C_n, µN/nm Q26.
    pub cn: PerLengthQ26,
    /// b_p, µN·s/nm² Q48.
    pub bp: PerLength2Q48,
    /// b_n, µN·s/nm² Q48.
    pub bn: PerLength2Q48,
    /// D_p, µN/nm Q26.
    pub dp: PerLengthQ26,
    /// D_n, µN/nm Q26.
    pub dn: PerLengthQ26,
    /// Δv/2.
    pub half_band: NanometresPerSecond,
}

/// Friction state: the last sliding force.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct FrictionState {
    last_sliding: MicroNewtons,
}

impl Friction {
    /// From SI parameters.
    pub const fn from_params(p: &TissueParams) -> Self {
        Self {
            cp: PerLengthQ26::from_n_per_m(p.cp_n_per_m),
            cn: PerLengthQ26::from_n_per_m(p.cn_n_per_m),
            bp: PerLength2Q48::from_si(p.bp_ns_per_m2),
            bn: PerLength2Q48::from_si(p.bn_ns_per_m2),
            dp: PerLengthQ26::from_n_per_m(p.dp_n_per_m),
            dn: PerLengthQ26::from_n_per_m(p.dn_n_per_m),
            half_band: NanometresPerSecond::from_mps(p.half_band_mps),
        }
    }

    /// Friction on `l` of needle in tissue moving at `v`.
    pub fn force(
        &self,
        state: &mut FrictionState,
        v: NanometresPerSecond,
        l: Nanometres,
    ) -> MicroNewtons {
        let l = l.0.max(0);
        if v.0 >= self.half_band.0 {
            state.last_sliding = MicroNewtons(affine_times(self.cp, self.bp, v.0, l));
            state.last_sliding
        } else if v.0 <= self.half_band.0.saturating_neg() {
            state.last_sliding = MicroNewtons(affine_times(self.cn, self.bn, v.0, l));
            state.last_sliding
        } else {
            let (lower, upper) = self.band(Nanometres(l));
            // max/min rather than clamp: no panic when a tissue's band is
            // upside down (upper wins).
            MicroNewtons(state.last_sliding.0.max(lower.0).min(upper.0))
        }
    }

    /// The static band on `l` of needle in tissue: (D_n·l, D_p·l).
    pub fn band(&self, l: Nanometres) -> (MicroNewtons, MicroNewtons) {
        let l = l.0.max(0);
        (
            MicroNewtons(affine_times(self.dn, PerLength2Q48(0), 0, l)),
            MicroNewtons(affine_times(self.dp, PerLength2Q48(0), 0, l)),
        )
    }
}
