//! `fit`, `detect` and `diagnose` on recordings shaped like a real rig's
//! (book, *What real recordings look like*): insert 25 mm at 1–3 mm/s, hold
//! 5 s, withdraw, with no oscillation; 100 Hz with jittered timing and gaps
//! up to 70 ms; the stage coordinate starting 2–15 mm before the surface; a
//! tare offset; up to two membranes below the capsule; the tissue dragged out
//! on withdrawal, so the pull lasts until 1.5–9 mm before the contact point.
//! Before this, `fit` and `diagnose` refused every such trial and `detect`
//! faulted on every withdrawal.

use std::path::Path;

use crate::diagnose::named_in_turn;
use needle_analysis::detect::{detect_dataset, Detection};
use needle_analysis::diagnose::{diagnose, load, Nominal, UNEXPLAINED};
use needle_analysis::fit::{fit_dataset, to_toml, Estimate, FitReport, RELAXATION_PRIOR};
use needle_analysis::sim::{effects, Dataset, Form, ProtocolKind, Rig, Sensor};
use needle_holder::config::DeviceConfig;
use serde_json::Value;

const SENSOR: Sensor = Sensor {
    rate_hz: 100.0,
    noise_n: 0.012,
    encoder_m: 1e-6,
};

const RIG: Rig = Rig {
    protocol: ProtocolKind::InsertDwellWithdraw,
    layers: 2,
    jitter: true,
    tare_sd_n: 0.004,
    spread: 0.0,
    tear_m: 0.0,
    accel_mps2: 0.0,
};

/// What varies between the tests' datasets; the rest is [`SENSOR`] and
/// [`RIG`]: skin phantom, insert–dwell–withdraw, 100 Hz, jitter, tare.
#[derive(Clone, Copy)]
struct Skin {
    effects: &'static str,
    form: Form,
    layers: u32,
    rate_hz: f64,
    trials: usize,
    seed: u64,
    /// Trial-to-trial spread of the tissue ([`Rig::spread`]).
    spread: f64,
    protocol: ProtocolKind,
    /// The stage's acceleration ([`Rig::accel_mps2`]).
    accel_mps2: f64,
}

/// Ten trials at seed 5 with up to two membranes, standard form.
const SKIN: Skin = Skin {
    effects: "",
    form: Form::Standard,
    layers: 2,
    rate_hz: 100.0,
    trials: 10,
    seed: 5,
    spread: 0.0,
    protocol: ProtocolKind::InsertDwellWithdraw,
    accel_mps2: 0.0,
};

impl Skin {
    /// Write the dataset into `dir`; returns the true parameters.
    fn write(self, dir: &Path) -> needle_holder::model::params::TissueParams {
        let skin = needle_io::tissue::resolve(Some("skin_phantom"), None).unwrap();
        let list = effects::parse_list(self.effects).unwrap();
        Dataset {
            tissue_name: "skin_phantom",
            tissue: &skin.params,
            effects: &list,
            trials: self.trials,
            seed: self.seed,
            sensor: Sensor {
                rate_hz: self.rate_hz,
                ..SENSOR
            },
            through: false,
            form: self.form,
            rig: Rig {
                protocol: self.protocol,
                layers: self.layers,
                spread: self.spread,
                accel_mps2: self.accel_mps2,
                ..RIG
            },
        }
        .write(dir)
        .unwrap();
        skin.params
    }

    /// The diagnosis of the dataset, fitted nominal.
    fn diagnosis(self) -> Value {
        let dir = tempfile::tempdir().unwrap();
        self.write(dir.path());
        let (_, data) = load(dir.path(), None).unwrap();
        serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap()
    }
}

/// Ten skin-phantom trials with `effect_list`; returns the true params.
fn simulate(dir: &Path, effect_list: &'static str) -> needle_holder::model::params::TissueParams {
    Skin {
        effects: effect_list,
        ..SKIN
    }
    .write(dir)
}

fn within(key: &str, estimate: &Estimate, truth: f64, tolerance: f64) {
    let got = estimate
        .value
        .unwrap_or_else(|| panic!("{key}: {estimate:?}"));
    assert!(
        (got - truth).abs() <= tolerance * truth.abs(),
        "{key}: fitted {got}, true {truth}"
    );
}

