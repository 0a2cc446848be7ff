//! `needle decode`: frames from a capture file or a serial port to text or
//! to the trial CSV (book, *Trial CSV*), reporting gaps and skipped bytes.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use needle_holder::faults::Faults;
use needle_holder::insertion::{EventKind, HaltReason, Phase, Sample};
use needle_holder::protocol::command::NO_READING_YET;
use needle_holder::protocol::{CommandError, TissueSource};
use needle_holder::units::MicroNewtons;

use crate::frames::{Item, Message, Missing, StreamDecoder, StreamStats};

#[derive(Debug, clap::Args)]
pub struct DecodeArgs {
    /// Capture file of raw frame bytes (what the device sent on its UART).
    #[arg(required_unless_present = "port", conflicts_with = "port")]
    pub file: Option<PathBuf>,
    /// Read from this serial port instead (e.g. /dev/ttyACM0).
    #[arg(long)]
    pub port: Option<String>,
    /// Serial baud rate.
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// Stop reading the port after this many seconds (default: until it closes).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Write samples as a trial CSV here; events, status and gaps still print.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Sample rate to assume when the stream holds no header or status frame.
    #[arg(long)]
    pub rate_hz: Option<u16>,
}

/// How long to read the port for: a finite, positive number of seconds
/// that a `Duration` holds (`inf` panicked converting; `-1`, `NaN` and `0`
/// read nothing and exited 0).
pub fn read_for(seconds: Option<f64>) -> Result<Option<Duration>> {
    let Some(s) = seconds else { return Ok(None) };
    if !(s.is_finite() && s > 0.0) {
        bail!("--seconds {s:?}: must be a number of seconds above 0 (leave it out to read until the port closes)");
    }
    Duration::try_from_secs_f64(s)
        .map(Some)
        .map_err(|_| anyhow::anyhow!("--seconds {s:?}: too long to wait for"))
}

pub fn run(args: &DecodeArgs) -> Result<()> {
    let read_for = read_for(args.seconds)?;
    crate::link::check_baud(args.baud)?;
    if args.rate_hz == Some(0) {
        bail!("--rate-hz 0: the sample rate must be at least 1 Hz");
    }
    // Opening the CSV truncates it: it must not be the capture being read.
    if let (Some(input), Some(csv)) = (&args.file, &args.csv) {
        if crate::input::same_file(input, csv) {
            bail!(
                "{}: --csv names the capture being decoded; writing it would empty it first",
                csv.display()
            );
        }
    }
    if let Some(csv) = &args.csv {
        if crate::input::is_stdout(csv) {
            bail!(
                "{}: --csv names standard output, where the text goes too: name a file",
                csv.display()
            );
        }
        crate::input::check_outputs(&[("--csv", csv)], &[])?;
    }
    // One decode to a CSV at a time: two at once interleaved their rows
    // and one's segment list named the other's segments.
    let _lock = match &args.csv {
        Some(csv) => Some(crate::input::lock_output(
            csv,
            &csv_lock_path(csv),
            "needle decode",
        )?),
        None => None,
    };
    // Ctrl-C, SIGTERM and SIGHUP end a decode to a CSV as its input's end
    // would: the rows in hand written whole, the segments listed.
    let stop = Arc::new(AtomicBool::new(false));
    if args.csv.is_some() {
        let flag = stop.clone();
        // A second signal ends it at once: a read from a pipe that sends
        // nothing is not interrupted by the first.
        ctrlc::set_handler(move || {
            if flag.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        })
        .context("cannot catch Ctrl-C, SIGTERM and SIGHUP")?;
    }
    let stopped = || stop.load(Ordering::SeqCst);
    let mut out = Output::new(args.csv.as_deref(), args.file.as_deref(), args.rate_hz);
    let mut decoder = StreamDecoder::new();
    let feed = |bytes: &[u8], decoder: &mut StreamDecoder, out: &mut Output| -> Result<()> {
        let mut items = Vec::new();
        decoder.feed(bytes, |item| items.push(item))?;
        items.into_iter().try_for_each(|item| out.item(item))
    };
    if let Some(path) = &args.file {
        read_blocks(path, &stopped, |block| feed(block, &mut decoder, &mut out))?;
    } else if let Some(port) = &args.port {
        let mut serial = serialport::new(port, args.baud)
            .timeout(Duration::from_millis(100))
            .open()
            .with_context(|| format!("{port}: cannot open serial port"))?;
        let deadline = read_for.and_then(|d| Instant::now().checked_add(d));
        let mut buf = [0u8; 4096];
        while deadline.is_none_or(|d| Instant::now() < d) && !stopped() {
            match serial.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => feed(&buf[..n], &mut decoder, &mut out)?,
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                Err(e) => return Err(e).with_context(|| format!("{port}: read failed")),
            }
        }
    }
    let mut tail = Vec::new();
    if stopped() {
        crate::note!("decode: stopped by a signal; what was read is written");
    }
    let stats = decoder.finish(|item| tail.push(item));
    tail.into_iter().try_for_each(|item| out.item(item))?;
    out.finish(&stats)?;
    if stats.frames == 0 {
        let source = match (&args.file, &args.port) {
            (Some(file), _) => file.display().to_string(),
            (None, Some(port)) => port.clone(),
            (None, None) => "the input".into(),
        };
        bail!(
            "{source}: no frame of the device's in {} bytes: not a capture of its serial output (a trial CSV or a replay file is none), or the wrong baud rate",
            stats.bytes
        );
    }
    Ok(())
}

