//! `cargo xtask`'s tasks run as a developer runs them: each image built
//! and sized, and an image run in QEMU on a replay leaves the device's
//! frames where it says.

use std::process::Command;

use needle_analysis::sim::{self, Plan};
use needle_holder::model::params::LIVER1;
use needle_io::frames::{decode_all, Item, Message};

fn xtask(args: &[&str]) -> (String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(args)
        .output()
        .expect("xtask runs");
    let stdout = String::from_utf8(out.stdout).unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(out.status.success(), "xtask {args:?}: {stderr}");
    (stdout, stderr)
}

#[test]
fn size_builds_every_image_and_names_its_file_flash_and_ram() {
    let (stdout, _) = xtask(&["size"]);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 5, "{stdout}");
    for line in lines {
        let flash: u64 = line
            .split(": ")
            .nth(1)
            .and_then(|rest| rest.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no flash figure in {line:?}"));
        assert!((8_000..128_000).contains(&flash), "{line}");
        let path = line.rsplit("  ").next().unwrap();
        assert!(std::path::Path::new(path).is_file(), "{line}");
    }
}

#[test]
fn qemu_runs_an_image_on_a_replay_and_leaves_its_frames_in_the_file_named() {
    let dir = tempfile::tempdir().unwrap();
    let (trial, _, bytes) = sim::insertion_replay(&LIVER1, &Plan::PAPER);
    let replay = dir.path().join("liver1.replay");
    std::fs::write(&replay, bytes).unwrap();
    let out = dir.path().join("frames.bin");
    let (stdout, _) = xtask(&[
        "qemu",
        "lm3s6965",
        replay.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let bytes = std::fs::read(&out).unwrap();
    assert!(
        stdout.contains(&format!("{} bytes", bytes.len())),
        "{stdout}"
    );
    let (items, stats) = decode_all(&bytes).unwrap();
    assert!(matches!(
        items.first(),
        Some(Item::Frame(Message::Header(_)))
    ));
    assert_eq!(stats.samples as usize, trial.len());
    assert_eq!(stats.gaps, 0);
}