/// `needle detect --params` with the tissue `needle fit --toml` wrote.
fn detect_with_fitted(dir: &Path, fit: &FitReport) -> Detection {
    let tissue = needle_io::tissue::parse(&to_toml(fit), Path::new("fitted.toml"))
        .unwrap()
        .remove(0);
    let config = DeviceConfig::for_tissue(&tissue.params).unwrap();
    detect_dataset(dir, &config).unwrap()
}

/// Membrane punctures `needle fit` found after the capsule, all layers.
fn membranes_found(fit: &FitReport) -> usize {
    fit.layers.iter().map(|l| l.trials).sum()
}

fn truth_events(dir: &Path, kind: &str) -> usize {
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("truth.json")).unwrap()).unwrap();
    truth["trials"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|t| t["events"].as_array().unwrap())
        .filter(|e| e["kind"] == kind)
        .count()
}

#[test]
fn fit_recovers_what_insert_dwell_withdraw_identifies() {
    let dir = tempfile::tempdir().unwrap();
    let p = simulate(dir.path(), "");
    let fit = fit_dataset(dir.path()).unwrap();
    assert_eq!(fit.trials, 10, "{:?}", fit.skipped);
    within("a1_n_per_m", &fit.a1_n_per_m, p.a1_n_per_m, 0.1);
    within("a2_n_per_m2", &fit.a2_n_per_m2, p.a2_n_per_m2, 0.1);
    within(
        "puncture_depth_m",
        &fit.puncture_depth_m,
        p.puncture_depth_m,
        0.1,
    );
    within(
        "puncture_force_n",
        &fit.puncture_force_n,
        p.stiffness_n(p.puncture_depth_m),
        0.1,
    );
    // Trials at 1, 2 and 3 mm/s: c and b split over the speeds.
    within("cp_n_per_m", &fit.cp_n_per_m, p.cp_n_per_m, 0.1);
    within("bp_ns_per_m2", &fit.bp_ns_per_m2, p.bp_ns_per_m2, 0.1);
    within("cn_n_per_m", &fit.cn_n_per_m, p.cn_n_per_m, 0.1);
    within("bn_ns_per_m2", &fit.bn_ns_per_m2, p.bn_ns_per_m2, 0.1);
    assert!(fit
        .bp_ns_per_m2
        .note
        .as_deref()
        .unwrap()
        .contains("several speeds"));
    // The dragged tissue lets go before the contact point, and a stop into
    // the dwell holds the tip's force with the shaft's: x_s3 is not seen.
    // ρ is held at the stated prior (the simulator's own 0.5 here), and
    // the cutting force is the insertion line's value there.
    assert!(fit.relaxation.value.is_none(), "{:?}", fit.relaxation);
    assert_eq!(fit.relaxation.model_uses, Some(RELAXATION_PRIOR));
    within(
        "cutting_force_n",
        &fit.cutting_force_n,
        p.cutting_force_n,
        0.1,
    );
    // The static band from the dwell: the stop at the cutting front holds
    // D_p·l of the tip's and the shaft's force.
    within("dp_n_per_m", &fit.dp_n_per_m, p.dp_n_per_m, 0.1);
    // And D_n from the withdrawal's stick, which gives way at D_n·l.
    within("dn_n_per_m", &fit.dn_n_per_m, p.dn_n_per_m, 0.1);
    // Where the tissue let go, against the simulator's own drag per trial
    // (drawn within 1.5–9 mm): the fit's estimate is their mean.
    let drag = fit.let_go_before_contact_m.as_ref().unwrap().value.unwrap();
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("truth.json")).unwrap())
            .unwrap();
    let drags: Vec<f64> = truth["trials"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["protocol"]["drag_m"].as_f64().unwrap())
        .collect();
    let true_drag = drags.iter().sum::<f64>() / drags.len() as f64;
    println!("let go {drag} m before contact; true mean {true_drag} m");
    assert!((drag - true_drag).abs() < 0.0005, "{drag} vs {true_drag}");
    // Every membrane's puncture, none from the stops.
    assert_eq!(membranes_found(&fit), truth_events(dir.path(), "structure"));
    // With no viscoelasticity nothing relaxes in the dwell but the noise.
    let fraction = fit
        .dwell_relaxation
        .as_ref()
        .unwrap()
        .fraction
        .value
        .unwrap();
    assert!(fraction.abs() < 0.05, "{fraction}");
}

