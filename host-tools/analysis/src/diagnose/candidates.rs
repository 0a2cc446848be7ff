//! The candidate effects, one per effect of the book, *Names*: each is a few columns
//! added to the nominal model, built from the trial's kinematics and the
//! nominal model's own terms, linear in their parameters and with at most
//! one nonlinear parameter searched on a grid. The forms are the physics of
//! each effect in general (a relaxing branch, a speed-dependent damping, a
//! lagging friction, a stiff wall that gives way, cutting that grows with
//! depth, a mass, an offset growing in time, a periodic tissue motion), not
//! the simulator's exact formulas.

use std::f64::consts::TAU;

use super::motion::{harmonics_along, moved_model, PhaseWander, TissueShift};
use super::prepare::{Prepared, AFTER, APPROACH, LOADING};
use super::stick::running;
use crate::fit::lsq::Lsq;

/// A candidate's columns for one trial, one vector per linear parameter.
pub type Columns = Vec<Vec<f64>>;

/// A candidate's columns for one trial at every value of a grid, each
/// given to the callback once ([`Each`]), as it is made, in an order of
/// the candidate's choosing.
pub type OnGrid = fn(&Prepared, &[f64], &mut Each<'_>);

/// What takes a candidate's columns at a grid value: the value's index in
/// the grid, the columns, and how many of them, from the first, are those
/// given at the call before for the same trial (so that what was made of
/// them may be used again; 0 at a trial's first call, and after a call
/// with another number of columns).
pub type Each<'a> = dyn FnMut(usize, &[Vec<f64>], usize) + 'a;

/// One candidate effect.
pub struct Candidate {
    pub effect: &'static str,
    /// Name and grid of its nonlinear parameter (one value if none).
    pub grid_name: &'static str,
    pub grid: &'static [f64],
    /// Names of the linear parameters, one per column.
    pub linear: &'static [&'static str],
    /// Columns (one vector per linear parameter) for a trial at a grid value.
    pub columns: fn(&Prepared, f64) -> Columns,
    /// The columns at every grid value at once, where grid values share
    /// work ([`Self::columns_on_grid`]); `columns` at each one if `None`.
    pub on_grid: Option<OnGrid>,
    /// The named parameters a grid value stands for.
    pub grid_params: fn(&'static str, f64) -> Vec<(&'static str, f64)>,
    /// How its fit is taken out of the data before the nominal is fitted
    /// again.
    pub backfit: Backfit,
    /// Its linear parameters are amounts the physics signs (a fraction of
    /// the force that relaxes away, a relaxing branch's stiffness): a fit
    /// that wants one negative is no fit of that physics, and leaves its
    /// column out (`PerTrial::non_negative`).
    pub non_negative: bool,
}

impl Candidate {
    /// [`Self::columns`] for a trial at every value of the grid, given to
    /// `each` with the value's index as they are made.
    pub fn columns_on_grid(&self, p: &Prepared, each: &mut Each<'_>) {
        match self.on_grid {
            Some(on_grid) => on_grid(p, self.grid, each),
            None => {
                for (gi, &g) in self.grid.iter().enumerate() {
                    each(gi, &(self.columns)(p, g), 0);
                }
            }
        }
    }
}

/// What backfitting under a named effect takes out of the data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backfit {
    /// Its fitted force, from the measured force.
    Force,
    /// The tissue's displacement, from the needle's position: the nominal
    /// is then fitted in the tissue's frame (`super::motion`).
    TissueFrame,
}

fn grid_as_named(name: &'static str, g: f64) -> Vec<(&'static str, f64)> {
    if name == "none" {
        Vec::new()
    } else {
        vec![(name, g)]
    }
}

/// Where depth-dependent cutting is in [`CANDIDATES`]: its profile free
/// along depth in each trial is the diagnosis's last resort, tried apart
/// from the shared candidates.
pub const CUTTING: usize = 4;
const _: () = assert!(matches!(
    CANDIDATES[CUTTING].effect.as_bytes(),
    b"depth_dependent_cutting"
));

/// All candidates, in the order of the book, *Names*.
pub const CANDIDATES: [Candidate; 8] = [
    Candidate {
        effect: "viscoelasticity",
        grid_name: "spectrum",
        grid: &[
            0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0,
            16.0, 17.0, 18.0, 19.0, 20.0, 21.0, 22.0, 23.0, 24.0, 25.0, 26.0, 27.0, 28.0, 29.0,
            30.0, 31.0, 32.0, 33.0, 34.0, 35.0, 36.0, 37.0, 38.0, 39.0, 40.0, 41.0, 42.0, 43.0,
            44.0,
        ],
        linear: &["capsule_gain", "gain"],
        columns: relaxation,
        on_grid: Some(relaxation_on_grid),
        grid_params: spectrum_params,
        backfit: Backfit::Force,
        non_negative: true,
    },
    Candidate {
        effect: "rate_dependent_friction",
        grid_name: "law",
        grid: &[-0.75, -0.5, -0.25, 0.5, 1.0, 2.0, 3.0, 4.0],
        linear: &["rate_gain"],
        columns: rate_friction,
        on_grid: None,
        grid_params: rate_law_params,
        backfit: Backfit::Force,
        non_negative: false,
    },
    Candidate {
        effect: "presliding_hysteresis",
        grid_name: "x_c_m",
        grid: &[0.0001, 0.0003, 0.001, 0.003],
        linear: &["lag_gain", "bristle_gain"],
        columns: friction_lag,
        on_grid: None,
        grid_params: grid_as_named,
        backfit: Backfit::Force,
        non_negative: false,
    },
    Candidate {
        effect: "internal_structures",
        grid_name: "stiffening_exponent",
        grid: &[1.0, 1.5, 2.0, 3.0],
        linear: &["wall_gain", "layer_step_gain"],
        columns: walls,
        on_grid: None,
        grid_params: grid_as_named,
        backfit: Backfit::Force,
        non_negative: false,
    },
    Candidate {
        effect: "depth_dependent_cutting",
        grid_name: "depth_exponent",
        grid: &[1.0, 0.5],
        linear: &["cutting_growth_at_10_mm_n", "cutting_correction_n"],
        columns: depth_cutting,
        on_grid: None,
        grid_params: grid_as_named,
        backfit: Backfit::Force,
        non_negative: false,
    },
    Candidate {
        effect: "holder_inertia",
        grid_name: "mount",
        grid: &MOUNT_GRID,
        linear: &["mass_kg", "mass_smooth_kg", "mount_gain", "compliance_gain"],
        columns: inertia,
        on_grid: Some(inertia_on_grid),
        grid_params: mount_params,
        backfit: Backfit::Force,
        non_negative: false,
    },
    Candidate {
        effect: "sensor_drift",
        grid_name: "thermal_tau_s",
        grid: &[0.0, 10.0, 30.0, 100.0, -10.0, -30.0, -100.0],
        linear: &["rate_n_per_s", "gain_on_rate_out_of_tissue"],
        columns: drift,
        on_grid: None,
        grid_params: grid_as_named,
        backfit: Backfit::Force,
        non_negative: false,
    },
    Candidate {
        effect: "tissue_motion",
        grid_name: "motion",
        grid: &[
            0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0,
        ],
        linear: &[
            "gain",
            "a1_n_per_m",
            "a2_n_per_m2",
            "nominal_loading_gain",
            "loading_offset_n",
        ],
        columns: tissue_motion,
        on_grid: Some(tissue_motion_on_grid),
        grid_params: motion_params,
        backfit: Backfit::TissueFrame,
        non_negative: false,
    },
];

/// Relaxation spectra on the grid: a centre τ of 0.25–4 s × a width of
/// one time constant (the standard linear solid), one, two or three
/// decades (Fung's quasi-linear viscoelasticity has a continuous box
/// spectrum from τ₁ to τ₂, in soft tissue three decades apart and more;
/// a power law a flat one over decades). The spectrum's shape is chosen on
/// the grid and its branches share one stiffness: a free weight per
/// branch would let them cancel one another, fit the training trials'
/// noise and miss the withheld ones.
const SPECTRUM_TAU_S: [f64; 5] = [0.25, 0.5, 1.0, 2.0, 4.0];
const SPECTRUM_DECADES: [f64; 4] = [0.0, 1.0, 2.0, 3.0];

fn spectrum_at(g: f64) -> (f64, f64) {
    let k = (g as usize).min(SPECTRUM_TAU_S.len() * SPECTRUM_DECADES.len() - 1);
    (
        SPECTRUM_TAU_S[k % SPECTRUM_TAU_S.len()],
        SPECTRUM_DECADES[k / SPECTRUM_TAU_S.len()],
    )
}

/// Grid values from here on are relaxation of the tissue's force
/// ([`qlv_branch`]); below, a relaxing branch driven by the needle's motion
/// ([`maxwell_branch`]).
const QLV_FROM: f64 = 20.0;
/// Grid values from here on are relaxation of the tissue's force over its
/// whole history, sliding as well as held ([`Branch::QlvWhole`]), with
/// Fung's wide box alone (three decades, as in soft tissue). Narrower
/// whole-history spectra are nearly collinear with the Maxwell branches
/// (a friction linear in depth, relaxed so, is a branch the velocity
/// loads) but at a turn, and each spectrum costs the search time.
const QLV_WHOLE_FROM: f64 = 40.0;
/// The index in [`spectrum_at`]'s table of the first three-decade
/// spectrum, where [`QLV_WHOLE_FROM`]'s family starts.
const THREE_DECADE_SPECTRUM_INDEX: f64 =
    ((SPECTRUM_DECADES.len() - 1) * SPECTRUM_TAU_S.len()) as f64;

/// The relaxing family at grid value `g` and the spectrum's index in it.
fn family_of(g: f64) -> (Branch, f64) {
    if g >= QLV_WHOLE_FROM {
        (
            Branch::QlvWhole,
            g - QLV_WHOLE_FROM + THREE_DECADE_SPECTRUM_INDEX,
        )
    } else if g >= QLV_FROM {
        (Branch::Qlv, g - QLV_FROM)
    } else {
        (Branch::Maxwell, g)
    }
}

fn spectrum_params(_: &'static str, g: f64) -> Vec<(&'static str, f64)> {
    let (family, g) = family_of(g);
    let (tau_s, decades) = spectrum_at(g);
    let flag = |on: bool| if on { 1.0 } else { 0.0 };
    vec![
        ("tau_s", tau_s),
        ("spectrum_decades", decades),
        ("of_tissue_force", flag(family != Branch::Maxwell)),
        ("relaxes_sliding", flag(family == Branch::QlvWhole)),
    ]
}

/// Viscoelasticity in any of its three readings: a branch the needle's
/// motion loads (k·m, the Maxwell element beside the nominal's springs;
/// gains in N/m), or relaxation of the force the tissue exerts (Fung's
/// quasi-linear viscoelasticity on each trial's fitted force, [`qlv_branch`]:
/// the capsule's as it loads, a held force from the stop, the dragged
/// tissue's — or every force over its whole history, sliding too; gains
/// the fraction that relaxes away, dimensionless). Each with one gain
/// for the capsule and one for the rest ([`capsule_and_shaft`]). Real
/// tissue relaxes 34–41 % of a held force in 5 s at rest, which no
/// motion-driven branch can do: the needle stands still.
fn relaxation(p: &Prepared, g: f64) -> Vec<Vec<f64>> {
    let mut cols = Vec::new();
    relaxation_on_grid(p, &[g], &mut |_, c, _| cols = c.to_vec());
    cols
}

/// [`relaxation`] at each of `grid`'s values, every relaxing branch
/// computed once: the spectra about one centre share their branches
/// (half a decade apart about it), so the grid's 45 spectra need 105
/// branches, not 195. They are made centre by centre, and only one
/// centre's branches are kept (a trial of 70 000 samples would hold
/// 59 MB of branches otherwise).
fn relaxation_on_grid(p: &Prepared, grid: &[f64], each: &mut Each<'_>) {
    let centre = |gi: &usize| {
        let (family, g) = family_of(grid[*gi]);
        (family, spectrum_at(g).0.to_bits())
    };
    let mut order: Vec<usize> = (0..grid.len()).collect();
    order.sort_by_key(centre);
    let mut branches = Branches::new(p);
    for gi in order {
        let (family, g) = family_of(grid[gi]);
        let col = branches.spectrum(family, g);
        each(gi, &capsule_and_shaft(p, &col), 0);
    }
}