/// The lock file of a `--csv` output: hidden beside it.
fn csv_lock_path(csv: &Path) -> std::path::PathBuf {
    let name = csv
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    csv.with_file_name(format!(".{name}.lock"))
}

/// Read a capture a block at a time into `each` (memory bounded whatever
/// the capture's size, time linear in it), with a progress line on stderr
/// every second while it lasts.
fn read_blocks(
    path: &Path,
    stopped: &dyn Fn() -> bool,
    mut each: impl FnMut(&[u8]) -> Result<()>,
) -> Result<()> {
    let shown = path.display();
    crate::input::not_a_device(path)?;
    let mut file = std::fs::File::open(path).with_context(|| format!("{shown}: cannot read"))?;
    let total = file.metadata().map_or(0, |m| m.len());
    let mut block = vec![0u8; 1 << 16];
    let (mut done, mut last_shown, mut progressed) = (0u64, Instant::now(), false);
    while !stopped() {
        let n = match file.read(&mut block) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e).with_context(|| format!("{shown}: cannot read")),
        };
        each(&block[..n])?;
        done += n as u64;
        if last_shown.elapsed() >= Duration::from_secs(1) {
            let percent = if total > 0 {
                100.0 * done as f64 / total as f64
            } else {
                0.0
            };
            crate::note_inline!(
                "\rdecode: {shown}: {:.0} MB of {:.0} MB ({percent:.0} %)",
                done as f64 / 1e6,
                total as f64 / 1e6
            );
            (last_shown, progressed) = (Instant::now(), true);
        }
    }
    if progressed {
        crate::note!("");
    }
    Ok(())
}

/// The CSV of segment `segment` (from 0): the first is `base` itself.
fn segment_path(base: &Path, segment: u32) -> PathBuf {
    if segment == 0 {
        return base.to_path_buf();
    }
    let stem = base
        .file_stem()
        .map_or_else(Default::default, |s| s.to_string_lossy().into_owned());
    let ext = base
        .extension()
        .map_or_else(String::new, |e| format!(".{}", e.to_string_lossy()));
    base.with_file_name(format!("{stem}-{}{ext}", segment + 1))
}

/// Where a decode lists the segment files it wrote beside `base`
/// (`NAME.csv.segments`), so that the next decode to the same `--csv` removes
/// those and nothing else (a file that merely looks like a segment may be
/// another decode's own output).
fn segment_list(base: &Path) -> PathBuf {
    let mut name = base.as_os_str().to_owned();
    name.push(".segments");
    PathBuf::from(name)
}

