//! Tissue motion as what it is: the tissue displaced along the needle's
//! axis under it, so the nominal model holds in the tissue's frame, not
//! the encoder's. The `tissue_motion` candidate ranks the effect with a
//! coarse grid of sinusoids (cheap, and enough to tell it from the
//! others); once it is named, this module finds the displacement itself,
//! trial by trial, and the backfit fits the nominal again on positions in
//! the tissue's frame.
//!
//! What is shared and what is per trial: the breathing frequency is a
//! property of the subject and is fitted on the training trials only (the
//! median of their own estimates); the displacement's phase and shape
//! (fundamental and second harmonic, four coefficients) are where the
//! breathing was during that trial, found on each trial withheld or not,
//! as its contact point is. Breathing is not a sine (a sharper inhale),
//! hence the second harmonic; nor is it steady (breaths differ in
//! length), hence a phase that may wander from breath to breath
//! ([`PhaseWander`]), also the trial's own.
//!
//! The fit is Levenberg–Marquardt on the measured force against the
//! nominal model evaluated in the moving tissue, with finite-difference
//! derivatives, over the samples in the tissue, the loading curve's
//! included, each trial's own cutting force, friction coefficients and
//! loading curve's shape solved for each displacement tried
//! (`residuals`). Written here rather than taken from a crate: the Rust
//! LM crates bring nalgebra, a large build for five unknowns (and, with
//! the wander, at most 36 whose normal equations are as small).

use std::f64::consts::TAU;

use needle_holder::model::params::TissueParams;

use super::prepare::{relaxed_surface, Prepared, LOADING};
use crate::fit::lsq::Lsq;
use crate::fit::predict::{predict_each, NeedleVelocity, SampleParts};
use crate::fit::tissue::CUTTING_PRIOR_N;

/// Breathing frequencies searched, Hz (6 to 40 breaths a minute).
const FREQ_FROM_HZ: f64 = 0.1;
const FREQ_TO_HZ: f64 = 0.7;
const FREQ_STEP_HZ: f64 = 0.002;

/// How well the tissue's fitted velocity is known, as a fraction of its
/// fastest, and its displacement, as a fraction of its amplitude (at
/// seed 7, 20–60 µm of 1.5 mm, mostly from the frequency).
const TISSUE_VELOCITY_SD: f64 = 0.02;

/// The needle's velocity is known to the encoder's quantisation over its
/// 20 ms difference, the tissue's to a few per cent of its fastest.
fn relative_velocity_sd(encoder_step_m: f64, tissue_fastest_mps: f64) -> f64 {
    let needle_sd_mps = encoder_step_m / (6f64.sqrt() * 0.02);
    needle_sd_mps.hypot(TISSUE_VELOCITY_SD * tissue_fastest_mps)
}

/// The tissue's displacement along the axis during one trial.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TissueShift {
    pub omega_rad_s: f64,
    /// Time the harmonics' phases are referred to (the trial's middle, so
    /// that a change of frequency does not swing the phase), s.
    pub t_ref_s: f64,
    /// sin, cos of the fundamental, sin, cos of the second harmonic, m.
    pub coeffs_m: [f64; 4],
    /// How the breathing's phase strays from the steady ω·(t − t_ref).
    pub wander: PhaseWander,
}

impl TissueShift {
    /// Displacement (m) and velocity (m/s) at `t_s`.
    pub fn at(&self, t_s: f64) -> (f64, f64) {
        self.at_harmonics(self.phase_at(t_s))
    }

    /// sin, cos of the phase and of twice it at `t_s`, and the phase's
    /// rate there, rad/s.
    fn phase_at(&self, t_s: f64) -> [f64; 5] {
        let (stray_rad, stray_rate) = self.wander.at(t_s);
        let [s1, c1, s2, c2] = harmonics(self.omega_rad_s * (t_s - self.t_ref_s) + stray_rad);
        [s1, c1, s2, c2, self.omega_rad_s + stray_rate]
    }

    /// [`Self::at`] from the harmonics' sines and cosines there and the
    /// phase's rate (`harmonics_along`).
    pub fn at_harmonics(&self, [s1, c1, s2, c2, w]: [f64; 5]) -> (f64, f64) {
        let [a, b, c, d] = self.coeffs_m;
        (
            a * s1 + b * c1 + c * s2 + d * c2,
            w * (a * c1 - b * s1) + 2.0 * w * (c * c2 - d * s2),
        )
    }

    /// Peak-to-peak half amplitude over one breath, m.
    pub fn amplitude_m(&self) -> f64 {
        let (lo, hi) = (0..64)
            .map(|k| {
                let [s1, c1, s2, c2] = harmonics(TAU * k as f64 / 64.0);
                self.at_harmonics([s1, c1, s2, c2, 0.0]).0
            })
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                (l.min(v), h.max(v))
            });
        (hi - lo) / 2.0
    }

    /// The tissue's fastest speed, m/s (a breath's fastest, at the
    /// fastest the phase runs).
    fn fastest_mps(&self) -> f64 {
        self.amplitude_m() * (self.omega_rad_s.abs() + self.wander.steepest_rad_s())
    }

    /// The needle's velocity relative to the tissue: the measured one less
    /// the tissue's, not a difference of moved positions (which would
    /// re-derive the encoder's steps, and no longer show them).
    pub fn velocity_in_tissue(&self, measured: &NeedleVelocity, t_s: &[f64]) -> NeedleVelocity {
        let mut v = measured.clone();
        for (vi, &t) in v.v_mps.iter_mut().zip(t_s) {
            *vi -= self.at(t).1;
        }
        for u in &mut v.uncertain {
            u.1 -= self.at(t_s[u.0]).1;
        }
        let fastest_mps = self.fastest_mps();
        v.sd_mps = relative_velocity_sd(measured.encoder_step_m, fastest_mps);
        v.tissue_sd_m = TISSUE_VELOCITY_SD * self.amplitude_m();
        v
    }

    /// The trial's positions in the tissue's frame.
    pub fn apply(&self, trial: &needle_io::trial::Trial) -> needle_io::trial::Trial {
        let mut moved = trial.clone();
        for (x, &t) in moved.x_m.iter_mut().zip(&trial.t_s) {
            *x -= self.at(t).0;
        }
        moved
    }
}

/// sin, cos of phase θ and of 2θ (by the double angle).
fn harmonics(theta: f64) -> [f64; 4] {
    let (s1, c1) = theta.sin_cos();
    [s1, c1, 2.0 * s1 * c1, c1 * c1 - s1 * s1]
}

