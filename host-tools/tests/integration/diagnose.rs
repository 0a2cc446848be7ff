//! `needle diagnose` on simulated datasets with the effect hidden from it:
//! every effect of the book, *Names* and `none`, two pairs, another physical
//! form of each effect, and the device's own residual stream as input.

use std::path::Path;
use std::process::Command;

use needle_analysis::diagnose::{
    diagnose, heldout_rms_with_displacement, load, Nominal, PhaseWander, TissueShift,
};
use needle_analysis::sim::{effects, Dataset, Form, ProtocolKind, Rig, Sensor};
use needle_holder::model::params::{tissue, TissueParams, LIVER1};
use serde_json::Value;

const SENSOR: Sensor = Sensor {
    rate_hz: 500.0,
    noise_n: 0.005,
    encoder_m: 1e-6,
};

fn simulate(dir: &Path, effect_list: &str, form: Form, seed: u64) {
    simulate_on(dir, (effect_list, form, seed), Rig::default());
}

/// Ten liver trials with `effect_list` in `form` at `seed` on `rig`.
fn simulate_on(dir: &Path, case: (&str, Form, u64), rig: Rig) {
    simulate_with(dir, case, rig, SENSOR);
}

/// [`simulate_on`] with a load cell of its own.
fn simulate_with(
    dir: &Path,
    (effect_list, form, seed): (&str, Form, u64),
    rig: Rig,
    sensor: Sensor,
) {
    let list = effects::parse_list(effect_list).unwrap();
    Dataset {
        tissue_name: "liver1",
        tissue: &LIVER1,
        effects: &list,
        trials: 10,
        seed,
        sensor,
        through: false,
        form,
        rig,
    }
    .write(dir)
    .unwrap();
}

/// [`simulate_with`] as real rigs record (book, *What real recordings look like*):
/// insert–dwell–withdraw at 100 Hz with a 12 mN load cell, clock jitter,
/// each trial's tissue 15 % its own.
fn simulate_as_rigs_record(dir: &Path, case: (&str, Form, u64)) {
    simulate_jittered(dir, case, ProtocolKind::InsertDwellWithdraw, (100.0, 0.012));
}

/// [`simulate_as_rigs_record`]'s dataset, diagnosed.
fn diagnosis_as_rigs_record(case: (&str, Form, u64)) -> Value {
    let dir = tempfile::tempdir().unwrap();
    simulate_as_rigs_record(dir.path(), case);
    diagnosis_of(dir.path())
}

/// [`simulate_with`] on `protocol` with a load cell of `(rate_hz,
/// noise_n)`, clock jitter, each trial's tissue 15 % its own.
fn simulate_jittered(
    dir: &Path,
    case: (&str, Form, u64),
    protocol: ProtocolKind,
    (rate_hz, noise_n): (f64, f64),
) {
    let rig = Rig {
        protocol,
        spread: 0.15,
        jitter: true,
        ..Default::default()
    };
    let sensor = Sensor {
        rate_hz,
        noise_n,
        ..SENSOR
    };
    simulate_with(dir, case, rig, sensor);
}

fn diagnosis(effect_list: &str, form: Form, seed: u64) -> Value {
    diagnosis_on((effect_list, form, seed), Rig::default())
}

/// [`simulate_on`]'s dataset, diagnosed.
fn diagnosis_on(case: (&str, Form, u64), rig: Rig) -> Value {
    let dir = tempfile::tempdir().unwrap();
    simulate_on(dir.path(), case, rig);
    diagnosis_of(dir.path())
}

