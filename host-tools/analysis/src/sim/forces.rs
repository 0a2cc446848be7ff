//! The unmodelled effects as the simulator steps them, one struct or
//! function each, beside the tissue's own force (`needle.rs`), as
//! the core's pipeline keeps one state per stage. Each acts in the form
//! asked for ([`Form`]): the standard form, an alternate one of the same
//! effect, or one from the literature.
//!
//! Each adds its force to the sample's in the order the simulator always
//! did, so that a dataset is the same, bit for bit, whatever the code's
//! shape; the literature form's mount instead passes on the force the
//! tissue effects made (see `Added::add`).

use std::f64::consts::TAU;

use super::effects::Effect;
use super::{Form, Protocol, TissueParams, TruthEvent};

/// What one sample's step reads: its time, the step to it, and the
/// needle's velocity relative to the tissue and its acceleration.
#[derive(Clone, Copy, Debug)]
pub(super) struct Kinematics {
    pub t_s: f64,
    pub dt_s: f64,
    pub vr_mps: f64,
    pub a_mps2: f64,
}

/// The tissue moving along the needle's axis (breathing): the needle's
/// position `p_m` and velocity `vr_mps` become relative to the tissue.
/// `breath_phase` is where the breath was when the trial began.
pub(super) fn move_with_tissue(
    effects: &[Effect],
    form: Form,
    breath_phase: f64,
    t: f64,
    (p_m, vr_mps): (&mut f64, &mut f64),
) {
    for effect in effects {
        let Effect::TissueMotion {
            amplitude_m,
            freq_hz,
        } = *effect
        else {
            continue;
        };
        match form {
            Form::Literature => {
                // The breathing period wanders by ±20 % over 30 s.
                let (w, w_m) = (TAU * freq_hz, TAU / 30.0);
                let beta = 0.2 * w / w_m;
                let th = w * t + beta * (w_m * t).sin() + breath_phase;
                *p_m -= amplitude_m * th.sin();
                *vr_mps -= amplitude_m * th.cos() * (w + beta * w_m * (w_m * t).cos());
            }
            Form::Alternate => {
                // Breathing is not a sine: a sharper inhale, 0.8 f.
                let w = 0.8 * TAU * freq_hz;
                let th = w * t + breath_phase;
                *p_m -= amplitude_m * (th.sin() + 0.3 * (2.0 * th).sin());
                *vr_mps -= amplitude_m * w * (th.cos() + 0.6 * (2.0 * th).cos());
            }
            Form::Standard => {
                let w = TAU * freq_hz;
                *p_m -= amplitude_m * (w * t).sin();
                *vr_mps -= amplitude_m * w * (w * t).cos();
            }
        }
    }
}

/// Presliding: the friction the shaft exerts, lagging the Karnopp value
/// over a travel x_c (without the effect it is that value at once).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Bristles {
    friction_n: f64,
}

impl Bristles {
    /// The friction after a travel `dx_m` towards `target_n`.
    pub fn follow(&mut self, effects: &[Effect], form: Form, target_n: f64, dx_m: f64) -> f64 {
        let x_c = effects.iter().find_map(|e| match *e {
            Effect::PreslidingHysteresis { x_c_m } if x_c_m > 0.0 => Some(x_c_m),
            _ => None,
        });
        let friction = self.friction_n;
        self.friction_n = match (x_c, form) {
            // Elasto-plastic: a bristle of fixed stiffness until it
            // slips, a linear ramp instead of an exponential.
            (Some(x_c), Form::Alternate) => {
                let most = target_n.abs().max(0.05) * dx_m / x_c;
                friction + (target_n - friction).clamp(-most, most)
            }
            // Dahl with exponent 2: dF/dx ∝ (1 − F/F_c)², a sharper
            // start and a slower approach.
            (Some(x_c), Form::Literature) => {
                let (gap, scale) = (target_n - friction, target_n.abs().max(0.05));
                let rel = (gap.abs() / scale).min(2.0);
                friction + gap.signum() * (scale * dx_m / x_c * rel * rel).min(gap.abs())
            }
            (Some(x_c), Form::Standard) => friction + (target_n - friction) * (dx_m / x_c).min(1.0),
            (None, _) => target_n,
        };
        self.friction_n
    }

