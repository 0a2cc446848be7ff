//! The time-stepping simulation of one trial, at fixed sub-steps between
//! the sample instants (so every sample is an exact state, not an
//! interpolation across a fall).

use super::physics::{
    kinetic_per_m, Friction, KineticLaw, LoadCurve, MotionPath, Relaxation, Relaxing, StepFactors,
    Trajectory,
};

/// Tip force after the first puncture.
#[derive(Clone, Debug)]
pub enum Tip {
    /// The paper's cutting force, while the tip advances into fresh tissue.
    Cutting { force_n: f64, modulation: CutMod },
    /// Measured layered-phantom shape: from `fall_n` the force climbs to
    /// `climb`× within ~`climb_m`, then drifts to `end_ratio`× by
    /// `end_depth_m` past the puncture.
    Profile {
        fall_n: f64,
        climb: f64,
        climb_m: f64,
        end_ratio: f64,
        end_depth_m: f64,
    },
}

#[derive(Clone, Debug)]
pub enum CutMod {
    None,
    Linear {
        per_m: f64,
    },
    /// Multiplier sampled every `step_m` of depth past the puncture.
    Grid {
        step_m: f64,
        values: Vec<f64>,
    },
}

impl Tip {
    pub fn force_n(&self, depth_past_m: f64) -> f64 {
        let p = depth_past_m.max(0.0);
        match self {
            Tip::Cutting {
                force_n,
                modulation,
            } => {
                force_n
                    * match modulation {
                        CutMod::None => 1.0,
                        CutMod::Linear { per_m } => 1.0 + per_m * p,
                        CutMod::Grid { step_m, values } => {
                            let x = p / step_m;
                            let i = (x as usize).min(values.len() - 2);
                            let q = (x - i as f64).min(1.0);
                            values[i] * (1.0 - q) + values[i + 1] * q
                        }
                    }
            }
            Tip::Profile {
                fall_n,
                climb,
                climb_m,
                end_ratio,
                end_depth_m,
            } => {
                let lam = climb_m / 3.5;
                let up = 1.0 + (climb - 1.0) * (1.0 - (-p / lam).exp());
                let q = ((p - climb_m) / (end_depth_m - climb_m).max(1e-3)).clamp(0.0, 1.0);
                let smooth = q * q * (3.0 - 2.0 * q);
                fall_n * (up + (end_ratio - climb) * smooth)
            }
        }
    }
}

/// Pre-sliding law of the needle–tissue interface.
#[derive(Clone, Debug)]
pub enum Pre {
    None,
    Dahl {
        presliding_m: f64,
        alpha: f64,
    },
    LuGre {
        presliding_m: f64,
        damping_s: f64,
        v_s_mps: f64,
    },
}

#[derive(Clone, Debug)]
pub enum Holder {
    None,
    Rigid {
        mass_kg: f64,
    },
    Compliant {
        mass_kg: f64,
        k_n_per_m: f64,
        c_n_s_per_m: f64,
    },
}

#[derive(Clone, Debug)]
pub enum Drift {
    None,
    Linear { n_per_s: f64 },
    Thermal { amp_n: f64, tau_s: f64 },
}

impl Drift {
    fn at(&self, t_s: f64) -> f64 {
        match *self {
            Drift::None => 0.0,
            Drift::Linear { n_per_s } => n_per_s * t_s,
            Drift::Thermal { amp_n, tau_s } => amp_n * (1.0 - (-t_s / tau_s).exp()),
        }
    }
}

/// An interior wall (vessel, septum, deeper membrane) at tissue depth d_m.
#[derive(Clone, Debug)]
pub struct Wall {
    pub d_m: f64,
    pub curve: LoadCurve,
    pub kind: &'static str,
}

/// Friction per unit length varying along the tissue depth y:
/// φ(y) = 1 + amp·(1/3)Σ sin(2πy/λ_j + p_j).
#[derive(Clone, Debug)]
pub struct ShaftProfile {
    pub amp: f64,
    pub terms: Vec<(f64, f64)>,
}

