//! The model's force along a measured trial, given the trial's geometry
//! (contact, puncture, relaxed surface): what `fit --plot` overlays and
//! what the sim-to-real diagnosis subtracts.

use needle_holder::model::params::TissueParams;

use super::trial::{velocity, TrialFit};
use crate::trial::Trial;

/// Expected force at every sample of `trial` under `params`, with the
/// surface positions found by the fit.
pub fn predict(params: &TissueParams, geometry: &TrialFit, trial: &Trial) -> Vec<f64> {
    let v = velocity(trial);
    let mut deepest = geometry.puncture_x_m;
    let mut last_sliding = 0.0;
    (0..trial.len())
        .map(|i| {
            let x = trial.x_m[i];
            if i <= geometry.puncture_index {
                return params.stiffness_n(x - geometry.contact_x_m);
            }
            let l = x - geometry.relaxed_x_m;
            if l <= 0.0 {
                return 0.0;
            }
            let (friction, last) = params.friction_n(v[i], l, last_sliding);
            last_sliding = last;
            let cutting = params.cutting_n(v[i], x >= deepest);
            deepest = deepest.max(x);
            friction + cutting
        })
        .collect()
}