/// The path of `base`'s segment called `name` (`NAME-k.csv`, k ≥ 2), if
/// it is one.
fn segment_named(base: &Path, name: &str) -> Option<PathBuf> {
    let digits = name.rsplit_once('-')?.1.split('.').next()?;
    let k: u32 = digits.parse().ok().filter(|&k| k >= 2)?;
    let path = segment_path(base, k - 1);
    (crate::trial::name_of(&path) == name).then_some(path)
}

/// The segment files an earlier decode to `base` listed are removed, so
/// that no stale segment of another capture stays beside the new CSV for
/// `fit` to read as a trial; each must still carry decode's header.
fn remove_stale_segments(base: &Path) -> Result<()> {
    let list = segment_list(base);
    if !list.exists() {
        return Ok(());
    }
    let text = crate::input::read_small_text(&list)?;
    let header = CSV_HEADER.join(",");
    // Only names a segment of `base` can have: the list is a file anyone
    // can write (`../x.csv` in it is no segment), and a file of that name
    // holding anything else is no list of ours.
    let mut segments = Vec::new();
    for (k, line) in text.lines().enumerate().filter(|(_, l)| !l.is_empty()) {
        let (name, bytes) = line.rsplit_once(' ').unwrap_or((line, ""));
        match (segment_named(base, name), bytes.parse::<u64>()) {
            (Some(path), Ok(bytes)) => segments.push((path, bytes)),
            _ => bail!(
                "{}:{}: {:?} is no segment of --csv {}: this is no segment list of decode's; move it, or name another --csv",
                list.display(),
                k + 1,
                line.chars().take(40).collect::<String>(),
                base.display()
            ),
        }
    }
    for (path, bytes) in &segments {
        // A few bytes only, and from a regular file only: the name may
        // have become a link to a device or a pipe.
        let mut first = String::new();
        if crate::input::regular_file(path).is_ok() {
            let file = std::fs::File::open(path)
                .with_context(|| format!("{}: cannot read", path.display()))?;
            let _ = std::io::Read::read_to_string(
                &mut std::io::Read::take(file, header.len() as u64 + 2),
                &mut first,
            );
        }
        // Another size: written since (another decode to that name, say),
        // and no segment of ours any more.
        let same = std::fs::metadata(path).is_ok_and(|m| m.len() == *bytes);
        if same && first.lines().next() == Some(header.as_str()) {
            std::fs::remove_file(path)
                .with_context(|| format!("{}: cannot remove", path.display()))?;
            crate::note!(
                "removed {} (a segment of an earlier decode to the same --csv, listed in {})",
                path.display(),
                list.display()
            );
        }
    }
    std::fs::remove_file(&list).with_context(|| format!("{}: cannot remove", list.display()))
}

/// The most segments one decode writes: a stream whose index goes back
/// thousands of times is no device's run (9000 repeats made 9000 files).
const MOST_SEGMENTS: u32 = 1000;

/// A trial CSV with its header line.
pub fn create_csv(path: &Path) -> Result<csv::Writer<std::fs::File>> {
    let mut w = csv::Writer::from_path(path)
        .with_context(|| format!("{}: cannot create", path.display()))?;
    w.write_record(CSV_HEADER)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    Ok(w)
}

/// Samples to `--csv`, a file per segment (`NAME.csv`, `NAME-2.csv`, …),
/// each created at its first sample: a decode that finds no sample leaves
/// an earlier decode's files as they were.
struct SegmentedCsv {
    base: PathBuf,
    /// The capture being read, which no segment may write over.
    capture: Option<PathBuf>,
    /// The segment being written, and its writer.
    open: Option<(u32, csv::Writer<std::fs::File>)>,
    /// Samples written to each file created, in order.
    written: Vec<(PathBuf, u64)>,
    /// Whether [`Self::finish`] listed the segments.
    listed: bool,
}

/// A decode that fails part way (a stream with too many segments, a
/// segment's name taken, a full disk) lists the segments it wrote all the
/// same, so that the next decode to the same `--csv` removes them.
impl Drop for SegmentedCsv {
    fn drop(&mut self) {
        if !self.listed {
            let _ = self.close();
            let _ = self.list_segments();
        }
    }
}

