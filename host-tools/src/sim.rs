//! Insertion generator: one trial of the paper's protocol with known truth,
//! and its conversion to a firmware replay (raw ADC and encoder counts).
//!
//! The force law here is the paper's model written directly in `f64`
//! (stiffness eq. 4 before puncture; damping friction b·l·v and constant
//! cutting after). It serves the demo; the simulator issue grows it.

use needle_holder::calibration::{Encoder, LoadCell};
use needle_holder::replay::{Record, ReplayHeader};
use needle_holder::units::{MicroNewtons, Nanometres};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::trial::Trial;

/// Tissue parameters, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tissue {
    /// Stiffness eq. 4, linear term, N/m.
    pub a1_n_per_m: f64,
    /// Stiffness eq. 4, quadratic term, N/m².
    pub a2_n_per_m2: f64,
    /// Deformation at which the capsule gives way, m.
    pub puncture_depth_m: f64,
    /// Surface relaxation ρ: x_s3 = x_s1 + ρ·(x_s2 − x_s1).
    pub relaxation: f64,
    /// Cutting force, N.
    pub cutting_force_n: f64,
    /// Damping per unit length, inserting, N·s/m².
    pub bp_ns_per_m2: f64,
    /// Damping per unit length, withdrawing, N·s/m².
    pub bn_ns_per_m2: f64,
}

impl Tissue {
    /// Liver 1 of the paper: Table 1 read in mm (DESIGN.md §1), cutting
    /// 0.94 N, b_p = 1327 (slow insertion), b_n = 458 N·s/m². The paper
    /// gives no relaxation; 0.5 is our assumption.
    pub const LIVER_1: Self = Self {
        a1_n_per_m: 48.0,
        a2_n_per_m2: 5200.0,
        puncture_depth_m: 0.01665,
        relaxation: 0.5,
        cutting_force_n: 0.94,
        bp_ns_per_m2: 1327.0,
        bn_ns_per_m2: 458.0,
    };

    /// Capsule force at deformation `d_m` (eq. 4).
    pub fn stiffness_n(&self, d_m: f64) -> f64 {
        self.a1_n_per_m * d_m + self.a2_n_per_m2 * d_m * d_m
    }
}

/// The motion of one trial.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plan {
    pub rate_hz: f64,
    pub speed_mps: f64,
    /// Position of the tissue surface, m.
    pub surface_x_m: f64,
    /// Deepest point past the surface, m.
    pub depth_m: f64,
    /// Rest at the deepest point, s.
    pub dwell_s: f64,
    /// Force noise, N (standard deviation).
    pub noise_n: f64,
    pub seed: u64,
}

impl Plan {
    /// The paper's protocol: 3 mm/s at 500 Hz, 5 mm of approach.
    pub const PAPER: Self = Self {
        rate_hz: 500.0,
        speed_mps: 0.003,
        surface_x_m: 0.005,
        depth_m: 0.03,
        dwell_s: 2.0,
        noise_n: 0.002,
        seed: 1,
    };
}

/// Ground truth of a generated trial.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Truth {
    pub contact_t_s: f64,
    pub contact_x_m: f64,
    pub puncture_t_s: f64,
    pub puncture_x_m: f64,
    pub puncture_force_n: f64,
}

/// Generate one insertion: in, dwell, out, at constant speed.
pub fn insertion(tissue: &Tissue, plan: &Plan) -> (Trial, Truth) {
    let dt = 1.0 / plan.rate_hz;
    let deepest = plan.surface_x_m + plan.depth_m;
    let t_in = deepest / plan.speed_mps;
    let t_total = 2.0 * t_in + plan.dwell_s;
    let n = (t_total * plan.rate_hz).round() as usize + 1;
    let mut rng = ChaCha8Rng::seed_from_u64(plan.seed);
    let noise = Normal::new(0.0, plan.noise_n.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).unwrap());

    let mut trial = Trial::default();
    let mut truth = Truth::default();
    let mut punctured_at: Option<f64> = None;
    let mut cut_to_m = 0.0_f64;
    for i in 0..n {
        let t = i as f64 * dt;
        let (x, v) = if t < t_in {
            (t * plan.speed_mps, plan.speed_mps)
        } else if t < t_in + plan.dwell_s {
            (deepest, 0.0)
        } else {
            (
                (deepest - (t - t_in - plan.dwell_s) * plan.speed_mps).max(0.0),
                -plan.speed_mps,
            )
        };
        let d = x - plan.surface_x_m;
        let f = match punctured_at {
            None if d <= 0.0 => 0.0,
            None => {
                if truth.contact_t_s == 0.0 {
                    truth.contact_t_s = t;
                    truth.contact_x_m = x;
                }
                let f = tissue.stiffness_n(d);
                if d >= tissue.puncture_depth_m {
                    punctured_at = Some(x);
                    cut_to_m = x;
                    truth.puncture_t_s = t;
                    truth.puncture_x_m = x;
                    truth.puncture_force_n = f;
                }
                f
            }
            Some(x_s2) => {
                let x_s3 = plan.surface_x_m + tissue.relaxation * (x_s2 - plan.surface_x_m);
                let l = (x - x_s3).max(0.0);
                let b = if v >= 0.0 {
                    tissue.bp_ns_per_m2
                } else {
                    tissue.bn_ns_per_m2
                };
                let cutting = if v > 0.0 && x > cut_to_m {
                    tissue.cutting_force_n
                } else {
                    0.0
                };
                cut_to_m = cut_to_m.max(x);
                b * l * v + cutting
            }
        };
        trial.push(t, x, f + noise.sample(&mut rng));
    }
    (trial, truth)
}

/// A trial as a firmware replay file for the given sensor calibration.
pub fn to_replay(trial: &Trial, rate_hz: u16, load_cell: &LoadCell, encoder: &Encoder) -> Vec<u8> {
    let mut bytes = ReplayHeader {
        sample_rate_hz: rate_hz,
    }
    .to_bytes()
    .to_vec();
    for (&x_m, &f_n) in trial.x_m.iter().zip(&trial.f_n) {
        let counts =
            (Nanometres::from_m(x_m).0 as f64 / encoder.nm_per_count as f64).round() as i64;
        let record = Record {
            adc_counts: load_cell.counts_for(MicroNewtons::from_n(f_n)),
            // The hardware counter keeps the low 16 bits.
            encoder_count: counts as u16,
        };
        bytes.extend_from_slice(&record.to_bytes());
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn liver_1_punctures_at_the_papers_force_and_depth() {
        let plan = Plan {
            noise_n: 0.0,
            ..Plan::PAPER
        };
        let (trial, truth) = insertion(&Tissue::LIVER_1, &plan);
        assert!((truth.puncture_force_n - 2.24).abs() < 0.01, "{truth:?}");
        assert!((truth.puncture_x_m - truth.contact_x_m - 0.01665).abs() < 1e-5);
        // After puncture the force falls to cutting plus a little friction.
        let after = trial
            .t_s
            .iter()
            .position(|&t| t > truth.puncture_t_s)
            .unwrap();
        assert!(
            (trial.f_n[after] - 0.94).abs() < 0.05,
            "{}",
            trial.f_n[after]
        );
    }

    #[test]
    fn same_seed_same_bytes() {
        let a = insertion(&Tissue::LIVER_1, &Plan::PAPER).0;
        let b = insertion(&Tissue::LIVER_1, &Plan::PAPER).0;
        assert_eq!(a, b);
    }
}
