//! What `needle diagnose` finds, as types; `--json` is their
//! serialisation (the keys of the book's *Sim-to-real gap diagnosis*).

use std::collections::BTreeMap;

use needle_io::trial::Skipped;
use serde::Serialize;

/// The whole diagnosis of a dataset.
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    pub trials: usize,
    /// What was taken off each trial's force before it was diagnosed, N,
    /// by file: its tare, the median force in air before the loading
    /// rise (0 with `--device-model`, whose force is the device's own).
    pub tare_n: BTreeMap<String, f64>,
    /// The sensor's noise, the trials' mean (N).
    pub noise_floor_n: f64,
    /// The held-out RMS at or under which what is left counts as
    /// explained (N): [`super::EXPLAINED_FACTOR`] noise floors or
    /// [`super::MODEL_TOLERANCE`] of the trials' mean puncture force, the
    /// larger.
    pub explained_below_n: f64,
    /// The nominal with its corrections, each trial's spread its own.
    pub baseline: Baseline,
    /// Where the nominal's residual lies: phase × 5 mm of position,
    /// largest share first (ten at most).
    #[serde(rename = "where")]
    pub where_residual: Vec<Place>,
    pub residual_tests: ResidualTests,
    /// Every candidate, most held-out shrink first.
    pub candidates: Vec<CandidateScore>,
    pub verdict: Verdict,
    /// The files left out and why (`needle diagnose` fills it in; the
    /// library's caller has its own list).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skipped: Option<Vec<Skipped>>,
}

/// RMS and share of the squared residual, by phase name (phases with
/// samples only).
pub type ByPhase = BTreeMap<&'static str, PhaseShare>;

#[derive(Clone, Copy, Debug, Serialize)]
pub struct PhaseShare {
    pub rms_n: f64,
    /// Share of the squared residual over all phases.
    pub share: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Baseline {
    pub heldout_rms_n: f64,
    /// The nominal corrections fitted on all trials (the shared ones; a
    /// spread correction's value here is fitted as if shared).
    pub corrections: BTreeMap<&'static str, f64>,
    pub by_phase: ByPhase,
    /// Held-out RMS of each trial, by file (N).
    pub by_trial: ByTrial,
}

/// Held-out RMS of each trial, by file (N): which insertions the model
/// misses, where one trial's misfit (a membrane the detector did not
/// find, a bad recording) would otherwise hide in the pooled RMS.
pub type ByTrial = BTreeMap<String, f64>;

/// A stretch of the residual: a phase and 5 mm of position.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Place {
    pub phase: &'static str,
    pub share: f64,
    pub x_from_m: f64,
    pub x_to_m: f64,
}

/// Whiteness of the residual in tissue and its correlation with the
/// signals an unmodelled effect would follow.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ResidualTests {
    pub lag1_autocorrelation: f64,
    /// 2/√n: a white residual's lag-1 autocorrelation lies within it.
    pub white_bound: f64,
    pub corr_velocity: f64,
    pub corr_acceleration: f64,
    pub corr_depth: f64,
    pub corr_time: f64,
}

/// One candidate effect, scored on withheld trials beside the baseline.
#[derive(Clone, Debug, Serialize)]
pub struct CandidateScore {
    pub effect: &'static str,
    /// The grid value chosen on all trials.
    pub grid_value: f64,
    pub heldout_rms_n: f64,
    /// 1 − held-out RMS / the baseline's.
    pub shrink: f64,
    /// Paired t of per-trial log ratios of held-out mean squares.
    pub paired_t: f64,
    pub significant: bool,
    pub by_phase: ByPhase,
    /// The grid's named values and the candidate's linear parameters.
    pub params: BTreeMap<&'static str, f64>,
}

/// What the diagnosis concludes.
#[derive(Clone, Debug, Serialize)]
pub struct Verdict {
    /// The first effect of the waterfall, `none` or `unexplained`.
    pub effect: &'static str,
    /// Of the held-out RMS, after every named effect (backfitted).
    pub shrink: f64,
    /// The waterfall's second effect, or `none`.
    pub second: &'static str,
    /// The waterfall: each named effect in turn.
    pub effects: Vec<Step>,
    pub heldout_rms_after_n: f64,
    /// What is left is within [`Diagnosis::explained_below_n`].
    pub explained: bool,
    /// The effects the waterfall took, named or (when they leave the gap
    /// mostly open) only the closest.
    pub closest: Vec<&'static str>,
    /// Where what is left lies.
    pub left_by_phase: ByPhase,
    /// What is left of each trial, held out, by file (N).
    pub left_by_trial: ByTrial,
}

/// One step of the waterfall.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Step {
    pub effect: &'static str,
    pub heldout_rms_after_n: f64,
    /// Its part of the gap, in mean squares above the noise floor.
    pub share_of_gap: f64,
    /// How the effect was fitted: `shared` (a law whose parameters the
    /// trials share, judged on withheld ones) or `along_depth_in_each_trial`
    /// (cutting free along each trial's own path, `depth_dependent_cutting`
    /// only: a heterogeneous tissue). The latter's held-out RMS is each
    /// withheld trial's cutting samples predicted from its own others
    /// nearby in depth (leave-one-out), as its spread is fitted on it;
    /// it is judged against the baseline alone, is then the only step,
    /// and `candidates` still lists the shared law's own score.
    pub law: &'static str,
    /// Along depth in each trial: the half-width of the depth window
    /// each cutting sample's profile is the mean over, m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub half_window_m: Option<f64>,
}

impl Step {
    /// The effect's name as a reader is shown it, with its law if it is
    /// not a shared one.
    pub fn label(&self) -> String {
        match self.half_window_m {
            Some(_) => format!("{} (along depth, each trial its own)", self.effect),
            None => self.effect.to_owned(),
        }
    }
}