impl SegmentedCsv {
    fn new(base: &Path, capture: Option<&Path>) -> Self {
        Self {
            base: base.to_path_buf(),
            capture: capture.map(Path::to_path_buf),
            open: None,
            written: Vec::new(),
            listed: false,
        }
    }

    /// Sample `s` of segment `segment` (from 0), its time at `rate_hz`.
    fn write(&mut self, segment: u32, s: &Sample, rate_hz: u16) -> Result<()> {
        if self.open.as_ref().map(|(k, _)| *k) != Some(segment) {
            self.start(segment)?;
        }
        if let (Some((_, w)), Some((path, n))) = (self.open.as_mut(), self.written.last_mut()) {
            w.write_record(csv_row(s, 0, rate_hz))
                .with_context(|| format!("{}: cannot write", path.display()))?;
            *n += 1;
        }
        Ok(())
    }

    fn start(&mut self, segment: u32) -> Result<()> {
        self.close()?;
        if self.written.is_empty() {
            remove_stale_segments(&self.base)?;
        }
        let path = segment_path(&self.base, segment);
        if let Some(capture) = self
            .capture
            .as_deref()
            .filter(|c| crate::input::same_file(c, &path))
        {
            bail!("{}: segment {} of --csv {} would be written over the capture being decoded: name another --csv", capture.display(), segment + 1, self.base.display());
        }
        if segment > 0 && path.exists() {
            bail!("{}: is where segment {} of --csv {} would go, and is no segment an earlier decode listed: move it, or name another --csv", path.display(), segment + 1, self.base.display());
        }
        if segment > MOST_SEGMENTS {
            bail!("more than {MOST_SEGMENTS} segments (the index went back that often): no capture of a device's run; stopped");
        }
        self.open = Some((segment, create_csv(&path)?));
        self.written.push((path, 0));
        Ok(())
    }

    /// The segment files written, with their sizes, for the next decode
    /// to the same `--csv` to remove ([`remove_stale_segments`]).
    fn list_segments(&self) -> Result<()> {
        if self.written.len() < 2 {
            return Ok(());
        }
        let list = segment_list(&self.base);
        // A link there would have the list written through it, elsewhere.
        if list.is_symlink() {
            std::fs::remove_file(&list)
                .with_context(|| format!("{}: cannot remove", list.display()))?;
        }
        let names: String = self
            .written
            .iter()
            .filter(|(p, _)| *p != self.base)
            .map(|(p, _)| {
                let bytes = std::fs::metadata(p).map_or(0, |m| m.len());
                format!("{} {bytes}\n", crate::trial::name_of(p))
            })
            .collect();
        std::fs::write(&list, names).with_context(|| format!("{}: cannot write", list.display()))
    }

    fn close(&mut self) -> Result<()> {
        let failed = self.failed();
        match self.open.take() {
            Some((_, mut w)) => w.flush().with_context(|| failed),
            None => Ok(()),
        }
    }

    /// What a failed write says: the file's name.
    fn failed(&self) -> String {
        let name = self.written.last().map_or(&self.base, |(p, _)| p);
        format!("{}: cannot write", name.display())
    }

    /// Close the file in hand and say what went where.
    fn finish(&mut self) -> Result<()> {
        self.close()?;
        self.list_segments()?;
        self.listed = true;
        let total: u64 = self.written.iter().map(|(_, n)| n).sum();
        match self.written.as_slice() {
            [] => crate::note!("no sample to write: {} not written", self.base.display()),
            [(path, _)] => crate::note!("wrote {total} samples to {}", path.display()),
            files => {
                let each: Vec<String> = files
                    .iter()
                    .map(|(p, n)| format!("{n} to {}", p.display()))
                    .collect();
                crate::note!("wrote {total} samples: {}", each.join(", "));
            }
        }
        Ok(())
    }
}

