//! The model's force along a measured trial, given the trial's geometry
//! (contact, puncture, relaxed surface): what `fit --plot` overlays and
//! what the sim-to-real diagnosis subtracts.

use needle_holder::model::params::TissueParams;

use super::cutting::{CuttingObserver, Odds};
use super::drag::withdrawing_length_m;
use super::jumps;
use super::trial::TrialFit;
use needle_io::trial::Trial;

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
    /// The last sample on the loading curve.
    pub puncture_index: usize,
    /// The needle's velocity the force law was evaluated at, m/s.
    pub v_mps: Vec<f64>,
    /// The samples whose velocity the encoder leaves open (beside a jump,
    /// at a rest's edge, at a turn), with how likely each moved at its
    /// alternative velocity (`NeedleVelocity::uncertain`) rather than its
    /// own: the encoder's odds, weighed by the measured force where
    /// [`NeedleVelocity::force_sd_n`] says how well it is known.
    pub other_side: Vec<(usize, f64)>,
    /// How the friction term changes with (c_p, b_p, c_n, b_n): the
    /// sliding sample's (l, v·l) on its side, held through a rest unless
    /// the static band clamps it. The friction is linear in these four.
    pub friction_basis: Vec<[f64; 4]>,
}

impl Parts {
    /// The model's whole force at every sample.
    pub fn total_n(&self) -> Vec<f64> {
        (0..self.stiffness_n.len())
            .map(|i| self.stiffness_n[i] + self.friction_n[i] + self.cutting_n[i])
            .collect()
    }
}

/// The model at one sample: its force by term (each 0 where it does not
/// act), as [`Parts`] holds them along a trial.
#[derive(Clone, Copy, Debug, Default)]
pub struct SampleParts {
    /// See [`Parts::stiffness_n`].
    pub stiffness_n: f64,
    /// See [`Parts::friction_n`].
    pub friction_n: f64,
    /// See [`Parts::cutting_n`].
    pub cutting_n: f64,
    /// See [`Parts::length_m`].
    pub length_m: f64,
    /// See [`Parts::friction_basis`].
    pub friction_basis: [f64; 4],
    /// How likely the sample moved at its alternative velocity, where it
    /// has one ([`Parts::other_side`]).
    pub other_side: Option<f64>,
}

impl SampleParts {
    /// The model's whole force.
    pub fn total_n(&self) -> f64 {
        self.stiffness_n + self.friction_n + self.cutting_n
    }
}

/// The expected force at every sample of `trial` under `params`, term by
/// term, with the surface positions found by the fit, at a needle
/// velocity already known (from [`needle_velocity`], with the load cell's
/// noise where the force is to settle what the encoder cannot): the
/// velocity is most of the cost, and a caller evaluating one trial under
/// many parameters needs it once.
pub fn predict_parts_at(
    params: &TissueParams,
    geometry: &TrialFit,
    trial: &Trial,
    v: NeedleVelocity,
) -> Parts {
    let n = trial.len();
    let mut p = Parts {
        stiffness_n: vec![0.0; n],
        friction_n: vec![0.0; n],
        cutting_n: vec![0.0; n],
        length_m: vec![0.0; n],
        friction_basis: vec![[0.0; 4]; n],
        ..Parts::default()
    };
    let puncture = predict_each(params, geometry, (trial, &trial.x_m), &v, |i, s| {
        p.stiffness_n[i] = s.stiffness_n;
        p.friction_n[i] = s.friction_n;
        p.cutting_n[i] = s.cutting_n;
        p.length_m[i] = s.length_m;
        p.friction_basis[i] = s.friction_basis;
        if let Some(w) = s.other_side {
            p.other_side.push((i, w));
        }
    });
    p.puncture_index = puncture;
    p.v_mps = v.v_mps;
    p
}

/// [`predict_parts_at`]'s whole force alone, with the needle at `x_m`
/// (see [`predict_each`]): what a search that evaluates the model along a
/// trial thousands of times needs, without the terms' arrays.
pub fn predict_total_at(
    params: &TissueParams,
    geometry: &TrialFit,
    (trial, x_m): (&Trial, &[f64]),
    v: &NeedleVelocity,
) -> Vec<f64> {
    let mut total = vec![0.0; trial.len()];
    predict_each(params, geometry, (trial, x_m), v, |i, s| {
        total[i] = s.total_n()
    });
    total
}

/// The model along `trial` with the needle at `x_m` (the trial's own
/// positions, or the same in a moving tissue's frame), handed to `each`
/// sample by sample in order (every sample, zeros where no term acts);
/// returns the last sample on the loading curve.
pub fn predict_each(
    params: &TissueParams,
    geometry: &TrialFit,
    (trial, x_m): (&Trial, &[f64]),
    v: &NeedleVelocity,
    mut each: impl FnMut(usize, &SampleParts),
) -> usize {
    let puncture = last_loaded_sample(geometry, trial);
    debug_assert_eq!(x_m.len(), trial.len(), "a position for every sample");
    let inside = || Inside::at_puncture(params, geometry, v, trial.t_s.get(puncture).copied());
    if v.force_sd_n <= 0.0 || v.uncertain.is_empty() {
        pass(inside(), (trial, x_m), puncture, each);
        return puncture;
    }
    // Where the measured force fits neither side's level of a jump, the
    // levels are moved to the trial's own, which the first pass shows.
    let mut first = Vec::with_capacity(trial.len());
    let seen = pass(inside(), (trial, x_m), puncture, |_, s| first.push(*s));
    let shifts = if seen.contested.is_empty() {
        Vec::new()
    } else {
        let total: Vec<f64> = first.iter().map(SampleParts::total_n).collect();
        let uncertain = (&seen.uncertain[..], &seen.contested[..]);
        level_shifts(trial, v, &total, puncture, uncertain)
    };
    if shifts.iter().all(Option::is_none) {
        for (i, s) in first.iter().enumerate() {
            each(i, s);
        }
    } else {
        let mut model = inside();
        model.shifts = shifts;
        pass(model, (trial, x_m), puncture, each);
    }
    puncture
}

/// One pass of the model along the trial, the loading curve up to
/// `puncture` and `model` past it.
fn pass<'a>(
    mut model: Inside<'a>,
    (trial, x_m): (&Trial, &[f64]),
    puncture: usize,
    mut each: impl FnMut(usize, &SampleParts),
) -> Inside<'a> {
    for (i, &x) in x_m.iter().enumerate().take(trial.len()) {
        let s = if i <= puncture {
            loading(model.params, model.geometry, x)
        } else {
            model.step(i, x, (trial.t_s[i], trial.f_n[i]))
        };
        each(i, &s);
    }
    model
}