#[test]
fn fit_reports_one_speed_as_a_combination() {
    let dir = tempfile::tempdir().unwrap();
    // Keep only the trials that ran at 2 mm/s (six of seed 5's ten).
    let p = simulate(dir.path(), "");
    let fit = fit_dataset(dir.path()).unwrap();
    let speeds = fit.insertion_friction.as_ref().unwrap().speed_mps.clone();
    let commonest = 0.002;
    for (k, v) in speeds.iter().enumerate() {
        if (v - commonest).abs() > 2e-4 {
            std::fs::remove_file(dir.path().join(format!("trial_{k:03}.csv"))).unwrap();
        }
    }
    let one = fit_dataset(dir.path()).unwrap();
    let note = one.bp_ns_per_m2.note.as_deref().unwrap();
    assert!(note.contains("not separable"), "{note}");
    // The combination at that speed is right.
    let b = one.bp_ns_per_m2.value.unwrap();
    let truth = p.cp_n_per_m + p.bp_ns_per_m2 * commonest;
    assert!((b * commonest - truth).abs() < 0.1 * truth, "{b}");
}

#[test]
fn detect_with_the_fitted_tissue_raises_no_fault_and_finds_every_membrane() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path(), "viscoelasticity=5");
    let out = detect_with_fitted(dir.path(), &fit_dataset(dir.path()).unwrap());
    for t in &out.trials {
        assert!(t.detection.faults.is_empty(), "{t:?}");
        assert!(t.detection.halt.is_none(), "{t:?}");
        let kinds: Vec<&str> = t.detection.events.iter().map(|e| e.kind).collect();
        assert_eq!(kinds.iter().filter(|k| **k == "puncture").count(), 1);
        assert!(!kinds.contains(&"exit"), "{t:?}");
    }
    let structures = out.kind("structure").unwrap();
    assert_eq!(structures.misses, 0, "{structures:?}");
    assert_eq!(structures.false_alarms, 0, "{structures:?}");
}

#[test]
fn diagnose_runs_on_them_and_never_says_none_over_a_gap() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path(), "viscoelasticity=5");
    let (_, data) = load(dir.path(), None).unwrap();
    assert_eq!(data.len(), 10);
    let out = serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap();
    let v = &out["verdict"];
    assert!(
        v["effect"] != "none" || v["explained"].as_bool().unwrap(),
        "{v}"
    );
    // The membranes first: they are most of the gap.
    assert_eq!(v["effect"], "internal_structures", "{v}");
    assert_eq!(v["effects"][0]["effect"], "internal_structures", "{v}");
}

#[test]
fn a_gap_in_a_recording_is_no_encoder_jump() {
    // 1 kHz at 3 mm/s with 70 ms lost: 210 µm between two rows, more than
    // one period's limit (200 counts) but well within the drive's 100 mm/s.
    let mut trial = needle_io::trial::Trial::default();
    let mut t = 0.0;
    for i in 0..3000 {
        if i == 1500 {
            t += 0.07;
        }
        trial.push(t, 0.003 * t, 0.0);
        t += 0.001;
    }
    let found = needle_analysis::detect::detect_trial(&trial, &DeviceConfig::default());
    assert!(found.faults.is_empty(), "{:?}", found.faults);
}

/// The diagnosis of ten trials with `effect_list` and no membranes.
fn diagnosis_without_layers(effect_list: &'static str) -> Value {
    Skin {
        effects: effect_list,
        layers: 0,
        ..SKIN
    }
    .diagnosis()
}

#[test]
fn with_no_effect_the_nominal_holds_through_dwell_and_dragged_withdrawal() {
    // The stop into the dwell at 100 Hz with a jittered clock is a jump
    // of the velocity, the Karnopp friction holds the insertion's, and the
    // withdrawal lets go where the dragged tissue does.
    let out = diagnosis_without_layers("");
    let noise = out["noise_floor_n"].as_f64().unwrap();
    let base = out["baseline"]["heldout_rms_n"].as_f64().unwrap();
    assert!(base < 1.2 * noise, "{base} vs {noise}");
    assert_eq!(out["verdict"]["effect"], "none");
}