/// Where decoded items go: text lines, and samples to CSV when asked.
struct Output {
    text: std::io::BufWriter<crate::stdout::Named>,
    csv: Option<SegmentedCsv>,
    /// Segments begun after the first (the index went back).
    segment: u32,
    /// Samples of the segment in hand, written or held back.
    in_segment: u64,
    /// The rate the stream gave (header, status), or `--rate-hz` once it
    /// had to stand in for one.
    rate_hz: Option<u16>,
    /// `--rate-hz`: for a stream that gives no rate. The stream's own
    /// wins (it once silently rebuilt a 500 Hz capture's times at 65 kHz).
    fallback_hz: Option<u16>,
    /// Samples (and their segments) that arrived before the sample rate
    /// was known.
    pending: Vec<(u32, Sample)>,
    /// Rates later frames gave against the one in use, each said once.
    disagreeing: Vec<u16>,
}

/// Samples held back waiting for the stream to give its rate: a status
/// frame comes every 250 samples, so a stream this long without one gives
/// none, and `--rate-hz` (or an error) decides.
const MOST_PENDING: usize = 1 << 16;

impl Output {
    fn new(csv_path: Option<&Path>, capture: Option<&Path>, rate_hz: Option<u16>) -> Self {
        Self {
            text: crate::stdout::buffered(),
            csv: csv_path.map(|p| SegmentedCsv::new(p, capture)),
            segment: 0,
            in_segment: 0,
            rate_hz: None,
            fallback_hz: rate_hz,
            pending: Vec::new(),
            disagreeing: Vec::new(),
        }
    }

    fn item(&mut self, item: Item) -> Result<()> {
        if let Item::Sample(_) = item {
            self.in_segment += 1;
        }
        match item {
            Item::Sample(s) if self.csv.is_some() => self.sample_to_csv(s)?,
            Item::Sample(s) => writeln!(
                self.text,
                "{}",
                describe_sample(&s, self.rate_hz.or(self.fallback_hz))
            )?,
            // Snapshots are for the decoder; a status line says the same.
            Item::Frame(Message::Snapshot(_)) => {}
            Item::Frame(frame) => {
                match &frame {
                    Message::Header(h) => self.learn_rate(h.sample_rate_hz, "header")?,
                    Message::Status(s) => self.learn_rate(s.sample_rate_hz, "status")?,
                    Message::Config(c) => {
                        self.learn_rate(c.config.velocity.sample_rate_hz, "configuration")?
                    }
                    _ => {}
                }
                writeln!(
                    self.text,
                    "{}",
                    describe(&frame, self.rate_hz.or(self.fallback_hz))
                )?;
            }
            Item::Skipped { bytes, reason } => {
                writeln!(self.text, "skipped {bytes} bytes ({reason})")?
            }
            Item::Gap { first, last, why } => writeln!(
                self.text,
                "gap     samples {first}..={last} {} ({})",
                missing_name(why),
                last - first + 1
            )?,
            Item::Restart { last } => self.restart(last)?,
        }
        Ok(())
    }

    /// The index went back: samples from here on go to a new CSV
    /// (`NAME-2.csv`, `NAME-3.csv`, …), so no file's time goes back. A
    /// segment with no sample yet goes on.
    fn restart(&mut self, last: u32) -> Result<()> {
        const WHY: &str =
            "the index went back (a device restart, or a stretch of the stream twice)";
        if self.in_segment == 0 {
            writeln!(self.text, "restart after sample {last}: {WHY}; the segment in hand has no sample yet and goes on")?;
            return Ok(());
        }
        self.segment += 1;
        self.in_segment = 0;
        let goes = match &self.csv {
            Some(csv) => format!(
                "goes to {}",
                segment_path(&csv.base, self.segment).display()
            ),
            None => "begins".into(),
        };
        writeln!(
            self.text,
            "restart after sample {last}: {WHY}; segment {} {goes}",
            self.segment + 1
        )?;
        Ok(())
    }