/// A column split in two, the capsule's part (loading) and the rest: the
/// capsule is a membrane, what the shaft and tip shear after it is the
/// tissue beneath, and the two need not relax alike.
fn capsule_and_shaft(p: &Prepared, col: &[f64]) -> Vec<Vec<f64>> {
    let (mut capsule, mut rest) = (vec![0.0; col.len()], vec![0.0; col.len()]);
    for (i, &c) in col.iter().enumerate() {
        if p.phase[i] == LOADING {
            capsule[i] = c;
        } else {
            rest[i] = c;
        }
    }
    vec![capsule, rest]
}

/// QLV with a reduced relaxation function G(t) = 1 − γ·(1 − Σ_k e^{−t/τ_k}/K)
/// acting on the tissue's force F as the baseline fitted it on the trial
/// ([`Prepared::fitted_n`]): σ = F − γ·(F − h), h_k the part of F's
/// history not yet relaxed (dh_k/dt = dF/dt − h_k/τ_k), so the column is
/// −(F − h) and γ its coefficient; one branch's F − h here, summed over
/// the spectrum by [`Branches::spectrum`]. Exact over each step for F
/// linear in it, so jittered clocks and gaps cost nothing.
///
/// Held where it is held (`relaxes_sliding` false): a needle sliding
/// through tissue meets fresh tissue at its tip and along its shaft all
/// the time, what it shears has had no time to relax, so nothing of a
/// sliding force has relaxed (h = F), and the force it holds once it
/// stops relaxes from there — the whole held force, as real tissue falls
/// 34–41 % in 5 s. The capsule, stretched without sliding, relaxes as it
/// loads; so does a tissue dragged along on withdrawal (the stick).
///
/// Fung's own form lets every force relax over its whole history
/// (`relaxes_sliding`): a sliding force, steadily renewed, then lags its
/// elastic value by what relaxed while it grew, and what it holds at a
/// stop is mostly relaxed already; the capsule's relaxed part carries past
/// the puncture and the held force's past a turn.
fn qlv_branch(steps: &[QlvStep], tau: f64, relaxes_sliding: bool) -> Vec<f64> {
    let mut decay = Decay::new(tau);
    let mut h = 0.0;
    steps
        .iter()
        .map(|step| match *step {
            // Out of the tissue there is no tissue force, and nothing
            // of its history is left to relax.
            QlvStep::Out => {
                h = 0.0;
                0.0
            }
            QlvStep::In { f_n, sliding, .. } if sliding && !relaxes_sliding => {
                h = f_n;
                0.0
            }
            QlvStep::In {
                f_n,
                dt_s,
                rate_n_per_s,
                ..
            } => {
                if dt_s > 0.0 {
                    let decay = decay.over(dt_s);
                    h = h * decay + rate_n_per_s * tau * (1.0 - decay);
                }
                f_n - h
            }
        })
        .collect()
}

/// The three relaxing families of [`relaxation`].
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Branch {
    /// [`maxwell_branch`]: driven by the needle's motion.
    Maxwell,
    /// [`qlv_branch`]: the tissue's force relaxing where it is held.
    Qlv,
    /// [`qlv_branch`]: the tissue's force relaxing sliding as well.
    QlvWhole,
}

/// A trial's relaxing branches about one spectrum centre, each computed
/// on first use and kept for every spectrum about that centre.
struct Branches<'p> {
    p: &'p Prepared,
    maxwell_steps: Option<Vec<Option<(f64, f64)>>>,
    qlv_steps: Option<Vec<QlvStep>>,
    /// The family and centre (its bits) of the branches kept.
    centre: Option<(Branch, u64)>,
    /// By offset from the centre in half decades.
    done: std::collections::HashMap<i32, Vec<f64>>,
}

impl<'p> Branches<'p> {
    fn new(p: &'p Prepared) -> Self {
        Self {
            p,
            maxwell_steps: None,
            qlv_steps: None,
            centre: None,
            done: Default::default(),
        }
    }

    /// The spectrum at grid value `g` of `family`: its branches spread
    /// evenly in log τ over its width (half a decade apart), summed with
    /// equal stiffness — for QLV as the column −(F − h) of its gain.
    fn spectrum(&mut self, family: Branch, g: f64) -> Vec<f64> {
        let (tau_s, decades) = spectrum_at(g);
        let branches = (2.0 * decades) as i32;
        let mut col = vec![0.0; self.p.trial.len()];
        for b in -branches / 2..=branches / 2 {
            let branch = self.branch(family, tau_s, b);
            for (c, m) in col.iter_mut().zip(branch) {
                match family {
                    Branch::Maxwell => *c += m / f64::from(branches + 1),
                    Branch::Qlv | Branch::QlvWhole => *c -= m / f64::from(branches + 1),
                }
            }
        }
        col
    }

    fn branch(&mut self, family: Branch, tau_s: f64, b: i32) -> &[f64] {
        let p = self.p;
        if self.centre != Some((family, tau_s.to_bits())) {
            self.centre = Some((family, tau_s.to_bits()));
            self.done.clear();
        }
        let (maxwell_steps, qlv_steps) = (&mut self.maxwell_steps, &mut self.qlv_steps);
        self.done.entry(b).or_insert_with(|| {
            let tau = tau_s * 10f64.powf(0.5 * f64::from(b));
            match family {
                Branch::Maxwell => maxwell_branch(
                    maxwell_steps.get_or_insert_with(|| maxwell_steps_of(p)),
                    tau,
                ),
                Branch::Qlv | Branch::QlvWhole => qlv_branch(
                    qlv_steps.get_or_insert_with(|| qlv_steps_of(p)),
                    tau,
                    family == Branch::QlvWhole,
                ),
            }
        })
    }
}

/// One sample as every branch of [`qlv_branch`] reads it, worked out once for
/// all of them (the branches were a quarter of a diagnosis's time).
#[derive(Clone, Copy)]
enum QlvStep {
    Out,
    /// In the tissue: the force, the step since the sample before (0 for
    /// the first) and its rate, and whether the needle slides through
    /// fresh tissue (rather than loading the capsule, held, or dragging
    /// the tissue).
    In {
        f_n: f64,
        dt_s: f64,
        rate_n_per_s: f64,
        sliding: bool,
    },
}

fn qlv_steps_of(p: &Prepared) -> Vec<QlvStep> {
    let f = |i: usize| if p.in_tissue(i) { p.fitted_n[i] } else { 0.0 };
    let sliding = |i: usize| {
        p.phase[i] != LOADING
            && p.velocity.v_mps[i].abs() >= p.params.half_band_mps
            && !p.stick.contains(&i)
    };
    let t = &p.trial.t_s;
    (0..p.trial.len())
        .map(|i| {
            if !p.in_tissue(i) {
                return QlvStep::Out;
            }
            let (dt_s, rate_n_per_s) = if i == 0 {
                (0.0, 0.0)
            } else {
                let dt_s = (t[i] - t[i - 1]).max(1e-9);
                (dt_s, (f(i) - f(i - 1)) / dt_s)
            };
            QlvStep::In {
                f_n: f(i),
                dt_s,
                rate_n_per_s,
                sliding: sliding(i),
            }
        })
        .collect()
}

/// e^{−dt/τ} for one τ, computed again only for a step neither of the
/// last two (by more than a part in 10⁹): a clocked recording repeats
/// its step, or alternates between two when its times are written to the
/// microsecond (1.512 and 1.513 ms at 661 Hz), and the exponential was a
/// seventh of a diagnosis's time.
struct Decay {
    tau_s: f64,
    /// (step, factor), the latest first.
    seen: [(f64, f64); 2],
}

impl Decay {
    fn new(tau_s: f64) -> Self {
        Self {
            tau_s,
            seen: [(0.0, 1.0); 2],
        }
    }

    fn over(&mut self, dt_s: f64) -> f64 {
        // Times stored as multiples of a step differ in their last bits.
        let same = |(step, _): (f64, f64)| (dt_s - step).abs() <= 1e-9 * dt_s;
        if same(self.seen[0]) {
            return self.seen[0].1;
        }
        if !same(self.seen[1]) {
            self.seen[1] = (dt_s, (-dt_s / self.tau_s).exp());
        }
        self.seen.swap(0, 1);
        self.seen[0].1
    }
}

/// One Maxwell branch's state, dm/dt = v − m/τ in tissue (the spectrum's
/// branches summed by [`Branches::spectrum`]). Each step is integrated exactly for a velocity
/// held over it, so a rig's jittered clock and its gaps cost nothing.
fn maxwell_branch(steps: &[Option<(f64, f64)>], tau: f64) -> Vec<f64> {
    let mut decay = Decay::new(tau);
    let mut m = 0.0;
    steps
        .iter()
        .map(|step| {
            m = match *step {
                Some((dt_s, v_mps)) => {
                    let decay = decay.over(dt_s);
                    m * decay + v_mps * tau * (1.0 - decay)
                }
                None => 0.0,
            };
            m
        })
        .collect()
}

/// What every branch of [`maxwell_branch`] reads: the step into each
/// sample in tissue (None out of it, and for the first) and the velocity
/// over it.
fn maxwell_steps_of(p: &Prepared) -> Vec<Option<(f64, f64)>> {
    let t = &p.trial.t_s;
    (0..p.trial.len())
        .map(|i| (p.in_tissue(i) && i > 0).then(|| (t[i] - t[i - 1], p.velocity.v_mps[i])))
        .collect()
}

/// Grid values of [`rate_friction`] from here on are Stribeck's law.
const STRIBECK_FROM: f64 = 1.0;

/// Stribeck's speed at grid value `g`: 0.25 mm/s doubling with each step;
/// `None` below [`STRIBECK_FROM`] (a power law's exponent minus 1).
fn stribeck_speed_mps(g: f64) -> Option<f64> {
    (g >= STRIBECK_FROM).then(|| 0.00025 * 2f64.powf(g - STRIBECK_FROM))
}

fn rate_law_params(_: &'static str, g: f64) -> Vec<(&'static str, f64)> {
    match stribeck_speed_mps(g) {
        Some(v_s) => vec![("stribeck_speed_mps", v_s)],
        None => vec![("exponent_minus_1", g)],
    }
}

/// Sliding damping l·v·(|v|/v_ref)^q. At rest the nominal's Karnopp
/// friction holds the sliding force it had when the needle stopped, and
/// so does this (a dwell after a fast insertion holds that speed's
/// damping).
///
/// Or Stribeck's law (grid values from [`STRIBECK_FROM`] on): friction
/// per length raised at low speed, l·sgn(v)·e^{−(|v|/v_s)²}, the raise
/// gone by a few v_s (boundary lubrication giving way to a fluid film;
/// v_s of 0.25–2 mm/s on the grid).
///
/// Not l·v beside it: each trial's viscous friction is its own
/// ([`super::SPREAD`]), and a shared l·v beside those is fitted only
/// where a rest holds it otherwise.
fn rate_friction(p: &Prepared, g: f64) -> Vec<Vec<f64>> {
    let mut held = 0.0;
    let law = |v: f64| match stribeck_speed_mps(g) {
        Some(v_s) => v.signum() * (-(v / v_s).powi(2)).exp(),
        None if v.abs() > 0.0005 => v * (v.abs() / 0.003).powf(g),
        None => 0.0,
    };
    let column = (0..p.trial.len())
        .map(|i| {
            let (v, l) = (p.velocity.v_mps[i], p.length_m[i]);
            if l <= 0.0 {
                held = 0.0;
                0.0
            } else if v.abs() >= p.params.half_band_mps {
                held = l * law(v);
                held
            } else if p.friction_basis[i] != [0.0; 4] {
                held
            } else {
                0.0
            }
        })
        .collect();
    vec![column]
}

/// Friction following the nominal Karnopp value with a lag over x_c of
/// travel, minus the nominal friction, in the two shapes the literature
/// gives presliding: Dahl's (the lag closes in proportion to itself, an
/// exponential approach over x_c) and the elasto-plastic bristle's (a
/// spring of stiffness F/x_c until it slips: a straight ramp that ends
/// at the Karnopp value). They differ most where the friction reverses,
/// which is where presliding shows. The bristle's F is the friction it
/// heads to, or where that is small (a viscous friction near a turn) the
/// trial's typical sliding friction on the side the needle moves to: a
/// bristle's stiffness belongs to the contact, not to the friction it
/// leaves (which would load a withdrawal after a fast insertion at the
/// insertion's stiffness).
fn friction_lag(p: &Prepared, x_c: f64) -> Vec<Vec<f64>> {
    let n = p.trial.len();
    let (mut dahl, mut bristle) = (vec![0.0; n], vec![0.0; n]);
    let (mut lag_dahl, mut lag_bristle) = (0.0_f64, 0.0_f64);
    let sliding = (sliding_friction_n(p, 1.0), sliding_friction_n(p, -1.0));
    for i in 0..n {
        let target = p.friction_n[i];
        if p.length_m[i] <= 0.0 {
            (lag_dahl, lag_bristle) = (0.0, 0.0);
            continue;
        }
        let step = if i > 0 {
            p.trial.x_m[i] - p.trial.x_m[i - 1]
        } else {
            0.0
        };
        let dx = step.abs();
        lag_dahl += (target - lag_dahl) * (dx / x_c).min(1.0);
        let side_n = if step >= 0.0 { sliding.0 } else { sliding.1 };
        let most = target.abs().max(side_n) * dx / x_c;
        lag_bristle += (target - lag_bristle).clamp(-most, most);
        dahl[i] = lag_dahl - target;
        bristle[i] = lag_bristle - target;
    }
    vec![dahl, bristle]
}