    /// Out of the tissue: nothing to lag behind.
    pub fn release(&mut self) {
        self.friction_n = 0.0;
    }
}

/// Cutting that depends on depth: `cutting_n` at `depth_m` below the
/// surface, the tip's deepest `past_puncture_m` beyond where the capsule
/// gave way.
pub(super) fn deeper_cutting(
    effects: &[Effect],
    form: Form,
    depth_m: f64,
    past_puncture_m: f64,
    cutting_n: f64,
) -> f64 {
    let mut cutting = cutting_n;
    for effect in effects {
        if let Effect::DepthDependentCutting { g_per_m } = *effect {
            cutting *= match form {
                // Growing as the square root of depth, the same at 10 mm,
                // and loaded again after the puncture: the layer beneath
                // a ruptured capsule must be compressed to its own
                // cutting force before it cuts, so the force falls below
                // its steady level and climbs back over the next
                // millimetres (real recordings: to 20–45 % of the peak,
                // then 1.2–3.3× within 3 mm).
                Form::Literature => {
                    let deficit = (RELOAD_DEFICIT * g_per_m / 15.0).min(0.9);
                    (1.0 + g_per_m * (depth_m.max(0.0) * 0.01).sqrt())
                        * (1.0 - deficit * (-past_puncture_m.max(0.0) / RELOAD_M).exp())
                }
                // Saturating over 20 mm, same initial slope (and
                // wandering about it along each trial's own path:
                // `Protocol::cutting_wander`).
                Form::Alternate => {
                    const L_M: f64 = 0.02;
                    1.0 + g_per_m * L_M * (1.0 - (-depth_m / L_M).exp())
                }
                Form::Standard => 1.0 + g_per_m * depth_m,
            };
        }
    }
    cutting
}

/// The literature form's cutting deficit at the puncture (at standard
/// strength) and the advance over which it recovers by 1/e: back within
/// 5 % by 2.4 mm.
const RELOAD_DEFICIT: f64 = 0.6;
const RELOAD_M: f64 = 0.8e-3;

/// The tent: tissue stuck to the shaft after a rest follows the needle
/// back until its pull reaches the static band, then slips.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Tent {
    /// Time at rest so far.
    rest_s: f64,
    /// Once the needle starts back after a rest: where it started and the
    /// force the rest held.
    from: Option<(f64, f64)>,
    /// The force the tent last left (the rest's hold).
    rest_force_n: f64,
}

impl Tent {
    /// The force at position `p_m` with `l_m` of shaft in the tissue,
    /// `f_n` without the tent.
    pub fn step(
        &mut self,
        protocol: &Protocol,
        tissue: &TissueParams,
        k: &Kinematics,
        (p_m, l_m): (f64, f64),
        f_n: f64,
    ) -> f64 {
        if protocol.tent_n_per_m > 0.0 {
            self.pull(protocol, tissue, k, (p_m, l_m), f_n)
        } else {
            f_n
        }
    }

    /// [`Self::step`] with a tent.
    fn pull(
        &mut self,
        protocol: &Protocol,
        tissue: &TissueParams,
        k: &Kinematics,
        (p_m, l_m): (f64, f64),
        f_n: f64,
    ) -> f64 {
        let mut f = f_n;
        let vr = k.vr_mps;
        if vr <= -tissue.half_band_mps && self.rest_s >= 1.0 {
            self.from = Some((p_m, self.rest_force_n));
        }
        self.rest_s = if vr.abs() < tissue.half_band_mps {
            self.rest_s + k.dt_s
        } else {
            0.0
        };
        if let Some((from_m, held_n)) = self.from {
            let pulled = held_n - protocol.tent_n_per_m * (from_m - p_m);
            if vr > -tissue.half_band_mps || pulled <= tissue.dn_n_per_m * l_m {
                self.from = None;
            } else {
                f = pulled;
            }
        }
        self.rest_force_n = f;
        f
    }
}

