//! `needle decode` as a user runs it.

use std::process::Command;

use host_tools::sim::{self, Plan};
use host_tools::twin;
use needle_holder::config::DeviceConfig;
use needle_holder::model::params::LIVER1;
use rand::{RngCore, SeedableRng};

fn needle(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn random_bytes_are_reported_as_skipped_and_refused_never_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    for round in 0..20 {
        let mut bytes = vec![0u8; 1 + (rng.next_u32() % 20_000) as usize];
        rng.fill_bytes(&mut bytes);
        let path = dir.path().join(format!("noise{round}.bin"));
        std::fs::write(&path, &bytes).unwrap();
        let out = needle(&["decode".as_ref(), path.as_os_str()]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        // Refused as no capture (exit 1), never a panic (101).
        assert_eq!(out.status.code(), Some(1), "round {round}: {stderr}");
        assert!(stderr.contains("bytes skipped"), "round {round}: {stderr}");
        assert!(
            stderr.contains("no frame of the device's"),
            "round {round}: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "round {round}: {stderr}");
    }
}

#[test]
fn capture_to_trial_csv_round_trips_the_simulated_trial() {
    let plan = Plan {
        noise_n: 0.0,
        ..Plan::PAPER
    };
    let (trial, _) = sim::insertion(&LIVER1, &plan);
    let config = DeviceConfig::default();
    let replay = sim::to_replay(&trial, 500, &config.load_cell, &config.encoder);
    let capture = twin::run(&replay).frames;
    let dir = tempfile::tempdir().unwrap();
    let cap_path = dir.path().join("capture.bin");
    let csv_path = dir.path().join("trial.csv");
    std::fs::write(&cap_path, &capture).unwrap();
    let out = needle(&[
        "decode".as_ref(),
        cap_path.as_os_str(),
        "--csv".as_ref(),
        csv_path.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let back = host_tools::trial::read(&csv_path).unwrap();
    assert_eq!(back.len(), trial.len());
    for i in 0..trial.len() {
        assert!((back.t_s[i] - trial.t_s[i]).abs() < 1e-9);
        assert!((back.x_m[i] - trial.x_m[i]).abs() <= 0.5e-6, "x at {i}");
        assert!((back.f_n[i] - trial.f_n[i]).abs() <= 2e-6, "f at {i}");
    }
}

#[test]
fn a_missing_file_is_a_clear_error() {
    let out = needle(&["decode".as_ref(), "/nonexistent/capture.bin".as_ref()]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("/nonexistent/capture.bin: cannot read"),
        "{stderr}"
    );
}