/// sin, cos of both harmonics of `shift`'s phase at every time of `t_s`,
/// and the phase's rate there ([`TissueShift::at_harmonics`]'s argument).
pub fn harmonics_along(shift: &TissueShift, t_s: &[f64]) -> Vec<[f64; 5]> {
    t_s.iter().map(|&t| shift.phase_at(t)).collect()
}

/// Most knots of a [`PhaseWander`].
const MAX_KNOTS: usize = 32;

/// A breathing period that changes from breath to breath: the phase's
/// departure from the steady ω·(t − t_ref), linear between knots about a
/// breath apart and held beyond the first and last, rad. No knots: no
/// departure. A subject's breaths differ in length (by 10–30 % from one
/// to the next at rest, more under stress), so over a trial of ten
/// breaths the phase strays by radians from any one frequency; the
/// period's changes are the subject's, like the phase, found on each
/// trial.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseWander {
    /// Time of the first knot, s.
    t0_s: f64,
    /// Time between knots (at least 1 ms), s.
    step_s: f64,
    /// Knots in use, 0 or 2 to [`MAX_KNOTS`].
    knots: usize,
    /// The phase's departure at each knot, rad.
    phase_rad: [f64; MAX_KNOTS],
}

impl PhaseWander {
    /// A steady breath.
    pub const NONE: Self = Self {
        t0_s: 0.0,
        step_s: 1.0,
        knots: 0,
        phase_rad: [0.0; MAX_KNOTS],
    };

    /// Knots `step_s` apart from `t0_s` with the departures `phase_rad`
    /// (the first 32); fewer than two: a steady breath.
    pub fn through(t0_s: f64, step_s: f64, phase_rad: &[f64]) -> Self {
        let knots = phase_rad.len().min(MAX_KNOTS);
        if knots < 2 {
            return Self::NONE;
        }
        let mut at = [0.0; MAX_KNOTS];
        at[..knots].copy_from_slice(&phase_rad[..knots]);
        Self {
            t0_s,
            step_s: step_s.max(1e-3),
            knots,
            phase_rad: at,
        }
    }

    /// Knots about `period_s` apart over `from_s..to_s` (farther apart
    /// when [`MAX_KNOTS`] would not reach), each where `self` has the
    /// phase then.
    fn over(&self, from_s: f64, to_s: f64, period_s: f64) -> Self {
        let span_s = (to_s - from_s).max(0.0);
        let breaths = (span_s / period_s.max(1e-3)).ceil().min(MAX_KNOTS as f64);
        let knots = (breaths as usize + 1).clamp(2, MAX_KNOTS);
        let step_s = (span_s / (knots - 1) as f64).max(1e-3);
        let mut phase_rad = [0.0; MAX_KNOTS];
        for (k, p) in phase_rad.iter_mut().take(knots).enumerate() {
            *p = self.at(from_s + step_s * k as f64).0;
        }
        Self {
            t0_s: from_s,
            step_s,
            knots,
            phase_rad,
        }
    }

    /// The departure (rad) and its rate (rad/s) at `t_s`.
    pub fn at(&self, t_s: f64) -> (f64, f64) {
        if self.knots < 2 {
            return (0.0, 0.0);
        }
        let last = (self.knots - 1) as f64;
        let u = (t_s - self.t0_s) / self.step_s;
        let k = (u.clamp(0.0, last).floor() as usize).min(self.knots - 2);
        let (a, b) = (self.phase_rad[k], self.phase_rad[k + 1]);
        let frac = u.clamp(0.0, last) - k as f64;
        let rate = if (0.0..=last).contains(&u) {
            (b - a) / self.step_s
        } else {
            0.0
        };
        (a + frac * (b - a), rate)
    }

    /// Knot k's share of the departure at `t_s` (a hat one step wide
    /// each side; the end knots hold beyond).
    fn weight(&self, k: usize, t_s: f64) -> f64 {
        let u = ((t_s - self.t0_s) / self.step_s).clamp(0.0, (self.knots - 1) as f64);
        (1.0 - (u - k as f64).abs()).max(0.0)
    }

    /// The fastest the departure runs, rad/s.
    fn steepest_rad_s(&self) -> f64 {
        self.phase_rad[..self.knots]
            .windows(2)
            .map(|w| (w[1] - w[0]).abs() / self.step_s)
            .fold(0.0, f64::max)
    }
}

/// The harmonics of a phase at every sample of a trial, for the last two
/// phases asked: `sin_cos` was a third of the fit's time, four of its five
/// Jacobian columns hold the phase, and a free frequency's column and step
/// alternate with the point they start from.
struct Harmonics {
    /// (ω, reference time, wander; [`harmonics_along`] them), the most
    /// recent first.
    kept: Vec<(Phase, Vec<[f64; 5]>)>,
}

/// What a [`TissueShift`]'s phase depends on.
type Phase = (f64, f64, PhaseWander);

impl Harmonics {
    fn new() -> Self {
        Self { kept: Vec::new() }
    }

    /// The harmonics for `shift` along `t_s`.
    fn follow(&mut self, shift: &TissueShift, t_s: &[f64]) -> &[[f64; 5]] {
        let key = (shift.omega_rad_s, shift.t_ref_s, shift.wander);
        match self.kept.iter().position(|k| k.0 == key) {
            Some(i) => self.kept[..=i].rotate_right(1),
            None => {
                self.kept.insert(0, (key, harmonics_along(shift, t_s)));
                self.kept.truncate(2);
            }
        }
        &self.kept[0].1
    }
}

/// The nominal model's force along `p`'s trial with the tissue displaced
/// by `shift(i) = (m, m/s)` at sample i, the needle's positions in the tissue's frame
/// and the contact point there: friction length, sliding and cutting follow
/// the needle's motion relative to the tissue. The needle's velocity
/// relative to the tissue is its own less the tissue's, not a difference
/// of the shifted positions (that would re-derive the encoder's steps on
/// every evaluation).
pub fn moved_model(
    p: &Prepared,
    params: &TissueParams,
    shift: &dyn Fn(usize) -> (f64, f64),
) -> (Vec<f64>, Vec<f64>, f64) {
    let mut total = vec![0.0; p.trial.len()];
    let (relative_x_m, contact_x_m) = moved_parts(p, params, shift, |i, s| total[i] = s.total_n());
    (total, relative_x_m, contact_x_m)
}

