//! `needle simulate`: trials of the paper's protocol with known truth, the
//! unmodelled effects of [`effects`] switchable, and firmware replays.
//!
//! The force law is the core's `f64` reference model
//! (`needle_holder::model::reference`) driven by the true geometry, plus
//! whatever effects are on, plus sensor noise and encoder quantisation.

pub mod effects;
mod forces;
pub mod motion;
mod needle;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use needle_holder::calibration::{Encoder, LoadCell};
use needle_holder::replay::{Record, ReplayHeader};
use needle_holder::units::{MicroNewtons, Nanometres};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use self::effects::{Effect, DEPTH_CUTTING_G_PER_M};
use self::forces::Kinematics;
use self::motion::Segment;
use self::needle::Needle;
pub use needle_holder::model::params::TissueParams;
use needle_io::trial::Trial;

/// Which physical form the effects take: the one documented in
/// [`effects`], or another form of the same physics, so that the
/// diagnosis is tested on data from a simulator it was not written against.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Form {
    #[default]
    Standard,
    Alternate,
    /// Forms from the literature, kept out of the diagnosis's tuning
    /// (written after it, and only measured) but for three written with
    /// the candidate column that looks for them (*Simulating and fitting* in
    /// the book): relaxation, cutting's reload and the mount. Fung's
    /// quasi-linear viscoelasticity acting on every force the tissue
    /// exerts, in motion as at rest, with a box spectrum (five branches,
    /// 0.05–20 s),
    /// Stribeck friction (a low-speed boost falling off by 0.5 mm/s), Dahl
    /// presliding with his exponent 2, walls stiffening exponentially
    /// (Fung's collagen), cutting growing with the square root of depth
    /// and loaded again over the first millimetres past the puncture, a
    /// load cell reading the holder's inertia and the tissue's force
    /// through a mount ringing at 25 Hz, a drift that accelerates as a
    /// bridge warms up, breathing whose period wanders by ±20 %.
    Literature,
}

/// Sensor realism.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Sensor {
    pub rate_hz: f64,
    /// Force noise, N (standard deviation, white).
    pub noise_n: f64,
    /// Encoder resolution, m (positions are whole counts).
    pub encoder_m: f64,
}

/// What one trial does: where the surface is and how the robot moves.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Protocol {
    pub surface_x_m: f64,
    /// Far side of the tissue sample, if the needle goes through it into
    /// air (the paper's "control tissue", §4.3): no cutting beyond it, and
    /// no more needle in tissue.
    pub far_surface_x_m: Option<f64>,
    pub segments: Vec<Segment>,
    /// Membranes below the capsule (skin on muscle, a vessel wall): each
    /// loads and gives way like the capsule, a sharp drop mid-insertion.
    pub layers: Vec<Layer>,
    /// How far before the contact point the withdrawing needle lets go of
    /// the tissue, m: the tissue is drawn out with the needle, so the
    /// withdrawal friction acts over the needle from a surface dragged
    /// there (book, *What real recordings look like*: zero force
    /// 1.5–9 mm before first contact).
    /// 0: it lets go at x_s3, as the paper's model has it.
    pub drag_m: f64,
    /// Stiffness of the tissue round the shaft, N/m: a needle that starts
    /// back after a rest of a second or more drags it along as an elastic
    /// tent, the force going from what the rest held towards the static
    /// band's pull D_n·l at this rate per metre of travel; there the
    /// tissue slips and the force snaps back to kinetic friction. 0: no
    /// tent (the paper's model: the band gives way at once).
    pub tent_n_per_m: f64,
    /// Residual tare offset of the load cell, N.
    pub tare_n: f64,
    /// The cutting force's factor along this trial's path, one every
    /// [`WANDER_STEP_M`] of depth past the surface (linear between; the
    /// last beyond): a heterogeneous tissue, whose cutting force wanders
    /// along each needle's path in its own way. Empty: no wander.
    pub cutting_wander: Vec<f64>,
    /// How far past its peak the capsule tears, m: a wall with no sharp
    /// fall (a 3 mm artery's force rolls over and eases off over 1–2.5
    /// mm; book, *What real recordings look like*) carries less of its
    /// peak force the further the tip pushes through it
    /// ([`tearing_share`]). 0: it gives way at once, the paper's
    /// puncture.
    pub tear_m: f64,
    /// Sample times, s (a rig's jittered clock with gaps); `None`: every
    /// 1/rate from 0.
    #[serde(skip)]
    pub times_s: Option<Vec<f64>>,
}

/// Depth between the knots of [`Protocol::cutting_wander`], m.
pub const WANDER_STEP_M: f64 = 0.0005;

/// The share of its peak force a capsule tearing over `tear_m` still
/// carries with the tip `past_m` beyond where it peaked: cos², so the
/// force flattens at the peak and rolls over, easing off to the force
/// inside the tissue by `tear_m` (none for a wall that gives way at once).
pub fn tearing_share(past_m: f64, tear_m: f64) -> f64 {
    if tear_m <= 0.0 || past_m >= tear_m {
        return 0.0;
    }
    (std::f64::consts::FRAC_PI_2 * past_m.max(0.0) / tear_m)
        .cos()
        .powi(2)
}

impl Protocol {
    /// [`Self::cutting_wander`]'s factor `depth_m` past the surface (1
    /// without one).
    pub fn cutting_factor(&self, depth_m: f64) -> f64 {
        let w = &self.cutting_wander;
        let Some(&last) = w.last() else {
            return 1.0;
        };
        let at = (depth_m / WANDER_STEP_M).max(0.0);
        let k = at.floor() as usize;
        match (w.get(k), w.get(k + 1)) {
            (Some(a), Some(b)) => a + (b - a) * (at - k as f64),
            _ => last,
        }
    }
}

/// A cutting force's wander along `reach_m` of a path through a
/// heterogeneous tissue: a random walk of its logarithm, 3 % per √mm
/// (16 % over 30 mm) times `size` (the effect's size, at least 1: `=2`
/// on the command line doubles it, `=0` leaves the wander without the
/// trend), from 1 at the surface.
fn cutting_wander(reach_m: f64, size: f64, rng: &mut impl Rng) -> Vec<f64> {
    let steps = (reach_m.max(0.0) / WANDER_STEP_M).ceil() as usize + 4;
    let sd = 0.03 * size.max(0.0) * (WANDER_STEP_M * 1e3).sqrt();
    let step = Normal::new(0.0, sd).expect("a finite, non-negative sd");
    let mut log_factor = 0.0;
    (0..=steps)
        .map(|k| {
            if k > 0 {
                log_factor += step.sample(rng);
            }
            f64::exp(log_factor)
        })
        .collect()
}

/// A membrane inside the tissue.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Layer {
    /// Depth of the membrane past the tissue surface (tissue frame), m.
    pub depth_m: f64,
    /// Its stiffness while it is pushed ahead of the tip, N/m.
    pub k_n_per_m: f64,
    /// The force at which it gives way, N.
    pub rupture_n: f64,
}

