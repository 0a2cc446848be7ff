//! One trial's needle in its tissue, a sample at a time: where the tip is
//! (outside, loading the capsule, inside), the force the tissue exerts
//! there with the effects' forces added, and the truth's events as they
//! happen. The effects' own states are in [`super::forces`]; this is the
//! tissue's, as the core's pipeline keeps one state per stage.

use super::effects::Effect;
use super::forces::{self, give_way, Added, Bristles, Kinematics, Tent, Walls};
use super::{friction_target, Form, Protocol, TissueParams, TrialTruth, TruthEvent};

/// Where the tip is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Contact {
    Out,
    Loading,
    Inserted,
}

/// The needle's state in one trial.
pub(super) struct Needle<'a> {
    tissue: &'a TissueParams,
    protocol: &'a Protocol,
    effects: &'a [Effect],
    form: Form,
    contact: Contact,
    /// x_s3, the relaxed surface once punctured (0 before), m.
    relaxed_surface_m: f64,
    /// The deepest the tip has been since the puncture (tissue frame), m.
    deepest_m: f64,
    /// Where the capsule gave way (tissue frame), m.
    punctured_m: f64,
    /// The capsule's force where it gave way, N: what a tearing wall
    /// carries a share of ([`super::tearing_share`]).
    peak_n: f64,
    /// The friction law's memory of the last sliding direction.
    last_sliding: f64,
    /// The tip's cutting force when the needle last moved, N.
    last_cutting_n: f64,
    /// The tip's position (tissue frame) at the previous sample, m.
    previous_m: f64,
    bristles: Bristles,
    tent: Tent,
    added: Added,
    walls: Walls,
    layers_ruptured: Vec<bool>,
    /// The puncture event whose fall comes at the next sample (its peak
    /// is the sample the capsule gave way at).
    falls_next: Option<usize>,
}