impl ShaftProfile {
    fn phi(&self, y: f64) -> f64 {
        let n = self.terms.len() as f64;
        1.0 + self.amp / n
            * self
                .terms
                .iter()
                .map(|&(lam, p)| (2.0 * std::f64::consts::PI * y / lam + p).sin())
                .sum::<f64>()
    }

    fn cumulative(&self, y: f64) -> f64 {
        let n = self.terms.len() as f64;
        let tau = 2.0 * std::f64::consts::PI;
        y - self.amp / n
            * self
                .terms
                .iter()
                .map(|&(lam, p)| lam / tau * ((tau * y / lam + p).cos() - p.cos()))
                .sum::<f64>()
    }
}

/// One trial, every random draw already made.
#[derive(Clone, Debug)]
pub struct Spec {
    pub t_s: Vec<f64>,
    pub traj: Trajectory,
    pub x_surface_m: f64,
    pub curve: LoadCurve,
    pub tip: Tip,
    pub friction: Friction,
    pub law: KineticLaw,
    pub pre: Pre,
    pub relax: Relaxation,
    pub set_m: f64,
    /// (tent stiffness, static pull-out capacity per unit length)
    pub tent: Option<(f64, f64)>,
    pub walls: Vec<Wall>,
    pub shaft: Option<ShaftProfile>,
    pub motion: Option<MotionPath>,
    pub holder: Holder,
    pub drift: Drift,
    pub tare_n: f64,
    pub encoder_m: f64,
    pub dt_max_s: f64,
}

#[derive(Clone, Debug)]
pub struct Rupture {
    pub kind: &'static str,
    pub t_s: f64,
    pub window_start_s: f64,
    pub sharp: bool,
}

#[derive(Clone, Debug, Default)]
pub struct RunOut {
    pub f_clean_n: Vec<f64>,
    pub x_rec_m: Vec<f64>,
    pub d_tip_m: Vec<f64>,
    pub ruptures: Vec<Rupture>,
    pub membrane_peak_n: f64,
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Phase {
    Outside,
    Loading,
    Inside,
    Out,
}

#[derive(Clone, Copy, Debug)]
enum Mode {
    Sliding,
    /// Held at e after rest_s at rest; the tissue around the shaft was at
    /// w0 when the needle was at d0 and moves with it while stuck.
    Stuck {
        e: f64,
        w0: f64,
        d0: f64,
        rest_s: f64,
    },
}

/// A wall being loaded: its relaxing force, when loading began, whether
/// it has failed, and where its (relaxed) force was highest.
#[derive(Clone, Debug)]
struct WallState {
    force: Relaxing,
    t_start: Option<f64>,
    done: bool,
    max_n: f64,
    u_at_max: f64,
}

impl WallState {
    fn new(r: &Relaxation) -> Self {
        WallState {
            force: Relaxing::new(r),
            t_start: None,
            done: false,
            max_n: f64::MIN,
            u_at_max: 0.0,
        }
    }

    fn track(&mut self, f: f64, u: f64) {
        if f > self.max_n {
            self.max_n = f;
            self.u_at_max = u;
        }
    }