/// [`moved_model`] term by term: each sample's parts handed to `each`;
/// returns the needle's positions in the tissue's frame and the contact
/// point there.
fn moved_parts(
    p: &Prepared,
    params: &TissueParams,
    shift: impl Fn(usize) -> (f64, f64),
    each: impl FnMut(usize, &SampleParts),
) -> (Vec<f64>, f64) {
    let trial = &p.trial;
    let n = trial.len();
    let mut relative_x_m = trial.x_m.clone();
    let mut v_rel = NeedleVelocity {
        v_mps: p.velocity.v_mps.clone(),
        encoder_step_m: p.velocity.encoder_step_m,
        ..NeedleVelocity::default()
    };
    let mut fastest_mps: f64 = 0.0;
    for (i, (x, v)) in relative_x_m.iter_mut().zip(&mut v_rel.v_mps).enumerate() {
        let (dx, dv) = shift(i);
        *x -= dx;
        *v -= dv;
        fastest_mps = fastest_mps.max(dv.abs());
    }
    v_rel.sd_mps = relative_velocity_sd(p.velocity.encoder_step_m, fastest_mps);
    // Contact: where the force first rose above the tissue's contact
    // threshold for good, less the depth that threshold takes, in the
    // tissue's frame. The fit's own contact assumes a monotonic loading
    // curve, which the motion bends.
    let threshold = params.contact_force_n.max(5.0 * p.noise_n);
    let crossing = (0..=p.geometry.puncture_index.min(n - 1))
        .rev()
        .find(|&i| trial.f_n[i] < threshold)
        .unwrap_or(0);
    let d_threshold = depth_at(params, threshold);
    let mut geometry = p.geometry.clone();
    geometry.contact_x_m = relative_x_m[crossing] - d_threshold;
    geometry.puncture_x_m = relative_x_m[p.geometry.puncture_index.min(n - 1)];
    // The tissue's ρ, not the trial's own: read in the lab frame, the
    // motion bends a trial's own. (Once the motion is named, the nominal
    // found again in the tissue's frame has each trial's own again, by
    // `relaxed_surfaces`, read in that frame.)
    geometry.relaxed_x_m = relaxed_surface(&geometry, params.relaxation);
    predict_each(params, &geometry, (trial, &relative_x_m), &v_rel, each);
    (relative_x_m, geometry.contact_x_m)
}