/// Interior walls (vessels, septa) at `(depth, rupture force)`: each
/// pushes back as it is stretched until it gives way.
pub(super) struct Walls {
    ruptured: Vec<bool>,
}

impl Walls {
    pub fn new(count: usize) -> Self {
        Self {
            ruptured: vec![false; count],
        }
    }

    /// `f_n` with every intact wall's force at `p_m` added (in order); a
    /// wall that gives way is a `structure` event at `(t, t − dt, x)`.
    pub fn add(
        &mut self,
        (effects, form): (&[Effect], Form),
        walls: &[(f64, f64)],
        p_m: f64,
        f_n: &mut f64,
        events: &mut Vec<TruthEvent>,
        at: (f64, f64, f64),
    ) {
        let k_v = effects.iter().find_map(|e| match *e {
            Effect::InternalStructures { k_n_per_m, .. } => Some(k_n_per_m),
            _ => None,
        });
        for (k, &(depth, rupture)) in walls.iter().enumerate() {
            if self.ruptured[k] || p_m <= depth {
                continue;
            }
            let stretch = p_m - depth;
            let wall = match form {
                // Fung's exponential collagen law, over 0.5 mm.
                Form::Literature => {
                    const L_M: f64 = 0.0005;
                    k_v.unwrap_or(0.0) * L_M * ((stretch / L_M).exp() - 1.0)
                }
                // Stiffening (a collagen wall), doubling at 1 mm.
                Form::Alternate => k_v.unwrap_or(0.0) * stretch * (1.0 + stretch / 0.001),
                Form::Standard => k_v.unwrap_or(0.0) * stretch,
            };
            *f_n += give_way(wall, rupture, &mut self.ruptured[k], events, at);
        }
    }
}

/// The force a wall or membrane pushes back with, or, once it reaches
/// `rupture_n`, nothing: it gives way (a `structure` event at `(t, x)`)
/// and stays ruptured.
pub(super) fn give_way(
    force_n: f64,
    rupture_n: f64,
    ruptured: &mut bool,
    events: &mut Vec<TruthEvent>,
    (t_s, peak_t_s, x_m): (f64, f64, f64),
) -> f64 {
    if force_n < rupture_n {
        return force_n;
    }
    *ruptured = true;
    events.push(TruthEvent {
        kind: "structure",
        t_s,
        peak_t_s,
        x_m,
    });
    0.0
}

/// The effects that add a force of their own to the tissue's, each its
/// state: relaxation, the holder's mass, the sensor's drift.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Added {
    relaxing: Relaxing,
    holder: Holder,
}

impl Added {
    /// Add each effect's force at this sample to `f_n`, in `effects'`
    /// order; `in_tissue` is false once the needle is out. The literature
    /// form's mount passes on every force the tissue exerts, and the load
    /// cell's drift lies beyond it: in that form the mount comes after
    /// relaxation and before drift, whatever the list's order (and once).
    pub fn add(
        &mut self,
        (effects, form): (&[Effect], Form),
        k: &Kinematics,
        in_tissue: bool,
        f_n: &mut f64,
    ) {
        let mounted = form == Form::Literature;
        let (mut mount_kg, mut drift_beyond_n) = (None, None);
        for effect in effects {
            match *effect {
                Effect::Viscoelasticity { k_n_per_m, tau_s } => {
                    self.relaxing
                        .add(form, (k_n_per_m, tau_s), k, in_tissue, f_n)
                }
                Effect::HolderInertia { mass_kg } if mounted => {
                    mount_kg.get_or_insert(mass_kg);
                }
                Effect::HolderInertia { mass_kg } => self.holder.add(form, mass_kg, k, f_n),
                Effect::SensorDrift { rate_n_per_s } if mounted => {
                    *drift_beyond_n.get_or_insert(0.0) += drift_n(form, rate_n_per_s, k.t_s)
                }
                Effect::SensorDrift { rate_n_per_s } => *f_n += drift_n(form, rate_n_per_s, k.t_s),
                _ => {}
            }
        }
        if mounted {
            if let Some(mass_kg) = mount_kg {
                self.holder.add(form, mass_kg, k, f_n);
            }
            if let Some(drift) = drift_beyond_n {
                *f_n += drift;
            }
        }
    }
}