fn diagnosis_of(dir: &Path) -> Value {
    let (_, data) = load(dir, None).unwrap();
    serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap()
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// The effects a verdict's waterfall names, in turn.
pub(crate) fn named_in_turn(verdict: &Value) -> Vec<&str> {
    verdict["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["effect"].as_str().unwrap())
        .collect()
}

/// [`simulate_jittered`]'s dataset on the paper's protocol with a 3 mN
/// load cell at 250 Hz, diagnosed.
fn diagnosis_on_the_papers_rig(case: (&str, Form, u64)) -> Value {
    let dir = tempfile::tempdir().unwrap();
    simulate_jittered(dir.path(), case, ProtocolKind::Paper, (250.0, 0.003));
    diagnosis_of(dir.path())
}

/// Trials whose friction differs in shape, not only in scale (five of
/// the journal's liver 1, which has a Coulomb friction, five with its
/// viscous friction 50 % up each way and its Coulomb friction as it
/// was), and no effect: each trial's own viscous friction takes it, the
/// nominal is left at the noise (5.0 mN on 5.0) and the verdict is
/// `none`. With each trial's friction the shared shape scaled it kept
/// 7.3 mN.
#[test]
fn friction_of_other_shapes_is_spread_not_an_effect() {
    let journal = tissue("liver1_journal").unwrap();
    let more_viscous = TissueParams {
        bp_ns_per_m2: journal.bp_ns_per_m2 * 1.5,
        bn_ns_per_m2: journal.bn_ns_per_m2 * 1.5,
        ..journal
    };
    let dir = tempfile::tempdir().unwrap();
    two_tissues(dir.path(), [&journal, &more_viscous], Rig::default());
    let out = diagnosis_of(dir.path());
    let (before, _) = heldout_before_after(&out);
    let noise = num(&out["noise_floor_n"]);
    println!("{:.1} mN on {:.1}", before * 1e3, noise * 1e3);
    assert!(before < 1.2 * noise, "{before} on {noise}");
    assert_eq!(out["verdict"]["effect"], "none", "{}", out["verdict"]);
}

/// Five trials of each of `tissues` in `dir` (`trial_{k}{j}.csv`), no
/// effect, on `rig`.
fn two_tissues(dir: &Path, tissues: [&TissueParams; 2], rig: Rig) {
    for (k, tissue) in tissues.into_iter().enumerate() {
        let part = tempfile::tempdir().unwrap();
        Dataset {
            tissue_name: "liver1",
            tissue,
            effects: &[],
            trials: 5,
            seed: 40 + k as u64,
            sensor: SENSOR,
            through: false,
            form: Form::Standard,
            rig,
        }
        .write(part.path())
        .unwrap();
        for j in 0..5 {
            let from = part.path().join(format!("trial_{j:03}.csv"));
            std::fs::copy(from, dir.join(format!("trial_{k}{j}.csv"))).unwrap();
        }
    }
}

/// Trials whose capsules differ in shape, not only in scale (five of
/// liver 1, five with its a1 30 % up and its a2 30 % down, as one tissue
/// differs from the next), and no effect: each trial's own loading slope
/// takes the shape, the loading is left at the noise and the verdict is
/// `none`. With a shared shape and each trial's scale alone the loading
/// kept 21.6 mN on a 5.0 mN floor.
#[test]
fn capsules_of_other_shapes_are_spread_not_an_effect() {
    let dir = tempfile::tempdir().unwrap();
    let other = TissueParams {
        a1_n_per_m: LIVER1.a1_n_per_m * 1.3,
        a2_n_per_m2: LIVER1.a2_n_per_m2 * 0.7,
        ..LIVER1
    };
    two_tissues(dir.path(), [&LIVER1, &other], Rig::default());
    let out = diagnosis_of(dir.path());
    let noise = num(&out["noise_floor_n"]);
    let loading = num(&out["baseline"]["by_phase"]["loading"]["rms_n"]);
    println!("loading {:.1} mN on {:.1}", loading * 1e3, noise * 1e3);
    assert!(loading < 1.2 * noise, "{loading} on {noise}");
    assert_eq!(out["verdict"]["effect"], "none", "{}", out["verdict"]);
}

/// A tip that lets its cutting force go over a tenth of a millimetre as
/// it is first drawn back (the tissue ahead of it was compressed), on the
/// paper's protocol with no effect: it is the nominal's tip, each trial's
/// own, not an effect, and the verdict is `none` (3.2 mN held out on a
/// 3.2 mN noise floor). With the nominal's tip dropping its force at once
/// 16.1 mN were held out and the verdict was `unexplained`.
#[test]
fn a_tip_that_lets_go_over_its_compliance_is_the_nominal() {
    let out = edited_no_effect_on_the_papers_rig(|_, rows| {
        compliant_tip(rows, LIVER1.cutting_force_n, 0.1e-3);
    });
    assert_eq!(out["verdict"]["effect"], "none", "{}", out["verdict"]);
}

/// A misfit no effect is and the nominal cannot take, a few noise floors
/// but under a hundredth of the puncture force (a slow wander of the
/// load cell's reading, 9 mN RMS, its phase each trial's own), on the
/// paper's protocol with no effect: within the nominal's tolerance, the
/// verdict is `none` (`unexplained` on the noise floor alone).
#[test]
fn a_misfit_within_the_nominals_tolerance_is_none() {
    let out = edited_no_effect_on_the_papers_rig(|trial, rows| {
        for row in rows {
            let wander_n: f64 = [0.5, 1.3, 2.9]
                .iter()
                .enumerate()
                .map(|(j, hz)| {
                    let phase = 1.7 * trial as f64 + 2.3 * j as f64;
                    0.0073 * (std::f64::consts::TAU * hz * row[0] + phase).sin()
                })
                .sum();
            row[2] += wander_n;
        }
    });
    let after = num(&out["verdict"]["heldout_rms_after_n"]);
    let noise = num(&out["noise_floor_n"]);
    assert!(after > 1.5 * noise, "{after} on {noise}");
    assert_eq!(out["verdict"]["effect"], "none", "{}", out["verdict"]);
    assert_eq!(out["verdict"]["explained"], true, "{}", out["verdict"]);
}

/// Ten trials of the paper's protocol on its rig (250 Hz, 3 mN, each
/// trial 15 % its own, seed 3), no effect, each trial's rows edited by
/// `edit` (given the trial's number), diagnosed.
fn edited_no_effect_on_the_papers_rig(edit: impl FnMut(usize, &mut [[f64; 3]])) -> Value {
    edited_no_effect(ProtocolKind::Paper, (250.0, 0.003), edit)
}

/// [`edited_no_effect_on_the_papers_rig`] on `protocol` at (rate, noise sd).
fn edited_no_effect(
    protocol: ProtocolKind,
    rig: (f64, f64),
    mut edit: impl FnMut(usize, &mut [[f64; 3]]),
) -> Value {
    let dir = tempfile::tempdir().unwrap();
    simulate_jittered(dir.path(), ("", Form::Standard, 3), protocol, rig);
    let mut trials: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .collect();
    trials.sort();
    for (k, path) in trials.iter().enumerate() {
        rewrite_trial(path, |rows| edit(k, rows));
    }
    let out = diagnosis_of(dir.path());
    println!(
        "{:.1} -> {:.1} mN on {:.1}, explained below {:.1}: {}",
        num(&out["baseline"]["heldout_rms_n"]) * 1e3,
        num(&out["verdict"]["heldout_rms_after_n"]) * 1e3,
        num(&out["noise_floor_n"]) * 1e3,
        num(&out["explained_below_n"]) * 1e3,
        out["verdict"]
    );
    out
}

/// A load cell whose zero drifts each recording its own way, 80–125 mN
/// over the trial, the sign alternating from one trial to the next (a
/// bridge's drift turns on how long it had been powered and what warmed
/// it): on insert–dwell–withdraw, where the needle comes out and the load
/// cell reads its zero again, the drift is named, read from each trial's
/// samples out of tissue. One rate for every trial would average the
/// trials' drifts away.
#[test]
fn a_drift_of_each_recordings_own_is_named() {
    let idw = (ProtocolKind::InsertDwellWithdraw, (100.0, 0.012));
    let out = edited_no_effect(idw.0, idw.1, |trial, rows| {
        let sign = if trial % 2 == 0 { 1.0 } else { -1.0 };
        let drift_n = sign * (0.080 + 0.005 * trial as f64);
        let (t0_s, t1_s) = (rows[0][0], rows[rows.len() - 1][0]);
        for row in rows {
            row[2] += drift_n * (row[0] - t0_s) / (t1_s - t0_s);
        }
    });
    assert_eq!(
        out["verdict"]["effect"], "sensor_drift",
        "{}",
        out["verdict"]
    );
}

/// Rewrites a trial's rows (`t_s`, `x_m`, `f_n`) with `edit`.
fn rewrite_trial(path: &Path, edit: impl FnOnce(&mut [[f64; 3]])) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let mut rows: Vec<[f64; 3]> = lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect();
    edit(&mut rows);
    let mut out = format!("{header}\n");
    for r in &rows {
        out += &format!("{},{},{}\n", r[0], r[1], r[2]);
    }
    std::fs::write(path, out).unwrap();
}

/// A trial's rows with its force as if its tip let `load_n` go linearly
/// over `compliance_m` of its first retraction from the deepest point,
/// rather than at once (the simulator's tip drops it at once).
fn compliant_tip(rows: &mut [[f64; 3]], load_n: f64, compliance_m: f64) {
    // The first stop at the deepest point: the oscillation after it
    // comes back to within an encoder step of it.
    let deepest_m = rows.iter().map(|r| r[1]).fold(f64::MIN, f64::max);
    let front_at = rows.iter().position(|r| r[1] >= deepest_m - 2e-6).unwrap();
    let front_m = rows[front_at][1];
    for i in front_at..rows.len() {
        let back_m = front_m - rows[i][1];
        if back_m >= compliance_m {
            break;
        }
        // The sample before the encoder's first step back can have the
        // stage, and the simulator's force, already on its way.
        let set_off = rows.get(i + 1).is_some_and(|next| next[1] < rows[i][1])
            && rows[i][2] < rows[i - 1][2] - 0.5 * load_n;
        if back_m > 0.0 || set_off {
            rows[i][2] += load_n * (1.0 - back_m / compliance_m);
        }
    }
}

/// The diagnosis's own scores of `effect`'s candidate.
fn candidate<'a>(out: &'a Value, effect: &str) -> &'a Value {
    out["candidates"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["effect"] == effect)
        .unwrap()
}

/// Held-out RMS of the baseline and after the verdict's effects, N.
fn heldout_before_after(out: &Value) -> (f64, f64) {
    (
        num(&out["baseline"]["heldout_rms_n"]),
        num(&out["verdict"]["heldout_rms_after_n"]),
    )
}

/// The verdict names `effect` (or `none`) first in its waterfall, and a
/// named effect's held-out shrink is real: the RMS after it is well below
/// the RMS before; it is also among the three candidates of most shrink
/// on its own, whose backfits decide the first effect.
fn assert_named(out: &Value, effect: &str, least_shrink: f64) {
    let v = &out["verdict"];
    assert_eq!(v["effect"], effect, "{effect}: {v}");
    if effect != "none" {
        assert_eq!(v["effects"][0]["effect"], effect, "{effect}: {v}");
        assert!(num(&v["shrink"]) >= least_shrink, "{effect}: {v}");
        assert_eq!(v["effects"][0]["law"], "shared", "{effect}: {v}");
        let leading: Vec<&Value> = out["candidates"]
            .as_array()
            .unwrap()
            .iter()
            .take(3)
            .map(|c| &c["effect"])
            .collect();
        assert!(
            leading.iter().any(|e| *e == effect),
            "{effect}: {leading:?}"
        );
    } else {
        assert_eq!(v["effects"], serde_json::json!([]), "{v}");
    }
}

/// A rate dependence of standard strength may be `none` when it leaves
/// the nominal within 1.5 noise floors: a power law (or a logarithm) over
/// the paper's strokes is nearly the nominal's c + b·v with each trial's
/// own friction scale, once the first dwell holds D_p·l whatever the
/// speed. Below the bar an effect must clear, `none` is the rule's answer
/// (book, "Targets not met").
fn below_the_bar(out: &Value, effect: &str) -> bool {
    if effect != "rate_dependent_friction" || out["verdict"]["effect"] != "none" {
        return false;
    }
    let before = num(&out["baseline"]["heldout_rms_n"]);
    assert!(before <= 1.5 * num(&out["noise_floor_n"]), "{out}");
    true
}