/// Which motion the robot runs in each trial.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ProtocolKind {
    /// The paper's: approach, puncture, insert, dwell, oscillate inside
    /// the tissue (reversals), dwell, withdraw.
    #[default]
    Paper,
    /// The field's commonest: insert 25 mm past the surface at 1, 2 or
    /// 3 mm/s from a stage 2–15 mm before it, hold 5 s, withdraw. No
    /// oscillation; the tissue is dragged out on withdrawal.
    InsertDwellWithdraw,
}

/// How the rig records, beyond the sensor's noise and resolution.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Rig {
    pub protocol: ProtocolKind,
    /// Membranes below the capsule in each trial (each trial draws
    /// 0..=layers of them).
    pub layers: u32,
    /// Jittered sample times (sd 10 % of the period) and gaps of up to
    /// 70 ms.
    pub jitter: bool,
    /// Standard deviation of each trial's residual tare offset, N.
    pub tare_sd_n: f64,
    /// Trial-to-trial spread of the tissue, as a coefficient of variation:
    /// each trial's stiffness (so its puncture force), cutting force and
    /// friction are the tissue's times 1 + spread·z, its puncture depth
    /// times 1 + spread/2·z (independent normal z, factors within
    /// 0.3–2), and so are the tissue's effects ([`vary_effects`]). Real
    /// tissue is never the same twice: the paper's 19 insertions have a
    /// puncture force of 2.30 ± 0.83 N (36 %), cutting 0.94 ± 0.36 N;
    /// phantoms 7–13 % on the peak, 9–20 % after it, their hold relaxing
    /// 32–47 %.
    pub spread: f64,
    /// How far past its peak each trial's capsule tears, m (each trial
    /// 0.5–1.5 times it; [`Protocol::tear_m`]); 0: a sharp fall.
    pub tear_m: f64,
    /// The stage's acceleration, m/s²: every move reaches and sheds its
    /// speed at it, as a real drive's trapezoidal profile does (0.05 m/s²
    /// ramps 1–3 mm/s over 20–60 ms, a sample to six at 100 Hz); 0: the
    /// speed changes at once.
    pub accel_mps2: f64,
}

/// A ground-truth event. For a puncture or a structure, `t_s` is the
/// first sample at which the force has fallen and `peak_t_s` the sample
/// of the peak before it (a detector can know of a rupture only once the
/// force falls, and must not report one before the peak); for a contact
/// or an exit both are the event's sample.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TruthEvent {
    pub kind: &'static str,
    pub t_s: f64,
    pub peak_t_s: f64,
    pub x_m: f64,
}

/// Ground truth of one simulated trial.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrialTruth {
    pub protocol: Protocol,
    /// x_s2, where the capsule gave way (needle position), m.
    pub puncture_x_m: Option<f64>,
    /// Peak force at puncture, N.
    pub puncture_force_n: Option<f64>,
    /// x_s3, the relaxed surface, m (tissue frame).
    pub relaxed_surface_x_m: Option<f64>,
    /// Vessel walls: depth (tissue frame, m) and rupture force (N).
    pub structures: Vec<(f64, f64)>,
    pub events: Vec<TruthEvent>,
}

/// The paper's protocol with variety: approach, puncture, insertion to
/// depth, dwell, retract by the oscillation amplitude, oscillate (reversals)
/// up to the deepest point without cutting, dwell, withdraw, rest outside.
pub fn random_protocol(rng: &mut impl Rng) -> Protocol {
    let surface = rng.gen_range(0.003..0.008);
    let speed = rng.gen_range(0.002..0.006);
    let deepest = surface + rng.gen_range(0.025..0.040);
    let amplitude = rng.gen_range(0.002..0.004);
    let freq = rng.gen_range(0.2..1.2);
    let cycles = if rng.gen_bool(0.5) { 2.0 } else { 2.5 };
    Protocol {
        far_surface_x_m: None,
        layers: Vec::new(),
        drag_m: 0.0,
        tent_n_per_m: 0.0,
        tare_n: 0.0,
        cutting_wander: Vec::new(),
        tear_m: 0.0,
        times_s: None,
        surface_x_m: surface,
        segments: vec![
            Segment::Move {
                to_m: deepest,
                speed_mps: speed,
                accel_mps2: 0.0,
            },
            Segment::Dwell {
                duration_s: rng.gen_range(1.0..2.0),
            },
            Segment::Move {
                to_m: deepest - amplitude,
                speed_mps: speed,
                accel_mps2: 0.0,
            },
            Segment::Oscillate {
                amplitude_m: amplitude,
                freq_hz: freq,
                cycles,
                from_rest: false,
            },
            Segment::Dwell { duration_s: 1.0 },
            Segment::Move {
                to_m: 0.0,
                speed_mps: speed,
                accel_mps2: 0.0,
            },
            Segment::Dwell { duration_s: 0.5 },
        ],
    }
}

/// Insert–dwell–withdraw as real rigs run it (book, *What real recordings
/// look like*): the stage starts 2–15 mm before the surface, inserts 25 mm
/// past it at 1, 2 or 3 mm/s, holds 5 s and withdraws; the tissue lets go of
/// the withdrawing needle 1.5–9 mm before the contact point; up to
/// `max_layers` membranes (`draw_layers`).
pub fn insert_dwell_withdraw(
    tissue: &TissueParams,
    max_layers: u32,
    rng: &mut impl Rng,
) -> Protocol {
    let surface = rng.gen_range(0.002..0.015);
    let speed = [0.001, 0.002, 0.003][rng.gen_range(0..3)];
    let deepest = surface + 0.025;
    let layers = draw_layers(tissue, max_layers, 0.025, rng);
    Protocol {
        surface_x_m: surface,
        far_surface_x_m: None,
        segments: vec![
            Segment::Move {
                to_m: deepest,
                speed_mps: speed,
                accel_mps2: 0.0,
            },
            Segment::Dwell { duration_s: 5.0 },
            Segment::Move {
                to_m: 0.0,
                speed_mps: speed,
                accel_mps2: 0.0,
            },
            Segment::Dwell { duration_s: 0.5 },
        ],
        layers,
        // The tissue lets go before the stage is back at 0: a rig
        // withdraws until the force is back to zero.
        drag_m: rng.gen_range(0.0015..0.009_f64.min(surface - 0.0005).max(0.0016)),
        // Of the order of the capsule's own stiffness at puncture.
        tent_n_per_m: rng.gen_range(250.0..600.0),
        tare_n: 0.0,
        cutting_wander: Vec::new(),
        tear_m: 0.0,
        times_s: None,
    }
}

