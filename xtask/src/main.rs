//! `cargo xtask`: the developers' tasks around the firmware, as rtic and
//! stabilizer keep theirs — build an image and say how big it is, run one
//! in QEMU on a replay, measure. Each goes through `needle-qemu`, which
//! asks `cargo metadata` where the target directory is, so
//! `CARGO_TARGET_DIR` is honoured throughout (the `run-m3`/`run-m4`
//! aliases' runners write `target/frames.bin` whatever it says).
//!
//! A user's commands stay in `needle` (`needle demo`, `needle bench`);
//! these are for working on the firmware.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use needle_qemu::bench::{self, image_size, BenchArgs};
use needle_qemu::firmware::{self, Board, Serial};

#[derive(Parser)]
#[command(
    name = "cargo xtask",
    about = "Firmware tasks: images, QEMU runs, the bench"
)]
struct Cli {
    #[command(subcommand)]
    task: Task,
}

#[derive(Subcommand)]
enum Task {
    /// Build every image (the QEMU boards' and the real board's) and print
    /// each one's path, flash and static RAM.
    Size,
    /// Run a board's image in QEMU on a replay file (`needle simulate`
    /// writes one a trial, `needle demo` one in the target directory); the
    /// UART's bytes go to `--out`, which `needle decode` reads.
    Qemu {
        /// The QEMU board.
        #[arg(value_enum)]
        board: Board,
        /// The replay file the image reads through semihosting.
        replay: PathBuf,
        /// Where the UART's bytes go (default: `frames.bin` in the target
        /// directory).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Stop QEMU after this many seconds.
        #[arg(long, default_value_t = 300)]
        timeout_s: u64,
    },
    /// Instructions a sample in QEMU, image sizes, stream bytes (what
    /// `needle bench` prints).
    Bench(BenchArgs),
}

fn main() -> ExitCode {
    match run(Cli::parse().task) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cargo xtask: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(task: Task) -> Result<()> {
    match task {
        Task::Size => size(),
        Task::Qemu {
            board,
            replay,
            out,
            timeout_s,
        } => qemu(board, &replay, out, Duration::from_secs(timeout_s)),
        Task::Bench(args) => bench::run(&args),
    }
}

fn size() -> Result<()> {
    let mut images = Vec::new();
    for board in Board::value_variants() {
        let name = board.to_possible_value().map(|v| v.get_name().to_string());
        let name = name.unwrap_or_else(|| format!("{board:?}"));
        images.push((
            format!("{name} ({})", board.target()),
            firmware::build(*board)?,
        ));
    }
    images.push((
        "the real board, Nucleo-F411RE (thumbv7em-none-eabihf)".into(),
        firmware::build_nucleo_f411re()?,
    ));
    for (name, elf) in images {
        let size = image_size(&elf)?;
        println!(
            "{name}: {} bytes flash, {} bytes static RAM  {}",
            size.flash_bytes,
            size.ram_bytes,
            elf.display()
        );
    }
    Ok(())
}

fn qemu(
    board: Board,
    replay: &std::path::Path,
    out: Option<PathBuf>,
    timeout: Duration,
) -> Result<()> {
    if !replay.is_file() {
        bail!("{}: no such replay file", replay.display());
    }
    firmware::ensure_qemu()?;
    let elf = firmware::build(board)?;
    let out = match out {
        Some(path) => path,
        None => firmware::target_directory()?.join("frames.bin"),
    };
    let cmd = firmware::qemu_command(board, &elf, replay, Serial::File(&out), &[]);
    let run = firmware::run_qemu(cmd, timeout)?
        .success()
        .with_context(|| format!("{} on {}", elf.display(), replay.display()))?;
    let bytes = std::fs::metadata(&out).map(|m| m.len()).unwrap_or(0);
    println!("{bytes} bytes from the UART in {}", out.display());
    if !run.stderr.is_empty() {
        eprint!("{}", run.stderr);
    }
    Ok(())
}