/// The depth at which the nominal's loading law reaches `force_n`, by
/// bisection up to the puncture depth (a law fitted to bent loading
/// curves can start flat, so its slope at contact is no guide).
fn depth_at(params: &TissueParams, force_n: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, params.puncture_depth_m.max(1e-3));
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if params.stiffness_n(mid) < force_n {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Samples the motion is fitted on: in tissue, the loading curve's too
/// (a breath whose period wanders is where it was during the loading
/// only by the loading's own record).
fn fitted_samples(p: &Prepared) -> Vec<usize> {
    (0..p.trial.len()).filter(|&i| p.in_tissue(i)).collect()
}

/// Samples whose spectrum shows the breathing: in tissue after the
/// puncture (the loading curve's own rise would crowd the band's lowest
/// bins).
fn spectral_samples(p: &Prepared) -> Vec<usize> {
    (0..p.trial.len())
        .filter(|&i| p.in_tissue(i) && p.phase[i] != LOADING)
        .collect()
}

/// Residuals of the measured force against the model moved by `shift`,
/// over `samples`.
fn residuals(
    p: &Prepared,
    params: &TissueParams,
    shift: &TissueShift,
    samples: &[usize],
    harmonics: &mut Harmonics,
) -> Vec<f64> {
    let h = harmonics.follow(shift, &p.trial.t_s);
    // Only what the rows below read: each sample's model force and the
    // columns the trial's own levels scale (a fit evaluates this
    // thousands of times a trial, and copying whole `SampleParts` showed
    // in its time).
    let mut parts = vec![[0.0; 6]; p.trial.len()];
    let (relative_x_m, contact_x_m) = moved_parts(
        p,
        params,
        |i| shift.at_harmonics(h[i]),
        |i, s| {
            let [b0, b1, b2, b3] = s.friction_basis;
            parts[i] = [s.total_n(), s.cutting_n, b0, b1, b2, b3];
        },
    );
    // The trial's own cutting force and friction coefficients: the pooled
    // nominal misses a trial's by the tissue's spread (15–30 %), and one
    // fitted in the encoder's frame of a moving tissue by far more (the
    // skin phantom's b_p 35 times its own); a displacement fitted against the wrong
    // levels moves the tissue to make up the difference. So is the loading
    // curve's shape in the tissue's frame beyond the nominal's (fitted
    // against the needle's position, which the motion bends): a step at
    // contact, the depth and its square. The force is linear in them (the
    // friction in (c_p, b_p, c_n, b_n) through its basis), so for each
    // displacement they are solved, not searched: by least squares, then
    // once more with Huber's weights of what that left, so the cliffs a
    // misplaced switch leaves weigh on the levels no more than on the loss.
    let rows: Vec<[f64; LEVELS]> = samples
        .iter()
        .map(|&i| {
            let [_, cutting_n, b0, b1, b2, b3] = parts[i];
            let d_mm = 1e3 * (relative_x_m[i] - contact_x_m);
            let [l0, l1, l2] = if p.phase[i] == LOADING && d_mm > 0.0 {
                [1.0, d_mm, d_mm * d_mm]
            } else {
                [0.0; 3]
            };
            [cutting_n, b0, b1, b2, b3, l0, l1, l2]
        })
        .collect();
    let corner_n = HUBER_CORNER_NOISE_SD * p.noise_n;
    let nominal_r: Vec<f64> = samples
        .iter()
        .map(|&i| p.trial.f_n[i] - parts[i][0])
        .collect();
    let mut weights = vec![1.0; samples.len()];
    let mut r = nominal_r.clone();
    for pass in 0..2 {
        if pass > 0 {
            weights = r.iter().map(|&e| huber_weight(e, corner_n)).collect();
        }
        let mut deltas = level_deltas(&rows, &nominal_r, &weights);
        // A trial's cutting pushes; it never pulls.
        deltas[0] = deltas[0].max(-1.0);
        for ((e, row), r0) in r.iter_mut().zip(&rows).zip(&nominal_r) {
            let levels_n: f64 = row.iter().zip(&deltas).map(|(c, d)| c * d).sum();
            *e = r0 - levels_n;
        }
    }
    r
}

/// A trial's own levels in [`residuals`]: the cutting force (as a share
/// of the model's), (c_p, b_p, c_n, b_n), and the loading curve's step,
/// slope and curvature (per mm of depth in the tissue's frame).
const LEVELS: usize = 8;

/// The changes to the levels ([`LEVELS`]; `rows`, their columns at each
/// sample) that best take up `r`, the residual of the model there, each
/// sample weighed by `weights`.
fn level_deltas(rows: &[[f64; LEVELS]], r: &[f64], weights: &[f64]) -> [f64; LEVELS] {
    let mut levels = Lsq::<LEVELS>::default();
    let weighed = rows.iter().zip(r).zip(weights).map(|((row, &e), &w)| {
        // A whole weight (most samples) scales nothing.
        if w == 1.0 {
            (*row, e)
        } else {
            let w = w.sqrt();
            (row.map(|c| w * c), w * e)
        }
    });
    levels.add_all(weighed);
    levels
        .solve_damped(LEVEL_RIDGE, LEVELS)
        .unwrap_or([0.0; LEVELS])
}

/// Corner of Huber's loss in the displacement's fit, in noise sd.
const HUBER_CORNER_NOISE_SD: f64 = 3.0;

/// Ridge on a trial's own levels in [`residuals`], as a share of each
/// level's own weight: enough to hold a level the displacement leaves
/// unseen (no cutting in a trial's fitted samples), too little to bias
/// one it shows.
const LEVEL_RIDGE: f64 = 1e-3;

/// Huber's loss with its corner at `c`: quadratic within, linear beyond.
/// The model's force has cliffs (the whole cutting force on or off as the
/// needle passes its deepest point in the tissue), which a displacement a
/// micrometre off puts on the wrong samples; squared, those few samples
/// would outweigh the friction's smooth record of the displacement on all
/// the others.
fn huber(r: &[f64], c: f64) -> f64 {
    r.iter()
        .map(|e| {
            let a = e.abs();
            if a <= c {
                0.5 * a * a
            } else {
                c * (a - 0.5 * c)
            }
        })
        .sum()
}

/// Weight of a residual in Huber's iteratively reweighted least squares.
fn huber_weight(e: f64, c: f64) -> f64 {
    if e.abs() <= c {
        1.0
    } else {
        c / e.abs()
    }
}

/// Frequencies of the periodogram, Hz.
fn periodogram_freqs_hz() -> impl Iterator<Item = f64> {
    let steps = ((FREQ_TO_HZ - FREQ_FROM_HZ) / FREQ_STEP_HZ).round() as usize;
    (0..=steps).map(|k| FREQ_FROM_HZ + FREQ_STEP_HZ * k as f64)
}

/// A trial's residual's periodogram over the breathing band, normalised
/// to its own total (each trial has one vote, however long).
fn periodogram(p: &Prepared, samples: &[usize]) -> Vec<f64> {
    let detrended = detrended_by_phase(p, samples);
    let bins = periodogram_freqs_hz().count();
    let (mut re, mut im) = (vec![0.0; bins], vec![0.0; bins]);
    // Each sample's phasor e^(−iωt) from bin to bin is a rotation by the
    // step's: two sin_cos a sample instead of one a sample and bin (0.2 s
    // of a 10-trial tissue-motion diagnosis).
    for (&i, &r) in samples.iter().zip(&detrended) {
        let t = p.trial.t_s[i];
        let (mut s, mut c) = (TAU * FREQ_FROM_HZ * t).sin_cos();
        let (ds, dc) = (TAU * FREQ_STEP_HZ * t).sin_cos();
        for (a, b) in re.iter_mut().zip(&mut im) {
            *a += r * c;
            *b -= r * s;
            (s, c) = (s * dc + c * ds, c * dc - s * ds);
        }
    }
    let spectrum: Vec<f64> = re.iter().zip(&im).map(|(a, b)| a * a + b * b).collect();
    let total = spectrum.iter().sum::<f64>().max(f64::MIN_POSITIVE);
    spectrum.into_iter().map(|s| s / total).collect()
}

/// The residual at `samples` less a straight line fitted over each run of
/// one phase: the nominal misses each phase of a protocol by its own level
/// and slope (a cutting force too low along the insertion, a holding force
/// in the dwell), steps a breath apart or slower whose spectrum would
/// crowd the breathing band's lowest bins; breathing is what varies
/// within a phase.
fn detrended_by_phase(p: &Prepared, samples: &[usize]) -> Vec<f64> {
    let mut out = Vec::with_capacity(samples.len());
    let mut start = 0;
    while start < samples.len() {
        let phase = p.phase[samples[start]];
        let end = samples[start..]
            .iter()
            .position(|&i| p.phase[i] != phase)
            .map_or(samples.len(), |k| start + k);
        let run = &samples[start..end];
        let t0 = p.trial.t_s[run[0]];
        let mut line = Lsq::<2>::default();
        for &i in run {
            line.add([1.0, p.trial.t_s[i] - t0], p.residual_n[i]);
        }
        // A run of one sample has no slope: its own level.
        let [a, b] = line.solve().unwrap_or([p.residual_n[run[0]], 0.0]);
        out.extend(
            run.iter()
                .map(|&i| p.residual_n[i] - a - b * (p.trial.t_s[i] - t0)),
        );
        start = end;
    }
    out
}

/// Candidate breathing frequencies outside trial j's fold, rad/s: the
/// [`PEAKS`] highest peaks of the other folds' summed periodograms (each
/// between bins by a parabola; a maximum at the band's edge is the flank
/// of something outside it, not a peak), and half of each that lies in
/// the band. The highest peak alone is not the breathing: a model whose
/// cutting switches on and off with the relative velocity leaves the
/// breathing's harmonics in the residual, and a second harmonic in the
/// motion itself (a sharper inhale) can outweigh the fundamental. The
/// model's own fit at each chooses ([`fit_shifts`]).
fn breathing_frequencies(spectra: &[Vec<f64>], j: usize, folds: usize) -> Vec<f64> {
    let mut sum = vec![0.0; spectra[0].len()];
    for (i, s) in spectra.iter().enumerate() {
        if i % folds != j % folds || spectra.len() == 1 {
            sum.iter_mut().zip(s).for_each(|(a, b)| *a += b);
        }
    }
    let mut peaks: Vec<usize> = (1..sum.len().saturating_sub(1))
        .filter(|&k| sum[k] > sum[k - 1] && sum[k] >= sum[k + 1])
        .collect();
    peaks.sort_by(|&a, &b| sum[b].total_cmp(&sum[a]));
    let mut hz: Vec<f64> = Vec::new();
    // Within two bins a candidate is the same breathing (a peak at twice
    // another's frequency has its half there).
    let mut push = |f: f64| {
        if f >= FREQ_FROM_HZ && hz.iter().all(|h| (h - f).abs() > 2.0 * FREQ_STEP_HZ) {
            hz.push(f);
        }
    };
    for k in peaks.into_iter().take(PEAKS) {
        let (l, c, r) = (sum[k - 1], sum[k], sum[k + 1]);
        let den = l - 2.0 * c + r;
        let offset = if den < 0.0 {
            (0.5 * (l - r) / den).clamp(-0.5, 0.5)
        } else {
            0.0
        };
        let f = FREQ_FROM_HZ + FREQ_STEP_HZ * (k as f64 + offset);
        push(f);
        push(f / 2.0);
    }
    // A flat or monotonic spectrum has no peak: the band's middle, which
    // the model's own fit then moves.
    if hz.is_empty() {
        hz.push(0.5 * (FREQ_FROM_HZ + FREQ_TO_HZ));
    }
    hz.into_iter().map(|f| TAU * f).collect()
}

/// Periodogram peaks tried as the breathing frequency.
const PEAKS: usize = 3;

/// Where LM starts: the best sinusoids of a grid of amplitudes and phases
/// at `omega`, one per amplitude, the [`STARTS`] best of those.
fn grid_starts(
    p: &Prepared,
    params: &TissueParams,
    omega: f64,
    samples: &[usize],
) -> Vec<TissueShift> {
    let t_ref_s = (p.trial.t_s[0] + p.trial.t_s[p.trial.len() - 1]) / 2.0;
    let mut harmonics = Harmonics::new();
    // The best phase moves little from one amplitude to the next.
    let mut guess = None;
    let mut per_amplitude: Vec<(f64, TissueShift)> =
        [0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0]
            .map(|a| a * 1e-3)
            .into_iter()
            .map(|amplitude_m| {
                let at_phase = |k: usize| {
                    let (s, c) = (TAU * k as f64 / GRID_PHASES as f64).sin_cos();
                    let shift = TissueShift {
                        omega_rad_s: omega,
                        t_ref_s,
                        coeffs_m: [amplitude_m * c, amplitude_m * s, 0.0, 0.0],
                        wander: PhaseWander::NONE,
                    };
                    // Squared: far from the displacement every sample is off
                    // by more than the noise, and Huber's loss would be an
                    // absolute one, which favours moving the tissue least.
                    let e: f64 = residuals(p, params, &shift, samples, &mut harmonics)
                        .iter()
                        .map(|e| e * e)
                        .sum();
                    (e, shift)
                };
                let (k, best) = least_phase(at_phase, guess);
                guess = Some(k);
                best
            })
            .collect();
    per_amplitude.sort_by(|a, b| a.0.total_cmp(&b.0));
    per_amplitude
        .into_iter()
        .take(STARTS)
        .map(|(_, s)| s)
        .collect()
}

/// Phases of the start grid: LM finds the phase between them.
const GRID_PHASES: usize = 16;

/// The grid phase of least error (`at_phase(k)`: its error and shift)
/// and its index, in a third of the sixteen evaluations: from `guess`
/// (the best at the amplitude before, which the next moves little from)
/// it walks downhill a phase at a time; with none, it tries every other
/// phase, then the two beside the best of those. Where the error over the
/// phase has one valley this is the least of all sixteen; where it has
/// two (friction flipping with the tissue's velocity can make a second)
/// it may be the other's bottom — a start for Levenberg–Marquardt, which
/// is given several.
fn least_phase(
    mut at_phase: impl FnMut(usize) -> (f64, TissueShift),
    guess: Option<usize>,
) -> (usize, (f64, TissueShift)) {
    let beside = |k: usize, by: usize| (k + by) % GRID_PHASES;
    let mut at = |k: usize| (k, at_phase(k));
    // The later of two only where strictly lower: ties keep the first.
    let lower = |a: (usize, (f64, TissueShift)), b: (usize, (f64, TissueShift))| {
        if b.1 .0 < a.1 .0 {
            b
        } else {
            a
        }
    };
    let Some(k0) = guess else {
        let first = at(0);
        let best = (2..GRID_PHASES).step_by(2).map(&mut at).fold(first, lower);
        let k = best.0;
        return [at(beside(k, 1)), at(beside(k, GRID_PHASES - 1))]
            .into_iter()
            .fold(best, lower);
    };
    let mut best = at(k0);
    let (up, down) = (at(beside(k0, 1)), at(beside(k0, GRID_PHASES - 1)));
    // Downhill the way the lower neighbour lies (up on a tie).
    let (mut next, by) = if down.1 .0 < up.1 .0 {
        (down, GRID_PHASES - 1)
    } else {
        (up, 1)
    };
    for _ in 0..GRID_PHASES {
        if next.1 .0 >= best.1 .0 {
            break;
        }
        best = next;
        next = at(beside(best.0, by));
    }
    best
}

/// Starts from the grid at one frequency (a round after the first, at
/// the frequency it found): the force is far from linear in the
/// displacement, and one start can stop at the wrong flip of friction.
const STARTS: usize = 3;
/// Starts from the grid at each of several candidate frequencies (the
/// first round).
const STARTS_PER_FREQUENCY: usize = 2;

/// Levenberg–Marquardt from `start` over its four coefficients, and its
/// frequency too when `free_omega`.
fn refine(
    p: &Prepared,
    params: &TissueParams,
    start: TissueShift,
    free_omega: bool,
    samples: &[usize],
    iterations: usize,
) -> (TissueShift, f64) {
    let unknowns = if free_omega { 5 } else { 4 };
    let with = |s: &TissueShift, k: usize, d: f64| {
        let mut s = *s;
        if k < 4 {
            s.coeffs_m[k] += d;
        } else {
            s.omega_rad_s += d;
        }
        s
    };
    // Steps that move the tissue about a micrometre.
    let step = |k: usize, s: &TissueShift| {
        if k < 4 {
            1e-6
        } else {
            let half_span_s = (p.trial.t_s[p.trial.len() - 1] - p.trial.t_s[0]) / 2.0;
            1e-6 / (s.amplitude_m().max(1e-4) * half_span_s.max(1.0))
        }
    };
    let corner_n = HUBER_CORNER_NOISE_SD * p.noise_n;
    let mut shift = start;
    let mut harmonics = Harmonics::new();
    let mut r = residuals(p, params, &shift, samples, &mut harmonics);
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let jac: Vec<Vec<f64>> = (0..unknowns)
            .map(|k| {
                let h = step(k, &shift);
                let rk = residuals(p, params, &with(&shift, k, h), samples, &mut harmonics);
                // d(model)/dθ = −d(residual)/dθ.
                rk.iter().zip(&r).map(|(a, b)| (b - a) / h).collect()
            })
            .collect();
        let mut normal = Lsq::<5>::default();
        for i in 0..r.len() {
            let w = huber_weight(r[i], corner_n).sqrt();
            let mut row = [0.0; 5];
            for (k, col) in jac.iter().enumerate() {
                row[k] = w * col[i];
            }
            normal.add(row, w * r[i]);
        }
        let loss = huber(&r, corner_n);
        let step = normal.damped_step(unknowns, &mut lambda, loss, |delta| {
            let mut next = shift;
            for (k, d) in delta.iter().enumerate().take(unknowns) {
                next = with(&next, k, *d);
            }
            let rn = residuals(p, params, &next, samples, &mut harmonics);
            let loss_next = huber(&rn, corner_n);
            ((next, rn), loss_next)
        });
        let Some(((next, rn), loss_next)) = step else {
            break;
        };
        (shift, r) = (next, rn);
        if 1.0 - loss_next / loss <= 1e-5 {
            break;
        }
    }
    let loss = huber(&r, corner_n);
    (shift, loss)
}