#[test]
fn a_moving_tissue_is_judged_by_the_protocols_phases() {
    // Breathing under a needle held still: in the tissue's frame, where
    // the nominal is fitted once the motion is named, the needle slides
    // back and forth, and its dwell read as `reversal`. What is left is
    // tallied by what the robot did: this protocol has no reversal.
    let out = diagnosis_without_layers("tissue_motion");
    let v = &out["verdict"];
    assert_eq!(v["effect"], "tissue_motion", "{v}");
    let phases = v["left_by_phase"].as_object().unwrap();
    assert!(phases.contains_key("dwell"), "{v}");
    assert!(!phases.contains_key("reversal"), "{v}");
}

/// Each trial's loading curve yielding over the `samples` up to its fall:
/// from where the law stood there, the force flattens and eases by
/// `ease_n` before the capsule falls, with the noise the samples before
/// it had about a straight line.
fn yield_before_the_fall(dir: &Path, samples: usize, ease_n: f64) {
    for k in 0..SKIN.trials {
        let path = dir.join(format!("trial_{k:03}.csv"));
        let mut trial = needle_io::trial::read(&path).unwrap();
        let (x, f) = (&trial.x_m, &trial.f_n);
        // The last sample before the capsule's fall (a newton or more in
        // one sample), at the top of the loading curve.
        let top = (0..f.len()).max_by(|&a, &b| f[a].total_cmp(&f[b])).unwrap();
        let peak = (top..f.len() - 1).find(|&i| f[i] - f[i + 1] > 1.0).unwrap();
        let from = peak - samples;
        let before = from - samples - 1..from;
        let n = before.len() as f64;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
        let (mx, mf) = (mean(&x[before.clone()]), mean(&f[before.clone()]));
        let slope = before
            .clone()
            .map(|i| (x[i] - mx) * (f[i] - mf))
            .sum::<f64>()
            / before.clone().map(|i| (x[i] - mx).powi(2)).sum::<f64>();
        let line = |i: usize| mf + slope * (x[i] - mx);
        let level = line(from);
        let eased: Vec<f64> = (0..=samples)
            .map(|k| {
                let noise = f[before.start + k] - line(before.start + k);
                level - ease_n * k as f64 / samples as f64 + noise
            })
            .collect();
        trial.f_n[from..=peak].copy_from_slice(&eased);
        needle_io::trial::write(&path, &trial).unwrap();
    }
}

#[test]
fn a_capsule_that_yields_before_it_falls_is_the_nominal() {
    // Real tissue's force flattens, then eases for 1-20 samples before it
    // falls (the book, *What real recordings look like*): here over the
    // last 15 samples before the fall, easing by 0.2 N (4 % of the
    // peak), each trial's own capsule. The loading curve's law would keep
    // rising there; each trial's yield is the nominal's, and what the
    // loading leaves is the noise.
    let dir = tempfile::tempdir().unwrap();
    Skin { layers: 0, ..SKIN }.write(dir.path());
    yield_before_the_fall(dir.path(), 15, 0.2);
    let (_, data) = load(dir.path(), None).unwrap();
    let out = serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap();
    let noise = out["noise_floor_n"].as_f64().unwrap();
    let loading = out["baseline"]["by_phase"]["loading"]["rms_n"]
        .as_f64()
        .unwrap();
    assert!(
        loading < 1.3 * noise,
        "loading {loading} N, noise {noise} N"
    );
    assert_eq!(out["verdict"]["effect"], "none", "{}", out["verdict"]);
}

#[test]
fn viscoelasticity_is_named_first_from_the_dwell_and_takes_most_of_the_gap() {
    // Ten times the standard branch (200 N/m, τ 1 s): 0.4 N held at
    // 2 mm/s, relaxing in the dwell (real tissue relaxes 34–41 % of 1–4 N
    // there). At the standard 20 N/m it holds 40 mN, which each trial's
    // own cutting force takes while the needle advances, and what is left
    // in the dwell is within the noise of a real rig (12 mN).
    let out = diagnosis_without_layers("viscoelasticity=10");
    let v = &out["verdict"];
    assert_eq!(v["effect"], "viscoelasticity", "{v}");
    let share = v["effects"][0]["share_of_gap"].as_f64().unwrap();
    assert!(share > 0.6, "{v}");
}