/// The friction a trial slides against in the direction `sign`,
/// typically: the median of its size over the samples where the needle
/// slides that way in the tissue.
fn sliding_friction_n(p: &Prepared, sign: f64) -> f64 {
    crate::fit::trial::median(
        (0..p.trial.len())
            .filter(|&i| {
                let v = p.velocity.v_mps[i] * sign;
                p.length_m[i] > 0.0 && v >= p.params.half_band_mps
            })
            .map(|i| p.friction_n[i].abs())
            .collect(),
    )
}

/// Walls and membranes where the detector found them, each a local
/// stiffening up to the force it let go of: wall_n·s^n over its own
/// stretch s (0 where it began to load, 1 at its top), n on the grid — 1
/// a linear spring, 2 and 3 a collagen wall stiffening as it stretches
/// (Fung). Each wall's stretch is its own (a vessel wall and a muscle
/// fascia differ tenfold), read from its rise ([`rise`]): no
/// earlier than where the wall before it was through, nor before the
/// capsule gave way — the tip reaches a deeper membrane only past the one
/// above it. A wall need not break at once: a layered vessel wall tears
/// layer by layer and a damaged one softens, so its force may roll over
/// and ease off over up to its thickness ([`rolled_over_top`],
/// [`give_way`]); the column then falls from the top in a straight line
/// to where the wall is through (a cohesive law's linear softening). A
/// wall that broke at once lets go of the fall the detector measured.
/// Each is read against the residual's own course there, a straight
/// line: the pooled nominal can miss one trial by newtons over its
/// insertion (its friction), and the nominal at its best for the trial
/// bends its corrections round the walls themselves.
fn walls(p: &Prepared, n: f64) -> Vec<Vec<f64>> {
    let found = Found {
        x_m: &p.trial.x_m,
        residual_n: &p.residual_n,
        structures: &p.structures,
        puncture_x_m: p.geometry.puncture_x_m,
        noise_n: p.noise_n,
    };
    let (col, steps) = wall_column(&found, n);
    vec![col, layer_steps(&steps, &p.cutting)]
}

/// The cutting beneath each wall's layer against the one above it: a
/// membrane parts two tissues (skin and the muscle under its fascia) that
/// need not cut alike, so the force past a wall need not come back to
/// the course it rose from. Each wall's step (`(through, step_n)`, the
/// wall's rise less its fall) holds past where it is through as long as
/// the tip cuts — the nominal's cutting share.
fn layer_steps(steps: &[(usize, f64)], cutting: &[f64]) -> Vec<f64> {
    let mut col = vec![0.0; cutting.len()];
    for &(through, step_n) in steps {
        for (c, share) in col.iter_mut().zip(cutting).skip(through) {
            *c += step_n * share;
        }
    }
    col
}

/// What [`walls`] reads of a trial: its positions and residual, the
/// structures the detector found (last sample held, its position, the
/// wall force), where the capsule gave way and the load cell's noise.
struct Found<'a> {
    x_m: &'a [f64],
    residual_n: &'a [f64],
    structures: &'a [(usize, f64, f64)],
    puncture_x_m: f64,
    noise_n: f64,
}

/// [`walls`]' first column: every wall found, each stiffening as s^n,
/// then softening to nothing over its give-way; and each wall's layer
/// step, where it is through (for [`layer_steps`]).
fn wall_column(found: &Found, n: f64) -> (Vec<f64>, Vec<(usize, f64)>) {
    let (x, r) = (found.x_m, found.residual_n);
    let mut col = vec![0.0; x.len()];
    let mut steps = Vec::new();
    let mut before: Option<usize> = None;
    for (k, &(last_held, _, fall_n)) in found.structures.iter().enumerate() {
        let next = found.structures.get(k + 1).map_or(x.len(), |s| s.0);
        let gave_way = before.unwrap_or(0);
        // A wall needs a sample past it to fall on, and lies past the one
        // before it.
        if last_held + 1 >= x.len() || last_held < gave_way {
            continue;
        }
        let from = (gave_way..last_held)
            .find(|&i| x[i] > found.puncture_x_m)
            .unwrap_or(last_held);
        let level = (0.02 * fall_n).max(3.0 * found.noise_n);
        // The wall's shape is read off the residual's course through it,
        // that course read again from the top of a wall that rolled over.
        let off = |course: &Rise| -> Vec<f64> {
            (0..x.len())
                .map(|i| r[i] - course.slope_n_per_m * x[i])
                .collect()
        };
        let held = rise(x, r, from, last_held, n);
        let mut off_course = off(&held);
        let top = rolled_over_top(x, &off_course, from, last_held, level).unwrap_or(last_held);
        let course = if top == last_held {
            held
        } else {
            let course = rise(x, r, from, top, n);
            off_course = off(&course);
            course
        };
        let (peak, through, wall_n) = match give_way(x, &off_course, top, next) {
            Some(g) if top != last_held || g.through > top + SHARP_SAMPLES => {
                (top, g.through, g.wall_n)
            }
            _ => (last_held, last_held + 1, fall_n),
        };
        let x_peak = x[peak];
        // A wall that rolled over but shows no give-way held to the fall.
        let risen = if peak == top { course } else { held };
        let start_m = x[risen.start];
        // A rise too short to read (no height) says nothing of the layer,
        // nor does a straight one (its height is its course's too).
        if risen.height_n > 0.0 && n > 1.0 {
            steps.push((through, risen.height_n - wall_n));
        }
        before = Some(through);
        let stretch_m = (x_peak - start_m).max(1e-6);
        for i in (0..=peak).rev() {
            if x[i] < start_m {
                break;
            }
            let s = ((x[i] - start_m) / stretch_m).clamp(0.0, 1.0);
            col[i] += wall_n * power(s, n);
        }
        let softening_m = (x[through] - x_peak).max(1e-9);
        for i in peak + 1..through {
            col[i] += wall_n * (1.0 - (x[i] - x_peak) / softening_m).clamp(0.0, 1.0);
        }
    }
    (col, steps)
}

/// A wall's rise ([`rise`]).
#[derive(Clone, Copy)]
struct Rise {
    /// The sample where the wall began to load.
    start: usize,
    /// The slope of the residual's course beneath it, N/m.
    slope_n_per_m: f64,
    /// How far it rose above that course to its peak, N.
    height_n: f64,
}

/// Where a wall began to load: the least-squares hinge of the residual's
/// course (a straight line) and the wall's rise on it, h·s^n over its
/// stretch s (0 at the start, 1 at the peak), over the samples `from`
/// (past the capsule and the wall before) to the peak, the start scanned
/// at up to [`RISE_STARTS`] places. The level before a wall need not be
/// the one after it (the tip may cut less in a vessel's lumen than in the
/// parenchyma around it), so the start is read from the rise itself; and
/// the pooled nominal can miss a trial by newtons over its insertion (its
/// friction), so the course is a line, not a level.
fn rise(x: &[f64], r: &[f64], from: usize, peak: usize, n: f64) -> Rise {
    let flat = Rise {
        start: from.min(peak),
        slope_n_per_m: 0.0,
        height_n: 0.0,
    };
    if peak < from + 3 {
        return flat;
    }
    let step = (peak - from).div_ceil(RISE_STARTS).max(1);
    // The course's sums are every start's: summed once, the rise's alone
    // over the samples past each start (s is 0 before it).
    let mut course = Lsq::<2>::default();
    course.add_all((from..=peak).map(|i| ([1.0, x[i] - x[peak]], r[i])));
    let (course_ata, course_aty, yy) = course.sums();
    let fit_from = |start: usize| -> Option<(f64, Rise)> {
        let span_m = x[peak] - x[start];
        if span_m <= 0.0 {
            return None;
        }
        let [mut ss, mut s1, mut sd, mut sr] = [0.0; 4];
        for i in (from..=peak).filter(|&i| x[i] > x[start]) {
            let s = power((x[i] - x[start]) / span_m, n);
            ss += s * s;
            s1 += s;
            sd += s * (x[i] - x[peak]);
            sr += s * r[i];
        }
        let fit = Lsq::<3>::from_sums(
            [
                [ss, s1, sd],
                [0.0, course_ata[0][0], course_ata[0][1]],
                [0.0, 0.0, course_ata[1][1]],
            ],
            [sr, course_aty[0], course_aty[1]],
            yy,
        );
        let c = fit.solve()?;
        let rise = Rise {
            start,
            slope_n_per_m: c[2],
            height_n: c[0],
        };
        (c[0] > 0.0).then(|| (fit.sse(&c), rise))
    };
    (from..peak - 1)
        .step_by(step)
        .filter_map(fit_from)
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map_or(flat, |(_, rise)| rise)
}

/// The end of the samples after `peak` a wall's fall is read over: while
/// the needle advances (neither backs off nor stands still over
/// [`STILL_SAMPLES`]), within [`THICKEST_WALL_M`] of the peak, before
/// the next wall's peak `next`.
fn fall_end(x: &[f64], peak: usize, next: usize) -> usize {
    let last = next.min(x.len());
    // Still over the last STILL_SAMPLES steps: the first of them is where
    // it stopped (the samples at rest are the stop's, not the wall's).
    let stood = |i: usize| i >= peak + STILL_SAMPLES && x[i] <= x[i - STILL_SAMPLES];
    (peak + 1..last)
        .find_map(|i| {
            if stood(i) {
                Some(i + 1 - STILL_SAMPLES)
            } else {
                (x[i] < x[i - 1] || x[i] - x[peak] > THICKEST_WALL_M).then_some(i)
            }
        })
        .unwrap_or(last)
        .max(peak + 1)
}

/// Samples the needle must not advance over to have stopped: an encoder
/// read faster than it counts repeats a reading while it still moves.
const STILL_SAMPLES: usize = 5;

/// s^n, by multiplication for the wall grid's exponents (1, 1.5, 2, 3):
/// `powf` was most of [`rise`]'s time.
fn power(s: f64, n: f64) -> f64 {
    match n {
        1.0 => s,
        1.5 => s * s.sqrt(),
        2.0 => s * s,
        3.0 => s * s * s,
        _ => s.powf(n),
    }
}

/// How many places [`rise`] tries a wall's start at.
const RISE_STARTS: usize = 200;

/// The top of a wall that rolled over and eased off before the fall the
/// detector saw: walking back from `last_held` (no further than
/// [`THICKEST_WALL_M`], nor past `from`) over means of five samples that
/// stay above the one there less `level_n` — the wall easing off, not
/// yet its rise — the highest, where it stands more than `level_n`
/// above the mean at `last_held`; `None` where the wall held its load to
/// the fall.
fn rolled_over_top(
    x: &[f64],
    r: &[f64],
    from: usize,
    last_held: usize,
    level_n: f64,
) -> Option<usize> {
    const SIDE: usize = 5;
    let mean_to = |i: usize| r[i + 1 - SIDE..=i].iter().sum::<f64>() / SIDE as f64;
    let held_n = mean_to(last_held.checked_sub(SIDE - 1)? + SIDE - 1);
    // Means from `from` on: one reaching further back would take in the
    // wall before.
    let (end, top_n) = (from + SIDE - 1..=last_held)
        .rev()
        .take_while(|&i| x[last_held] - x[i] <= THICKEST_WALL_M)
        .map(|i| (i, mean_to(i)))
        .take_while(|&(_, m)| m >= held_n - level_n)
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    (top_n > held_n + level_n).then_some(end - SIDE / 2)
}

/// A fall within this many samples of the peak is a wall that broke at
/// once: it lets go of the fall the detector measured there.
const SHARP_SAMPLES: usize = 2;

/// The thickest wall a give-way is looked for over, m: a 3 mm artery.
const THICKEST_WALL_M: f64 = 0.003;

/// How a wall gave way after its peak ([`give_way`]).
struct GiveWay {
    /// The first sample where the wall is through.
    through: usize,
    /// The force the wall let go of over its fall.
    wall_n: f64,
}

