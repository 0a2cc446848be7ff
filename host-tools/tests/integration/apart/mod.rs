//! An independent generator of needle-insertion force recordings, written
//! apart from the project's simulator, fitter, detectors and diagnosis, from
//! the physics literature only, so that those analyses can be checked on
//! data whose forms their authors did not choose. It is validation data:
//! never tune an analysis on it (see README.md beside this file).
//!
//! Conventions: force positive when it resists insertion, `x_m` increases
//! into the tissue, trial CSV `t_s,x_m,f_n`.
//!
//! Numbers used, and where they come from:
//! - Bovine liver 1 (Okamura, Simone, O'Leary, "Modeling of needle
//!   insertion forces for robot-assisted percutaneous therapy", ICRA 2004;
//!   its Table 1 only fits with x in mm): capsule f = a1·x + a2·x²,
//!   a1 = 48 N/m, a2 = 5200 N/m²;
//!   puncture 2.30 ± 0.83 N at 16.65 ± 3.55 mm after contact, drop to
//!   0.66 ± 0.56 N; cutting 0.94 ± 0.36 N at 3 mm/s, rising slightly with
//!   depth; Karnopp friction per unit length b_p 904 (1327 at 0.2 Hz, 377
//!   at 0.8 Hz), b_n 458 N·s/m², D_p 30.4, D_n −29.3 N/m, C ≈ 0; the
//!   journal version's refit (IEEE TBME 2004, as a public implementation
//!   uses it) C_p 10.57, C_n −11.96, D_p 18.45, D_n −18.23 N/m,
//!   Δv/2 = 5 µm/s; 500 Hz, 3 mm/s, sinusoids at 0.2–0.8 Hz; the surface
//!   after puncture rests between its first and its puncture position.
//! - Published recordings from another lab's stage rig on skin,
//!   skin-on-muscle and 3 mm artery phantoms (6-axis force/torque sensor
//!   at the needle base, 44 insertions), as measured traits: ~100 Hz
//!   (75–120) with jitter and gaps up to 70 ms, stage coordinates starting
//!   2–15 mm before the surface, noise sd ≈ 12 mN, a few mN of residual
//!   tare; insert 25 mm at 1–3 mm/s, hold 5 s, withdraw; held force (1–4 N)
//!   relaxing 34–41 % in 5 s, τ ≈ 1.5 s; withdrawal pulls −0.8 to −2.2 N and
//!   the force is back to zero 1.5–9 mm before the first-contact position;
//!   puncture 4.8 ± 0.3 N (skin), 5.2 ± 0.4 N (skin on muscle), 1.9 ± 0.3 N
//!   (artery, rolls over, no sharp fall); before a fall the force flattens
//!   and eases for 1–20 samples, then falls to 20–45 % within two samples;
//!   it climbs again 1.2–3.3× within 3 mm and ends at 0.7–2.7× the fallen
//!   value; spread between insertions: peak CV 7–13 %, puncture depth sd
//!   0.3–1.4 mm, post-puncture force CV 9–20 %.
//! - Viscoelasticity: generalized Maxwell (Prony) series; power-law
//!   relaxation G ∝ (1 + t/t0)^−n (soft tissue, e.g. Nekouzadeh & Genin);
//!   Fung's quasi-linear viscoelasticity with a box spectrum between τ1 and
//!   τ2 (Fung, Biomechanics, 1993), all held to the 34–41 % / 5 s figure.
//! - Friction: Stribeck curve; power-law velocity dependence (fits the
//!   paper's damping that falls from 1327 to 377 N·s/m² as the speed rises
//!   fourfold, i.e. F ∝ v^n with small n); Dahl (1968)
//!   dF/dx = σ0(1 − F/F_c·sgn ẋ)^α; LuGre (Canudas de Wit et al. 1995)
//!   ż = v − σ0|v|z/g(v), F = σ0 z + σ1 ż + σ2 v.
//! - Static friction grows with contact time (Dieterich/Rabinowicz aging),
//!   which is why the pull-out capacity after a 5 s hold exceeds D.
//! - Organ motion: breathing 0.2–0.33 Hz, 0.5–3 mm along the needle axis;
//!   Lujan et al. (1999) z(t) = z0 − b·cos^(2n)(πt/τ − φ), irregular period.
//! - Load cells drift: ~0.02–0.1 % of full scale per °C and with warm-up
//!   (a thermal first-order approach over tens of seconds).
//!
//! Choices where the sources are silent (README.md has the full list):
//! walls fail at a drawn deflection and their elastic law is scaled so the
//! force they actually reach is the drawn puncture force, so force and
//! depth spread independently; at rest the tissue force sticks at its
//! carried-over value clamped to the static band (the paper's F_a rule);
//! the surface keeps a permanent set after the puncture; relaxation acts on
//! loaded walls, on held forces, and on sliding friction through the age of
//! the channel (a steady cut renews its material and is not relaxed).
//!
//! Every random number comes from a ChaCha8 stream keyed by (seed, trial,
//! purpose), so an effect's own draws never shift the baseline's: a case
//! and its effect-free twin share tissue, timing and noise exactly.

// Test-support module: the tests use only part of
// the API, which would otherwise warn (and fail clippy -D warnings).
#![allow(dead_code)]

mod physics;
mod sim;

use std::f64::consts::PI;
use std::io::Write;
use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde_json::{json, Value};

pub use physics::{Friction, KineticLaw, LoadCurve, MotionPath, Relaxation};
use physics::{Seg, Trajectory};
use sim::{CutMod, Drift, Holder, Pre, ShaftProfile, Spec, Tip, Wall};

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Protocol {
    /// Approach, capsule loading, puncture, insertion, dwell, sinusoidal
    /// oscillation, dwell, withdrawal (the paper's experiments).
    Paper,
    /// Insert 25 mm past the surface, hold 5 s, withdraw (real rigs).
    InsertDwellWithdraw,
}

impl Protocol {
    pub fn tag(self) -> &'static str {
        match self {
            Protocol::Paper => "paper",
            Protocol::InsertDwellWithdraw => "idw",
        }
    }
}

/// The paper's friction (C ≈ 0 in liver).
pub const PAPER_FRICTION: Friction = Friction {
    c_p_n_per_m: 0.0,
    c_n_n_per_m: 0.0,
    d_p_n_per_m: 30.4,
    d_n_n_per_m: -29.3,
    b_p_n_s_per_m2: 904.0,
    b_n_n_s_per_m2: 458.0,
    dv_half_mps: 5e-6,
};

