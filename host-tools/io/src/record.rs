//! `needle record --port P --out DIR`: insertions from a device to trial
//! CSVs, one per insertion, split where the needle leaves the tissue, with
//! the device's own columns (velocity, model, residual, phase) after the
//! trial columns; the raw stream beside them (`stream.bin`, which `needle
//! decode` reads). Shows progress while recording; stops at Ctrl-C (or
//! when the device goes away, or after `--seconds`) and writes the trial
//! in progress first.
//!
//! Samples after the last exit with no insertion in them are no trial:
//! they stay in `stream.bin` only.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use needle_holder::insertion::{Phase, Sample};
use needle_holder::protocol::{BoardCounters, Command};

use crate::decode::{command_error, create_csv, csv_row, describe, missing_name};
use crate::frames::{Item, Message};
use crate::link::Link;

#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Serial port of the device (e.g. /dev/ttyACM0).
    #[arg(long)]
    pub port: String,
    /// Serial baud rate (the Nucleo-F411RE's is 921 600).
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// Directory for the trial CSVs (created; must hold no CSV yet).
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many seconds (default: Ctrl-C or the device going away).
    #[arg(long)]
    pub seconds: Option<f64>,
}

pub fn run(args: &RecordArgs) -> Result<()> {
    let until = crate::decode::read_for(args.seconds)?
        .map(|d| {
            Instant::now()
                .checked_add(d)
                .context("--seconds: too long to wait for")
        })
        .transpose()?;
    check_dir(&args.out)?;
    // Ctrl-C, `kill` and a closed terminal all end a recording the same
    // way: the trial in hand is written whole.
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
        .context("cannot catch Ctrl-C, SIGTERM and SIGHUP")?;
    let mut link = Link::open(&args.port, args.baud)?;
    link.keep_capture();
    if let Err(e) = link.command(Command::Stream(true))? {
        bail!(
            "{}: the device refused to stream: {}",
            args.port,
            command_error(&e)
        );
    }
    // Created once a device has answered: a port with no device behind
    // it left an empty directory.
    let mut recorder = Recorder::create(&args.out, None, "needle record")?;
    let (file, capture) = recorder.stream_file()?;
    link.capture_to(file, &capture)?;
    crate::note!(
        "recording from {} into {} (Ctrl-C stops)",
        args.port,
        args.out.display()
    );
    let recorded = record(&mut link, &mut recorder, &stop, until);
    if let Err(e) = recorded {
        recorder.abandon();
        show(&mut recorder);
        return Err(e);
    }
    let why = if link.closed() {
        "the device went away"
    } else if stop.load(Ordering::SeqCst) {
        "stopped by a signal"
    } else {
        "the recording ended"
    };
    let finished = recorder.finish(why);
    show(&mut recorder);
    finished?;
    crate::note!("{}", crate::decode::summary_line(&link.decoder().stats()));
    Ok(())
}

/// The recorder's lines, each above the progress line.
fn show(recorder: &mut Recorder) {
    for line in recorder.take_lines() {
        crate::note!("\r\x1b[K{line}");
    }
}

/// How long a device may send nothing at all (its status heartbeat comes
/// twice a second at 500 Hz) before `record` asks it to stream.
const SILENCE: Duration = Duration::from_secs(3);