/// Relaxation: Maxwell branches driven by the needle's motion in the
/// tissue (standard and alternate forms), or Fung's quasi-linear
/// viscoelasticity acting on every force the tissue exerts (literature).
#[derive(Clone, Copy, Debug, Default)]
struct Relaxing {
    maxwell: f64,
    maxwell_slow: f64,
    /// The literature form: each branch's part of the tissue's force not
    /// yet relaxed, and that force at the sample before.
    unrelaxed_n: [f64; 5],
    tissue_before_n: f64,
}

/// The literature form's fraction of a force that relaxes away in the end
/// (γ, dimensionless), per N/m of the effect's stiffness, so that one
/// strength scales every form: 0.08 at the standard size (20 N/m), 0.4
/// at five times it (the box relaxes about 78 % of γ in 5 s: 31 % of a
/// force held from rest, near real skin's 34–41 %; a force renewed while
/// sliding has relaxed most of its part already when it stops).
const QLV_FRACTION_PER_N_PER_M: f64 = 0.004;
/// Most of a force that may relax away: G(∞) = 1 − γ stays positive, a
/// tissue that holds some force for good.
const QLV_MOST_FRACTION: f64 = 0.9;

impl Relaxing {
    fn add(
        &mut self,
        form: Form,
        (k_n_per_m, tau_s): (f64, f64),
        k: &Kinematics,
        in_tissue: bool,
        f_n: &mut f64,
    ) {
        if form == Form::Literature {
            self.fung(
                k_n_per_m * QLV_FRACTION_PER_N_PER_M,
                tau_s,
                k.dt_s,
                in_tissue,
                f_n,
            );
            return;
        }
        let (dt, vr) = (k.dt_s, k.vr_mps);
        // Alternate: a Prony series of two branches.
        let (k1, tau1, k2, tau2) = if form == Form::Alternate {
            (0.5 * k_n_per_m, tau_s / 3.0, k_n_per_m, 3.0 * tau_s)
        } else {
            (k_n_per_m, tau_s, 0.0, 1.0)
        };
        if in_tissue {
            self.maxwell += (k1 * vr - self.maxwell / tau1) * dt;
            self.maxwell_slow += (k2 * vr - self.maxwell_slow / tau2) * dt;
        } else {
            (self.maxwell, self.maxwell_slow) = (0.0, 0.0);
        }
        *f_n += self.maxwell + self.maxwell_slow;
    }