/// The journal refit's Coulomb and static levels with the paper's damping.
pub const JOURNAL_FRICTION: Friction = Friction {
    c_p_n_per_m: 10.57,
    c_n_n_per_m: -11.96,
    d_p_n_per_m: 18.45,
    d_n_n_per_m: -18.23,
    b_p_n_s_per_m2: 904.0,
    b_n_n_s_per_m2: 458.0,
    dv_half_mps: 5e-6,
};

/// The wall the needle loads before the first puncture.
#[derive(Clone, Debug)]
pub struct Membrane {
    pub a1_n_per_m: f64,
    pub a2_n_per_m2: f64,
    /// Mean peak force and its coefficient of variation between trials.
    pub peak_n: f64,
    pub peak_cv: f64,
    /// Deflection at the peak (from contact), mean and sd between trials.
    pub depth_m: f64,
    pub depth_sd_m: f64,
    pub yield_: Option<Yield>,
    pub roll: Option<Roll>,
    /// Range of 1–3 % dips on the way up (no puncture).
    pub dips: (usize, usize),
}

/// The tissue yields before it fails: flattening, then easing.
#[derive(Clone, Debug)]
pub struct Yield {
    pub flat_m: (f64, f64),
    /// Travel of the easing, in samples at the trial's speed and rate.
    pub ease_samples: (f64, f64),
    pub ease_frac: (f64, f64),
}

/// The wall rolls over and eases off without a sharp fall.
#[derive(Clone, Debug)]
pub struct Roll {
    pub flat_m: (f64, f64),
    pub roll_m: (f64, f64),
    pub to_frac: (f64, f64),
}

#[derive(Clone, Debug)]
pub enum TipSpec {
    /// The paper's cutting force (mean, CV between trials).
    Cutting { force_n: f64, cv: f64 },
    /// Layered-phantom shape after the fall (see `sim::Tip::Profile`).
    Profile {
        /// fallen force / peak: (mean, sd)
        fall_frac: (f64, f64),
        climb: (f64, f64),
        climb_m: (f64, f64),
        end_ratio: (f64, f64),
    },
}

/// A deeper membrane (e.g. the muscle under skin) that fails like the
/// first one, `after_m` past the previous failure.
#[derive(Clone, Debug)]
pub struct Layer {
    pub prob: f64,
    pub after_m: (f64, f64),
    pub rise_n: (f64, f64),
    pub span_m: (f64, f64),
    pub yield_: Yield,
}

#[derive(Clone, Debug)]
pub struct Tissue {
    pub name: &'static str,
    pub membrane: Membrane,
    pub tip: TipSpec,
    pub friction: Friction,
    pub friction_scale_cv: f64,
    /// Permanent set of the surface after the puncture, as a fraction of
    /// the puncture deflection (the paper's x_s1 < x_s3 < x_s2).
    pub set_fraction: (f64, f64),
    /// Intrinsic relaxation (5 s loss range), for tissues where it is the
    /// rule rather than an effect under test.
    pub relaxation_loss: Option<(f64, f64)>,
    pub layers: Vec<Layer>,
}

/// Withdrawal drags the tissue out: an elastic tent held by static
/// friction until it lets go.
#[derive(Clone, Debug)]
pub struct Drag {
    pub pull_n: (f64, f64),
    pub tent_k_n_per_m: (f64, f64),
}

#[derive(Clone, Debug)]
pub struct Oscillation {
    pub freq_hz: f64,
    pub amp_m: f64,
    pub cycles: usize,
    pub second_dwell_s: f64,
}

#[derive(Clone, Debug)]
pub struct Structures {
    pub count: (usize, usize),
    pub k_n_per_m: (f64, f64),
    pub rupture_n: (f64, f64),
    pub span_m: (f64, f64),
    /// Amplitude of the variation of friction per unit length along the
    /// tissue depth (0.3 = ±30 %).
    pub friction_variation: f64,
    /// Quadratic (tenting membrane) instead of linear (vessel wall).
    pub septum: bool,
}

/// One unmodelled effect in one literature form, with its strength.
#[derive(Clone, Debug)]
pub enum Effect {
    None,
    Viscoelastic(Relaxation),
    Kinetic(KineticLaw),
    Dahl {
        presliding_m: f64,
        alpha: f64,
    },
    LuGre {
        presliding_m: f64,
        damping_s: f64,
        v_s_mps: f64,
    },
    Structures(Structures),
    CuttingLinear {
        per_m: f64,
    },
    CuttingRandomWalk {
        sd: f64,
        corr_len_m: f64,
    },
    RigidHolder {
        mass_kg: f64,
    },
    CompliantHolder {
        mass_kg: f64,
        f_hz: f64,
        zeta: f64,
    },
    LinearDrift {
        n_per_s: f64,
    },
    ThermalDrift {
        amp_n: f64,
        tau_s: f64,
    },
    SinusoidMotion {
        amp_m: f64,
        freq_hz: f64,
    },
    BreathingMotion {
        amp_m: f64,
        period_s: f64,
        period_cv: f64,
        power_n: i32,
    },
}

#[derive(Clone, Debug)]
pub struct Case {
    pub name: String,
    pub protocol: Protocol,
    pub effects: Vec<&'static str>,
    pub effect: Effect,
    pub tissue: Tissue,
    pub rate_hz: f64,
    /// Trial i moves at speeds_mps[i % len].
    pub speeds_mps: Vec<f64>,
    pub noise_n: f64,
    pub depth_past_surface_m: f64,
    pub dwell_s: f64,
    pub oscillation: Option<Oscillation>,
    pub accel_mps2: f64,
    /// Distance from the start to the tissue surface.
    pub approach_m: (f64, f64),
    pub jitter_sd_s: f64,
    pub gap_prob: f64,
    pub max_gap_s: f64,
    pub tare_sd_n: f64,
    pub encoder_m: f64,
    pub drag: Option<Drag>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    pub kind: &'static str,
    pub t_s: f64,
    pub x_m: f64,
    pub peak_t_s: f64,
}

