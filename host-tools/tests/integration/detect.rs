//! The device's detectors over simulated trials, scored against the
//! simulator's truth by the evaluation harness (`needle evaluate`), and
//! the robot-assist halts over the same trials. The targets: over ≥ 200
//! insertions at 5 mN noise with interior structures, puncture between
//! the force peak and 2 samples after the fall with no miss and no false
//! alarm; structures at recall and precision ≥ 95 % within 5 samples of
//! their fall. The scorer's windows are checked first, on hand-placed
//! events, so that a detector firing early or late cannot pass.

use std::sync::OnceLock;

use crate::common;

use needle_analysis::evaluate::{cell, kind, Cell};

/// A 500 Hz trial's true puncture: peak at 10.000 s, fall at 10.002 s.
fn true_event(kind: &str) -> needle_analysis::detect::TrueEvent {
    needle_analysis::detect::TrueEvent {
        kind: kind.into(),
        t_s: 10.002,
        peak_t_s: 10.000,
        x_m: 0.020,
    }
}

fn found_at(kind: &str, t_s: f64, needle_x_m: f64) -> needle_analysis::detect::Found {
    needle_analysis::detect::Found {
        kind: kind.into(),
        t_s,
        needle_x_m,
    }
}

#[test]
fn the_scorer_takes_a_puncture_from_its_peak_to_2_samples_after_the_fall_only() {
    use needle_analysis::detect::finds;
    let period = 1.0 / 500.0;
    let puncture = true_event("puncture");
    let at = |t| finds(&puncture, &found_at("puncture", t, 0.02), period);
    assert!(!at(10.000 - period), "a sample before the peak");
    assert!(!at(10.000 - 10.0 * period), "10 samples early");
    assert!(at(10.000), "at the peak");
    assert!(at(10.002), "at the fall");
    assert!(at(10.002 + 2.0 * period), "2 samples after the fall");
    assert!(!at(10.002 + 3.0 * period), "3 samples after the fall");
    // A structure: 5 samples after its fall, not 1 s.
    let wall = true_event("structure");
    let at = |t| finds(&wall, &found_at("structure", t, 0.02), period);
    assert!(at(10.002 + 5.0 * period));
    assert!(!at(10.002 + 6.0 * period));
    assert!(!at(11.002), "1 s late");
    assert!(!at(10.000 - period), "before its peak");
    // An exit: from its sample to 2 after.
    let exit = true_event("exit");
    let at = |t| finds(&exit, &found_at("exit", t, 0.02), period);
    assert!(!at(10.002 - period) && at(10.002) && at(10.002 + 2.0 * period));
    assert!(!at(10.002 + 3.0 * period));
    // A contact: from its sample until the needle is 2 mm past it.
    let contact = true_event("contact");
    let at = |t, x| finds(&contact, &found_at("contact", t, x), period);
    assert!(!at(10.0, 0.0200), "before it happens");
    assert!(at(10.5, 0.0215) && at(10.7, 0.0219));
    assert!(!at(10.8, 0.0221), "2.1 mm past the surface");
}

#[test]
fn a_detection_outside_its_window_is_a_miss_and_a_false_alarm() {
    use needle_analysis::detect::score;
    let truth = [true_event("puncture")];
    let early = [found_at("puncture", 10.000 - 10.0 / 500.0, 0.02)];
    let s = &score(&truth, &early, 500.0, &["puncture"])[0];
    assert_eq!((s.misses, s.false_alarms, s.detected), (1, 1, 1));
    // 10.006 s is 2 samples (2 ms each at 500 Hz) after the fall at
    // 10.002 s: the last that counts.
    let on_time = [found_at("puncture", 10.006, 0.02)];
    let s = &score(&truth, &on_time, 500.0, &["puncture"])[0];
    assert_eq!((s.misses, s.false_alarms), (0, 0));
    assert!((s.latency_samples_max - 2.0).abs() < 1e-6, "{s:?}");
    assert!((s.latency_samples_min - 2.0).abs() < 1e-6, "{s:?}");
}