/// Up to `max_layers` membranes between 4 mm past the capsule's puncture
/// and 2 mm short of `reach_m` past the surface, each giving way at
/// 30–90 % of the capsule's puncture force after 2–5 mm of stretch, each
/// clear of the next one's stretch by 1 mm.
fn draw_layers(
    tissue: &TissueParams,
    max_layers: u32,
    reach_m: f64,
    rng: &mut impl Rng,
) -> Vec<Layer> {
    let mut layers: Vec<Layer> = Vec::new();
    let (lo, hi) = (tissue.puncture_depth_m + 0.004, reach_m - 0.002);
    if hi <= lo {
        return layers;
    }
    for _ in 0..rng.gen_range(0..=max_layers) {
        for _attempt in 0..20 {
            let rupture_n = tissue.puncture_force_n * rng.gen_range(0.3..0.9);
            let stretch_m = rng.gen_range(0.002..0.005);
            let depth_m = rng.gen_range(lo..hi);
            let clear = layers.iter().all(|o| {
                depth_m > o.depth_m + o.rupture_n / o.k_n_per_m + WALL_GAP_M
                    || o.depth_m > depth_m + stretch_m + WALL_GAP_M
            });
            if clear && depth_m + stretch_m < reach_m {
                layers.push(Layer {
                    depth_m,
                    k_n_per_m: rupture_n / stretch_m,
                    rupture_n,
                });
                break;
            }
        }
    }
    layers.sort_by(|a, b| a.depth_m.total_cmp(&b.depth_m));
    layers
}

/// A rig's sample clock at `rate_hz` over `duration_s`: each period off by
/// a normal 10 % (clipped to ±30 %), and now and then (one sample in 500)
/// a gap of up to 70 ms where samples were lost.
pub fn jittered_times(rate_hz: f64, duration_s: f64, rng: &mut impl Rng) -> Vec<f64> {
    let dt = 1.0 / rate_hz;
    let spread: Normal<f64> = Normal::new(0.0, 0.1).expect("constant sd");
    let mut times = vec![0.0];
    let mut t = 0.0;
    loop {
        t += dt * (1.0 + spread.sample(rng).clamp(-0.3, 0.3));
        if rng.gen_bool(0.002) {
            t += rng.gen_range(0.0..(0.07 - dt).max(dt));
        }
        if t > duration_s {
            break;
        }
        times.push(t);
    }
    times
}

/// Least distance between one wall's rupture and the next wall (m).
const WALL_GAP_M: f64 = 0.001;

/// Simulate one trial of `protocol` in `tissue` with `effects` in their
/// standard form.
pub fn simulate_trial(
    tissue: &TissueParams,
    protocol: &Protocol,
    effects: &[Effect],
    sensor: &Sensor,
    rng: &mut impl Rng,
) -> (Trial, TrialTruth) {
    simulate_trial_in(tissue, protocol, effects, Form::Standard, sensor, rng)
}

/// Simulate one trial with the effects in `form`.
pub fn simulate_trial_in(
    tissue: &TissueParams,
    protocol: &Protocol,
    effects: &[Effect],
    form: Form,
    sensor: &Sensor,
    rng: &mut impl Rng,
) -> (Trial, TrialTruth) {
    // Breathing does not start with the trial (alternate form).
    let breath_phase = if form != Form::Standard {
        rng.gen_range(0.0..std::f64::consts::TAU)
    } else {
        0.0
    };
    let m = match &protocol.times_s {
        Some(times) => motion::sample_at(&protocol.segments, 0.0, times),
        None => motion::sample(&protocol.segments, 0.0, sensor.rate_hz),
    };
    let noise = Normal::new(0.0, sensor.noise_n.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).unwrap());
    let cell = needle_holder::calibration::LoadCell::TEN_NEWTON_24_BIT;
    let full_scale_n = cell.force(cell.full_scale_counts).as_n();
    let deepest_planned = m.x_m.iter().copied().fold(0.0, f64::max);
    let mut structures = place_walls(tissue, protocol, effects, deepest_planned, rng);
    structures.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut truth = TrialTruth {
        protocol: protocol.clone(),
        puncture_x_m: None,
        puncture_force_n: None,
        relaxed_surface_x_m: None,
        structures,
        events: Vec::new(),
    };
    let mut needle = Needle::new(tissue, protocol, (effects, form), truth.structures.len());
    let mut trial = Trial::default();
    for i in 0..m.t_s.len() {
        let (t, x, v, a) = (m.t_s[i], m.x_m[i], m.v_mps[i], m.a_mps2[i]);
        let dt = if i == 0 {
            1.0 / sensor.rate_hz
        } else {
            t - m.t_s[i - 1]
        };
        // Position and velocity relative to the tissue.
        let (mut p, mut vr) = (x, v);
        forces::move_with_tissue(effects, form, breath_phase, t, (&mut p, &mut vr));
        let k = Kinematics {
            t_s: t,
            dt_s: dt,
            vr_mps: vr,
            a_mps2: a,
        };
        let f = needle.step(&k, x, p, &mut truth);
        let x_counts = (x / sensor.encoder_m).round() * sensor.encoder_m;
        // The load cell reads no more than its full scale: the trial's
        // replay says saturated there.
        let measured_n = (f + noise.sample(rng)).clamp(-full_scale_n, full_scale_n);
        trial.push(t, x_counts, measured_n);
    }
    (trial, truth)
}

/// Where the interior walls sit and the force each gives way at
/// (`(depth, rupture)`, unsorted), drawn for one trial: between 3 mm past
/// the puncture and 2 mm before the far surface or the deepest point.
fn place_walls(
    tissue: &TissueParams,
    protocol: &Protocol,
    effects: &[Effect],
    deepest_planned: f64,
    rng: &mut impl Rng,
) -> Vec<(f64, f64)> {
    let s1 = protocol.surface_x_m;
    let mut walls: Vec<(f64, f64)> = Vec::new();
    for effect in effects {
        if let Effect::InternalStructures {
            max_count,
            k_n_per_m,
            rupture_min_n,
            rupture_max_n,
        } = *effect
        {
            let lo = s1 + tissue.puncture_depth_m + 0.003;
            let hi = protocol.far_surface_x_m.unwrap_or(deepest_planned) - 0.002;
            // Walls do not overlap: each is clear of the others by
            // WALL_GAP_M beyond the travel it takes to rupture. Two walls
            // loading together are one force bump, to a detector and to
            // anyone reading the trace, so they would not be two events.
            let reach = |(depth, rupture): (f64, f64)| depth + rupture / k_n_per_m.max(1.0);
            if hi > lo {
                for _ in 0..rng.gen_range(1..=max_count.max(1)) {
                    for _attempt in 0..20 {
                        let rupture =
                            rng.gen_range(rupture_min_n..=rupture_max_n.max(rupture_min_n));
                        let wall = (rng.gen_range(lo..hi), rupture);
                        let clear = walls.iter().all(|&other| {
                            wall.0 > reach(other) + WALL_GAP_M || other.0 > reach(wall) + WALL_GAP_M
                        });
                        if clear {
                            walls.push(wall);
                            break;
                        }
                    }
                }
            }
        }
    }
    walls
}

