//! The candidate effects, one per DESIGN.md §4 name: each is a few columns
//! added to the nominal model, built from the trial's kinematics and the
//! nominal model's own terms, linear in their parameters and with at most
//! one nonlinear parameter searched on a grid. The forms are the physics of
//! each effect in general (a relaxing branch, a speed-dependent damping, a
//! lagging friction, a stiff wall that gives way, cutting that grows with
//! depth, a mass, an offset growing in time, a periodic tissue motion), not
//! the simulator's exact formulas.

use std::f64::consts::TAU;

use super::prepare::{Prepared, LOADING};

/// One candidate effect.
pub struct Candidate {
    pub effect: &'static str,
    /// Name and grid of its nonlinear parameter (one value if none).
    pub grid_name: &'static str,
    pub grid: &'static [f64],
    /// Names of the linear parameters, one per column.
    pub linear: &'static [&'static str],
    /// Columns (one vector per linear parameter) for a trial at a grid value.
    pub columns: fn(&Prepared, f64) -> Vec<Vec<f64>>,
}

/// All candidates, DESIGN.md order.
pub const CANDIDATES: [Candidate; 8] = [
    Candidate {
        effect: "viscoelasticity",
        grid_name: "tau_s",
        grid: &[0.25, 0.5, 1.0, 2.0, 4.0],
        linear: &["k_n_per_m"],
        columns: maxwell,
    },
    Candidate {
        effect: "rate_dependent_friction",
        grid_name: "exponent_minus_1",
        grid: &[-0.75, -0.5, -0.25, 0.5],
        linear: &["b_extra_ns_per_m2", "b_correction_ns_per_m2"],
        columns: rate_friction,
    },
    Candidate {
        effect: "presliding_hysteresis",
        grid_name: "x_c_m",
        grid: &[0.0001, 0.0003, 0.001, 0.003],
        linear: &["lag_gain"],
        columns: friction_lag,
    },
    Candidate {
        effect: "internal_structures",
        grid_name: "k_n_per_m",
        grid: &[100.0, 200.0, 400.0, 800.0],
        linear: &["wall_gain"],
        columns: walls,
    },
    Candidate {
        effect: "depth_dependent_cutting",
        grid_name: "none",
        grid: &[0.0],
        linear: &["cutting_per_m_n_per_m", "cutting_correction_n"],
        columns: depth_cutting,
    },
    Candidate {
        effect: "holder_inertia",
        grid_name: "none",
        grid: &[0.0],
        linear: &["mass_kg", "mass_smooth_kg"],
        columns: inertia,
    },
    Candidate {
        effect: "sensor_drift",
        grid_name: "none",
        grid: &[0.0],
        linear: &["rate_n_per_s"],
        columns: drift,
    },
    Candidate {
        effect: "tissue_motion",
        grid_name: "freq_hz",
        grid: &[0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5],
        linear: &["sin_n", "cos_n", "sin_stiffness_m", "cos_stiffness_m"],
        columns: tissue_motion,
    },
];

/// Maxwell branch state: dm/dt = v − m/τ in tissue (θ = its stiffness).
fn maxwell(p: &Prepared, tau_s: f64) -> Vec<Vec<f64>> {
    let dt = 1.0 / p.trial.rate_hz();
    let mut m = 0.0;
    let col = (0..p.trial.len())
        .map(|i| {
            m = if p.in_tissue(i) {
                m + (p.v_mps[i] - m / tau_s) * dt
            } else {
                0.0
            };
            m
        })
        .collect();
    vec![col]
}

/// Sliding damping l·v·(|v|/v_ref)^q beside l·v itself.
fn rate_friction(p: &Prepared, q: f64) -> Vec<Vec<f64>> {
    let n = p.trial.len();
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        let (v, l) = (p.v_mps[i], p.length_m[i]);
        if l > 0.0 && v.abs() > 0.0005 {
            a[i] = l * v * (v.abs() / 0.003).powf(q);
            b[i] = l * v;
        }
    }
    vec![a, b]
}

