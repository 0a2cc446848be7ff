//! Constitutive laws: relaxation, friction, load curves, organ motion,
//! stage trajectories. Numbers and their sources are in `mod.rs` and the
//! README beside it.

use std::f64::consts::PI;

/// Reduced relaxation function G(t) = g_inf + Σ g_i·exp(−t/τ_i), G(0) = 1.
/// Every form here (Prony, power law, Fung's QLV) is held as such a sum:
/// the power law and QLV's continuous spectrum are discretised in log τ
/// (the standard way to integrate a hereditary law in time), so one
/// recursive update serves all forms.
#[derive(Clone, Debug)]
pub struct Relaxation {
    pub form: &'static str,
    pub g_inf: f64,
    /// (g_i, τ_i in s)
    pub branches: Vec<(f64, f64)>,
}

impl Relaxation {
    pub fn elastic() -> Self {
        Relaxation {
            form: "elastic",
            g_inf: 1.0,
            branches: Vec::new(),
        }
    }

    pub fn is_elastic(&self) -> bool {
        self.branches.is_empty()
    }

    pub fn g(&self, t_s: f64) -> f64 {
        self.g_inf
            + self
                .branches
                .iter()
                .map(|&(g, tau_s)| g * (-t_s / tau_s).exp())
                .sum::<f64>()
    }

    /// Prony series with the given time constants and relative weights,
    /// scaled so that a force held from t = 0 has lost `loss` at `hold_s`.
    pub fn prony(taus_s: &[f64], weights: &[f64], loss: f64, hold_s: f64) -> Self {
        let raw: f64 = taus_s
            .iter()
            .zip(weights)
            .map(|(tau_s, w)| w * (1.0 - (-hold_s / tau_s).exp()))
            .sum();
        let k = loss / raw;
        let branches: Vec<(f64, f64)> = taus_s
            .iter()
            .zip(weights)
            .map(|(&tau_s, &w)| (w * k, tau_s))
            .collect();
        let g_inf = 1.0 - branches.iter().map(|b| b.0).sum::<f64>();
        assert!(g_inf > 0.0, "Prony weights exceed G(0) = 1");
        Relaxation {
            form: "prony",
            g_inf,
            branches,
        }
    }

    /// G(t) = (1 + t/t0)^−n, written as its Laplace spectrum
    /// (1/Γ(n))∫ s^(n−1) e^(−s(1 + t/t0)) ds sampled in log s; n is solved
    /// on the discretised G so that the held force loses `loss` at `hold_s`.
    pub fn power_law(t0_s: f64, loss: f64, hold_s: f64) -> Self {
        let build = |n: f64| {
            let m = 44;
            let (lo, hi) = (1e-6_f64.ln(), 25.0_f64.ln());
            let mut branches = Vec::with_capacity(m);
            let mut total = 0.0;
            for k in 0..m {
                let s = (lo + (hi - lo) * (k as f64 + 0.5) / m as f64).exp();
                let w = s.powf(n) * (-s).exp();
                total += w;
                branches.push((w, t0_s / s));
            }
            for b in &mut branches {
                b.0 /= total;
            }
            Relaxation {
                form: "power_law",
                g_inf: 0.0,
                branches,
            }
        };
        let n = bisect(0.01, 1.5, |n| 1.0 - build(n).g(hold_s) - loss);
        build(n)
    }

    /// Fung's reduced relaxation function with a box spectrum between τ1
    /// and τ2: G(t) = [1 + c(E1(t/τ2) − E1(t/τ1))]/[1 + c·ln(τ2/τ1)];
    /// c solved so that the held force loses `loss` at `hold_s`.
    pub fn qlv(tau1_s: f64, tau2_s: f64, loss: f64, hold_s: f64) -> Self {
        let build = |c: f64| {
            let m = 16;
            let span = (tau2_s / tau1_s).ln();
            let norm = 1.0 + c * span;
            let branches = (0..m)
                .map(|k| {
                    let tau_s = tau1_s * (span * (k as f64 + 0.5) / m as f64).exp();
                    (c * span / m as f64 / norm, tau_s)
                })
                .collect();
            Relaxation {
                form: "qlv",
                g_inf: 1.0 / norm,
                branches,
            }
        };
        let c = bisect(1e-4, 50.0, |c| 1.0 - build(c).g(hold_s) - loss);
        build(c)
    }
}