#[derive(Clone, Debug)]
pub struct Trial {
    pub t_s: Vec<f64>,
    pub x_m: Vec<f64>,
    pub f_n: Vec<f64>,
    pub events: Vec<Event>,
    pub case: String,
    pub protocol: Protocol,
    pub effects: Vec<&'static str>,
    /// Present in every trial of the protocol, not an effect under test.
    pub baseline_traits: Vec<&'static str>,
    /// The drawn parameters (for reading results, not for fitting).
    pub params: Value,
}

pub fn liver1() -> Tissue {
    Tissue {
        name: "bovine_liver_1",
        membrane: Membrane {
            a1_n_per_m: 48.0,
            a2_n_per_m2: 5200.0,
            peak_n: 2.30,
            peak_cv: 0.25,
            depth_m: 16.65e-3,
            depth_sd_m: 2.5e-3,
            yield_: None,
            roll: None,
            dips: (0, 0),
        },
        tip: TipSpec::Cutting {
            force_n: 0.94,
            cv: 0.30,
        },
        friction: JOURNAL_FRICTION,
        friction_scale_cv: 0.15,
        set_fraction: (0.08, 0.28),
        relaxation_loss: None,
        layers: Vec::new(),
    }
}

pub fn base_case(protocol: Protocol) -> Case {
    match protocol {
        Protocol::Paper => Case {
            name: "paper/none".into(),
            protocol,
            effects: Vec::new(),
            effect: Effect::None,
            tissue: liver1(),
            rate_hz: 500.0,
            speeds_mps: vec![3e-3],
            noise_n: 0.003,
            depth_past_surface_m: 40e-3,
            dwell_s: 3.0,
            oscillation: Some(Oscillation {
                freq_hz: 0.5,
                amp_m: 2.5e-3,
                cycles: 3,
                second_dwell_s: 2.0,
            }),
            accel_mps2: 0.05,
            approach_m: (3e-3, 6e-3),
            jitter_sd_s: 0.0,
            gap_prob: 0.0,
            max_gap_s: 0.0,
            tare_sd_n: 0.0,
            encoder_m: 1e-6,
            drag: None,
        },
        Protocol::InsertDwellWithdraw => Case {
            name: "idw/none".into(),
            protocol,
            effects: Vec::new(),
            effect: Effect::None,
            tissue: liver1(),
            rate_hz: 100.0,
            speeds_mps: vec![1e-3, 2e-3, 3e-3],
            noise_n: 0.012,
            depth_past_surface_m: 25e-3,
            dwell_s: 5.0,
            oscillation: None,
            accel_mps2: 0.05,
            approach_m: (2e-3, 15e-3),
            jitter_sd_s: 2e-3,
            gap_prob: 0.003,
            max_gap_s: 0.07,
            tare_sd_n: 0.004,
            encoder_m: 1e-7,
            drag: Some(Drag {
                pull_n: (0.9, 2.0),
                tent_k_n_per_m: (250.0, 600.0),
            }),
        },
    }
}

/// Every effect in each of its literature forms, the baseline alone, and
/// one realistic combined case, for both protocols.
pub fn diagnosis_cases() -> Vec<Case> {
    let hold_s = 5.0;
    let mut cases = Vec::new();
    for protocol in [Protocol::Paper, Protocol::InsertDwellWithdraw] {
        let paper = protocol == Protocol::Paper;
        let tag = protocol.tag();
        let base = base_case(protocol);
        cases.push(base.clone());
        if paper {
            let mut c = base.clone();
            c.name = "paper/none/paper_friction".into();
            c.tissue.friction = PAPER_FRICTION;
            cases.push(c);
        }
        let structures = |septum| {
            Effect::Structures(Structures {
                count: if paper { (2, 4) } else { (1, 2) },
                k_n_per_m: (50.0, 200.0),
                rupture_n: (0.1, 0.5),
                span_m: (1e-3, 4e-3),
                friction_variation: 0.3,
                septum,
            })
        };
        let forms: Vec<(&'static str, &'static str, Effect)> = vec![
            (
                "viscoelasticity",
                "prony1",
                Effect::Viscoelastic(Relaxation::prony(&[1.5], &[1.0], 0.37, hold_s)),
            ),
            (
                "viscoelasticity",
                "prony2",
                Effect::Viscoelastic(Relaxation::prony(&[0.5, 3.0], &[0.4, 0.6], 0.38, hold_s)),
            ),
            (
                "viscoelasticity",
                "prony3",
                Effect::Viscoelastic(Relaxation::prony(
                    &[0.15, 1.5, 12.0],
                    &[0.25, 0.5, 0.25],
                    0.40,
                    hold_s,
                )),
            ),
            (
                "viscoelasticity",
                "power_law",
                Effect::Viscoelastic(Relaxation::power_law(0.3, 0.40, hold_s)),
            ),
            (
                "viscoelasticity",
                "qlv",
                Effect::Viscoelastic(Relaxation::qlv(0.05, 30.0, 0.41, hold_s)),
            ),
            (
                "rate_dependent_friction",
                "stribeck",
                Effect::Kinetic(KineticLaw::Stribeck {
                    static_p_n_per_m: JOURNAL_FRICTION.d_p_n_per_m,
                    static_n_n_per_m: JOURNAL_FRICTION.d_n_n_per_m,
                    v_s_mps: 1.5e-3,
                    exponent: 2.0,
                }),
            ),
            (
                "rate_dependent_friction",
                "power_law",
                Effect::Kinetic(KineticLaw::PowerLaw {
                    n: 0.3,
                    v_ref_mps: 3e-3,
                }),
            ),
            (
                "presliding_hysteresis",
                "dahl",
                Effect::Dahl {
                    presliding_m: if paper { 0.8e-3 } else { 0.4e-3 },
                    alpha: 1.5,
                },
            ),
            (
                "presliding_hysteresis",
                "lugre",
                Effect::LuGre {
                    presliding_m: 0.5e-3,
                    damping_s: 0.01,
                    v_s_mps: 0.5e-3,
                },
            ),
            ("internal_structures", "vessels", structures(false)),
            ("internal_structures", "septa", structures(true)),
            (
                "depth_dependent_cutting",
                "linear",
                // The insert-dwell-withdraw trial cuts only ~8 mm of liver.
                Effect::CuttingLinear {
                    per_m: if paper { 20.0 } else { 40.0 },
                },
            ),
            (
                "depth_dependent_cutting",
                "random_walk",
                Effect::CuttingRandomWalk {
                    sd: 0.25,
                    corr_len_m: 3e-3,
                },
            ),
            (
                "holder_inertia",
                "rigid",
                Effect::RigidHolder { mass_kg: 0.5 },
            ),
            (
                "holder_inertia",
                "compliant_mount",
                Effect::CompliantHolder {
                    mass_kg: 0.25,
                    f_hz: 35.0,
                    zeta: 0.15,
                },
            ),
            (
                "sensor_drift",
                "linear",
                Effect::LinearDrift {
                    n_per_s: if paper { 1e-3 } else { 2e-3 },
                },
            ),
            (
                "sensor_drift",
                "thermal",
                Effect::ThermalDrift {
                    amp_n: if paper { 0.05 } else { 0.12 },
                    tau_s: 20.0,
                },
            ),
            (
                "tissue_motion",
                "sinusoid",
                Effect::SinusoidMotion {
                    amp_m: 1.5e-3,
                    freq_hz: 0.25,
                },
            ),
            (
                "tissue_motion",
                "breathing",
                Effect::BreathingMotion {
                    amp_m: 2e-3,
                    period_s: 4.0,
                    period_cv: 0.12,
                    power_n: 2,
                },
            ),
        ];
        for (j, (effect_name, form, effect)) in forms.into_iter().enumerate() {
            let mut c = base.clone();
            vary(&mut c, j);
            c.name = format!("{tag}/{effect_name}/{form}");
            c.effects = vec![effect_name];
            c.effect = effect;
            if effect_name == "holder_inertia" {
                // Inertia shows only under acceleration: a brisk stage and
                // the fastest of the paper's sinusoids.
                c.accel_mps2 = 0.3;
                if let Some(o) = &mut c.oscillation {
                    o.freq_hz = 0.8;
                    o.amp_m = 4e-3;
                    o.cycles = 6;
                }
            }
            cases.push(c);
        }
        let mut c = base.clone();
        c.name = format!("{tag}/realistic/viscoelastic_drag");
        c.effects = vec!["viscoelasticity"];
        c.effect = Effect::Viscoelastic(Relaxation::prony(&[0.5, 3.0], &[0.4, 0.6], 0.37, hold_s));
        // Held force 1–4 N as measured: more shaft friction than liver
        // 1's, and a static band that holds the tip's load.
        c.tissue.friction.c_p_n_per_m = 25.0;
        c.tissue.friction.c_n_n_per_m = -25.0;
        c.tissue.friction.d_p_n_per_m = 90.0;
        c.tissue.friction.d_n_n_per_m = -90.0;
        c.tissue.tip = TipSpec::Cutting {
            force_n: 1.4,
            cv: 0.2,
        };
        c.drag = Some(Drag {
            pull_n: (0.9, 2.0),
            tent_k_n_per_m: (250.0, 600.0),
        });
        cases.push(c);
    }
    cases
}