/// Trials driven at 1, 2 and 3 mm/s hold three relaxing forces (k·v·τ):
/// relaxation beside the membranes gains much on the fast trials and
/// little on the slow ones, on every one of them. That is consistent
/// however unlike the gains are; a paired t of them (2.7 here) alone
/// left relaxation unnamed, 22.5 mN on a 12.3 mN floor.
#[test]
fn relaxation_at_three_speeds_is_named_beside_the_membranes() {
    let out = Skin {
        effects: "viscoelasticity=5,internal_structures",
        layers: 0,
        seed: 2,
        spread: 0.15,
        ..SKIN
    }
    .diagnosis();
    assert_named_in_turn_and_explained(&out, &["internal_structures", "viscoelasticity"]);
}

/// Membranes of a newton beside a relaxation of 50 mN in the dwell: the
/// membranes take nearly all of the gap, and relaxation, explaining the
/// dwell, is named after them on what they left.
#[test]
fn relaxation_is_named_after_membranes_many_times_its_size() {
    let out = Skin {
        effects: "viscoelasticity=5",
        layers: 2,
        seed: 1,
        spread: 0.15,
        ..SKIN
    }
    .diagnosis();
    assert_named_in_turn_and_explained(&out, &["internal_structures", "viscoelasticity"]);
}

/// The verdict names `effects` in turn and leaves the gap within the
/// noise floors the issue sets as closed.
fn assert_named_in_turn_and_explained(out: &Value, effects: &[&str]) {
    let v = &out["verdict"];
    assert_eq!(named_in_turn(v), effects, "{v}");
    assert_eq!(v["explained"], true, "{v}");
}

/// After the fall real skin climbs again 1.2–3.3× within 3 mm: the layer
/// beneath the ruptured capsule loads before it cuts, in every
/// insertion by its own amount. The simulator's literature form of
/// depth-dependent cutting has it (40 % of the cutting force at the
/// fall, back within 5 % by 2.4 mm), with a rise as the square root of
/// depth that, at insert–dwell–withdraw's one speed, is a friction per
/// length. On the skin phantom, each trial 10 % its own, the nominal
/// reads each trial's reload (its correction's mean gain near 1) and
/// the gap is closed with nothing to name.
#[test]
fn a_layer_loaded_again_after_the_fall_is_the_nominals() {
    let out = Skin {
        effects: "depth_dependent_cutting",
        form: Form::Literature,
        layers: 0,
        seed: 4,
        spread: 0.1,
        ..SKIN
    }
    .diagnosis();
    let v = &out["verdict"];
    assert_eq!(v["effect"], "none", "{v}");
    let reload = out["baseline"]["corrections"]["reload_n"].as_f64().unwrap();
    assert!((0.5..1.5).contains(&reload), "{}", out["baseline"]);
    let noise = out["noise_floor_n"].as_f64().unwrap();
    let after = v["heldout_rms_after_n"].as_f64().unwrap();
    assert!(after < 1.5 * noise, "{after} vs {noise}: {v}");
}

/// The verdict on ten insert–dwell–withdraw trials (skin phantom, 100 Hz,
/// jitter, tare, no membranes) with one effect in `form`: (named, second,
/// explained, held-out RMS before and after, noise floor).
fn verdict_on(effect: &'static str, form: Form) -> (String, String, bool, f64, f64, f64) {
    let out = Skin {
        effects: effect,
        form,
        layers: 0,
        ..SKIN
    }
    .diagnosis();
    let v = &out["verdict"];
    let num = |v: &Value| v.as_f64().unwrap();
    let text = |v: &Value| v.as_str().unwrap().to_owned();
    (
        text(&v["effect"]),
        text(&v["second"]),
        v["explained"].as_bool().unwrap(),
        num(&out["baseline"]["heldout_rms_n"]),
        num(&v["heldout_rms_after_n"]),
        num(&out["noise_floor_n"]),
    )
}