/// 100 insertions at 500 Hz and 100 at 2 kHz, 5 mN, with structures and
/// through the sample; computed once for the tests below.
fn five_mn() -> &'static [Cell; 2] {
    static CELLS: OnceLock<[Cell; 2]> = OnceLock::new();
    CELLS.get_or_init(|| {
        [
            cell(500.0, 0.005, true, "", 100, 31).unwrap(),
            cell(2000.0, 0.005, true, "", 100, 32).unwrap(),
        ]
    })
}

#[test]
fn puncture_within_2_samples_no_miss_no_false_alarm_over_200_insertions() {
    let mut insertions = 0;
    for c in five_mn() {
        let p = kind(c, "puncture");
        insertions += p.true_events;
        assert_eq!((p.misses, p.false_alarms), (0, 0), "{p:?}");
        // The scorer's window already holds every hit between the peak and
        // 2 samples after the fall; the simulator's fall is one sample
        // after its peak, so no latency is below -1.
        assert!(p.latency_samples_max <= 2.0, "{p:?}");
        assert!(p.latency_samples_min >= -1.0, "{p:?}");
    }
    assert_eq!(insertions, 200);
}

#[test]
fn structures_at_recall_and_precision_of_95_percent() {
    for c in five_mn() {
        let s = kind(c, "structure");
        let (truth, detected) = (s.true_events, s.detected);
        let hits = truth - s.misses;
        assert!(truth >= 100, "{s:?}");
        assert!(hits as f64 >= 0.95 * truth as f64, "recall: {s:?}");
        assert!(hits as f64 >= 0.95 * detected as f64, "precision: {s:?}");
        assert!(s.latency_samples_max <= 5.0, "{s:?}");
    }
}

#[test]
fn contacts_are_found_within_2_mm_of_travel_without_false_alarms() {
    for c in five_mn() {
        let k = kind(c, "contact");
        assert_eq!(k.true_events, 100, "{k:?}");
        assert_eq!((k.misses, k.false_alarms), (0, 0), "{k:?}");
    }
}

#[test]
fn exits_into_air_are_found_without_false_alarms() {
    for c in five_mn() {
        let e = kind(c, "exit");
        assert!(e.true_events >= 50, "{e:?}");
        assert_eq!((e.misses, e.false_alarms), (0, 0), "{e:?}");
        assert!(e.latency_samples_max <= 2.0, "{e:?}");
    }
}

/// Every other unmodelled effect at once, at 10 mN: the puncture detector
/// still neither misses nor false-alarms (other kinds degrade; the book
/// gives the figures).
#[test]
fn puncture_holds_up_under_every_unmodelled_effect() {
    let others = "viscoelasticity,rate_dependent_friction,presliding_hysteresis,\
                  depth_dependent_cutting,holder_inertia,sensor_drift,tissue_motion";
    let c = cell(500.0, 0.01, true, others, 40, 33).unwrap();
    let p = kind(&c, "puncture");
    assert_eq!(p.true_events, 40, "{p:?}");
    assert_eq!((p.misses, p.false_alarms), (0, 0), "{p:?}");
}