impl<'a> Needle<'a> {
    /// Outside the tissue, before the first sample; `walls` vessel walls.
    pub fn new(
        tissue: &'a TissueParams,
        protocol: &'a Protocol,
        (effects, form): (&'a [Effect], Form),
        walls: usize,
    ) -> Self {
        Self {
            tissue,
            protocol,
            effects,
            form,
            contact: Contact::Out,
            relaxed_surface_m: 0.0,
            deepest_m: 0.0,
            punctured_m: 0.0,
            peak_n: 0.0,
            last_sliding: 0.0,
            last_cutting_n: 0.0,
            previous_m: 0.0,
            bristles: Bristles::default(),
            tent: Tent::default(),
            added: Added::default(),
            walls: Walls::new(walls),
            layers_ruptured: vec![false; protocol.layers.len()],
            falls_next: None,
        }
    }

    /// The force on the load cell at one sample, before noise: the needle
    /// at `x_m` (the stage's frame), `p_m` in the tissue's frame.
    pub fn step(&mut self, k: &Kinematics, x_m: f64, p_m: f64, truth: &mut TrialTruth) -> f64 {
        if let Some(event) = self.falls_next.take() {
            truth.events[event].t_s = k.t_s;
        }
        self.touch(k, x_m, p_m, truth);
        let mut f = match self.contact {
            Contact::Loading => self.load(k, x_m, p_m, truth),
            Contact::Inserted => self.inside(k, x_m, p_m, truth),
            Contact::Out => 0.0,
        };
        if self.contact == Contact::Out {
            self.bristles.release();
        }
        let touching = self.contact != Contact::Out;
        self.added
            .add((self.effects, self.form), k, touching, &mut f);
        self.previous_m = p_m;
        f + self.protocol.tare_n
    }

    /// The tip reaching the surface, once a trial.
    fn touch(&mut self, k: &Kinematics, x_m: f64, p_m: f64, truth: &mut TrialTruth) {
        let reached = p_m >= self.protocol.surface_x_m && self.relaxed_surface_m == 0.0;
        if self.contact == Contact::Out && reached {
            self.contact = Contact::Loading;
            truth.events.push(event("contact", k.t_s, x_m));
        }
    }

    /// The capsule's force, until it gives way.
    fn load(&mut self, k: &Kinematics, x_m: f64, p_m: f64, truth: &mut TrialTruth) -> f64 {
        let s1 = self.protocol.surface_x_m;
        let d = p_m - s1;
        if d < 0.0 {
            self.contact = Contact::Out;
            return 0.0;
        }
        let f = self.tissue.stiffness_n(d);
        if d >= self.tissue.puncture_depth_m {
            self.contact = Contact::Inserted;
            self.relaxed_surface_m = s1 + self.tissue.relaxation * d;
            self.deepest_m = p_m;
            self.punctured_m = p_m;
            self.peak_n = f;
            truth.puncture_x_m = Some(x_m);
            truth.puncture_force_n = Some(f);
            truth.relaxed_surface_x_m = Some(self.relaxed_surface_m);
            self.falls_next = Some(truth.events.len());
            truth.events.push(event("puncture", k.t_s, x_m));
        }
        f
    }

    /// Inside the tissue: the shaft's and the tip's force over the length
    /// in contact, the tent of a dragged withdrawal, membranes and walls
    /// giving way.
    fn inside(&mut self, k: &Kinematics, x_m: f64, p_m: f64, truth: &mut TrialTruth) -> f64 {
        let protocol = self.protocol;
        let far = protocol.far_surface_x_m.unwrap_or(f64::INFINITY);
        // A withdrawing needle draws the tissue out with it.
        let exit_m = if protocol.drag_m > 0.0 && k.vr_mps < 0.0 {
            protocol.surface_x_m - protocol.drag_m
        } else {
            self.relaxed_surface_m
        };
        let l = p_m.min(far) - exit_m;
        if p_m >= far && self.deepest_m < far {
            truth.events.push(event("exit", k.t_s, x_m));
        }
        if l <= 0.0 {
            self.contact = Contact::Out;
            return 0.0;
        }
        let f = self.shaft_and_tip_n(k, p_m, l, far);
        let f = self.tent.step(protocol, self.tissue, k, (p_m, l), f);
        let holding = super::tearing_share(self.deepest_m - self.punctured_m, protocol.tear_m);
        let mut f = holding * self.peak_n + (1.0 - holding) * f;
        let at = (k.t_s, k.t_s - k.dt_s, x_m);
        for (n, layer) in protocol.layers.iter().enumerate() {
            let stretch = p_m - (protocol.surface_x_m + layer.depth_m);
            if self.layers_ruptured[n] || stretch <= 0.0 {
                continue;
            }
            f += give_way(
                layer.k_n_per_m * stretch,
                layer.rupture_n,
                &mut self.layers_ruptured[n],
                &mut truth.events,
                at,
            );
        }
        let effects = (self.effects, self.form);
        self.walls.add(
            effects,
            &truth.structures,
            p_m,
            &mut f,
            &mut truth.events,
            at,
        );
        f
    }

    /// Friction along `l_m` of shaft and the tip's cutting force; at rest
    /// the static band holds the force the needle was applied with when
    /// it stopped, the tip's cutting force with the shaft's friction (the
    /// paper's Karnopp law, max(D_n, min(F_a, D_p)) of the applied force
    /// F_a): the tissue ahead of a stopped tip stays compressed.
    fn shaft_and_tip_n(&mut self, k: &Kinematics, p_m: f64, l_m: f64, far_m: f64) -> f64 {
        let (tissue, effects, form) = (self.tissue, self.effects, self.form);
        let target = friction_target(tissue, effects, form, k.vr_mps, l_m, &mut self.last_sliding);
        let moved_m = (p_m - self.previous_m).abs();
        let friction = self.bristles.follow(effects, form, target, moved_m);
        let cutting = tissue.cutting_n(k.vr_mps, p_m >= self.deepest_m && p_m < far_m);
        let depth_m = p_m - self.protocol.surface_x_m;
        let past_puncture_m = self.deepest_m.max(p_m) - self.punctured_m;
        let cutting = forces::deeper_cutting(effects, form, depth_m, past_puncture_m, cutting)
            * self.protocol.cutting_factor(depth_m);
        self.deepest_m = self.deepest_m.max(p_m);
        if k.vr_mps.abs() >= tissue.half_band_mps {
            self.last_cutting_n = cutting;
            friction + cutting
        } else {
            let held_n = self
                .last_cutting_n
                .min((tissue.dp_n_per_m * l_m - friction).max(0.0));
            friction + cutting + held_n
        }
    }
}

/// A truth event at its own time.
fn event(kind: &'static str, t_s: f64, x_m: f64) -> TruthEvent {
    TruthEvent {
        kind,
        t_s,
        peak_t_s: t_s,
        x_m,
    }
}