/// How far the trial's own force stands from the model's on either side
/// of each uncertain sample (`sorted` by sample, as `Inside` meets them):
/// [this side, the other side], for the `contested` samples (whose force
/// fit neither side's level) where the difference is significant on
/// either side, else `None`. A trial's tissue is its own: its held force or cutting differs
/// from the nominal's by its spread (30 % of the cutting in the paper's
/// liver), by as much as the step between the two sides. Judged by the
/// nominal's own levels, a stop whose held force the nominal puts low
/// reads as still cutting. The model's miss at the nearest sure samples
/// either side (up to [`SURE_SAMPLES`] of them, past the puncture, within
/// two velocity windows and those samples: a rest's edge leaves a run of
/// up to two windows of uncertain samples) moves each side's level by the
/// trial's own, the model carrying the force's trend between them.
fn level_shifts(
    trial: &Trial,
    v: &NeedleVelocity,
    total_n: &[f64],
    puncture: usize,
    (sorted, contested): (&[(usize, f64, f64)], &[usize]),
) -> Vec<Option<[f64; 2]>> {
    let uncertain = |k: usize| sorted.binary_search_by_key(&k, |u| u.0).is_ok();
    let n = trial.len().min(total_n.len());
    let reach = 2 * window_samples(trial.rate_hz()) + SURE_SAMPLES;
    // The mean miss at the nearest sure samples, how many, and the
    // nearest.
    let miss = |ks: &mut dyn Iterator<Item = usize>| -> Option<(f64, usize, usize)> {
        let ks: Vec<usize> = ks
            .filter(|&k| k > puncture && k < n && !uncertain(k))
            .take(SURE_SAMPLES)
            .collect();
        let m = ks.len();
        (m > 0).then(|| {
            let sum: f64 = ks.iter().map(|&k| trial.f_n[k] - total_n[k]).sum();
            (sum / m as f64, m, ks[0])
        })
    };
    sorted
        .iter()
        .map(|&(i, v_other, _)| {
            // Met in sample order, so sorted.
            contested.binary_search(&i).ok()?;
            let (before, m_b, k_b) = miss(&mut (i.saturating_sub(reach)..i).rev())?;
            let (after, m_a, _) = miss(&mut (i + 1..=i + reach))?;
            let bar = |m: usize| 3.0 * v.force_sd_n / (m as f64).sqrt();
            if before.abs() < bar(m_b) && after.abs() < bar(m_a) {
                return None;
            }
            // This side is the one whose velocity the sure sample before
            // shares (the samples between may be uncertain themselves).
            let vb = v.v_mps[k_b];
            let here_before = (v.v_mps[i] - vb).abs() <= (v_other - vb).abs();
            Some(if here_before {
                [before, after]
            } else {
                [after, before]
            })
        })
        .collect()
}

/// How many noise sd from a side's level the force at an uncertain
/// sample may stand and still fit it: past this on both sides, the
/// trial's own levels are looked up ([`level_shifts`]).
const FITS_LEVEL_SD: f64 = 4.0;

/// How many sure samples either side are averaged: a few, so that their
/// noise adds little to the sample's own, and near enough that the
/// model's trend carries them to it.
const SURE_SAMPLES: usize = 3;

/// The capsule's force with the tip at `x_m`, up to the puncture.
fn loading(params: &TissueParams, geometry: &TrialFit, x_m: f64) -> SampleParts {
    // A rational law fitted to a bent loading curve can reach its pole;
    // the capsule holds no more than its puncture force.
    let f = params.stiffness_n(x_m - geometry.contact_x_m);
    SampleParts {
        stiffness_n: if f.is_finite() {
            f
        } else {
            params.puncture_force_n
        },
        ..SampleParts::default()
    }
}

/// The model past the puncture, a sample at a time: what the force law
/// remembers from one sample to the next (the friction's last sliding
/// side, where the tip has cut to, whether it cuts, what it holds at
/// rest).
struct Inside<'a> {
    params: &'a TissueParams,
    geometry: &'a TrialFit,
    v: &'a NeedleVelocity,
    /// How far past the deepest point the tip must be to cut again: the
    /// encoder's jitter (see [`Inside::at_puncture`]).
    front_m: f64,
    /// The cutting state is followed from the force ([`CuttingObserver`]).
    observed: bool,
    observer: CuttingObserver,
    deepest_m: f64,
    last_sliding: f64,
    last_basis: [f64; 4],
    held_cut_n: f64,
    cutting: bool,
    /// The samples next to a jump, in order, met by a cursor (a search of
    /// the whole list at every sample was a tenth of the model's time).
    uncertain: Vec<(usize, f64, f64)>,
    next_uncertain: usize,
    /// The trial's own levels either side of each uncertain sample, as
    /// shifts of the model's ([`level_shifts`]); empty for none.
    shifts: Vec<Option<[f64; 2]>>,
    /// The uncertain samples whose force fit neither side's level.
    contested: Vec<usize>,
}

impl<'a> Inside<'a> {
    /// The tip just through the capsule at `t_s`.
    ///
    /// Cutting goes on from the puncture, and again only once the tip is
    /// past its deepest point by more than the encoder's jitter: a stroke
    /// that turns round exactly at the deepest point (the paper's
    /// oscillations) cuts nothing, though its encoder reading ties it. By
    /// the same jitter it stays on: in a moving tissue the tip can advance
    /// by less than an encoder step a sample, and its reading, relative to
    /// the tissue, then dithers about the deepest point. In a moving
    /// tissue, with the force's noise known, the cutting state is followed
    /// from the force.
    fn at_puncture(
        params: &'a TissueParams,
        geometry: &'a TrialFit,
        v: &'a NeedleVelocity,
        t_s: Option<f64>,
    ) -> Self {
        let mut uncertain = v.uncertain.clone();
        uncertain.sort_by_key(|u| u.0);
        Self {
            params,
            geometry,
            v,
            front_m: 3.0 * v.encoder_step_m,
            observed: v.sd_mps > 0.0 && v.tissue_sd_m > 0.0 && v.force_sd_n > 0.0,
            observer: CuttingObserver::at_puncture(t_s.unwrap_or(0.0)),
            deepest_m: geometry.puncture_x_m,
            last_sliding: 0.0,
            last_basis: [0.0; 4],
            held_cut_n: 0.0,
            cutting: true,
            uncertain,
            next_uncertain: 0,
            shifts: Vec::new(),
            contested: Vec::new(),
        }
    }

    /// Sample `i`, the tip at `x_m`, at time `t_s` with `f_n` measured.
    fn step(&mut self, i: usize, x_m: f64, (t_s, f_n): (f64, f64)) -> SampleParts {
        let (params, v) = (self.params, self.v);
        let mut s = SampleParts::default();
        // A withdrawing needle holds the tissue until it lets go, which a
        // dragged tissue does before x_s3 (even before x_s1).
        let retreating = self.geometry.retreat_t_s.is_none_or(|from_s| t_s >= from_s);
        let l = match (self.geometry.let_go_x_m, self.geometry.drag) {
            (Some(let_go), drag) if v.v_mps[i] < -params.half_band_mps && retreating => {
                withdrawing_length_m(x_m, let_go.min(self.geometry.relaxed_x_m), drag)
            }
            _ => x_m - self.geometry.relaxed_x_m,
        };
        if l <= 0.0 {
            return s;
        }
        let at = Here {
            x_m,
            l_m: l,
            past_sd_m: (self.observer).past_sd_m(t_s, self.front_m, v.sd_mps, v.tissue_sd_m),
        };
        let at_rest = v.v_mps[i].abs() < params.half_band_mps;
        if at_rest {
            self.eased_to_rest(i, l);
        }
        let here = Sliding::at(params, v.v_mps[i], l, self.last_sliding, self.last_basis);
        let cutting_n = self.tip_n(&at, v.v_mps[i], here.friction_n);
        (s.friction_n, s.friction_basis, s.cutting_n) = (here.friction_n, here.basis, cutting_n);
        self.other_side(i, &at, f_n, &here, &mut s);
        let on = self.cuts(i, &at, at_rest, f_n, &s);
        (self.last_basis, self.last_sliding, self.cutting) = (here.basis, here.last_sliding, on);
        if !at_rest {
            self.held_cut_n = s.cutting_n;
        }
        s.length_m = l;
        // The front follows the tip while it cuts and while it is not
        // advancing (a stop at speed lands between samples, and the rest
        // reading is the true deepest point), but not while it creeps
        // forward uncut by less than the jitter a sample: it would never
        // get past the front (a tissue moving along with the needle).
        if (on || v.v_mps[i] <= 0.0) && x_m > self.deepest_m {
            self.deepest_m = x_m;
            self.observer.advanced(t_s);
        }
        s
    }