/// A regression snapshot, not a claim of correctness: what the diagnosis
/// names today for each effect in each form on real rigs' protocol. The
/// standard and alternate columns are the tool's own output, misses
/// included (`None`: `none`), pinned so that a change to them is seen and
/// argued; the literature forms are only printed
/// (`cargo test -p host-tools --test integration real_rig::confusion_snapshot -- --nocapture`).
/// What is claimed, and checked apart, is that the verdict is never
/// `none` over a gap.
#[test]
fn confusion_snapshot_on_insert_dwell_withdraw() {
    // (hidden, named in the standard form, in the alternate form).
    let snapshot: [(&str, &str, &str); 9] = SNAPSHOT;
    eprintln!("| hidden | form | named (second) | before → after (floor) | explained |");
    eprintln!("|---|---|---|---|---|");
    let mut got = Vec::new();
    let mut rule_broken = Vec::new();
    for (effect, ..) in snapshot {
        let mut named_in = Vec::new();
        for form in [Form::Standard, Form::Alternate, Form::Literature] {
            let (named, second, explained, before, after, floor) = verdict_on(effect, form);
            eprintln!(
                "| {effect} | {form:?} | {named} ({second}) | {:.1} → {:.1} mN ({:.1}) | {explained} |",
                before * 1e3,
                after * 1e3,
                floor * 1e3
            );
            // The rule, in every form: the effect itself, unexplained, or
            // none with nothing left to explain.
            if !(named == effect || named == UNEXPLAINED || (named == "none" && explained)) {
                rule_broken.push(format!("{effect} {form:?}: {named}"));
            }
            named_in.push(named);
        }
        got.push((effect, named_in[0].clone(), named_in[1].clone()));
    }
    assert!(rule_broken.is_empty(), "{rule_broken:?}");
    let pinned: Vec<(&str, String, String)> = snapshot
        .iter()
        .map(|(e, s, a)| (*e, s.to_string(), a.to_string()))
        .collect();
    assert_eq!(
        got, pinned,
        "the snapshot moved: argue the change, then pin it"
    );
}

/// What [`confusion_snapshot_on_insert_dwell_withdraw`] pins: (hidden,
/// named in the standard form, in the alternate form), the tool's output
/// with the trials' own stiffness, cutting and friction scale refitted.
const SNAPSHOT: [(&str, &str, &str); 9] = [
    ("none", "none", "none"),
    // The standard branch (τ = 1 s) acts for about a second after each
    // stop: it is sized where it acts, in the dwell it explains.
    ("viscoelasticity", "viscoelasticity", "viscoelasticity"),
    ("rate_dependent_friction", "none", "none"),
    // On this protocol presliding acts where the needle starts back after
    // the dwell, which the withdrawal's stick (a tent of each trial's own
    // stiffness) holds: at standard strength it is `none`, within the
    // noise floor.
    ("presliding_hysteresis", "none", "none"),
    (
        "internal_structures",
        "internal_structures",
        "internal_structures",
    ),
    // The alternate form's cutting wanders along each trial's path about
    // its saturating growth (a heterogeneous tissue): named as cutting
    // along depth in each trial. The standard form's linear growth is
    // within the noise floor on this protocol.
    ("depth_dependent_cutting", "none", "depth_dependent_cutting"),
    ("holder_inertia", "none", "none"),
    ("sensor_drift", "sensor_drift", "sensor_drift"),
    ("tissue_motion", "tissue_motion", "tissue_motion"),
];

#[test]
fn a_puncture_drop_spread_over_samples_is_no_exit() {
    // 100 Hz at 2 mm/s into a skin phantom: loading to 4.8 N, the drop to
    // 1.5 N over three samples (a real rig's skin, the book, *What real recordings look like*), then
    // cutting and a friction slowly growing. Before, the drop's tail read
    // as an exit.
    let skin = needle_io::tissue::resolve(Some("skin_phantom"), None).unwrap();
    let mut trial = needle_io::trial::Trial::default();
    let (rate, speed) = (100.0, 0.002);
    let (contact, puncture) = (0.005, 0.015);
    let mut fell = 0;
    for i in 0..1500 {
        let t = i as f64 / rate;
        let x = speed * t;
        let f = if x < contact {
            0.0
        } else if x < puncture {
            skin.params.stiffness_n(x - contact).min(4.8)
        } else if fell < 3 {
            fell += 1;
            4.8 - 1.1 * fell as f64
        } else {
            1.5 + 30.0 * (x - puncture)
        };
        trial.push(t, x, f);
    }
    let config = DeviceConfig::for_tissue(&skin.params).unwrap();
    let found = needle_analysis::detect::detect_trial(&trial, &config);
    let kinds: Vec<&str> = found.events.iter().map(|e| e.kind).collect();
    assert_eq!(kinds, ["contact", "puncture"], "{:?}", found.events);
    assert!(found.faults.is_empty(), "{:?}", found.faults);
}