/// Read the device into `recorder` until a signal, `until`, or the
/// device goes away.
fn record(
    link: &mut Link,
    recorder: &mut Recorder,
    stop: &AtomicBool,
    until: Option<Instant>,
) -> Result<()> {
    let mut shown = Instant::now();
    let mut asked: Option<Instant> = None;
    let mut heard = Instant::now();
    while !stop.load(Ordering::SeqCst) && !link.closed() && until.is_none_or(|u| Instant::now() < u)
    {
        for item in link.poll()? {
            heard = Instant::now();
            recorder.item(&item)?;
        }
        if let Some(e) = link.take_capture_error() {
            return Err(e);
        }
        show(recorder);
        // Nothing at all, not even a heartbeat: a device that was reset
        // and waits for its host (the QEMU replay does) is asked to stream.
        if heard.elapsed() >= SILENCE && asked.is_none_or(|a| a.elapsed() >= SILENCE) {
            recorder.stream_off = true;
            recorder.line(&format!(
                "nothing from the device for {} s (reset, or unplugged and back?)",
                SILENCE.as_secs()
            ));
        }
        // A device told by another program to stop streaming (or one that
        // came back with its stream off) sends no samples until asked:
        // recording on in silence waited forever. Asked again, at most
        // once a second.
        if recorder.take_stream_off() && asked.is_none_or(|a| a.elapsed() >= Duration::from_secs(1))
        {
            asked = Some(Instant::now());
            // No answer (the device going away, say) ends nothing here:
            // the loop's own checks close the trial as they would have.
            let answer = match link.command(Command::Stream(true)) {
                Ok(Ok(())) => "asked for it again".to_owned(),
                Ok(Err(e)) => format!("asked for it again, refused: {}", command_error(&e)),
                Err(e) => format!("asked for it again, no answer: {e:#}"),
            };
            recorder.line(&format!(
                "the device's stream is off (another program turned it off, or the device came back with it off): {answer}"
            ));
        }
        show(recorder);
        if shown.elapsed() >= Duration::from_millis(500) {
            if let Some(progress) = recorder.progress() {
                crate::note_inline!("\r\x1b[K{progress}");
            }
            shown = Instant::now();
        }
    }
    for item in link.finish() {
        recorder.item(&item)?;
    }
    if link.closed() {
        recorder.line("the device went away (its port closed)");
    }
    Ok(())
}

/// The output directory, if it exists: a directory without trial CSVs
/// that the new ones would mix with.
fn check_dir(dir: &Path) -> Result<()> {
    crate::input::out_dir(dir)?;
    if !dir.exists() {
        return Ok(());
    }
    let existing = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot read", dir.display()))?
        .filter_map(|e| e.ok())
        .any(|e| {
            let name = e.file_name();
            crate::trial::is_trial_csv(&e.path())
                || name == "stream.bin"
                || name.to_string_lossy().ends_with(".csv.part")
        });
    if existing {
        bail!(
            "{}: already holds CSV files or a stream.bin (an earlier session's); record into an empty directory",
            dir.display()
        );
    }
    Ok(())
}

/// One trial being written, under a temporary name (`trial_NNN.csv.part`,
/// which no command reads as a trial) until it is whole.
struct TrialFile {
    path: PathBuf,
    part: PathBuf,
    writer: csv::Writer<std::fs::File>,
    first_index: u32,
    samples: u64,
    entered: bool,
    last: Option<Sample>,
}

/// Splits a device's samples into trials and writes them, one CSV an
/// insertion, as `needle record` does (and `needle live` when asked to
/// record). What it has to say — a trial written, a gap, an event — it
/// keeps for its caller to show ([`Recorder::take_lines`]).
pub struct Recorder {
    dir: PathBuf,
    rate_hz: Option<u16>,
    pending: Vec<Sample>,
    current: Option<TrialFile>,
    written: usize,
    /// Samples before the needle was first seen out of tissue: the tail of
    /// an insertion under way when the recording began, no trial.
    before_out: Option<u64>,
    /// A status frame said the device's stream is off since
    /// [`Recorder::take_stream_off`] last looked.
    stream_off: bool,
    /// The board's counters as the last status gave them: a rise is
    /// reported once.
    board: BoardCounters,
    lines: Vec<String>,
    /// Whether events, halts and replies get a line each (a terminal has
    /// no other place for them; the live page lists them itself).
    frame_lines: bool,
    /// One recording into a directory at a time.
    _lock: crate::input::OutputLock,
}