    /// A stage easing to rest passes into the static band between two
    /// samples, its speed by then the band's edge: the sliding force the
    /// tissue holds is the law's there (its Coulomb part), not the
    /// law's at the last sample's velocity, which a window reads
    /// millimetres a second above it (0.2–0.4 N of a skin's damping). A
    /// stop at speed — a jump in the velocity at this sample — holds the
    /// force it slid with.
    fn eased_to_rest(&mut self, i: usize, l_m: f64) {
        let (params, v) = (self.params, self.v);
        let Some(&before_mps) = i.checked_sub(1).and_then(|b| v.v_mps.get(b)) else {
            return;
        };
        if before_mps.abs() < params.half_band_mps || beside_jump(&v.jumps, i) {
            return;
        }
        let edge_mps = params.half_band_mps.copysign(before_mps);
        let edge = Sliding::at(params, edge_mps, l_m, self.last_sliding, self.last_basis);
        (self.last_sliding, self.last_basis) = (edge.last_sliding, edge.basis);
    }

    fn odds(&self, at: &Here, v_mps: f64) -> Odds {
        Odds {
            v_over_band_mps: v_mps - self.params.half_band_mps,
            v_sd_mps: self.v.sd_mps,
            past_m: at.x_m - self.deepest_m,
            past_sd_m: at.past_sd_m,
        }
    }

    /// Whether the tip is ahead of where it has cut to (by the jitter,
    /// the way that keeps the state `on` it is in).
    fn ahead(&self, at: &Here, on: bool) -> bool {
        if on {
            at.x_m >= self.deepest_m - self.front_m
        } else {
            at.x_m > self.deepest_m + self.front_m
        }
    }

    /// The cutting force at velocity `v_mps`, the tip cutting (`on`) or
    /// not at the sample before.
    fn cut_n(&self, at: &Here, v_mps: f64, on: bool) -> f64 {
        let params = self.params;
        if self.observed {
            params.cutting_force_n * self.observer.predict(self.odds(at, v_mps))
        } else if self.v.sd_mps > 0.0 && self.ahead(at, on) {
            // Known only to sd_mps, the velocity cuts as likely as it is
            // above the band: a tissue moving along with the needle holds
            // it near there for many samples.
            let above = jumps::normal_cdf((v_mps - params.half_band_mps) / self.v.sd_mps);
            params.cutting_force_n * above
        } else {
            params.cutting_n(v_mps, self.ahead(at, on))
        }
    }

    /// The tip's force. At rest the static band holds the force the
    /// needle was applied with when it stopped, the tip's cutting force
    /// with the shaft's friction (the paper's Karnopp law,
    /// max(D_n, min(F_a, D_p)) of the applied force F_a): the tissue ahead
    /// of a stopped tip stays compressed. Each part is held in its own
    /// term.
    fn tip_n(&self, at: &Here, v_mps: f64, friction_n: f64) -> f64 {
        let params = self.params;
        if v_mps.abs() < params.half_band_mps {
            self.held_cut_n
                .min((params.dp_n_per_m * at.l_m - friction_n).max(0.0))
        } else {
            self.cut_n(at, v_mps, self.cutting)
        }
    }

    /// Next to a jump placed to within a fraction of a sample, the sample
    /// may be on its other side: the force law there is the expected one
    /// over both.
    fn other_side(&mut self, i: usize, at: &Here, f_n: f64, here: &Sliding, s: &mut SampleParts) {
        while self
            .uncertain
            .get(self.next_uncertain)
            .is_some_and(|u| u.0 < i)
        {
            self.next_uncertain += 1;
        }
        let Some(&(_, v_other, prior)) =
            self.uncertain.get(self.next_uncertain).filter(|u| u.0 == i)
        else {
            return;
        };
        let other = Sliding::at(
            self.params,
            v_other,
            at.l_m,
            self.last_sliding,
            self.last_basis,
        );
        let other_cutting_n = self.tip_n(at, v_other, other.friction_n);
        let mut model_n = [
            here.friction_n + s.cutting_n,
            other.friction_n + other_cutting_n,
        ];
        let mut sd_n = self.v.force_sd_n;
        if let Some(Some(shift)) = self.shifts.get(self.next_uncertain) {
            model_n[0] += shift[0];
            model_n[1] += shift[1];
            // Each level now carries the mean noise of its sure samples.
            sd_n *= (1.0 + 1.0 / SURE_SAMPLES as f64).sqrt();
        }
        let fits = |m: f64| (f_n - m).abs() <= FITS_LEVEL_SD * sd_n;
        if !fits(model_n[0]) && !fits(model_n[1]) {
            self.contested.push(i);
        }
        let w = other_side_odds(prior, f_n, model_n, sd_n);
        let mix = |a: f64, b: f64| (1.0 - w) * a + w * b;
        s.friction_n = mix(here.friction_n, other.friction_n);
        for (k, b) in s.friction_basis.iter_mut().enumerate() {
            *b = mix(*b, other.basis[k]);
        }
        s.cutting_n = mix(s.cutting_n, other_cutting_n);
        s.other_side = Some(w);
    }

    /// Whether the tip cuts at this sample, for the next.
    fn cuts(&mut self, i: usize, at: &Here, at_rest: bool, f_n: f64, s: &SampleParts) -> bool {
        let (params, v) = (self.params, self.v);
        if !self.observed {
            return self.ahead(at, self.cutting) && v.v_mps[i] >= params.half_band_mps;
        }
        // What the tip holds at rest is not cutting.
        let (moving_n, held_n) = if at_rest {
            (self.cut_n(at, v.v_mps[i], self.cutting), s.cutting_n)
        } else {
            (s.cutting_n, 0.0)
        };
        let predicted = moving_n / params.cutting_force_n.max(f64::MIN_POSITIVE);
        let odds = self.odds(at, v.v_mps[i]);
        self.observer.correct(
            odds,
            predicted,
            f_n - held_n,
            [s.friction_n, s.friction_n + params.cutting_force_n],
            v.force_sd_n,
        )
    }
}