    /// Fung's QLV as he wrote it: the force is the convolution of the
    /// tissue's elastic force F (`f_n`, the paper's model with the other
    /// effects) with the reduced relaxation function G(t) = 1 − γ + γ·Σ
    /// e^{−t/τ_k}/5 over a box spectrum of five branches, τ log-spaced over
    /// 0.05–20 s (the box's centre `tau_s`, 1 s by default). Every force
    /// relaxes, the capsule's, the shaft's and the tip's, in motion as at
    /// rest: h_k, the part not yet relaxed, follows dh_k/dt = dF/dt −
    /// h_k/τ_k, exact for F linear over each step; the force is F − γ·Σ
    /// (F − h_k)/5.
    fn fung(&mut self, gamma: f64, tau_s: f64, dt_s: f64, in_tissue: bool, f_n: &mut f64) {
        if !in_tissue {
            self.unrelaxed_n = [0.0; 5];
            self.tissue_before_n = 0.0;
            return;
        }
        let rate_n_per_s = if dt_s > 0.0 {
            (*f_n - self.tissue_before_n) / dt_s
        } else {
            0.0
        };
        let mut relaxed_n = 0.0;
        for (b, h) in self.unrelaxed_n.iter_mut().enumerate() {
            let tau = tau_s * 0.05 * 400f64.powf(b as f64 / 4.0);
            let decay = (-dt_s / tau).exp();
            *h = *h * decay + rate_n_per_s * tau * (1.0 - decay);
            relaxed_n += (*f_n - *h) / 5.0;
        }
        self.tissue_before_n = *f_n;
        *f_n -= gamma.clamp(0.0, QLV_MOST_FRACTION) * relaxed_n;
    }
}

/// The holder's mass, felt by the load cell as it accelerates.
#[derive(Clone, Copy, Debug, Default)]
struct Holder {
    /// The literature form's mount: the force the load cell reads
    /// through it and its rate, and the force driving it at the sample
    /// before.
    mount_n: f64,
    mount_rate_n_per_s: f64,
    drive_n: f64,
    /// The alternate form's acceleration, as the drive reaches it.
    a_filtered: f64,
}

impl Holder {
    fn add(&mut self, form: Form, mass_kg: f64, k: &Kinematics, f_n: &mut f64) {
        let (dt, a) = (k.dt_s, k.a_mps2);
        if form == Form::Literature {
            // The holder hangs on a mount ringing at 25 Hz, damping ratio
            // 0.2, between the load cell and the needle: the load cell
            // reads through the mount both the holder's inertia and the
            // tissue's force (m·ÿ + c·ẏ + k·y = F + m·a for the mount's
            // deflection y, the load cell reading k·y), so a puncture's
            // fall rings. Integrated in sub-steps, stable over a 70 ms
            // gap, the force taken to change evenly between samples. The
            // deflection's own effect on where the needle is (F/k, 0.5 mm
            // at 2 N at 0.15 kg) is not simulated.
            let (w, zeta) = (TAU * 25.0, 0.2);
            let steps = ((dt * w / 0.1).ceil() as usize).max(1);
            let h = dt / steps as f64;
            let drive_n = *f_n + mass_kg * a;
            for j in 1..=steps {
                let at_n = self.drive_n + (drive_n - self.drive_n) * j as f64 / steps as f64;
                self.mount_rate_n_per_s +=
                    (w * w * (at_n - self.mount_n) - 2.0 * zeta * w * self.mount_rate_n_per_s) * h;
                self.mount_n += self.mount_rate_n_per_s * h;
            }
            self.drive_n = drive_n;
            *f_n = self.mount_n;
            return;
        }
        // Alternate: the drive reaches its speed over ~10 ms.
        let gain = if form == Form::Alternate {
            dt / 0.01
        } else {
            1.0
        };
        self.a_filtered += (a - self.a_filtered) * gain;
        *f_n += mass_kg * self.a_filtered;
    }
}

/// The load cell's drift at `t_s`.
fn drift_n(form: Form, rate_n_per_s: f64, t_s: f64) -> f64 {
    match form {
        // A bridge warming up: the drift accelerates, reaching the
        // standard rate at 20 s.
        Form::Literature => rate_n_per_s * t_s * t_s / (2.0 * 20.0),
        // A bridge settling thermally over 30 s.
        Form::Alternate => {
            const TAU_S: f64 = 30.0;
            rate_n_per_s * TAU_S * (1.0 - (-t_s / TAU_S).exp())
        }
        Form::Standard => rate_n_per_s * t_s,
    }
}
