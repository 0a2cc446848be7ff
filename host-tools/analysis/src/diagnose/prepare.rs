//! One trial made ready for diagnosis: the nominal model along it, the
//! residual, the phase of every sample (book, *Names*), and the
//! kinematic signals the candidate effects are built from.

use needle_holder::config::DeviceConfig;
use needle_holder::model::params::TissueParams;

use crate::fit::jumps::Jump;
use crate::fit::predict::{
    last_loaded_sample, predict_each, predict_parts_at, NeedleVelocity, Parts,
};
use crate::fit::tissue::CUTTING_PRIOR_N;
use crate::fit::{fit_trial_at, puncture_index_at, Falls, TrialFit};
use needle_io::trial::Trial;

/// Phases (book, *Names*): outside before contact, up to the
/// puncture, advancing before the first step back, at rest in tissue,
/// the strokes between the first step back and the last advance, the final
/// retreat, outside after it.
pub const PHASES: [&str; 7] = [
    "approach",
    "loading",
    "insertion",
    "dwell",
    "reversal",
    "withdrawal",
    "after",
];
pub const APPROACH: usize = 0;
pub const LOADING: usize = 1;
pub const INSERTION: usize = 2;
pub const DWELL: usize = 3;
const REVERSAL: usize = 4;
pub const WITHDRAWAL: usize = 5;
pub const AFTER: usize = 6;

/// Moving, for the phase split, m/s.
const MOVING_MPS: f64 = 0.0005;
/// Least time at rest that is a dwell, not the turning point of a stroke.
const DWELL_S: f64 = 0.1;

/// Fastest sample rate the diagnosis's searches run at: the capsule's
/// relaxation ρ, a moving tissue's displacement and a breathing's phase
/// are each found on every k-th sample of a faster trial, then the
/// candidates are scored on all of them. What they search for moves at
/// a few hertz at most (breathing 0.1–0.7 Hz, a relaxed surface that is
/// one number a trial), real rigs record at about 100 Hz, and each
/// search evaluates the model along the trial hundreds of times.
pub const SEARCH_RATE_HZ: f64 = 50.0;

/// A trial, its geometry and its velocity along every `step`-th sample
/// (the geometry's puncture index moved to the kept sample at or before it).
pub fn thinned(
    trial: &Trial,
    geometry: &TrialFit,
    velocity: &NeedleVelocity,
    step: usize,
) -> (Trial, TrialFit, NeedleVelocity) {
    (
        trial.thinned(step),
        TrialFit {
            puncture_index: geometry.puncture_index / step.max(1),
            fallen_index: geometry.fallen_index / step.max(1),
            ..geometry.clone()
        },
        velocity.thinned(step),
    )
}