/// Robot assist over simulated trials: stop on puncture halts at the
/// puncture's own sample; stop at depth halts within one sample's travel
/// of the target past the surface the device found.
#[test]
fn assist_halts_at_the_event_sample_and_at_the_target_depth() {
    use needle_analysis::detect::detect_trial;
    use needle_analysis::sim::{simulate_dataset, Sensor};
    use needle_holder::config::DeviceConfig;
    use needle_holder::model::params::LIVER1;
    use needle_io::device::parse_assist;
    let dir = tempfile::tempdir().unwrap();
    let sensor = Sensor {
        rate_hz: 1000.0,
        noise_n: 0.005,
        encoder_m: 1e-6,
    };
    simulate_dataset(dir.path(), "liver1", &LIVER1, &[], 10, 34, &sensor).unwrap();
    let on_puncture = DeviceConfig::default().with_assist(parse_assist("puncture").unwrap());
    let mut at_depth = DeviceConfig::default().with_assist(parse_assist("depth").unwrap());
    at_depth.assist.target_depth = needle_holder::units::Nanometres::from_m(0.02);
    for file in needle_io::trial::dataset_files(dir.path()).unwrap() {
        let trial = needle_io::trial::read(&file).unwrap();
        let found = detect_trial(&trial, &on_puncture);
        let puncture = found.events.iter().find(|e| e.kind == "puncture").unwrap();
        let halt = found.halt.as_ref().expect("a halt");
        assert_eq!((halt.reason, halt.t_s), ("puncture", puncture.t_s));

        let found = detect_trial(&trial, &at_depth);
        let contact = found.events.iter().find(|e| e.kind == "contact").unwrap();
        let halt = found.halt.as_ref().expect("a halt");
        assert_eq!(halt.reason, "target_depth");
        let past_surface = halt.x_m - contact.x_m;
        assert!(
            (0.02..0.02 + 11e-6).contains(&past_surface),
            "{past_surface}"
        );
    }
    assert!(parse_assist("puncture,warp").is_err());
}

/// `needle detect DIR --samples OUT`: the device's own samples for every
/// trial of a recording that never went through a device, in `needle
/// decode --csv`'s columns and the file's times and positions, with the
/// model's prediction and its residual; never over the dataset, never
/// over earlier output.
#[test]
fn detect_writes_the_devices_samples_per_trial_beside_no_trial() {
    use needle_analysis::sim::{simulate_dataset, Sensor};
    use needle_holder::model::params::LIVER1;
    let sensor = Sensor {
        rate_hz: 500.0,
        noise_n: 0.005,
        encoder_m: 1e-6,
    };
    let dir = tempfile::tempdir().unwrap();
    simulate_dataset(dir.path(), "t", &LIVER1, &[], 2, 4, &sensor).unwrap();
    let out = dir.path().join("device");
    let needle = |out: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_needle"))
            .args(["detect", "--samples"])
            .arg(out)
            .arg(dir.path())
            .output()
            .unwrap()
    };
    let run = needle(&out);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let trials = needle_io::trial::dataset_files(dir.path()).unwrap();
    assert_eq!(trials.len(), 2);
    for input in &trials {
        let name = input.file_name().unwrap();
        let recorded = needle_io::trial::read(input).unwrap();
        let mut rows = csv::Reader::from_path(out.join(name)).unwrap();
        assert_eq!(
            rows.headers().unwrap().iter().collect::<Vec<_>>(),
            needle_io::decode::CSV_HEADER
        );
        let rows: Vec<csv::StringRecord> = rows.records().map(Result::unwrap).collect();
        assert_eq!(rows.len(), recorded.len());
        let num = |r: &csv::StringRecord, k: usize| r[k].parse::<f64>().unwrap();
        let mut predicted = 0;
        for (i, r) in rows.iter().enumerate() {
            assert!((num(r, 0) - recorded.t_s[i]).abs() < 1e-6);
            // The encoder's micrometre and the load cell's counts.
            assert!((num(r, 1) - recorded.x_m[i]).abs() < 2e-6, "{i}");
            assert!((num(r, 2) - recorded.f_n[i]).abs() < 1e-3, "{i}");
            // The residual is the measured force less the model's.
            assert!((num(r, 5) - (num(r, 2) - num(r, 4))).abs() < 2e-6, "{i}");
            predicted += usize::from(num(r, 4).abs() > 0.1);
        }
        assert!(predicted > rows.len() / 4, "the model predicts a force");
        let phases: std::collections::BTreeSet<&str> = rows.iter().map(|r| &r[6]).collect();
        assert!(
            phases.contains("loading") && phases.len() >= 3,
            "{phases:?}"
        );
    }
    // Again into the same directory: refused, the first output kept.
    let before = std::fs::read(out.join(trials[0].file_name().unwrap())).unwrap();
    let again = needle(&out);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("already holds 2 CSV"));
    assert_eq!(
        std::fs::read(out.join(trials[0].file_name().unwrap())).unwrap(),
        before
    );
    // Into the dataset itself: refused, nothing added.
    let into = needle(dir.path());
    assert!(!into.status.success());
    assert!(String::from_utf8_lossy(&into.stderr).contains("names the dataset itself"));
    assert_eq!(
        needle_io::trial::dataset_files(dir.path()).unwrap().len(),
        2
    );
}