/// Root of an increasing function on [lo, hi].
pub fn bisect(mut lo: f64, mut hi: f64, f: impl Fn(f64) -> f64) -> f64 {
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if f(mid) > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Per-step factors of a relaxation law, computed once per time step and
/// shared by every relaxing force.
pub struct StepFactors {
    pub decay: Vec<f64>,
    pub phi: Vec<f64>,
}

impl StepFactors {
    pub fn new(r: &Relaxation) -> Self {
        StepFactors {
            decay: vec![1.0; r.branches.len()],
            phi: vec![1.0; r.branches.len()],
        }
    }

    pub fn update(&mut self, r: &Relaxation, h_s: f64) {
        for (i, &(_, tau_s)) in r.branches.iter().enumerate() {
            let x = h_s / tau_s;
            self.decay[i] = (-x).exp();
            // A ramp of the input over the step, integrated exactly.
            self.phi[i] = if x > 1e-9 {
                (1.0 - self.decay[i]) / x
            } else {
                1.0
            };
        }
    }
}

/// A force obeying the hereditary integral F(t) = ∫ G(t−s) dE(s), E the
/// elastic (instantaneous) force.
#[derive(Clone, Debug, Default)]
pub struct Relaxing {
    e: f64,
    h: Vec<f64>,
}

impl Relaxing {
    pub fn new(r: &Relaxation) -> Self {
        Relaxing {
            e: 0.0,
            h: vec![0.0; r.branches.len()],
        }
    }

    pub fn value(&self, r: &Relaxation) -> f64 {
        r.g_inf * self.e + self.h.iter().sum::<f64>()
    }

    /// Freshly loaded material (a steady cutting or sliding process keeps
    /// renewing the material it loads, so it carries no relaxed history).
    pub fn reset(&mut self, r: &Relaxation, v: f64) {
        self.e = v;
        for (h, &(g, _)) in self.h.iter_mut().zip(&r.branches) {
            *h = g * v;
        }
    }

    pub fn load(&mut self, r: &Relaxation, f: &StepFactors, new_e: f64) {
        let de = new_e - self.e;
        for (i, h) in self.h.iter_mut().enumerate() {
            *h = *h * f.decay[i] + r.branches[i].0 * de * f.phi[i];
        }
        self.e = new_e;
    }
}

/// Friction per unit length of needle in tissue (Karnopp, Okamura et al.).
#[derive(Clone, Copy, Debug)]
pub struct Friction {
    pub c_p_n_per_m: f64,
    pub c_n_n_per_m: f64,
    pub d_p_n_per_m: f64,
    pub d_n_n_per_m: f64,
    pub b_p_n_s_per_m2: f64,
    pub b_n_n_s_per_m2: f64,
    pub dv_half_mps: f64,
}

impl Friction {
    pub fn scaled(self, k: f64) -> Self {
        Friction {
            c_p_n_per_m: self.c_p_n_per_m * k,
            c_n_n_per_m: self.c_n_n_per_m * k,
            d_p_n_per_m: self.d_p_n_per_m * k,
            d_n_n_per_m: self.d_n_n_per_m * k,
            b_p_n_s_per_m2: self.b_p_n_s_per_m2 * k,
            b_n_n_s_per_m2: self.b_n_n_s_per_m2 * k,
            dv_half_mps: self.dv_half_mps,
        }
    }

    pub fn karnopp_per_m(&self, v_mps: f64) -> f64 {
        if v_mps > 0.0 {
            self.c_p_n_per_m + self.b_p_n_s_per_m2 * v_mps
        } else {
            self.c_n_n_per_m + self.b_n_n_s_per_m2 * v_mps
        }
    }
}

/// Velocity law of the sliding friction.
#[derive(Clone, Debug)]
pub enum KineticLaw {
    /// C + b·v (the paper's model).
    Karnopp,
    /// sgn(v)[C + (S − C)·exp(−(|v|/v_s)^δ)] + b·v (Stribeck curve).
    Stribeck {
        static_p_n_per_m: f64,
        static_n_n_per_m: f64,
        v_s_mps: f64,
        exponent: f64,
    },
    /// k·(|v|/v_ref)^n, k = C + b·v_ref (damping falling with speed).
    PowerLaw { n: f64, v_ref_mps: f64 },
}

pub fn kinetic_per_m(f: &Friction, law: &KineticLaw, v_mps: f64) -> f64 {
    match *law {
        KineticLaw::Karnopp => f.karnopp_per_m(v_mps),
        KineticLaw::Stribeck {
            static_p_n_per_m,
            static_n_n_per_m,
            v_s_mps,
            exponent,
        } => {
            let w = (-(v_mps.abs() / v_s_mps).powf(exponent)).exp();
            if v_mps > 0.0 {
                f.c_p_n_per_m + (static_p_n_per_m - f.c_p_n_per_m) * w + f.b_p_n_s_per_m2 * v_mps
            } else {
                f.c_n_n_per_m + (static_n_n_per_m - f.c_n_n_per_m) * w + f.b_n_n_s_per_m2 * v_mps
            }
        }
        KineticLaw::PowerLaw { n, v_ref_mps } => {
            let r = (v_mps.abs() / v_ref_mps).powf(n);
            if v_mps > 0.0 {
                (f.c_p_n_per_m + f.b_p_n_s_per_m2 * v_ref_mps) * r
            } else {
                (f.c_n_n_per_m - f.b_n_n_s_per_m2 * v_ref_mps) * r
            }
        }
    }
}

/// Force–deflection law of a membrane or wall loaded by the needle tip,
/// unscaled: f0(u) = a1·u + a2·u², then (optionally) the tissue yields:
/// the slope falls to zero over `flat_m` (flattening), the force eases by
/// `ease_frac` over `ease_m`, and the wall fails (sharp fall); or, with
/// `roll`, the force rolls over to `to_frac` of its peak within `roll_m`
/// and the wall gives way without a fall. `dips` are micro-slips of the
/// membrane under the tip: at deflection `at` the origin moves by `du`.
#[derive(Clone, Debug)]
pub struct LoadCurve {
    pub a1: f64,
    pub a2: f64,
    pub flat_m: f64,
    pub u_peak_m: f64,
    pub ease_m: f64,
    pub ease_frac: f64,
    pub roll: Option<(f64, f64)>,
    pub dips: Vec<(f64, f64)>,
}

impl LoadCurve {
    pub fn sharp(a1: f64, a2: f64, u_peak_m: f64) -> Self {
        LoadCurve {
            a1,
            a2,
            flat_m: 0.0,
            u_peak_m,
            ease_m: 0.0,
            ease_frac: 0.0,
            roll: None,
            dips: Vec::new(),
        }
    }

    fn f0(&self, u: f64) -> f64 {
        self.a1 * u + self.a2 * u * u
    }

    fn slope0(&self, u: f64) -> f64 {
        self.a1 + 2.0 * self.a2 * u
    }

    /// Deflection past which the wall has failed.
    pub fn u_end(&self) -> f64 {
        match self.roll {
            Some((roll_m, _)) => self.u_peak_m + roll_m,
            None => self.u_peak_m + self.ease_m,
        }
    }

    pub fn peak(&self) -> f64 {
        let u_y = self.u_peak_m - self.flat_m;
        self.f0(u_y) + self.slope0(u_y) * self.flat_m / 2.0
    }

    /// Deflection net of the micro-slips so far.
    pub fn effective(&self, u_raw: f64) -> f64 {
        u_raw
            - self
                .dips
                .iter()
                .filter(|d| u_raw >= d.0)
                .map(|d| d.1)
                .sum::<f64>()
    }

    pub fn force(&self, u_raw: f64) -> f64 {
        let u = self.effective(u_raw).max(0.0);
        let u_y = self.u_peak_m - self.flat_m;
        if u <= u_y {
            return self.f0(u);
        }
        if u <= self.u_peak_m {
            let x = u - u_y;
            let s = self.slope0(u_y);
            return self.f0(u_y) + s * x - s * x * x / (2.0 * self.flat_m);
        }
        let pk = self.peak();
        let x = u - self.u_peak_m;
        match self.roll {
            Some((roll_m, to_frac)) => {
                let q = (x / roll_m).min(1.0);
                pk * (1.0 - (1.0 - to_frac) * (1.0 - (PI * q).cos()) / 2.0)
            }
            None if self.ease_m > 0.0 => {
                let q = (x / self.ease_m).min(1.0);
                pk * (1.0 - self.ease_frac * q * q)
            }
            None => pk,
        }
    }
}

/// Displacement of the organ along the needle axis (positive: away from
/// the needle, deeper).
#[derive(Clone, Debug)]
pub enum MotionPath {
    Sinusoid {
        amp_m: f64,
        freq_hz: f64,
        phase: f64,
    },
    /// Lujan et al. (1999): z(t) = z0 − b·cos^(2n)(πt/τ − φ), with a period
    /// and depth drawn per breath (irregular breathing). Breaths join at
    /// end-exhale, where cos = 0, so the path is continuous.
    Breathing {
        /// (start time, period, depth b) of each breath
        breaths: Vec<(f64, f64, f64)>,
        power_n: i32,
        offset_m: f64,
    },
}

impl MotionPath {
    pub fn displacement_m(&self, t_s: f64) -> f64 {
        match self {
            MotionPath::Sinusoid {
                amp_m,
                freq_hz,
                phase,
            } => amp_m * ((2.0 * PI * freq_hz * t_s + phase).sin() - phase.sin()),
            MotionPath::Breathing {
                breaths,
                power_n,
                offset_m,
            } => {
                let i = breaths.partition_point(|b| b.0 <= t_s).saturating_sub(1);
                let (t0, period, b) = breaths[i];
                let theta = PI / 2.0 + PI * (t_s - t0) / period;
                b * theta.cos().powi(2 * power_n) - offset_m
            }
        }
    }

    pub fn velocity_mps(&self, t_s: f64) -> f64 {
        let h = 1e-4;
        (self.displacement_m(t_s + h) - self.displacement_m(t_s - h)) / (2.0 * h)
    }
}

/// Stage (drive) trajectory: holds, trapezoidal moves with a bounded
/// acceleration, and the sinusoid x0 − A(1 − cos ωt) (which starts at rest
/// and never passes the depth it started from, so it cuts no new tissue).
#[derive(Clone, Debug)]
pub enum Seg {
    Hold {
        x_m: f64,
    },
    Move {
        x0_m: f64,
        x1_m: f64,
        v_mps: f64,
        a_mps2: f64,
    },
    Osc {
        x0_m: f64,
        amp_m: f64,
        omega: f64,
    },
}

impl Seg {
    pub fn duration_s(&self, hold_s: f64) -> f64 {
        match *self {
            Seg::Hold { .. } => hold_s,
            Seg::Move {
                x0_m,
                x1_m,
                v_mps,
                a_mps2,
            } => {
                let dist = (x1_m - x0_m).abs();
                if dist < v_mps * v_mps / a_mps2 {
                    2.0 * (dist / a_mps2).sqrt()
                } else {
                    dist / v_mps + v_mps / a_mps2
                }
            }
            Seg::Osc { .. } => hold_s,
        }
    }

    /// (x, v, a) at time tau into the segment.
    fn eval(&self, tau: f64, dur: f64) -> (f64, f64, f64) {
        match *self {
            Seg::Hold { x_m } => (x_m, 0.0, 0.0),
            Seg::Move {
                x0_m,
                x1_m,
                v_mps,
                a_mps2,
            } => {
                let sgn = (x1_m - x0_m).signum();
                let dist = (x1_m - x0_m).abs();
                let v_pk = v_mps.min((dist * a_mps2).sqrt());
                let t_acc = v_pk / a_mps2;
                let t = tau.clamp(0.0, dur);
                let (s, v, a) = if t < t_acc {
                    (0.5 * a_mps2 * t * t, a_mps2 * t, a_mps2)
                } else if t < dur - t_acc {
                    (0.5 * a_mps2 * t_acc * t_acc + v_pk * (t - t_acc), v_pk, 0.0)
                } else {
                    let r = dur - t;
                    (dist - 0.5 * a_mps2 * r * r, a_mps2 * r, -a_mps2)
                };
                (x0_m + sgn * s, sgn * v, sgn * a)
            }
            Seg::Osc { x0_m, amp_m, omega } => {
                let p = omega * tau;
                (
                    x0_m - amp_m * (1.0 - p.cos()),
                    -amp_m * omega * p.sin(),
                    -amp_m * omega * omega * p.cos(),
                )
            }
        }
    }
}

#[derive(Clone, Debug, Default)]
pub struct Trajectory {
    /// (start time, duration, segment, phase name)
    pub segs: Vec<(f64, f64, Seg, &'static str)>,
}

impl Trajectory {
    pub fn push(&mut self, seg: Seg, hold_s: f64, phase: &'static str) {
        let t0 = self.end_s();
        let dur = seg.duration_s(hold_s);
        self.segs.push((t0, dur, seg, phase));
    }

    pub fn end_s(&self) -> f64 {
        self.segs.last().map_or(0.0, |s| s.0 + s.1)
    }

    pub fn eval(&self, t_s: f64) -> (f64, f64, f64) {
        let i = self.segs.partition_point(|s| s.0 <= t_s).saturating_sub(1);
        let (t0, dur, ref seg, _) = self.segs[i];
        seg.eval(t_s - t0, dur)
    }

    /// Start time of the first segment of a phase.
    pub fn phase_start_s(&self, phase: &str) -> Option<f64> {
        self.segs.iter().find(|s| s.3 == phase).map(|s| s.0)
    }
}