/// A trial with its nominal model and signals.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub file: String,
    /// The nominal model's parameters (with the pooled relaxation).
    pub params: TissueParams,
    pub trial: Trial,
    pub geometry: TrialFit,
    pub nominal_n: Vec<f64>,
    /// The nominal with this trial's own corrections as the baseline
    /// fitted them ([`super::with_fitted`]): the force the tissue exerts
    /// as the nominal at its best has it, what relaxes. `nominal_n` until
    /// fitted.
    pub fitted_n: Vec<f64>,
    pub residual_n: Vec<f64>,
    /// Index into [`PHASES`], by the needle's motion in the tissue: what
    /// the nominal's terms follow.
    pub phase: Vec<usize>,
    /// The protocol's phase (index into [`PHASES`]) as the encoder has
    /// it, what the robot did: where the held-out error is tallied and
    /// shown. The same as `phase` but in the tissue's frame, where the
    /// needle held still in a moving tissue slides back and forth
    /// through it (the robot's dwell is `reversal` there, and each turn
    /// of the breath a short `dwell`): the effects of the tissue that
    /// act in the robot's dwell are judged where they act.
    pub protocol_phase: Vec<usize>,
    /// The needle's velocity (relative to the tissue where the trial is
    /// in the tissue's frame) and its jumps.
    pub velocity: NeedleVelocity,
    /// The samples next to a jump that may lie on its other side, and how
    /// likely they do ([`Parts::other_side`]).
    pub other_side: Vec<(usize, f64)>,
    pub a_mps2: Vec<f64>,
    /// The friction term's derivatives by (c_p, b_p, c_n, b_n).
    pub friction_basis: Vec<[f64; 4]>,
    /// Nominal friction term and needle length in tissue after puncture.
    pub friction_n: Vec<f64>,
    pub length_m: Vec<f64>,
    /// How much of the cutting force the nominal has on (0 to 1; between
    /// where it mixes both sides of a jump, or cannot yet tell in a moving
    /// tissue).
    pub cutting: Vec<f64>,
    /// Interior structures the device's detector found: (sample index,
    /// peak position, wall force = fall of the force there).
    pub structures: Vec<(usize, f64, f64)>,
    /// The withdrawal's stick (`diagnose::stick`): the samples from the
    /// needle's first step out (up to 10 ms before the withdrawal phase)
    /// to where the dragged tissue slipped with a snap, or where its grip
    /// gave way without one; empty if it never stuck.
    pub stick: std::ops::Range<usize>,
    /// The tip's unloading on its first retraction from the cutting
    /// front, 1 to 0 over the compliance chosen on the trial
    /// (the `tip` module); made once, with the rest of the trial.
    pub tip_unloading: Vec<f64>,
    /// The tip's load on every later return to the cutting front, 1 to 0
    /// over the compliance chosen on the trial (the `tip` module); made
    /// once, with the rest of the trial.
    pub tip_return: Vec<f64>,
    /// The layer beneath the capsule loaded again after the puncture: the
    /// force's shortfall below its steady course, as the trial reads it
    /// (the `reload` module); made once, with the rest of the trial.
    pub reload: Vec<f64>,
    /// The capsule's excess over the course as it tears, the nominal's
    /// column (the `tear` module); made once, with the reload (a trial's
    /// wall breaks or tears: one of the two is zero).
    pub tear: Vec<f64>,
    /// The first sample of the needle out of the tissue for good as the
    /// measured force has it (see `came_free` in this module); the trial's length if it
    /// does not say.
    pub came_free: usize,
    pub noise_n: f64,
    /// [`Self::for_search`]'s trial, made on first use: the searches ask
    /// for it once per grid value. Copied with the struct (a backfit's
    /// copies reuse it): a copy whose trial, geometry or parameters are
    /// then changed is to be prepared again, not edited.
    search: std::sync::OnceLock<Box<Prepared>>,
    /// [`Self::at_sudden_fall`]'s trial where it differs, made on first
    /// use; copied as `search` is.
    sudden: std::sync::OnceLock<Option<Box<Prepared>>>,
}

impl Prepared {
    /// How likely the nominal has sample `i` sliding: the side of a stop
    /// or start placed between samples its velocity puts it on, or the
    /// other ([`Self::other_side`]).
    pub fn sliding_odds(&self, i: usize) -> f64 {
        let v_mps = self.velocity.v_mps[i];
        odds_of_sliding(&self.other_side, v_mps, self.params.half_band_mps, i)
    }

    /// Take the protocol's phases of the same samples prepared before
    /// (`protocol_phase`): a trial moved into the tissue's frame and
    /// prepared again finds its phases from the motion in the tissue.
    pub fn keep_protocol_phase(&mut self, protocol_phase: &[usize]) {
        if protocol_phase.len() == self.trial.len() {
            self.protocol_phase = protocol_phase.to_vec();
        }
    }

    /// The samples of the trial's first dwell, if it has one.
    pub fn first_dwell(&self) -> Option<std::ops::Range<usize>> {
        let start = self.phase.iter().position(|&ph| ph == DWELL)?;
        let len = self.phase[start..]
            .iter()
            .take_while(|&&ph| ph == DWELL)
            .count();
        Some(start..start + len)
    }