/// Levenberg–Marquardt over `shift`'s four coefficients and its phase's
/// departure at knots about a breath apart ([`PhaseWander`]), from the
/// departure `shift` has. A knot's Jacobian column is the model's
/// change with the whole phase (one evaluation) times the knot's share
/// at each sample: a breath's force depends on where the breath is then,
/// and little on the phase's rate, which a knot's change also moves
/// (the step is tried on the model itself, so an approximate column
/// costs iterations, not accuracy). Each knot's change from the last is
/// weighed against the data as what a period that varies from breath
/// to breath would give ([`BREATH_PERIOD_CV`]), and each knot against a
/// half turn from the steady phase (the coefficients' rotation does the
/// same as a shift of every knot, and the data cannot tell the two).
fn refine_wander(
    p: &Prepared,
    params: &TissueParams,
    shift: TissueShift,
    samples: &[usize],
) -> TissueShift {
    let (Some(&first), Some(&last)) = (samples.first(), samples.last()) else {
        return shift;
    };
    let period_s = TAU / shift.omega_rad_s.abs().max(1e-3);
    let t_s = &p.trial.t_s;
    let mut shift = TissueShift {
        wander: shift.wander.over(t_s[first], t_s[last], period_s),
        ..shift
    };
    let knots = shift.wander.knots;
    let unknowns = 4 + knots;
    let noise_n = p.noise_n.max(1e-6);
    let prior = WanderPrior::new(&shift.wander, noise_n, period_s);
    let corner_n = HUBER_CORNER_NOISE_SD * noise_n;
    let mut harmonics = Harmonics::new();
    let mut r = residuals(p, params, &shift, samples, &mut harmonics);
    let mut loss = huber(&r, corner_n) + prior.loss(&shift.wander);
    let mut lambda = 1e-3;
    for _ in 0..ITERATIONS {
        let column = |s: &TissueShift, h: f64, harmonics: &mut Harmonics| -> Vec<f64> {
            let rk = residuals(p, params, s, samples, harmonics);
            rk.iter().zip(&r).map(|(a, b)| (b - a) / h).collect()
        };
        let coeff_cols: Vec<Vec<f64>> = (0..4)
            .map(|k| {
                let mut s = shift;
                s.coeffs_m[k] += 1e-6;
                column(&s, 1e-6, &mut harmonics)
            })
            .collect();
        let whole_phase = {
            let mut s = shift;
            let h = 1e-6 / shift.amplitude_m().max(1e-4);
            s.wander.phase_rad[..knots].iter_mut().for_each(|p| *p += h);
            column(&s, h, &mut harmonics)
        };
        let mut normal = Lsq::<WANDER_UNKNOWNS>::default();
        for (n, &i) in samples.iter().enumerate() {
            let w = huber_weight(r[n], corner_n).sqrt();
            let mut row = [0.0; WANDER_UNKNOWNS];
            for (k, col) in coeff_cols.iter().enumerate() {
                row[k] = w * col[n];
            }
            for k in 0..knots {
                row[4 + k] = w * shift.wander.weight(k, t_s[i]) * whole_phase[n];
            }
            normal.add(row, w * r[n]);
        }
        for (row, y) in prior.rows(&shift.wander) {
            normal.add(row, y);
        }
        let step = normal.damped_step(unknowns, &mut lambda, loss, |delta| {
            let mut next = shift;
            for (k, d) in delta.iter().enumerate().take(unknowns) {
                if k < 4 {
                    next.coeffs_m[k] += d;
                } else {
                    next.wander.phase_rad[k - 4] += d;
                }
            }
            let rn = residuals(p, params, &next, samples, &mut harmonics);
            let loss_next = huber(&rn, corner_n) + prior.loss(&next.wander);
            ((next, rn), loss_next)
        });
        let Some(((next, rn), loss_next)) = step else {
            break;
        };
        let improved = 1.0 - loss_next / loss > 1e-5;
        (shift, r, loss) = (next, rn, loss_next);
        if !improved {
            break;
        }
    }
    shift
}

