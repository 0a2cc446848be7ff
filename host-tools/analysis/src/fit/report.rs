//! What `needle fit` found over a dataset, as types: [`FitReport`] is its
//! JSON (`--json`) and what the tissue it writes (`--toml`) is read from.

use needle_io::trial::Skipped;
use serde::ser::{Serialize, SerializeMap, Serializer};

/// One quantity estimated over the trials: its value (`None`: not
/// identified) and what qualifies it. Serialised as a bare number when
/// nothing qualifies it (a single trial), otherwise as an object with the
/// fields that are present.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Estimate {
    pub value: Option<f64>,
    /// Sample standard deviation over the trials.
    pub sd: Option<f64>,
    /// Residual standard deviation of a line fitted across trials.
    pub residual_sd: Option<f64>,
    /// The most the data allow where the value is not identified
    /// (`lower_bound` for a positive quantity, `upper_bound` otherwise).
    pub bound: Option<Bound>,
    /// The value the model takes where the data give none.
    pub model_uses: Option<f64>,
    pub note: Option<String>,
}

/// A one-sided bound on a quantity the data do not identify.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Bound {
    Lower(Option<f64>),
    Upper(Option<f64>),
}

impl Estimate {
    /// Mean and sample standard deviation of `values` (no sd for one).
    pub fn of(values: &[f64]) -> Self {
        let (mean, sd) = mean_sd(values);
        Self {
            value: Some(mean),
            sd,
            ..Self::default()
        }
    }

    /// A value chosen rather than estimated (the model's own, or one set
    /// from another estimate): no value of its own, the model's given.
    pub fn chosen(model_uses: f64) -> Self {
        Self {
            model_uses: Some(model_uses),
            ..Self::default()
        }
    }

    /// The number the model takes for it: the estimate, else the value
    /// the model uses where the data give none, else the bound the data
    /// give (what was seen held).
    pub fn written(&self) -> Option<f64> {
        let bound = match self.bound {
            Some(Bound::Lower(b) | Bound::Upper(b)) => b,
            None => None,
        };
        self.value.or(self.model_uses).or(bound)
    }

    /// Only a note (no value: not identified, unless the caller sets it).
    pub fn noting(note: impl Into<String>) -> Self {
        Self {
            note: Some(note.into()),
            ..Self::default()
        }
    }

    fn bare(&self) -> bool {
        self.sd.is_none()
            && self.residual_sd.is_none()
            && self.bound.is_none()
            && self.model_uses.is_none()
            && self.note.is_none()
            && self.value.is_some()
    }
}

impl Serialize for Estimate {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        if self.bare() {
            return s.serialize_f64(self.value.unwrap_or(f64::NAN));
        }
        let mut m = s.serialize_map(None)?;
        m.serialize_entry("value", &self.value)?;
        if let Some(sd) = self.sd {
            m.serialize_entry("sd", &sd)?;
        }
        if let Some(sd) = self.residual_sd {
            m.serialize_entry("residual_sd", &sd)?;
        }
        match self.bound {
            Some(Bound::Lower(b)) => m.serialize_entry("lower_bound", &b)?,
            Some(Bound::Upper(b)) => m.serialize_entry("upper_bound", &b)?,
            None => {}
        }
        if let Some(v) = self.model_uses {
            m.serialize_entry("model_uses", &v)?;
        }
        if let Some(note) = &self.note {
            m.serialize_entry("note", note)?;
        }
        m.end()
    }
}

/// Mean and sample standard deviation (None for one value).
pub fn mean_sd(values: &[f64]) -> (f64, Option<f64>) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let sd = (values.len() > 1)
        .then(|| (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt());
    (mean, sd)
}

/// How well a stiffness law fitted the loading curves, on average.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct LawFit {
    pub rms_n: f64,
    pub r2: f64,
}

/// Both stiffness laws, and the one the tissue takes.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct StiffnessLaws {
    pub polynomial: LawFit,
    pub rational: LawFit,
    /// `"polynomial"` or `"rational"`.
    pub better: &'static str,
}

/// Friction per length at each trial's one speed (trials without
/// strokes both ways).
#[derive(Clone, Debug, serde::Serialize)]
pub struct AtSpeeds {
    pub speed_mps: Vec<f64>,
    pub n_per_m: Vec<f64>,
}

/// How the force relaxed where the needle rested in the tissue.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DwellSummary {
    pub trials: usize,
    pub duration_s: Estimate,
    pub fraction: Estimate,
    pub tau_s: Estimate,
    pub gain: Estimate,
    pub fall_n: Estimate,
}

/// A membrane punctured after the capsule.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LayerSummary {
    /// 2 for the first membrane after the capsule.
    pub layer: usize,
    pub trials: usize,
    pub puncture_force_n: Estimate,
    pub drop_to_n: Estimate,
}

/// One trial's geometry.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrialGeometry {
    pub file: String,
    pub contact_x_m: f64,
    pub puncture_x_m: f64,
    pub puncture_force_n: f64,
    pub relaxed_surface_x_m: f64,
    /// The offset taken off the trial's force before fitting, N (its
    /// residual tare: the median force in air before the loading rise).
    pub tare_n: f64,
}

/// How far to trust the puncture detector with the fitted tissue, on the
/// fitted trials as the device's detector reads them: the largest fall
/// while loading before each peak and its margin to firing early, the
/// smallest capsule fall after it and its margin to being missed.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PunctureMargins {
    pub threshold_n: f64,
    pub least_peak_n: f64,
    pub largest_fall_before_peak_n: f64,
    pub margin_to_early_n: f64,
    pub smallest_puncture_fall_n: f64,
    pub margin_to_miss_n: f64,
    pub note: &'static str,
}

/// `needle fit`'s estimates over a dataset: mean ± sd of the per-trial
/// fits, the per-trial geometry and the trials left out.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FitReport {
    pub trials: usize,
    pub a1_n_per_m: Estimate,
    pub a2_n_per_m2: Estimate,
    pub rational_a_per_n: Estimate,
    pub rational_b_m_per_n: Estimate,
    pub stiffness_fit: StiffnessLaws,
    pub puncture_force_n: Estimate,
    pub puncture_depth_m: Estimate,
    pub puncture_drop_to_n: Estimate,
    pub puncture_drop_n: Estimate,
    pub cutting_force_n: Estimate,
    pub cp_n_per_m: Estimate,
    pub cn_n_per_m: Estimate,
    pub bp_ns_per_m2: Estimate,
    pub bn_ns_per_m2: Estimate,
    pub insertion_friction: Option<AtSpeeds>,
    pub withdrawal_friction: Option<AtSpeeds>,
    pub dp_n_per_m: Estimate,
    pub dn_n_per_m: Estimate,
    pub relaxation: Estimate,
    pub let_go_before_contact_m: Option<Estimate>,
    pub dwell_relaxation: Option<DwellSummary>,
    pub layers: Vec<LayerSummary>,
    pub noise_n: Estimate,
    pub per_trial: Vec<TrialGeometry>,
    /// The files left out.
    pub skipped: Vec<Skipped>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub puncture_detection: Option<PunctureMargins>,
}