/// Speeds, rates and oscillation frequencies differ between cases, within
/// the protocols' ranges, so that no analysis sees only one of each.
fn vary(c: &mut Case, j: usize) {
    match c.protocol {
        Protocol::Paper => {
            let speeds = [3e-3, 1e-3, 5e-3, 10e-3, 2e-3, 3e-3];
            let rates = [500.0, 500.0, 1000.0, 500.0, 2000.0, 500.0];
            let freqs = [0.5, 0.2, 0.8, 0.5, 0.2, 0.8];
            c.speeds_mps = vec![speeds[j % speeds.len()]];
            c.rate_hz = rates[j % rates.len()];
            if let Some(o) = &mut c.oscillation {
                o.freq_hz = freqs[j % freqs.len()];
                o.cycles = if o.freq_hz < 0.3 { 3 } else { 4 };
            }
        }
        Protocol::InsertDwellWithdraw => {
            let rates = [100.0, 75.0, 120.0, 90.0, 110.0, 100.0];
            c.rate_hz = rates[j % rates.len()];
        }
    }
}

/// Paper protocol into bovine liver 1 with 2–5 interior vessels after the
/// capsule and friction varying ±30 % along the depth.
pub fn vessel_liver(n_trials: usize, seed: u64) -> Vec<Trial> {
    let mut c = base_case(Protocol::Paper);
    c.name = "vessel_liver".into();
    c.noise_n = 0.004;
    c.depth_past_surface_m = 55e-3;
    c.effects = vec!["internal_structures"];
    c.effect = Effect::Structures(Structures {
        count: (2, 5),
        k_n_per_m: (50.0, 200.0),
        rupture_n: (0.1, 0.5),
        span_m: (1e-3, 4e-3),
        friction_variation: 0.3,
        septum: false,
    });
    generate(&c, n_trials, seed)
}

fn phantom_yield() -> Yield {
    Yield {
        flat_m: (0.6e-3, 1.5e-3),
        ease_samples: (2.0, 18.0),
        ease_frac: (0.02, 0.06),
    }
}