    /// The rate a frame (`from`) gives: the first one sets the times; a
    /// later frame that says otherwise is named, once per rate (a header
    /// of 65 535 Hz beside a configuration of 500 Hz compressed the times
    /// 131-fold without a word).
    fn learn_rate(&mut self, rate_hz: u16, from: &str) -> Result<()> {
        if rate_hz == 0 {
            return Ok(());
        }
        if let Some(used) = self.rate_hz {
            if rate_hz != used && !self.disagreeing.contains(&rate_hz) {
                self.disagreeing.push(rate_hz);
                crate::note!("decode: a {from} frame says {rate_hz} Hz where the stream said {used} Hz before: the times stay at {used} Hz; the capture contradicts itself (a corrupt header, or frames from two devices)");
            }
            return Ok(());
        }
        if let Some(given) = self.fallback_hz.filter(|&g| g != rate_hz) {
            crate::note!("decode: the stream says {rate_hz} Hz; --rate-hz {given} is for a stream that says nothing, and is not used");
        }
        self.use_rate(rate_hz)
    }

    /// Times from here on at `rate_hz`, the samples held back first, each
    /// to its own segment's file.
    fn use_rate(&mut self, rate_hz: u16) -> Result<()> {
        self.rate_hz = Some(rate_hz);
        if let Some(csv) = self.csv.as_mut() {
            for (segment, s) in std::mem::take(&mut self.pending) {
                csv.write(segment, &s, rate_hz)?;
            }
        }
        Ok(())
    }

    fn sample_to_csv(&mut self, s: Sample) -> Result<()> {
        if let (Some(csv), Some(rate)) = (self.csv.as_mut(), self.rate_hz) {
            return csv.write(self.segment, &s, rate);
        }
        self.pending.push((self.segment, s));
        if self.pending.len() >= MOST_PENDING {
            match self.fallback_hz {
                Some(given) => self.use_rate(given)?,
                None => bail!("{MOST_PENDING} samples and no header, status or configuration frame gave the sample rate: pass --rate-hz"),
            }
        }
        Ok(())
    }

    fn finish(mut self, stats: &StreamStats) -> Result<()> {
        self.text.flush()?;
        if let (false, Some(given)) = (self.pending.is_empty(), self.fallback_hz) {
            self.use_rate(given)?;
        }
        if !self.pending.is_empty() {
            bail!(
                "{} samples but no header or status frame gave the sample rate: pass --rate-hz",
                self.pending.len()
            );
        }
        if let Some(csv) = self.csv.as_mut() {
            csv.finish()?;
        }
        crate::note!("{}", summary_line(stats));
        Ok(())
    }
}

/// The trial CSV's columns (book, *Trial CSV*), then the device's own.
pub const CSV_HEADER: [&str; 7] = [
    "t_s",
    "x_m",
    "f_n",
    "v_mps",
    "model_n",
    "residual_n",
    "phase",
];

/// One sample as a trial CSV row, its time from sample `first_index`.
pub fn csv_row(s: &Sample, first_index: u32, rate_hz: u16) -> [String; 7] {
    let t_s = f64::from(s.index.wrapping_sub(first_index)) / f64::from(rate_hz);
    csv_row_at(s, t_s, s.x.as_m())
}

/// One sample as a trial CSV row at time `t_s` and position `x_m` (a
/// recording's own, where the device's were counted from its first
/// sample).
pub fn csv_row_at(s: &Sample, t_s: f64, x_m: f64) -> [String; 7] {
    [
        format!("{t_s:.6}"),
        format!("{x_m:.9}"),
        format!("{:.6}", s.force.as_n()),
        format!("{:.9}", s.v.as_mps()),
        format!("{:.6}", s.model.as_n()),
        format!("{:.6}", s.residual.as_n()),
        phase_name(s.phase).to_string(),
    ]
}

/// One-line account of a stream.
pub fn summary_line(s: &StreamStats) -> String {
    format!(
        "{} frames ({} samples, {} events), {} gaps ({} samples lost, {} withheld), {} bytes skipped in {} runs{}",
        s.frames,
        s.samples,
        s.events,
        s.gaps,
        s.lost_samples,
        s.withheld_samples,
        s.skipped_bytes,
        s.skipped_runs,
        if s.restarts > 0 {
            format!(", {} restarts (new segments)", s.restarts)
        } else {
            String::new()
        }
    )
}

/// Phase name as used in CSV files and reports.
pub fn phase_name(phase: Phase) -> &'static str {
    match phase {
        Phase::Out => "out",
        Phase::Loading => "loading",
        Phase::Inserted => "inserted",
        Phase::Withdrawal => "withdrawal",
    }
}

