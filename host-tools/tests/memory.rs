//! Peak memory of `needle` on huge inputs, in a test
//! binary of its own: a child's peak as wait4 reports it includes the
//! memory of the process it was spawned from, so no other test may run
//! (and grow this process) beside these.

use std::process::Command;

mod common;
use common::run as needle;

/// Run needle with `args`: whether it exited 0, its own peak resident
/// memory in kB (wait4, which reaps it — not the largest of the suite's),
/// and its stderr. Stdout is dropped.
#[allow(clippy::zombie_processes)] // reaped by wait4, which clippy does not know
fn peak_memory(args: &[&str]) -> (bool, i64, String) {
    let log = tempfile::NamedTempFile::new().unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(log.reopen().unwrap())
        .spawn()
        .unwrap();
    // SAFETY: wait4 on our own child's pid fills the status and usage.
    let (status, peak_kb) = unsafe {
        let mut status = 0;
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::wait4(child.id() as i32, &mut status, 0, &mut usage);
        (status, usage.ru_maxrss)
    };
    let ok = libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0;
    (ok, peak_kb, std::fs::read_to_string(log.path()).unwrap())
}

#[test]
fn decode_reads_a_capture_in_bounded_memory() {
    // A capture was read whole into memory. 64 MB of
    // line noise (a zero every 100 kB) now pass through 64 kB blocks, and
    // are then refused as no capture.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("noise.bin");
    let mut chunk = vec![0x55u8; 100_000];
    chunk[99_999] = 0;
    // Written a chunk at a time: a child's peak counts the parent's pages
    // it was forked with.
    let mut file = std::fs::File::create(&path).unwrap();
    for _ in 0..671 {
        std::io::Write::write_all(&mut file, &chunk).unwrap();
    }
    drop(file);
    let (ok, peak_kb, err) = peak_memory(&["decode", path.to_str().unwrap()]);
    assert!(!ok, "{err}");
    assert!(err.contains("67100000 bytes skipped"), "{err}");
    assert!(
        err.contains("no frame of the device's in 67100000 bytes"),
        "{err}"
    );
    // Reading the capture whole would take 64 MB.
    assert!(peak_kb < 48 * 1024, "peak resident {peak_kb} kB");
}

#[test]
fn fit_and_diagnose_read_a_huge_trial_in_bounded_memory_and_say_so() {
    // A trial at 65 535 Hz beside two at
    // 500 Hz. Read whole, 2.3 M rows took `diagnose` 199 s and 900 MB
    // (fit: 290 MB). Now read in one pass, thinned as it streams to the
    // device's top rate (2 kHz), with a note saying so.
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let big = dir.path().join("big");
    let run = |args: &[&str]| assert!(needle(args).status.success(), "needle {args:?}");
    run(&["simulate", "--out", data.to_str().unwrap(), "--trials", "2"]);
    run(&[
        "simulate",
        "--out",
        big.to_str().unwrap(),
        "--trials",
        "1",
        "--seed",
        "5",
        "--rate-hz",
        "65535",
        "--protocol",
        "insert-dwell-withdraw",
    ]);
    let huge = data.join("trial_huge.csv");
    std::fs::rename(big.join("trial_000.csv"), &huge).unwrap();
    assert!(std::fs::metadata(&huge).unwrap().len() > 60_000_000);
    for command in ["fit", "diagnose"] {
        let json = dir.path().join(format!("{command}.json"));
        let (ok, peak_kb, err) = peak_memory(&[
            command,
            data.to_str().unwrap(),
            "--json",
            json.to_str().unwrap(),
        ]);
        assert!(ok, "{command}: {err}");
        // 65 535 Hz to at most 2 kHz: 65 535 / 2 000 = 32.8, so 1 in 33
        // (1 986 Hz), however the times were rounded when written.
        assert!(
            err.contains("trial_huge.csv: 2284662 rows, thinned to 1 in 33 "),
            "{command}: {err}"
        );
        // Reading it whole took 290 MB (fit) and 900 MB (diagnose).
        assert!(peak_kb < 96 * 1024, "{command}: peak resident {peak_kb} kB");
        let out: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(out["trials"], 3, "{command}: {out}");
        assert!(out["skipped"].as_array().unwrap().is_empty(), "{out}");
    }
}