/// The three phantom tissues: 0 skin, 1 skin on muscle, 2 artery.
pub fn phantom_tissue(kind: usize) -> Tissue {
    let friction = Friction {
        c_p_n_per_m: 20.0,
        c_n_n_per_m: -25.0,
        d_p_n_per_m: 200.0,
        d_n_n_per_m: -200.0,
        b_p_n_s_per_m2: 500.0,
        b_n_n_s_per_m2: 500.0,
        dv_half_mps: 5e-6,
    };
    let base = Tissue {
        name: "skin",
        membrane: Membrane {
            a1_n_per_m: 200.0,
            a2_n_per_m2: 4e4,
            peak_n: 4.8,
            peak_cv: 0.08,
            depth_m: 9e-3,
            depth_sd_m: 0.8e-3,
            yield_: Some(phantom_yield()),
            roll: None,
            dips: (0, 2),
        },
        tip: TipSpec::Profile {
            fall_frac: (0.31, 0.03),
            climb: (1.4, 3.0),
            climb_m: (1.5e-3, 3e-3),
            end_ratio: (0.8, 2.4),
        },
        friction,
        friction_scale_cv: 0.12,
        set_fraction: (0.3, 0.6),
        relaxation_loss: Some((0.36, 0.41)),
        layers: vec![Layer {
            prob: 0.35,
            after_m: (5e-3, 9e-3),
            rise_n: (0.5, 0.9),
            span_m: (1.5e-3, 3e-3),
            yield_: phantom_yield(),
        }],
    };
    match kind {
        0 => base,
        1 => Tissue {
            name: "skin_on_muscle",
            membrane: Membrane {
                a2_n_per_m2: 3.2e4,
                peak_n: 5.2,
                peak_cv: 0.077,
                depth_m: 10e-3,
                depth_sd_m: 1.0e-3,
                ..base.membrane.clone()
            },
            tip: TipSpec::Profile {
                fall_frac: (0.30, 0.03),
                climb: (1.3, 2.6),
                climb_m: (1.5e-3, 3e-3),
                end_ratio: (0.8, 2.2),
            },
            layers: vec![
                Layer {
                    prob: 1.0,
                    after_m: (3e-3, 6e-3),
                    rise_n: (1.0, 2.0),
                    span_m: (2e-3, 4e-3),
                    yield_: phantom_yield(),
                },
                Layer {
                    prob: 0.3,
                    after_m: (2e-3, 4e-3),
                    rise_n: (0.45, 0.8),
                    span_m: (1.5e-3, 2.5e-3),
                    yield_: phantom_yield(),
                },
            ],
            ..base
        },
        _ => Tissue {
            name: "artery",
            membrane: Membrane {
                a1_n_per_m: 100.0,
                a2_n_per_m2: 2.5e4,
                peak_n: 1.9,
                peak_cv: 0.12,
                depth_m: 7e-3,
                depth_sd_m: 0.6e-3,
                yield_: None,
                roll: Some(Roll {
                    flat_m: (0.5e-3, 1.2e-3),
                    roll_m: (1.0e-3, 2.5e-3),
                    to_frac: (0.45, 0.65),
                }),
                dips: (0, 1),
            },
            tip: TipSpec::Profile {
                fall_frac: (0.5, 0.05),
                climb: (1.0, 1.5),
                climb_m: (1.5e-3, 3e-3),
                end_ratio: (0.8, 2.2),
            },
            layers: vec![Layer {
                prob: 0.5,
                after_m: (2.5e-3, 4e-3),
                rise_n: (0.45, 0.8),
                span_m: (1e-3, 2e-3),
                yield_: phantom_yield(),
            }],
            ..base
        },
    }
}

/// Insert-dwell-withdraw into the phantoms; trial i is tissue i % 3 at
/// 1, 2 or 3 mm/s ((i / 3) % 3).
pub fn layered_phantoms(n_trials: usize, seed: u64) -> Vec<Trial> {
    (0..n_trials)
        .map(|i| {
            let kind = i % 3;
            let mut c = base_case(Protocol::InsertDwellWithdraw);
            c.tissue = phantom_tissue(kind);
            c.name = format!("layered_phantoms/{}", c.tissue.name);
            c.effects = vec!["viscoelasticity", "depth_dependent_cutting"];
            c.rate_hz = [100.0, 90.0, 110.0][kind];
            c.speeds_mps = vec![[1e-3, 2e-3, 3e-3][(i / 3) % 3]];
            c.drag = Some(Drag {
                pull_n: (0.9, 2.0),
                tent_k_n_per_m: (300.0, 800.0),
            });
            generate_trial(&c, i, seed)
        })
        .collect()
}

pub fn generate(case: &Case, n_trials: usize, seed: u64) -> Vec<Trial> {
    (0..n_trials)
        .map(|i| generate_trial(case, i, seed))
        .collect()
}

/// The same case with its effect removed (the baseline twin: same draws).
pub fn without_effect(case: &Case) -> Case {
    let mut c = case.clone();
    c.effect = Effect::None;
    c.effects.clear();
    c
}

const S_TIMING: u64 = 1;
const S_TISSUE: u64 = 2;
const S_NOISE: u64 = 3;
const S_WALLS: u64 = 4;
const S_CUT: u64 = 5;
const S_MOTION: u64 = 6;
const S_PROTO: u64 = 7;
const S_LAYERS: u64 = 8;
const S_SHAFT: u64 = 9;

fn stream(seed: u64, trial: usize, purpose: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(((trial as u64) << 8) | purpose);
    r
}

fn z(rng: &mut ChaCha8Rng) -> f64 {
    let v: f64 = rng.sample(StandardNormal);
    v.clamp(-2.5, 2.5)
}

fn uniform(rng: &mut ChaCha8Rng, (lo, hi): (f64, f64)) -> f64 {
    lo + (hi - lo) * rng.gen::<f64>()
}

fn lognormal(rng: &mut ChaCha8Rng, cv: f64) -> f64 {
    let s = (1.0 + cv * cv).ln().sqrt();
    (s * z(rng) - s * s / 2.0).exp()
}

fn sample_times(case: &Case, t_end_s: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let period = 1.0 / case.rate_hz;
    let n = (t_end_s / period).floor() as usize;
    let max_skip = ((case.max_gap_s / period - 1.0).floor() as usize)
        .saturating_sub(1)
        .max(1);
    let mut t = Vec::with_capacity(n + 1);
    let mut k = 0;
    while k <= n {
        let j = if k == 0 || case.jitter_sd_s == 0.0 {
            0.0
        } else {
            (case.jitter_sd_s * z(rng)).clamp(-0.45 * period, 0.45 * period)
        };
        t.push(k as f64 * period + j);
        if case.gap_prob > 0.0 && rng.gen::<f64>() < case.gap_prob {
            k += rng.gen_range(1..=max_skip);
        }
        k += 1;
    }
    t
}

struct Info {
    peak_target_n: f64,
    withdrawal_start_s: f64,
    params: Value,
}