#[test]
fn fit_and_detect_hold_from_50_hz_to_2_khz() {
    // The slowest rigs and the device's fastest rate: at 2 kHz a needle at
    // 1 mm/s reads the same 1 µm count for samples on end, and must not
    // look stopped (a membrane's fall was an exit, and the dragged
    // tissue's pull a fault, before).
    for rate_hz in [50.0, 2000.0] {
        let dir = tempfile::tempdir().unwrap();
        Skin {
            effects: "viscoelasticity=3",
            rate_hz,
            trials: 6,
            seed: 9,
            ..SKIN
        }
        .write(dir.path());
        let fit = fit_dataset(dir.path()).unwrap();
        assert_eq!(fit.trials, 6, "{rate_hz} Hz: {:?}", fit.skipped);
        assert_eq!(
            membranes_found(&fit),
            truth_events(dir.path(), "structure"),
            "{rate_hz} Hz"
        );
        let out = detect_with_fitted(dir.path(), &fit);
        for t in &out.trials {
            assert!(t.detection.faults.is_empty(), "{rate_hz} Hz: {t:?}");
        }
        for kind in ["puncture", "structure", "exit"] {
            let k = out.kind(kind).unwrap();
            assert_eq!(k.misses, 0, "{rate_hz} Hz: {k:?}");
            assert_eq!(k.false_alarms, 0, "{rate_hz} Hz: {k:?}");
        }
    }
}

/// The misses and false alarms of `kind` in a detection's evaluation.
fn misses_and_false_alarms(out: &Detection, kind: &str) -> (usize, usize) {
    let k = out.kind(kind).unwrap();
    (k.misses, k.false_alarms)
}

/// The book's workflow on real-rig-like data — membranes, jitter, a
/// dragged withdrawal, each trial's tissue its own, relaxation or another
/// effect — with the tissue `needle fit --toml` writes: every capsule and
/// membrane puncture inside the scorer's window (from the force's peak to
/// two samples after its fall; a report before the peak is a miss and a
/// false alarm), and never worse than the built-in default tissue.
#[test]
fn the_fitted_tissue_finds_every_puncture_in_its_window_and_no_worse_than_the_default() {
    let sweep = [
        ("viscoelasticity=2", 11, 0.15),
        ("", 12, 0.1),
        ("presliding_hysteresis", 13, 0.1),
        ("rate_dependent_friction,sensor_drift", 14, 0.2),
    ];
    for (effects, seed, spread) in sweep {
        let dir = tempfile::tempdir().unwrap();
        Skin {
            effects,
            seed,
            spread,
            ..SKIN
        }
        .write(dir.path());
        let fit = fit_dataset(dir.path()).unwrap();
        // The tissue carries the fall the trials made and the spreads the
        // detector takes its margins from.
        let tissue = fit.tissue().unwrap();
        let truth = needle_io::tissue::resolve(Some("skin_phantom"), None)
            .unwrap()
            .params;
        let fallen_to = tissue.puncture_drop_to_n;
        assert!(
            (fallen_to - truth.puncture_drop_to_n).abs() < 0.2 * truth.puncture_force_n,
            "{effects}: falls to {fallen_to} N"
        );
        for sd in [tissue.puncture_force_sd_n, tissue.puncture_drop_sd_n] {
            assert!(sd.is_some_and(|sd| sd > 0.0), "{effects}: {tissue:?}");
        }
        let fitted = detect_with_fitted(dir.path(), &fit);
        let default = detect_dataset(dir.path(), &DeviceConfig::default()).unwrap();
        for kind in ["puncture", "structure"] {
            let with_fit = misses_and_false_alarms(&fitted, kind);
            assert_eq!(with_fit, (0, 0), "{effects} seed {seed}: {kind}");
            let (m, f) = misses_and_false_alarms(&default, kind);
            assert!(
                with_fit.0 + with_fit.1 <= m + f,
                "{effects} seed {seed}: {kind}"
            );
        }
    }
}