#[test]
fn each_effect_and_none_is_named_with_a_real_shrink() {
    // (effect, least shrink, most gap left after it in noise floors: the
    // target is 1.5)
    let cases = [
        ("none", 0.0, 1.5),
        ("viscoelasticity", 0.5, 1.5),
        ("rate_dependent_friction", 0.1, 1.5),
        ("presliding_hysteresis", 0.7, 1.5),
        ("internal_structures", 0.6, 1.5),
        ("depth_dependent_cutting", 0.6, 1.5),
        ("holder_inertia", 0.45, 1.5),
        ("sensor_drift", 0.7, 1.5),
        // The nominal refitted in the tissue's frame leaves 2.5 noise
        // floors (book, "Targets not met"): whether the needle cuts turns
        // on where it is in the moving tissue to a micrometre, which the
        // fitted displacement is not; the cutting state is followed from
        // the force one sample behind, and each switch still costs about
        // a sample of the whole cutting force.
        ("tissue_motion", 0.9, 3.0),
    ];
    for (effect, shrink, most) in cases {
        let out = diagnosis(effect, Form::Standard, 7);
        if below_the_bar(&out, effect) {
            continue;
        }
        assert_named(&out, effect, shrink);
        let after = num(&out["verdict"]["heldout_rms_after_n"]);
        let noise = num(&out["noise_floor_n"]);
        assert!(
            after <= most * noise,
            "{effect}: {after} N left, noise {noise} N"
        );
    }
}

#[test]
fn tissue_motions_fitted_displacement_does_nearly_as_well_as_the_true_one() {
    // What tissue motion leaves (book, "Targets") is the cutting state's
    // switches, which the model places only to the encoder's resolution
    // and the needle's velocity, not the fitted displacement's error: the
    // true displacement leaves nearly as much.
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path(), "tissue_motion", Form::Standard, 7);
    let (_, data) = load(dir.path(), None).unwrap();
    let out = serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap();
    let fitted = num(&out["verdict"]["heldout_rms_after_n"]);
    let [effects::Effect::TissueMotion {
        amplitude_m,
        freq_hz,
    }] = effects::parse_list("tissue_motion").unwrap()[..]
    else {
        panic!("tissue_motion is one effect");
    };
    // The simulator moves the tissue by A·sin(2π f t).
    let truth = TissueShift {
        omega_rad_s: std::f64::consts::TAU * freq_hz,
        t_ref_s: 0.0,
        coeffs_m: [amplitude_m, 0.0, 0.0, 0.0],
        wander: PhaseWander::NONE,
    };
    let known = heldout_rms_with_displacement(&data, &vec![truth; data.len()]).unwrap();
    let noise = num(&out["noise_floor_n"]);
    eprintln!(
        "tissue_motion, seed 7: held-out RMS {:.1} mN with the fitted displacement, \
         {:.1} mN with the true one, noise floor {:.1} mN",
        fitted * 1e3,
        known * 1e3,
        noise * 1e3
    );
    assert!(fitted <= 1.25 * known, "fitted {fitted} N, true {known} N");
}

#[test]
fn with_no_effect_the_gap_left_is_near_the_noise_floor() {
    let out = diagnosis("", Form::Standard, 7);
    let base = num(&out["baseline"]["heldout_rms_n"]);
    let noise = num(&out["noise_floor_n"]);
    assert!(base < 1.5 * noise, "{base} vs noise {noise}");
    assert!((noise - 0.005).abs() < 0.0005, "noise floor {noise}");
}

#[test]
fn both_effects_of_a_pair_are_named() {
    // (pair, seed, most gap left after both in noise floors.) At seed 3
    // sensor_drift shrinks most beside viscoelasticity, but not
    // significantly (t = 3.0 under its residual); viscoelasticity is
    // significant, and drift on top of it. The relaxation time it is named
    // with there is off, and 3.2 noise floors are left (book, *Sim-to-real gap diagnosis*).
    for (pair, seed, most) in [
        (["sensor_drift", "internal_structures"], 7, 1.5),
        (["holder_inertia", "depth_dependent_cutting"], 7, 1.5),
        (["viscoelasticity", "sensor_drift"], 3, 3.5),
    ] {
        let out = diagnosis(&pair.join(","), Form::Standard, seed);
        let v = &out["verdict"];
        let mut named = [v["effect"].as_str().unwrap(), v["second"].as_str().unwrap()];
        named.sort();
        let mut want = pair;
        want.sort();
        assert_eq!(named, want, "{v}");
        let (after, noise) = (num(&v["heldout_rms_after_n"]), num(&out["noise_floor_n"]));
        assert!(
            after <= most * noise,
            "{pair:?}: {after} N left, noise {noise} N"
        );
        // The waterfall: both, in the verdict's order, each leaving less
        // than the step before, their shares of the gap within 0..=1.
        let steps = v["effects"].as_array().unwrap();
        assert_eq!(steps.len(), 2, "{v}");
        assert_eq!(steps[0]["effect"], v["effect"]);
        assert_eq!(steps[1]["effect"], v["second"]);
        let base = num(&out["baseline"]["heldout_rms_n"]);
        let rms: Vec<f64> = steps
            .iter()
            .map(|s| num(&s["heldout_rms_after_n"]))
            .collect();
        assert!(base > rms[0] && rms[0] > rms[1], "{base} {rms:?}");
        let shares: f64 = steps.iter().map(|s| num(&s["share_of_gap"])).sum();
        assert!(shares > 0.0 && shares <= 1.0 + 1e-9, "{shares}");
    }
}

/// The paper's protocol and nominal physics, each trial's tissue its own
/// (stiffness, cutting and friction 20 % apart, puncture depth 10 %):
/// spread is not missing physics, so the verdict is `none` and what is
/// left is within 1.5 noise floors: the trials' own stiffness, cutting,
/// friction and first-dwell level take the spread (`diagnose::SPREAD`).
#[test]
fn trial_to_trial_spread_alone_is_none_within_1_5_noise_floors() {
    // Seed 2 draws trials far apart in friction (the static band was set
    // by the most holding trial) and one soft capsule with a hard cut.
    for seed in [21, 2] {
        spread_alone_is_none("liver1", seed, 0.0);
    }
}

/// With the journal's friction (C_p 10.57, C_n −11.96 N/m) friction at
/// rest is far from zero, so where each trial's punctured surface rests
/// (its own relaxation ρ) shows at every stroke and in every rest at the
/// static band: each trial's own x_s3 (random effects) and band level.
#[test]
fn spread_alone_with_friction_at_rest_is_none_too() {
    for seed in [2, 3] {
        spread_alone_is_none("liver1_journal", seed, 0.0);
    }
}

/// The paper's protocol read at 100 Hz on a clock jittered by a tenth of
/// its period, samples lost now and then: its strokes (±4 mm at 1.1 Hz)
/// bend within a velocity window, a stroke set off at speed lands
/// further from where straight lines either side put it than an encoder
/// step says, and a gap of lost samples makes a window lopsided. None of
/// that is an effect: spread alone is still `none`.
#[test]
fn spread_alone_read_at_100_hz_on_a_jittered_clock_is_none_too() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::Paper, (100.0, 0.002), 0.0);
    for seed in [2, 6] {
        spread_alone_is_none_on("liver1", seed, sensor, rig);
    }
}

