//! A fresh machine may have the pinned toolchain without the thumb targets
//! (rustup applies rust-toolchain.toml's `targets` only when it installs the
//! toolchain itself). Every firmware build asks rustup first and adds a
//! missing target. These tests drive that step through a stand-in rustup
//! that records its calls, so nothing is removed from the real toolchain.

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

use needle_qemu::firmware::{ensure_target_using, target_action, TargetAction};

/// One test at a time writes and runs its script: a script written by one
/// thread while another forks a child is open for writing in that child
/// until it execs, and running the script then fails with "text file
/// busy" (seen once on a fresh machine).
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// A shell script standing in for rustup: lists `installed` for
/// `target list --installed`, appends every call to `log`, and fails
/// `target add` when `add_fails`.
fn fake_rustup(dir: &Path, installed: &[&str], add_fails: bool) -> (PathBuf, PathBuf) {
    let log = dir.join("calls.log");
    let script = dir.join("rustup");
    let list = installed.join("\n");
    let add_exit = if add_fails { 1 } else { 0 };
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\necho \"$*\" >> '{log}'\nif [ \"$1 $2\" = \"target list\" ]; then printf '%s\\n' '{list}'; exit 0; fi\nif [ \"$1 $2\" = \"target add\" ]; then exit {add_exit}; fi\nexit 2\n",
            log = log.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    (script, log)
}

fn calls(log: &Path) -> Vec<String> {
    std::fs::read_to_string(log)
        .unwrap_or_default()
        .lines()
        .map(str::to_owned)
        .collect()
}

#[test]
fn decision_reads_rustups_list() {
    let list = "x86_64-unknown-linux-gnu\nthumbv7m-none-eabi\n";
    assert_eq!(
        target_action(list, "thumbv7m-none-eabi"),
        TargetAction::Present
    );
    assert_eq!(
        target_action(list, "thumbv6m-none-eabi"),
        TargetAction::Install
    );
    // A prefix of an installed triple is not the triple.
    assert_eq!(target_action(list, "thumbv7m"), TargetAction::Install);
    assert_eq!(
        target_action("", "thumbv7m-none-eabi"),
        TargetAction::Install
    );
}

#[test]
fn missing_target_is_added() {
    let _one = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (rustup, log) = fake_rustup(dir.path(), &["x86_64-unknown-linux-gnu"], false);
    ensure_target_using(&rustup, dir.path(), "thumbv7m-none-eabi").unwrap();
    assert_eq!(
        calls(&log),
        ["target list --installed", "target add thumbv7m-none-eabi"]
    );
}

#[test]
fn present_target_is_left_alone() {
    let _one = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (rustup, log) = fake_rustup(
        dir.path(),
        &["x86_64-unknown-linux-gnu", "thumbv7em-none-eabihf"],
        false,
    );
    ensure_target_using(&rustup, dir.path(), "thumbv7em-none-eabihf").unwrap();
    assert_eq!(calls(&log), ["target list --installed"]);
}

#[test]
fn failed_install_names_the_command() {
    let _one = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (rustup, _) = fake_rustup(dir.path(), &[], true);
    let err = ensure_target_using(&rustup, dir.path(), "thumbv6m-none-eabi").unwrap_err();
    assert!(
        err.to_string()
            .contains("rustup target add thumbv6m-none-eabi"),
        "{err}"
    );
}