/// Karnopp friction with the rate-dependent damping effect applied.
fn friction_target(
    tissue: &TissueParams,
    effects: &[Effect],
    form: Form,
    v: f64,
    l: f64,
    last: &mut f64,
) -> f64 {
    let mut p = *tissue;
    for effect in effects {
        if let Effect::RateDependentFriction {
            exponent,
            v_ref_mps,
        } = *effect
        {
            let speed = v.abs().max(tissue.half_band_mps);
            if form == Form::Literature {
                // Stribeck: sliding friction boosted at low speed, the
                // boost falling off by 0.5 mm/s (20 N/m at strength 1).
                let boost = 20.0 * (1.0 - exponent) / 0.5 * (-(speed / 0.0005).powi(2)).exp();
                p.cp_n_per_m += boost;
                p.cn_n_per_m -= boost;
                continue;
            }
            let scale = if form == Form::Alternate {
                // Logarithmic strengthening, as strong as the power law.
                let s = (1.0 - exponent) / 0.5;
                (1.0 - s) + s * v_ref_mps * (1.0 + speed / v_ref_mps).ln() / speed
            } else {
                (speed / v_ref_mps).powf(exponent - 1.0)
            };
            p.bp_ns_per_m2 *= scale;
            p.bn_ns_per_m2 *= scale;
        }
    }
    let (f, new_last) = p.friction_n(v, l, *last);
    *last = new_last;
    f
}

/// The motion of one trial of the paper's plain protocol.
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

/// Ground truth of a plain insertion.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Truth {
    pub contact_t_s: f64,
    pub contact_x_m: f64,
    pub puncture_t_s: f64,
    pub puncture_x_m: f64,
    pub puncture_force_n: f64,
}

/// One plain insertion (in at constant speed, dwell, out), no effects.
pub fn insertion(tissue: &TissueParams, plan: &Plan) -> (Trial, Truth) {
    let deepest = plan.surface_x_m + plan.depth_m;
    let protocol = Protocol {
        surface_x_m: plan.surface_x_m,
        far_surface_x_m: None,
        layers: Vec::new(),
        drag_m: 0.0,
        tent_n_per_m: 0.0,
        tare_n: 0.0,
        cutting_wander: Vec::new(),
        tear_m: 0.0,
        times_s: None,
        segments: vec![
            Segment::Move {
                to_m: deepest,
                speed_mps: plan.speed_mps,
                accel_mps2: 0.0,
            },
            Segment::Dwell {
                duration_s: plan.dwell_s,
            },
            Segment::Move {
                to_m: 0.0,
                speed_mps: plan.speed_mps,
                accel_mps2: 0.0,
            },
        ],
    };
    let sensor = Sensor {
        rate_hz: plan.rate_hz,
        noise_n: plan.noise_n,
        encoder_m: 1e-9,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(plan.seed);
    let (trial, full) = simulate_trial(tissue, &protocol, &[], &sensor, &mut rng);
    let event = |kind| full.events.iter().find(|e| e.kind == kind);
    let truth = Truth {
        contact_t_s: event("contact").map_or(0.0, |e| e.t_s),
        contact_x_m: event("contact").map_or(0.0, |e| e.x_m),
        puncture_t_s: event("puncture").map_or(0.0, |e| e.peak_t_s),
        puncture_x_m: full.puncture_x_m.unwrap_or(0.0),
        puncture_force_n: full.puncture_force_n.unwrap_or(0.0),
    };
    (trial, truth)
}

/// `needle simulate` options.
#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Directory for the trial CSVs, replays and truth.json.
    #[arg(long)]
    pub out: std::path::PathBuf,
    /// Tissue from the library (default liver1).
    #[arg(long)]
    pub tissue: Option<String>,
    /// Tissue library file to take the tissue from.
    #[arg(long)]
    pub params: Option<std::path::PathBuf>,
    /// Unmodelled effects to add, comma-separated, optionally `name=strength`.
    #[arg(long, default_value = "")]
    pub effects: String,
    #[arg(long, default_value_t = 10)]
    pub trials: usize,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, default_value_t = 500.0)]
    pub rate_hz: f64,
    /// Force noise standard deviation, N.
    #[arg(long, default_value_t = 0.002)]
    pub noise_n: f64,
    /// Form of the effects: `standard` (documented in sim/effects.rs) or
    /// `alternate` (another form of the same physics, same place).
    #[arg(long, value_enum, default_value_t = Form::Standard)]
    pub effect_form: Form,
    /// The needle goes through the sample: its far side lies 8 mm past the
    /// puncture depth or deeper, 4 mm short of the deepest point at most.
    #[arg(long)]
    pub through: bool,
    /// Motion of each trial: `paper` (with oscillation) or
    /// `insert-dwell-withdraw` (the field's commonest; tissue dragged out
    /// on withdrawal).
    #[arg(long, value_enum, default_value_t = ProtocolKind::Paper)]
    pub protocol: ProtocolKind,
    /// Membranes below the capsule: each trial draws 0 to this many.
    #[arg(long, default_value_t = 0)]
    pub layers: u32,
    /// Jittered sample times (10 % of the period) and gaps of up to 70 ms.
    #[arg(long)]
    pub jitter: bool,
    /// Standard deviation of each trial's residual tare offset, N.
    #[arg(long, default_value_t = 0.0)]
    pub tare_n: f64,
    /// Trial-to-trial spread of the tissue (coefficient of variation of
    /// its stiffness, cutting and friction, and of its effects' sizes;
    /// half of it on the puncture depth), within 0..=0.5.
    #[arg(long, default_value_t = 0.0)]
    pub spread: f64,
    /// The capsule tears over this many mm past its peak instead of
    /// falling at once (each trial 0.5–1.5 times it): its force rolls over
    /// and eases off, as a 3 mm artery's does over 1–2.5 mm; 0 to 5.
    #[arg(long, default_value_t = 0.0)]
    pub tear_mm: f64,
    /// The stage's acceleration, m/s²: each move ramps its speed up and
    /// down at it (a real drive's trapezoid); 0 (the default) changes
    /// speed at once; else 0.005 to 10.
    #[arg(long, default_value_t = 0.0)]
    pub accel_mps2: f64,
}

#[derive(Serialize)]
struct TruthFile<'a> {
    tissue: &'a str,
    params: &'a TissueParams,
    effects: &'a [Effect],
    effect_form: Form,
    seed: u64,
    sensor: Sensor,
    rig: Rig,
    trials: Vec<TruthTrial<'a>>,
}

#[derive(Serialize)]
struct TruthTrial<'a> {
    file: String,
    replay: String,
    /// Sizes as written: a file of another size is not the simulation's
    /// any more (a user's trial copied over it), and is never replaced.
    file_bytes: u64,
    replay_bytes: u64,
    /// The effects as this trial met them ([`vary_effects`]).
    effects: &'a [Effect],
    #[serde(flatten)]
    truth: &'a TrialTruth,
}

/// A `truth.json` as far as it says which files a simulation wrote: it is
/// one of ours only if it reads as one (a hand-written truth for scoring
/// real trials is not).
#[derive(serde::Deserialize)]
struct Written {
    // Read only to tell ours from a hand-written truth, which has neither.
    #[serde(rename = "seed")]
    _seed: u64,
    #[serde(rename = "sensor")]
    _sensor: serde_json::Value,
    trials: Vec<WrittenTrial>,
}

#[derive(serde::Deserialize)]
struct WrittenTrial {
    file: String,
    replay: String,
    /// Absent from a truth.json of before the sizes were kept.
    file_bytes: Option<u64>,
    replay_bytes: Option<u64>,
}

