//! Every subcommand with its standard output or standard error closed,
//! full (`/dev/full`) or a pipe whose reader has gone (`| head -1`):
//! never a panic; output that cannot be written is an error naming
//! standard output (a closed pipe ends the command quietly); a broken
//! standard error costs the notes only, never the work.

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Output, Stdio};

use needle_analysis::sim::{self, Plan};
use needle_holder::config::DeviceConfig;
use needle_holder::model::params::LIVER1;
use needle_io::twin;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Stream {
    Stdout,
    Stderr,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Broken {
    /// The descriptor closed before the command starts.
    Closed,
    /// `/dev/full`: every write fails with ENOSPC.
    Full,
    /// A pipe whose reading end is closed: EPIPE.
    Pipe,
}

/// `needle args` with `stream` broken as `how`; the other stream is
/// captured.
fn run(args: &[&str], stream: Stream, how: Broken) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_needle"));
    cmd.args(args).stdin(Stdio::null());
    let broken = match how {
        Broken::Closed => Stdio::null(), // replaced by the close below
        Broken::Full => std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap()
            .into(),
        Broken::Pipe => Stdio::piped(),
    };
    match stream {
        Stream::Stdout => cmd.stdout(broken).stderr(Stdio::piped()),
        Stream::Stderr => cmd.stderr(broken).stdout(Stdio::piped()),
    };
    if how == Broken::Closed {
        let fd = if stream == Stream::Stdout { 1 } else { 2 };
        // SAFETY: close(2) between fork and exec touches only the child.
        unsafe {
            cmd.pre_exec(move || {
                libc::close(fd);
                Ok(())
            });
        }
    }
    let mut child = cmd.spawn().unwrap();
    // The reader goes away before the command writes anything.
    if how == Broken::Pipe {
        match stream {
            Stream::Stdout => drop(child.stdout.take()),
            Stream::Stderr => drop(child.stderr.take()),
        }
    }
    child.wait_with_output().unwrap()
}

/// A dataset of two simulated trials and a capture of the device's frames.
fn inputs(dir: &Path) {
    let sim = dir.join("sim");
    let made = Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(["simulate", "--trials", "2", "--out"])
        .arg(&sim)
        .output()
        .unwrap();
    assert!(made.status.success(), "{made:?}");
    let (trial, _) = sim::insertion(&LIVER1, &Plan::PAPER);
    let config = DeviceConfig::default();
    let replay = sim::to_replay(&trial, 500, &config.load_cell, &config.encoder);
    std::fs::write(dir.join("capture.bin"), twin::run(&replay).frames).unwrap();
}

/// What a command writes to standard output (its result), and whether it
/// can run whole without a device.
struct Case {
    args: Vec<String>,
    writes_stdout: bool,
    succeeds: bool,
}

fn cases(dir: &Path) -> Vec<Case> {
    let d = |p: &str| dir.join(p).to_str().unwrap().to_string();
    let case = |args: &[&str], writes_stdout: bool, succeeds: bool| Case {
        args: args.iter().map(|s| s.to_string()).collect(),
        writes_stdout,
        succeeds,
    };
    vec![
        case(&["decode", &d("capture.bin")], true, true),
        case(
            &["decode", &d("capture.bin"), "--csv", &d("q.csv")],
            true,
            true,
        ),
        case(&["device", "tissues"], true, true),
        case(&["device", "--port", &d("no-port"), "config"], false, false),
        case(
            &["record", "--port", &d("no-port"), "--out", &d("rec")],
            false,
            false,
        ),
        case(&["fit", &d("sim")], true, true),
        case(&["fit", &d("sim"), "--json", &d("fit.json")], false, true),
        case(&["detect", &d("sim")], true, true),
        case(&["diagnose", &d("sim")], true, true),
        case(
            &[
                "evaluate",
                "--trials",
                "1",
                "--rates-hz",
                "500",
                "--noise-n",
                "0.002",
            ],
            true,
            true,
        ),
        case(
            &["simulate", "--trials", "1", "--out", &d("sim2")],
            false,
            true,
        ),
        case(&["--help"], true, true),
        case(&["fit", "--no-such-option"], false, false),
    ]
}