    /// A yielding wall fails once the tip has gone `ease_m` past the
    /// point where the force it actually carries peaked (so a relaxing
    /// wall that peaks early still eases for the drawn travel); any wall
    /// fails at the end of its curve.
    fn failed(&self, c: &LoadCurve, u: f64) -> bool {
        let yielding = c.flat_m > 0.0 && c.roll.is_none();
        (yielding && u >= c.u_peak_m - c.flat_m && u >= self.u_at_max + c.ease_m) || u >= c.u_end()
    }
}

const CUT_CELL_M: f64 = 5e-5;

struct State {
    fac: StepFactors,
    membrane: WallState,
    iface: Relaxing,
    walls: Vec<WallState>,
    shaft_acc: Vec<f64>,
    cut_time_s: Vec<f64>,
    phase: Phase,
    xn: f64,
    vn: f64,
    f_cell: f64,
    f_tissue: f64,
    d_prev: f64,
    v_rel_prev: f64,
    d_max: f64,
    d_punct: f64,
    mode: Mode,
    pre_state: f64,
    break_offset_per_m: f64,
    break_slip_m: f64,
    w_tent: f64,
    lock: Option<(f64, f64)>,
    applied: Option<f64>,
    t_load_start: f64,
    membrane_peak: f64,
    scale: f64,
    ruptures: Vec<Rupture>,
}

pub fn run(s: &Spec, scale: f64, stop_at_puncture: bool) -> RunOut {
    let r = &s.relax;
    let (x0, v0, _) = s.traj.eval(s.t_s[0]);
    let mut st = State {
        fac: StepFactors::new(r),
        membrane: WallState::new(r),
        iface: Relaxing::new(r),
        walls: s.walls.iter().map(|_| WallState::new(r)).collect(),
        shaft_acc: vec![0.0; r.branches.len()],
        cut_time_s: vec![f64::NAN; 4000],
        phase: Phase::Outside,
        xn: x0,
        vn: v0,
        f_cell: 0.0,
        f_tissue: 0.0,
        d_prev: f64::NEG_INFINITY,
        v_rel_prev: 0.0,
        d_max: 0.0,
        d_punct: 0.0,
        mode: Mode::Sliding,
        pre_state: 0.0,
        break_offset_per_m: 0.0,
        break_slip_m: 0.0,
        w_tent: 0.0,
        lock: None,
        applied: None,
        t_load_start: 0.0,
        membrane_peak: 0.0,
        scale,
        ruptures: Vec::new(),
    };
    let n = s.t_s.len();
    let mut out = RunOut {
        f_clean_n: Vec::with_capacity(n),
        x_rec_m: Vec::with_capacity(n),
        d_tip_m: Vec::with_capacity(n),
        ..RunOut::default()
    };
    let (d0, f0) = st.step(s, s.t_s[0], 0.0);
    out.record(s, s.t_s[0], d0, f0);
    for k in 1..n {
        let (ta, tb) = (s.t_s[k - 1], s.t_s[k]);
        let m = ((tb - ta) / s.dt_max_s).ceil().max(1.0) as usize;
        let h = (tb - ta) / m as f64;
        let mut last = (0.0, 0.0);
        for j in 1..=m {
            let t = if j == m { tb } else { ta + h * j as f64 };
            last = st.step(s, t, h);
        }
        out.record(s, tb, last.0, last.1);
        if stop_at_puncture && !st.ruptures.is_empty() {
            break;
        }
    }
    out.ruptures = st.ruptures;
    out.membrane_peak_n = st.membrane_peak;
    out
}

impl RunOut {
    fn record(&mut self, s: &Spec, t_s: f64, d_m: f64, f_n: f64) {
        let (xd, _, _) = s.traj.eval(t_s);
        self.x_rec_m.push((xd / s.encoder_m).round() * s.encoder_m);
        self.f_clean_n.push(f_n);
        self.d_tip_m.push(d_m);
    }
}

fn signed_pow(y: f64, a: f64) -> f64 {
    y.signum() * y.abs().powf(a)
}

impl State {
    /// Advances to t_s over a step of h_s; returns (tip depth in the tissue
    /// frame, measured force without noise).
    fn step(&mut self, s: &Spec, t_s: f64, h_s: f64) -> (f64, f64) {
        let r = &s.relax;
        let (xd, vd, ad) = s.traj.eval(t_s);
        match s.holder {
            Holder::Compliant {
                mass_kg,
                k_n_per_m,
                c_n_s_per_m,
            } => {
                // A needle stuck in the tissue stays put while the mount
                // pushes within the static band (Karnopp: friction takes
                // the applied force), so a compliant mount cannot creep it.
                let held = self.lock.and_then(|(lo, hi)| {
                    let spring = k_n_per_m * (xd - self.xn) + c_n_s_per_m * vd;
                    (lo..=hi).contains(&spring).then_some(spring)
                });
                self.applied = held;
                if let Some(spring) = held {
                    self.vn = 0.0;
                    self.f_cell = spring;
                } else {
                    let spring = k_n_per_m * (xd - self.xn) + c_n_s_per_m * (vd - self.vn);
                    let an = (spring - self.f_tissue) / mass_kg;
                    self.vn += an * h_s;
                    self.xn += self.vn * h_s;
                    self.f_cell = k_n_per_m * (xd - self.xn) + c_n_s_per_m * (vd - self.vn);
                }
            }
            _ => {
                self.xn = xd;
                self.vn = vd;
            }
        }
        let (m_m, vm) = match &s.motion {
            Some(p) => (p.displacement_m(t_s), p.velocity_mps(t_s)),
            None => (0.0, 0.0),
        };
        let d = self.xn - s.x_surface_m - m_m;
        let v_rel = self.vn - vm;
        let dd = if self.d_prev.is_finite() {
            d - self.d_prev
        } else {
            0.0
        };
        if h_s > 0.0 {
            self.fac.update(r, h_s);
        }
        let f_tissue = match self.phase {
            Phase::Outside => {
                if d > 0.0 {
                    self.phase = Phase::Loading;
                    self.t_load_start = t_s;
                    self.loading(s, t_s, d, v_rel)
                } else {
                    0.0
                }
            }
            Phase::Loading => self.loading(s, t_s, d, v_rel),
            Phase::Inside => self.inside(s, t_s, h_s, d, dd, v_rel),
            Phase::Out => 0.0,
        };
        self.f_tissue = f_tissue;
        self.d_prev = d;
        if v_rel != 0.0 {
            self.v_rel_prev = v_rel;
        }
        let f_meas = match s.holder {
            Holder::None => f_tissue,
            Holder::Rigid { mass_kg } => f_tissue + mass_kg * ad,
            Holder::Compliant { .. } => self.f_cell,
        };
        (d, f_meas + s.drift.at(t_s) + s.tare_n)
    }