/// With the journal's friction on insert–dwell–withdraw at a real rig's
/// 100 Hz and 12 mN, the tissue dragged out lets go onto a kinetic
/// friction nearly as deep as its pull (0.3 N): a snap of 8–9 noise sd
/// on single samples, which the withdrawal's stick must still find, or
/// the tent's ramp is left to the friction line.
#[test]
fn spread_alone_with_friction_at_rest_withdrawn_at_a_rigs_rate_is_none() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::InsertDwellWithdraw, (100.0, 0.012), 0.0);
    spread_alone_is_none_on("liver1_journal", 1, sensor, rig);
}

/// The skin phantom read at 1 kHz by a 3 mN load cell: its damping (4–17
/// times liver's) turns the velocity's reading error, an encoder step
/// over a 20 ms window, into 5 mN of the friction law's force, more than
/// the load cell's noise. A trial whose strokes the right law fits to
/// that places its own ρ (the tissue's lies 1.3 mm off one trial's
/// relaxed surface, and leaves 15–40 mN along its strokes).
#[test]
fn spread_alone_on_skin_read_at_1_khz_is_none() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::Paper, (1000.0, 0.003), 0.003);
    spread_alone_is_none_on("skin_phantom", 3, sensor, rig);
}

/// The skin phantom at 250 Hz: a stroke stopping at 20 mm/s 44 µs after
/// a sample (±48 µs) at which the encoder already reads the rest (within
/// half a step: 24 µs of travel). The rest starts there by the encoder;
/// the sample's alternative is the velocity before the stop, and the
/// force (still cutting, a newton above the rest's) settles it.
#[test]
fn spread_alone_on_skin_stopping_at_speed_is_none() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::Paper, (250.0, 0.003), 0.003);
    spread_alone_is_none_on("skin_phantom", 3, sensor, rig);
}

/// Liver by eq. 3 on insert–dwell–withdraw at 100 Hz with a 3 mN load
/// cell: a stop the force puts on the sliding side (the encoder read the
/// rest a sample before the stop the lines place) holds the first
/// dwell's level only as likely as it is at rest, so the trial's own
/// dwell — twice the nominal's — does not scale it into a newton.
#[test]
fn spread_alone_on_a_stop_the_force_puts_before_the_dwell_is_none() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::InsertDwellWithdraw, (100.0, 0.003), 0.003);
    spread_alone_is_none_on("liver1_rational", 3, sensor, rig);
}

/// Liver by eq. 3's rational law, punctured from 1 to 6 N as its puncture
/// spreads (its pole 9 mm past the mean puncture): the law is the tissue's
/// and is fitted on every trial, and the laws' mean is the law at the
/// mean depth, though the puncture forces' mean is not.
#[test]
fn spread_alone_on_a_law_punctured_near_its_pole_is_none() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::Paper, (250.0, 0.012), 0.003);
    spread_alone_is_none_on("liver1_rational", 3, sensor, rig);
}

/// Liver 2 on the paper's protocol at 100 Hz with a 12 mN load cell, one
/// trial's capsule giving way at 0.22 N onto nearly as much cutting: its
/// puncture is that capsule's, not a stroke inside the cut track that
/// eases below 60 % of its own peak as it slows towards its turn (read
/// so, its contact and tare came with it, and the dataset was
/// `unexplained` at 33 mN on 12).
#[test]
fn spread_alone_on_a_capsule_giving_way_onto_its_cutting_is_none() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::Paper, (100.0, 0.012), 0.003);
    spread_alone_is_none_on("liver2", 5, sensor, rig);
}

/// Liver 2 cutting as hard as liver 1 on insert–dwell–withdraw (harder
/// than its capsule holds, so one trial in ten reads a puncture and the
/// rest do not):
/// a fold without that trial has no cutting and no friction ahead to fit,
/// and the held-out figures must still be the force's, not a rounding
/// error's (1.3e15 N were reported).
#[test]
fn a_correction_only_one_trial_has_is_not_fitted_to_rounding() {
    let (sensor, rig) = a_rigs_spread(ProtocolKind::InsertDwellWithdraw, (250.0, 0.012), 0.003);
    let liver2 = TissueParams {
        cutting_force_n: 0.94,
        ..tissue("liver2").unwrap()
    };
    let out = no_effect_diagnosis_of(("liver2", &liver2), 3, sensor, rig);
    let baseline_n = num(&out["baseline"]["heldout_rms_n"]);
    assert!(baseline_n < 1.0, "{}", out["baseline"]);
    for c in out["candidates"].as_array().unwrap() {
        assert!(num(&c["heldout_rms_n"]) < 1.0, "{c}");
    }
}

/// Each trial's load cell zeroed mN off (10 mN sd on 5 mN of
/// noise), as real rigs leave it: an offset through the whole trial is
/// the trial's own, like its tissue, not an effect; each trial is tared
/// on its own approach.
#[test]
fn a_tare_left_on_each_trial_is_no_effect() {
    let out = spread_alone_is_none("liver1", 21, 0.01);
    // What was taken off is reported, trial by trial.
    let tares = out["tare_n"].as_object().unwrap();
    assert_eq!(tares.len(), 10, "{tares:?}");
    assert!(tares.values().any(|t| num(t).abs() > 0.003), "{tares:?}");
}

/// Liver withdrawn at 1–3 mm/s pulls a few mN by kinetic friction (its
/// b_n·v·l), within a few noise sd of a 5 mN load cell, after the tent of
/// tissue dragged from the dwell slips by hundreds of mN. The slip is
/// found from what the friction after it pulls on average: the tent is no
/// friction, the withdrawal's damping b_n comes out within 5 %, and the
/// verdict is `none` (before, the tent was read as kinetic friction on
/// every load cell noisier than 2 mN: b_n negative, `unexplained`).
#[test]
fn a_slip_onto_friction_within_the_noise_is_still_a_slip() {
    for seed in [5, 1] {
        let dir = tempfile::tempdir().unwrap();
        let rig = Rig {
            protocol: ProtocolKind::InsertDwellWithdraw,
            ..Default::default()
        };
        simulate_on(dir.path(), ("", Form::Standard, seed), rig);
        assert_fitted_bn_within(dir.path(), 0.05, &format!("seed {seed}"));
        assert_named(&diagnosis_of(dir.path()), "none", 0.0);
    }
}

/// `needle fit`'s withdrawal damping b_n on the liver trials in `dir` is
/// liver 1's within `tolerance` (relative); `case` names it on failure.
fn assert_fitted_bn_within(dir: &Path, tolerance: f64, case: &str) {
    let fit = needle_analysis::fit::fit_dataset(dir).unwrap();
    let bn = fit.bn_ns_per_m2.value.unwrap();
    let truth = LIVER1.bn_ns_per_m2;
    assert!(
        (bn / truth - 1.0).abs() <= tolerance,
        "{case}: b_n {bn} against {truth}"
    );
}

/// Liver with Dahl's presliding (his exponent 2) on insert–dwell–withdraw
/// at 100 Hz: after the dwell the withdrawing needle drags the tissue
/// for up to 2 mm, then slips onto liver's kinetic friction — at 1 mm/s a
/// noise sd or so, which reads as a let-go onto zero. The slip comes
/// 15–25 mm deep, far past where the capsule gave way, where the tissue
/// cannot have let go. Read as a let-go, three trials put the tent's pull
/// into the withdrawal's friction line (b_n 5 131 N·s/m² against 458;
/// the dataset `unexplained`, 54.2 mN held out on 12.0).
#[test]
fn a_snap_deep_in_the_tissue_is_a_slip_not_a_let_go() {
    let dir = tempfile::tempdir().unwrap();
    simulate_as_rigs_record(dir.path(), ("presliding_hysteresis", Form::Literature, 2));
    assert_fitted_bn_within(dir.path(), 0.15, "Dahl, literature form");
    let out = diagnosis_of(dir.path());
    let left = num(&out["verdict"]["heldout_rms_after_n"]);
    assert!(
        left <= 1.1 * num(&out["noise_floor_n"]),
        "{}",
        out["verdict"]
    );
}