/// Whether `name` is one a simulation writes (`trial_NNN.csv`,
/// `trial_NNN.replay`, `truth.json`).
fn simulation_name(name: &str) -> bool {
    let stem = name
        .strip_suffix(".csv")
        .or_else(|| name.strip_suffix(".replay"))
        .and_then(|n| n.strip_prefix("trial_"));
    name == "truth.json"
        || stem.is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
}

/// The files of an earlier simulation in `dir`, which the new one of
/// `trials` trials replaces: those its `truth.json` lists, and that file
/// (so no stale trial from another seed or count stays beside the new
/// ones: a second run with fewer trials left the rest, and `fit` mixed two
/// seeds). Nothing else is ever deleted or written over: trials no
/// simulation listed (they would mix with the new ones), or a file of a
/// name the new one writes that no simulation wrote, and the directory is
/// refused.
fn previous_simulation(dir: &Path, trials: usize) -> Result<Vec<PathBuf>> {
    let truth = dir.join("truth.json");
    let written: Option<Written> = truth
        .is_file()
        .then(|| needle_io::input::read_small_text(&truth).ok())
        .flatten()
        .and_then(|text| serde_json::from_str(&text).ok());
    // Each listed file with the size it was written at, if kept.
    let mut listed: std::collections::BTreeMap<String, Option<u64>> = written
        .iter()
        .flat_map(|w| &w.trials)
        .flat_map(|t| {
            [
                (t.file.clone(), t.file_bytes),
                (t.replay.clone(), t.replay_bytes),
            ]
        })
        .filter(|(n, _)| simulation_name(n))
        .collect();
    if written.is_some() {
        listed.insert("truth.json".into(), None);
    }
    // A listed file changed since (another size, or newer than the
    // truth.json written after it) is someone's now, not the simulation's.
    let truth_time = std::fs::metadata(&truth).and_then(|m| m.modified()).ok();
    listed.retain(|name, bytes| {
        let Ok(meta) = std::fs::symlink_metadata(dir.join(name.as_str())) else {
            return true;
        };
        let newer = matches!((meta.modified(), truth_time), (Ok(t), Some(truth)) if t > truth);
        let resized = bytes.is_some_and(|b| b != meta.len());
        name == "truth.json" || !(newer || resized)
    });
    let refuse = |path: &Path, what: &str| {
        anyhow::anyhow!(
            "{}: holds {what} ({}); simulate into another directory",
            dir.display(),
            path.display()
        )
    };
    for entry in
        std::fs::read_dir(dir).with_context(|| format!("{}: cannot list", dir.display()))?
    {
        let path = entry?.path();
        let name = needle_io::trial::name_of(&path);
        if needle_io::trial::is_trial_csv(&path) && !listed.contains_key(&name) {
            return Err(refuse(&path, "trials that are not a simulation's"));
        }
    }
    let new_names = (0..trials)
        .flat_map(|k| [format!("trial_{k:03}.csv"), format!("trial_{k:03}.replay")])
        .chain(std::iter::once("truth.json".to_owned()));
    for name in new_names {
        let path = dir.join(&name);
        if path.exists() && !listed.contains_key(&name) {
            return Err(refuse(
                &path,
                "a file the simulation would write over that no simulation wrote",
            ));
        }
    }
    Ok(listed
        .keys()
        .map(|n| dir.join(n))
        .filter(|p| p.is_file())
        .collect())
}

/// A staging directory left by a stopped run is removed only when all it
/// holds is what a simulation writes.
fn clear_staging(staging: &Path) -> Result<()> {
    if staging.is_symlink() {
        return std::fs::remove_file(staging)
            .with_context(|| format!("{}: cannot remove", staging.display()));
    }
    if !staging.exists() {
        return Ok(());
    }
    let entries: Vec<PathBuf> = std::fs::read_dir(staging)
        .with_context(|| format!("{}: cannot list", staging.display()))?
        .map(|e| e.map(|e| e.path()))
        .collect::<std::io::Result<_>>()?;
    if let Some(other) = entries
        .iter()
        .find(|p| !(p.is_file() && simulation_name(&needle_io::trial::name_of(p))))
    {
        bail!(
            "{}: left by a stopped simulation, but holds {}, which no simulation writes: move it",
            staging.display(),
            other.display()
        );
    }
    std::fs::remove_dir_all(staging)
        .with_context(|| format!("{}: cannot remove", staging.display()))
}

/// Where a simulation is written before it replaces the one in `--out`.
const STAGING: &str = ".simulating";

/// A sample rate a simulation can be made at: 50 Hz (the slowest rigs the
/// analysis commands take, the book, *What real recordings look like*) to
/// 65 535 Hz (the replay header's u16), in whole hertz (the replay's header
/// holds whole hertz: 99.5 was written as 100). `flag` names the argument
/// in the message.
pub fn check_rate_hz(flag: &str, rate_hz: f64) -> Result<()> {
    if !((50.0..=65_535.0).contains(&rate_hz) && rate_hz.fract() == 0.0) {
        bail!("{flag} {rate_hz}: a sample rate must be a whole number of Hz within 50..=65535");
    }
    Ok(())
}

/// The largest force noise or tare offset a simulation takes: the device's
/// load-cell full scale (±10 N); 1e308 N wrote `inf` into trial CSVs.
pub const MOST_NOISE_N: f64 = 10.0;

/// A force noise (or tare spread) a simulation can be made with: within
/// 0..=10 N.
pub fn check_noise_n(flag: &str, noise_n: f64) -> Result<()> {
    if !(0.0..=MOST_NOISE_N).contains(&noise_n) {
        bail!("{flag} {noise_n:?}: must be a number of newtons within 0..={MOST_NOISE_N} (the load cell's full scale)");
    }
    Ok(())
}

/// Most a trial's cutting force is of its puncture force under
/// [`vary`] (or the tissue's own share, if more): the paper's 0.94 N of
/// 2.30 N is 0.41, and its spread (±0.36 of ±0.83 N) reaches about 0.6
/// two standard deviations out.
pub const MOST_CUTTING_SHARE: f64 = 0.6;

/// One insertion's factor on a quantity of coefficient of variation `cv`:
/// 1 + cv·z for a standard normal z, within 0.3–2 (no tissue is a third
/// as stiff or twice as stiff as itself from one insertion to the next).
fn spread_factor(cv: f64, rng: &mut impl Rng) -> f64 {
    let z: f64 = rng.sample(rand_distr::StandardNormal);
    (1.0 + cv * z).clamp(0.3, 2.0)
}