    fn loading(&mut self, s: &Spec, t_s: f64, d: f64, v_rel: f64) -> f64 {
        let r = &s.relax;
        let e = self.scale * s.curve.force(d.max(0.0));
        if self.fac.decay.is_empty() {
            self.membrane.force.reset(r, e);
        } else {
            self.membrane.force.load(r, &self.fac, e);
        }
        let f = self.membrane.force.value(r).max(0.0);
        let u = s.curve.effective(d);
        self.membrane.track(f, u);
        self.membrane_peak = self.membrane_peak.max(f);
        if self.membrane.failed(&s.curve, u) {
            self.ruptures.push(Rupture {
                kind: "puncture",
                t_s,
                window_start_s: self.t_load_start,
                sharp: s.curve.roll.is_none(),
            });
            self.membrane.force.reset(r, 0.0);
            self.phase = Phase::Inside;
            // The tip is now cutting: the tissue past where it was a step
            // ago is fresh.
            self.d_max = self.d_prev.min(d);
            self.d_punct = d;
            self.mode = Mode::Sliding;
            // The puncture itself is a steady sliding start: the shaft
            // has just entered and the tip is cutting.
            self.iface.reset(r, s.tip.force_n(0.0));
            // The channel the shaft now occupies was just opened.
            let l0 = (d - s.set_m).max(0.0);
            for a in self.shaft_acc.iter_mut() {
                *a = l0;
            }
            for c in 0..=Self::cell(d) {
                self.cut_time_s[c] = t_s;
            }
            let dd = d - self.d_max;
            return self.inside(s, t_s, 0.0, d, dd, v_rel);
        }
        f
    }