fn build_spec(case: &Case, i: usize, seed: u64) -> (Spec, Info) {
    let tissue = &case.tissue;
    let v_mps = case.speeds_mps[i % case.speeds_mps.len()];

    let mut rp = stream(seed, i, S_PROTO);
    let (x_start, x_surface) = match case.protocol {
        Protocol::Paper => (0.0, uniform(&mut rp, case.approach_m)),
        Protocol::InsertDwellWithdraw => {
            let x0 = uniform(&mut rp, (0.0, 0.02));
            (x0, x0 + uniform(&mut rp, case.approach_m))
        }
    };
    let x_end = x_surface + case.depth_past_surface_m;
    let mut traj = Trajectory::default();
    traj.push(Seg::Hold { x_m: x_start }, 0.4, "approach");
    let mv = |x0_m, x1_m| Seg::Move {
        x0_m,
        x1_m,
        v_mps,
        a_mps2: case.accel_mps2,
    };
    traj.push(mv(x_start, x_end), 0.0, "insertion");
    traj.push(Seg::Hold { x_m: x_end }, case.dwell_s, "dwell");
    if let Some(o) = &case.oscillation {
        traj.push(
            Seg::Osc {
                x0_m: x_end,
                amp_m: o.amp_m,
                omega: 2.0 * PI * o.freq_hz,
            },
            o.cycles as f64 / o.freq_hz,
            "reversal",
        );
        traj.push(Seg::Hold { x_m: x_end }, o.second_dwell_s, "dwell");
    }
    traj.push(mv(x_end, x_start), 0.0, "withdrawal");
    traj.push(Seg::Hold { x_m: x_start }, 0.5, "after");
    let t_end_s = traj.end_s();
    let t_s = sample_times(case, t_end_s, &mut stream(seed, i, S_TIMING));

    // Tissue, drawn per trial.
    let mut rt = stream(seed, i, S_TISSUE);
    let m = &tissue.membrane;
    let peak_target_n = m.peak_n * (1.0 + m.peak_cv * z(&mut rt).clamp(-2.0, 2.0));
    // Leave room for tissue past the puncture within the insertion.
    let u_peak = (m.depth_m + m.depth_sd_m * z(&mut rt))
        .clamp(0.4 * m.depth_m, case.depth_past_surface_m - 5e-3);
    let mut curve = LoadCurve::sharp(m.a1_n_per_m, m.a2_n_per_m2, u_peak);
    if let Some(y) = &m.yield_ {
        curve.flat_m = uniform(&mut rt, y.flat_m).min(0.5 * u_peak);
        curve.ease_m = uniform(&mut rt, y.ease_samples) * v_mps / case.rate_hz;
        curve.ease_frac = uniform(&mut rt, y.ease_frac);
    }
    if let Some(ro) = &m.roll {
        curve.flat_m = uniform(&mut rt, ro.flat_m).min(0.5 * u_peak);
        curve.roll = Some((uniform(&mut rt, ro.roll_m), uniform(&mut rt, ro.to_frac)));
    }
    let n_dips = rt.gen_range(m.dips.0..=m.dips.1);
    let mut dip_at: Vec<f64> = (0..n_dips)
        .map(|_| uniform(&mut rt, (0.3, 0.75)) * (u_peak - curve.flat_m))
        .collect();
    dip_at.sort_by(f64::total_cmp);
    for at in dip_at {
        // A slip that lowers the force by 1–3 %: du = frac·f/f'.
        let frac = uniform(&mut rt, (0.01, 0.03));
        let f = curve.force(at);
        let slope = (curve.force(at + 1e-6) - f) / 1e-6;
        curve.dips.push((at, frac * f / slope));
    }
    let set_m = uniform(&mut rt, tissue.set_fraction) * u_peak;
    let friction_scale = lognormal(&mut rt, tissue.friction_scale_cv);
    let friction = tissue.friction.scaled(friction_scale);
    let end_depth_m = case.depth_past_surface_m - curve.u_end();
    let mut tip = match &tissue.tip {
        // A puncture is a fall: the tissue that fails carries more than
        // the cutting that follows it.
        TipSpec::Cutting { force_n, cv } => Tip::Cutting {
            force_n: (force_n * (1.0 + cv * z(&mut rt)).max(0.2)).min(0.5 * peak_target_n),
            modulation: CutMod::None,
        },
        TipSpec::Profile {
            fall_frac,
            climb,
            climb_m,
            end_ratio,
        } => {
            let frac = (fall_frac.0 + fall_frac.1 * z(&mut rt)).clamp(0.2, 0.45);
            let fall_n = match curve.roll {
                Some((_, to_frac)) => to_frac * peak_target_n,
                None => frac * peak_target_n,
            };
            Tip::Profile {
                fall_n,
                climb: uniform(&mut rt, *climb),
                climb_m: uniform(&mut rt, *climb_m),
                end_ratio: uniform(&mut rt, *end_ratio),
                end_depth_m,
            }
        }
    };
    let mut relax = match tissue.relaxation_loss {
        Some(range) => Relaxation::prony(
            &[0.5, 3.0],
            &[0.4, 0.6],
            uniform(&mut rt, range),
            case.dwell_s,
        ),
        None => Relaxation::elastic(),
    };
    let tent = case.drag.as_ref().map(|dg| {
        let k = uniform(&mut rt, dg.tent_k_n_per_m);
        let pull = uniform(&mut rt, dg.pull_n);
        (k, pull / (case.depth_past_surface_m - set_m))
    });
    let tare_n = case.tare_sd_n * z(&mut rt);

    // Deeper membranes of layered tissues.
    let mut rl = stream(seed, i, S_LAYERS);
    let mut walls = Vec::new();
    let mut next_d = curve.u_end();
    for layer in &tissue.layers {
        let draw = rl.gen::<f64>();
        let after = uniform(&mut rl, layer.after_m);
        let span = uniform(&mut rl, layer.span_m);
        let rise = uniform(&mut rl, layer.rise_n);
        let flat = uniform(&mut rl, layer.yield_.flat_m).min(0.5 * span);
        let ease_m = uniform(&mut rl, layer.yield_.ease_samples) * v_mps / case.rate_hz;
        let ease_frac = uniform(&mut rl, layer.yield_.ease_frac);
        let d_m = next_d + after;
        if draw >= layer.prob || d_m + span + ease_m + 2e-3 > case.depth_past_surface_m {
            continue;
        }
        let mut wc = LoadCurve::sharp(1.0, 2.0 / span, span);
        wc.flat_m = flat;
        wc.ease_m = ease_m;
        wc.ease_frac = ease_frac;
        let k = rise / wc.peak();
        wc.a1 *= k;
        wc.a2 *= k;
        next_d = d_m + wc.u_end();
        walls.push(Wall {
            d_m,
            curve: wc,
            kind: "structure",
        });
    }

    let mut spec = Spec {
        t_s,
        traj,
        x_surface_m: x_surface,
        curve,
        tip: tip.clone(),
        friction,
        law: KineticLaw::Karnopp,
        pre: Pre::None,
        relax: Relaxation::elastic(),
        set_m,
        tent,
        walls,
        shaft: None,
        motion: None,
        holder: Holder::None,
        drift: Drift::None,
        tare_n,
        encoder_m: case.encoder_m,
        dt_max_s: match case.protocol {
            Protocol::Paper => (1.0 / case.rate_hz).min(5e-4),
            Protocol::InsertDwellWithdraw => 1e-3,
        },
    };

    match &case.effect {
        Effect::None => {}
        Effect::Viscoelastic(r) => relax = r.clone(),
        Effect::Kinetic(law) => {
            spec.law = match *law {
                KineticLaw::Stribeck {
                    static_p_n_per_m,
                    static_n_n_per_m,
                    v_s_mps,
                    exponent,
                } => KineticLaw::Stribeck {
                    static_p_n_per_m: static_p_n_per_m * friction_scale,
                    static_n_n_per_m: static_n_n_per_m * friction_scale,
                    v_s_mps,
                    exponent,
                },
                ref other => other.clone(),
            }
        }
        Effect::Dahl {
            presliding_m,
            alpha,
        } => {
            spec.pre = Pre::Dahl {
                presliding_m: *presliding_m,
                alpha: *alpha,
            }
        }
        Effect::LuGre {
            presliding_m,
            damping_s,
            v_s_mps,
        } => {
            spec.pre = Pre::LuGre {
                presliding_m: *presliding_m,
                damping_s: *damping_s,
                v_s_mps: *v_s_mps,
            }
        }
        Effect::Structures(st) => {
            let mut rw = stream(seed, i, S_WALLS);
            let lo = spec.curve.u_end() + 1e-3;
            let hi = case.depth_past_surface_m - 0.8e-3;
            let count = rw.gen_range(st.count.0..=st.count.1);
            let slot = (hi - lo) / count.max(1) as f64;
            for k in 0..count {
                let rupture = uniform(&mut rw, st.rupture_n);
                let span0 = uniform(&mut rw, st.span_m);
                let offset = uniform(&mut rw, (0.0, 1.0));
                // Each wall within its own slot of the depth left after
                // the puncture, stiffness and rupture force kept in range.
                let span = span0.min(slot - 0.6e-3);
                if span < st.span_m.0 {
                    continue;
                }
                let k_n_per_m = (rupture / span)
                    .clamp(st.k_n_per_m.0.max(st.rupture_n.0 / span), st.k_n_per_m.1);
                let rupture = k_n_per_m * span;
                let room = slot - span - 0.5e-3;
                let curve = if st.septum {
                    LoadCurve::sharp(0.0, rupture / (span * span), span)
                } else {
                    LoadCurve::sharp(k_n_per_m, 0.0, span)
                };
                spec.walls.push(Wall {
                    d_m: lo + slot * k as f64 + offset * room,
                    curve,
                    kind: "structure",
                });
            }
            let mut rs = stream(seed, i, S_SHAFT);
            spec.shaft = Some(ShaftProfile {
                amp: st.friction_variation,
                terms: (0..3)
                    .map(|_| {
                        (
                            uniform(&mut rs, (6e-3, 25e-3)),
                            uniform(&mut rs, (0.0, 2.0 * PI)),
                        )
                    })
                    .collect(),
            });
        }
        Effect::CuttingLinear { per_m } => {
            if let Tip::Cutting { modulation, .. } = &mut tip {
                *modulation = CutMod::Linear { per_m: *per_m };
            }
        }
        Effect::CuttingRandomWalk { sd, corr_len_m } => {
            let mut rc = stream(seed, i, S_CUT);
            let step_m = 1e-4;
            let a = (-step_m / corr_len_m).exp();
            let mut x = sd * z(&mut rc);
            let values = (0..1200)
                .map(|_| {
                    let v = (x - sd * sd / 2.0).exp();
                    x = a * x + sd * (1.0 - a * a).sqrt() * z(&mut rc);
                    v
                })
                .collect();
            if let Tip::Cutting { modulation, .. } = &mut tip {
                *modulation = CutMod::Grid { step_m, values };
            }
        }
        Effect::RigidHolder { mass_kg } => spec.holder = Holder::Rigid { mass_kg: *mass_kg },
        Effect::CompliantHolder {
            mass_kg,
            f_hz,
            zeta,
        } => {
            let k = mass_kg * (2.0 * PI * f_hz).powi(2);
            spec.holder = Holder::Compliant {
                mass_kg: *mass_kg,
                k_n_per_m: k,
                c_n_s_per_m: 2.0 * zeta * (k * mass_kg).sqrt(),
            };
            spec.dt_max_s = spec.dt_max_s.min(2.5e-4);
        }
        Effect::LinearDrift { n_per_s } => spec.drift = Drift::Linear { n_per_s: *n_per_s },
        Effect::ThermalDrift { amp_n, tau_s } => {
            spec.drift = Drift::Thermal {
                amp_n: *amp_n,
                tau_s: *tau_s,
            }
        }
        Effect::SinusoidMotion { amp_m, freq_hz } => {
            let mut rm = stream(seed, i, S_MOTION);
            spec.motion = Some(MotionPath::Sinusoid {
                amp_m: *amp_m,
                freq_hz: *freq_hz,
                phase: uniform(&mut rm, (0.0, 2.0 * PI)),
            });
        }
        Effect::BreathingMotion {
            amp_m,
            period_s,
            period_cv,
            power_n,
        } => {
            let mut rm = stream(seed, i, S_MOTION);
            let mut breaths = Vec::new();
            let mut t0 = -uniform(&mut rm, (0.0, *period_s));
            while t0 < t_end_s + 1.0 {
                let p = period_s * (1.0 + period_cv * z(&mut rm)).max(0.5);
                let b = 2.0 * amp_m * (1.0 + 0.1 * z(&mut rm));
                breaths.push((t0, p, b));
                t0 += p;
            }
            // Mean of cos^(2n) over a breath: (2n−1)!!/(2n)!!.
            let mean: f64 = (1..=*power_n)
                .map(|k| (2 * k - 1) as f64 / (2 * k) as f64)
                .product();
            spec.motion = Some(MotionPath::Breathing {
                breaths,
                power_n: *power_n,
                offset_m: 2.0 * amp_m * mean,
            });
        }
    }
    spec.tip = tip;
    spec.relax = relax;

    let params = json!({
        "speed_mps": v_mps,
        "rate_hz": case.rate_hz,
        "x_surface_m": x_surface,
        "puncture_force_target_n": peak_target_n,
        "puncture_deflection_m": u_peak,
        "set_m": set_m,
        "friction_scale": friction_scale,
        "tip": format!("{:?}", spec.tip).chars().take(200).collect::<String>(),
        "relaxation_form": spec.relax.form,
        "relaxation_loss_at_dwell": 1.0 - spec.relax.g(case.dwell_s),
        "tent_k_n_per_m": spec.tent.map(|t| t.0),
        "pull_capacity_n": spec.tent.map(|t| t.1 * (case.depth_past_surface_m - set_m)),
        "walls": spec.walls.iter().map(|w| json!({"d_m": w.d_m, "peak_n": w.curve.peak()})).collect::<Vec<_>>(),
        "tare_n": tare_n,
        "noise_n": case.noise_n,
    });
    let info = Info {
        peak_target_n,
        withdrawal_start_s: spec.traj.phase_start_s("withdrawal").unwrap_or(t_end_s),
        params,
    };
    (spec, info)
}