/// How a wall gave way after its peak: the residual (off its course)
/// there as the wall's force falling in a straight line from the peak to
/// nothing where it is through, on a level — the least-squares hinge
/// over every place the fall may end ([`fall_end`]). A wall that broke
/// at once has its hinge right after the peak. Written
/// here: a hinge scanned over its knot is a few lines, and no regression
/// crate has it.
fn give_way(x: &[f64], r: &[f64], peak: usize, next_peak: usize) -> Option<GiveWay> {
    let end = fall_end(x, peak, next_peak);
    // The level alone over the last k samples of the window, for every k.
    let tails = running((peak..end).rev(), r, |_| [0.0, 1.0]);
    let mut best: Option<(f64, GiveWay)> = None;
    for through in peak + 1..end {
        let span_m = x[through] - x[peak];
        if span_m <= 0.0 {
            continue;
        }
        let mut fit = tails[end - through].clone();
        fit.add_all((peak..through).map(|i| ([1.0 - (x[i] - x[peak]) / span_m, 1.0], r[i])));
        let Some(c) = fit.solve() else { continue };
        let sse = fit.sse(&c);
        if best.as_ref().is_none_or(|(s, _)| sse < *s) {
            best = Some((
                sse,
                GiveWay {
                    through,
                    wall_n: c[0],
                },
            ));
        }
    }
    best.map(|(_, g)| g).filter(|g| g.wall_n > 0.0)
}

/// Cutting that depends on depth: growing with depth past the surface
/// as a power of it (the paper: cutting "rose slightly with depth";
/// `exponent` 1, a rise in proportion, or ½, one that slows as it goes,
/// as a power law or a saturating rise has it), beside a cutting offset.
/// The growth is the share of the cutting force the nominal has on,
/// times (depth / [`GROWTH_DEPTH_M`])^`exponent`: its gain is the growth
/// at that depth, N. (A layer loaded again after the puncture is each
/// trial's own, the nominal's: `super::reload`.)
fn depth_cutting(p: &Prepared, exponent: f64) -> Vec<Vec<f64>> {
    let n = p.trial.len();
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        let depth_m = (p.trial.x_m[i] - p.geometry.contact_x_m).max(0.0);
        a[i] = p.cutting[i] * (depth_m / GROWTH_DEPTH_M).powf(exponent);
        b[i] = p.cutting[i];
    }
    vec![a, b]
}

/// The depth at which [`depth_cutting`]'s growth is given.
const GROWTH_DEPTH_M: f64 = 0.01;

/// [`inertia`]'s grid: a rigid holder (0), a drive's first-order lag of
/// 3, 10 or 30 ms, then, from 1 on, the mounts of [`mount_at`], a mode
/// and a stiffness each.
const MOUNT_GRID: [f64; 4 + MOUNTS] = {
    let mut grid = [0.0; 4 + MOUNTS];
    (grid[1], grid[2], grid[3]) = (0.003, 0.01, 0.03);
    let mut m = 0;
    while m < MOUNTS {
        grid[4 + m] = (m + 1) as f64;
        m += 1;
    }
    grid
};
const MOUNTS: usize = {
    let (mut mounts, mut s) = (0, 0);
    while s < MOUNT_STIFFNESS.len() {
        mounts += MOUNT_STIFFNESS[s].modes();
        s += 1;
    }
    mounts
};

/// A mount's stiffness as [`held_by_mount`] has it, and the modes it is
/// searched at.
struct MountStiffness {
    /// `None`: stiff, the needle goes where the stage goes.
    k_n_per_m: Option<f64>,
    /// The lowest and highest of [`mount_at`]'s frequencies, in thirds of
    /// an octave from 5 Hz, and every how many thirds between them.
    lowest_third: usize,
    highest_third: usize,
    every_thirds: usize,
}

impl MountStiffness {
    /// How many modes (frequency and damping ratio) it is searched at.
    const fn modes(&self) -> usize {
        self.frequencies() * DAMPING_RATIOS.len()
    }

    const fn frequencies(&self) -> usize {
        (self.highest_third - self.lowest_third) / self.every_thirds + 1
    }
}

/// The mounts' stiffnesses: stiff, at every mode; or 30, 10 or 3 kN/m —
/// a benchtop stage's flexures to a robot arm at its tool or a printed
/// holder — at the modes a holder of 0.1 to 1 kg (a load cell and a
/// needle driver) rings at on it, √(k/m)/2π (27.6–87 Hz, 15.9–50 Hz,
/// 8.7–27.6 Hz; the grid stops at 40 Hz), two thirds of an octave apart:
/// what a compliant mount adds is its give, and its ring is the stiff
/// mount's, searched at every mode (every compliant mode costs a grid
/// value in every round). Stiffer than about 100 kN/m, a newton's change
/// is taken up within 10 µm of travel, an encoder count or a few: the
/// stiff mount.
const MOUNT_STIFFNESS: [MountStiffness; 4] = [
    MountStiffness {
        k_n_per_m: None,
        lowest_third: 0,
        highest_third: THIRDS_OF_OCTAVE - 1,
        every_thirds: 1,
    },
    MountStiffness {
        k_n_per_m: Some(3.0e4),
        lowest_third: 7,
        highest_third: 9,
        every_thirds: 2,
    },
    MountStiffness {
        k_n_per_m: Some(1.0e4),
        lowest_third: 5,
        highest_third: 9,
        every_thirds: 2,
    },
    MountStiffness {
        k_n_per_m: Some(3.0e3),
        lowest_third: 2,
        highest_third: 8,
        every_thirds: 2,
    },
];

/// Acceleration two ways, each as the holder feels it through a mount
/// or drive that spreads it over τ (first-order; τ = 0 is rigid) or
/// rings ([`mount_at`]): the
/// jumps of the needle's velocity (a start or stop is an impulse m·Δv,
/// which a sampled load cell shows on the first sample after it), and the
/// smooth rest, the second difference of position over ±10 ms with the
/// jumps' kinks taken out (else every jump is also a 20 ms triangle);
/// through a ringing mount, the tissue's own force less itself
/// ([`tissue_force_n`]; zero for a drive's lag, which passes it as it is);
/// and what a compliant mount's give changes in that force while the
/// needle is held ([`held_by_mount`]; quasi-static, not rung, and zero on
/// a stiff mount).
fn inertia(p: &Prepared, g: f64) -> Vec<Vec<f64>> {
    let mut cols = Vec::new();
    inertia_on_grid(p, &[g], &mut |_, c, _| cols = c.to_vec());
    cols
}

/// [`inertia`] at each of `grid`'s values, the two accelerations and the
/// tissue's force made once for all the mounts they are felt through.
fn inertia_on_grid(p: &Prepared, grid: &[f64], each: &mut Each<'_>) {
    let (n, rate) = (p.trial.len(), p.trial.rate_hz());
    let (step, smooth) = accelerations(p);
    let tissue_n = tissue_force_n(p);
    let sticking = Sticking::of(p);
    // What each stiffness's give changes in the tissue's force.
    let give_n: [Option<Vec<f64>>; MOUNT_STIFFNESS.len()] = MOUNT_STIFFNESS.map(|s| {
        let held_n = held_by_mount(&tissue_n, &sticking, s.k_n_per_m?);
        Some(held_n.iter().zip(&tissue_n).map(|(h, t)| h - t).collect())
    });
    let mut modes: Vec<AtMode> = Vec::new();
    for (gi, &g) in grid.iter().enumerate() {
        match mount_at(g) {
            Some((mode, s)) => match modes.iter_mut().find(|(m, _)| *m == mode) {
                Some((_, at)) => at.push((gi, s)),
                None => modes.push((mode, vec![(gi, s)])),
            },
            None => {
                let lagged = |s: &[f64]| lag(s.to_vec(), g, rate);
                each(
                    gi,
                    &[lagged(&step), lagged(&smooth), vec![0.0; n], vec![0.0; n]],
                    0,
                );
            }
        }
    }
    // Eight modes' signals rung together (and held at once, not every
    // mode's); the grid values are handed on mode by mode, out of the
    // grid's order, so that a mode's stiffnesses, which differ in the give
    // alone, keep its first three columns.
    for group in modes.chunks(CHAINS) {
        let chains = group.iter().flat_map(|(mode, _)| {
            [
                (&step[..], *mode, Hold::Step),
                (&smooth[..], *mode, Hold::Step),
                (&tissue_n[..], *mode, Hold::Ramp),
            ]
        });
        let mut rung = ring_each(chains.collect(), rate).into_iter();
        for (_, at) in group {
            let mut next = || rung.next().unwrap_or_default();
            let (step, smooth, mut mounted) = (next(), next(), next());
            for (m, f) in mounted.iter_mut().zip(&p.fitted_n) {
                *m -= f;
            }
            let mut cols = [step, smooth, mounted, vec![0.0; n]];
            for (i, &(gi, s)) in at.iter().enumerate() {
                match &give_n[s] {
                    Some(give_n) => cols[3].clone_from(give_n),
                    None => cols[3].fill(0.0),
                }
                each(gi, &cols, if i == 0 { 0 } else { 3 });
            }
        }
    }
}

/// A mode (Hz, damping ratio) and the grid values at it: (index in the
/// grid, index into [`MOUNT_STIFFNESS`]).
type AtMode = ((f64, f64), Vec<(usize, usize)>);

/// The tissue's force `tissue_n` as a compliant mount of stiffness
/// `k_n_per_m` passes it on: while the needle slides with the stage the
/// mount bears what the tissue resists with, but where the tissue's force
/// turns over while the needle is held — at a turn, at the start of a
/// withdrawal, at a start after a rest — the stage moves on and only the
/// mount gives, the force changing by k per metre of the stage's travel
/// until it reaches the force the needle slides at. At rest the force held lies in
/// the static band (a stop from a force above it slides the needle on
/// until it is back at the band's edge, as the nominal's held force is).
/// Outside the tissue's friction (on the capsule, out of the tissue) the
/// needle follows the stage. Quasi-static: the needle's mass and the
/// mount's ring are the mode's ([`ring_each`]); the deflection's shift of
/// the loading curve (F/k along the stage) is left to the nominal's fit.
fn held_by_mount(tissue_n: &[f64], s: &Sticking, k_n_per_m: f64) -> Vec<f64> {
    let mut held_n = tissue_n.to_vec();
    let n = held_n
        .len()
        .min(s.x_m.len())
        .min(s.v_mps.len())
        .min(s.length_m.len());
    for i in 1..n {
        let (target_n, l_m, v_mps) = (tissue_n[i], s.length_m[i], s.v_mps[i]);
        if l_m <= 0.0 {
            continue;
        }
        let taken_up_n = held_n[i - 1] + k_n_per_m * (s.x_m[i] - s.x_m[i - 1]);
        held_n[i] = if v_mps >= s.half_band_mps {
            taken_up_n.min(target_n)
        } else if v_mps <= -s.half_band_mps {
            taken_up_n.max(target_n)
        } else {
            let (dn_n_per_m, dp_n_per_m) = s.band_n_per_m;
            let lowest_n = target_n.min(dn_n_per_m * l_m);
            let highest_n = target_n.max(dp_n_per_m * l_m);
            taken_up_n.clamp(lowest_n, highest_n)
        };
    }
    held_n
}

/// What [`held_by_mount`] needs of a trial: where the stage is, how fast
/// it moves (as the encoder reads it: the needle is held where that lies
/// within the zero-velocity band, or where the mount has yet to take up
/// a turn) and how much of the needle is in the tissue, sample by sample;
/// the half width of the zero-velocity band, m/s; and the static band per
/// unit length (D_n ≤ 0, D_p ≥ 0), N/m.
struct Sticking<'a> {
    x_m: &'a [f64],
    v_mps: &'a [f64],
    length_m: &'a [f64],
    half_band_mps: f64,
    band_n_per_m: (f64, f64),
}

impl<'a> Sticking<'a> {
    fn of(p: &'a Prepared) -> Self {
        Self {
            x_m: &p.trial.x_m,
            v_mps: &p.velocity.v_mps,
            length_m: &p.length_m,
            half_band_mps: p.params.half_band_mps,
            band_n_per_m: (p.params.dn_n_per_m, p.params.dp_n_per_m),
        }
    }
}

