//! `needle`: host tools for the instrumented needle holder.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use needle_analysis::{detect, diagnose, evaluate, fit, sim};
use needle_io::{decode, device, record};
use needle_qemu::{bench, demo};

#[derive(Parser)]
#[command(
    name = "needle",
    version,
    about = "Host tools for the instrumented needle holder"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Decode device frames from a capture file or a serial port.
    Decode(decode::DecodeArgs),
    /// Send a command to a device on a serial port (tare, tissue, assist, rearm, stream, config).
    Device(device::DeviceArgs),
    /// Record insertions from a device to trial CSVs, one per insertion.
    Record(record::RecordArgs),
    /// Watch an insertion live in a browser (a page on 127.0.0.1).
    Live(needle_live::LiveArgs),
    /// Build the firmware, replay one liver insertion in QEMU, decode it live.
    Demo(DemoCommand),
    /// Count instructions per sample under QEMU; measure flash and RAM.
    Bench(bench::BenchArgs),
    /// Simulate trials (CSV + firmware replays + truth.json), with effects.
    Simulate(sim::SimulateArgs),
    /// Estimate the model's parameters from a directory of trials.
    Fit(fit::FitArgs),
    /// Run the device's event detectors over trials (and score them against truth.json).
    Detect(detect::DetectArgs),
    /// Score the detectors over simulated trials: rates × noise × structures.
    Evaluate(evaluate::EvaluateArgs),
    /// Where the model misses, which unmodelled effect causes it, judged on withheld trials.
    Diagnose(diagnose::DiagnoseArgs),
}

/// `needle demo`, in the terminal or, with `--live`, in the browser.
#[derive(clap::Args)]
struct DemoCommand {
    #[command(flatten)]
    demo: demo::DemoArgs,
    /// Serve the live view over the demo's insertion instead of decoding
    /// it here (`needle live --replay` on the demo's replay, on the
    /// lm3s6965 board); open the address it prints.
    #[arg(long)]
    live: bool,
    /// With --live: where to serve the page.
    #[arg(long, default_value = "127.0.0.1:0", requires = "live")]
    listen: std::net::SocketAddr,
}

fn run_demo(args: &DemoCommand) -> anyhow::Result<()> {
    if !args.live {
        return demo::run(&args.demo);
    }
    if args.demo.board != needle_qemu::firmware::Board::Lm3s6965 {
        let board = clap::ValueEnum::to_possible_value(&args.demo.board)
            .map_or_else(String::new, |v| v.get_name().to_owned());
        anyhow::bail!(
            "--live runs the firmware on the lm3s6965 board; leave --board out (or run `needle demo --board {board}` without --live)"
        );
    }
    let demo = demo::write_replay(&args.demo)?;
    needle_live::run_command(&needle_live::LiveArgs {
        port: None,
        baud: 115_200,
        record_into: demo.dir.join("recordings"),
        replay: Some(demo.replay),
        listen: args.listen,
    })
}

fn main() -> ExitCode {
    keep_freed_heap();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return clap_exit(&e),
    };
    let result = match &cli.command {
        Command::Decode(args) => decode::run(args),
        Command::Demo(args) => run_demo(args),
        Command::Device(args) => device::run(args),
        Command::Record(args) => record::run(args),
        Command::Live(args) => needle_live::run_command(args),
        Command::Bench(args) => bench::run(args),
        Command::Simulate(args) => sim::run(args),
        Command::Fit(args) => fit::run(args),
        Command::Detect(args) => detect::run(args),
        Command::Evaluate(args) => evaluate::run(args),
        Command::Diagnose(args) => diagnose::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // `needle decode … | head` closing the pipe is not a failure.
        Err(err) if is_broken_pipe(&err) => ExitCode::SUCCESS,
        Err(err) => {
            needle_io::note!("needle: {err:#}");
            ExitCode::FAILURE
        }
    }
}

/// What clap would do for `--help`, `--version` or a bad argument, but a
/// help that cannot be written is a failure (clap's own `exit` ignores
/// that and exits 0 over `needle --help > /dev/full`).
fn clap_exit(e: &clap::Error) -> ExitCode {
    use std::io::ErrorKind::BrokenPipe;
    let printed = e.print();
    if e.use_stderr() {
        return ExitCode::from(2);
    }
    match printed {
        Err(io) if io.kind() != BrokenPipe => {
            needle_io::note!("needle: cannot write to standard output: {io}");
            ExitCode::FAILURE
        }
        _ => ExitCode::SUCCESS,
    }
}

fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|cause| {
        cause
            .downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// Keep freed memory in the heap instead of handing it back to the
/// kernel (by a trim, or by unmapping a large block). The diagnosis
/// evaluates the model along a trial tens of thousands of times, each
/// evaluation allocating and freeing traces of ~100 kB; glibc trimmed the
/// heap after each free and the next evaluation faulted the pages back in
/// (a tissue-motion diagnosis: 9.7 s → 7.9 s on one core). A refused
/// setting (mallopt returns 0) only costs that time, so it is not checked.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn keep_freed_heap() {
    // SAFETY: mallopt only sets an allocator tunable; called before any
    // other thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 16 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 256 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn keep_freed_heap() {}