/// Fung's QLV over every tissue force (a box spectrum of five branches
/// over 0.05–20 s, five times the standard size) on
/// insert–dwell–withdraw: its slowest branches still hold part of the
/// insertion's force when the withdrawal's tent slips, so the slip lands
/// away from the free needle's level. It must still be read as a slip,
/// or the tent's pull goes into the withdrawal's friction and hides the
/// relaxation.
#[test]
fn a_slip_onto_a_slow_relaxations_hold_is_a_slip() {
    let out = diagnosis_as_rigs_record(("viscoelasticity=5", Form::Literature, 1));
    let v = &out["verdict"];
    assert_eq!(v["effect"], "viscoelasticity", "{v}");
    let left = num(&v["heldout_rms_after_n"]);
    assert!(left <= 1.1 * num(&out["noise_floor_n"]), "{v}");
}

/// Breathing that outruns a 1 mm/s needle (1.5 mm at 0.25 Hz, up to 2.4
/// mm/s) on insert–dwell–withdraw at 100 Hz, each trial 15 % its own:
/// the loading curve sags as the tissue draws away, which `needle fit`
/// takes for a wall rolling over (4 of 10 trials punctured seconds early
/// at seed 1, the cutting force fitted as none). The tissue's motion is looked for
/// with the puncture at the sudden fall, each trial's cutting and
/// friction its own, and the breathing frequency chosen by the model
/// among the periodogram's peaks and their halves; a period that wanders
/// from breath to breath, with the phase free at knots a breath apart
/// and the loading curve's own record of where the breath was.
#[test]
fn breathing_that_outruns_the_needle_is_named() {
    // The literature form's period wanders by ±20 % over 30 s: a
    // steady phase strays by 1.5 rad over a trial, and the wander's fit
    // leaves 4.2–7.7 noise floors over seeds 1–6 (4.5 at this one; 5.0
    // since `needle fit` reads no friction within 0.4 mm of the cutting
    // front, where in the tissue's frame a breathing tissue brings the
    // tip back every breath).
    for (form, most_floors) in [
        (Form::Standard, 2.0),
        (Form::Alternate, 2.0),
        (Form::Literature, 5.5),
    ] {
        let out = diagnosis_as_rigs_record(("tissue_motion", form, 1));
        let v = &out["verdict"];
        assert_eq!(v["effect"], "tissue_motion", "{form:?}: {v}");
        let (left, floor) = (
            num(&v["effects"][0]["heldout_rms_after_n"]),
            num(&out["noise_floor_n"]),
        );
        eprintln!(
            "breathing, {form:?}: {:.1} mN left by tissue_motion, floor {:.1} mN",
            left * 1e3,
            floor * 1e3
        );
        assert!(left <= most_floors * floor, "{form:?}: {v}");
    }
}

/// Breathing whose period wanders by ±20 % over 30 s on the paper's
/// protocol (250 Hz, 3 mN, each trial 15 % its own, seed 2): a phase
/// for the whole trial leaves the candidate that ranks the effects under
/// every other one, and the gap was `unexplained` (115 → 100 mN). With
/// the phase chosen per window of two breaths the candidate ranks, and
/// the wander fitted after it takes most of the gap.
#[test]
fn breathing_whose_period_wanders_is_ranked_with_a_phase_per_window() {
    let out = diagnosis_on_the_papers_rig(("tissue_motion", Form::Literature, 2));
    let v = &out["verdict"];
    assert_eq!(v["effect"], "tissue_motion", "{v}");
    let (before, after) = heldout_before_after(&out);
    assert!(after <= 0.3 * before, "{before} → {after} N");
}

/// Relaxation on the paper's protocol (250 Hz, 3 mN, each trial 15 % its
/// own, seed 2): a relaxing branch holds a steady force through the final
/// withdrawal and lets go of it where the needle leaves the tissue, a
/// snap to the free level that need not be where the nominal's relaxed
/// surface lies (the protocol places that surface only by a friction
/// that fades to nothing). The branch must end at the snap for the gap
/// to close in every form: within two noise floors, or to a fifth of
/// the nominal's misfit where each trial relaxes by a share of its own
/// (the simulator varies relaxation's size from trial to trial, and one
/// gain leaves each trial's departure from it: the alternate form,
/// 41.7 → 7.7 mN on 3.2). Before the branch ended at the snap, that form
/// was `unexplained` with most of its misfit left. A better nominal
/// leaves the same relaxation a larger share of a smaller gap: with each
/// trial's tip returns among its corrections the alternate form is
/// 38.1 → 7.8 mN, a ratio of 0.205 (0.197 at 41.6 → 8.2 before), hence
/// 0.22.
#[test]
fn a_relaxing_branch_ends_where_the_needle_came_free() {
    for form in [Form::Standard, Form::Alternate, Form::Literature] {
        let out = diagnosis_on_the_papers_rig(("viscoelasticity", form, 2));
        let v = &out["verdict"];
        assert_eq!(v["effect"], "viscoelasticity", "{form:?}: {v}");
        let (before, after) = heldout_before_after(&out);
        let closed = after <= 2.0 * num(&out["noise_floor_n"]) || after <= 0.22 * before;
        assert!(closed, "{form:?}: {v}");
    }
}

/// Stribeck friction on the paper's protocol (250 Hz, 3 mN, each trial
/// 15 % its own): friction raised at low speed, gone by a few v_s, so
/// it shows where the sinusoidal strokes turn. A power law in speed
/// takes about half of it; Stribeck's own law most.
#[test]
fn stribecks_raise_at_low_speed_is_taken_by_its_own_law() {
    for seed in [1, 2] {
        let out = diagnosis_on_the_papers_rig(("rate_dependent_friction", Form::Literature, seed));
        let v = &out["verdict"];
        assert_eq!(v["effect"], "rate_dependent_friction", "seed {seed}: {v}");
        let rate = candidate(&out, "rate_dependent_friction");
        assert!(rate["params"]["stribeck_speed_mps"].is_number(), "{rate}");
        let (before, after) = heldout_before_after(&out);
        assert!(after <= 0.45 * before, "seed {seed}: {before} → {after} N");
    }
}

/// The holder on a compliant mount (the literature form: ringing at
/// 25 Hz, damping ratio 0.2), between the load cell and the needle: the
/// load cell reads the tissue's force through it, so each puncture's
/// fall overshoots by half the fall and rings, as every stop and
/// reversal does. Named on the paper's protocol (250 Hz, 3 mN, each trial
/// 15 % its own, seed 2) with the mode found within a third of an octave
/// and the tissue's force passed through it for the most part (its gain
/// 0.61: each trial's tip unloading on its first retraction takes a
/// little of the ring there, 0.74 without that column, 0.69 with it, and
/// each trial's reload after the fall a little of the first trough
/// below the course), and
/// on insert–dwell–withdraw as rigs record it (100 Hz, 12 mN, seed 1),
/// where the fall's ring lies on a sample or two.
#[test]
fn a_holder_on_a_ringing_mount_is_named() {
    let out = diagnosis_on_the_papers_rig(("holder_inertia", Form::Literature, 2));
    let v = &out["verdict"];
    assert_eq!(v["effect"], "holder_inertia", "{v}");
    let mount = candidate(&out, "holder_inertia");
    let hz = num(&mount["params"]["mount_hz"]);
    assert!((20.0..=32.0).contains(&hz), "{mount}");
    let gain = num(&mount["params"]["mount_gain"]);
    assert!((0.55..=1.3).contains(&gain), "{mount}");
    let (before, after) = heldout_before_after(&out);
    assert!(after <= 0.6 * before, "{before} → {after} N");
    let out = diagnosis_as_rigs_record(("holder_inertia", Form::Literature, 1));
    assert_eq!(
        out["verdict"]["effect"], "holder_inertia",
        "{}",
        out["verdict"]
    );
}

