//! Self-check of the independent validation generator (`apart/`): the
//! data it writes has the physical properties it claims, measured from
//! the CSV columns (time, position, force), not from its parameters.

use crate::apart;

use std::collections::BTreeMap;
use std::sync::OnceLock;

use apart::{Case, Protocol, Trial};

const SEED: u64 = 0x5eed_a9a7;

fn cases() -> &'static Vec<Case> {
    static C: OnceLock<Vec<Case>> = OnceLock::new();
    C.get_or_init(apart::diagnosis_cases)
}

/// Two trials of every diagnosis case.
fn diagnosis_trials() -> &'static Vec<(Case, Vec<Trial>)> {
    static T: OnceLock<Vec<(Case, Vec<Trial>)>> = OnceLock::new();
    T.get_or_init(|| {
        cases()
            .iter()
            .map(|c| (c.clone(), apart::generate(c, 2, SEED)))
            .collect()
    })
}

fn phantoms() -> &'static Vec<Trial> {
    static T: OnceLock<Vec<Trial>> = OnceLock::new();
    T.get_or_init(|| apart::layered_phantoms(30, SEED))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn sd(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

fn index_at(tr: &Trial, t_s: f64) -> usize {
    tr.t_s
        .iter()
        .position(|&t| (t - t_s).abs() < 1e-12)
        .expect("an event names a sample time")
}

fn events<'a>(tr: &'a Trial, kind: &str) -> Vec<&'a apart::Event> {
    tr.events.iter().filter(|e| e.kind == kind).collect()
}

/// Force at the sample of the peak and at the first fallen sample.
fn fall(tr: &Trial, e: &apart::Event) -> (f64, f64) {
    (
        tr.f_n[index_at(tr, e.peak_t_s)],
        tr.f_n[index_at(tr, e.t_s)],
    )
}

/// Samples of the first hold at the deepest stage position.
fn dwell(tr: &Trial) -> (usize, usize) {
    let x_max = tr.x_m.iter().copied().fold(f64::MIN, f64::max);
    let a = tr.x_m.iter().position(|&x| x >= x_max - 1e-9).unwrap();
    let b = (a..tr.x_m.len())
        .find(|&k| tr.x_m[k] < x_max - 1e-9)
        .unwrap_or(tr.x_m.len())
        - 1;
    (a, b)
}

fn window_mean(tr: &Trial, t0: f64, t1: f64) -> f64 {
    let v: Vec<f64> = (0..tr.t_s.len())
        .filter(|&k| tr.t_s[k] >= t0 && tr.t_s[k] <= t1)
        .map(|k| tr.f_n[k])
        .collect();
    mean(&v)
}

/// Fractional fall of the force held in the dwell: start (just after the
/// stage stopped) against its last half second.
fn dwell_relaxation(tr: &Trial) -> (f64, f64) {
    let (a, b) = dwell(tr);
    let t0 = tr.t_s[a] + 0.02;
    let f_start = window_mean(tr, t0, t0 + 0.06);
    // Stop short of the end: the encoder still reads the hold for a few
    // samples after the next move has begun.
    let f_end = window_mean(tr, tr.t_s[b] - 0.55, tr.t_s[b] - 0.05);
    (f_start, 1.0 - f_end / f_start)
}

fn smooth(v: &[f64], k: usize) -> Vec<f64> {
    (0..v.len())
        .map(|i| {
            let a = i.saturating_sub(k / 2);
            let b = (i + k / 2 + 1).min(v.len());
            mean(&v[a..b])
        })
        .collect()
}

/// (position where the withdrawal force is back at zero, relative to the
/// first contact; the strongest pull), from the columns: zero is the level
/// with the needle out at the end.
fn withdrawal_shape(tr: &Trial, noise_n: f64) -> (f64, f64) {
    let n = tr.t_s.len();
    let t_end = tr.t_s[n - 1];
    let zero = window_mean(tr, t_end - 0.4, t_end);
    let (_, b) = dwell(tr);
    let fs = smooth(&tr.f_n[b..], 5);
    let pull = fs.iter().copied().fold(f64::MAX, f64::min) - zero;
    let thr = (4.0 * noise_n).max(0.03);
    let last = (0..fs.len())
        .rev()
        .find(|&k| (fs[k] - zero).abs() > thr)
        .unwrap();
    let x_contact = events(tr, "contact")[0].x_m;
    (tr.x_m[b + last] - x_contact, pull)
}

