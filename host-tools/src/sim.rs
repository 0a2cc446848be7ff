//! Insertion generator: one trial of the paper's protocol with known truth,
//! and its conversion to a firmware replay (raw ADC and encoder counts).
//!
//! The force law is the core's `f64` reference model
//! (`needle_holder::model::reference`) driven by the true geometry.

use needle_holder::calibration::{Encoder, LoadCell};
use needle_holder::replay::{Record, ReplayHeader};
use needle_holder::units::{MicroNewtons, Nanometres};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::trial::Trial;
pub use needle_holder::model::params::TissueParams;

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
pub fn insertion(tissue: &TissueParams, plan: &Plan) -> (Trial, Truth) {
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
    let mut last_sliding_n = 0.0;
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
                let (friction, last) = tissue.friction_n(v, x - x_s3, last_sliding_n);
                last_sliding_n = last;
                let cutting = tissue.cutting_n(v, x >= cut_to_m);
                cut_to_m = cut_to_m.max(x);
                friction + cutting
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
    use needle_holder::model::params::LIVER1;

    #[test]
    fn liver_1_punctures_at_the_papers_force_and_depth() {
        let plan = Plan {
            noise_n: 0.0,
            ..Plan::PAPER
        };
        let (trial, truth) = insertion(&LIVER1, &plan);
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
        let a = insertion(&LIVER1, &Plan::PAPER).0;
        let b = insertion(&LIVER1, &Plan::PAPER).0;
        assert_eq!(a, b);
    }
}