/// Elasto-plastic presliding on the paper's protocol (250 Hz, 3 mN,
/// each trial 15 % its own): a bristle of fixed stiffness loads as a
/// ramp at each reversal. Its stiffness is the sliding friction's level
/// over x_c — of the friction ahead: read off the friction left behind,
/// a withdrawal after a faster insertion would load seven times too
/// fast. (Seed 1: 33.3 → 18.6 mN; 30.7 → 20.6 since `needle fit` reads
/// no friction within 0.4 mm of the cutting front, where the first
/// bristle ramp after the turn at the front lies.)
#[test]
fn a_bristles_ramp_is_set_by_the_friction_ahead() {
    for seed in [1, 2] {
        let out = diagnosis_on_the_papers_rig(("presliding_hysteresis", Form::Alternate, seed));
        let v = &out["verdict"];
        assert_eq!(v["effect"], "presliding_hysteresis", "seed {seed}: {v}");
        let (before, after) = heldout_before_after(&out);
        assert!(after <= 0.7 * before, "seed {seed}: {before} → {after} N");
    }
}

/// The waterfall names what is there, not what the first effect's
/// candidate misses of the tissue's form: Dahl's presliding with exponent
/// 2 on the paper's protocol leaves a residual of which relaxation and
/// then cutting along depth took 0.08 and 0.04 of the gap, each on every
/// withheld trial; neither is a cause, and neither is named.
#[test]
fn the_misfit_of_the_first_effects_form_is_not_a_second_effect() {
    let out = diagnosis_on_the_papers_rig(("presliding_hysteresis", Form::Literature, 2));
    let v = &out["verdict"];
    assert_eq!(named_in_turn(v), ["presliding_hysteresis"], "{v}");
}

/// A bridge warming through the body it is bonded to: its drift starts
/// flat and accelerates (the literature form, the standard rate reached
/// at 20 s), 0.27 N by the end of a minute-long insert–dwell–withdraw
/// trial, all of it in the needle-free samples the model holds at zero.
/// A steady or settling drift takes two fifths of the gap and not the
/// same share in every trial (paired t 2.5); a drift lagging a steady
/// warming takes it all.
#[test]
fn a_drift_that_accelerates_is_named() {
    let out = diagnosis_as_rigs_record(("sensor_drift", Form::Literature, 1));
    let v = &out["verdict"];
    assert_eq!(v["effect"], "sensor_drift", "{v}");
    let left = num(&v["heldout_rms_after_n"]);
    assert!(left <= 1.2 * num(&out["noise_floor_n"]), "{v}");
}

/// A bridge settling after power-up (the alternate form: 3 mN/s at
/// first, settling over 30 s) on insert–dwell–withdraw: the trial's
/// force was tared on the first half of its approach, where the drift
/// had already begun, so the drift the trial shows is the drift since
/// then, and the candidate's column is tared the same way: a column zero
/// at the first sample misses each trial by a constant no correction
/// takes, and this drift is under half a noise floor over the trial.
#[test]
fn a_drift_is_tared_where_the_trial_was() {
    let out = diagnosis_as_rigs_record(("sensor_drift", Form::Alternate, 1));
    let v = &out["verdict"];
    assert_eq!(v["effect"], "sensor_drift", "{v}");
}

/// Insert–dwell–withdraw into liver whose every trial is 20 % its own
/// (stiffness, cutting, friction): the sample on which the stage stops
/// lies on either side of the stop to the encoder, and the force settles
/// it — against the trial's own levels either side, not the nominal's,
/// which the trial's spread moves by as much as the step between them.
/// Judged by the nominal's levels, one stop sample in three trials read
/// as still cutting, 0.3 N off, and the dataset was `unexplained` (8.0 mN
/// on a 5 mN floor at 500 Hz, 18.9 on 12 at 100 Hz).
#[test]
fn a_stop_is_placed_by_the_trials_own_levels_either_side() {
    for (rate_hz, noise_n) in [(500.0, 0.005), (100.0, 0.012)] {
        let dir = tempfile::tempdir().unwrap();
        let rig = Rig {
            protocol: ProtocolKind::InsertDwellWithdraw,
            spread: 0.2,
            ..Default::default()
        };
        let sensor = Sensor {
            rate_hz,
            noise_n,
            ..SENSOR
        };
        simulate_with(dir.path(), ("", Form::Standard, 5), rig, sensor);
        let out = diagnosis_of(dir.path());
        assert_named(&out, "none", 0.0);
        let (left, noise) = (
            num(&out["verdict"]["heldout_rms_after_n"]),
            num(&out["noise_floor_n"]),
        );
        assert!(left <= 1.1 * noise, "{rate_hz} Hz: {left} on {noise}");
    }
}

/// A load cell of `(rate_hz, noise_n)` on a jittered clock, each trial's
/// tissue 20 % its own and its zero `tare_sd_n` off, on `protocol`: the
/// rigs of the book's no-effect grid.
fn a_rigs_spread(
    protocol: ProtocolKind,
    (rate_hz, noise_n): (f64, f64),
    tare_sd_n: f64,
) -> (Sensor, Rig) {
    let sensor = Sensor {
        rate_hz,
        noise_n,
        ..SENSOR
    };
    let rig = Rig {
        protocol,
        spread: 0.2,
        jitter: true,
        tare_sd_n,
        ..Default::default()
    };
    (sensor, rig)
}

fn spread_alone_is_none(tissue_name: &'static str, seed: u64, tare_sd_n: f64) -> serde_json::Value {
    let rig = Rig {
        spread: 0.2,
        tare_sd_n,
        ..Default::default()
    };
    spread_alone_is_none_on(tissue_name, seed, SENSOR, rig)
}

fn spread_alone_is_none_on(
    tissue_name: &'static str,
    seed: u64,
    sensor: Sensor,
    rig: Rig,
) -> serde_json::Value {
    let out = no_effect_diagnosis(tissue_name, seed, sensor, rig);
    let v = &out["verdict"];
    assert_eq!(v["effect"], "none", "{tissue_name} seed {seed}: {v}");
    assert_eq!(
        v["effects"],
        serde_json::json!([]),
        "{tissue_name} seed {seed}: {v}"
    );
    let (left, noise) = (num(&v["heldout_rms_after_n"]), num(&out["noise_floor_n"]));
    assert!(
        left <= 1.5 * noise,
        "{tissue_name} seed {seed}: {left} vs {noise}"
    );
    out
}

/// Ten trials of `tissue_name`'s nominal physics on `sensor` and `rig`,
/// diagnosed against the fitted nominal.
fn no_effect_diagnosis(tissue_name: &'static str, seed: u64, sensor: Sensor, rig: Rig) -> Value {
    no_effect_diagnosis_of(
        (tissue_name, &tissue(tissue_name).unwrap()),
        seed,
        sensor,
        rig,
    )
}

