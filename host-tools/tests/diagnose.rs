//! `needle diagnose` on simulated datasets with one effect hidden from it.
//! Only the cases the first cut gets right are asserted here; the README
//! lists the ones it does not get right yet (issue 6 is in progress).

use host_tools::diagnose::{diagnose, load};
use host_tools::sim::{effects, simulate_dataset, Sensor};
use needle_holder::model::params::LIVER1;

fn verdict(effect_list: &str) -> (String, f64) {
    let dir = tempfile::tempdir().unwrap();
    let sensor = Sensor {
        rate_hz: 500.0,
        noise_n: 0.005,
        encoder_m: 1e-6,
    };
    let list = effects::parse_list(effect_list).unwrap();
    simulate_dataset(dir.path(), "liver1", &LIVER1, &list, 10, 7, &sensor).unwrap();
    let (_, data) = load(dir.path(), None).unwrap();
    let out = diagnose(&data);
    let v = &out["verdict"];
    (
        v["effect"].as_str().unwrap().to_owned(),
        v["shrink"].as_f64().unwrap(),
    )
}

#[test]
fn no_effect_is_named_when_there_is_none() {
    assert_eq!(verdict("").0, "none");
}

#[test]
fn drift_walls_and_depth_dependent_cutting_are_named_with_a_real_shrink() {
    for effect in [
        "sensor_drift",
        "internal_structures",
        "depth_dependent_cutting",
    ] {
        let (named, shrink) = verdict(effect);
        assert_eq!(named, effect);
        assert!(shrink > 0.2, "{effect}: shrink {shrink}");
    }
}