fn check(case: &Case, stream: Stream, how: Broken) {
    let out = run(
        &case.args.iter().map(String::as_str).collect::<Vec<_>>(),
        stream,
        how,
    );
    let what = format!("needle {:?} with {stream:?} {how:?}", case.args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_ne!(out.status.code(), Some(101), "{what} panicked: {stderr}");
    assert!(out.status.code().is_some(), "{what} died of a signal");
    assert!(!stderr.contains("panicked"), "{what}: {stderr}");
    let code = out.status.code().unwrap();
    let expected = match (stream, how) {
        // A full disk under the result is an error that says where.
        (Stream::Stdout, Broken::Full) if case.writes_stdout => {
            assert!(
                stderr.contains("standard output"),
                "{what} does not name standard output: {stderr}"
            );
            1
        }
        // A reader that went away ends the command quietly.
        (Stream::Stdout, Broken::Pipe) if case.writes_stdout && case.succeeds => 0,
        // Otherwise the broken stream changes nothing but the notes.
        _ if case.succeeds => 0,
        _ if case.args[0] == "fit" => 2, // clap's usage error
        _ => 1,
    };
    assert_eq!(code, expected, "{what}: {stderr}");
}

#[test]
fn no_subcommand_panics_on_a_closed_full_or_broken_output_stream() {
    let dir = tempfile::tempdir().unwrap();
    inputs(dir.path());
    for case in cases(dir.path()) {
        for stream in [Stream::Stdout, Stream::Stderr] {
            for how in [Broken::Closed, Broken::Full, Broken::Pipe] {
                // Each run of `simulate` replaces its own simulation, and
                // `decode --csv` its own segments: both may run again.
                check(&case, stream, how);
            }
        }
    }
}

#[test]
fn demo_and_bench_stop_at_their_first_line_when_standard_output_breaks() {
    // Both build firmware and run QEMU after their first line; with that
    // line unwritable they stop there (with standard output closed they
    // would run whole, which the other tests do).
    for args in [["demo"], ["bench"]] {
        let out = run(&args, Stream::Stdout, Broken::Full);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains("standard output"), "{stderr}");
        let out = run(&args, Stream::Stdout, Broken::Pipe);
        assert_eq!(out.status.code(), Some(0), "{args:?}");
    }
}

#[test]
fn record_with_no_device_and_stderr_full_exits_1_and_leaves_no_directory() {
    // `needle record … 2>/dev/full` with no device: the refusal cannot be
    // said, but the exit says it, and no directory is left behind.
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("rec");
    let out = run(
        &[
            "record",
            "--port",
            dir.path().join("none").to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ],
        Stream::Stderr,
        Broken::Full,
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(!out_dir.exists());
}

#[test]
fn no_tool_prints_through_a_macro_that_panics() {
    // `println!` and friends panic when their stream breaks; the tools
    // write through `needle_io::stdout` instead. Every source file is
    // read, so a new one is covered without being listed.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut offenders = Vec::new();
    let mut dirs: Vec<_> = ["src", "io/src", "analysis/src", "qemu/src"]
        .iter()
        .map(|d| root.join(d))
        .collect();
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let text = std::fs::read_to_string(&path).unwrap();
                for (i, line) in text.lines().enumerate() {
                    let code = line.split("//").next().unwrap_or("");
                    if ["println!", "eprintln!", "print!(", "eprint!("]
                        .iter()
                        .any(|m| code.contains(m))
                    {
                        offenders.push(format!("{}:{}: {line}", path.display(), i + 1));
                    }
                }
            }
        }
    }
    assert!(offenders.is_empty(), "{offenders:#?}");
}