    /// Replace the nominal model by another one sample for sample (the
    /// device's, from its residual stream).
    pub fn use_nominal(&mut self, model_n: Vec<f64>) -> anyhow::Result<()> {
        if model_n.len() != self.trial.len() {
            anyhow::bail!(
                "{} model values for {} samples",
                model_n.len(),
                self.trial.len()
            );
        }
        self.residual_n = (0..model_n.len())
            .map(|i| self.trial.f_n[i] - model_n[i])
            .collect();
        self.nominal_n = model_n;
        // The thinned copies hold the nominal they were made with.
        self.search = Default::default();
        self.sudden = Default::default();
        Ok(())
    }

    /// This trial as a rig at [`SEARCH_RATE_HZ`] or slower would have
    /// recorded it, prepared against the same nominal (itself when it is
    /// that slow already).
    pub fn for_search(&self) -> &Prepared {
        let step = self.trial.thinning_step(SEARCH_RATE_HZ);
        if step == 1 {
            return self;
        }
        self.search.get_or_init(|| {
            let (trial, geometry, velocity) =
                thinned(&self.trial, &self.geometry, &self.velocity, step);
            let mut p = prepare(self.file.clone(), trial, geometry, &self.params, velocity);
            p.fitted_n = needle_io::trial::every(&self.fitted_n, step);
            p.keep_protocol_phase(&needle_io::trial::every(&self.protocol_phase, step));
            Box::new(p)
        })
    }

    /// This trial prepared with its puncture at its first sudden fall
    /// ([`Falls::Sudden`]) where that is not where `needle fit` put it
    /// (itself where it is): a tissue that moves away faster than the
    /// needle advances sags the loading curve as a wall rolling over does,
    /// and the tissue's motion is looked for with the loading curve where
    /// it is in the tissue's frame.
    pub fn at_sudden_fall(&self) -> &Prepared {
        let sudden = self.sudden.get_or_init(|| {
            // Against the rule `needle fit` has on the same samples (a
            // backfit's geometry was found on its cleaned force).
            let sudden = puncture_index_at(&self.trial, Falls::Sudden);
            if sudden.is_none() || sudden == puncture_index_at(&self.trial, Falls::AnyFall) {
                return None;
            }
            let mut g = fit_trial_at(&self.trial, Falls::Sudden).ok()?;
            g.tare_n = self.geometry.tare_n;
            relaxed_surfaces(&mut [&mut g], self.params.relaxation);
            let (trial, v) = (self.trial.clone(), self.velocity.clone());
            let mut p = prepare(self.file.clone(), trial, g, &self.params, v);
            p.keep_protocol_phase(&self.protocol_phase);
            Some(Box::new(p))
        });
        sudden.as_deref().unwrap_or(self)
    }

    /// The needle cuts at sample `i`: advancing, with the nominal's
    /// cutting more than half on (at rest the nominal holds the tip's
    /// force, at one depth).
    pub fn cuts(&self, i: usize) -> bool {
        self.cutting[i] > 0.5 && self.velocity.v_mps[i] >= self.params.half_band_mps
    }

    /// The needle touches tissue at sample `i`: loading, or after the
    /// puncture until the measured force says it came free, or where it
    /// does not say, with some of its length in the tissue as the nominal
    /// has it (a withdrawing needle the tissue has let go of touches
    /// nothing, though the stage is still withdrawing).
    pub fn in_tissue(&self, i: usize) -> bool {
        let punctured = !matches!(self.phase[i], APPROACH | LOADING);
        let out = if self.came_free < self.trial.len() {
            i >= self.came_free
        } else {
            self.phase[i] == AFTER || self.length_m[i] <= 0.0
        };
        self.phase[i] == LOADING || (punctured && !out)
    }