/// Where the tip is at one sample: its position, the length in tissue,
/// and how uncertain its distance past the deepest point is.
struct Here {
    x_m: f64,
    l_m: f64,
    past_sd_m: f64,
}

/// How likely a sample next to a jump lies on its other side, given the
/// encoder's `prior` odds and the measured force `f_n` against the force
/// law on this side and the other (`model_n`). The encoder places a stop
/// at 3 mm/s to a third of a 2 ms sample; the load cell shows the whole
/// cutting force come or go on the very sample, a step of hundreds of
/// noise floors. Gaussian noise of `sd_n`; 0 keeps the prior.
pub(super) fn other_side_odds(prior: f64, f_n: f64, model_n: [f64; 2], sd_n: f64) -> f64 {
    if sd_n <= 0.0 {
        return prior;
    }
    // Log-likelihood ratio other : here, clamped so the odds stay finite.
    let z = |m: f64| (f_n - m) / sd_n;
    let llr = (0.5 * (z(model_n[0]).powi(2) - z(model_n[1]).powi(2))).clamp(-50.0, 50.0);
    let odds = prior / (1.0 - prior).max(1e-12) * llr.exp();
    odds / (1.0 + odds)
}

/// The friction law at one sample: its force, its derivatives by (c_p,
/// b_p, c_n, b_n), and the sliding force it holds through a rest.
struct Sliding {
    friction_n: f64,
    basis: [f64; 4],
    last_sliding: f64,
}

impl Sliding {
    fn at(params: &TissueParams, v: f64, l: f64, last_sliding: f64, last_basis: [f64; 4]) -> Self {
        let (friction_n, last) = params.friction_n(v, l, last_sliding);
        let basis = if v >= params.half_band_mps {
            [l, v * l, 0.0, 0.0]
        } else if v <= -params.half_band_mps {
            [0.0, 0.0, l, v * l]
        } else if friction_n == last_sliding {
            last_basis
        } else {
            [0.0; 4]
        };
        Self {
            friction_n,
            basis,
            last_sliding: last,
        }
    }
}

/// The last sample still on the loading curve. The fit's puncture index
/// is the peak of a noisy, nearly flat top, often a few samples before the
/// capsule gives way; modelling those samples as inserted would put the
/// whole drop (over 1 N) into the residual.
pub fn last_loaded_sample(geometry: &TrialFit, trial: &Trial) -> usize {
    let mid = 0.5 * (geometry.puncture_force_n + geometry.puncture_drop_to_n);
    let mut i = geometry.puncture_index;
    while i + 1 < trial.len() && trial.f_n[i + 1] > mid {
        i += 1;
    }
    i
}

/// The needle's velocity at each sample, as the force law needs it.
///
/// A stop, start or turn at speed falls between two samples, and the
/// force law steps there (the whole cutting force, the friction from one
/// side to the other): a window across it calls the samples next to it
/// half-moving, over a newton of residual each. So the jumps are found
/// first ([`jumps::velocity_steps`], placed to the sample by where the
/// motions either side meet), and each sample's velocity is a central
/// difference over up to 10 ms either side (three samples at least:
/// [`window_samples`]) that stays between them (read at the
/// sample's own time where the clock is uneven and the window bends:
/// `centred_mps`), one-sided on the sample next to a jump.
pub fn needle_velocity(trial: &Trial) -> NeedleVelocity {
    let n = trial.len();
    if n < 2 {
        return NeedleVelocity {
            v_mps: vec![0.0; n],
            encoder_step_m: encoder_step_m(trial),
            ..NeedleVelocity::default()
        };
    }
    let (t, x) = (&trial.t_s, &trial.x_m);
    let dt = 1.0 / trial.rate_hz();
    let k = window_samples(trial.rate_hz());
    // Five encoder steps over a 10 ms window: above the two steps
    // quantisation can make of a smooth motion's contrast, and below the
    // stop of a 1 mm/s insertion read to 1 µm (ten steps, 1 mm/s, missed
    // it at 500 Hz and above: the model cut on into the dwell and held
    // the friction of a velocity window tapering across the stop).
    let step_m = encoder_step_m(trial);
    let least_mps = 5.0 * step_m / (k as f64 * dt);
    let jumps = jumps::velocity_steps(t, x, k, least_mps, step_m);
    let mut bounds: Vec<usize> = jumps.iter().map(|j| j.index).collect();
    let least_rest = k.max((LEAST_STOP_S / dt).round() as usize);
    let rests = rests(x, least_rest, step_m);
    // A rest's end just after a jump is the jump's: a stage setting off
    // at speed can move less than half an encoder step by the first
    // sample the jump places after it, and that sample slides with the
    // samples after it, not at rest as a one-sample run of its own would
    // have it. One sample at most: the slowest jump read (`least_mps`,
    // five steps a window) covers half a step in a tenth of a window,
    // under a sample up to 1 kHz. A rest's start stays where the encoder
    // puts it: a needle within half a step of where it stops has stopped.
    for r in &rests {
        let set_off = set_off_jump(&jumps, r).is_some();
        for edge in [Some(r.start), (!set_off).then_some(r.end)]
            .into_iter()
            .flatten()
        {
            if edge > 0 && edge < n && !bounds.contains(&edge) {
                bounds.push(edge);
            }
        }
    }
    bounds.sort_unstable();
    bounds.push(n);
    let mut v = vec![0.0; n];
    let mut start = 0;
    for end in bounds {
        // Samples start..end move without a jump.
        for (i, vi) in v.iter_mut().enumerate().take(end).skip(start) {
            let m = (i - start).min(end - 1 - i).min(k);
            if m > 0 {
                *vi = centred_mps(t, x, (i - m, i, i + m), step_m);
                continue;
            }
            let (a, b) = if end - 1 > i {
                (i, (i + k).min(end - 1))
            } else if i > start {
                (i.saturating_sub(k).max(start), i)
            } else {
                (i, i)
            };
            if b > a {
                *vi = (x[b] - x[a]) / (t[b] - t[a]);
            }
        }
        start = end;
    }
    let ramps = set_off_ramps(&rests, &jumps, k);
    for r in &ramps {
        for i in r.clone() {
            v[i] = (x[i + 1] - x[i - 1]) / (t[i + 1] - t[i - 1]);
        }
    }
    // The samples either side of each jump, with the other side's velocity
    // and how likely they are on that side.
    // A rest's last samples may already move below half a step, however
    // the jump after it is placed: a stage sets off at a finite
    // acceleration, half a ramp before the lines either side cross, and
    // Karnopp's friction turns at 5 µm/s. The force settles them. A rest
    // whose last sample the jump already has moving ends at the jump.
    let settled: Vec<(usize, f64, f64)> = rests
        .iter()
        .flat_map(|r| {
            let end = set_off_jump(&jumps, r).map_or(r.end, |j| j.index);
            settling(
                r.start..end,
                &v,
                (k, least_mps),
                beside_jump(&jumps, r.start),
            )
        })
        .collect();
    let mut uncertain = Vec::new();
    for j in &jumps {
        let [early, _, late] = j.landing(t);
        let (before, after) = (j.index - 1, j.index);
        if v[before] == v[after] && before > 0 {
            // A stop at speed the lines place just after a sample at which
            // the encoder already reads the rest (within half a step of
            // it: 24 µs at 20 mm/s): the rest starts at that sample, and
            // it moved with the samples before it as likely as the stop
            // came after it.
            if 1.0 - early > 0.01 {
                uncertain.push((before, v[before - 1], 1.0 - early));
            }
        } else if early > 0.01 {
            uncertain.push((before, v[after], early));
        }
        if late > 0.01 && after + 1 < n {
            uncertain.push((after, v[before], late));
        }
    }
    uncertain.retain(|u| !settled.iter().any(|s| s.0 == u.0));
    uncertain.extend(settled);
    let quantum_mps = step_m / (2 * k) as f64 / dt;
    let known: Vec<usize> = uncertain.iter().map(|u| u.0).collect();
    for (j, other, odds, here) in turning(&v, quantum_mps, least_rest) {
        if !known.contains(&j) && !beside_jump(&jumps, j) && !beside_jump(&jumps, j + 1) {
            v[j] = here;
            uncertain.push((j, other, odds));
        }
    }
    // The encoder has a ramp's samples off the rest: moving, whatever
    // the jump's placement leaves open.
    uncertain.retain(|u| !ramps.iter().any(|r| r.contains(&u.0)));
    uncertain.sort_by_key(|u| u.0);
    NeedleVelocity {
        v_mps: v,
        uncertain,
        jumps,
        encoder_step_m: step_m,
        sd_mps: 0.0,
        tissue_sd_m: 0.0,
        force_sd_n: 0.0,
    }
}