fn generate_trial(case: &Case, i: usize, seed: u64) -> Trial {
    let (spec, info) = build_spec(case, i, seed);
    // The wall's elastic law is scaled so that the force it actually
    // reaches (relaxed, yielding) is the drawn puncture force.
    let probe = sim::run(&spec, 1.0, true);
    let scale = info.peak_target_n / probe.membrane_peak_n.max(1e-9);
    let out = sim::run(&spec, scale, false);
    let events = extract_events(&spec, &out, info.withdrawal_start_s);
    let mut rn = stream(seed, i, S_NOISE);
    let f_n = out
        .f_clean_n
        .iter()
        .map(|f| {
            let e: f64 = rn.sample(StandardNormal);
            f + case.noise_n * e
        })
        .collect();
    let mut effects = case.effects.clone();
    if !spec.walls.is_empty() && !effects.contains(&"internal_structures") {
        effects.push("internal_structures");
    }
    let mut baseline_traits = vec!["spread_between_trials", "permanent_set_after_puncture"];
    if case.protocol == Protocol::InsertDwellWithdraw {
        baseline_traits.extend(["timing_jitter_and_gaps", "tare_offset", "stage_coordinates"]);
    }
    if case.drag.is_some() {
        baseline_traits.push("dragged_withdrawal");
    }
    Trial {
        t_s: spec.t_s.clone(),
        x_m: out.x_rec_m,
        f_n,
        events,
        case: case.name.clone(),
        protocol: case.protocol,
        effects,
        baseline_traits,
        params: info.params,
    }
}