/// The tissue's force as a ringing mount passes it to the load cell
/// ([`inertia`]'s third column, that force through the mount less the
/// nominal): the holder's mass hangs on the mount between the load cell
/// and the needle, so the load cell reads the tissue's force through the
/// mount as it reads the holder's inertia (m·ÿ + c·ẏ + k·y = F + m·a for
/// the mount's deflection y; the load cell reads k·y), and a force that
/// falls at once, a puncture's, rings. The force is the nominal at its
/// best for the trial ([`Prepared::fitted_n`]), taken to change evenly
/// between samples ([`Hold::Ramp`]): a fall lies anywhere between two
/// samples, and the mount's mean response to a fall at a time drawn
/// evenly over the interval is its response to that ramp. The mount
/// takes a quarter of its period to pass a fall on, and the nominal's
/// loading curve, fitted to the measured force, runs on until the
/// measured force has fallen far (the loading phase ends at the fall's
/// first sharp step, past the peak): the tissue's force fell before the
/// first sample after the peak
/// ([`crate::fit::trial::TrialFit::puncture_index`]) that lies three
/// noise sd below that curve. The column takes up those samples too (the
/// mount's delay is its physics); a fall the tissue itself spreads over
/// two samples offers it the same, which the no-effect grid and the
/// phantoms measure (book, *Decisions*).
fn tissue_force_n(p: &Prepared) -> Vec<f64> {
    let mut tissue_n = p.fitted_n.clone();
    let n = p.trial.len();
    let peak = p.geometry.puncture_index;
    let unloaded = (peak + 1..n).find(|&i| p.phase[i] != LOADING);
    if let Some(fallen) = unloaded {
        let below = |i: &usize| p.trial.f_n[*i] < p.fitted_n[*i] - 3.0 * p.noise_n;
        let fell = (peak + 1..fallen).find(below).unwrap_or(fallen);
        let fallen_n = tissue_n[fallen];
        for f in &mut tissue_n[fell..fallen] {
            *f = fallen_n;
        }
    }
    tissue_n
}

/// The needle's acceleration as [`inertia`] splits it: the jumps of its
/// velocity, each on the samples it may have landed on, and the smooth
/// rest.
fn accelerations(p: &Prepared) -> (Vec<f64>, Vec<f64>) {
    let (t, x) = (&p.trial.t_s, &p.trial.x_m);
    let n = x.len();
    let rate = p.trial.rate_hz();
    let k = ((0.01 * rate).round() as usize).max(1);
    let mut step = vec![0.0; n];
    let mut kinked = x.clone();
    for jump in &p.velocity.jumps {
        // Spread over the samples it may have landed on, by how likely each
        // is: a pulse on the wrong sample is two pulses of error.
        for (j, w) in (jump.index - 1..).zip(p.landing(jump)) {
            if j < n {
                step[j] += w * jump.dv_mps * rate;
            }
        }
        for i in jump.index..n {
            kinked[i] -= jump.dv_mps * (t[i] - jump.t_s);
        }
    }
    let span_s = k as f64 / rate;
    let smooth = (0..n)
        .map(|i| {
            if i < k || i + k >= n {
                0.0
            } else {
                (kinked[i + k] - 2.0 * kinked[i] + kinked[i - k]) / (span_s * span_s)
            }
        })
        .collect();
    (step, smooth)
}

const THIRDS_OF_OCTAVE: usize = 10;
const DAMPING_RATIOS: [f64; 3] = [0.05, 0.15, 0.4];

/// The mount at grid value `g` of [`inertia`] (from 1 on): its mode, 5–40
/// Hz, a benchtop stage's and holder's first modes, a third of an octave
/// apart on a stiff mount (two thirds on a compliant one,
/// [`MOUNT_STIFFNESS`]; a ring a sixth of an octave off drifts by a
/// tenth of a cycle over the first cycle, in which a damped ring is most
/// of its size),
/// lightly damped (a bolted joint), less so, or well damped (an
/// elastomer), as (Hz, damping ratio); and its stiffness, an index into
/// [`MOUNT_STIFFNESS`]. Listed stiffness by stiffness, damping ratio by
/// damping ratio, frequency by frequency. `None` below 1: `g` is a
/// first-order lag in s.
fn mount_at(g: f64) -> Option<((f64, f64), usize)> {
    let mut m = (g >= 1.0).then(|| (g as usize - 1).min(MOUNTS - 1))?;
    for (s, stiffness) in MOUNT_STIFFNESS.iter().enumerate() {
        let frequencies = stiffness.frequencies();
        if m < stiffness.modes() {
            let third = stiffness.lowest_third + m % frequencies * stiffness.every_thirds;
            let hz = 5.0 * 2f64.powf(third as f64 / 3.0);
            return Some(((hz, DAMPING_RATIOS[m / frequencies]), s));
        }
        m -= stiffness.modes();
    }
    None
}

fn mount_params(_: &'static str, g: f64) -> Vec<(&'static str, f64)> {
    let Some(((hz, zeta), s)) = mount_at(g) else {
        return vec![("lag_s", g)];
    };
    let mut params = vec![("mount_hz", hz), ("mount_damping_ratio", zeta)];
    if let Some(k) = MOUNT_STIFFNESS[s].k_n_per_m {
        params.push(("mount_stiffness_n_per_m", k));
    }
    params
}

/// How a sampled signal runs between its samples.
#[derive(Clone, Copy, PartialEq)]
enum Hold {
    /// At a sample's value over the interval up to it (an acceleration's
    /// pulse, put on the sample after it).
    Step,
    /// Straight from one sample's value to the next.
    Ramp,
}

/// [`ring_each`] with one mode (Hz, damping ratio) for all `signals`.
#[cfg(test)]
fn ring<const K: usize>(
    signals: [Vec<f64>; K],
    mode: (f64, f64),
    rate_hz: f64,
    holds: [Hold; K],
) -> [Vec<f64>; K] {
    let chains = signals
        .iter()
        .zip(holds)
        .map(|(s, hold)| (&s[..], mode, hold));
    let mut rung = ring_each(chains.collect(), rate_hz).into_iter();
    std::array::from_fn(|_| rung.next().unwrap_or_default())
}

/// Each signal as the load cell feels it through its own mount, ringing
/// at a mode (Hz, damping ratio ζ): the mount's deflection
/// y'' + 2ζω·y' + ω²·y = ω²·a, stepped a sample at a time by its exact
/// solution over the mean sample interval for the way the signal runs
/// between samples ([`Mount`]; a trial without a rate, too short to have
/// one, is left as it is). The signals are stepped [`CHAINS`] at a time,
/// side by side: each sample's step waits on the one before, and
/// independent chains run together in the time of one.
fn ring_each(chains: Vec<(&[f64], (f64, f64), Hold)>, rate_hz: f64) -> Vec<Vec<f64>> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return chains.into_iter().map(|(s, ..)| s.to_vec()).collect();
    }
    let n = chains.iter().map(|(s, ..)| s.len()).min().unwrap_or(0);
    let count = chains.len();
    let mut batch: Vec<Chain> = Vec::with_capacity(CHAINS);
    let mut rung = Vec::with_capacity(count);
    let mut mounts: Vec<((f64, f64), Mount)> = Vec::new();
    for (signal, mode, hold) in chains {
        let mount = match mounts.iter().find(|(m, _)| *m == mode) {
            Some((_, mount)) => *mount,
            None => {
                let mount = Mount::over(mode, 1.0 / rate_hz);
                mounts.push((mode, mount));
                mount
            }
        };
        batch.push(Chain::new(signal, mount, hold));
        if batch.len() == CHAINS {
            rung.extend(step_chains(std::mem::take(&mut batch), n));
        }
    }
    if !batch.is_empty() {
        let (real, quiet) = (batch.len(), vec![0.0; n]);
        batch.resize(CHAINS, Chain::new(&quiet, Mount::QUIET, Hold::Step));
        rung.extend(step_chains(batch, n).into_iter().take(real));
    }
    rung
}

/// How many signals [`ring_each`] steps side by side.
const CHAINS: usize = 8;

/// One signal to ring and the coefficients of its mount's step, as
/// [`step_chains`] takes them: the state after a sample is
/// Φ·(y, y') + b·(value before) + a·(value now), where a held signal's
/// value before is its value now ([`Mount`]).
#[derive(Clone)]
struct Chain<'s> {
    signal: &'s [f64],
    phi: [[f64; 2]; 2],
    on_before: [f64; 2],
    on_now: [f64; 2],
    /// The state the mount starts in.
    y0: f64,
}

impl<'s> Chain<'s> {
    fn new(signal: &'s [f64], mount: Mount, hold: Hold) -> Self {
        let Mount { phi, start, end } = mount;
        let first = signal.first().copied().unwrap_or(0.0);
        let (on_before, on_now, y0) = match hold {
            Hold::Step => ([0.0; 2], [start[0] + end[0], start[1] + end[1]], 0.0),
            // A force the mount already bears when the trial begins does
            // not ring; the needle is still then, with no acceleration to
            // bear.
            Hold::Ramp => (start, end, first),
        };
        Self {
            signal,
            phi,
            on_before,
            on_now,
            y0,
        }
    }
}

/// [`CHAINS`] signals of `n` samples stepped side by side, each through
/// its own mount, the coefficients laid out lane by lane.
fn step_chains(chains: Vec<Chain>, n: usize) -> Vec<Vec<f64>> {
    const K: usize = CHAINS;
    let lanes = |f: &dyn Fn(&Chain) -> f64| -> [f64; K] { std::array::from_fn(|k| f(&chains[k])) };
    let (p00, p01) = (lanes(&|c| c.phi[0][0]), lanes(&|c| c.phi[0][1]));
    let (p10, p11) = (lanes(&|c| c.phi[1][0]), lanes(&|c| c.phi[1][1]));
    let (b0, b1) = (lanes(&|c| c.on_before[0]), lanes(&|c| c.on_before[1]));
    let (a0, a1) = (lanes(&|c| c.on_now[0]), lanes(&|c| c.on_now[1]));
    let mut y = lanes(&|c| c.y0);
    let mut before = lanes(&|c| c.signal.first().copied().unwrap_or(0.0));
    let mut dy = [0.0; K];
    // A mount at rest with nothing to bear stays at rest: the ring starts
    // where a signal does.
    let from = if y.iter().all(|&y| y == 0.0) {
        let quiet = |i: &usize| chains.iter().all(|c| c.signal[*i] == 0.0);
        (0..n).find(|i| !quiet(i)).unwrap_or(n)
    } else {
        0
    };
    let signals: [&[f64]; K] = std::array::from_fn(|k| &chains[k].signal[..n]);
    let mut rung: [Vec<f64>; K] = std::array::from_fn(|k| {
        let mut out = Vec::with_capacity(n);
        out.extend_from_slice(&signals[k][..from]);
        out
    });
    // Sample i of each of the K signals: an iterator over one would not do.
    #[allow(clippy::needless_range_loop)]
    for i in from..n {
        let now: [f64; K] = std::array::from_fn(|k| signals[k][i]);
        for k in 0..K {
            let next_y = p00[k] * y[k] + p01[k] * dy[k] + b0[k] * before[k] + a0[k] * now[k];
            dy[k] = p10[k] * y[k] + p11[k] * dy[k] + b1[k] * before[k] + a1[k] * now[k];
            y[k] = next_y;
        }
        before = now;
        for (out, &y) in rung.iter_mut().zip(&y) {
            out.push(y);
        }
    }
    rung.into()
}

/// One sample interval of a mount's ring ([`ring_each`]), solved once, so
/// that a trial is stepped once a sample whatever the mode: the state
/// (y, y') after it is Φ·(y, y') + s·a₀ + e·a₁ for an input running
/// straight from a₀ to a₁ (a held input is a₀ = a₁). Φ's columns are the
/// state after the interval from a unit y and from a unit y' with no
/// input; s and e from rest under the input falling from 1 to 0 and
/// rising from 0 to 1. Each is found by integrating the mount's equation
/// over the interval in 64 fourth-order Runge–Kutta steps (0.04 rad each
/// at 40 Hz and 100 Hz: within 10⁻⁸ of the exact solution).
#[derive(Clone, Copy)]
struct Mount {
    phi: [[f64; 2]; 2],
    start: [f64; 2],
    end: [f64; 2],
}

impl Mount {
    /// A mount that passes nothing on (what [`ring_each`] pads a batch
    /// with).
    const QUIET: Self = Self {
        phi: [[0.0; 2]; 2],
        start: [0.0; 2],
        end: [0.0; 2],
    };