/// The velocity at sample `i` from samples `a..=b` about it (indices):
/// the central difference, the velocity of the middle of `a..b`, or
/// each side's mean velocity, at the middle of its span, interpolated to
/// `t[i]` (exact for a constant acceleration), where the middle is far
/// enough off `i` to matter:
/// - samples lost beside `i` (one side's span longer than the other's by
///   more than a sample's period): the middle is tens of ms off `i`, and
///   on a stroke turning round the velocity there is mm/s off (0.2 m/s²
///   over 15 ms, a force-law step of 70 mN);
/// - a clock that jitters, where the window bends by two encoder steps or
///   more (its middle's sagitta, ½·a·back·ahead): a stroke turning at
///   100 Hz (0.2 m/s², a sagitta of 90 µm) is read at the window's middle
///   up to a millisecond off `i`, 0.2 mm/s, on the wrong side of its turn
///   one sample in ten — a friction stepping by a newton there. Where the
///   window bends less than quantisation can make it bend, the central
///   difference, which does not read `x[i]`: the interpolation reads
///   its encoder step once more, by (ahead − back)/(back·ahead) — beside
///   a rest or a jump, where a window shrinks to a sample or two either
///   side, 0.3 mm/s a step at 1 kHz, tens of mN of a skin's damping.
///
/// A window even within rounding keeps the central difference, whose
/// exact zero where the encoder reads the same position either side
/// marks a turn that reads still.
fn centred_mps(t: &[f64], x: &[f64], (a, i, b): (usize, usize, usize), step_m: f64) -> f64 {
    let (back_s, ahead_s) = (t[i] - t[a], t[b] - t[i]);
    let span_s = back_s + ahead_s;
    let central = (x[b] - x[a]) / span_s.max(1e-12);
    if back_s <= 0.0 || ahead_s <= 0.0 || (back_s - ahead_s).abs() <= 1e-9 * span_s {
        return central;
    }
    let (back, ahead) = ((x[i] - x[a]) / back_s, (x[b] - x[i]) / ahead_s);
    let lopsided = (back_s - ahead_s).abs() > span_s / (b - a) as f64;
    let sagitta_m = (ahead - back).abs() * back_s * ahead_s / span_s;
    if lopsided || sagitta_m >= 2.0 * step_m {
        back + (ahead - back) * back_s / span_s
    } else {
        central
    }
}

/// The samples where a smooth turn (a stroke reversing, no jump and no
/// rest) may already have turned: a window's central difference reads a
/// needle about its turning point as still to within one encoder step
/// over the window (`quantum_mps`), so which side of the turn such a
/// sample lies on the encoder cannot say, while the friction steps from
/// one side's force to the other's there, hundreds of noise floors. Each
/// such sample gets the velocity of the turn's other side and even odds,
/// for the force to settle ([`other_side_odds`]), and the velocity of
/// the side its reading lies on as its own (`here`, returned as the
/// fourth of each): a stroke passes through zero in microseconds, so a
/// sample of a turn slides one way or the other, and its reading, within
/// a step of zero, may fall inside the friction's band (5 µm/s), where
/// the model would hold it at rest on the force before — a newton off
/// the skin phantom's force once it has flipped. A run still as long as
/// a rest (`least_rest` samples) is a stop, which [`settling`] takes.
fn turning(v: &[f64], quantum_mps: f64, least_rest: usize) -> Vec<(usize, f64, f64, f64)> {
    let mut out = Vec::new();
    let mut i = 1;
    while i < v.len() {
        if v[i].abs() > quantum_mps + 1e-12 {
            i += 1;
            continue;
        }
        let still = i..(i..v.len())
            .find(|&j| v[j].abs() > quantum_mps + 1e-12)
            .unwrap_or(v.len());
        let (before, after) = (v[still.start - 1], v.get(still.end).copied().unwrap_or(0.0));
        if before * after < 0.0 && still.len() < least_rest {
            for j in still.clone() {
                let (here, other) = if v[j] * after > 0.0 {
                    (after, before)
                } else {
                    (before, after)
                };
                out.push((j, other, 0.5, here));
            }
        }
        i = still.end;
    }
    out
}

/// The half-width of the velocity windows, samples: 10 ms, but three
/// samples at least (a jump is placed where lines through the samples
/// either side cross, and a line needs two). Also how far either side of
/// a rest's edge the force settles what the encoder cannot.
pub fn window_samples(rate_hz: f64) -> usize {
    ((0.01 * rate_hz).round() as usize).max(3)
}

/// Shortest run at one encoder position that is a stop (a dwell, as
/// `needle diagnose` calls one). Shorter runs are motion too slow for the
/// encoder to read each sample (crawling a micrometre per 10 ms, a
/// 0.2 Hz stroke turning), which a window across them measures.
const LEAST_STOP_S: f64 = 0.1;

/// The runs of at least `least` samples that the encoder reads at one
/// position: the needle at rest. A start or stop eased in over a few
/// samples is no jump, yet the force law steps there all the same: a
/// velocity window reaching across the edge has the needle sliding while
/// the encoder still reads it at rest, a newton of residual a sample
/// where a dwell turns into a withdrawal.
fn rests(x: &[f64], least: usize, step_m: f64) -> Vec<std::ops::Range<usize>> {
    let mut runs = Vec::new();
    let mut start = 0;
    for i in 1..=x.len() {
        if i < x.len() && (x[i] - x[start]).abs() < 0.5 * step_m {
            continue;
        }
        if i - start >= least {
            runs.push(start..i);
        }
        start = i;
    }
    runs
}

