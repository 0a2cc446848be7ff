//! One trial made ready for diagnosis: the nominal model along it, the
//! residual, the phase of every sample (DESIGN.md §4 names), and the
//! kinematic signals the candidate effects are built from.

use needle_holder::config::DeviceConfig;
use needle_holder::model::params::TissueParams;

use crate::fit::predict::predict_parts;
use crate::fit::trial::velocity;
use crate::fit::TrialFit;
use crate::trial::Trial;

/// Phases as the diagnosis splits them.
pub const PHASES: [&str; 4] = ["out", "loading", "inserted", "withdrawal"];

/// A trial with its nominal model and signals.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub file: String,
    pub trial: Trial,
    pub geometry: TrialFit,
    pub nominal_n: Vec<f64>,
    pub residual_n: Vec<f64>,
    /// Index into [`PHASES`].
    pub phase: Vec<usize>,
    pub v_mps: Vec<f64>,
    pub a_mps2: Vec<f64>,
    /// Nominal friction term and needle length in tissue after puncture.
    pub friction_n: Vec<f64>,
    pub length_m: Vec<f64>,
    /// The nominal cutting term is on.
    pub cutting: Vec<bool>,
    /// Interior structures the device's detector found: (sample index,
    /// peak position, wall force = fall of the force there).
    pub structures: Vec<(usize, f64, f64)>,
    pub noise_n: f64,
}

/// Prepare a trial against `params`, with its geometry as `needle fit`'s
/// code found it.
pub fn prepare(file: String, trial: Trial, geometry: TrialFit, params: &TissueParams) -> Prepared {
    let parts = predict_parts(params, &geometry, &trial);
    let n = trial.len();
    let nominal_n: Vec<f64> = (0..n)
        .map(|i| parts.stiffness_n[i] + parts.friction_n[i] + parts.cutting_n[i])
        .collect();
    let residual_n: Vec<f64> = (0..n).map(|i| trial.f_n[i] - nominal_n[i]).collect();
    let v_mps = velocity(&trial);
    let phase = (0..n)
        .map(|i| {
            let x = trial.x_m[i];
            if i <= geometry.puncture_index {
                usize::from(x >= geometry.contact_x_m)
            } else if parts.length_m[i] <= 0.0 {
                0
            } else if v_mps[i] < -0.0005 {
                3
            } else {
                2
            }
        })
        .collect();
    let a_mps2 = acceleration(&trial);
    let structures = structures(&trial, params, &residual_n);
    Prepared {
        file,
        noise_n: geometry.noise_n,
        geometry,
        nominal_n,
        residual_n,
        phase,
        v_mps,
        a_mps2,
        friction_n: parts.friction_n,
        length_m: parts.length_m,
        cutting: parts.cutting_n.iter().map(|&c| c != 0.0).collect(),
        structures,
        trial,
    }
}

/// Second difference of position, m/s².
fn acceleration(trial: &Trial) -> Vec<f64> {
    let n = trial.len();
    let dt = 1.0 / trial.rate_hz();
    (0..n)
        .map(|i| {
            if i == 0 || i + 1 >= n {
                0.0
            } else {
                (trial.x_m[i + 1] - 2.0 * trial.x_m[i] + trial.x_m[i - 1]) / (dt * dt)
            }
        })
        .collect()
}

/// Structure events of the device's own detector, with the wall force
/// taken as the fall of the residual across the event.
fn structures(trial: &Trial, params: &TissueParams, residual: &[f64]) -> Vec<(usize, f64, f64)> {
    let Ok(config) = DeviceConfig::for_tissue(params) else {
        return Vec::new();
    };
    let found = crate::detect::detect_trial(trial, &config);
    found
        .events
        .iter()
        .filter(|e| e.kind == "structure")
        .filter_map(|e| {
            let at = trial.t_s.iter().position(|&t| t >= e.t_s)?;
            let peak = trial.x_m[..at].iter().rposition(|&x| x <= e.x_m)?;
            let before = residual[peak.saturating_sub(2)..=peak]
                .iter()
                .copied()
                .fold(f64::MIN, f64::max);
            let after_end = (at + 6).min(residual.len());
            let after =
                residual[at..after_end].iter().sum::<f64>() / (after_end - at).max(1) as f64;
            Some((peak, e.x_m, (before - after).max(0.0)))
        })
        .collect()
}