fn extract_events(spec: &Spec, out: &sim::RunOut, withdrawal_start_s: f64) -> Vec<Event> {
    let t = &spec.t_s;
    let f = &out.f_clean_n;
    let x = &out.x_rec_m;
    let n = f.len();
    let mut events = Vec::new();
    let Some(k_contact) = out.d_tip_m.iter().position(|&d| d > 0.0) else {
        return events;
    };
    events.push(Event {
        kind: "contact",
        t_s: t[k_contact],
        x_m: x[k_contact],
        peak_t_s: t[k_contact],
    });
    let first_at = |t_s: f64| t.partition_point(|&ti| ti < t_s - 1e-12).min(n - 1);
    for r in &out.ruptures {
        let k_after = first_at(r.t_s).max(1);
        let k_win = first_at(r.window_start_s).min(k_after - 1);
        let argmax =
            |a: usize, b: usize| (a..=b).max_by(|&i, &j| f[i].total_cmp(&f[j])).unwrap_or(b);
        if r.sharp {
            let k_pk = argmax(k_win, k_after - 1);
            let f_before = f[k_after - 1];
            let span = ((0.02 / (t[k_after] - t[k_after - 1]).max(1e-6)) as usize).max(3);
            let end = (k_after + span).min(n - 1);
            let f_min = f[k_after..=end]
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min);
            let drop = f_before - f_min;
            let k_fall = (k_after..=end)
                .find(|&k| f[k] < f_before - 0.5 * drop)
                .unwrap_or(k_after);
            events.push(Event {
                kind: r.kind,
                t_s: t[k_fall],
                x_m: x[k_fall],
                peak_t_s: t[k_pk],
            });
        } else {
            let k_pk = argmax(k_win, k_after);
            events.push(Event {
                kind: r.kind,
                t_s: t[k_pk],
                x_m: x[k_pk],
                peak_t_s: t[k_pk],
            });
        }
    }
    let x_contact = x[k_contact];
    let k_w = first_at(withdrawal_start_s);
    if let Some(k_exit) = (k_w..n).find(|&k| x[k] <= x_contact) {
        events.push(Event {
            kind: "exit",
            t_s: t[k_exit],
            x_m: x[k_exit],
            peak_t_s: t[k_exit],
        });
    }
    events.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    events
}

/// trial_000.csv … and truth.json.
pub fn write_dataset(dir: &Path, trials: &[Trial]) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut truth = Vec::with_capacity(trials.len());
    for (i, tr) in trials.iter().enumerate() {
        let file = format!("trial_{i:03}.csv");
        let mut w = std::io::BufWriter::new(std::fs::File::create(dir.join(&file))?);
        writeln!(w, "t_s,x_m,f_n")?;
        for k in 0..tr.t_s.len() {
            writeln!(w, "{},{},{}", tr.t_s[k], tr.x_m[k], tr.f_n[k])?;
        }
        w.flush()?;
        truth.push(json!({
            "file": file,
            "case": tr.case,
            "protocol": tr.protocol.tag(),
            "events": tr.events.iter().map(|e| json!({
                "kind": e.kind,
                "t_s": e.t_s,
                "x_m": e.x_m,
                "peak_t_s": e.peak_t_s,
            })).collect::<Vec<_>>(),
            "effects": tr.effects,
            "baseline_traits": tr.baseline_traits,
            "params": tr.params,
        }));
    }
    let doc = json!({
        "generator": "apart (independent validation data; never tune on it)",
        "trials": truth,
    });
    std::fs::write(
        dir.join("truth.json"),
        serde_json::to_string_pretty(&doc).map_err(std::io::Error::other)? + "\n",
    )
}