/// The unknowns of [`refine_wander`]: four coefficients, then the knots.
const WANDER_UNKNOWNS: usize = 4 + MAX_KNOTS;

/// What [`refine_wander`] weighs the knots against, as rows of its
/// normal equations: each knot's change from the last against the
/// spread of a breath's length ([`BREATH_PERIOD_CV`]), each knot against
/// half a turn; both in noise sd, so they add to the data's squares.
struct WanderPrior {
    step_scale: f64,
    level_scale: f64,
}

impl WanderPrior {
    fn new(wander: &PhaseWander, noise_n: f64, period_s: f64) -> Self {
        let step_sd_rad = TAU * BREATH_PERIOD_CV * (wander.step_s / period_s).sqrt();
        Self {
            step_scale: noise_n / step_sd_rad,
            level_scale: noise_n / std::f64::consts::PI,
        }
    }

    /// (row, residual) of each term at `w`: the residual is
    /// 0 − scale·(the term's combination of knots).
    fn rows(&self, w: &PhaseWander) -> Vec<([f64; WANDER_UNKNOWNS], f64)> {
        let knot = |k: usize| 4 + k;
        let steps = (1..w.knots).map(|k| {
            let mut row = [0.0; WANDER_UNKNOWNS];
            (row[knot(k)], row[knot(k - 1)]) = (self.step_scale, -self.step_scale);
            (
                row,
                -self.step_scale * (w.phase_rad[k] - w.phase_rad[k - 1]),
            )
        });
        let levels = (0..w.knots).map(|k| {
            let mut row = [0.0; WANDER_UNKNOWNS];
            row[knot(k)] = self.level_scale;
            (row, -self.level_scale * w.phase_rad[k])
        });
        steps.chain(levels).collect()
    }

    /// Its share of the loss at `w` (half the sum of squares).
    fn loss(&self, w: &PhaseWander) -> f64 {
        self.rows(w).iter().map(|(_, y)| 0.5 * y * y).sum()
    }
}