/// `tissue` as one insertion meets it, varied by `spread` ([`Rig::spread`]).
pub fn vary(tissue: &TissueParams, spread: f64, rng: &mut impl Rng) -> TissueParams {
    if spread <= 0.0 {
        return *tissue;
    }
    let mut factor = |cv: f64| spread_factor(cv, rng);
    let (stiff, depth, cut, fric) = (
        factor(spread),
        factor(spread / 2.0),
        factor(spread),
        factor(spread),
    );
    let mut p = *tissue;
    p.a1_n_per_m *= stiff;
    p.a2_n_per_m2 *= stiff;
    // x/(a·x + b) times `stiff` is x/((a/stiff)·x + b/stiff).
    p.rational_a_per_n /= stiff;
    p.rational_b_m_per_n /= stiff;
    p.puncture_depth_m *= depth;
    p.puncture_force_n = p.stiffness_n(p.puncture_depth_m);
    p.puncture_drop_to_n *= stiff;
    // A puncture is a fall (the paper's definition): the cutting force
    // that follows it stays below the force at which the capsule failed.
    // Drawn independently, a soft capsule and a hard cut would make a
    // trial with no puncture to see, which no rig records as one. A
    // tissue that cuts harder than that (liver 2) keeps its own share.
    let share = MOST_CUTTING_SHARE.max(tissue.cutting_force_n / tissue.puncture_force_n);
    p.cutting_force_n = (p.cutting_force_n * cut).min(share * p.puncture_force_n);
    for v in [
        &mut p.cp_n_per_m,
        &mut p.cn_n_per_m,
        &mut p.bp_ns_per_m2,
        &mut p.bn_ns_per_m2,
        &mut p.dp_n_per_m,
        &mut p.dn_n_per_m,
    ] {
        *v *= fric;
    }
    // Where the punctured surface rests (x_s3) is each insertion's own as
    // well: real withdrawals let go 1.5–9 mm apart. Drawn last, so the
    // draws before it are those of a simulation without it.
    p.relaxation = (p.relaxation * factor(spread)).clamp(0.0, 1.0);
    p
}

/// The tissue's effects as one insertion meets them, varied by `spread`
/// ([`Rig::spread`]) as the tissue is: real skin's hold relaxes by 32–47 %
/// from one insertion to the next, and a tissue's friction, cutting and
/// motion differ as much as its stiffness. Relaxation's stiffness, the
/// presliding length, cutting's growth with depth, the rate dependence's
/// departure from linear and the motion's amplitude are each times
/// 1 + spread·z (τ and the amplitude 1 + spread/2·z; factors within
/// 0.3–2). The holder's mass and the load cell's drift are the rig's, the
/// same in every trial; the walls are drawn per trial already.
pub fn vary_effects(effects: &[Effect], spread: f64, rng: &mut impl Rng) -> Vec<Effect> {
    if spread <= 0.0 {
        return effects.to_vec();
    }
    let mut factor = |cv: f64| spread_factor(cv, rng);
    effects
        .iter()
        .map(|effect| match *effect {
            Effect::Viscoelasticity { k_n_per_m, tau_s } => Effect::Viscoelasticity {
                k_n_per_m: k_n_per_m * factor(spread),
                tau_s: tau_s * factor(spread / 2.0),
            },
            Effect::RateDependentFriction {
                exponent,
                v_ref_mps,
            } => Effect::RateDependentFriction {
                exponent: 1.0 - (1.0 - exponent) * factor(spread),
                v_ref_mps,
            },
            Effect::PreslidingHysteresis { x_c_m } => Effect::PreslidingHysteresis {
                x_c_m: x_c_m * factor(spread),
            },
            Effect::DepthDependentCutting { g_per_m } => Effect::DepthDependentCutting {
                g_per_m: g_per_m * factor(spread),
            },
            Effect::TissueMotion {
                amplitude_m,
                freq_hz,
            } => Effect::TissueMotion {
                amplitude_m: amplitude_m * factor(spread / 2.0),
                freq_hz,
            },
            other => other,
        })
        .collect()
}

/// Run `needle simulate`.
pub fn run(args: &SimulateArgs) -> Result<()> {
    check_rate_hz("--rate-hz", args.rate_hz)?;
    check_noise_n("--noise-n", args.noise_n)?;
    check_noise_n("--tare-n", args.tare_n)?;
    if !(0.0..=0.5).contains(&args.spread) {
        bail!(
            "--spread {}: must be within 0..=0.5 (a coefficient of variation)",
            args.spread
        );
    }
    if !(1..=10_000).contains(&args.trials) {
        bail!("--trials {}: must be within 1..=10000", args.trials);
    }
    if args.layers > 3 {
        bail!("--layers must be within 0..=3");
    }
    if !(0.0..=5.0).contains(&args.tear_mm) {
        bail!("--tear-mm {}: must be within 0..=5", args.tear_mm);
    }
    if !(args.accel_mps2 == 0.0 || (0.005..=10.0).contains(&args.accel_mps2)) {
        bail!(
            "--accel-mps2 {}: must be 0 or within 0.005..=10",
            args.accel_mps2
        );
    }
    let tissue = needle_io::tissue::resolve(args.tissue.as_deref(), args.params.as_deref())?;
    let effects = effects::parse_list(&args.effects)?;
    let sensor = Sensor {
        rate_hz: args.rate_hz,
        noise_n: args.noise_n,
        encoder_m: 1e-6,
    };
    let written = Dataset {
        tissue_name: &tissue.name,
        tissue: &tissue.params,
        effects: &effects,
        trials: args.trials,
        seed: args.seed,
        sensor,
        through: args.through,
        form: args.effect_form,
        rig: Rig {
            protocol: args.protocol,
            layers: args.layers,
            jitter: args.jitter,
            tare_sd_n: args.tare_n,
            spread: args.spread,
            tear_m: args.tear_mm * 1e-3,
            accel_mps2: args.accel_mps2,
        },
    }
    .write(&args.out)?;
    needle_io::note!("wrote {written} trials to {}", args.out.display());
    Ok(())
}

/// What to simulate: a tissue with its effects, how many trials from which
/// seed, through which sensor, and whether the needle goes through.
#[derive(Clone, Copy, Debug)]
pub struct Dataset<'a> {
    pub tissue_name: &'a str,
    pub tissue: &'a TissueParams,
    pub effects: &'a [Effect],
    pub trials: usize,
    pub seed: u64,
    pub sensor: Sensor,
    /// The far side of the sample lies inside the motion (`--through`).
    pub through: bool,
    pub form: Form,
    /// Protocol, layers, clock and tare.
    pub rig: Rig,
}

/// Simulate `trials` trials into `dir` (not through the sample).
pub fn simulate_dataset(
    dir: &Path,
    tissue_name: &str,
    tissue: &TissueParams,
    effects: &[Effect],
    trials: usize,
    seed: u64,
    sensor: &Sensor,
) -> Result<usize> {
    Dataset {
        tissue_name,
        tissue,
        effects,
        trials,
        seed,
        sensor: *sensor,
        through: false,
        form: Form::Standard,
        rig: Rig::default(),
    }
    .write(dir)
}