/// On insert–dwell–withdraw trials whose tissue relaxes at rest (the
/// simulator's standard and alternate forms, relaxing branches the
/// needle's motion loads; trial-to-trial spread, jitter, the tissue
/// dragged on withdrawal), the tissue `needle fit --toml` writes carries
/// the relaxation, and with it the device's residual over every dwell
/// stays within two noise floors; without the relaxation keys it does
/// not. The literature form (Fung's QLV on every tissue force, over its
/// whole history) holds a force that rises at rest where the static band
/// holds less than the needle slid with: the device's relaxation at rest
/// cannot follow that, and `needle fit` writes none.
#[test]
fn the_device_predicts_the_dwell_with_the_fitted_relaxation() {
    use common::needle;
    let noise_n = 0.012;
    for (form, effect) in [
        ("standard", "viscoelasticity"),
        ("alternate", "viscoelasticity"),
        ("literature", "viscoelasticity=5"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let path = |p: &str| dir.path().join(p).to_str().unwrap().to_owned();
        needle(&[
            "simulate",
            "--out",
            &path("trials"),
            "--trials",
            "6",
            "--seed",
            "5",
            "--protocol",
            "insert-dwell-withdraw",
            "--effects",
            effect,
            "--effect-form",
            form,
            "--rate-hz",
            "100",
            "--noise-n",
            "0.012",
            "--jitter",
            "--spread",
            "0.2",
        ]);
        needle(&["fit", &path("trials"), "--toml", &path("fitted.toml")]);
        let toml = std::fs::read_to_string(path("fitted.toml")).unwrap();
        if form == "literature" {
            assert!(
                !toml.contains("relax_gain_1 = ") && toml.contains("at rest the force fell -"),
                "{form}: {toml}"
            );
            continue;
        }
        assert!(
            toml.contains("relax_gain_1 = ") && toml.contains("relax_tau_1_s = "),
            "{form}: {toml}"
        );
        let without: String = toml
            .lines()
            .filter(|l| !l.starts_with("relax_"))
            .map(|l| format!("{l}\n"))
            .collect();
        std::fs::write(path("unrelaxed.toml"), without).unwrap();
        let mut worst = [0.0f64; 2];
        for (k, tissue) in ["fitted.toml", "unrelaxed.toml"].iter().enumerate() {
            let out = path(&format!("device_{k}"));
            needle(&[
                "detect",
                &path("trials"),
                "--params",
                &path(tissue),
                "--samples",
                &out,
            ]);
            for (sum, n) in common::dwells(std::path::Path::new(&out)) {
                assert!(n > 300, "{form}: a trial with no dwell");
                worst[k] = worst[k].max((sum / n as f64).sqrt());
            }
        }
        println!("{form}: worst dwell residual {:.1} mN with the fitted relaxation, {:.1} mN without ({:.0} mN noise)", worst[0] * 1e3, worst[1] * 1e3, noise_n * 1e3);
        assert!(worst[0] <= 2.0 * noise_n, "{form}: {worst:?}");
        assert!(worst[1] > worst[0], "{form}: {worst:?}");
    }
}
