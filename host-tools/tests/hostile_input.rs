//! Issue 20's rows, one test each as they are fixed: bad arguments get a
//! clear message and a non-zero exit, never silence.

use std::process::Command;

fn needle(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(args)
        .output()
        .expect("run needle")
}

#[test]
fn diagnose_rejects_an_unknown_tissue() {
    // Row 9: `needle diagnose DIR --tissue nope` was accepted and ignored.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let sim = needle(&["simulate", "--out", d, "--trials", "2", "--seed", "1"]);
    assert!(sim.status.success());
    let out = needle(&["diagnose", d, "--tissue", "nope"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope"), "{err}");
}