    fn over((hz, zeta): (f64, f64), interval_s: f64) -> Self {
        let w = std::f64::consts::TAU * hz;
        const STEPS: usize = 64;
        let h = interval_s / STEPS as f64;
        // The state after the interval from `state`, the input running
        // from `a0` to `a1`.
        let solve = |mut state: [f64; 2], (a0, a1): (f64, f64)| {
            let slope = |[y, dy]: [f64; 2], at_s: f64| {
                let a = a0 + (a1 - a0) * at_s / interval_s;
                [dy, w * w * (a - y) - 2.0 * zeta * w * dy]
            };
            for j in 0..STEPS {
                let at_s = j as f64 * h;
                let add = |s: [f64; 2], d: [f64; 2], by: f64| [s[0] + by * d[0], s[1] + by * d[1]];
                let k1 = slope(state, at_s);
                let k2 = slope(add(state, k1, h / 2.0), at_s + h / 2.0);
                let k3 = slope(add(state, k2, h / 2.0), at_s + h / 2.0);
                let k4 = slope(add(state, k3, h), at_s + h);
                for d in 0..2 {
                    state[d] += h / 6.0 * (k1[d] + 2.0 * k2[d] + 2.0 * k3[d] + k4[d]);
                }
            }
            state
        };
        let (from_y, from_dy) = (solve([1.0, 0.0], (0.0, 0.0)), solve([0.0, 1.0], (0.0, 0.0)));
        Self {
            phi: [[from_y[0], from_dy[0]], [from_y[1], from_dy[1]]],
            start: solve([0.0; 2], (1.0, 0.0)),
            end: solve([0.0; 2], (0.0, 1.0)),
        }
    }
}

/// First-order lag of time constant `tau_s` (none at 0).
fn lag(mut signal: Vec<f64>, tau_s: f64, rate_hz: f64) -> Vec<f64> {
    if tau_s > 0.0 {
        let alpha = 1.0 - (-1.0 / (tau_s * rate_hz)).exp();
        let mut y = 0.0;
        for s in &mut signal {
            y += (*s - y) * alpha;
            *s = y;
        }
    }
    signal
}

/// An offset growing in time since the recording began, as a bridge's
/// temperature moves it: at a steady rate (`tau_s` 0); settling to a new
/// zero with time constant `tau_s` > 0, τ·(1 − e^{−t/τ}) (a first-order
/// approach over tens of seconds), the coefficient its rate at the start;
/// or, `tau_s` < 0, lagging a steady warming by |τ|, t − |τ|·(1 −
/// e^{−t/|τ|}): the gauge warms through the body it is bonded to, so its
/// drift starts flat and accelerates (as t²/2|τ| at first) towards the
/// rate, the coefficient. Each is taken less its value where the trial
/// was tared (`fit::trial::tare`: the median of the first half of the
/// samples before the loading rise, which the approach nearly spans; for
/// a drift moving one way, its value halfway through that half): the
/// force holds the drift since then. Two columns: the drift at one rate
/// shared by every trial, and at each trial's own rate as the samples with
/// no tissue on the needle read it ([`rate_out_of_tissue`]; none where
/// the load cell did not read its zero again after the needle came out),
/// with one gain (1 where the form is the drift's): a bridge's drift is
/// the recording's, not the tissue's — which way and how fast it moves
/// turns on how long the bridge had been powered and what warmed it, and
/// can differ from one insertion to the next.
fn drift(p: &Prepared, tau_s: f64) -> Vec<Vec<f64>> {
    let t0 = p.trial.t_s.first().copied().unwrap_or(0.0);
    let lag_s = -tau_s;
    let mut column: Vec<f64> = p
        .trial
        .t_s
        .iter()
        .map(|t| {
            let t = t - t0;
            if tau_s > 0.0 {
                tau_s * (1.0 - (-t / tau_s).exp())
            } else if lag_s > 0.0 {
                t - lag_s * (1.0 - (-t / lag_s).exp())
            } else {
                t
            }
        })
        .collect();
    let approach = p.phase.iter().take_while(|&&k| k == APPROACH).count();
    let zero = column.get(approach / 4).copied().unwrap_or(0.0);
    column.iter_mut().for_each(|c| *c -= zero);
    let rate = rate_out_of_tissue(p, &column).unwrap_or(0.0);
    let own = column.iter().map(|c| rate * c).collect();
    vec![column, own]
}

/// A trial's own drift along `column` (per unit of it), by least squares
/// of the residual over the samples with no tissue on the needle (before
/// contact, and after it came out): there the load cell reads its zero
/// and nothing else, so no misfit of the tissue's model can set it. Read
/// on the trial itself, withheld or not, as the nominal's spread is: one
/// number a trial, from samples the tissue's model does not reach. None
/// where fewer than [`OUT_OF_TISSUE_SAMPLES`] follow the needle's coming
/// out: the approach alone, before the drift has grown, reads little of
/// it.
fn rate_out_of_tissue(p: &Prepared, column: &[f64]) -> Option<f64> {
    let after = p.phase.iter().filter(|&&k| k == AFTER).count();
    let out = (0..p.trial.len()).filter(|&i| matches!(p.phase[i], APPROACH | AFTER));
    let (mut cc, mut cr) = (0.0, 0.0);
    for i in out {
        cc += column[i] * column[i];
        cr += column[i] * p.residual_n[i];
    }
    (after >= OUT_OF_TISSUE_SAMPLES && cc > 0.0).then(|| cr / cc)
}

/// Least samples after the needle came out that read a trial's own
/// drift: 0.5 s at 100 Hz.
const OUT_OF_TISSUE_SAMPLES: usize = 50;

/// Tissue motion grid: frequency (breathing, 0.15–0.4 Hz) × amplitude.
const MOTION_FREQ_HZ: [f64; 5] = [0.15, 0.2, 0.25, 0.3, 0.4];
const MOTION_AMPLITUDE_M: [f64; 3] = [0.0005, 0.0015, 0.003];
/// Phases tried per trial (breathing does not start with the trial).
const MOTION_PHASES: usize = 12;

fn motion_at(g: f64) -> (f64, f64) {
    let k = (g as usize).min(MOTION_FREQ_HZ.len() * MOTION_AMPLITUDE_M.len() - 1);
    (
        MOTION_FREQ_HZ[k % MOTION_FREQ_HZ.len()],
        MOTION_AMPLITUDE_M[k / MOTION_FREQ_HZ.len()],
    )
}

fn motion_params(_: &'static str, g: f64) -> Vec<(&'static str, f64)> {
    let (f, a) = motion_at(g);
    vec![("freq_hz", f), ("amplitude_m", a)]
}

/// The tissue moving along the axis by A·sin(2π f t + φ): after the
/// puncture, the nominal model evaluated at the needle's position in the
/// moving tissue (friction length, sliding and cutting all follow the
/// relative motion), minus the nominal; while loading, a stiffness
/// polynomial in the relative depth beside the nominal's own curve, which
/// was fitted against the needle's position and is bent by the motion.
/// φ is found on each trial, withheld or not, like the contact point: it
/// is where the breathing was when the trial began, not a property of
/// the tissue; where it fits better, φ is found per window of two breaths
/// ([`wandering`]): a breath's length varies.
fn tissue_motion(p: &Prepared, g: f64) -> Vec<Vec<f64>> {
    let mut cols = Vec::new();
    tissue_motion_on_grid(p, &[g], &mut |_, c, _| cols = c.to_vec());
    cols
}

/// [`tissue_motion`] at each of `grid`'s values, the harmonics of each
/// frequency made once for all its amplitudes (sine and cosine of both
/// harmonics at every sample, at the search rate and at the full one).
fn tissue_motion_on_grid(p: &Prepared, grid: &[f64], each: &mut Each<'_>) {
    // The phase is searched on the trial at the search rate, the columns
    // made at the full one; the moved model has the trial's loading curve
    // where the tissue's frame has it, up to its sudden fall.
    let coarse = p.for_search();
    let sudden = p.at_sudden_fall();
    let coarse_sudden = sudden.for_search();
    let t0 = p.trial.t_s[0];
    // Frequency by frequency, so that one frequency's harmonics are kept.
    let mut order: Vec<usize> = (0..grid.len()).collect();
    order.sort_by(|&a, &b| motion_at(grid[a]).0.total_cmp(&motion_at(grid[b]).0));
    // (ω, its harmonics at the search rate, at the full rate.)
    let (mut kept_omega, mut coarse_h, mut full_h) = (f64::NAN, Vec::new(), Vec::new());
    for gi in order {
        let (f_hz, amplitude_m) = motion_at(grid[gi]);
        let steady = TissueShift {
            omega_rad_s: TAU * f_hz,
            t_ref_s: t0,
            coeffs_m: [0.0; 4],
            wander: PhaseWander::NONE,
        };
        if kept_omega != steady.omega_rad_s {
            kept_omega = steady.omega_rad_s;
            coarse_h = harmonics_along(&steady, &coarse.trial.t_s);
            full_h = harmonics_along(&steady, &p.trial.t_s);
        }
        // A·sin(ωt + φ) = A·cos φ·sin ωt + A·sin φ·cos ωt.
        let sine = |k: usize| {
            let (s, c) = (TAU * k as f64 / MOTION_PHASES as f64).sin_cos();
            TissueShift {
                coeffs_m: [amplitude_m * c, amplitude_m * s, 0.0, 0.0],
                ..steady
            }
        };
        // Each phase's squared error at every sample searched (the
        // loading curve's column is not searched).
        let errors: Vec<Vec<f64>> = (0..MOTION_PHASES)
            .map(|k| {
                let shift = sine(k);
                let (moved, ..) = moved_model(coarse_sudden, &coarse.params, &|i| {
                    shift.at_harmonics(coarse_h[i])
                });
                (0..coarse.trial.len())
                    .map(|i| match coarse.phase[i] {
                        LOADING => 0.0,
                        _ => (coarse.residual_n[i] - moved_less_nominal(coarse, &moved, i)).powi(2),
                    })
                    .collect()
            })
            .collect();
        let steady_sse = |k: usize| errors[k].iter().sum::<f64>();
        let best = (0..MOTION_PHASES)
            .min_by(|&a, &b| steady_sse(a).total_cmp(&steady_sse(b)))
            .unwrap_or(0);
        let wander = wandering((coarse, coarse_sudden), &errors, steady, amplitude_m)
            .filter(|w| w.1 < steady_sse(best));
        let full_wander;
        let (shift, h): (TissueShift, &[[f64; 5]]) = match wander {
            Some((w, _)) => {
                full_wander = harmonics_along(&w, &p.trial.t_s);
                (w, &full_wander)
            }
            None => (sine(best), &full_h),
        };
        each(
            gi,
            &moved_nominal(p, sudden, &|i| shift.at_harmonics(h[i])),
            0,
        );
    }
}

/// Breaths a window of [`wandering`] spans.
const MOTION_WINDOW_BREATHS: f64 = 2.0;

/// A·sin(ωt + φ(t)) with φ the best of the grid's phases in each window of
/// [`MOTION_WINDOW_BREATHS`] (`errors[k][i]`: phase k's squared error at
/// sample i), linear between the windows' middles, and its squared error
/// over the trial (the model moved with `coarse_sudden`'s geometry, as
/// the grid's); `None` for a trial of one window, or none that tells
/// the phases apart. A breath's length
/// varies, so over a trial its phase strays from any one frequency's (and
/// from the grid's frequency, which is the nearest of five): one phase for
/// the trial leaves the candidate under the others where the period
/// wanders.
fn wandering(
    (coarse, coarse_sudden): (&Prepared, &Prepared),
    errors: &[Vec<f64>],
    steady: TissueShift,
    amplitude_m: f64,
) -> Option<(TissueShift, f64)> {
    let t_s = &coarse.trial.t_s;
    let window_s = MOTION_WINDOW_BREATHS * TAU / steady.omega_rad_s;
    let window = |i: usize| ((t_s[i] - t_s[0]) / window_s) as usize;
    let windows = window(t_s.len() - 1) + 1;
    if windows < 2 {
        return None;
    }
    // Each window's squared error at each phase.
    let mut sums = vec![vec![0.0; errors.len()]; windows];
    for (k, e) in errors.iter().enumerate() {
        for (i, ei) in e.iter().enumerate() {
            sums[window(i)][k] += ei;
        }
    }
    // A window where every phase does as well (the approach, the loading
    // curve, the needle out) says nothing: it keeps the nearest one's.
    let chosen: Vec<Option<usize>> = sums
        .iter()
        .map(|at| {
            let (lo, hi) = at
                .iter()
                .fold((f64::INFINITY, 0.0f64), |(l, h), &e| (l.min(e), h.max(e)));
            (hi > lo).then(|| (0..at.len()).find(|&k| at[k] == lo).unwrap_or(0))
        })
        .collect();
    let first = chosen.iter().flatten().next().copied()?;
    let mut phases: Vec<f64> = Vec::with_capacity(windows);
    let mut last_k = first;
    for k in &chosen {
        last_k = k.unwrap_or(last_k);
        let phase = TAU * last_k as f64 / errors.len() as f64;
        // Unwrapped: the turn nearest the window before's.
        let last = phases.last().copied().unwrap_or(phase);
        phases.push(phase + TAU * ((last - phase) / TAU).round());
    }
    let shift = TissueShift {
        coeffs_m: [amplitude_m, 0.0, 0.0, 0.0],
        wander: PhaseWander::through(t_s[0] + window_s / 2.0, window_s, &phases),
        ..steady
    };
    let h = harmonics_along(&shift, t_s);
    let (moved, ..) = moved_model(coarse_sudden, &coarse.params, &|i| shift.at_harmonics(h[i]));
    let sse = (0..t_s.len())
        .filter(|&i| coarse.phase[i] != LOADING)
        .map(|i| (coarse.residual_n[i] - moved_less_nominal(coarse, &moved, i)).powi(2))
        .sum();
    Some((shift, sse))
}