    fn shaft_length(&self, s: &Spec, surface: f64, d: f64) -> f64 {
        match &s.shaft {
            Some(p) => (p.cumulative(d) - p.cumulative(surface)).max(0.0),
            None => (d - surface).max(0.0),
        }
    }

    fn cell(d: f64) -> usize {
        ((d.max(0.0) / CUT_CELL_M) as usize).min(3999)
    }

    fn inside(&mut self, s: &Spec, t_s: f64, h_s: f64, d: f64, dd: f64, v_rel: f64) -> f64 {
        let r = &s.relax;
        // Interior walls.
        let mut f_walls = 0.0;
        for (w, ws) in s.walls.iter().zip(self.walls.iter_mut()) {
            if ws.done {
                continue;
            }
            let u = d - w.d_m;
            if u > 0.0 && ws.t_start.is_none() {
                ws.t_start = Some(t_s);
            }
            let Some(t_start) = ws.t_start else { continue };
            let e = w.curve.force(u.max(0.0));
            if self.fac.decay.is_empty() {
                ws.force.reset(r, e);
            } else {
                ws.force.load(r, &self.fac, e);
            }
            let f = ws.force.value(r).max(0.0);
            let u_eff = w.curve.effective(u);
            ws.track(f, u_eff);
            if ws.failed(&w.curve, u_eff) {
                self.ruptures.push(Rupture {
                    kind: w.kind,
                    t_s,
                    window_start_s: t_start,
                    sharp: w.curve.roll.is_none(),
                });
                ws.done = true;
                ws.force.reset(r, 0.0);
                continue;
            }
            f_walls += f;
        }

        // Shaft geometry.
        let surface = s.set_m + self.w_tent;
        if d - surface <= 0.0 && v_rel < 0.0 {
            self.phase = Phase::Out;
            return 0.0;
        }
        let l_eff = self.shaft_length(s, surface, d);
        let phi_tip = s.shaft.as_ref().map_or(1.0, |p| p.phi(d));

        // Fresh tissue at the tip, and the age of the channel the shaft
        // occupies (pressure on the shaft relaxes with the time since the
        // tip cut that part of the channel).
        let fresh_from = self.d_prev.max(self.d_max);
        let advancing_fresh = dd > 0.0 && d > self.d_max;
        if !r.is_elastic() {
            for (i, a) in self.shaft_acc.iter_mut().enumerate() {
                *a *= self.fac.decay[i];
            }
            if dd > 0.0 {
                let old_end = d.min(self.d_max);
                if old_end > self.d_prev {
                    let age = t_s - self.cut_time_s[Self::cell(self.d_prev)];
                    for (i, a) in self.shaft_acc.iter_mut().enumerate() {
                        let w = if age.is_finite() {
                            (-age / r.branches[i].1).exp()
                        } else {
                            1.0
                        };
                        *a += phi_tip * (old_end - self.d_prev) * w;
                    }
                }
                if advancing_fresh {
                    for a in self.shaft_acc.iter_mut() {
                        *a += phi_tip * (d - fresh_from);
                    }
                }
            } else if dd < 0.0 {
                let age = t_s - self.cut_time_s[Self::cell(self.d_prev)];
                for (i, a) in self.shaft_acc.iter_mut().enumerate() {
                    let w = if age.is_finite() {
                        (-age / r.branches[i].1).exp()
                    } else {
                        1.0
                    };
                    *a -= phi_tip * (-dd) * w;
                }
            }
            for a in self.shaft_acc.iter_mut() {
                *a = a.clamp(0.0, l_eff);
            }
        }
        if advancing_fresh {
            for c in Self::cell(fresh_from)..=Self::cell(d) {
                if self.cut_time_s[c].is_nan() {
                    self.cut_time_s[c] = t_s;
                }
            }
            self.d_max = d;
        }
        let l_slide = if r.is_elastic() {
            l_eff
        } else {
            r.g_inf * l_eff
                + r.branches
                    .iter()
                    .zip(&self.shaft_acc)
                    .map(|(b, a)| b.0 * a)
                    .sum::<f64>()
        };

        let f = &s.friction;
        let band = f.dv_half_mps;
        let rigid = s.tent.is_none();

        // Pre-sliding state of a rigid interface evolves with every
        // relative displacement.
        let mut pre_per_m = None;
        if rigid && h_s > 0.0 {
            match s.pre {
                Pre::None => {}
                Pre::Dahl {
                    presliding_m,
                    alpha,
                } => {
                    let sigma0 = (f.c_p_n_per_m + f.b_p_n_s_per_m2 * 3e-3) / presliding_m;
                    if dd != 0.0 {
                        let target = kinetic_per_m(f, &s.law, dd / h_s);
                        if target.abs() > 1e-9 {
                            self.pre_state +=
                                sigma0 * dd * signed_pow(1.0 - self.pre_state / target, alpha);
                        }
                    }
                    pre_per_m = Some(self.pre_state);
                }
                Pre::LuGre {
                    presliding_m,
                    damping_s,
                    v_s_mps,
                } => {
                    let sigma0 = f.d_p_n_per_m / presliding_m;
                    let v = v_rel;
                    let z = self.pre_state;
                    let mut z_new = z;
                    if v.abs() > 1e-12 {
                        let w = (-(v / v_s_mps).powi(2)).exp();
                        let g = if v > 0.0 {
                            f.c_p_n_per_m + (f.d_p_n_per_m - f.c_p_n_per_m) * w
                        } else {
                            f.c_n_n_per_m + (f.d_n_n_per_m - f.c_n_n_per_m) * w
                        };
                        let z_ss = g / sigma0;
                        z_new = z_ss + (z - z_ss) * (-sigma0 * v.abs() * h_s / g.abs()).exp();
                    }
                    let zdot = (z_new - z) / h_s;
                    self.pre_state = z_new;
                    let b = if v > 0.0 {
                        f.b_p_n_s_per_m2
                    } else {
                        f.b_n_n_s_per_m2
                    };
                    pre_per_m = Some(sigma0 * z_new + sigma0 * damping_s * zdot + b * v);
                }
            }
        }

        let f_tip = if advancing_fresh && v_rel > band {
            s.tip.force_n(d - self.d_punct)
        } else {
            0.0
        };
        let reversed = v_rel * self.v_rel_prev < 0.0;
        let moving = v_rel.abs() >= band && !reversed;
        let kinetic = |st: &mut State| -> f64 {
            let per_m = match pre_per_m {
                Some(p) => p,
                None => {
                    let mut k = kinetic_per_m(f, &s.law, v_rel);
                    if st.break_offset_per_m != 0.0 {
                        if let Pre::LuGre { presliding_m, .. } = s.pre {
                            st.break_slip_m += dd.abs();
                            k += st.break_offset_per_m * (-st.break_slip_m / presliding_m).exp();
                        }
                    }
                    k
                }
            };
            per_m * l_slide
        };

        let band_lo = f.d_n_n_per_m * l_eff;
        let band_hi = f.d_p_n_per_m * l_eff;
        let k_tent = s.tent.map(|t| t.0);
        // Sliding: the tent sits where its spring balances the shaft's
        // friction (the tip's load is carried by the tissue ahead of it).
        let slide = |st: &mut State| -> f64 {
            let shaft = kinetic(st);
            if let Some(k) = k_tent {
                st.w_tent = shaft / k;
            }
            let v = shaft + f_tip;
            st.iface.reset(r, v);
            v
        };
        let f_iface = match self.mode {
            Mode::Sliding => {
                if moving {
                    slide(self)
                } else {
                    let e = self.iface.value(r).clamp(band_lo, band_hi);
                    self.iface.reset(r, e);
                    self.mode = Mode::Stuck {
                        e,
                        w0: self.w_tent,
                        d0: d,
                        rest_s: 0.0,
                    };
                    e
                }
            }
            Mode::Stuck { e, w0, d0, rest_s } => match s.tent {
                None => {
                    if moving {
                        self.mode = Mode::Sliding;
                        slide(self)
                    } else {
                        let e = self.applied.unwrap_or(e).clamp(band_lo, band_hi);
                        self.mode = Mode::Stuck { e, w0, d0, rest_s };
                        self.iface.load(r, &self.fac, e);
                        self.iface.value(r)
                    }
                }
                Some((k_tent, pull_per_m)) => {
                    // The tissue around the shaft moves with the needle
                    // (an elastic tent) until static friction lets go. The
                    // pull-out capacity ages with the time at rest
                    // (Dieterich: strength ∝ log of contact time): full
                    // after a 5 s hold, only the kinetic level after a
                    // stick in passing (a bounce, a reversal).
                    let rest_s = rest_s + if v_rel.abs() < band { h_s } else { 0.0 };
                    let aging = ((1.0 + rest_s / 0.1).ln() / (1.0_f64 + 5.0 / 0.1).ln()).min(1.0);
                    let d_n = (-f.c_n_n_per_m).min(pull_per_m);
                    let cap_neg = -(d_n + (pull_per_m - d_n).max(0.0) * aging) * l_eff;
                    let cap = if dd >= 0.0 { band_hi } else { cap_neg };
                    let series = match s.pre {
                        Pre::None => None,
                        Pre::Dahl {
                            presliding_m,
                            alpha,
                        } => Some((presliding_m, alpha)),
                        // LuGre's quasi-static bristle curve is Dahl's
                        // with exponent 1.
                        Pre::LuGre { presliding_m, .. } => Some((presliding_m, 1.0)),
                    };
                    let (e_new, slip) = match series {
                        None => {
                            let e_new = e + k_tent * dd;
                            let v = self.value_after(r, e_new);
                            // Slip only in the direction the needle moves.
                            (
                                e_new,
                                (v > band_hi && dd > 0.0) || (v < cap_neg && dd < 0.0),
                            )
                        }
                        Some((presliding_m, alpha)) => {
                            let q = if cap.abs() > 1e-12 { e / cap } else { 1.0 };
                            let stiff =
                                cap.abs() / presliding_m * signed_pow(1.0 - q, alpha).max(1e-9);
                            let e_new = e + dd / (1.0 / k_tent + 1.0 / stiff);
                            (e_new, dd != 0.0 && (1.0 - e_new / cap) < 0.03)
                        }
                    };
                    if slip && moving {
                        self.mode = Mode::Sliding;
                        if let Pre::LuGre { .. } = s.pre {
                            self.break_slip_m = 0.0;
                            self.break_offset_per_m = if l_slide > 1e-9 {
                                e_new / l_slide - kinetic_per_m(f, &s.law, v_rel)
                            } else {
                                0.0
                            };
                        }
                        slide(self)
                    } else {
                        self.w_tent = w0 + (d - d0);
                        self.mode = Mode::Stuck {
                            e: e_new,
                            w0,
                            d0,
                            rest_s,
                        };
                        self.iface.load(r, &self.fac, e_new);
                        self.iface.value(r)
                    }
                }
            },
        };
        self.lock = match (self.mode, s.tent) {
            (Mode::Stuck { .. }, None) => Some((band_lo, band_hi)),
            _ => None,
        };
        f_iface + f_walls
    }

    fn value_after(&self, r: &Relaxation, e_new: f64) -> f64 {
        let mut probe = self.iface.clone();
        probe.load(r, &self.fac, e_new);
        probe.value(r)
    }
}