    /// How likely `jump` shows on the sample before its own, its own, or
    /// the one after: the encoder's odds ([`Jump::landing`]), unless the
    /// measured force settled which side those samples lie on.
    pub fn landing(&self, jump: &Jump) -> [f64; 3] {
        let [mut early, _, mut late] = jump.landing(&self.trial.t_s);
        let v = &self.velocity.v_mps;
        // Whether the alternative velocity offered for sample `i` is the
        // jump's far side (it differs from the sample's own by the jump),
        // or its near side (by minus the jump: the encoder already read
        // the rest at the sample before the stop the lines place). By the
        // jump's size, not by equality: in the tissue's frame each
        // sample's velocity is less the tissue's at its own time.
        let offers_far_side = |i: usize| {
            self.velocity
                .uncertain
                .iter()
                .find(|u| u.0 == i)
                .is_none_or(|u| {
                    let d = u.1 - v[i];
                    (d - jump.dv_mps).abs() <= (d + jump.dv_mps).abs()
                })
        };
        for &(i, w) in &self.other_side {
            if i + 1 == jump.index {
                // On the far side as likely as its alternative is, if that
                // is the far side.
                early = if offers_far_side(i) { w } else { 1.0 - w };
            } else if i == jump.index {
                late = w;
            }
        }
        let on = (1.0 - early - late).max(0.0);
        let total = early + on + late;
        [early / total, on / total, late / total]
    }
}

/// How much of the cutting force the nominal has on at each sample (0 to
/// 1), from its cutting force `cutting_n`. A nominal fitted with no
/// cutting force still cuts: one speed and no oscillation confound
/// cutting with friction, `needle fit` takes no negative value, and a
/// share read off a force of zero would leave each trial's own cutting
/// level, and every candidate built on where the needle cuts, a column
/// of zeros. The share is then read from the model with the prior
/// cutting force ([`CUTTING_PRIOR_N`]).
fn cutting_share(
    params: &TissueParams,
    geometry: &TrialFit,
    trial: &Trial,
    velocity: &NeedleVelocity,
    cutting_n: &[f64],
) -> Vec<f64> {
    if params.cutting_force_n > 0.0 {
        return cutting_n
            .iter()
            .map(|c| c / params.cutting_force_n)
            .collect();
    }
    let with_prior = TissueParams {
        cutting_force_n: CUTTING_PRIOR_N,
        ..*params
    };
    predict_parts_at(&with_prior, geometry, trial, velocity.clone())
        .cutting_n
        .iter()
        .map(|c| c / CUTTING_PRIOR_N)
        .collect()
}

/// Prepare a trial against `params`, with its geometry as `needle fit`'s
/// code found it and its relaxed surface as [`relaxed_surfaces`] placed
/// it (`geometry.relaxed_x_m`), and the
/// needle's velocity ([`needle_velocity`](crate::fit::predict::needle_velocity) of the measured positions, less
/// the tissue's own where the trial is in the tissue's frame).
pub fn prepare(
    file: String,
    trial: Trial,
    geometry: TrialFit,
    params: &TissueParams,
    velocity: NeedleVelocity,
) -> Prepared {
    let parts = predict_parts_at(params, &geometry, &trial, velocity.clone());
    let n = trial.len();
    let mut nominal_n = parts.total_n();
    let phase = phases(&trial, &geometry, &parts, params.half_band_mps);
    // While the withdrawing needle drags the tissue along, the force is
    // the tent's (the stick's own corrections, per trial), not kinetic
    // friction.
    let stick = super::stick::stick(&trial, &phase, (&parts, params), &geometry);
    let mut parts = parts;
    for i in stick.clone() {
        nominal_n[i] = 0.0;
        parts.friction_n[i] = 0.0;
        parts.friction_basis[i] = [0.0; 4];
        parts.cutting_n[i] = 0.0;
    }
    let mut cutting = cutting_share(params, &geometry, &trial, &velocity, &parts.cutting_n);
    for i in stick.clone() {
        cutting[i] = 0.0;
    }
    let residual_n: Vec<f64> = (0..n).map(|i| trial.f_n[i] - nominal_n[i]).collect();
    let came_free = came_free(&trial, &geometry, &stick);
    let a_mps2 = acceleration(&trial);
    let structures = structures(&trial, params, &residual_n);
    let mut prepared = Prepared {
        stick,
        came_free,
        fitted_n: nominal_n.clone(),
        file,
        noise_n: geometry.noise_n,
        params: *params,
        geometry,
        nominal_n,
        residual_n,
        protocol_phase: phase.clone(),
        phase,
        velocity,
        other_side: parts.other_side,
        friction_basis: parts.friction_basis,
        a_mps2,
        friction_n: parts.friction_n,
        length_m: parts.length_m,
        cutting,
        structures,
        trial,
        tip_unloading: Vec::new(),
        tip_return: Vec::new(),
        reload: Vec::new(),
        tear: Vec::new(),
        search: Default::default(),
        sudden: Default::default(),
    };
    [prepared.tip_unloading, prepared.tip_return] = super::tip::columns(&prepared);
    let [reload, tear] = super::reload::after_the_fall(&prepared);
    prepared.reload = reload;
    prepared.tear = tear;
    prepared
}