/// Event kind name (book, *Names*, plus `fault`).
pub fn event_name(kind: EventKind) -> &'static str {
    match kind {
        EventKind::Contact => "contact",
        EventKind::Puncture => "puncture",
        EventKind::Structure => "structure",
        EventKind::Exit => "exit",
        EventKind::Fault => "fault",
    }
}

/// Comma-separated names of a fault set, or `none`.
pub fn fault_names(faults: Faults) -> String {
    if faults.is_empty() {
        return "none".into();
    }
    faults.names().collect::<Vec<_>>().join(",")
}

/// Why samples are missing, as decode says it.
pub fn missing_name(why: Missing) -> &'static str {
    use needle_holder::stream::Withheld;
    match why {
        Missing::Lost => "lost",
        Missing::Withheld(Withheld::OutOfStep) => "withheld (arrived while out of step, until the next snapshot)",
        Missing::Withheld(Withheld::Malformed) => "withheld (malformed batch)",
        Missing::Withheld(Withheld::CheckMismatch) => {
            "withheld (the device's check disagrees: this needle's core or configuration is not the device's)"
        }
    }
}

fn time_of(index: u32, rate_hz: Option<u16>) -> String {
    match rate_hz {
        Some(r) => format!("{:9.3} s", f64::from(index) / f64::from(r)),
        None => format!("#{index:>9}"),
    }
}

/// A sample as one line of text.
pub fn describe_sample(s: &Sample, rate_hz: Option<u16>) -> String {
    format!(
        "sample  {}  x {:8.3} mm  v {:7.3} mm/s  f {:7.3} N  model {:7.3} N  residual {:7.3} N  {}",
        time_of(s.index, rate_hz),
        s.x.as_m() * 1e3,
        s.v.as_mps() * 1e3,
        s.force.as_n(),
        s.model.as_n(),
        s.residual.as_n(),
        phase_name(s.phase)
    )
}

/// The name of a tissue source: the library entry's, or `uploaded`.
pub fn tissue_name(source: TissueSource) -> String {
    match source {
        TissueSource::Library(i) => needle_holder::model::params::LIBRARY
            .get(usize::from(i))
            .map_or_else(
                || format!("library entry {i}"),
                |(name, _)| (*name).to_string(),
            ),
        TissueSource::Uploaded => "uploaded".into(),
    }
}

/// Why the device refused a command, in words.
pub fn command_error(e: &CommandError) -> String {
    match e {
        CommandError::Corrupted => {
            "the command arrived corrupted (bad CRC or framing, or another protocol version)".into()
        }
        CommandError::Unknown => {
            "the device knows no such command (another protocol version?)".into()
        }
        CommandError::Stale { next_seq } => {
            format!("sequence number already used (the device takes {next_seq} next)")
        }
        CommandError::NoSuchTissue { library_len } => {
            format!("no such tissue: the library has {library_len} entries")
        }
        CommandError::InvalidTissue { field, problem } => {
            format!("tissue rejected: `{field}` {problem}")
        }
        CommandError::OutOfRange { field } if field.as_str() == NO_READING_YET => {
            "the load cell has given no reading yet to make its zero of: tare again in a moment"
                .into()
        }
        CommandError::OutOfRange { field } => format!("{field} is out of range"),
        CommandError::NeedleInTissue => {
            "the needle is in tissue: withdraw it first (a tare or a new gain would move the force under it)".into()
        }
        CommandError::LoadOnNeedle { force } => format!(
            "{:.3} N on the load cell is a load, not an offset (over 0.5 N)",
            MicroNewtons::from(*force).as_n()
        ),
        CommandError::HaltCausePersists { reason } => format!(
            "the halt's cause ({}) is still there",
            halt_reason_name((*reason).into())
        ),
    }
}

