//! Hostile use, one test for each way found: bad arguments get a
//! clear message and a non-zero exit, never silence.

use crate::library;

use library::liver1_entry;
use std::process::Command;

use crate::common;
use common::run as needle;

/// A fresh directory with `trials` simulated trials from `seed`.
fn simulated(trials: u32, seed: u32) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let (t, s) = (trials.to_string(), seed.to_string());
    let d = dir.path().to_str().unwrap();
    let out = needle(&["simulate", "--out", d, "--trials", &t, "--seed", &s]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir
}

/// Run needle with `args`, which must fail: its stderr.
fn refused(args: &[&str]) -> String {
    let out = needle(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "needle {args:?} succeeded: {err}");
    err
}

#[test]
fn diagnose_rejects_an_unknown_tissue() {
    // `needle diagnose DIR --tissue nope` was accepted and ignored.
    let dir = simulated(2, 1);
    let d = dir.path().to_str().unwrap();
    let err = refused(&["diagnose", d, "--tissue", "nope"]);
    assert!(err.contains("nope"), "{err}");
}

#[test]
fn decode_rejects_seconds_that_are_not_a_duration() {
    // `--seconds inf` (or 1e30) panicked converting to a Duration;
    // -1, NaN and 0 read nothing and exited 0. Checked before the port is
    // opened, so /dev/null stands in for one.
    for bad in ["inf", "1e30", "-1", "NaN", "0"] {
        let seconds = format!("--seconds={bad}");
        let err = refused(&["decode", "--port", "/dev/null", &seconds]);
        assert!(err.contains("--seconds"), "--seconds {bad}: {err}");
        assert!(!err.contains("panicked"), "--seconds {bad}: {err}");
    }
}

#[test]
fn decode_never_writes_over_the_capture_it_reads() {
    // `needle decode same.bin --csv same.bin` emptied the capture
    // before reading it, printed 0 frames and exited 0.
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("same.bin");
    std::fs::write(&capture, b"\x01\x02\x00some bytes\x00").unwrap();
    let before = std::fs::read(&capture).unwrap();
    let path = capture.to_str().unwrap();
    let link = dir.path().join("link.bin");
    std::os::unix::fs::symlink(&capture, &link).unwrap();
    for csv in [path, link.to_str().unwrap()] {
        let err = refused(&["decode", path, "--csv", csv]);
        assert!(err.contains("capture"), "{err}");
        assert_eq!(
            std::fs::read(&capture).unwrap(),
            before,
            "the capture changed"
        );
    }
}

#[test]
fn decode_rejects_a_zero_sample_rate() {
    // `--rate-hz 0` wrote `inf` for every t_s and exited 0.
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("cap.bin");
    std::fs::write(&capture, b"").unwrap();
    let csv = dir.path().join("o.csv");
    let err = refused(&[
        "decode",
        capture.to_str().unwrap(),
        "--rate-hz",
        "0",
        "--csv",
        csv.to_str().unwrap(),
    ]);
    assert!(err.contains("--rate-hz"), "{err}");
    assert!(!csv.exists(), "no CSV is written for a refused command");
}

