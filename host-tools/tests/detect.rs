//! The device's detectors over simulated trials, scored against the
//! simulator's truth with `needle detect`'s own evaluation.

use host_tools::detect::detect_dataset;
use host_tools::sim::{effects, simulate_dataset, Sensor};
use needle_holder::config::DeviceConfig;
use needle_holder::model::params::LIVER1;
use serde_json::Value;

fn evaluate(rate_hz: f64, noise_n: f64, effect_list: &str, trials: usize, seed: u64) -> Vec<Value> {
    let dir = tempfile::tempdir().unwrap();
    let sensor = Sensor {
        rate_hz,
        noise_n,
        encoder_m: 1e-6,
    };
    let effects = effects::parse_list(effect_list).unwrap();
    simulate_dataset(
        dir.path(),
        "liver1",
        &LIVER1,
        &effects,
        trials,
        seed,
        &sensor,
        false,
    )
    .unwrap();
    let out = detect_dataset(dir.path(), &DeviceConfig::default()).unwrap();
    out["evaluation"].as_array().unwrap().clone()
}

fn kind<'a>(eval: &'a [Value], name: &str) -> &'a Value {
    eval.iter().find(|k| k["kind"] == name).unwrap()
}

#[test]
fn puncture_is_flagged_within_2_samples_with_no_miss_or_false_alarm() {
    for rate in [500.0, 2000.0] {
        let eval = evaluate(rate, 0.005, "internal_structures", 20, 31);
        let p = kind(&eval, "puncture");
        assert_eq!(
            (
                p["true_events"].as_u64(),
                p["misses"].as_u64(),
                p["false_alarms"].as_u64()
            ),
            (Some(20), Some(0), Some(0)),
            "{p}"
        );
        assert!(p["latency_samples_max"].as_f64().unwrap() <= 2.0, "{p}");
        assert!(p["latency_samples_max"].as_f64().unwrap() >= 0.0, "{p}");
    }
}

#[test]
fn vessel_walls_are_found_without_false_alarms_at_5_mn() {
    let eval = evaluate(500.0, 0.005, "internal_structures", 20, 32);
    let s = kind(&eval, "structure");
    let (truth, misses) = (
        s["true_events"].as_u64().unwrap(),
        s["misses"].as_u64().unwrap(),
    );
    assert!(truth >= 20, "{s}");
    assert!(
        (truth - misses) as f64 >= 0.9 * truth as f64,
        "recall below 90 %: {s}"
    );
    assert_eq!(s["false_alarms"].as_u64(), Some(0), "{s}");
}