/// Whether a jump in velocity lies beside sample `i` (its first sample
/// after the jump within one of `i`).
fn beside_jump(jumps: &[jumps::Jump], i: usize) -> bool {
    jumps.iter().any(|j| j.index.abs_diff(i) <= 1)
}

/// The jump that sets off from `rest` at its last sample, if one does.
fn set_off_jump<'j>(
    jumps: &'j [jumps::Jump],
    rest: &std::ops::Range<usize>,
) -> Option<&'j jumps::Jump> {
    jumps.iter().find(|j| j.index + 1 == rest.end)
}

/// The samples a stage ramping up from a rest moves before the jump the
/// lines either side place (each from the rest's end, where the encoder
/// first reads it off the rest, to the jump, within a window of it). A
/// stage sets off at a finite acceleration: the lines of rest and of the
/// speed reached cross halfway up the ramp, half a ramp after it set off
/// (15–40 ms for a 30–80 ms ramp, a sample or more at 100 Hz), and a
/// sample in between moves while the jump's placement calls it at rest —
/// where Karnopp's friction has already turned at 5 µm/s, a newton off.
/// Such samples take the central difference about them (the ramp's
/// speed); a set-off between samples (a jump in velocity) has none.
fn set_off_ramps(
    rests: &[std::ops::Range<usize>],
    jumps: &[jumps::Jump],
    k: usize,
) -> Vec<std::ops::Range<usize>> {
    rests
        .iter()
        .filter_map(|r| {
            let j = jumps
                .iter()
                .find(|j| j.index > r.end && j.index <= r.end + k)?;
            (r.end > 0).then_some(r.end..j.index)
        })
        .collect()
}

/// The samples about a rest where the encoder cannot tell whether the
/// needle moves, each with the velocity of its other side, even odds,
/// the force to settle them ([`other_side_odds`]): up to `k` at each end
/// of the rest, which may already (or still) be moving below one encoder
/// step, and up to `k` outside it creeping slower than `creep_mps` (a
/// stage easing to a stop reads a micrometre a sample while the tissue
/// already holds). A rest shorter than 2·`k` gives each end its own
/// half. A start at a jump (`start_at_jump`) is left to the jump's own
/// placement: a stop at speed lands where the encoder reads the rest.
fn settling(
    rest: std::ops::Range<usize>,
    v: &[f64],
    (k, creep_mps): (usize, f64),
    start_at_jump: bool,
) -> Vec<(usize, f64, f64)> {
    let mid = rest.start + rest.len() / 2;
    let creeping = |i: &usize| v[*i] != 0.0 && v[*i].abs() < creep_mps;
    let mut out = Vec::new();
    if let Some(&before) = rest.start.checked_sub(1).and_then(|i| v.get(i)) {
        if before != 0.0 && !start_at_jump {
            let from = rest.start.saturating_sub(k);
            let creep: Vec<usize> = (from..rest.start).rev().take_while(creeping).collect();
            out.extend(creep.into_iter().rev().map(|i| (i, 0.0, 0.5)));
            out.extend((rest.start..mid.min(rest.start + k)).map(|i| (i, before, 0.5)));
        }
    }
    if let Some(&after) = v.get(rest.end) {
        if after != 0.0 {
            out.extend((mid.max(rest.end.saturating_sub(k))..rest.end).map(|i| (i, after, 0.5)));
            let to = (rest.end + k).min(v.len());
            out.extend((rest.end..to).take_while(creeping).map(|i| (i, 0.0, 0.5)));
        }
    }
    out
}

/// The needle's velocity at each sample, the samples that may lie on the
/// other side of a jump or of a rest's edge: (sample, velocity on the
/// other side, probability; the force settles them where
/// [`Self::force_sd_n`] is known, else the probability mixes both), and
/// the jumps themselves.
#[derive(Clone, Debug, Default)]
pub struct NeedleVelocity {
    pub v_mps: Vec<f64>,
    pub uncertain: Vec<(usize, f64, f64)>,
    pub jumps: Vec<jumps::Jump>,
    /// The encoder's resolution, m: the jitter the cutting front allows.
    /// Kept from the measured positions, which show it; positions moved
    /// into a moving tissue's frame do not.
    pub encoder_step_m: f64,
    /// How well `v_mps` is known where that matters (relative to a moving
    /// tissue, whose velocity is itself estimated), m/s; 0 for exact.
    pub sd_mps: f64,
    /// How well the needle's position relative to the tissue is known
    /// (a moving tissue's fitted displacement), m; 0 for exact. With
    /// `sd_mps` and `force_sd_n`, the cutting state is followed from the
    /// force where these cannot tell it ([`CuttingObserver`]).
    pub tissue_sd_m: f64,
    /// The load cell's noise, N, when the measured force is to settle which
    /// side of a jump an uncertain sample lies on; 0 leaves it to the
    /// encoder (a model drawn over data, not yet fitted to it).
    pub force_sd_n: f64,
}

impl NeedleVelocity {
    /// Along [`Trial::thinned`]`(step)`: every `step`-th velocity (as
    /// estimated at the full rate), the uncertain samples that are kept,
    /// and each jump before the first kept sample after it.
    pub fn thinned(&self, step: usize) -> NeedleVelocity {
        let step = step.max(1);
        let n = self.v_mps.len().div_ceil(step);
        NeedleVelocity {
            v_mps: needle_io::trial::every(&self.v_mps, step),
            uncertain: self
                .uncertain
                .iter()
                .filter(|u| u.0 % step == 0)
                .map(|&(i, v, p)| (i / step, v, p))
                .collect(),
            jumps: self
                .jumps
                .iter()
                .map(|j| jumps::Jump {
                    index: j.index.div_ceil(step),
                    ..*j
                })
                .filter(|j| (1..n).contains(&j.index))
                .collect(),
            ..*self
        }
    }
}

