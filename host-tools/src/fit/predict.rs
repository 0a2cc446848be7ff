//! The model's force along a measured trial, given the trial's geometry
//! (contact, puncture, relaxed surface): what `fit --plot` overlays and
//! what the sim-to-real diagnosis subtracts.

use needle_holder::model::params::TissueParams;

use super::trial::{velocity_over, TrialFit};
use crate::trial::Trial;

/// The model's force at every sample, by term.
#[derive(Clone, Debug, Default)]
pub struct Parts {
    /// Capsule stiffness, up to puncture.
    pub stiffness_n: Vec<f64>,
    /// Karnopp friction, after puncture.
    pub friction_n: Vec<f64>,
    /// Cutting, after puncture, while advancing into new tissue.
    pub cutting_n: Vec<f64>,
    /// Needle length in tissue after puncture (0 before), m.
    pub length_m: Vec<f64>,
}

/// Expected force at every sample of `trial` under `params`, with the
/// surface positions found by the fit.
pub fn predict(params: &TissueParams, geometry: &TrialFit, trial: &Trial) -> Vec<f64> {
    let p = predict_parts(params, geometry, trial);
    (0..trial.len())
        .map(|i| p.stiffness_n[i] + p.friction_n[i] + p.cutting_n[i])
        .collect()
}

/// [`predict`], term by term.
pub fn predict_parts(params: &TissueParams, geometry: &TrialFit, trial: &Trial) -> Parts {
    // Sliding, stopped and cutting decided on a ±2 ms velocity: the fit's
    // ±10 ms one keeps cutting "on" for 10 ms after a stop, which alone is
    // a residual of the whole cutting force for 5 samples at every stop.
    let v = velocity_over(trial, 0.002);
    let speed = one_sided_speed(trial);
    let mut deepest = geometry.puncture_x_m;
    let mut last_sliding = 0.0;
    let n = trial.len();
    let mut p = Parts {
        stiffness_n: vec![0.0; n],
        friction_n: vec![0.0; n],
        cutting_n: vec![0.0; n],
        length_m: vec![0.0; n],
    };
    for i in 0..n {
        let x = trial.x_m[i];
        if i <= geometry.puncture_index {
            p.stiffness_n[i] = params.stiffness_n(x - geometry.contact_x_m);
            continue;
        }
        let l = x - geometry.relaxed_x_m;
        if l <= 0.0 {
            continue;
        }
        // Sliding or not from the sharp velocity; how fast from the fuller
        // one-sided window, so the last sliding sample before a stop (half
        // a step by central differences) holds the full friction.
        let v_friction = if v[i].abs() >= params.half_band_mps {
            v[i].signum() * speed[i]
        } else {
            v[i]
        };
        let (friction, last) = params.friction_n(v_friction, l, last_sliding);
        last_sliding = last;
        p.friction_n[i] = friction;
        p.cutting_n[i] = params.cutting_n(v[i], x >= deepest);
        p.length_m[i] = l;
        deepest = deepest.max(x);
    }
    p
}

/// Speed over 10 ms on whichever side of the sample moved more: full speed
/// up to the last sample before a stop and from the first after a start.
fn one_sided_speed(trial: &Trial) -> Vec<f64> {
    let n = trial.len();
    let k = ((0.01 * trial.rate_hz()).round() as usize).max(1);
    let dt = 1.0 / trial.rate_hz();
    (0..n)
        .map(|i| {
            let back = i
                .checked_sub(k)
                .map_or(0.0, |a| (trial.x_m[i] - trial.x_m[a]).abs());
            let fwd = trial
                .x_m
                .get(i + k)
                .map_or(0.0, |b| (b - trial.x_m[i]).abs());
            back.max(fwd) / (k as f64 * dt)
        })
        .collect()
}