/// How much a breath's length differs from the last one's, as a share
/// of the period (one standard deviation): 10–30 % at rest in the
/// literature on breathing variability; the larger, so that the prior
/// holds only what the data leave open.
const BREATH_PERIOD_CV: f64 = 0.3;

/// Most Levenberg–Marquardt iterations of a fit, and of a scouting one
/// from each of several starts (the best of which is then fitted fully).
const ITERATIONS: usize = 20;
const SCOUT_ITERATIONS: usize = 5;

/// The displacement fitted from the best of `first` and `others`, with
/// its frequency: each is scouted for a few iterations, the best fitted.
fn best_of(
    p: &Prepared,
    params: &TissueParams,
    first: TissueShift,
    others: impl Iterator<Item = TissueShift>,
    samples: &[usize],
) -> TissueShift {
    let scout = |s: TissueShift| refine(p, params, s, true, samples, SCOUT_ITERATIONS);
    let (best, _) = others.fold(scout(first), |best, s| {
        let next = scout(s);
        if next.1 < best.1 {
            next
        } else {
            best
        }
    });
    refine(
        p,
        params,
        best,
        true,
        samples,
        ITERATIONS - SCOUT_ITERATIONS,
    )
    .0
}

/// The median of the values outside trial j's fold.
fn median_outside(values: &[f64], j: usize, folds: usize) -> f64 {
    let mut others: Vec<f64> = values
        .iter()
        .enumerate()
        .filter(|(i, _)| i % folds != j % folds)
        .map(|(_, v)| *v)
        .collect();
    others.sort_by(f64::total_cmp);
    others.get(others.len() / 2).copied().unwrap_or(values[j])
}

