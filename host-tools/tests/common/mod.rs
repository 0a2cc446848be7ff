//! What more than one test binary does the same way: run `needle`, and
//! read the device's residual over each dwell of `needle detect
//! --samples`'s output.

// Each test binary uses some of these, none all of them.
#![allow(dead_code)]

use std::ffi::OsStr;
use std::path::Path;
use std::process::{Command, Output};

/// Run `needle` with `args` to its end, whatever it exits with.
pub fn run<S: AsRef<OsStr>>(args: &[S]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_needle"))
        .args(args)
        .output()
        .expect("run needle")
}

/// Run `needle` with `args`; it must succeed (its stderr in the message).
pub fn needle(args: &[&str]) {
    let run = run(args);
    assert!(
        run.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// Each trial's longest rest in the tissue (`inserted`, velocity 0) in
/// the device samples under `dir`: the sum of its squared residuals, N²,
/// and its length, samples.
pub fn dwells(dir: &Path) -> Vec<(f64, usize)> {
    needle_io::trial::dataset_files(dir)
        .unwrap()
        .iter()
        .map(|file| {
            let rows: Vec<csv::StringRecord> = csv::Reader::from_path(file)
                .unwrap()
                .records()
                .map(Result::unwrap)
                .collect();
            let at_rest =
                |r: &csv::StringRecord| &r[6] == "inserted" && r[3].parse::<f64>().unwrap() == 0.0;
            let best = rows
                .split(|r| !at_rest(r))
                .max_by_key(|run| run.len())
                .unwrap_or(&[]);
            let squares = best.iter().map(|r| r[5].parse::<f64>().unwrap().powi(2));
            (squares.sum(), best.len())
        })
        .collect()
}