/// A frame as one line of text.
pub fn describe(frame: &Message, rate_hz: Option<u16>) -> String {
    let t = |index: u32| time_of(index, rate_hz);
    match frame {
        // The schema key from protocol 6 on (read as zeros before).
        Message::Header(h) if h.protocol_version >= 6 => {
            let key = crate::frames::hex(&h.schema_key);
            format!(
                "header  protocol {}, schema {key}, {} Hz",
                h.protocol_version, h.sample_rate_hz
            )
        }
        Message::Header(h) => {
            format!("header  protocol {}, {} Hz", h.protocol_version, h.sample_rate_hz)
        }
        Message::Config(c) => format!(
            "config  tissue {}, tare {} counts, gain {:.4} uN/count, {} nm/count, assist {:#04x}, target depth {:.1} mm",
            tissue_name(c.tissue),
            c.config.load_cell.tare_counts,
            f64::from(c.config.load_cell.gain_q16) / 65536.0,
            c.config.encoder.nm_per_count,
            c.config.assist.modes.0,
            c.config.assist.target_depth.as_m() * 1e3,
        ),
        Message::Snapshot(s) => format!("snapshot {}", t(s.next_index)),
        Message::Event(e) => format!(
            "event   {}  {:<9} x {:8.3} mm  f {:7.3} N  confidence {:.1} %",
            t(e.index),
            event_name(e.kind),
            e.x.as_m() * 1e3,
            e.force.as_n(),
            f64::from(e.confidence_permille) / 10.0
        ),
        Message::Status(s) => format!(
            "status  {} samples, {} frames dropped, {}faults {}, halt {}{}",
            s.samples,
            s.frames_dropped,
            // Protocol 5 on: older devices never counted them.
            if s.protocol_version >= 5 {
                format!(
                    "{} conversions lost, {} receive errors, ",
                    s.board.conversions_lost, s.board.line_errors
                )
            } else {
                String::new()
            },
            fault_names(s.faults.into()),
            if s.halt { "ASSERTED" } else { "released" },
            if s.streaming { "" } else { ", stream stopped" }
        ),
        Message::Halt(h) => format!(
            "HALT    {}  {:<12} x {:8.3} mm  hold at {:8.3} mm",
            t(h.index),
            halt_reason_name(h.reason),
            h.x.as_m() * 1e3,
            h.hold_x.as_m() * 1e3
        ),
        Message::SelfTest(t) => crate::selftest::summary(t),
        Message::Reply(r) => match &r.result {
            Ok(()) => format!("reply   command {} done", r.seq),
            Err(e) => format!("reply   command {} refused: {}", r.seq, command_error(e)),
        },
    }
}

/// The name of a halt reason.
pub fn halt_reason_name(reason: HaltReason) -> &'static str {
    match reason {
        HaltReason::Fault => "fault",
        HaltReason::Contact => "contact",
        HaltReason::Puncture => "puncture",
        HaltReason::Structure => "structure",
        HaltReason::Exit => "exit",
        HaltReason::TargetDepth => "target_depth",
        HaltReason::SpeedLimit => "speed_limit",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_status_names_the_boards_counters_and_the_new_faults() {
        let status = needle_holder::protocol::Status {
            protocol_version: needle_holder::protocol::PROTOCOL_VERSION,
            sample_rate_hz: 2000,
            samples: 10,
            frames_dropped: 0,
            faults: Faults::WATCHDOG_RESET.union(Faults::SETTINGS_STORE).into(),
            halt: true,
            streaming: true,
            next_command_seq: 1,
            board: needle_holder::protocol::BoardCounters {
                conversions_lost: 3,
                line_errors: 7,
            },
            schema_key: needle_holder::protocol::SCHEMA_KEY,
        };
        let said = describe(&Message::Status(status), Some(2000));
        assert!(
            said.contains("3 conversions lost, 7 receive errors")
                && said.contains("watchdog_reset")
                && said.contains("settings_store"),
            "{said}"
        );
    }

    #[test]
    fn a_tare_before_any_reading_says_so_and_not_out_of_range() {
        let said = command_error(&CommandError::out_of_range(NO_READING_YET));
        assert!(said.contains("no reading yet"), "{said}");
        assert!(!said.contains("out of range"), "{said}");
        let other = command_error(&CommandError::out_of_range("depth"));
        assert_eq!(other, "depth is out of range");
    }
}
