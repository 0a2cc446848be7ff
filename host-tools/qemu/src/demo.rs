//! `needle demo`: the whole chain on a fresh machine. Builds the firmware,
//! generates one liver-1 insertion as a replay, runs it in QEMU with UART0
//! connected to a loopback TCP socket, decodes the frames as they arrive
//! and says what happened.

use std::io::Read;
use std::net::TcpListener;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use needle_holder::insertion::{Event, EventKind, Sample};

use crate::firmware::{self, Board, Serial};
use needle_analysis::sim::{self, Plan, Truth};
use needle_holder::model::params::LIVER1;
use needle_io::decode::{describe, summary_line};
use needle_io::frames::{Item, Message, StreamDecoder};

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// QEMU board to run.
    #[arg(long, value_enum, default_value_t = Board::Lm3s6965)]
    pub board: Board,
    /// Directory for the replay, frame capture and defmt log (default:
    /// `demo/` in the target directory, `target/demo` unless
    /// `CARGO_TARGET_DIR` says otherwise).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

const QEMU_TIMEOUT: Duration = Duration::from_secs(120);

pub fn run(args: &DemoArgs) -> Result<()> {
    let demo = write_replay(args)?;
    firmware::ensure_qemu()?;
    needle_io::out!("building the firmware for {} …", args.board.target())?;
    let elf = firmware::build(args.board)?;
    let Demo {
        dir,
        replay: replay_path,
        truth,
    } = demo;

    let listener = TcpListener::bind("127.0.0.1:0").context("cannot listen on loopback")?;
    let addr = listener.local_addr()?;
    needle_io::out!(
        "running QEMU {:?}; frames UART → tcp {addr}, decoded as they arrive:",
        args.board
    )?;
    let cmd = firmware::qemu_command(args.board, &elf, &replay_path, Serial::Tcp(addr), &[]);
    let qemu = std::thread::spawn(move || firmware::run_qemu(cmd, QEMU_TIMEOUT));

    let (mut stream, _) = accept_within(&listener, Duration::from_secs(30))?;
    let mut decoder = StreamDecoder::new();
    let mut seen = Seen::default();
    let mut capture = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let n = stream.read(&mut buf).context("reading QEMU's UART")?;
        if n == 0 {
            break;
        }
        capture.extend_from_slice(&buf[..n]);
        decoder.feed(&buf[..n], |item| seen.item(item))?;
        seen.output_result()?;
    }
    let stats = decoder.finish(|item| seen.item(item));
    seen.output_result()?;
    let run = qemu
        .join()
        .map_err(|_| anyhow::anyhow!("QEMU thread panicked"))??
        .success()?;
    std::fs::write(dir.join("frames.bin"), &capture)?;
    std::fs::write(dir.join("defmt.bin"), &run.defmt)?;

    needle_io::out!("{}", summary_line(&stats))?;
    let (Some(contact), Some(puncture), Some(last)) = (seen.contact, seen.puncture, seen.last)
    else {
        bail!("the device did not report both contact and puncture");
    };
    let past_contact_mm = |x: f64| (x - contact.x.as_m()) * 1e3;
    needle_io::out!(
        "contact at x = {:.3} mm; puncture {:.2} mm past contact at {:.3} N \
         (simulated truth {:.2} mm, {:.3} N; paper 16.65 ± 3.55 mm, 2.30 ± 0.83 N)",
        contact.x.as_m() * 1e3,
        past_contact_mm(puncture.x.as_m()),
        puncture.force.as_n(),
        (truth.puncture_x_m - truth.contact_x_m) * 1e3,
        truth.puncture_force_n,
    )?;
    needle_io::out!(
        "deepest {:.2} mm past contact; final position {:.3} mm; {} faults",
        past_contact_mm(seen.deepest_m),
        last.x.as_m() * 1e3,
        seen.faults
    )?;
    needle_io::out!(
        "capture {} and defmt log {} kept (decode: needle decode FILE; defmt-print -e {} < LOG)",
        dir.join("frames.bin").display(),
        dir.join("defmt.bin").display(),
        elf.display()
    )?;
    if stats.gaps > 0 || stats.skipped_bytes > 0 || seen.faults > 0 {
        bail!("the stream was not clean: see above");
    }
    Ok(())
}