impl Recorder {
    /// A recording into `dir` (created if missing; it must hold no trial
    /// CSV or stream yet, and no other recording may be writing to it),
    /// of a device sampling at `rate_hz` if known (else from its first
    /// header or status frame); `by` names the program in the lock.
    pub fn create(dir: &Path, rate_hz: Option<u16>, by: &str) -> Result<Self> {
        check_dir(dir)?;
        crate::input::create_out_dir(dir)?;
        // Two recordings into one directory replaced each other's trials,
        // both saying they succeeded; and, the lock taken, the directory
        // is checked again: another may have recorded into it since.
        let lock = crate::input::lock_output(dir, &dir.join(".needle-record.lock"), by)?;
        check_dir(dir)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            rate_hz: rate_hz.filter(|&r| r > 0),
            pending: Vec::new(),
            current: None,
            written: 0,
            before_out: Some(0),
            stream_off: false,
            board: BoardCounters::default(),
            lines: Vec::new(),
            frame_lines: true,
            _lock: lock,
        })
    }

    /// No line for each event, halt and reply: the caller shows them.
    pub fn without_frame_lines(mut self) -> Self {
        self.frame_lines = false;
        self
    }

    /// `stream.bin` in the recording's directory, new, for the raw bytes
    /// (`needle decode` reads it).
    pub fn stream_file(&self) -> Result<(std::fs::File, PathBuf)> {
        let path = self.dir.join("stream.bin");
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
            .with_context(|| format!("{}: cannot create", path.display()))?;
        Ok((file, path))
    }

    /// The directory the trials go to.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Trials written so far.
    pub fn written(&self) -> usize {
        self.written
    }

    /// What the recorder has said since the last call, oldest first.
    pub fn take_lines(&mut self) -> Vec<String> {
        std::mem::take(&mut self.lines)
    }

    /// Whether a status frame said the device's stream is off since the
    /// last call.
    pub fn take_stream_off(&mut self) -> bool {
        std::mem::take(&mut self.stream_off)
    }

    /// One item from the device's stream.
    pub fn item(&mut self, item: &Item) -> Result<()> {
        match item {
            Item::Sample(s) => self.sample(*s)?,
            Item::Frame(Message::Header(h)) => self.learn_rate(h.sample_rate_hz)?,
            Item::Frame(Message::Status(s)) => {
                self.stream_off |= !s.streaming;
                if s.board != self.board {
                    // The counters start again at a device's boot.
                    if s.board.conversions_lost > self.board.conversions_lost
                        || s.board.line_errors > self.board.line_errors
                    {
                        self.line(&format!(
                            "board   {} conversions lost, {} receive errors since the device started",
                            s.board.conversions_lost, s.board.line_errors
                        ));
                    }
                    self.board = s.board;
                }
                self.learn_rate(s.sample_rate_hz)?
            }
            Item::Frame(frame @ (Message::Event(_) | Message::Halt(_) | Message::Reply(_))) => {
                if self.frame_lines {
                    self.line(&describe(frame, self.rate_hz))
                }
            }
            Item::Gap { first, last, why } => self.line(&format!(
                "gap     samples {first}..={last} {} ({})",
                missing_name(*why),
                last - first + 1
            )),
            Item::Skipped { bytes, reason } => {
                self.line(&format!("skipped {bytes} bytes ({reason})"))
            }
            // The device restarted: the trial in hand ends there.
            Item::Restart { last } => {
                self.line(&format!("the device restarted after sample {last}"));
                self.close("the device restarted")?;
                self.before_out = Some(0);
            }
            Item::Frame(_) => {}
        }
        Ok(())
    }

    fn line(&mut self, text: &str) {
        self.lines.push(text.to_owned());
    }

    fn learn_rate(&mut self, rate_hz: u16) -> Result<()> {
        if self.rate_hz.is_none() && rate_hz > 0 {
            self.rate_hz = Some(rate_hz);
            for s in std::mem::take(&mut self.pending) {
                self.sample(s)?;
            }
        }
        Ok(())
    }

    fn sample(&mut self, s: Sample) -> Result<()> {
        let Some(rate) = self.rate_hz else {
            self.pending.push(s);
            return Ok(());
        };
        // A trial begins with the needle out: what comes before is the
        // rest of an insertion that began before the recording did.
        if let Some(n) = self.before_out {
            if s.phase != Phase::Out {
                self.before_out = Some(n + 1);
                return Ok(());
            }
            self.before_out = None;
            if n > 0 {
                self.line(&format!(
                    "{n} samples of an insertion under way when the recording began: in stream.bin only, no trial"
                ));
            }
        }
        if self.current.is_none() {
            let path = self.dir.join(format!("trial_{:03}.csv", self.written));
            let part = self.dir.join(format!("trial_{:03}.csv.part", self.written));
            let writer = create_csv(&part)?;
            self.current = Some(TrialFile {
                path,
                part,
                writer,
                first_index: s.index,
                samples: 0,
                entered: false,
                last: None,
            });
        }
        let Some(trial) = self.current.as_mut() else {
            return Ok(());
        };
        trial
            .writer
            .write_record(csv_row(&s, trial.first_index, rate))
            .with_context(|| format!("{}: cannot write", trial.part.display()))?;
        trial.samples += 1;
        trial.last = Some(s);
        if s.phase != Phase::Out {
            trial.entered = true;
        } else if trial.entered {
            // The needle left the tissue: this insertion is complete.
            self.close("the needle left the tissue")?;
        }
        Ok(())
    }

    /// Write the trial in hand, ended for `why`; one with no insertion is
    /// no trial.
    fn close(&mut self, why: &str) -> Result<()> {
        let Some(mut trial) = self.current.take() else {
            return Ok(());
        };
        trial
            .writer
            .flush()
            .with_context(|| format!("{}: cannot write", trial.part.display()))?;
        drop(trial.writer);
        if !trial.entered {
            std::fs::remove_file(&trial.part)
                .with_context(|| format!("{}: cannot remove", trial.part.display()))?;
            self.line(&format!(
                "{} samples after the last insertion (no tissue in them): kept in stream.bin only",
                trial.samples
            ));
            return Ok(());
        }
        std::fs::rename(&trial.part, &trial.path).with_context(|| {
            format!(
                "{}: cannot rename to {}",
                trial.part.display(),
                trial.path.display()
            )
        })?;
        let rate = f64::from(self.rate_hz.unwrap_or(1));
        self.line(&format!(
            "{}: {} samples, {:.2} s ({why})",
            trial.path.display(),
            trial.samples,
            trial.samples as f64 / rate
        ));
        self.written += 1;
        Ok(())
    }

    /// After a failure (a full disk, say): the trial in hand stays under
    /// its temporary name, as far as it could be written, and is named.
    pub fn abandon(&mut self) {
        if let Some(mut trial) = self.current.take() {
            let _ = trial.writer.flush();
            self.line(&format!(
                "{}: the trial in hand, incomplete ({} samples), left under this name",
                trial.part.display(),
                trial.samples
            ));
        }
    }

    /// The trial in hand, in a line: its length, where the needle is,
    /// the force, the phase.
    pub fn progress(&self) -> Option<String> {
        let (trial, rate) = (self.current.as_ref()?, self.rate_hz?);
        let s = trial.last?;
        Some(format!(
            "trial {}: {:.1} s, {} samples, x {:.2} mm, f {:.3} N, {}",
            self.written,
            trial.samples as f64 / f64::from(rate),
            trial.samples,
            s.x.as_m() * 1e3,
            s.force.as_n(),
            crate::decode::phase_name(s.phase)
        ))
    }

    /// End the recording, for `why`: the trial in hand is written (if the
    /// needle entered the tissue in it).
    pub fn finish(&mut self, why: &str) -> Result<()> {
        if let Some(n) = self.before_out.filter(|&n| n > 0) {
            self.line(&format!(
                "{n} samples, all of an insertion under way when the recording began: in stream.bin only, no trial"
            ));
            self.before_out = None;
        }
        if !self.pending.is_empty() {
            bail!(
                "{} samples but no header or status frame gave the sample rate",
                self.pending.len()
            );
        }
        self.close(why)?;
        let done = format!("{} trials in {}", self.written, self.dir.display());
        self.line(&done);
        Ok(())
    }
}