/// The encoder's resolution as the data show it: the least gap between
/// two positions it read.
pub(crate) fn encoder_step_m(trial: &Trial) -> f64 {
    // The least gap between distinct positions anywhere in the trial, not
    // between neighbouring samples: at 100 Hz a needle moves ten counts a
    // sample, but the withdrawal's positions fall between the insertion's.
    // At least 0.1 µm: a position stored in floating point is no encoder.
    let mut distinct = trial.x_m.clone();
    distinct.sort_by(f64::total_cmp);
    distinct
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|&d| d > 1e-12)
        .fold(f64::INFINITY, f64::min)
        .clamp(1e-7, 1e-4)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_force_settles_the_side_the_encoder_cannot() {
        // Moving: 1.05 N (friction + cutting); stopped: 0.11 N. Even odds
        // from the encoder, 5 mN noise.
        let sides = [1.05, 0.11];
        let reads_moving = other_side_odds(0.5, 1.047, sides, 0.005);
        let reads_stopped = other_side_odds(0.5, 0.113, sides, 0.005);
        assert!(reads_moving < 1e-6, "{reads_moving}");
        assert!(reads_stopped > 1.0 - 1e-6, "{reads_stopped}");
        // Halfway between the two, the encoder's odds stand.
        assert!((other_side_odds(0.3, 0.58, sides, 0.005) - 0.3).abs() < 1e-9);
        // Without a noise figure the force is not read at all.
        assert_eq!(other_side_odds(0.3, 0.113, sides, 0.0), 0.3);
        // A force far from both (an effect the nominal lacks) still picks
        // the nearer side, and the odds stay a probability.
        let far = other_side_odds(0.5, -0.13, sides, 0.005);
        assert!(far > 0.99 && far <= 1.0, "{far}");
    }

    #[test]
    fn a_sides_level_is_the_trials_own_at_the_sure_samples_on_that_side() {
        // Moving to sample 7, at rest from 10; 8 and 9 read at rest by
        // the encoder but may still move (a stage creeping to its stop).
        // The model misses the trial's moving force by +0.40 N and its
        // held force by -0.06 N.
        let n = 20;
        let v_mps: Vec<f64> = (0..n).map(|i| if i < 8 { 1e-3 } else { 0.0 }).collect();
        let moving = |i: usize| i < 10;
        let total_n: Vec<f64> = (0..n).map(|i| if moving(i) { 0.9 } else { 0.6 }).collect();
        let f_n: Vec<f64> = (0..n)
            .map(|i| total_n[i] + if moving(i) { 0.4 } else { -0.06 })
            .collect();
        let trial = Trial {
            t_s: (0..n).map(|i| i as f64 * 0.002).collect(),
            x_m: vec![0.0; n],
            f_n,
        };
        let v = NeedleVelocity {
            v_mps,
            uncertain: vec![(8, 1e-3, 0.5), (9, 1e-3, 0.5)],
            force_sd_n: 0.005,
            ..NeedleVelocity::default()
        };
        let close = |a: Option<[f64; 2]>, b: [f64; 2]| {
            a.is_some_and(|a| (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9)
        };
        // Both read at rest: this side's level is the rest's own, the
        // other side's the motion's — for 9 too, whose sample before is
        // itself uncertain and at rest: the side is judged by the sure
        // sample before (7, moving).
        let shifts = level_shifts(&trial, &v, &total_n, 0, (&v.uncertain, &[8, 9]));
        assert!(close(shifts[0], [-0.06, 0.4]), "{shifts:?}");
        assert!(close(shifts[1], [-0.06, 0.4]), "{shifts:?}");
        // Not contested: no shift; the model's own levels stand.
        assert_eq!(
            level_shifts(&trial, &v, &total_n, 0, (&v.uncertain, &[8]))[1],
            None
        );
        // Where the model meets the trial's levels, no shift either.
        let met = Trial {
            f_n: total_n.clone(),
            ..trial
        };
        let none = level_shifts(&met, &v, &total_n, 0, (&v.uncertain, &[8, 9]));
        assert!(none.iter().all(Option::is_none), "{none:?}");
    }

    /// A needle dithering by one encoder step between samples 1.1 and
    /// 0.8 ms apart reads still: a bend no more than quantisation can make
    /// is no turn, and the window's central difference holds.
    #[test]
    fn a_dither_of_one_step_on_a_jittered_clock_reads_still() {
        let (t, x) = ([0.0, 0.0011, 0.0019], [0.02, 0.020001, 0.02]);
        assert_eq!(centred_mps(&t, &x, (0, 1, 2), 1e-6), 0.0);
    }

    /// The paper's strokes (±4 mm at 1.1 Hz) read at 100 Hz on a clock
    /// jittered by a tenth of its period, encoder 1 µm: at each turn the
    /// window's middle is up to a millisecond off the sample, 0.2 mm/s of
    /// the stroke's, yet every sample's velocity is on its own side of the
    /// turn (or is marked uncertain), as the friction's side needs.
    #[test]
    fn a_stroke_turning_on_a_jittered_clock_is_read_on_its_side() {
        use crate::fit::jumps::tests::{read_at, stroke_mps};
        use rand::SeedableRng;
        let mut wrong = Vec::new();
        for seed in 0..20 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let t_s = crate::sim::jittered_times(100.0, 6.0, &mut rng);
            let trial = Trial {
                f_n: vec![0.0; t_s.len()],
                x_m: read_at(&t_s, stroke_mps),
                t_s,
            };
            let v = needle_velocity(&trial);
            for (i, &t) in trial.t_s.iter().enumerate() {
                let exact_mps = stroke_mps(t);
                let marked = v.uncertain.iter().any(|u| u.0 == i);
                if v.v_mps[i] * exact_mps < 0.0 && !marked {
                    wrong.push((seed, i, v.v_mps[i], exact_mps));
                }
            }
        }
        assert!(wrong.is_empty(), "{wrong:?}");
    }

    /// A sample of a turn slides one way or the other: its velocity and
    /// its alternative lie either side of zero, each beyond the
    /// friction's band (5 µm/s, inside which the model holds a sample at
    /// rest), its own the side its reading leans to, which is the
    /// stroke's more often than not. 100 and 250 Hz on jittered clocks.
    #[test]
    fn a_sample_of_a_turn_slides_on_one_side_or_the_other() {
        use crate::fit::jumps::tests::{read_at, stroke_mps};
        use rand::SeedableRng;
        let band_mps = 5e-6;
        let mut wrong = Vec::new();
        let (mut turning, mut on_its_side) = (0, 0);
        for (seed, rate_hz) in (0..20).flat_map(|s| [(s, 100.0), (s, 250.0)]) {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let t_s = crate::sim::jittered_times(rate_hz, 6.0, &mut rng);
            let trial = Trial {
                f_n: vec![0.0; t_s.len()],
                x_m: read_at(&t_s, stroke_mps),
                t_s,
            };
            let v = needle_velocity(&trial);
            for &(i, other, _) in &v.uncertain {
                let (here, exact) = (v.v_mps[i], stroke_mps(trial.t_s[i]));
                // Turning, not set off or stopped by a jump.
                if exact == 0.0 || exact.abs() > 1e-3 {
                    continue;
                }
                let sides = here * other < 0.0 && here.abs() > band_mps && other.abs() > band_mps;
                if !sides {
                    wrong.push((seed, rate_hz, i, here, other, exact));
                }
                turning += 1;
                on_its_side += usize::from(here * exact > 0.0);
            }
        }
        assert!(wrong.is_empty(), "{wrong:?}");
        // A reading within a step of zero still leans the right way more
        // often than not: most samples' own velocity is the stroke's side.
        assert!(
            turning > 20 && 10 * on_its_side >= 6 * turning,
            "{on_its_side} of {turning}"
        );
    }

    #[test]
    fn a_velocity_beside_lost_samples_is_the_velocity_at_its_sample() {
        // 500 Hz, 66 ms lost after sample 99, speeding up at 0.2 m/s²:
        // the windows beside the gap reach across it, lopsided in time.
        let mut t_s: Vec<f64> = (0..100).map(|i| i as f64 * 0.002).collect();
        t_s.extend((100..200).map(|i| i as f64 * 0.002 + 0.066));
        let trial = Trial {
            f_n: vec![0.0; t_s.len()],
            x_m: t_s.iter().map(|&t| 0.02 + 0.01 * t + 0.1 * t * t).collect(),
            t_s,
        };
        let v = needle_velocity(&trial);
        for i in 95..105 {
            let exact_mps = 0.01 + 0.2 * trial.t_s[i];
            assert!(
                (v.v_mps[i] - exact_mps).abs() < 1e-9,
                "{i}: {} against {exact_mps}",
                v.v_mps[i]
            );
        }
    }

    #[test]
    fn an_eased_start_from_rest_leaves_the_rest_to_the_force() {
        // 500 Hz, 1 µm encoder: 0.2 s at rest, then a withdrawal eased in
        // at 0.5 m/s² (the encoder reads the first step 2 ms after the
        // needle sets off, the force law has flipped on the first sample).
        let dt = 0.002;
        let n = 200;
        let t_s: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
        let x_m: Vec<f64> = t_s
            .iter()
            .map(|&t| {
                let moved = 0.5 * 0.5 * (t - 0.2).max(0.0).powi(2);
                ((0.02 - moved) * 1e6).round() * 1e-6
            })
            .collect();
        let trial = Trial {
            f_n: vec![0.0; n],
            x_m,
            t_s,
        };
        let v = needle_velocity(&trial);
        let first_moved = trial.x_m.iter().position(|&x| x < 0.02 - 5e-7).unwrap();
        // At rest by the encoder up to its first step, and no window
        // reaches across it ...
        assert!(v.v_mps[..first_moved].iter().all(|&v| v == 0.0));
        assert!(v.v_mps[first_moved..].iter().all(|&v| v < 0.0));
        // ... but the samples just before it may already be moving: the
        // force is to settle them, with the withdrawal's velocity.
        let settled: Vec<usize> = v.uncertain.iter().map(|u| u.0).collect();
        assert!(settled.contains(&(first_moved - 1)), "{settled:?}");
        assert!(v.uncertain.iter().all(|u| u.1 < 0.0 && u.0 < first_moved));
        assert!(settled.iter().all(|&i| i + 5 >= first_moved), "{settled:?}");
    }

    #[test]
    fn a_start_at_speed_under_one_encoder_step_slides_from_the_jump() {
        // 200 Hz, 1 µm encoder: a creep in at a count a sample, at rest,
        // then off at 4 mm/s 0.1 ms before a sample, which reads the
        // rest's position (0.4 µm moved) though the force law has flipped
        // there. The jump is placed before that sample, so it slides.
        let dt = 0.005;
        let n = 100;
        let start_s = 50.0 * dt - 1e-4;
        let t_s: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
        let x_m: Vec<f64> = t_s
            .iter()
            .enumerate()
            .map(|(i, &t)| {
                let creep_m = 1e-6 * 20usize.saturating_sub(i) as f64;
                ((0.03 - creep_m - 0.004 * (t - start_s).max(0.0)) * 1e6).round() * 1e-6
            })
            .collect();
        assert_eq!(x_m[50], x_m[49]);
        let trial = Trial {
            f_n: vec![0.0; n],
            x_m,
            t_s,
        };
        let v = needle_velocity(&trial);
        let jump = v
            .jumps
            .iter()
            .find(|j| j.index.abs_diff(50) <= 1)
            .unwrap_or_else(|| panic!("{:?}", v.jumps));
        assert_eq!(jump.index, 50, "{jump:?}");
        assert!(v.v_mps[50] < -0.003, "{}", v.v_mps[50]);
        assert_eq!(v.v_mps[49], 0.0);
    }

    #[test]
    fn a_smooth_turn_leaves_its_side_to_the_force() {
        // The paper's strokes: 2.5 mm at 0.5 Hz, 500 Hz, 1 µm encoder. Near
        // each turning point the encoder reads one position for several
        // samples and the windows read the needle as still.
        let dt = 0.002;
        let n = 2000;
        let t_s: Vec<f64> = (0..n).map(|i| i as f64 * dt).collect();
        let x_m: Vec<f64> = t_s
            .iter()
            .map(|&t| {
                let x = 0.04 - 2.5e-3 * (1.0 - (std::f64::consts::PI * t).cos());
                (x * 1e6).round() * 1e-6
            })
            .collect();
        let trial = Trial {
            f_n: vec![0.0; n],
            x_m,
            t_s,
        };
        let v = needle_velocity(&trial);
        // Turns at 1 s and 2 s (samples 500, 1000, 1500): each has samples
        // whose side the force is to settle, with the other side's
        // velocity, of the other sign.
        for turn in [500usize, 1000, 1500] {
            let near: Vec<&(usize, f64, f64)> = v
                .uncertain
                .iter()
                .filter(|u| u.0.abs_diff(turn) <= 10)
                .collect();
            assert!(!near.is_empty(), "turn at {turn}: {:?}", v.uncertain);
            for &&(i, other, prior) in &near {
                assert_eq!(prior, 0.5);
                assert!(other * v.v_mps[i] <= 0.0 && other != 0.0, "{i}: {other}");
            }
        }
        // Elsewhere the encoder knows the side.
        assert!(v.uncertain.iter().all(|u| [0usize, 500, 1000, 1500]
            .iter()
            .any(|t| u.0.abs_diff(*t) <= 10)));
    }

    /// A stage setting off from rest at 0.1 m/s² to 2 mm/s (a 20 ms
    /// ramp, two samples at 100 Hz), 1 µm encoder, the set-off anywhere
    /// between samples: a sample at rest reads at rest or is left to the
    /// force, and a sample the ramp already has past 0.3 mm/s slides
    /// forward or is left to the force with a forward alternative —
    /// never held at rest where the encoder saw it leave.
    #[test]
    fn a_stage_ramping_up_from_rest_slides_from_its_first_samples() {
        let (accel_mps2, speed_mps, dt) = (0.1, 0.002, 0.01);
        let mut wrong = Vec::new();
        for phase in 0..20 {
            let start_s = 0.5 + dt * phase as f64 / 20.0;
            let exact_mps = |t: f64| (accel_mps2 * (t - start_s)).clamp(0.0, speed_mps);
            let exact_m = |t: f64| {
                let ramp_s = speed_mps / accel_mps2;
                let s = (t - start_s).max(0.0);
                if s < ramp_s {
                    0.5 * accel_mps2 * s * s
                } else {
                    0.5 * speed_mps * ramp_s + speed_mps * (s - ramp_s)
                }
            };
            let t_s: Vec<f64> = (0..150).map(|i| i as f64 * dt).collect();
            let trial = Trial {
                f_n: vec![0.0; t_s.len()],
                x_m: t_s
                    .iter()
                    .map(|&t| ((0.02 + exact_m(t)) * 1e6).round() * 1e-6)
                    .collect(),
                t_s,
            };
            let v = needle_velocity(&trial);
            for (i, &t) in trial.t_s.iter().enumerate() {
                let other = v.uncertain.iter().find(|u| u.0 == i).map(|u| u.1);
                let sides = [Some(v.v_mps[i]), other];
                let at_rest = exact_mps(t) == 0.0;
                let right = if at_rest {
                    sides.contains(&Some(0.0))
                } else if exact_mps(t) > 3e-4 {
                    sides.iter().flatten().any(|&s| s > 5e-6)
                } else {
                    true
                };
                if !right {
                    wrong.push((phase, i, v.v_mps[i], other, exact_mps(t)));
                }
            }
        }
        assert!(wrong.is_empty(), "{wrong:?}");
    }
}