#[test]
fn cases_cover_every_effect_in_literature_forms() {
    let mut names = std::collections::BTreeSet::new();
    let mut forms: BTreeMap<(Protocol, &str), usize> = BTreeMap::new();
    for c in cases() {
        assert!(names.insert(c.name.clone()), "duplicate case {}", c.name);
        for e in &c.effects {
            *forms.entry((c.protocol, e)).or_default() += 1;
        }
    }
    for p in [Protocol::Paper, Protocol::InsertDwellWithdraw] {
        assert!(cases()
            .iter()
            .any(|c| c.protocol == p && c.effects.is_empty()));
        for e in [
            "viscoelasticity",
            "rate_dependent_friction",
            "presliding_hysteresis",
            "internal_structures",
            "depth_dependent_cutting",
            "holder_inertia",
            "sensor_drift",
            "tissue_motion",
        ] {
            assert!(forms.get(&(p, e)).copied().unwrap_or(0) >= 2, "{p:?} {e}");
        }
    }
}

#[test]
fn dataset_round_trips_through_csv_and_truth() {
    let (case, trials) = &diagnosis_trials()[0];
    let dir = tempfile::tempdir().unwrap();
    apart::write_dataset(dir.path(), trials).unwrap();
    for (i, tr) in trials.iter().enumerate() {
        let text = std::fs::read_to_string(dir.path().join(format!("trial_{i:03}.csv"))).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("t_s,x_m,f_n"));
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), tr.t_s.len());
        for (k, r) in rows.iter().enumerate() {
            assert_eq!(r, &vec![tr.t_s[k], tr.x_m[k], tr.f_n[k]]);
        }
    }
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("truth.json")).unwrap())
            .unwrap();
    let t = &truth["trials"][0];
    assert_eq!(t["file"], "trial_000.csv");
    assert_eq!(t["case"], case.name.as_str());
    assert!(t["baseline_traits"].is_array());
    let kinds: Vec<&str> = t["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds.first(), Some(&"contact"));
    assert_eq!(kinds.last(), Some(&"exit"));
    assert!(kinds.contains(&"puncture"));
}