impl Dataset<'_> {
    /// Write trial CSVs, firmware replays and truth.json into `dir`. Same
    /// seed, same bytes.
    pub fn write(&self, dir: &Path) -> Result<usize> {
        needle_io::input::out_dir(dir)?;
        needle_io::input::create_out_dir(dir)?;
        // One simulation at a time in a directory (two at once shared the
        // staging and each removed the other's files); the lock goes with
        // the process, however it ends.
        let lock =
            std::fs::File::open(dir).with_context(|| format!("{}: cannot open", dir.display()))?;
        if lock.try_lock().is_err() {
            bail!("{}: another simulation is writing it", dir.display());
        }
        let previous = previous_simulation(dir, self.trials)?;
        // Written beside, then moved in: a run stopped half-way (Ctrl-C, a
        // full disk) left trials without a truth.json, which the next run
        // then refused as another's, and the earlier simulation gone.
        let staging = dir.join(STAGING);
        clear_staging(&staging)?;
        std::fs::create_dir(&staging)
            .with_context(|| format!("{}: cannot create", staging.display()))?;
        let written = self.write_into(&staging)?;
        // Moved over the earlier files first, the rest of those removed
        // after, so a failure on the way removes nothing; truth.json last:
        // it is what makes the directory a simulation.
        let mut staged: Vec<PathBuf> = std::fs::read_dir(&staging)
            .with_context(|| format!("{}: cannot list", staging.display()))?
            .map(|e| e.map(|e| e.path()))
            .collect::<std::io::Result<_>>()?;
        staged.sort_by_key(|p| p.ends_with("truth.json"));
        let staged_names: std::collections::BTreeSet<String> = staged
            .iter()
            .map(|p| needle_io::trial::name_of(p))
            .collect();
        for from in staged {
            let to = dir.join(from.file_name().unwrap_or_default());
            std::fs::rename(&from, &to)
                .with_context(|| format!("{}: cannot move to {}", from.display(), to.display()))?;
        }
        std::fs::remove_dir(&staging)
            .with_context(|| format!("{}: cannot remove", staging.display()))?;
        for path in previous
            .iter()
            .filter(|p| !staged_names.contains(&needle_io::trial::name_of(p)))
        {
            std::fs::remove_file(path)
                .with_context(|| format!("{}: cannot remove", path.display()))?;
        }
        drop(lock);
        Ok(written)
    }

    /// Write the trials, replays and truth.json into `dir`.
    fn write_into(&self, dir: &Path) -> Result<usize> {
        let Dataset {
            tissue_name,
            tissue,
            effects,
            trials,
            seed,
            ref sensor,
            through,
            form,
            rig,
        } = *self;
        let config = needle_holder::config::DeviceConfig::default();
        // The replays run on this tissue where the firmware has it (a
        // library tissue, unchanged); another runs on the image's default.
        let library_index = needle_holder::model::params::LIBRARY
            .iter()
            .position(|(name, params)| *name == tissue_name && params == tissue)
            .and_then(|i| u8::try_from(i).ok());
        let mut truths = Vec::new();
        for k in 0..trials {
            let mut rng =
                ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1_000_003).wrapping_add(k as u64));
            let mut protocol = match rig.protocol {
                ProtocolKind::Paper => random_protocol(&mut rng),
                ProtocolKind::InsertDwellWithdraw => {
                    insert_dwell_withdraw(tissue, rig.layers, &mut rng)
                }
            };
            if rig.protocol == ProtocolKind::Paper && rig.layers > 0 {
                let reach_m = deepest_x_m(&protocol) - protocol.surface_x_m;
                protocol.layers = draw_layers(tissue, rig.layers, reach_m, &mut rng);
            }
            if through {
                protocol.far_surface_x_m = far_surface(tissue, &protocol, &mut rng);
            }
            if rig.tare_sd_n > 0.0 {
                protocol.tare_n = rng.sample(Normal::new(0.0, rig.tare_sd_n)?);
            }
            let wander_size = effects.iter().find_map(|e| match e {
                Effect::DepthDependentCutting { g_per_m } if form == Form::Alternate => {
                    Some((g_per_m / DEPTH_CUTTING_G_PER_M).max(1.0))
                }
                _ => None,
            });
            if let Some(size) = wander_size {
                let mut wander_rng = ChaCha8Rng::seed_from_u64(
                    seed.wrapping_mul(104_729).wrapping_add(k as u64) ^ 0x3A4D_3A4D,
                );
                let reach_m = deepest_x_m(&protocol) - protocol.surface_x_m;
                protocol.cutting_wander = cutting_wander(reach_m, size, &mut wander_rng);
            }
            if rig.tear_m > 0.0 {
                let mut tear_rng = ChaCha8Rng::seed_from_u64(
                    seed.wrapping_mul(3_571).wrapping_add(k as u64) ^ 0x7EA2_7EA2,
                );
                protocol.tear_m = rig.tear_m * tear_rng.gen_range(0.5..1.5);
            }
            for seg in &mut protocol.segments {
                match seg {
                    Segment::Move { accel_mps2, .. } => *accel_mps2 = rig.accel_mps2,
                    Segment::Oscillate {
                        from_rest, cycles, ..
                    } if rig.accel_mps2 > 0.0 => {
                        *from_rest = true;
                        *cycles = cycles.ceil();
                    }
                    Segment::Oscillate { .. } => {}
                    Segment::Dwell { .. } => {}
                }
            }
            if rig.jitter {
                let duration_s = motion::duration_s(&protocol.segments, 0.0);
                protocol.times_s = Some(jittered_times(sensor.rate_hz, duration_s, &mut rng));
            }
            // Drawn from a stream of its own: a simulation without spread
            // is the same trial for trial as before spread existed.
            let mut spread_rng = ChaCha8Rng::seed_from_u64(
                seed.wrapping_mul(7_919).wrapping_add(k as u64) ^ 0x5EED_5EED,
            );
            let varied = vary(tissue, rig.spread, &mut spread_rng);
            // The tissue's effects vary as the tissue does, from a stream
            // of their own so that nothing else drawn moves with them.
            let mut effects_rng = ChaCha8Rng::seed_from_u64(
                seed.wrapping_mul(6_271).wrapping_add(k as u64) ^ 0xEFEC_7500,
            );
            let trial_effects = vary_effects(effects, rig.spread, &mut effects_rng);
            let (trial, truth) =
                simulate_trial_in(&varied, &protocol, &trial_effects, form, sensor, &mut rng);
            let name = format!("trial_{k:03}");
            let csv = dir.join(format!("{name}.csv"));
            needle_io::trial::write(&csv, &trial)?;
            let header = ReplayHeader {
                sample_rate_hz: sensor.rate_hz.round() as u16,
                tissue: library_index,
            };
            let replay = to_replay_with(&trial, header, &config.load_cell, &config.encoder);
            let path = dir.join(format!("{name}.replay"));
            let bytes = [replay.len() as u64, std::fs::metadata(&csv)?.len()];
            std::fs::write(&path, replay)
                .with_context(|| format!("{}: cannot write", path.display()))?;
            truths.push((name, truth, bytes, trial_effects));
        }
        let file = TruthFile {
            tissue: tissue_name,
            params: tissue,
            effects,
            effect_form: form,
            seed,
            sensor: *sensor,
            rig,
            trials: truths
                .iter()
                .map(
                    |(name, truth, [replay_bytes, file_bytes], effects)| TruthTrial {
                        file: format!("{name}.csv"),
                        replay: format!("{name}.replay"),
                        file_bytes: *file_bytes,
                        replay_bytes: *replay_bytes,
                        effects,
                        truth,
                    },
                )
                .collect(),
        };
        let json = serde_json::to_string_pretty(&file)?;
        let path = dir.join("truth.json");
        std::fs::write(&path, json + "\n")
            .with_context(|| format!("{}: cannot write", path.display()))?;
        Ok(trials)
    }
}