/// [`no_effect_diagnosis`] of a tissue given by its parameters.
fn no_effect_diagnosis_of(
    (tissue_name, params): (&'static str, &TissueParams),
    seed: u64,
    sensor: Sensor,
    rig: Rig,
) -> Value {
    let dir = tempfile::tempdir().unwrap();
    Dataset {
        tissue_name,
        tissue: params,
        effects: &[],
        trials: 10,
        seed,
        sensor,
        through: false,
        form: Form::Standard,
        rig,
    }
    .write(dir.path())
    .unwrap();
    let (_, data) = load(dir.path(), None).unwrap();
    serde_json::to_value(diagnose(&data, Nominal::Fitted)).unwrap()
}

/// A heterogeneous tissue: each trial's cutting force wanders along its
/// own path (a random walk, sim's alternate form at no trend), with the
/// tissue's spread from trial to trial and a jittered clock. No shared
/// law predicts a withheld trial's wander; the verdict names it as
/// cutting along depth in each trial, on both protocols, and leaves
/// little of the gap.
#[test]
fn cutting_that_wanders_along_each_path_is_named() {
    for protocol in [ProtocolKind::Paper, ProtocolKind::InsertDwellWithdraw] {
        let rig = Rig {
            protocol,
            jitter: true,
            spread: 0.15,
            ..Default::default()
        };
        let case = ("depth_dependent_cutting=0", Form::Alternate, 5);
        assert_named_along_depth(&diagnosis_on(case, rig));
    }
}

/// Cutting that wanders along each path at the simulator's standard size
/// (its alternate form), on insert–dwell–withdraw as the effect sweep's
/// rig records it (liver 1, 100 Hz, a 12 mN load cell, clock jitter,
/// 15 % spread). The wander acts only while the tip cuts, and the dwell
/// and withdrawal the nominal fits to the noise dilute it: over the
/// whole trials the nominal misses by 1.14 noise floors, within the 1.5
/// that count as explained, while in the insertion it misses by two.
/// The gap where the tip cuts is still a gap, and the profile free along
/// depth is named for it.
#[test]
fn cutting_that_wanders_only_where_the_tip_cuts_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(["simulate", "--out", dir.path().to_str().unwrap()])
        .args(["--protocol", "insert-dwell-withdraw", "--jitter"])
        .args(["--rate-hz", "100", "--noise-n", "0.012", "--spread", "0.15"])
        .args([
            "--trials",
            "10",
            "--seed",
            "1",
            "--effect-form",
            "alternate",
        ])
        .args(["--effects", "depth_dependent_cutting"])
        .output()
        .unwrap();
    assert!(status.status.success(), "{status:?}");
    let out = diagnosis_of(dir.path());
    let noise = num(&out["noise_floor_n"]);
    let (before, after) = heldout_before_after(&out);
    let insertion = num(&out["baseline"]["by_phase"]["insertion"]["rms_n"]);
    assert!(before <= 1.5 * noise && insertion > 1.5 * noise, "{out}");
    let v = &out["verdict"];
    assert_eq!(v["effect"], "depth_dependent_cutting", "{v}");
    assert_eq!(v["effects"][0]["law"], "along_depth_in_each_trial", "{v}");
    assert!(after <= 1.1 * noise, "{v}");
}

/// The skin phantom as real rigs record it (insert–dwell–withdraw at
/// 100 Hz, a 12 mN load cell, a 4 mN tare, clock jitter, 15 % spread)
/// with `effects` in their alternate form at `seed`, through `needle
/// simulate` and `needle diagnose`.
fn skin_diagnosis(effects: &str, seed: u64) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(["simulate", "--out", dir.path().to_str().unwrap()])
        .args([
            "--tissue",
            "skin_phantom",
            "--protocol",
            "insert-dwell-withdraw",
        ])
        .args(["--jitter", "--rate-hz", "100", "--noise-n", "0.012"])
        .args(["--tare-n", "0.004", "--spread", "0.15", "--trials", "10"])
        .args(["--seed", &seed.to_string(), "--effect-form", "alternate"])
        .args(["--effects", effects])
        .output()
        .unwrap();
    assert!(status.status.success(), "{status:?}");
    diagnosis_of(dir.path())
}

/// Cutting that wanders along each path (a tissue of layers as real
/// skin recordings show: the force after the puncture climbs and eases
/// along depth, each insertion its own way) beside relaxation at five
/// times its standard size, on the skin phantom: no shared law takes the
/// wander, the profile free along depth does. Six times the standard
/// wander leads, and the dwell's relaxation it leaves is named after it;
/// four times is led by the relaxation, and the profile is named after
/// it on what it leaves. Either way little of the gap is left: within
/// 1.5 noise floors (four times the wander: 14.9 mN on 12.6), or under
/// 15 % of the nominal's misfit (six times: 39 mN of 295 on 12.7, each
/// trial's own relaxing share among it).
#[test]
fn relaxation_and_cutting_that_wanders_along_each_path_are_both_named() {
    for (effects, seed, order) in [
        ("depth_dependent_cutting=6,viscoelasticity=5", 2, [0, 1]),
        ("depth_dependent_cutting=4,viscoelasticity=5", 1, [1, 0]),
    ] {
        let out = skin_diagnosis(effects, seed);
        let v = &out["verdict"];
        let [cutting, relaxation] = order.map(|k| &v["effects"][k]);
        assert_eq!(cutting["effect"], "depth_dependent_cutting", "{v}");
        assert_eq!(cutting["law"], "along_depth_in_each_trial", "{v}");
        assert_eq!(relaxation["effect"], "viscoelasticity", "{v}");
        assert_eq!(relaxation["law"], "shared", "{v}");
        let (before, after) = heldout_before_after(&out);
        let noise = num(&out["noise_floor_n"]);
        assert!(after <= 1.5 * noise || after < 0.15 * before, "{v}");
    }
}

/// Cutting loaded again after the puncture and rising as the square root
/// of depth (the simulator's literature form: the layer beneath a
/// ruptured capsule cuts at 40 % of its level at first, back within 5 %
/// by 2.4 mm), recorded as real rigs record and on the paper's rig. The
/// reload is every real recording's, each trial's own: the nominal reads
/// it (its correction's mean gain near 1, each trial's deficit its own
/// reading). The rise with depth is named on the paper's protocol, whose
/// strokes tell it from friction, in its own shape (the exponent ½); on
/// insert–dwell–withdraw, at one speed, a rise with depth is a friction
/// per length, and the verdict is `none`.
#[test]
fn a_reload_is_the_nominals_and_a_rise_with_depth_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let case = ("depth_dependent_cutting", Form::Literature, 1);
    simulate_as_rigs_record(dir.path(), case);
    let paper = Rig {
        jitter: true,
        spread: 0.15,
        ..Default::default()
    };
    let (rigs, paper) = (diagnosis_of(dir.path()), diagnosis_on(case, paper));
    for out in [&rigs, &paper] {
        let reload = num(&out["baseline"]["corrections"]["reload_n"]);
        assert!((0.5..1.5).contains(&reload), "{}", out["baseline"]);
    }
    let v = &paper["verdict"];
    assert_eq!(v["effect"], "depth_dependent_cutting", "{v}");
    let chosen = candidate(&paper, "depth_dependent_cutting");
    assert_eq!(num(&chosen["params"]["depth_exponent"]), 0.5, "{chosen}");
    assert_eq!(rigs["verdict"]["effect"], "none", "{}", rigs["verdict"]);
}

/// The verdict names cutting along depth in each trial, tried after the
/// shared candidates (whatever their ranking), with a real shrink and a
/// window within the ones tried.
fn assert_named_along_depth(out: &Value) {
    let v = &out["verdict"];
    assert_eq!(v["effect"], "depth_dependent_cutting", "{v}");
    let step = &v["effects"][0];
    assert_eq!(step["law"], "along_depth_in_each_trial", "{v}");
    assert!(num(&v["shrink"]) >= 0.15, "{v}");
    let half_window_m = num(&step["half_window_m"]);
    assert!((0.000_05..=0.002).contains(&half_window_m), "{v}");
}

#[test]
fn another_form_of_the_physics_is_still_named() {
    // Two-branch viscoelasticity, elasto-plastic presliding, stiffening
    // walls, saturating depth dependence, a drive with finite
    // acceleration, thermally settling drift (sim::Form::Alternate).
    // Non-sinusoidal breathing at a random phase. Logarithmic rate
    // strengthening.
    for effect in [
        "none",
        "viscoelasticity",
        "rate_dependent_friction",
        "presliding_hysteresis",
        "internal_structures",
        "depth_dependent_cutting",
        "holder_inertia",
        "sensor_drift",
        "tissue_motion",
    ] {
        let out = diagnosis(effect, Form::Alternate, 11);
        if below_the_bar(&out, effect) {
            continue;
        }
        // Each trial's own friction scale (the spread of a tissue) takes
        // the part of a rate dependence that differs between trials run
        // at different speeds; what is left is the shape within a trial.
        let least = if effect == "rate_dependent_friction" {
            0.05
        } else {
            0.15
        };
        // The alternate form's cutting wanders along each trial's path
        // about its trend: named either way.
        let along = out["verdict"]["effects"][0]["law"] == "along_depth_in_each_trial";
        if effect == "depth_dependent_cutting" && along {
            assert_named_along_depth(&out);
            continue;
        }
        assert_named(&out, effect, least);
    }
}

