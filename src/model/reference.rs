//! The same model in `f64`, SI units: the oracle the fixed-point model is
//! tested against, and the force law the host simulator and fitter use.
//! Not used by the firmware.

use super::params::{StiffnessLaw, TissueParams};

impl TissueParams {
    /// Capsule force at deformation `d_m` (eq. 4 or eq. 3), N; zero for
    /// `d_m ≤ 0`, infinite past the pole of a rational law.
    pub fn stiffness_n(&self, d_m: f64) -> f64 {
        if d_m <= 0.0 {
            return 0.0;
        }
        match self.stiffness_law {
            StiffnessLaw::Polynomial => self.a1_n_per_m * d_m + self.a2_n_per_m2 * d_m * d_m,
            StiffnessLaw::Rational => {
                let den = self.rational_a_per_n * d_m + self.rational_b_m_per_n;
                if den <= 0.0 {
                    f64::INFINITY
                } else {
                    d_m / den
                }
            }
        }
    }

    /// Karnopp friction on `l_m` of needle moving at `v_mps`, N, given the
    /// last sliding friction; returns the force and the new last sliding
    /// friction (see `model::friction` for the reading inside the band).
    pub fn friction_n(&self, v_mps: f64, l_m: f64, last_sliding_n: f64) -> (f64, f64) {
        let l = l_m.max(0.0);
        if v_mps >= self.half_band_mps {
            let f = (self.cp_n_per_m + self.bp_ns_per_m2 * v_mps) * l;
            (f, f)
        } else if v_mps <= -self.half_band_mps {
            let f = (self.cn_n_per_m + self.bn_ns_per_m2 * v_mps) * l;
            (f, f)
        } else {
            let f = last_sliding_n.clamp(self.dn_n_per_m * l, self.dp_n_per_m * l);
            (f, last_sliding_n)
        }
    }

    /// Cutting force: constant while the tip advances into uncut tissue.
    pub fn cutting_n(&self, v_mps: f64, advancing_into_uncut: bool) -> f64 {
        if advancing_into_uncut && v_mps >= self.half_band_mps {
            self.cutting_force_n
        } else {
            0.0
        }
    }
}