#[test]
fn time_increases_and_sampling_is_as_stated() {
    let all = diagnosis_trials()
        .iter()
        .flat_map(|(c, t)| t.iter().map(move |tr| (c, tr)))
        .chain(phantoms().iter().map(|tr| (&cases()[0], tr)));
    for (c, tr) in all {
        assert!(tr.t_s.windows(2).all(|w| w[1] > w[0]), "{}", tr.case);
        assert!(tr.f_n.iter().chain(&tr.x_m).all(|v| v.is_finite()));
        let dt: Vec<f64> = tr.t_s.windows(2).map(|w| w[1] - w[0]).collect();
        let max_dt = dt.iter().copied().fold(0.0, f64::max);
        if tr.protocol == Protocol::InsertDwellWithdraw {
            assert!(max_dt <= 0.0705, "{}: gap {max_dt}", tr.case);
            let rate = 1.0 / median(&dt);
            assert!((70.0..=125.0).contains(&rate), "{}: {rate} Hz", tr.case);
            // Stage coordinates: the start lies 2–15 mm before contact.
            let before = events(tr, "contact")[0].x_m - tr.x_m[0];
            assert!(
                (1.9e-3..=15.5e-3).contains(&before),
                "{}: {before}",
                tr.case
            );
        } else {
            assert!((max_dt - 1.0 / c.rate_hz).abs() < 1e-9, "{}", tr.case);
        }
    }
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

#[test]
fn dwell_relaxes_only_where_viscoelastic() {
    let mut report = Vec::new();
    for (c, trials) in diagnosis_trials() {
        for tr in trials {
            let (f0, relax) = dwell_relaxation(tr);
            report.push(format!(
                "{:45} held {f0:6.3} N relaxes {:5.1} %",
                c.name,
                100.0 * relax
            ));
            let visco = c.effects.contains(&"viscoelasticity");
            if c.protocol == Protocol::InsertDwellWithdraw && visco {
                assert!((0.33..=0.42).contains(&relax), "{}: {relax}", c.name);
            }
            if c.protocol == Protocol::Paper && visco {
                // The paper protocol's dwell is 3 s, not 5.
                assert!((0.2..=0.45).contains(&relax), "{}: {relax}", c.name);
            }
            if c.effects.is_empty() {
                let tol = 6.0 * c.noise_n / f0.abs().max(0.1);
                assert!(relax.abs() < tol, "{}: {relax}", c.name);
            }
        }
    }
    eprintln!("{}", report.join("\n"));
    for tr in phantoms() {
        let (f0, relax) = dwell_relaxation(tr);
        assert!((0.33..=0.42).contains(&relax), "{}: {relax}", tr.case);
        assert!((0.8..=4.5).contains(&f0), "{}: held {f0}", tr.case);
    }
    let realistic = diagnosis_trials()
        .iter()
        .find(|(c, _)| c.name == "idw/realistic/viscoelastic_drag")
        .unwrap();
    for tr in &realistic.1 {
        let (f0, _) = dwell_relaxation(tr);
        assert!((0.9..=4.0).contains(&f0), "realistic held force {f0}");
    }
}

#[test]
fn liver_punctures_have_the_papers_force_and_spread() {
    let case = &cases()[0];
    assert_eq!(case.name, "paper/none");
    let trials = apart::generate(case, 30, SEED + 1);
    let mut peaks = Vec::new();
    let mut depths = Vec::new();
    for tr in &trials {
        let p = events(tr, "puncture");
        assert_eq!(p.len(), 1);
        let (pk, fallen) = fall(tr, p[0]);
        peaks.push(pk);
        let contact = events(tr, "contact")[0];
        depths.push(tr.x_m[index_at(tr, p[0].peak_t_s)] - contact.x_m);
        // The drop to cutting + friction happens within a sample or two.
        assert!(fallen < 0.85 * pk, "{pk} -> {fallen}");
        let k = index_at(tr, p[0].t_s);
        assert!(k - index_at(tr, p[0].peak_t_s) <= 2);
    }
    let (m, cv) = (mean(&peaks), sd(&peaks) / mean(&peaks));
    eprintln!(
        "liver puncture {m:.3} N, CV {:.1} %, depth {:.2} ± {:.2} mm",
        100.0 * cv,
        1e3 * mean(&depths),
        1e3 * sd(&depths)
    );
    assert!((2.0..=2.6).contains(&m), "{m}");
    assert!((0.10..=0.35).contains(&cv), "{cv}");
    assert!((14e-3..=19e-3).contains(&mean(&depths)));
    assert!((0.3e-3..=3.5e-3).contains(&sd(&depths)));
}

#[test]
fn truth_events_sit_on_the_force() {
    let vessels = apart::vessel_liver(6, SEED);
    let all = diagnosis_trials()
        .iter()
        .flat_map(|(c, t)| t.iter().map(move |tr| (c.noise_n, tr)))
        .chain(phantoms().iter().map(|tr| (0.012, tr)))
        .chain(vessels.iter().map(|tr| (0.004, tr)));
    let mut n_sharp = 0;
    for (noise_n, tr) in all {
        let contact = events(tr, "contact");
        assert_eq!(contact.len(), 1, "{}", tr.case);
        assert_eq!(events(tr, "exit").len(), 1, "{}", tr.case);
        let exit = events(tr, "exit")[0];
        assert!(exit.x_m <= contact[0].x_m + 1e-12);
        assert!(!events(tr, "puncture").is_empty(), "{}", tr.case);
        for e in tr
            .events
            .iter()
            .filter(|e| e.kind == "puncture" || e.kind == "structure")
        {
            assert!(e.peak_t_s <= e.t_s);
            if e.t_s > e.peak_t_s {
                let (pk, fallen) = fall(tr, e);
                let margin = (6.0 * noise_n).max(0.04);
                assert!(
                    fallen < pk - margin,
                    "{} {} at {}: {pk} -> {fallen}",
                    tr.case,
                    e.kind,
                    e.t_s
                );
                n_sharp += 1;
            }
        }
    }
    assert!(n_sharp > 100);
}

#[test]
fn vessels_ride_on_the_friction_and_rupture() {
    let trials = apart::vessel_liver(8, SEED + 2);
    for tr in &trials {
        let s = events(tr, "structure");
        assert!((1..=5).contains(&s.len()), "{} structures", s.len());
        let p = events(tr, "puncture")[0];
        for e in s {
            assert!(e.t_s > p.t_s);
            let (pk, fallen) = fall(tr, e);
            assert!(
                (0.05..=0.7).contains(&(pk - fallen)),
                "drop {}",
                pk - fallen
            );
        }
    }
    let total: usize = trials.iter().map(|t| events(t, "structure").len()).sum();
    assert!(total >= 2 * trials.len(), "{total}");
}

#[test]
fn withdrawal_drags_the_tissue_and_lets_go_before_the_surface() {
    let idw = diagnosis_trials()
        .iter()
        .filter(|(c, _)| {
            c.protocol == Protocol::InsertDwellWithdraw
                && (c.effects.is_empty() || c.name.contains("realistic"))
        })
        .flat_map(|(c, t)| t.iter().map(move |tr| (c.noise_n, tr)))
        .chain(phantoms().iter().map(|tr| (0.012, tr)));
    for (noise_n, tr) in idw {
        let (zero_at, pull) = withdrawal_shape(tr, noise_n);
        assert!(
            (1.0e-3..=10.5e-3).contains(&zero_at),
            "{}: zero {zero_at} past contact",
            tr.case
        );
        assert!((-2.4..=-0.6).contains(&pull), "{}: pull {pull}", tr.case);
    }
}

#[test]
fn phantoms_have_the_measured_punctures() {
    let mut by_kind: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut fallen_by_kind: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for tr in phantoms() {
        let p = events(tr, "puncture");
        assert_eq!(p.len(), 1, "{}", tr.case);
        let (pk, fallen) = fall(tr, p[0]);
        // The truth's peak is the maximum of the loading (to the noise).
        let k_c = index_at(tr, events(tr, "contact")[0].t_s);
        let k_p = index_at(tr, p[0].t_s);
        let max = tr.f_n[k_c..=k_p].iter().copied().fold(f64::MIN, f64::max);
        assert!(max <= pk + 0.1, "{}: max {max} vs peak {pk}", tr.case);
        let sharp = events(tr, "structure").len() + usize::from(p[0].t_s > p[0].peak_t_s);
        assert!(sharp <= 3);
        if tr.case.ends_with("artery") {
            assert_eq!(p[0].t_s, p[0].peak_t_s);
        } else {
            let r = fallen / pk;
            assert!((0.15..=0.5).contains(&r), "{}: falls to {r}", tr.case);
            let ease = k_p - index_at(tr, p[0].peak_t_s);
            assert!(
                (1..=25).contains(&ease),
                "{}: eases {ease} samples",
                tr.case
            );
            // It climbs again within 3 mm, and ends the insertion at
            // 0.7–2.7× (plus a little friction) the fallen force.
            let x_fall = tr.x_m[k_p];
            let climbed = (k_p..tr.x_m.len())
                .take_while(|&k| tr.x_m[k] < x_fall + 3e-3)
                .map(|k| tr.f_n[k])
                .fold(f64::MIN, f64::max);
            let climb = climbed / fallen;
            assert!((1.1..=3.5).contains(&climb), "{}: climbs {climb}", tr.case);
            let (a, _) = dwell(tr);
            let end = tr.f_n[a - 1] / fallen;
            assert!((0.6..=3.2).contains(&end), "{}: ends at {end}", tr.case);
            fallen_by_kind
                .entry(tr.case.clone())
                .or_default()
                .push(fallen);
        }
        by_kind.entry(tr.case.clone()).or_default().push(pk);
    }
    for (kind, peaks) in &by_kind {
        let (m, cv) = (mean(peaks), sd(peaks) / mean(peaks));
        eprintln!(
            "{kind}: {m:.2} N CV {:.1} % ({} trials)",
            100.0 * cv,
            peaks.len()
        );
        let target = if kind.ends_with("skin") {
            4.8
        } else if kind.ends_with("muscle") {
            5.2
        } else {
            1.9
        };
        assert!((m - target).abs() < 0.12 * target, "{kind}: {m}");
        assert!((0.03..=0.2).contains(&cv), "{kind}: {cv}");
    }
    for (kind, f) in &fallen_by_kind {
        let cv = sd(f) / mean(f);
        assert!((0.05..=0.25).contains(&cv), "{kind}: post-puncture CV {cv}");
    }
}

/// RMS of (trial − its effect-free twin) over the trial, in noise floors:
/// the twin shares every draw, noise included, so the difference is the
/// effect alone.
#[test]
fn effects_stand_above_the_noise() {
    let mut lines = Vec::new();
    let mut faint = Vec::new();
    for c in cases().iter().filter(|c| !c.effects.is_empty()) {
        let with = &apart::generate(c, 1, SEED)[0];
        let without = &apart::generate(&apart::without_effect(c), 1, SEED)[0];
        assert_eq!(with.t_s, without.t_s);
        let rms = (with
            .f_n
            .iter()
            .zip(&without.f_n)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / with.f_n.len() as f64)
            .sqrt();
        let floors = rms / c.noise_n;
        lines.push(format!("{:45} {floors:8.1} noise floors", c.name));
        // Effects that need velocity changes or reversals barely show in
        // a constant-speed insert-dwell-withdraw trial (see apart/README.md).
        let weak =
            c.protocol == Protocol::InsertDwellWithdraw && c.name.contains("holder_inertia/rigid");
        if !weak && floors < 2.0 {
            faint.push(c.name.clone());
        }
    }
    eprintln!("{}", lines.join("\n"));
    assert!(faint.is_empty(), "too faint: {faint:?}");
}