#[test]
fn the_json_has_the_issues_keys_sorted_best_first() {
    let out = diagnosis("sensor_drift", Form::Standard, 3);
    assert_eq!(out["trials"], 10);
    let phases = [
        "approach",
        "loading",
        "insertion",
        "dwell",
        "reversal",
        "withdrawal",
        "after",
    ];
    let by_phase = out["baseline"]["by_phase"].as_object().unwrap();
    assert!(by_phase.keys().all(|k| phases.contains(&k.as_str())));
    let share: f64 = by_phase.values().map(|p| num(&p["share"])).sum();
    assert!((share - 1.0).abs() < 1e-9);
    // Each trial's held-out RMS, by file: the pooled RMS lies between the
    // trials' least and greatest, before and after the named effects.
    for (by_trial, pooled) in [
        (
            &out["baseline"]["by_trial"],
            &out["baseline"]["heldout_rms_n"],
        ),
        (
            &out["verdict"]["left_by_trial"],
            &out["verdict"]["heldout_rms_after_n"],
        ),
    ] {
        let rms: Vec<f64> = by_trial.as_object().unwrap().values().map(num).collect();
        assert_eq!(rms.len(), 10, "{by_trial}");
        let (least, most) = rms
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &r| (a.min(r), b.max(r)));
        assert!(
            least <= num(pooled) && num(pooled) <= most,
            "{by_trial} {pooled}"
        );
    }
    let where_ = out["where"].as_array().unwrap();
    assert!(where_
        .windows(2)
        .all(|w| num(&w[0]["share"]) >= num(&w[1]["share"])));
    assert!(where_
        .iter()
        .all(|w| num(&w["x_to_m"]) > num(&w["x_from_m"])));
    let cands = out["candidates"].as_array().unwrap();
    assert_eq!(cands.len(), 8);
    assert!(cands
        .windows(2)
        .all(|w| num(&w[0]["shrink"]) >= num(&w[1]["shrink"])));
    // The simulator's drift, 3 mN/s in every trial, is what each trial's
    // samples out of tissue read: the drift fitted is the shared rate and
    // the gain on that read together.
    let drift = &cands[0]["params"];
    let rate_n_per_s =
        num(&drift["rate_n_per_s"]) + num(&drift["gain_on_rate_out_of_tissue"]) * 0.003;
    assert!((rate_n_per_s - 0.003).abs() < 0.0005, "drift {drift}");
    for key in ["effect", "shrink", "second"] {
        assert!(!out["verdict"][key].is_null());
    }
}

#[test]
fn a_decoded_stream_names_the_drift_and_the_device_models_gap_has_it_closest() {
    let sim = tempfile::tempdir().unwrap();
    simulate(sim.path(), "sensor_drift", Form::Standard, 7);
    let live = tempfile::tempdir().unwrap();
    let needle = env!("CARGO_BIN_EXE_needle");
    for k in 0..10 {
        let replay = std::fs::read(sim.path().join(format!("trial_{k:03}.replay"))).unwrap();
        let frames = live.path().join(format!("trial_{k:03}.frames"));
        std::fs::write(&frames, needle_io::twin::run(&replay).frames).unwrap();
        let csv = live.path().join(format!("trial_{k:03}.csv"));
        let status = Command::new(needle)
            .args([
                "decode",
                frames.to_str().unwrap(),
                "--csv",
                csv.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert!(status.status.success(), "{status:?}");
        std::fs::remove_file(frames).unwrap();
    }
    let diagnose_live = |extra: &[&str]| -> Value {
        let out = Command::new(needle)
            .arg("diagnose")
            .arg(live.path())
            .args(extra)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).unwrap()
    };
    // The decoded stream as trials: the same verdict as on the simulation.
    let host = diagnose_live(&[]);
    assert_eq!(
        host["verdict"]["effect"], "sensor_drift",
        "{}",
        host["verdict"]
    );
    assert!(num(&host["verdict"]["shrink"]) > 0.5);
    // Against the firmware's own model (its residual stream): what the
    // device's online geometry misses in the dwell and at the reversals
    // leaves more than 1.5 noise floors (within the nominal's tolerance
    // of 1 % of the puncture force, so `explained` may say either), the
    // drift the first effect named or, if none is significant, the
    // closest candidate.
    let device = diagnose_live(&["--device-model"]);
    let v = &device["verdict"];
    println!("against the device's model: {v}");
    let closest = v["closest"].as_array().unwrap();
    let left = num(&v["heldout_rms_after_n"]);
    let noise = num(&device["noise_floor_n"]);
    assert!(left > 1.5 * noise, "{left} on {noise}: {v}");
    assert_eq!(closest[0], "sensor_drift", "{v}");
    assert!(
        v["effect"] == "unexplained" || v["effect"] == "sensor_drift",
        "{v}"
    );
}

/// `--residuals` gives every sample against the pooled nominal and
/// against the nominal at its best for its trial (the trial's own
/// corrections as the baseline fits them): with each trial's tissue 20 %
/// its own, the first misses by the spread, the second only by the noise.
#[test]
fn the_residuals_file_has_each_trials_nominal_at_its_best_too() {
    let sim = tempfile::tempdir().unwrap();
    let rig = Rig {
        spread: 0.2,
        ..Default::default()
    };
    simulate_on(sim.path(), ("", Form::Standard, 21), rig);
    let out = tempfile::tempdir().unwrap();
    let csv = out.path().join("r.csv");
    let run = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(["diagnose", sim.path().to_str().unwrap(), "--residuals"])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let diagnosis: Value = serde_json::from_slice(&run.stdout).unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (nominal, fitted) = (column("residual_n"), column("fitted_residual_n"));
    let (mut nominal_ss, mut fitted_ss, mut n) = (0.0, 0.0, 0.0);
    for line in lines {
        let cells: Vec<f64> = line
            .split(',')
            .map(|c| c.parse().unwrap_or(f64::NAN))
            .collect();
        nominal_ss += cells[nominal].powi(2);
        fitted_ss += cells[fitted].powi(2);
        n += 1.0;
    }
    let (nominal_rms, fitted_rms) = ((nominal_ss / n).sqrt(), (fitted_ss / n).sqrt());
    let noise = num(&diagnosis["noise_floor_n"]);
    assert!(
        fitted_rms < 0.5 * nominal_rms && fitted_rms <= 1.5 * noise,
        "{fitted_rms} against {nominal_rms} (noise {noise})"
    );
}

#[test]
fn a_report_is_written_with_its_figure() {
    let sim = tempfile::tempdir().unwrap();
    simulate(sim.path(), "depth_dependent_cutting", Form::Standard, 5);
    let out = tempfile::tempdir().unwrap();
    let page = out.path().join("gap.html");
    let status = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args([
            "diagnose",
            sim.path().to_str().unwrap(),
            "--report",
            page.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(status.status.success());
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains("depth_dependent_cutting") && html.contains("gap.svg"));
    // Each candidate's parameters as it was fitted, the named one's too.
    assert!(
        html.contains("cutting_growth_at_10_mm_n = "),
        "no parameters"
    );
    // The waterfall: the nominal, each effect, the noise floor and the
    // level below which the gap counts as explained, each labelled.
    for label in [
        "nominal",
        "+ depth_dependent_cutting",
        "noise floor",
        "explained below",
    ] {
        assert!(html.contains(label), "waterfall lacks {label}");
    }
    let svg = std::fs::read_to_string(out.path().join("gap.svg")).unwrap();
    for label in [
        "measured",
        "nominal, the trial&apos;s own levels",
        "+ depth_dependent_cutting",
        "insertion",
        "reversal",
        "measured − nominal",
        "measured − (nominal + depth_dependent_cutting)",
    ] {
        assert!(svg.contains(label), "figure lacks {label}");
    }
}