/// ρ, the capsule's relaxation (x_s3 = x_s1 + ρ·(x_s2 − x_s1)), that
/// fits all trials best under `params`: the tissue's, from which
/// [`relaxed_surfaces`] moves each trial towards its own. `needle fit`
/// finds x_s3 per trial together with that trial's own friction
/// coefficients, which trade off against it where friction at rest is
/// near zero (0.8 mm off on some trials); per trial under the shared
/// coefficients an unmodelled effect bends it trial by trial to hide
/// itself. One ρ for the tissue, as the paper has it, is well determined
/// and hard for an effect to hide in.
pub fn fit_relaxation(
    trials: &[(&Trial, &TrialFit, &NeedleVelocity)],
    params: &TissueParams,
) -> f64 {
    let searched: Vec<_> = trials
        .iter()
        .map(|(t, g, v)| thinned(t, g, v, t.thinning_step(SEARCH_RATE_HZ)))
        .collect();
    let sse = |rho: f64| {
        searched
            .iter()
            .map(|(trial, geometry, v)| {
                let g = TrialFit {
                    relaxed_x_m: relaxed_surface(geometry, rho),
                    ..(*geometry).clone()
                };
                // Each sample's square capped at ten noise sd: a membrane's
                // or a wall's few newtons, which no ρ explains, must not
                // decide it. Samples at rest neither: what the static band
                // holds there (D_p·l) moves with ρ, but its level is each
                // trial's own (the diagnosis frees it per trial), and a
                // dwell's thousands of samples would set ρ by it. The
                // loading curve is the capsule's, which ρ does not move.
                let cap = (10.0 * geometry.noise_n).powi(2).max(f64::MIN_POSITIVE);
                let puncture = last_loaded_sample(&g, trial);
                let mut sse = 0.0;
                predict_each(params, &g, (trial, &trial.x_m), v, |i, s| {
                    if i > puncture && v.v_mps[i].abs() >= params.half_band_mps {
                        sse += (trial.f_n[i] - s.friction_n - s.cutting_n).powi(2).min(cap);
                    }
                });
                sse
            })
            .sum::<f64>()
    };
    let best_on = |from: f64, to: f64, steps: usize| {
        (0..=steps)
            .map(|k| from + (to - from) * k as f64 / steps as f64)
            .map(|rho| (rho, sse(rho)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(params.relaxation, |(rho, _)| rho)
    };
    // 0.05 apart, then 0.005 about the best (each step a prediction of
    // every trial: the grid is most of a backfit round's cost).
    let coarse = best_on(0.0, 1.0, 20);
    best_on((coarse - 0.05).max(0.0), (coarse + 0.05).min(1.0), 20)
}

/// Each trial's relaxed surface x_s3: the tissue's ρ (`shared`, from
/// [`fit_relaxation`]) moved towards the trial's own as far as the
/// trial's strokes place it better than the trials differ — a
/// random-effects estimate. Real tissue relaxes differently from one
/// insertion to the next (withdrawals let go 1.5–9 mm apart), and with
/// friction at rest far from zero each trial's own x_s3 shows at every
/// stroke; but an unmodelled effect moves a trial's own ρ too, and a
/// per-trial ρ taken at face value would hide it there. So: τ², the
/// spread of the trials' own ρ beyond what their standard errors explain
/// (`TrialFit::relaxation_sd`, wide where the friction law misses), is
/// var(ρ_own) − mean(sd²), none when the trials agree as well as their
/// errors allow or an effect moves them all alike; each trial's ρ is
/// shared + τ²/(τ² + sd²)·(ρ_own − shared): the trial's own where its
/// error is far below the spread, the tissue's where it is far above.
/// Trials without an error on their own ρ (`TrialFit::relaxation_sd`:
/// insert–dwell–withdraw's, withdrawn one way, and any whose friction law
/// misses its strokes) keep the shared one; with fewer than three that
/// have one, all do.
pub fn relaxed_surfaces(geometries: &mut [&mut TrialFit], shared: f64) {
    let own: Vec<(f64, f64)> = geometries
        .iter()
        .filter(|g| g.relaxation_identified)
        .filter_map(|g| Some((g.relaxation, g.relaxation_sd?)))
        .collect();
    let k = own.len();
    let tau2 = if k >= 3 {
        let mean = own.iter().map(|o| o.0).sum::<f64>() / k as f64;
        let var = own.iter().map(|o| (o.0 - mean).powi(2)).sum::<f64>() / (k - 1) as f64;
        let noise = own.iter().map(|o| o.1 * o.1).sum::<f64>() / k as f64;
        (var - noise).max(0.0)
    } else {
        0.0
    };
    for g in geometries.iter_mut() {
        let rho = match (g.relaxation_identified, g.relaxation_sd) {
            (true, Some(sd)) if tau2 > 0.0 => {
                shared + tau2 / (tau2 + sd * sd) * (g.relaxation - shared)
            }
            _ => shared,
        };
        g.relaxed_x_m = relaxed_surface(g, rho.clamp(0.0, 1.0));
    }
}

/// x_s3 for relaxation `rho`.
pub fn relaxed_surface(geometry: &TrialFit, rho: f64) -> f64 {
    geometry.contact_x_m + rho * (geometry.puncture_x_m - geometry.contact_x_m)
}

/// The phase of every sample (index into [`PHASES`]).
fn phases(trial: &Trial, geometry: &TrialFit, parts: &Parts, half_band_mps: f64) -> Vec<usize> {
    let n = trial.len();
    let v_mps = &parts.v_mps;
    let after_puncture = |i: &usize| *i > parts.puncture_index;
    let first_back = (0..n)
        .filter(after_puncture)
        .find(|&i| v_mps[i] < -MOVING_MPS)
        .unwrap_or(n);
    // A stroke easing to its turn still advances, however slowly: the
    // withdrawal starts once the needle no longer slides forward.
    let last_forward = (0..n)
        .rev()
        .find(|&i| v_mps[i] > half_band_mps)
        .unwrap_or(0);
    let left = (0..n)
        .filter(after_puncture)
        .find(|&i| parts.length_m[i] <= 0.0 && i > first_back)
        .unwrap_or(n);
    let min_rest = (DWELL_S * trial.rate_hz()) as usize;
    let mut phase = vec![APPROACH; n];
    let mut rest_run = 0;
    for i in 0..n {
        phase[i] = if i <= parts.puncture_index {
            if trial.x_m[i] >= geometry.contact_x_m {
                LOADING
            } else {
                APPROACH
            }
        } else if i >= left {
            AFTER
        } else if i < first_back {
            INSERTION
        } else if i > last_forward {
            WITHDRAWAL
        } else {
            REVERSAL
        };
        // A run at rest long enough is a dwell, from its start.
        rest_run = if v_mps[i].abs() < MOVING_MPS {
            rest_run + 1
        } else {
            0
        };
        if rest_run >= min_rest && !matches!(phase[i], APPROACH | LOADING | AFTER) {
            for p in &mut phase[i + 1 - rest_run.min(i + 1)..=i] {
                if !matches!(*p, APPROACH | LOADING | AFTER) {
                    *p = DWELL;
                }
            }
        }
    }
    phase
}

/// How likely a nominal whose velocity at sample `i` is `v_mps` has it
/// sliding, given the samples its encoder leaves open (`other_side`,
/// [`Parts::other_side`]).
pub fn odds_of_sliding(
    other_side: &[(usize, f64)],
    v_mps: f64,
    half_band_mps: f64,
    i: usize,
) -> f64 {
    let other = other_side
        .iter()
        .find(|&&(j, _)| j == i)
        .map_or(0.0, |&(_, w)| w);
    if v_mps.abs() < half_band_mps {
        other
    } else {
        1.0 - other
    }
}

/// Where the measured force says a withdrawing needle came out of the
/// tissue for good: after the trial's last sample pulling by ten noise sd
/// or more, the needle moving back and not the end of the withdrawal's
/// stick (a dragged tissue's slip onto a kinetic friction of a noise sd
/// or two looks the same), the next five all within three noise
/// sd of what the load cell reads with the needle free
/// ([`crate::fit::trial::free_level_n`]). A pull that only friction makes
/// fades with the length in the tissue and has no such snap; one that a
/// relaxing branch carries ends where the needle leaves, which need not
/// be where the nominal's relaxed surface puts it (the paper's protocol
/// places that surface only by the friction fading to nothing). The
/// trial's length where there is no snap.
fn came_free(trial: &Trial, geometry: &TrialFit, stick: &std::ops::Range<usize>) -> usize {
    let n = trial.len();
    let free_n = crate::fit::trial::free_level_n(trial, geometry.contact_x_m);
    let noise_n = geometry.noise_n.max(1e-4);
    let Some(last_pull) = trial.f_n.iter().rposition(|&f| f < free_n - 10.0 * noise_n) else {
        return n;
    };
    let after = last_pull + 1..last_pull + 6;
    let quiet = after.end <= n
        && trial.f_n[after.clone()]
            .iter()
            .all(|&f| (f - free_n).abs() <= 3.0 * noise_n);
    let withdrawing = last_pull > 0 && trial.x_m[last_pull] < trial.x_m[last_pull - 1];
    let slip = !stick.is_empty() && (stick.start..=stick.end).contains(&last_pull);
    if quiet && withdrawing && !slip {
        after.start
    } else {
        n
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

/// Structure events of the device's own detector: (last sample the wall
/// held, its position, the wall force). The detector reports the peak of
/// the noisy top of the wall's rise, which can be samples before the wall
/// gave way (its rise is about a noise step per sample); the wall gave way
/// at the largest one-sample fall of the residual from there to where the
/// detector confirmed it. The wall force is that fall, measured between
/// the means of five samples either side, the earlier mean moved up the
/// wall's slope to the last sample.
fn structures(trial: &Trial, params: &TissueParams, residual: &[f64]) -> Vec<(usize, f64, f64)> {
    const SIDE: usize = 5;
    let Ok(config) = DeviceConfig::for_tissue(params) else {
        return Vec::new();
    };
    let n = residual.len();
    let found = crate::detect::detect_trial(trial, &config);
    found
        .events
        .iter()
        .filter(|e| e.kind == "structure")
        .filter_map(|e| {
            let at = trial.t_s.iter().position(|&t| t >= e.t_s)?;
            let peak = trial.x_m[..at].iter().rposition(|&x| x <= e.x_m)?;
            // Two windows of SIDE samples before it, one after.
            let last = (peak.saturating_sub(3).max(2 * SIDE)..at.min(n.saturating_sub(SIDE + 1)))
                .max_by(|&a, &b| {
                (residual[a] - residual[a + 1]).total_cmp(&(residual[b] - residual[b + 1]))
            })?;
            let mean = |from: usize, to: usize| {
                residual[from..to].iter().sum::<f64>() / (to - from) as f64
            };
            let before = mean(last + 1 - SIDE, last + 1);
            let slope = (before - mean(last + 1 - 2 * SIDE, last + 1 - SIDE)) / SIDE as f64;
            let held = before + slope.max(0.0) * (SIDE - 1) as f64 / 2.0;
            let wall_n = held - mean(last + 1, last + 1 + SIDE);
            Some((last, trial.x_m[last], wall_n.max(0.0)))
        })
        .collect()
}