/// Columns of [`tissue_motion`] for one tissue displacement and velocity
/// `shift(i)` at sample i, the model moved with `sudden`'s geometry
/// ([`Prepared::at_sudden_fall`]).
fn moved_nominal(
    p: &Prepared,
    sudden: &Prepared,
    shift: &dyn Fn(usize) -> (f64, f64),
) -> Vec<Vec<f64>> {
    let n = p.trial.len();
    let (moved, relative_x_m, contact_x_m) = moved_model(sudden, &p.params, shift);
    // The polynomial's own offset stands for an error in that contact.
    let mut cols = vec![vec![0.0; n]; 5];
    for i in 0..n {
        if p.phase[i] == LOADING {
            let d = (relative_x_m[i] - contact_x_m).max(0.0);
            cols[1][i] = d;
            cols[2][i] = d * d;
            cols[3][i] = -p.nominal_n[i];
            cols[4][i] = f64::from(u8::from(d > 0.0));
        } else {
            cols[0][i] = moved_less_nominal(p, &moved, i);
        }
    }
    cols
}

/// The column of [`moved_nominal`] after the puncture at sample i.
fn moved_less_nominal(p: &Prepared, moved: &[f64], i: usize) -> f64 {
    moved[i] - p.nominal_n[i]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each family's grid values map to its table, end to end.
    #[test]
    fn grid_values_name_the_law_they_stand_for() {
        assert_eq!(mount_at(0.03), None);
        assert_eq!(mount_at(1.0), Some(((5.0, 0.05), 0)));
        assert_eq!(mount_at(4.0), Some(((10.0, 0.05), 0)));
        assert_eq!(mount_at(10.0), Some(((40.0, 0.05), 0)));
        assert_eq!(mount_at(11.0), Some(((5.0, 0.15), 0)));
        assert_eq!(mount_at(30.0), Some(((40.0, 0.4), 0)));
        // 30 kN/m at 25 and 40 Hz, at each damping ratio.
        let hz = |g: f64| mount_at(g).map(|((hz, _), _)| (hz * 10.0).round() / 10.0);
        assert_eq!(mount_at(31.0).map(|(_, s)| s), Some(1));
        assert_eq!(hz(31.0), Some(25.2));
        assert_eq!(mount_at(33.0), Some(((25.198420997897465, 0.15), 1)));
        assert_eq!(hz(MOUNTS as f64), Some(31.7));
        assert_eq!(
            mount_at(MOUNTS as f64).map(|((_, z), s)| (z, s)),
            Some((0.4, 3))
        );
        assert_eq!(MOUNT_GRID.len(), 4 + 30 + 6 + 9 + 12);
        let params = mount_params("mount", MOUNTS as f64);
        assert_eq!(params.last(), Some(&("mount_stiffness_n_per_m", 3.0e3)));
        assert_eq!(stribeck_speed_mps(0.5), None);
        assert_eq!(stribeck_speed_mps(1.0), Some(0.00025));
        assert_eq!(stribeck_speed_mps(4.0), Some(0.002));
        let spectrum = |g: f64| {
            let p = spectrum_params("spectrum", g);
            p.iter().map(|&(_, v)| v).collect::<Vec<_>>()
        };
        // τ, decades, of the tissue's force, relaxing while it slides.
        assert_eq!(spectrum(0.0), [0.25, 0.0, 0.0, 0.0]);
        assert_eq!(spectrum(19.0), [4.0, 3.0, 0.0, 0.0]);
        assert_eq!(spectrum(20.0), [0.25, 0.0, 1.0, 0.0]);
        assert_eq!(spectrum(40.0), [0.25, 3.0, 1.0, 1.0]);
        let last = CANDIDATES[0].grid.last().copied().unwrap_or(0.0);
        assert_eq!(spectrum(last), [4.0, 3.0, 1.0, 1.0]);
    }

    /// A force sliding up at 0.1 N/s for 10 s, then held 5 s (the column
    /// is the part relaxed, F − h). Relaxing where it is held alone,
    /// nothing of it has relaxed at the stop and all of it relaxes from
    /// there; over its whole history only rate·τ of it is still unrelaxed
    /// at the stop, and only that relaxes at rest.
    #[test]
    fn the_tissue_force_relaxes_from_the_stop_or_over_its_whole_history() {
        let (dt_s, rate, tau) = (0.01, 0.1, 1.0);
        let top_n = rate * dt_s * 999.0;
        let steps: Vec<QlvStep> = (0..1500)
            .map(|i| {
                let sliding = i < 1000;
                QlvStep::In {
                    f_n: rate * dt_s * f64::from(i.min(999)),
                    dt_s,
                    rate_n_per_s: if sliding && i > 0 { rate } else { 0.0 },
                    sliding,
                }
            })
            .collect();
        let held = qlv_branch(&steps, tau, false);
        let whole = qlv_branch(&steps, tau, true);
        assert!(held[..1000].iter().all(|&c| c == 0.0));
        let unrelaxed_n = rate * tau * (1.0 - (-9.99f64 / tau).exp());
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        assert!(close(whole[999], top_n - unrelaxed_n), "{}", whole[999]);
        let left = (-5.0f64 / tau).exp();
        assert!(close(held[1499], top_n * (1.0 - left)), "{}", held[1499]);
        assert!(
            close(whole[1499], top_n - unrelaxed_n * left),
            "{}",
            whole[1499]
        );
    }

    /// A mount passes a held acceleration at unit gain; lightly damped, a
    /// step overshoots by e^{−πζ/√(1−ζ²)} (73 % at ζ = 0.1) and rings at
    /// its own frequency; a rate of zero leaves the signal as it was.
    #[test]
    fn a_mount_rings_at_its_mode_and_settles_on_the_acceleration() {
        let rate_hz = 1000.0;
        let [rung] = ring([vec![1.0; 4000]], (10.0, 0.1), rate_hz, [Hold::Step]);
        let peak = rung.iter().copied().fold(f64::MIN, f64::max);
        let peak_at = rung.iter().position(|&y| y == peak).unwrap();
        assert!((peak - 1.73).abs() < 0.02, "{peak}");
        // Half a damped period: 1/(2·10 Hz·√(1 − 0.01)) = 50 ms.
        assert!(
            (peak_at as f64 / rate_hz - 0.050).abs() < 0.002,
            "{peak_at}"
        );
        assert!((rung[3999] - 1.0).abs() < 1e-3, "{}", rung[3999]);
        assert_eq!(
            ring([vec![1.0, 2.0]], (10.0, 0.1), 0.0, [Hold::Step]),
            [vec![1.0, 2.0]]
        );
    }

    /// A compliant mount at a turn: the needle sticks while the stage
    /// travels back, the force falling k per metre of that travel (10 mN
    /// for each µm at 10 kN/m) from the insertion's +0.5 N until it
    /// reaches the withdrawal's −0.5 N, 100 µm on; a stiff mount turns at
    /// once. A stop from a sliding force above the static band drops to
    /// the band's edge at once (the needle slides on until it is held);
    /// the needle follows the stage out of the tissue.
    #[test]
    fn a_compliant_mount_takes_up_the_stages_travel_while_the_needle_sticks() {
        let turn = 50;
        let mut x_m: Vec<f64> = (0..turn).map(|i| i as f64 * 1e-6).collect();
        x_m.extend((0..=150).map(|j| (turn as f64 - 1.0 - j as f64) * 1e-6));
        let n = x_m.len();
        let v_mps: Vec<f64> = (0..n)
            .map(|i| match i.cmp(&turn) {
                std::cmp::Ordering::Less => 1e-3,
                std::cmp::Ordering::Equal => 0.0,
                std::cmp::Ordering::Greater => -1e-3,
            })
            .collect();
        let tissue_n: Vec<f64> = (0..n).map(|i| if i <= turn { 0.5 } else { -0.5 }).collect();
        let length_m = vec![0.02; n];
        let s = Sticking {
            x_m: &x_m,
            v_mps: &v_mps,
            length_m: &length_m,
            half_band_mps: 5e-6,
            band_n_per_m: (-30.0, 30.0),
        };
        let held = held_by_mount(&tissue_n, &s, 1.0e4);
        assert!(held[..=turn].iter().all(|&f| f == 0.5), "{held:?}");
        for j in 1..=100 {
            let expected = 0.5 - 0.01 * j as f64;
            assert!(
                (held[turn + j] - expected).abs() < 1e-9,
                "{j}: {}",
                held[turn + j]
            );
        }
        assert!(held[turn + 101..].iter().all(|&f| f == -0.5));
        assert_eq!(held_by_mount(&tissue_n, &s, 1.0e9), tissue_n);

        let stop_v = [1e-3, 1e-3, 0.0, 0.0];
        let (stop_x, stop_l) = ([0.0, 1e-6, 1e-6, 1e-6], [0.02; 4]);
        let stop = Sticking {
            x_m: &stop_x,
            v_mps: &stop_v,
            length_m: &stop_l,
            ..s
        };
        let held = held_by_mount(&[0.8, 0.8, 0.6, 0.6], &stop, 1.0e4);
        assert_eq!(held, [0.8, 0.8, 0.6, 0.6]);
        let out = Sticking {
            length_m: &[0.0; 4],
            ..stop
        };
        assert_eq!(
            held_by_mount(&[0.8, 0.1, 0.0, 0.0], &out, 1.0e4),
            [0.8, 0.1, 0.0, 0.0]
        );
    }

    /// [`wall_column`] on a trial past its puncture with a 12 mN load
    /// cell: the column and each wall's layer step.
    fn walls_of(
        x_m: &[f64],
        residual_n: &[f64],
        structures: &[(usize, f64, f64)],
        n: f64,
    ) -> (Vec<f64>, Vec<(usize, f64)>) {
        let found = Found {
            x_m,
            residual_n,
            structures,
            puncture_x_m: 0.0,
            noise_n: 0.012,
        };
        wall_column(&found, n)
    }

    /// [`walls_of`]'s column alone.
    fn column_of(
        x_m: &[f64],
        residual_n: &[f64],
        structures: &[(usize, f64, f64)],
        n: f64,
    ) -> Vec<f64> {
        walls_of(x_m, residual_n, structures, n).0
    }

    /// Two membranes, 1 µm a sample: the first rises from sample 100 to
    /// 3.8 N at 199 and falls to −0.23 N; the second rises from 300 to
    /// 2.3 N at 399 and gives way as the stage stops, falling to the
    /// dwell's −0.32 N. Each wall's column is its own rise, from where it
    /// began: nothing between them, where a second wall read back to the
    /// dwell's level would reach over the first.
    #[test]
    fn a_wall_begins_past_the_one_before_it() {
        let x_m: Vec<f64> = (0..500).map(|i| i as f64 * 1e-6).collect();
        let rise =
            |i: usize, from: usize, to_n: f64| -0.25 + (to_n + 0.25) * (i - from) as f64 / 99.0;
        let residual_n: Vec<f64> = (0..500)
            .map(|i| match i {
                100..=199 => rise(i, 100, 3.8),
                200..=299 => -0.23,
                300..=399 => rise(i, 300, 2.3),
                400.. => -0.32,
                _ => -0.25,
            })
            .collect();
        let structures = [(199, x_m[199], 4.03), (399, x_m[399], 2.62)];
        let col = column_of(&x_m, &residual_n, &structures, 1.0);
        assert!(col[..95].iter().all(|&c| c == 0.0), "{:?}", &col[..100]);
        assert!(
            col[200..295].iter().all(|&c| c == 0.0),
            "{:?}",
            &col[200..300]
        );
        assert!((col[199] - 4.03).abs() < 1e-9 && (col[399] - 2.62).abs() < 1e-9);
        assert!(col[400..].iter().all(|&c| c == 0.0));
    }

    /// A vessel wall, 10 µm a sample, on a residual that stands 0.3 N
    /// before it and 0.05 N after: it loads linearly from sample 100 to
    /// 0.9 N at 200, rolls over and eases off in a straight line to the
    /// level after at 260 (the wall's fall 0.85 N), while the detector saw
    /// the fall only at 230 and measured it 0.2 N. The column rises from
    /// where the wall began, not from where the residual comes down to the
    /// level after, to the wall's whole fall at the top, and softens to
    /// nothing where it is through.
    #[test]
    fn a_wall_that_rolls_over_softens_from_its_top_to_where_it_is_through() {
        let x_m: Vec<f64> = (0..400).map(|i| i as f64 * 1e-5).collect();
        let residual_n: Vec<f64> = (0..400)
            .map(|i| match i {
                0..=99 => 0.3,
                100..=199 => 0.3 + 0.6 * (i - 100) as f64 / 100.0,
                200..=259 => 0.9 - 0.85 * (i - 200) as f64 / 60.0,
                _ => 0.05,
            })
            .collect();
        let structures = [(230, x_m[230], 0.2)];
        let col = column_of(&x_m, &residual_n, &structures, 1.0);
        assert!(col[..100].iter().all(|&c| c == 0.0), "{:?}", &col[..110]);
        // The top is read from means of five samples: a sample off.
        let near = |i: usize, want_n: f64| (col[i] - want_n).abs() < 0.02;
        assert!(
            near(200, 0.85) && near(150, 0.425) && near(230, 0.425),
            "{:?}",
            &col[140..240]
        );
        assert!(col[260..].iter().all(|&c| c == 0.0), "{:?}", &col[255..265]);
    }

    /// A wall that breaks at once on a residual whose course falls 1 N a
    /// millimetre (a pooled nominal that pulls harder than this trial's
    /// shaft), 10 µm a sample: it loads as 0.6 N·s² from sample 100 to
    /// 200 and falls at once. Read against that course, it began at 100,
    /// did not roll over (the residual stands higher 50 samples earlier,
    /// on the course), and broke at once.
    #[test]
    fn a_wall_is_read_against_the_residuals_course_through_it() {
        let x_m: Vec<f64> = (0..400).map(|i| i as f64 * 1e-5).collect();
        let residual_n: Vec<f64> = (0..400)
            .map(|i| {
                let wall_n = match i {
                    100..=200 => 0.6 * ((i - 100) as f64 / 100.0).powi(2),
                    _ => 0.0,
                };
                -1000.0 * x_m[i] + wall_n
            })
            .collect();
        let structures = [(200, x_m[200], 0.6)];
        let col = column_of(&x_m, &residual_n, &structures, 2.0);
        assert!(
            col[..=100].iter().all(|&c| c.abs() < 1e-9),
            "{:?}",
            &col[..110]
        );
        assert!((col[150] - 0.15).abs() < 1e-9 && (col[200] - 0.6).abs() < 1e-9);
        assert!(col[201..].iter().all(|&c| c == 0.0), "{:?}", &col[195..210]);
    }

    /// Two walls, 10 µm a sample: the first rises to 2 N at sample 199
    /// and breaks at once to a level of 0.35 N, which holds to the second
    /// wall's fall at 259 (its rise hidden in the level). The second is
    /// read from where the first is through: it does not roll over from
    /// the first's top, nor soften over the level it held.
    #[test]
    fn a_wall_is_not_read_back_over_the_one_before_it() {
        let x_m: Vec<f64> = (0..400).map(|i| i as f64 * 1e-5).collect();
        let residual_n: Vec<f64> = (0..400)
            .map(|i| match i {
                100..=199 => 2.0 * (i - 100) as f64 / 99.0,
                200..=259 => 0.35,
                _ => 0.0,
            })
            .collect();
        let structures = [(199, x_m[199], 1.65), (259, x_m[259], 0.35)];
        let col = column_of(&x_m, &residual_n, &structures, 1.0);
        assert!((col[199] - 1.65).abs() < 1e-9, "{:?}", &col[195..205]);
        assert!(
            col[200..206].iter().all(|&c| c < 0.1),
            "{:?}",
            &col[200..210]
        );
        assert!(
            col[255..=259].iter().all(|&c| c > 0.3),
            "{:?}",
            &col[250..262]
        );
        assert!(col[260..].iter().all(|&c| c == 0.0));
    }

    /// A wall at a trial's last sample has nothing to fall on, and one
    /// listed before the wall ahead of it is through lies behind it:
    /// neither is read, and neither reads past the trial.
    #[test]
    fn a_wall_with_no_sample_past_it_or_behind_another_is_not_read() {
        let x_m: Vec<f64> = (0..300).map(|i| i as f64 * 1e-5).collect();
        let residual_n: Vec<f64> = (0..300)
            .map(|i| match i {
                100..=199 => (i - 100) as f64 / 99.0,
                _ => 0.0,
            })
            .collect();
        let structures = [
            (199, x_m[199], 1.0),
            (150, x_m[150], 0.5),
            (299, x_m[299], 0.2),
        ];
        let col = column_of(&x_m, &residual_n, &structures, 1.0);
        assert!((col[199] - 1.0).abs() < 1e-9 && (col[150] - 0.5).abs() < 0.02);
        assert!(col[200..].iter().all(|&c| c == 0.0), "{:?}", &col[195..]);
    }

    /// An encoder read faster than it counts repeats a reading while the
    /// needle advances: a wall easing off over 40 samples, 10 µm a
    /// sample with every fourth reading repeated, is read through to
    /// where it is through, not to the first repeat.
    #[test]
    fn a_repeated_encoder_reading_does_not_end_a_walls_give_way() {
        let x_m: Vec<f64> = (0..400).map(|i| (i - i / 4) as f64 * 1e-5).collect();
        let residual_n: Vec<f64> = (0..400)
            .map(|i| match i {
                100..=199 => 0.9 * (i - 100) as f64 / 100.0,
                200..=239 => 0.9 - 0.9 * (i - 200) as f64 / 40.0,
                _ => 0.0,
            })
            .collect();
        let g = give_way(&x_m, &residual_n, 200, 400).expect("a give-way");
        assert!((238..=241).contains(&g.through), "{}", g.through);
        assert!((g.wall_n - 0.9).abs() < 0.05, "{}", g.wall_n);
    }

    /// A wall's fall is read to where the stage stopped, its first sample
    /// at rest: the force there falls as cutting and sliding stop, which
    /// is the stop's, not the wall's.
    #[test]
    fn a_walls_fall_is_read_to_where_the_needle_stopped() {
        let x_m: Vec<f64> = (0..400).map(|i| i.min(250) as f64 * 1e-5).collect();
        assert_eq!(fall_end(&x_m, 200, 400), 251);
        let mut once = x_m.clone();
        once[230] = once[229];
        assert_eq!(fall_end(&once, 200, 400), 251);
    }

    /// A fascia between skin and the muscle beneath it, 10 µm a sample:
    /// the residual stands at 0 N, stiffens as s² by 1 N to sample 200
    /// and falls 1.5 N at once, to −0.5 N, where the muscle cuts half a
    /// newton less than the skin until the stage stops at 300 (the
    /// nominal's cutting share 1 to there, 0 at rest). The layer's step
    /// is −0.5 N past the wall while the tip cuts, nothing before it nor
    /// at rest; a wall whose force comes back to its course leaves none,
    /// and a straight rise (n = 1, its height its course's too) none.
    #[test]
    fn a_layer_beneath_a_wall_cuts_by_its_own_step() {
        let x_m: Vec<f64> = (0..400).map(|i| i.min(300) as f64 * 1e-5).collect();
        let cutting: Vec<f64> = (0..400).map(|i| f64::from(i < 300)).collect();
        let steps_of = |after_n: f64| {
            let residual_n: Vec<f64> = (0..400)
                .map(|i| match i {
                    100..=200 => ((i - 100) as f64 / 100.0).powi(2),
                    201.. => after_n,
                    _ => 0.0,
                })
                .collect();
            let structures = [(200, x_m[200], 1.0 - after_n)];
            let steps =
                |n: f64| layer_steps(&walls_of(&x_m, &residual_n, &structures, n).1, &cutting);
            (steps(2.0), steps(1.0))
        };
        let (step, straight) = steps_of(-0.5);
        assert!(straight.iter().all(|&c| c == 0.0));
        assert!(
            step[..=200].iter().all(|&c| c == 0.0),
            "{:?}",
            &step[195..205]
        );
        assert!(
            step[201..300].iter().all(|&c| (c + 0.5).abs() < 1e-6),
            "{:?}",
            &step[201..210]
        );
        assert!(step[300..].iter().all(|&c| c == 0.0));
        assert!(steps_of(0.0).0.iter().all(|&c| c.abs() < 1e-6));
    }

    /// Each compliant stiffness is searched at the modes a holder of
    /// 0.1 to 1 kg rings at on it (√(k/m)/2π): every such mode up to the
    /// grid's 40 Hz lies within a third of an octave of one searched, and
    /// none searched lies further than that outside them; the stiff mount
    /// at every mode.
    #[test]
    fn each_stiffness_is_searched_at_the_modes_a_holder_rings_at_on_it() {
        let third = 2f64.powf(1.0 / 3.0);
        let searched = |s: usize| -> Vec<f64> {
            (1..=MOUNTS)
                .filter_map(|g| mount_at(g as f64))
                .filter(|&(_, k)| k == s)
                .map(|((hz, _), _)| hz)
                .collect()
        };
        assert_eq!(searched(0).len(), THIRDS_OF_OCTAVE * DAMPING_RATIOS.len());
        for (s, stiffness) in MOUNT_STIFFNESS.iter().enumerate().skip(1) {
            let k_n_per_m = stiffness.k_n_per_m.unwrap();
            let mode_hz = |m_kg: f64| (k_n_per_m / m_kg).sqrt() / std::f64::consts::TAU;
            let hz = searched(s);
            for m_kg in (0..=20).map(|i| 0.1 * 10f64.powf(i as f64 / 20.0)) {
                let f = mode_hz(m_kg);
                if f <= 40.0 * third.sqrt() {
                    let nearest = hz
                        .iter()
                        .map(|h| (h / f).ln().abs())
                        .fold(f64::MAX, f64::min);
                    assert!(
                        nearest <= third.ln() + 1e-9,
                        "{k_n_per_m} N/m, {m_kg} kg: {hz:?}"
                    );
                }
            }
            for h in hz {
                assert!(
                    h >= mode_hz(1.0) / third && h <= mode_hz(0.1) * third,
                    "{h} Hz"
                );
            }
        }
    }

    /// A mount is stepped by its exact solution, however coarse the
    /// sampling: a 40 Hz mode read at 100 Hz follows the closed-form step
    /// response 1 − e^{−ζωt}(cos ω_d t + ζ/√(1−ζ²)·sin ω_d t) at every
    /// sample; a force it bears from the start does not ring, and one
    /// rising evenly between samples is the held one's response a half
    /// sample later, near enough (a tenth of the step's overshoot).
    #[test]
    fn a_mount_is_stepped_by_its_exact_solution() {
        let (hz, zeta, rate_hz) = (40.0, 0.15, 100.0);
        let mut input = vec![0.0; 40];
        input[1..].fill(1.0);
        let [held, ramped] = ring(
            [input.clone(), input],
            (hz, zeta),
            rate_hz,
            [Hold::Step, Hold::Ramp],
        );
        let w = std::f64::consts::TAU * hz;
        let wd = w * (1.0 - zeta * zeta).sqrt();
        // The held step acts from sample 0 on, over the interval before
        // sample 1.
        for (i, y) in held.iter().enumerate().skip(1) {
            let t = i as f64 / rate_hz;
            let exact = 1.0
                - (-zeta * w * t).exp()
                    * ((wd * t).cos() + zeta / (1.0 - zeta * zeta).sqrt() * (wd * t).sin());
            assert!((y - exact).abs() < 1e-7, "sample {i}: {y} against {exact}");
        }
        assert_eq!(held[0], 0.0);
        let [borne] = ring([vec![2.5; 20]], (hz, zeta), rate_hz, [Hold::Ramp]);
        assert!(borne.iter().all(|y| (y - 2.5).abs() < 1e-9), "{borne:?}");
        let peak = |v: &[f64]| v.iter().copied().fold(f64::MIN, f64::max);
        assert!(peak(&ramped) < peak(&held), "{ramped:?}");
        assert!(
            peak(&ramped) > 1.0 + 0.5 * (peak(&held) - 1.0),
            "{ramped:?}"
        );
    }
}
