//! `needle decode` as a user runs it.

use std::process::Command;

use needle_analysis::sim::{self, Plan};
use needle_holder::config::DeviceConfig;
use needle_holder::model::params::LIVER1;
use needle_io::twin;
use rand::{RngCore, SeedableRng};

use crate::common;
use common::run as needle;

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
    let back = needle_io::trial::read(&csv_path).unwrap();
    assert_eq!(back.len(), trial.len());
    for i in 0..trial.len() {
        assert!((back.t_s[i] - trial.t_s[i]).abs() < 1e-9);
        assert!((back.x_m[i] - trial.x_m[i]).abs() <= 0.5e-6, "x at {i}");
        assert!((back.f_n[i] - trial.f_n[i]).abs() <= 2e-6, "f at {i}");
    }
}

#[test]
fn a_missing_file_is_a_clear_error() {
    let out = needle(&["decode", "/nonexistent/capture.bin"]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("/nonexistent/capture.bin: cannot read"),
        "{stderr}"
    );
}

#[test]
fn a_second_decode_to_one_csv_is_refused_naming_the_first() {
    // Two decodes into one --csv interleaved their rows (time going
    // backwards) and one's segment list named the other's segments.
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("capture.fifo");
    let fifo_c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: mkfifo(3) on a path we own.
    assert_eq!(unsafe { libc::mkfifo(fifo_c.as_ptr(), 0o600) }, 0);
    let csv = dir.path().join("out.csv");
    // The first waits on a pipe no one writes yet, holding its output.
    let mut first = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args([
            "decode".as_ref(),
            fifo.as_os_str(),
            "--csv".as_ref(),
            csv.as_os_str(),
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let lock = dir.path().join(".out.csv.lock");
    let until = std::time::Instant::now() + std::time::Duration::from_secs(30);
    while !std::fs::read_to_string(&lock).is_ok_and(|s| s.contains("pid")) {
        assert!(
            std::time::Instant::now() < until,
            "the first decode never took its lock"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let second = needle(&[
        "decode".as_ref(),
        dir.path().join("other.bin").as_os_str(),
        "--csv".as_ref(),
        csv.as_os_str(),
    ]);
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{err}");
    let holder = format!("needle decode (pid {}) is writing it", first.id());
    assert!(err.contains(&holder), "{err}");
    first.kill().unwrap();
    first.wait().unwrap();
}