/// A far side for the sample, between 8 mm past the puncture depth and
/// 4 mm short of the deepest point of the motion (`None` if no room).
fn far_surface(tissue: &TissueParams, protocol: &Protocol, rng: &mut impl Rng) -> Option<f64> {
    let deepest = deepest_x_m(protocol);
    let lo = protocol.surface_x_m + tissue.puncture_depth_m + 0.008;
    let hi = deepest - 0.004;
    (hi > lo).then(|| rng.gen_range(lo..hi))
}

/// The deepest point of a protocol's motion, m (sampled at 100 Hz).
fn deepest_x_m(protocol: &Protocol) -> f64 {
    motion::sample(&protocol.segments, 0.0, 100.0)
        .x_m
        .into_iter()
        .fold(0.0, f64::max)
}

/// What the sensors read for a needle at `x_m` under `f_n`: ADC counts
/// through the load-cell calibration, and the encoder's 16-bit count.
pub fn raw_record(x_m: f64, f_n: f64, load_cell: &LoadCell, encoder: &Encoder) -> Record {
    let counts = (Nanometres::from_m(x_m).0 as f64 / encoder.nm_per_count as f64).round() as i64;
    Record {
        adc_counts: load_cell.counts_for(MicroNewtons::from_n(f_n)),
        // The hardware counter keeps the low 16 bits.
        encoder_count: counts as u16,
    }
}

/// One plain insertion of `tissue` under `plan`, its truth, and its
/// replay for a device of the default configuration: what the demo, the
/// bench and the QEMU tests run.
pub fn insertion_replay(tissue: &TissueParams, plan: &Plan) -> (Trial, Truth, Vec<u8>) {
    let (trial, truth) = insertion(tissue, plan);
    let config = needle_holder::config::DeviceConfig::default();
    let rate_hz = plan.rate_hz as u16;
    let replay = to_replay(&trial, rate_hz, &config.load_cell, &config.encoder);
    (trial, truth, replay)
}

/// The library tissue that relaxes at rest (`skin_phantom`) inserted
/// 20 mm and held still 5 s, as a replay that names it (the firmware
/// runs that tissue): what `needle bench` counts with relaxation on and
/// the QEMU twin compares. Its library index, and the replay.
pub fn relaxing_dwell_replay() -> Result<(u8, Vec<u8>)> {
    let (index, skin) = needle_holder::model::params::LIBRARY
        .iter()
        .enumerate()
        .find(|(_, (name, _))| *name == "skin_phantom")
        .map(|(i, (_, p))| (i as u8, *p))
        .context("skin_phantom is not in the tissue library")?;
    let plan = Plan {
        depth_m: 0.02,
        dwell_s: 5.0,
        ..Plan::PAPER
    };
    let (trial, _) = insertion(&skin, &plan);
    let config = needle_holder::config::DeviceConfig::default();
    let header = ReplayHeader {
        sample_rate_hz: 500,
        tissue: Some(index),
    };
    Ok((
        index,
        to_replay_with(&trial, header, &config.load_cell, &config.encoder),
    ))
}

/// A trial as a firmware replay file for the given sensor calibration,
/// run on the image's default tissue.
pub fn to_replay(trial: &Trial, rate_hz: u16, load_cell: &LoadCell, encoder: &Encoder) -> Vec<u8> {
    let header = ReplayHeader {
        sample_rate_hz: rate_hz,
        tissue: None,
    };
    to_replay_with(trial, header, load_cell, encoder)
}

/// [`to_replay`] under `header` (its rate, and a library tissue to run in
/// place of the image's default).
pub fn to_replay_with(
    trial: &Trial,
    header: ReplayHeader,
    load_cell: &LoadCell,
    encoder: &Encoder,
) -> Vec<u8> {
    let mut bytes = header.to_bytes().to_vec();
    for (&x_m, &f_n) in trial.x_m.iter().zip(&trial.f_n) {
        let record = raw_record(x_m, f_n, load_cell, encoder);
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

    /// The literature mount passes on what relaxation adds and lies
    /// before the load cell's drift, however the effects are listed: a
    /// trial is the same whatever their order, and differs from one
    /// without the mount.
    #[test]
    fn the_literature_mount_bears_the_tissue_and_not_the_drift_in_any_order() {
        let sensor = Sensor {
            rate_hz: 250.0,
            noise_n: 0.0,
            encoder_m: 1e-6,
        };
        let run = |list: &str| {
            let effects = effects::parse_list(list).unwrap();
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            let protocol = insert_dwell_withdraw(&LIVER1, 0, &mut rng);
            simulate_trial_in(
                &LIVER1,
                &protocol,
                &effects,
                Form::Literature,
                &sensor,
                &mut rng,
            )
            .0
        };
        let all = run("viscoelasticity,holder_inertia,sensor_drift");
        assert_eq!(all, run("sensor_drift,holder_inertia,viscoelasticity"));
        assert_eq!(all, run("holder_inertia,sensor_drift,viscoelasticity"));
        assert_ne!(all, run("viscoelasticity,sensor_drift"));
    }

    /// With spread, each trial meets its own relaxation (stiffness and τ)
    /// and presliding length, around the tissue's, and the rig's holder
    /// and drift as they are; without it, the effects as asked.
    #[test]
    fn each_trial_meets_its_own_effects_with_spread() {
        use rand::SeedableRng;
        let asked = effects::parse_list(
            "viscoelasticity,presliding_hysteresis,holder_inertia,sensor_drift",
        )
        .unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        assert_eq!(vary_effects(&asked, 0.0, &mut rng), asked);
        let trials: Vec<Vec<Effect>> = (0..20)
            .map(|_| vary_effects(&asked, 0.2, &mut rng))
            .collect();
        let k_of = |e: &[Effect]| match e[0] {
            Effect::Viscoelasticity { k_n_per_m, tau_s } => (k_n_per_m, tau_s),
            _ => unreachable!("relaxation first, as asked"),
        };
        let ks: Vec<f64> = trials.iter().map(|t| k_of(t).0).collect();
        let mean = ks.iter().sum::<f64>() / ks.len() as f64;
        let sd = (ks.iter().map(|k| (k - mean).powi(2)).sum::<f64>() / ks.len() as f64).sqrt();
        assert!((mean / 20.0 - 1.0).abs() < 0.15, "{mean}");
        assert!((0.1..0.35).contains(&(sd / mean)), "{}", sd / mean);
        assert!(trials.iter().any(|t| k_of(t).1 != 1.0));
        assert!(trials.iter().any(|t| t[1] != asked[1]));
        assert!(trials.iter().all(|t| t[2..] == asked[2..]), "the rig's own");
    }
}