/// The tissue's displacement in every trial, cross-fitted: trial j's
/// frequency is the median of the other folds' own estimates (trial j in
/// fold j mod `folds`), its phase and shape its own. Each trial's own fit
/// is the best of several starts ([`best_of`]): the best sinusoids of a
/// grid at each of the other folds' candidate frequencies
/// ([`breathing_frequencies`]; or at `start`'s, a round before under
/// another nominal) and `start` itself. The force is
/// far from linear in the displacement: friction flips with the tissue's
/// velocity, and a local search from one start stops at the wrong flip
/// (at seed 11, two trials of ten at a fifth of the true amplitude).
pub fn fit_shifts(
    data: &[Prepared],
    params: &TissueParams,
    folds: usize,
    start: Option<&[TissueShift]>,
) -> Vec<TissueShift> {
    // The model's cutting is a shape here, its level each trial's own
    // ([`residuals`]): a nominal fitted in the encoder's frame whose cut
    // track the motion hid (cutting fitted as none) still cuts.
    let shape = TissueParams {
        cutting_force_n: params.cutting_force_n.max(CUTTING_PRIOR_N),
        ..*params
    };
    let params = &shape;
    let samples: Vec<Vec<usize>> = data.iter().map(fitted_samples).collect();
    let spectra: Vec<Vec<f64>> = match start {
        Some(_) => Vec::new(),
        None => data
            .iter()
            .map(|p| periodogram(p, &spectral_samples(p)))
            .collect(),
    };
    let own: Vec<TissueShift> = data
        .iter()
        .enumerate()
        .map(|(j, p)| {
            // Each round starts again from the grid as well as from the
            // round before: under a better nominal, a trial stuck at the
            // wrong flip of friction has a better start there.
            let omegas_rad_s = start.map_or_else(
                || breathing_frequencies(&spectra, j, folds),
                |s| vec![s[j].omega_rad_s],
            );
            let per_frequency = if omegas_rad_s.len() > 1 {
                STARTS_PER_FREQUENCY
            } else {
                STARTS
            };
            let mut grid = omegas_rad_s.iter().flat_map(|&w| {
                grid_starts(p, params, w, &samples[j])
                    .into_iter()
                    .take(per_frequency)
            });
            let first = match start {
                Some(s) => s[j],
                None => grid.next().unwrap_or(TissueShift {
                    omega_rad_s: omegas_rad_s[0],
                    t_ref_s: 0.0,
                    coeffs_m: [0.0; 4],
                    wander: PhaseWander::NONE,
                }),
            };
            best_of(p, params, first, grid, &samples[j])
        })
        .collect();
    let omegas: Vec<f64> = own.iter().map(|s| s.omega_rad_s).collect();
    data.iter()
        .enumerate()
        .map(|(j, p)| {
            let at_fold = TissueShift {
                omega_rad_s: median_outside(&omegas, j, folds),
                ..own[j]
            };
            let steady = refine(p, params, at_fold, false, &samples[j], ITERATIONS).0;
            refine_wander(p, params, steady, &samples[j])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The phase of least error is found from any guess where the error
    /// has one valley over the phase (walking either way round, across
    /// phase 0), and with no guess; where it has two, the walk stops at
    /// the bottom of the guess's own.
    #[test]
    fn the_least_phase_is_found_downhill_from_any_guess() {
        let shift = TissueShift {
            omega_rad_s: 1.0,
            t_ref_s: 0.0,
            coeffs_m: [0.0; 4],
            wander: PhaseWander::NONE,
        };
        let around = |k: usize, to: usize| {
            let d = (k as i64 - to as i64).rem_euclid(GRID_PHASES as i64);
            d.min(GRID_PHASES as i64 - d) as f64
        };
        for bottom in [0, 5, 11, 15] {
            let valley = |k: usize| (1.0 + around(k, bottom).powi(2), shift);
            for guess in [None, Some(0), Some(3), Some(8), Some(14)] {
                let (k, (e, _)) = least_phase(valley, guess);
                assert_eq!((k, e), (bottom, 1.0), "bottom {bottom}, guess {guess:?}");
            }
        }
        // Valleys at 2 (the deeper) and 10.
        let two = |k: usize| (around(k, 2).min(around(k, 10) + 0.5), shift);
        assert_eq!(least_phase(two, Some(9)).0, 10);
        assert_eq!(least_phase(two, Some(4)).0, 2);
        let evaluations = std::cell::Cell::new(0);
        let counted = |k: usize| {
            evaluations.set(evaluations.get() + 1);
            (around(k, 7), shift)
        };
        least_phase(counted, Some(6));
        assert!(evaluations.get() <= 5, "{}", evaluations.get());
    }

    /// The candidates are the highest peaks, each between bins by a
    /// parabola, and half of each (a fundamental whose second harmonic is
    /// the peak), never a maximum at the band's edge nor one candidate
    /// twice, and trial j's are the other folds' alone.
    #[test]
    fn breathing_candidates_are_the_peaks_and_their_halves() {
        let bins = periodogram_freqs_hz().count();
        let bin = |f_hz: f64| ((f_hz - FREQ_FROM_HZ) / FREQ_STEP_HZ).round() as usize;
        // Falling from the band's lowest bin (a trend's flank); a peak at
        // 0.44 Hz leaning towards the bin above, one at 0.22 Hz (its
        // half), and a lower one at 0.3 Hz.
        let mut spectrum: Vec<f64> = (0..bins).map(|k| 1e-3 / (1.0 + k as f64)).collect();
        spectrum[bin(0.44)] += 3.0;
        spectrum[bin(0.44) + 1] += 1.5;
        spectrum[bin(0.22)] += 2.0;
        spectrum[bin(0.3)] += 1.0;
        // Trial 0's own spectrum, in its own fold, peaks elsewhere.
        let mut own = vec![0.0; bins];
        own[bin(0.55)] = 100.0;
        let spectra = vec![own, spectrum.clone(), spectrum];
        let hz: Vec<f64> = breathing_frequencies(&spectra, 0, 3)
            .iter()
            .map(|w| w / TAU)
            .collect();
        // The parabola through 0, 3, 1.5 peaks a sixth of a bin above.
        let top_hz = 0.44 + FREQ_STEP_HZ / 6.0;
        assert!((hz[0] - top_hz).abs() < 1e-5, "the highest first: {hz:?}");
        let near = |f: f64| {
            hz.iter()
                .filter(|h| (*h - f).abs() < 2.0 * FREQ_STEP_HZ)
                .count()
        };
        assert_eq!(near(0.22), 1, "the half and the 0.22 Hz peak once: {hz:?}");
        for f in [0.11, 0.3, 0.15] {
            assert_eq!(near(f), 1, "{f}: {hz:?}");
        }
        assert_eq!(near(FREQ_FROM_HZ) + near(0.55), 0, "{hz:?}");
        assert_eq!(hz.len(), 5, "{hz:?}");
    }

    /// The departure is the knots' weighted sum everywhere (the wander's
    /// Jacobian columns rest on it), held beyond the end knots, and knots
    /// laid out again keep the departure where they fall.
    #[test]
    fn a_wander_is_linear_between_knots_and_laid_out_again_keeps_its_phase() {
        let mut w = PhaseWander {
            t0_s: 2.0,
            step_s: 4.0,
            knots: 4,
            ..PhaseWander::NONE
        };
        w.phase_rad[..4].copy_from_slice(&[0.5, -1.0, 2.0, 0.0]);
        for t in [0.0, 2.0, 3.0, 6.0, 9.5, 14.0, 20.0] {
            let summed: f64 = (0..w.knots).map(|k| w.weight(k, t) * w.phase_rad[k]).sum();
            assert!((summed - w.at(t).0).abs() < 1e-12, "at {t}");
        }
        assert_eq!(w.at(0.0), (0.5, 0.0));
        assert_eq!(w.at(30.0), (0.0, 0.0));
        assert!((w.at(4.0).0 + 0.25).abs() < 1e-12 && (w.at(4.0).1 + 0.375).abs() < 1e-12);
        assert!((w.steepest_rad_s() - 0.75).abs() < 1e-12);
        // Over 3–13 s at a 4 s breath: four knots 3⅓ s apart.
        let again = w.over(3.0, 13.0, 4.0);
        assert_eq!(again.knots, 4);
        for k in 0..again.knots {
            let t = again.t0_s + again.step_s * k as f64;
            assert!((again.phase_rad[k] - w.at(t).0).abs() < 1e-12, "knot {k}");
        }
        // More breaths than knots: the knots spread to reach.
        let long = PhaseWander::NONE.over(0.0, 310.0, 1.0);
        assert_eq!(long.knots, MAX_KNOTS);
        assert!((long.step_s - 10.0).abs() < 1e-12);
        assert_eq!(PhaseWander::NONE.at(5.0), (0.0, 0.0));
    }

    #[test]
    fn the_velocity_is_the_displacements_derivative() {
        let shift = TissueShift {
            omega_rad_s: TAU * 0.25,
            t_ref_s: 3.0,
            coeffs_m: [0.0012, -0.0004, 0.0003, 0.0001],
            wander: PhaseWander::NONE,
        };
        for t in [0.0, 1.3, 2.9, 7.7] {
            // The harmonics are those of the phase, the second by itself.
            let th = shift.omega_rad_s * (t - shift.t_ref_s);
            let (s2, c2) = (2.0 * th).sin_cos();
            let h2 = harmonics(th);
            assert!((h2[2] - s2).abs() < 1e-12 && (h2[3] - c2).abs() < 1e-12);
            let h = 1e-6;
            let numeric = (shift.at(t + h).0 - shift.at(t - h).0) / (2.0 * h);
            assert!((numeric - shift.at(t).1).abs() < 1e-9, "at {t}");
        }
        // The kept harmonics give the same displacement as computed afresh,
        // for either of the last two frequencies asked.
        let t_s: Vec<f64> = (0..50).map(|i| i as f64 * 0.2).collect();
        let other = TissueShift {
            omega_rad_s: 1.1,
            ..shift
        };
        let mut kept = Harmonics::new();
        for s in [shift, other, shift, other] {
            let h = kept.follow(&s, &t_s).to_vec();
            for (i, &t) in t_s.iter().enumerate() {
                let (a, b) = (s.at_harmonics(h[i]), s.at(t));
                assert!((a.0 - b.0).abs() < 1e-15 && (a.1 - b.1).abs() < 1e-15);
            }
        }
        assert_eq!(kept.kept.len(), 2);
        // A phase that wanders: the velocity is still the derivative,
        // between knots and beyond them.
        let mut wander = PhaseWander {
            t0_s: 1.0,
            step_s: 2.5,
            knots: 3,
            ..PhaseWander::NONE
        };
        wander.phase_rad[..3].copy_from_slice(&[0.4, -0.8, 0.3]);
        let wandering = TissueShift { wander, ..shift };
        for t in [0.2, 1.7, 3.1, 4.9, 7.3] {
            let h = 1e-6;
            let numeric = (wandering.at(t + h).0 - wandering.at(t - h).0) / (2.0 * h);
            assert!(
                (numeric - wandering.at(t).1).abs() < 1e-9,
                "wandering, at {t}"
            );
        }
        // A pure sine of 1.2 mm has that half peak-to-peak amplitude.
        let sine = TissueShift {
            coeffs_m: [0.0012, 0.0, 0.0, 0.0],
            ..shift
        };
        assert!((sine.amplitude_m() - 0.0012).abs() < 1e-6);
    }
}