/// The demo's insertion, written as a replay file.
pub struct Demo {
    /// Where the demo keeps its files.
    pub dir: PathBuf,
    /// The replay of liver 1 under the paper's protocol.
    pub replay: PathBuf,
    pub truth: Truth,
}

/// Say what the demo inserts, and write its replay into the demo's
/// directory (`needle demo --live` serves the live view over it).
pub fn write_replay(args: &DemoArgs) -> Result<Demo> {
    let tissue = LIVER1;
    let plan = Plan::PAPER;
    needle_io::out!(
        "needle demo: liver 1 of the paper (a1 = {} N/m, a2 = {} N/m², puncture at {:.2} mm), {} mm/s, {} Hz",
        tissue.a1_n_per_m,
        tissue.a2_n_per_m2,
        tissue.puncture_depth_m * 1e3,
        plan.speed_mps * 1e3,
        plan.rate_hz
    )?;
    let dir = match &args.out {
        Some(dir) => dir.clone(),
        None => firmware::target_directory()?.join("demo"),
    };
    needle_io::input::create_out_dir(&dir)?;
    let (trial, truth, replay) = sim::insertion_replay(&tissue, &plan);
    let replay_path = dir.join("liver1.replay");
    std::fs::write(&replay_path, &replay)
        .with_context(|| format!("{}: cannot write", replay_path.display()))?;
    needle_io::out!(
        "replay: {} ({} samples, {:.1} s)",
        replay_path.display(),
        trial.len(),
        trial.t_s.last().unwrap_or(&0.0)
    )?;
    Ok(Demo {
        dir,
        replay: replay_path,
        truth,
    })
}

fn accept_within(
    listener: &TcpListener,
    limit: Duration,
) -> Result<(std::net::TcpStream, std::net::SocketAddr)> {
    listener.set_nonblocking(true)?;
    let deadline = Instant::now() + limit;
    loop {
        match listener.accept() {
            Ok((stream, addr)) => {
                stream.set_nonblocking(false)?;
                return Ok((stream, addr));
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock && Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => return Err(e).context("QEMU did not connect its UART"),
        }
    }
}

/// What the demo has seen so far; prints the interesting frames live.
#[derive(Default)]
struct Seen {
    rate_hz: Option<u16>,
    contact: Option<Event>,
    puncture: Option<Event>,
    last: Option<Sample>,
    deepest_m: f64,
    faults: u32,
    /// Standard output failed (the decoder's callback cannot return it).
    output_error: Option<anyhow::Error>,
}

impl Seen {
    fn output_result(&mut self) -> Result<()> {
        self.output_error.take().map_or(Ok(()), Err)
    }

    fn item(&mut self, item: Item) {
        if self.output_error.is_none() {
            if let Err(e) = self.show(item) {
                self.output_error = Some(e);
            }
        }
    }

    fn show(&mut self, item: Item) -> Result<()> {
        match item {
            Item::Sample(s) => {
                self.deepest_m = self.deepest_m.max(s.x.as_m());
                self.last = Some(s);
            }
            Item::Frame(frame) => {
                match &frame {
                    Message::Header(h) => self.rate_hz = Some(h.sample_rate_hz),
                    Message::Event(e) if e.kind == EventKind::Contact => self.contact = Some(*e),
                    Message::Event(e) if e.kind == EventKind::Puncture => self.puncture = Some(*e),
                    Message::Event(_) => self.faults += 1,
                    Message::Status(s) if !s.faults.is_empty() => self.faults += 1,
                    _ => {}
                }
                let quiet = match &frame {
                    Message::Status(s) => s.faults.is_empty() && s.samples % 2500 != 0,
                    Message::Snapshot(_) | Message::Config(_) => true,
                    _ => false,
                };
                if !quiet {
                    needle_io::out!("  {}", describe(&frame, self.rate_hz))?;
                }
            }
            other => needle_io::out!("  {other:?}")?,
        }
        Ok(())
    }
}