/// The insert–dwell–withdraw case: relaxation (five times the
/// standard branch, which holds and relaxes about a third of a newton
/// through the dwell), the static band holding the tip's force through
/// the dwell, the tissue dragged out as a tent, and each trial's tissue
/// 10 % its own. The waterfall names relaxation first and leaves at most
/// 5 % of the puncture force on the withheld trials, in every form.
#[test]
fn relaxation_over_a_held_dwell_and_a_dragged_tent_is_named_leaving_under_5_percent() {
    for form in [Form::Standard, Form::Alternate, Form::Literature] {
        let dir = tempfile::tempdir().unwrap();
        let p = Skin {
            effects: "viscoelasticity=5",
            form,
            layers: 0,
            seed: 4,
            spread: 0.1,
            ..SKIN
        }
        .write(dir.path());
        let (_, data) = load(dir.path(), None).unwrap();
        let out = serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap();
        let v = &out["verdict"];
        assert_eq!(
            v["effects"][0]["effect"], "viscoelasticity",
            "{form:?}: {v}"
        );
        let left = v["heldout_rms_after_n"].as_f64().unwrap();
        assert!(left <= 0.05 * p.puncture_force_n, "{form:?}: {left} N");
    }
}

/// A wall that tears over 1–3 mm past its peak (`needle simulate
/// --tear-mm 2`: each trial 0.5–1.5 times it) rather than falling at
/// once, as a 3 mm artery's force rolls over and eases off: a stiffer,
/// shallower capsule than the skin's (1.9 N at 5 mm), cutting 0.6 N, 15 %
/// spread. The nominal reads each trial's tear: no effect is `none`, and
/// relaxation beside it is named first, its cutting not read as a
/// profile along depth (before the tear was the nominal's, the first was
/// `depth_dependent_cutting` in both).
#[test]
fn a_wall_that_tears_rather_than_falls_is_the_nominal() {
    let mut artery = needle_io::tissue::resolve(Some("skin_phantom"), None)
        .unwrap()
        .params;
    artery.a1_n_per_m = 100.0;
    artery.a2_n_per_m2 = 56_000.0;
    artery.puncture_depth_m = 0.005;
    artery.puncture_force_n = artery.stiffness_n(0.005);
    artery.puncture_drop_to_n = 0.6;
    artery.cutting_force_n = 0.6;
    for (effect_list, first) in [("", "none"), ("viscoelasticity=5", "viscoelasticity")] {
        let dir = tempfile::tempdir().unwrap();
        let list = effects::parse_list(effect_list).unwrap();
        Dataset {
            tissue_name: "artery",
            tissue: &artery,
            effects: &list,
            trials: 10,
            seed: 1,
            sensor: SENSOR,
            through: false,
            form: Form::Standard,
            rig: Rig {
                layers: 0,
                spread: 0.15,
                tear_m: 0.002,
                ..RIG
            },
        }
        .write(dir.path())
        .unwrap();
        let (_, data) = load(dir.path(), None).unwrap();
        let out = serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap();
        let v = &out["verdict"];
        assert_eq!(v["effect"], first, "{effect_list}: {v}");
        assert!(v["explained"].as_bool().unwrap(), "{effect_list}: {v}");
    }
}

/// A real stage sets off at a finite acceleration: the samples of its
/// ramp move while the lines of rest and of the speed reached cross half
/// a ramp later, and Karnopp's friction turns at 5 µm/s. Taken as at
/// rest, each set-off on the paper's protocol (every stroke starts from
/// rest) is a newton off for a sample or two. And it eases into each
/// stop: the tissue then holds the friction at the band's edge, not at
/// the last sample's speed (0.35 N of the skin's damping after an
/// oscillation easing to rest, at 0.05 m/s²).
#[test]
fn a_stage_that_ramps_its_speed_is_the_nominal() {
    for accel_mps2 in [0.05, 0.1, 0.3] {
        let out = Skin {
            protocol: ProtocolKind::Paper,
            layers: 0,
            spread: 0.15,
            seed: 1,
            accel_mps2,
            ..SKIN
        }
        .diagnosis();
        let noise = out["noise_floor_n"].as_f64().unwrap();
        let base = out["baseline"]["heldout_rms_n"].as_f64().unwrap();
        eprintln!("accel {accel_mps2}: held out {base} noise {noise}");
        assert_eq!(out["verdict"]["effect"], "none", "{accel_mps2}");
        assert!(base < 2.0 * noise, "{accel_mps2}: {base} vs {noise}");
    }
}