#[test]
fn a_full_disk_on_stdout_is_an_error_and_a_closed_pipe_a_quiet_end() {
    // `needle fit DIR > /dev/full` panicked "failed printing to
    // stdout" (exit 101), and so did `needle evaluate … | head -1`.
    let dir = simulated(2, 1);
    let d = dir.path().to_str().unwrap();
    for args in [vec!["fit", d], vec!["detect", d]] {
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_needle"))
            .args(&args)
            .stdout(full)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("standard output"), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    // The reader goes after the table's header line.
    let mut child = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args([
            "evaluate",
            "--trials",
            "1",
            "--rates-hz",
            "500",
            "--noise-n",
            "0.002",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = child.stdout.take().unwrap();
    let mut first = [0u8; 8];
    std::io::Read::read_exact(&mut stdout, &mut first).unwrap();
    drop(stdout);
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn evaluate_rejects_rates_and_noises_it_cannot_simulate() {
    // --rates-hz 1e9 grew to 24 GB; -500, 10 and 99.5 were
    // accepted (99.5 silently as 100 Hz); 0 failed naming a temp file;
    // --noise-n -1 and NaN labelled tables "-1000 mN" and "NaN mN".
    for (flag, bad) in [
        ("--rates-hz", "1e9"),
        ("--rates-hz", "-500"),
        ("--rates-hz", "10"),
        ("--rates-hz", "99.5"),
        ("--rates-hz", "0"),
        ("--noise-n", "-1"),
        ("--noise-n", "NaN"),
        // 1e308 N of noise wrote `inf` into the trials, and the error
        // named a temp file after the work had begun.
        ("--noise-n", "1e308"),
    ] {
        let arg = format!("{flag}={bad}");
        let out = needle(&["evaluate", "--trials", "1", &arg]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{arg} accepted");
        assert!(err.contains(flag), "{arg}: {err}");
        assert!(out.stdout.is_empty(), "{arg}: a table was started");
    }
    // simulate holds the same line, and bounds effects and the tare.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    refused(&["simulate", "--out", d, "--rate-hz", "99.5"]);
    for (flag, bad, says) in [
        ("--noise-n", "1e308", "--noise-n 1e308"),
        ("--tare-n", "11", "--tare-n 11"),
        ("--effects", "tissue_motion=1e300", "strength 1e300"),
        ("--tear-mm", "NaN", "--tear-mm NaN"),
        ("--tear-mm", "7", "--tear-mm 7"),
        ("--accel-mps2", "NaN", "--accel-mps2 NaN"),
        ("--accel-mps2", "20", "--accel-mps2 20"),
        ("--accel-mps2", "0.001", "--accel-mps2 0.001"),
    ] {
        let err = refused(&["simulate", "--out", d, "--trials", "1", flag, bad]);
        assert!(err.contains(says), "{flag} {bad}: {err}");
    }
    // Zero trials wrote a truth.json of none over the last simulation.
    let err = refused(&["simulate", "--out", d, "--trials", "0"]);
    assert!(err.contains("--trials 0"), "{err}");
    // The JSON's path is checked before the evaluation, not after it.
    let err = refused(&[
        "evaluate",
        "--trials",
        "1",
        "--json",
        "/nonexistent-dir/x.json",
    ]);
    assert!(
        err.contains("/nonexistent-dir/x.json: cannot write: no directory"),
        "{err}"
    );
}

#[test]
fn no_command_writes_over_its_input_or_one_output_over_another() {
    // `fit d --json d/trial_000.csv` emptied the trial it fitted; `detect
    // d --json d/truth.json` replaced the truth it then scored a perfect
    // run against; `diagnose --report r.svg` wrote its HTML over its
    // figure, `--residuals r.svg` the figure over the residuals.
    let dir = simulated(2, 3);
    let d = dir.path().to_str().unwrap();
    let trial = dir.path().join("trial_000.csv");
    let truth = dir.path().join("truth.json");
    let before = (
        std::fs::read(&trial).unwrap(),
        std::fs::read(&truth).unwrap(),
    );
    let (t, j) = (trial.to_str().unwrap(), truth.to_str().unwrap());
    for args in [
        &["fit", d, "--json", t][..],
        &["fit", d, "--toml", t],
        &["fit", d, "--plot", j],
        &["detect", d, "--json", j],
        &["diagnose", d, "--residuals", t],
        &["diagnose", d, "--json", j],
    ] {
        let err = refused(args);
        assert!(err.contains("names an input"), "{args:?}: {err}");
    }
    assert_eq!(
        before,
        (
            std::fs::read(&trial).unwrap(),
            std::fs::read(&truth).unwrap()
        )
    );
    let out = tempfile::tempdir().unwrap();
    let at = |name: &str| out.path().join(name).to_str().unwrap().to_owned();
    let err = refused(&["diagnose", d, "--report", &at("r.svg")]);
    assert!(err.contains("name the same file"), "{err}");
    let err = refused(&[
        "diagnose",
        d,
        "--report",
        &at("r.html"),
        "--residuals",
        &at("r.svg"),
    ]);
    assert!(err.contains("name the same file"), "{err}");
    let err = refused(&["fit", d, "--json", &at("f"), "--toml", &at("f")]);
    assert!(
        err.contains("--toml and --json name the same file"),
        "{err}"
    );
}

#[test]
fn a_truth_json_that_says_what_cannot_be_scored_is_refused_by_line() {
    // An event of an unknown kind, or without a time, was dropped without
    // a word and the detection that found it scored as a false alarm.
    let dir = simulated(1, 3);
    let d = dir.path().to_str().unwrap();
    let path = dir.path().join("truth.json");
    let good = std::fs::read_to_string(&path).unwrap();
    for (from, to, says) in [
        (
            "\"kind\": \"contact\"",
            "\"kind\": \"explode\"",
            "unknown variant `explode`",
        ),
        ("\"t_s\":", "\"time\":", "missing field `t_s`"),
    ] {
        assert!(good.contains(from), "{from} not in truth.json");
        std::fs::write(&path, good.replacen(from, to, 1)).unwrap();
        let err = refused(&["detect", d]);
        assert!(
            err.contains(&format!("{}:", path.display())) && err.contains(says),
            "{err}"
        );
    }
}

#[test]
fn a_tissue_past_the_devices_fixed_point_is_refused_naming_its_key() {
    // a1 = 40 000 N/m saturated to 32 000 on the device and in `detect`
    // (the same output as 32 000 and 1e300), while `simulate` used it as
    // given; a string in place of a number named neither key nor line.
    let dir = tempfile::tempdir().unwrap();
    let liver1 = liver1_entry();
    for (value, says) in [
        ("40000.0", "is not within the device's ±32 000 N/m"),
        ("\"abc\"", "must be a number, not string"),
    ] {
        let text: String = liver1
            .lines()
            .map(|l| {
                if l.starts_with("a1_n_per_m =") {
                    format!("a1_n_per_m = {value}")
                } else {
                    l.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("\n");
        let line = text
            .lines()
            .position(|l| l.starts_with("a1_n_per_m"))
            .unwrap()
            + 1;
        let toml = dir.path().join("t.toml");
        std::fs::write(&toml, text).unwrap();
        let out = tempfile::tempdir().unwrap();
        let err = refused(&[
            "simulate",
            "--out",
            out.path().to_str().unwrap(),
            "--params",
            toml.to_str().unwrap(),
        ]);
        assert!(
            err.contains(&format!("t.toml:{line}:"))
                && err.contains("a1_n_per_m")
                && err.contains(says),
            "{err}"
        );
    }
}

#[test]
fn a_csv_with_a_line_without_end_is_left_out_in_bounded_memory_and_quoted_short() {
    // A 1 GB line took 3 GB to read; a 10 MB field was echoed whole to
    // stderr and into the JSON.
    let dir = simulated(2, 3);
    let d = dir.path().to_str().unwrap();
    let long = format!("t_s,x_m,f_n\n0,0,0\n1,0,{}\n", "9".repeat(200_000));
    std::fs::write(dir.path().join("long.csv"), long).unwrap();
    let wide = format!("t_s,x_m,f_n\n0,0,0\n1,0,{}\n", "x".repeat(60_000));
    std::fs::write(dir.path().join("wide.csv"), wide).unwrap();
    // Lines ended by a bare CR (old exporters) are lines, not one long one.
    let trial = std::fs::read_to_string(dir.path().join("trial_000.csv")).unwrap();
    std::fs::write(dir.path().join("cr.csv"), trial.replace('\n', "\r")).unwrap();
    let out = needle(&["detect", d]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("long.csv:3: a line longer than 65536 bytes"),
        "{err}"
    );
    assert!(
        err.contains("wide.csv:3: `f_n` is not a number: \"xxxxxxxx"),
        "{err}"
    );
    assert!(!err.contains("cr.csv:"), "{err}");
    assert!(err.len() < 4000, "{} bytes on stderr", err.len());
    assert!(
        out.stdout.len() < 100_000,
        "the JSON quotes the field whole"
    );
}

#[test]
fn a_second_simulation_replaces_the_first_and_never_deletes_real_trials() {
    // Five trials, then two at another seed into the same
    // directory: the three stale ones stayed and `fit` mixed two seeds.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    assert!(needle(&["simulate", "--out", d, "--trials", "5"])
        .status
        .success());
    assert!(
        needle(&["simulate", "--out", d, "--trials", "2", "--seed", "9"])
            .status
            .success()
    );
    let mut csvs: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".csv"))
        .collect();
    csvs.sort();
    assert_eq!(csvs, ["trial_000.csv", "trial_001.csv"]);
    // A directory of someone's recordings is refused, and left as it was.
    let real = tempfile::tempdir().unwrap();
    std::fs::write(real.path().join("rig_07.csv"), "t_s,x_m,f_n\n0,0,0\n").unwrap();
    let err = refused(&["simulate", "--out", real.path().to_str().unwrap()]);
    assert!(err.contains("rig_07.csv"), "{err}");
    assert_eq!(std::fs::read_dir(real.path()).unwrap().count(), 1);
}

#[test]
fn a_csv_that_is_a_device_is_refused_not_read() {
    // A `.csv` symlink to /dev/zero aborted allocating 4 GiB while
    // reading its header.
    let dir = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink("/dev/zero", dir.path().join("zero.csv")).unwrap();
    for command in ["fit", "detect", "diagnose"] {
        let err = refused(&[command, dir.path().to_str().unwrap()]);
        assert!(
            err.contains("zero.csv") && err.contains("not a regular file"),
            "{command}: {err}"
        );
    }
}

#[test]
fn a_truth_json_or_tissue_library_that_is_a_device_is_refused_not_read() {
    // `truth.json` linked to /dev/zero made `detect`, and
    // `--params /dev/zero` made `simulate`, `fit --params`… read without
    // end, memory growing.
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let data_arg = data.to_str().unwrap();
    assert!(needle(&["simulate", "--out", data_arg, "--trials", "2"])
        .status
        .success());
    let truth = data.join("truth.json");
    std::fs::remove_file(&truth).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &truth).unwrap();
    let err = refused(&["detect", data_arg]);
    assert!(err.contains("truth.json: not a regular file"), "{err}");
    let x = dir.path().join("x");
    let x = x.to_str().unwrap();
    let err = refused(&["simulate", "--params", "/dev/zero", "--out", x]);
    assert!(err.contains("/dev/zero: not a regular file"), "{err}");
    // A library far larger than any is refused by size, unread.
    let huge = dir.path().join("huge.toml");
    std::fs::File::create(&huge)
        .unwrap()
        .set_len(needle_io::input::MOST_TEXT_BYTES + 1)
        .unwrap();
    let err = refused(&["simulate", "--params", huge.to_str().unwrap(), "--out", x]);
    assert!(
        err.contains("huge.toml: 16777217 bytes, more than"),
        "{err}"
    );
}

#[test]
fn a_csv_that_cannot_be_written_is_named() {
    // `needle decode cap.bin --csv /dev/full` failed
    // without saying which file.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    assert!(needle(&["simulate", "--out", d, "--trials", "1"])
        .status
        .success());
    let replay = std::fs::read(dir.path().join("trial_000.replay")).unwrap();
    let capture = dir.path().join("cap.bin");
    std::fs::write(&capture, needle_io::twin::run(&replay).frames).unwrap();
    let err = refused(&["decode", capture.to_str().unwrap(), "--csv", "/dev/full"]);
    assert!(err.contains("/dev/full"), "{err}");
}

#[test]
fn a_capture_of_another_schema_under_this_version_is_refused_naming_both_keys() {
    // A device built with a frame type changed and no new version: its
    // header carries another schema key, and its frames would decode
    // into garbage.
    use needle_holder::protocol::{Frame, FrameEncoder, SCHEMA_KEY};
    let mut other = needle_holder::protocol::header(500);
    other.schema_key = [0xab; 8];
    let mut bytes = FrameEncoder::default()
        .encode(&Frame::Header(other))
        .to_vec();
    bytes.extend(twin_capture(1.0));
    let dir = tempfile::tempdir().unwrap();
    let cap = dir.path().join("other.bin");
    std::fs::write(&cap, bytes).unwrap();
    let err = refused(&["decode", cap.to_str().unwrap()]);
    let ours = needle_io::frames::hex(&SCHEMA_KEY);
    assert!(err.contains("abababababababab"), "{err}");
    assert!(err.contains(&ours), "{err}");
}

/// A capture of the host twin on a simulated liver insertion at 500 Hz.
fn twin_capture(seconds: f64) -> Vec<u8> {
    use needle_analysis::sim::{self, Plan};
    use needle_holder::config::DeviceConfig;
    use needle_holder::model::params::LIVER1;
    let plan = Plan {
        depth_m: seconds * 0.003 - 0.005,
        dwell_s: 0.0,
        ..Plan::PAPER
    };
    let (trial, _) = sim::insertion(&LIVER1, &plan);
    let config = DeviceConfig::default();
    let replay = sim::to_replay(&trial, 500, &config.load_cell, &config.encoder);
    needle_io::twin::run(&replay).frames
}

/// Each CSV's `t_s` column, which must rise from row to row.
fn times(path: &std::path::Path) -> Vec<f64> {
    let text = std::fs::read_to_string(path).unwrap();
    let t: Vec<f64> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert!(
        t.windows(2).all(|w| w[1] > w[0]),
        "{}: time goes back",
        path.display()
    );
    t
}

#[test]
fn decode_splits_at_an_index_that_goes_back_and_never_writes_time_backwards() {
    // A chunk repeated, or two captures joined (a reboot): the index
    // going back was not reported, the jump forward counted as thousands
    // of lost samples, and the CSV's time went backwards.
    let dir = tempfile::tempdir().unwrap();
    let one = twin_capture(12.0);
    // Two captures joined: the device rebooted.
    let joined = dir.path().join("joined.bin");
    std::fs::write(&joined, [one.clone(), one.clone()].concat()).unwrap();
    let csv = dir.path().join("joined.csv");
    let out = needle(&[
        "decode",
        joined.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(text.contains("restart after sample"), "{text}");
    assert!(
        err.contains("0 samples lost") && err.contains("1 restarts"),
        "{err}"
    );
    // As text too: the samples before the restart are a segment of their
    // own (text mode counted none and said the segment had no sample).
    let out = needle(&["decode", joined.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("; segment 2 begins"));
    let (first, second) = (times(&csv), times(&dir.path().join("joined-2.csv")));
    assert_eq!(first.len(), second.len());
    // A stretch of the stream twice (cut at frame boundaries): up to b,
    // a..c again, then on from b — a restart, and the first segment going
    // on where it stopped, with nothing lost.
    let frames: Vec<&[u8]> = one.split_inclusive(|&b| b == 0).collect();
    let (a, c, b) = (frames.len() / 4, frames.len() / 3, frames.len() / 2);
    let repeated: Vec<u8> = frames[..b]
        .iter()
        .chain(&frames[a..c])
        .chain(&frames[b..])
        .flat_map(|f| f.to_vec())
        .collect();
    let rep = dir.path().join("repeated.bin");
    std::fs::write(&rep, repeated).unwrap();
    let csv = dir.path().join("repeated.csv");
    let out = needle(&[
        "decode",
        rep.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("0 samples lost") && err.contains("2 restarts"),
        "{err}"
    );
    let segments = [
        csv.clone(),
        dir.path().join("repeated-2.csv"),
        dir.path().join("repeated-3.csv"),
    ];
    let total: usize = segments.iter().map(|p| times(p).len()).sum();
    assert!(total >= first.len(), "every sample is in some segment");
}

#[test]
fn decode_segments_never_write_over_the_capture_or_stay_stale() {
    let dir = tempfile::tempdir().unwrap();
    let one = twin_capture(6.0);
    let joined = [one.clone(), one.clone()].concat();
    let at = |name: &str| dir.path().join(name);
    let s = |p: &std::path::Path| p.to_str().unwrap().to_owned();
    // A capture named where segment 2 goes: creating the segment emptied
    // the capture half-way through reading it.
    std::fs::write(at("cap-2.csv"), &joined).unwrap();
    let err = refused(&["decode", &s(&at("cap-2.csv")), "--csv", &s(&at("cap.csv"))]);
    assert!(err.contains("would be written over the capture"), "{err}");
    assert_eq!(std::fs::read(at("cap-2.csv")).unwrap(), joined);
    // Three segments, then one capture to the same --csv: the old
    // segment files went on standing beside it, for `fit` to read.
    std::fs::write(
        at("joined.bin"),
        [one.clone(), one.clone(), one.clone()].concat(),
    )
    .unwrap();
    std::fs::write(at("one.bin"), &one).unwrap();
    let out = needle(&["decode", &s(&at("joined.bin")), "--csv", &s(&at("o.csv"))]);
    assert!(out.status.success());
    assert!(at("o-3.csv").exists());
    let out = needle(&["decode", &s(&at("one.bin")), "--csv", &s(&at("o.csv"))]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!at("o-2.csv").exists() && !at("o-3.csv").exists(), "{err}");
    assert!(err.contains("removed") && err.contains("o-2.csv"), "{err}");
    // Another decode's own output named like a segment (`o2.csv` then
    // `o.csv`'s segment 2) was deleted as a stale segment: only the
    // segments a decode listed in `o.csv.segments` go.
    let out = needle(&["decode", &s(&at("one.bin")), "--csv", &s(&at("p-2.csv"))]);
    assert!(out.status.success());
    let other = std::fs::read(at("p-2.csv")).unwrap();
    let err = refused(&["decode", &s(&at("joined.bin")), "--csv", &s(&at("p.csv"))]);
    assert!(
        err.contains("is no segment an earlier decode listed"),
        "{err}"
    );
    // The list is a file anyone can write: one naming what is no segment
    // of `p.csv` (`../x.csv`, `other.csv`) is refused, and nothing removed.
    let outside = dir.path().join("sub");
    std::fs::create_dir(&outside).unwrap();
    std::fs::copy(at("p-2.csv"), at("other.csv")).unwrap();
    std::fs::write(
        at("sub/p.csv.segments"),
        "../other.csv\nother.csv\n/etc/hostname\n",
    )
    .unwrap();
    let err = refused(&[
        "decode",
        &s(&at("one.bin")),
        "--csv",
        &s(&outside.join("p.csv")),
    ]);
    assert!(
        err.contains("p.csv.segments:1: \"../other.csv\" is no segment"),
        "{err}"
    );
    assert!(at("other.csv").exists());
    let out = needle(&["decode", &s(&at("one.bin")), "--csv", &s(&at("p.csv"))]);
    assert!(out.status.success());
    assert_eq!(std::fs::read(at("p-2.csv")).unwrap(), other);
    // Bytes that hold no frame are no capture: an error, not an empty CSV,
    // and the earlier decode's CSV is left as it was.
    let good = std::fs::read(at("o.csv")).unwrap();
    std::fs::write(at("junk.bin"), vec![0x55u8; 3000]).unwrap();
    let err = refused(&["decode", &s(&at("junk.bin")), "--csv", &s(&at("o.csv"))]);
    assert!(err.contains("no frame of the device's"), "{err}");
    assert_eq!(std::fs::read(at("o.csv")).unwrap(), good);
    std::fs::write(
        at("noise.bin"),
        (0..5000u32)
            .map(|i| (i * 7919 % 251) as u8)
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    let err = refused(&["decode", &s(&at("noise.bin")), "--csv", &s(&at("n.csv"))]);
    assert!(err.contains("noise.bin: no frame of the device's"), "{err}");
}

#[test]
fn one_bad_file_among_good_ones_is_left_out_by_every_command_naming_file_and_line() {
    // `fit` skipped a bad CSV, `detect` and `diagnose` stopped at
    // it. One rule now: left out with a warning naming file and line,
    // listed in the JSON's `skipped`, the others analysed.
    let dir = simulated(3, 4);
    let d = dir.path().to_str().unwrap();
    std::fs::write(
        dir.path().join("zz_bad.csv"),
        "t_s,x_m,f_n\n0,0,0\n0.001,0,0\n0.0005,0,0\n",
    )
    .unwrap();
    // A trial whose times are scaled by 1e-308: steps of 1e-310 s made the
    // rate infinite and `fit` and `diagnose` panic on a one-sample trial.
    let good = std::fs::read_to_string(dir.path().join("trial_000.csv")).unwrap();
    let mut lines = good.lines();
    let fast: String = std::iter::once(format!("{}\n", lines.next().unwrap()))
        .chain(lines.map(|l| {
            let (t, rest) = l.split_once(',').unwrap();
            format!("{:e},{rest}\n", t.parse::<f64>().unwrap() * 1e-308)
        }))
        .collect();
    std::fs::write(dir.path().join("zz_fast.csv"), fast).unwrap();
    for command in ["fit", "detect", "diagnose"] {
        let json = dir.path().join(format!("{command}.json"));
        let out = needle(&[command, d, "--json", json.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{command}: {err}");
        assert!(
            err.contains("zz_bad.csv:4: time does not increase"),
            "{command}: {err}"
        );
        let value: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let skipped = value["skipped"]
            .as_array()
            .unwrap_or_else(|| panic!("{command}: no skipped list"));
        for bad in ["zz_bad.csv", "zz_fast.csv"] {
            assert!(
                skipped
                    .iter()
                    .any(|s| s["file"].as_str().unwrap_or("").ends_with(bad)),
                "{command}: {skipped:?}"
            );
        }
        assert!(
            err.contains("zz_fast.csv:2-1025: the median time step is"),
            "{command}: {err}"
        );
    }
    // Only bad files: an error, not an empty analysis.
    let bad_only = tempfile::tempdir().unwrap();
    std::fs::write(bad_only.path().join("a.csv"), "t_s,x_m\n0,0\n").unwrap();
    for command in ["fit", "detect", "diagnose"] {
        let err = refused(&[command, bad_only.path().to_str().unwrap()]);
        assert!(err.contains("a.csv:1: no `f_n` column"), "{command}: {err}");
    }
}

#[test]
fn detect_warns_when_truth_json_and_the_csvs_disagree() {
    // CSVs and truth.json that disagree were scored
    // without a word.
    let dir = simulated(3, 2);
    let d = dir.path().to_str().unwrap();
    std::fs::remove_file(dir.path().join("trial_001.csv")).unwrap();
    let out = needle(&["detect", d]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("truth.json and the CSVs disagree") && err.contains("trial_001.csv"),
        "{err}"
    );
}

#[test]
fn outputs_that_cannot_be_written_name_their_path_in_words() {
    // `--plot /nodir/x.svg` said `BackendError(DrawingError(Os
    // {..}))`, `simulate --out existing_file` said "cannot create: File
    // exists".
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("d");
    let d = d.to_str().unwrap();
    assert!(
        needle(&["simulate", "--out", d, "--trials", "2", "--seed", "3"])
            .status
            .success()
    );
    let missing = dir.path().join("nodir").join("x.svg");
    let out = needle(&["fit", d, "--plot", missing.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("x.svg: cannot write: no directory"), "{err}");
    assert!(!err.contains("BackendError"), "{err}");
    let report = dir.path().join("nodir").join("r.html");
    let out = needle(&["diagnose", d, "--report", report.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("cannot write") && !err.contains("BackendError"),
        "{err}"
    );
    let file = dir.path().join("afile");
    std::fs::write(&file, "").unwrap();
    let out = needle(&["simulate", "--out", file.to_str().unwrap(), "--trials", "1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("afile: is a file, not a directory"), "{err}");
    // `--out` a dangling link said "File exists".
    let link = dir.path().join("dangling");
    std::os::unix::fs::symlink(dir.path().join("gone"), &link).unwrap();
    let link = link.to_str().unwrap();
    for args in [
        vec!["simulate", "--out", link, "--trials", "1"],
        vec!["detect", d, "--samples", link],
    ] {
        let out = needle(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert!(
            err.contains("dangling: a link to") && err.contains("gone, which does not exist"),
            "{err}"
        );
        assert!(!err.contains("File exists"), "{err}");
    }
}

#[test]
fn needle_record_never_writes_over_an_earlier_sessions_stream() {
    // A session with no insertion leaves only stream.bin, which the next
    // session into the same directory overwrote.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("stream.bin"), "earlier").unwrap();
    let err = refused(&[
        "record",
        "--port",
        "/dev/null",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(err.contains("stream.bin"), "{err}");
    assert_eq!(
        std::fs::read_to_string(dir.path().join("stream.bin")).unwrap(),
        "earlier"
    );
}

#[test]
fn needle_record_on_a_port_with_no_device_leaves_no_directory() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("trials");
    let err = refused(&[
        "record",
        "--port",
        "/dev/null",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(err.contains("/dev/null: cannot open serial port"), "{err}");
    assert!(!out.exists(), "an empty directory was left");
}

#[test]
fn needle_device_checks_its_arguments_before_the_port() {
    // The library listing needs no device; every other action names the
    // port it lacks; bad numbers and names are refused before any byte
    // is sent.
    let tmp = tempfile::tempdir().unwrap();
    let scratch = tmp.path().join("x");
    let scratch = scratch.to_str().unwrap();
    // A file of several tissues with no --name uploaded
    // its first without a word.
    let library = tmp.path().join("several.toml");
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../src/model/tissues.toml"),
    )
    .unwrap();
    std::fs::write(&library, text).unwrap();
    let library = library.to_str().unwrap();
    let out = needle(&["device", "tissues"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("liver1"));
    for (args, says) in [
        (&["device", "tare"][..], "--port"),
        (
            &[
                "device",
                "--port",
                "/dev/null",
                "assist",
                "puncture",
                "--depth-mm",
                "NaN",
            ],
            "--depth-mm NaN",
        ),
        (
            &["device", "--port", "/dev/null", "assist", "sideways"],
            "unknown assist mode `sideways`",
        ),
        (
            &["device", "--port", "/dev/null", "tissue", "spleen"],
            "spleen: neither a tissue",
        ),
        (
            &["device", "--port", "/dev/null", "tissue", library],
            "several.toml: holds 5 tissues (liver1, liver1_journal, liver1_rational, liver2, skin_phantom): say which with --name",
        ),
        // An empty list meant `none`; baud 0 means "hang up" to a tty.
        (
            &["device", "--port", "/dev/null", "assist", ""],
            "name the modes, or `none`",
        ),
        (
            &["device", "--port", "/dev/null", "--baud", "0", "tare"],
            "--baud 0",
        ),
        (
            &[
                "record",
                "--port",
                "/dev/null",
                "--out",
                scratch,
                "--baud",
                "0",
            ],
            "--baud 0",
        ),
        (
            &[
                "record",
                "--port",
                "/dev/null",
                "--out",
                scratch,
                "--seconds",
                "1e308",
            ],
            "--seconds 1e308",
        ),
    ] {
        let out = needle(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} accepted");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

#[test]
fn decode_refuses_a_device_named_as_its_capture() {
    // `needle decode /dev/zero` decoded zeros until stopped, and a serial
    // port named as a capture was read without its baud rate.
    let err = refused(&["decode", "/dev/zero"]);
    assert!(
        err.contains(
            "/dev/zero: a device, not a capture file (a serial port is read with --port /dev/zero)"
        ),
        "{err}"
    );
}

/// `trial_000.csv` of `from` rewritten into `to/name` with `t` and `x`
/// scaled.
fn scaled_copy(from: &std::path::Path, to: &std::path::Path, name: &str, t_by: f64, x_by: f64) {
    let text = std::fs::read_to_string(from.join("trial_000.csv")).unwrap();
    let mut lines = text.lines();
    let mut out = format!("{}\n", lines.next().unwrap());
    for l in lines {
        let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
        out += &format!("{:e},{:e},{}\n", v[0] * t_by, v[1] * x_by, v[2]);
    }
    std::fs::write(to.join(name), out).unwrap();
}

#[test]
fn fit_leaves_out_what_no_needle_drive_could_do_and_writes_no_tissue_it_would_refuse() {
    // Positions in millimetres (a 3 mm/s insertion read as 3 m/s) were
    // fitted without a word into a puncture depth of metres, and the
    // TOML written was one `--params` then refused.
    let dir = simulated(2, 1);
    let d = dir.path().to_str().unwrap();
    scaled_copy(dir.path(), dir.path(), "mm.csv", 1.0, 1000.0);
    let json = dir.path().join("fit.json");
    let out = needle(&["fit", d, "--json", json.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("mm.csv: cannot fit: x_m moves")
            && err.contains("faster than any needle drive's 1 m/s"),
        "{err}"
    );
    let value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(value["skipped"][0]["file"], "mm.csv", "{value}");
    // At the speed of a drive (ten times the simulated one, sampled at
    // 25 Hz) but 200 times as deep: a fit, and a tissue past the device's
    // 2 m, which is not written.
    let deep = tempfile::tempdir().unwrap();
    for k in 0..2 {
        let one = simulated(1, k + 5);
        scaled_copy(one.path(), deep.path(), &format!("t{k}.csv"), 20.0, 200.0);
    }
    let toml = deep.path().join("fit.toml");
    let err = refused(&[
        "fit",
        deep.path().to_str().unwrap(),
        "--toml",
        toml.to_str().unwrap(),
    ]);
    assert!(
        err.contains("fit.toml: not written") && err.contains("puncture_depth_m"),
        "{err}"
    );
    assert!(!toml.exists());
}

#[test]
fn decode_takes_the_streams_rate_over_rate_hz_and_never_writes_to_its_stdout() {
    // --rate-hz 65535 rebuilt a 500 Hz capture's times at 65 kHz; --csv
    // /dev/stdout wrote the CSV and the text over each other.
    let dir = tempfile::tempdir().unwrap();
    let cap = dir.path().join("cap.bin");
    std::fs::write(&cap, twin_capture(3.0)).unwrap();
    let csv = dir.path().join("cap.csv");
    let out = needle(&[
        "decode",
        cap.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
        "--rate-hz",
        "65535",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("the stream says 500 Hz; --rate-hz 65535"),
        "{err}"
    );
    assert_eq!(times(&csv)[1], 0.002);
    let err = refused(&["decode", cap.to_str().unwrap(), "--csv", "/dev/stdout"]);
    assert!(err.contains("--csv names standard output"), "{err}");
    // A header of 65 535 Hz before a 500 Hz device's
    // configuration and status compressed the times without a word.
    use needle_holder::protocol::{Frame, FrameEncoder};
    let mut lying = FrameEncoder::default()
        .encode(&Frame::Header(needle_holder::protocol::header(65_535)))
        .to_vec();
    lying.extend(twin_capture(1.0));
    std::fs::write(&cap, lying).unwrap();
    let out = needle(&["decode", cap.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("frame says 500 Hz where the stream said 65535 Hz before"),
        "{err}"
    );
    assert_eq!(
        err.matches("where the stream said").count(),
        1,
        "said once: {err}"
    );
}

#[test]
fn detect_and_evaluate_take_only_what_the_device_does() {
    // A target depth the device refuses was used (1e308 mm: never a halt);
    // 65 kHz trials were thinned to 2 kHz and the row labelled 65535 Hz.
    let dir = simulated(1, 2);
    let d = dir.path().to_str().unwrap();
    for depth in ["1e308", "100.0001", "0.09999"] {
        let err = refused(&["detect", d, "--assist", "depth", "--target-depth-mm", depth]);
        assert!(
            err.contains("must be between 0.1 and 100 mm"),
            "{depth}: {err}"
        );
    }
    // An empty list meant no assist here and was refused by `device`.
    let err = refused(&["detect", d, "--assist", ","]);
    assert!(err.contains("name the modes, or `none`"), "{err}");
    let err = refused(&["evaluate", "--trials", "1", "--rates-hz", "65535"]);
    assert!(err.contains("at most 2000 Hz"), "{err}");
    let err = refused(&["evaluate", "--trials", "1001"]);
    assert!(err.contains("--trials 1001"), "{err}");
}

#[test]
fn a_stopped_simulation_leaves_the_earlier_one_whole_and_the_next_run_goes_on() {
    // Stopped half-way, simulate had already deleted the earlier
    // truth.json; the next run refused its own leftovers as another's.
    let dir = simulated(2, 1);
    let d = dir.path().to_str().unwrap();
    let truth = std::fs::read(dir.path().join("truth.json")).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args([
            "simulate",
            "--out",
            d,
            "--trials",
            "50",
            "--rate-hz",
            "20000",
            "--seed",
            "9",
        ])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Stopped once it has begun writing.
    let staging = dir.path().join(".simulating");
    wait_while_running(&mut child, &staging.join("trial_000.csv"));
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        staging.join("trial_000.csv").exists(),
        "stopped before it wrote anything"
    );
    assert_eq!(std::fs::read(dir.path().join("truth.json")).unwrap(), truth);
    assert!(!dir.path().join("trial_002.csv").exists());
    let out = needle(&["simulate", "--out", d, "--trials", "1", "--seed", "3"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!dir.path().join(".simulating").exists());
    assert!(!dir.path().join("trial_001.csv").exists());
}

/// Wait for `path` to appear while `child` runs: a child that ends first,
/// or a minute without it, fails the test (it used to go on silently).
fn wait_while_running(child: &mut std::process::Child, path: &std::path::Path) {
    let until = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while !path.exists() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "ended before {} appeared",
            path.display()
        );
        assert!(std::time::Instant::now() < until, "no {}", path.display());
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

#[test]
fn a_simulated_load_cell_reads_no_more_than_its_full_scale() {
    // Every effect at ten times its size wrote 483 N for a 10 N cell.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let all = "viscoelasticity=10,rate_dependent_friction=10,presliding_hysteresis=10,internal_structures=10,depth_dependent_cutting=10,holder_inertia=10,sensor_drift=10,tissue_motion=10";
    let out = needle(&[
        "simulate",
        "--out",
        d,
        "--trials",
        "1",
        "--effects",
        all,
        "--tare-n",
        "10",
        "--noise-n",
        "10",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.path().join("trial_000.csv")).unwrap();
    let most = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(2).unwrap().parse::<f64>().unwrap().abs())
        .fold(0.0, f64::max);
    assert!(most <= 10.0 && most > 9.9, "{most} N");
}

#[test]
fn simulate_deletes_and_writes_over_nothing_a_simulation_did_not_write() {
    // Any truth.json made a directory a simulation's, so a hand-written
    // one beside real trials had them deleted; a user's file in
    // `.simulating`, or a replay named like ours, went without a word.
    let real = simulated(3, 1);
    let d = real.path().to_str().unwrap();
    std::fs::write(
        real.path().join("truth.json"),
        r#"{"trials":[{"file":"trial_000.csv","events":[]}]}"#,
    )
    .unwrap();
    let before = std::fs::read(real.path().join("trial_002.csv")).unwrap();
    let err = refused(&["simulate", "--out", d, "--trials", "1"]);
    assert!(err.contains("trials that are not a simulation's"), "{err}");
    assert_eq!(
        std::fs::read(real.path().join("trial_002.csv")).unwrap(),
        before
    );
    let notes = tempfile::tempdir().unwrap();
    std::fs::create_dir(notes.path().join(".simulating")).unwrap();
    std::fs::write(notes.path().join(".simulating/mine.txt"), "precious").unwrap();
    let err = refused(&[
        "simulate",
        "--out",
        notes.path().to_str().unwrap(),
        "--trials",
        "1",
    ]);
    assert!(
        err.contains("mine.txt, which no simulation writes"),
        "{err}"
    );
    assert!(notes.path().join(".simulating/mine.txt").exists());
    let replay = tempfile::tempdir().unwrap();
    std::fs::write(replay.path().join("trial_000.replay"), "mine").unwrap();
    let err = refused(&[
        "simulate",
        "--out",
        replay.path().to_str().unwrap(),
        "--trials",
        "1",
    ]);
    assert!(
        err.contains("would write over that no simulation wrote"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(replay.path().join("trial_000.replay")).unwrap(),
        "mine"
    );
}

#[test]
fn detect_gives_positions_in_the_files_own_coordinates() {
    // A stage 0.12 m off zero was given events and a hold position counted
    // from the first sample: a robot in stage coordinates would have been
    // told to hold 0.12 m away.
    let dir = simulated(1, 4);
    let d = dir.path().to_str().unwrap();
    let text = std::fs::read_to_string(dir.path().join("trial_000.csv")).unwrap();
    let mut lines = text.lines();
    let mut moved = format!("{}\n", lines.next().unwrap());
    for l in lines {
        let v: Vec<&str> = l.split(',').collect();
        moved += &format!(
            "{},{:.9},{}\n",
            v[0],
            v[1].parse::<f64>().unwrap() + 0.12,
            v[2]
        );
    }
    let stage = tempfile::tempdir().unwrap();
    std::fs::write(stage.path().join("trial_000.csv"), moved).unwrap();
    let events = |dir: &str| -> serde_json::Value {
        let out = needle(&["detect", dir, "--assist", "puncture,back-off"]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()["trials"][0].clone()
    };
    let (at_zero, on_stage) = (events(d), events(stage.path().to_str().unwrap()));
    let x = |t: &serde_json::Value, p: &str| t.pointer(p).and_then(|v| v.as_f64()).unwrap();
    for p in [
        "/events/0/x_m",
        "/events/1/x_m",
        "/halt/x_m",
        "/halt/hold_x_m",
    ] {
        let shift = x(&on_stage, p) - x(&at_zero, p);
        assert!((shift - 0.12).abs() < 2e-6, "{p}: {shift}");
    }
}

#[test]
fn two_simulations_into_one_directory_are_not_run_at_once() {
    // Two at once shared the staging directory; each removed the other's
    // files and one reported success over a dataset of two seeds.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let mut first = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args([
            "simulate",
            "--out",
            d,
            "--trials",
            "100",
            "--rate-hz",
            "20000",
        ])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    wait_while_running(&mut first, &dir.path().join(".simulating/trial_000.csv"));
    let err = refused(&["simulate", "--out", d, "--trials", "1", "--seed", "2"]);
    first.kill().unwrap();
    first.wait().unwrap();
    assert!(err.contains("another simulation is writing it"), "{err}");
}

#[test]
fn simulate_never_replaces_a_trial_changed_since_it_wrote_it() {
    // A user's trial copied over a simulated one of the same name (truth.json
    // still listing it) was overwritten or deleted without a word.
    let dir = simulated(2, 1);
    let d = dir.path().to_str().unwrap();
    let other = simulated(1, 7);
    std::fs::copy(
        other.path().join("trial_000.csv"),
        dir.path().join("trial_001.csv"),
    )
    .unwrap();
    let mine = std::fs::read(dir.path().join("trial_001.csv")).unwrap();
    let err = refused(&["simulate", "--out", d, "--trials", "1", "--seed", "3"]);
    assert!(err.contains("trial_001.csv"), "{err}");
    assert_eq!(
        std::fs::read(dir.path().join("trial_001.csv")).unwrap(),
        mine
    );
}

#[test]
fn decode_takes_a_segment_list_only_if_it_is_one_and_never_writes_through_a_link() {
    let dir = tempfile::tempdir().unwrap();
    let at = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    std::fs::write(at("one.bin"), twin_capture(3.0)).unwrap();
    // A CSV where the list goes (another decode's output) was deleted.
    assert!(
        needle(&["decode", &at("one.bin"), "--csv", &at("o.csv.segments")])
            .status
            .success()
    );
    let before = std::fs::read(at("o.csv.segments")).unwrap();
    let err = refused(&["decode", &at("one.bin"), "--csv", &at("o.csv")]);
    assert!(err.contains("is no segment list of decode's"), "{err}");
    assert_eq!(std::fs::read(at("o.csv.segments")).unwrap(), before);
    // A dangling link where the list goes had the list written through it.
    let joined = [twin_capture(3.0), twin_capture(3.0)].concat();
    std::fs::write(at("joined.bin"), joined).unwrap();
    std::os::unix::fs::symlink(dir.path().join("elsewhere.txt"), at("q.csv.segments")).unwrap();
    let out = needle(&["decode", &at("joined.bin"), "--csv", &at("q.csv")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!dir.path().join("elsewhere.txt").exists());
    let bytes = std::fs::metadata(at("q-2.csv")).unwrap().len();
    assert_eq!(
        std::fs::read_to_string(at("q.csv.segments")).unwrap(),
        format!("q-2.csv {bytes}\n")
    );
    // A listed segment written since by another decode of its own (to
    // `q-2.csv` on purpose) was removed as stale: another size, kept.
    std::fs::write(at("two.bin"), twin_capture(5.0)).unwrap();
    assert!(needle(&["decode", &at("two.bin"), "--csv", &at("q-2.csv")])
        .status
        .success());
    let mine = std::fs::read(at("q-2.csv")).unwrap();
    let out = needle(&["decode", &at("one.bin"), "--csv", &at("q.csv")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read(at("q-2.csv")).unwrap(), mine);
    // 9000 restarts made 9000 files, in time growing with their square.
    let short = twin_capture(2.0);
    std::fs::write(at("many.bin"), short.repeat(1002)).unwrap();
    std::fs::create_dir(dir.path().join("many")).unwrap();
    let err = refused(&["decode", &at("many.bin"), "--csv", &at("many/m.csv")]);
    assert!(err.contains("more than 1000 segments"), "{err}");
    // The segments written before the refusal are listed, not left for
    // `fit` to read and the next decode to trip over; the next decode to
    // that name removes them.
    let list = std::fs::read_to_string(at("many/m.csv.segments")).unwrap();
    assert_eq!(list.lines().count(), 1000, "m-2.csv … m-1001.csv");
    std::fs::write(at("one_more.bin"), &short).unwrap();
    let out = needle(&["decode", &at("one_more.bin"), "--csv", &at("many/m.csv")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let left: Vec<String> = std::fs::read_dir(dir.path().join("many"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["m.csv"]);
}

#[test]
fn fit_says_every_value_it_writes_other_than_estimated() {
    let dir = simulated(3, 2);
    let d = dir.path().to_str().unwrap();
    let toml = dir.path().join("fitted.toml");
    let out = needle(&["fit", d, "--toml", toml.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let text = std::fs::read_to_string(&toml).unwrap();
    let notes: Vec<&str> = text.lines().filter(|l| l.starts_with("# note:")).collect();
    // The paper's protocol at one speed cannot split friction's constant
    // from its damping, nor give the withdrawal's static band: there is
    // something to note.
    assert!(!notes.is_empty(), "{text}");
    for note in notes {
        assert!(
            err.contains(note.trim_start_matches("# ")),
            "{note} not said: {err}"
        );
    }
    let back = needle(&[
        "detect",
        d,
        "--params",
        toml.to_str().unwrap(),
        "--json",
        dir.path().join("d.json").to_str().unwrap(),
    ]);
    assert!(
        back.status.success(),
        "{}",
        String::from_utf8_lossy(&back.stderr)
    );
}

#[test]
fn host_and_device_check_a_tissue_alike() {
    // `contact_force_n = 1e-9` was taken by `detect --params` (75 false
    // structures, a fault) and refused by the device; a contact force
    // above the puncture force was taken by both, and nothing detected.
    let dir = simulated(1, 3);
    let d = dir.path().to_str().unwrap();
    let liver1 = liver1_entry();
    for (value, line_has) in [("1e-9", "contact_force_n"), ("3.0", "contact_force_n")] {
        let text = liver1.replace(
            "contact_force_n = 0.05",
            &format!("contact_force_n = {value}"),
        );
        let toml = dir.path().join("t.toml");
        std::fs::write(&toml, &text).unwrap();
        let line = text
            .lines()
            .position(|l| l.starts_with("contact_force_n"))
            .unwrap()
            + 1;
        let err = refused(&["detect", d, "--params", toml.to_str().unwrap()]);
        assert!(err.contains(&format!("t.toml:{line}:")), "{err}");
        assert!(err.contains(line_has), "{err}");
        let err = refused(&[
            "device",
            "--port",
            "/dev/null",
            "tissue",
            toml.to_str().unwrap(),
        ]);
        assert!(err.contains(line_has), "{err}");
    }
}

/// Rewrite `trial_000.csv` of `dir` row by row (index from 0 after the
/// header, and its three values).
fn rewrite_rows(dir: &std::path::Path, edit: impl Fn(usize, [f64; 3]) -> [f64; 3]) {
    let path = dir.join("trial_000.csv");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut out = String::from("t_s,x_m,f_n\n");
    for (i, line) in text.lines().skip(1).enumerate() {
        let v: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        let [t, x, f] = edit(i, [v[0], v[1], v[2]]);
        out += &format!("{t:e},{x:e},{f:e}\n");
    }
    std::fs::write(&path, out).unwrap();
}

#[test]
fn fit_leaves_out_what_is_no_needle_insertion() {
    // One row of 1e300 N gave a cutting force of 4.6e296 N; time in
    // milliseconds fitted damping and cutting as 0; a +5 mm encoder spike
    // every 50 rows fitted a1 at 77 N/m for 48. Each trial is left out,
    // named with why, and fit goes on with the others.
    type Edit = fn(usize, [f64; 3]) -> [f64; 3];
    let cases: [(&str, Edit); 3] = [
        ("beyond any needle insertion's 100 N", |i, [t, x, f]| {
            [t, x, if i == 4000 { 1e300 } else { f }]
        }),
        ("is t_s in seconds?", |_, [t, x, f]| [t * 1000.0, x, f]),
        ("an encoder glitching", |i, [t, x, f]| {
            [t, if i % 50 == 49 { x + 0.005 } else { x }, f]
        }),
    ];
    for (why, edit) in cases {
        let dir = simulated(3, 2);
        rewrite_rows(dir.path(), edit);
        let json = dir.path().join("fit.json");
        let out = needle(&[
            "fit",
            dir.path().to_str().unwrap(),
            "--json",
            json.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{why}: {err}");
        assert!(
            err.contains("trial_000.csv") && err.contains(why),
            "{why}: {err}"
        );
        let fit: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(fit["trials"], 2, "{why}: {fit}");
    }
}

#[test]
fn a_decode_stopped_by_a_signal_writes_whole_rows_and_says_so() {
    // Ctrl-C left the last CSV cut mid-line and its
    // segments unlisted. The capture comes through a pipe held open, so
    // the decode is mid-stream when the signal comes.
    use std::io::Write;
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("live");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let csv = dir.path().join("live.csv");
    let child = Command::new(env!("CARGO_BIN_EXE_needle"))
        .arg("decode")
        .arg(&fifo)
        .arg("--csv")
        .arg(&csv)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stream = twin_capture(20.0);
    let mut pipe = std::fs::OpenOptions::new().write(true).open(&fifo).unwrap();
    let half = stream.len() / 2;
    pipe.write_all(&stream[..half]).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(500));
    let pid = child.id().to_string();
    assert!(Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .unwrap()
        .success());
    // The decode sees the signal once a read returns, and its handler
    // runs on a thread of its own, which a loaded machine can schedule
    // after that read: more of the stream follows, a block at a time,
    // until the decode has ended (running out of stream first is an end
    // of input, not a signal, and fails below).
    let mut child = child;
    for block in stream[half..].chunks(4096) {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        let _ = pipe.write_all(block);
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    drop(pipe);
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("stopped by a signal"), "{err}");
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(text.ends_with('\n'), "the last row is whole");
    let rows: Vec<&str> = text.lines().collect();
    assert!(rows.len() > 100, "{} rows", rows.len());
    assert!(
        rows.iter().all(|r| r.split(',').count() == 7),
        "every row whole"
    );
}