/// Friction following the nominal Karnopp value with a lag over x_c of
/// travel, minus the nominal friction.
fn friction_lag(p: &Prepared, x_c: f64) -> Vec<Vec<f64>> {
    let mut lagged = 0.0;
    let col = (0..p.trial.len())
        .map(|i| {
            let target = p.friction_n[i];
            if p.length_m[i] <= 0.0 {
                lagged = 0.0;
                return 0.0;
            }
            let dx = if i > 0 {
                (p.trial.x_m[i] - p.trial.x_m[i - 1]).abs()
            } else {
                0.0
            };
            lagged += (target - lagged) * (dx / x_c).min(1.0);
            lagged - target
        })
        .collect();
    vec![col]
}

/// Walls where the detector found them: a force rising at k per metre up
/// to the wall force seen falling there.
fn walls(p: &Prepared, k: f64) -> Vec<Vec<f64>> {
    let mut col = vec![0.0; p.trial.len()];
    for &(peak, x_peak, wall_n) in &p.structures {
        let start = x_peak - wall_n / k;
        for i in (0..=peak).rev() {
            let x = p.trial.x_m[i];
            if x < start {
                break;
            }
            col[i] += wall_n - k * (x_peak - x);
        }
    }
    vec![col]
}

/// Cutting growing with depth past the surface, beside a cutting offset.
fn depth_cutting(p: &Prepared, _: f64) -> Vec<Vec<f64>> {
    let n = p.trial.len();
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        if p.cutting[i] {
            a[i] = p.trial.x_m[i] - p.geometry.contact_x_m;
            b[i] = 1.0;
        }
    }
    vec![a, b]
}

/// Acceleration two ways: the step of the needle velocity into each
/// sample (a start or stop is one sample of the whole speed change, as
/// the velocity the force law uses has it), and over ±10 ms (a smooth
/// stroke, without the encoder's quantisation, which a second difference
/// of positions turns into tens of mN at 0.15 kg).
fn inertia(p: &Prepared, _: f64) -> Vec<Vec<f64>> {
    let n = p.trial.len();
    let rate = p.trial.rate_hz();
    let k = ((0.01 * rate).round() as usize).max(1);
    let v = &p.v_mps;
    let step = (0..n)
        .map(|i| {
            if i == 0 {
                0.0
            } else {
                (v[i] - v[i - 1]) * rate
            }
        })
        .collect();
    let smooth = (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(k), (i + k).min(n - 1));
            if b > a {
                (v[b] - v[a]) * rate / (b - a) as f64
            } else {
                0.0
            }
        })
        .collect();
    vec![step, smooth]
}

/// An offset growing in time since the recording began.
fn drift(p: &Prepared, _: f64) -> Vec<Vec<f64>> {
    vec![p.trial.t_s.iter().map(|t| t - p.trial.t_s[0]).collect()]
}

/// Periodic motion of the tissue at f: a sinusoid while in tissue, and
/// the same moving the capsule along its stiffness while loading.
#[allow(clippy::needless_range_loop)] // four columns filled per sample
fn tissue_motion(p: &Prepared, f_hz: f64) -> Vec<Vec<f64>> {
    let n = p.trial.len();
    let mut cols = vec![vec![0.0; n]; 4];
    for i in 0..n {
        if !p.in_tissue(i) {
            continue;
        }
        let w = TAU * f_hz * (p.trial.t_s[i] - p.trial.t_s[0]);
        let (s, c) = w.sin_cos();
        cols[0][i] = s;
        cols[1][i] = c;
        if p.phase[i] == LOADING && i > 0 && i + 1 < n {
            let dx = p.trial.x_m[i + 1] - p.trial.x_m[i - 1];
            let slope = if dx.abs() > 1e-7 {
                (p.nominal_n[i + 1] - p.nominal_n[i - 1]) / dx
            } else {
                0.0
            };
            cols[2][i] = s * slope;
            cols[3][i] = c * slope;
        }
    }
    cols
}
