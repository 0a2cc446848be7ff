//! Trial CSV files (book, *Trial CSV*): header `t_s,x_m,f_n`, extra columns
//! allowed. Readers reject bad files with the file and line at fault.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

/// One trial: time, position, force, all SI.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trial {
    pub t_s: Vec<f64>,
    pub x_m: Vec<f64>,
    pub f_n: Vec<f64>,
}

impl Trial {
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Sample rate, Hz, from the median time step (robust to a late sample).
    pub fn rate_hz(&self) -> f64 {
        median_rate_hz(&self.t_s)
    }

    /// Every `step`-th sample, from the first: a slower rig's recording of
    /// the same insertion (no averaging, so the encoder's positions stay
    /// on its grid and the force keeps its per-sample noise).
    pub fn thinned(&self, step: usize) -> Trial {
        Trial {
            t_s: every(&self.t_s, step),
            x_m: every(&self.x_m, step),
            f_n: every(&self.f_n, step),
        }
    }

    /// The step [`Self::thinned`] takes to bring this trial to `most_hz`
    /// or below: 1 when it is there already.
    pub fn thinning_step(&self, most_hz: f64) -> usize {
        step_to(self.rate_hz(), most_hz)
    }

    pub fn push(&mut self, t_s: f64, x_m: f64, f_n: f64) {
        self.t_s.push(t_s);
        self.x_m.push(x_m);
        self.f_n.push(f_n);
    }
}

/// Sample rate, Hz, from the median step of increasing times; 0 for fewer
/// than two.
fn median_rate_hz(t_s: &[f64]) -> f64 {
    median_step_s(t_s).map_or(0.0, |dt| 1.0 / dt)
}

/// Samples a time step is measured over: times written to the
/// microsecond make a 65 535 Hz recording's single steps 15 or 16 µs (a
/// median of 16 µs read it as 62.5 kHz); over 16 samples the rounding is
/// a sixteenth as large, and a gap or a late sample still moves only the
/// span it falls in, which the median passes over.
const STEP_SPAN: usize = 16;

/// The median step of the times, each measured over [`STEP_SPAN`]
/// samples (fewer when there are not so many); `None` for fewer than two.
fn median_step_s(t_s: &[f64]) -> Option<f64> {
    let span = STEP_SPAN.min(t_s.len().saturating_sub(1)).max(1);
    let mut dt: Vec<f64> = t_s
        .windows(span + 1)
        .step_by(span)
        .map(|w| (w[span] - w[0]) / span as f64)
        .collect();
    let mid = dt.len() / 2;
    (!dt.is_empty()).then(|| *dt.select_nth_unstable_by(mid, f64::total_cmp).1)
}

/// The thinning step that brings `rate_hz` to `most_hz` or below. A ratio a
/// hair above a whole number (2000.0000000011 Hz from microsecond
/// timestamps) is that number: 2 kHz is not halved, 10 kHz taken 1 in 5.
fn step_to(rate_hz: f64, most_hz: f64) -> usize {
    let ratio = rate_hz / most_hz;
    if ratio.is_finite() && ratio > 1.0 {
        ((ratio - 1e-6).ceil() as usize).max(1)
    } else {
        1
    }
}

/// Every `step`-th value, from the first.
pub fn every<T: Copy>(values: &[T], step: usize) -> Vec<T> {
    values.iter().step_by(step.max(1)).copied().collect()
}

/// The longest line a trial CSV may have: a row of a few numbers is tens
/// of bytes; a 1 GB line made the reader hold 3 GB.
pub const MOST_LINE_BYTES: usize = 64 << 10;

/// A reader that fails at a line longer than [`MOST_LINE_BYTES`], naming
/// the file and line, so that the CSV reader's buffer stays bounded.
struct LineLimit<R> {
    inner: R,
    line: u64,
    in_line: usize,
}

impl<R: std::io::Read> std::io::Read for LineLimit<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        for &b in &buf[..n] {
            // A bare `\r` ends a line too (old exporters), for the length.
            if b == b'\n' || b == b'\r' {
                self.line += u64::from(b == b'\n');
                self.in_line = 0;
            } else {
                self.in_line += 1;
                if self.in_line > MOST_LINE_BYTES {
                    return Err(std::io::Error::other(LineTooLong { line: self.line }));
                }
            }
        }
        Ok(n)
    }
}

/// The error [`LineLimit`] stops at.
#[derive(Debug)]
struct LineTooLong {
    line: u64,
}

impl std::fmt::Display for LineTooLong {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "a line longer than {MOST_LINE_BYTES} bytes: no trial CSV has one"
        )
    }
}

impl std::error::Error for LineTooLong {}

/// A CSV reader on `path`, which must be a regular file: a `.csv` link to
/// `/dev/zero` made the reader allocate 4 GiB for a header that never
/// ends, and aborted.
fn open_csv(path: &Path) -> Result<csv::Reader<LineLimit<std::fs::File>>> {
    crate::input::regular_file(path)?;
    let shown = path.display();
    let file = std::fs::File::open(path).with_context(|| format!("{shown}: cannot open"))?;
    let limited = LineLimit {
        inner: file,
        line: 1,
        in_line: 0,
    };
    Ok(csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(limited))
}

/// A CSV reader's error as said to a user, with file and line: a line
/// too long knows its own line.
fn csv_error(path: &Path, line: u64, e: csv::Error) -> anyhow::Error {
    let line = e.position().map_or(line, |p| p.line());
    let shown = path.display();
    match e.kind() {
        csv::ErrorKind::Io(io) => {
            match io.get_ref().and_then(|i| i.downcast_ref::<LineTooLong>()) {
                Some(long) => anyhow::anyhow!("{shown}:{}: {long}", long.line),
                None => anyhow::anyhow!("{shown}:{line}: cannot read: {io}"),
            }
        }
        _ => anyhow::anyhow!("{shown}:{line}: malformed CSV: {e}"),
    }
}

/// A value quoted in a message, cut to 40 characters (a 10 MB field was
/// echoed whole to stderr and into the JSON's `skipped`).
fn quoted(text: &str) -> String {
    match text.char_indices().nth(40) {
        Some((cut, _)) => format!("{:?}…", &text[..cut]),
        None => format!("{text:?}"),
    }
}

/// Each row of a trial CSV in one pass, as the values of `columns` (the
/// first must be `t_s`; unused places 0), checking columns, numbers and
/// time order; returns the number of rows. `progress` hears of long reads.
fn each_row(
    path: &Path,
    columns: &[&str],
    mut progress: Option<&mut Progress>,
    mut row: impl FnMut([f64; 4]) -> Result<()>,
) -> Result<usize> {
    let shown = path.display();
    let mut reader = open_csv(path)?;
    let headers = reader.headers().map_err(|e| csv_error(path, 1, e))?;
    let at = columns
        .iter()
        .map(|name| {
            let hint = if TRIAL.contains(name) {
                " (a trial needs t_s,x_m,f_n)"
            } else {
                ""
            };
            headers
                .iter()
                .position(|h| h == *name)
                .with_context(|| format!("{shown}:1: no `{name}` column{hint}"))
        })
        .collect::<Result<Vec<usize>>>()?;
    let mut last_t_s: Option<f64> = None;
    let mut rows: usize = 0;
    let mut record = csv::StringRecord::new();
    while reader
        .read_record(&mut record)
        .map_err(|e| csv_error(path, rows as u64 + 2, e))?
    {
        let line = record.position().map_or(0, |p| p.line());
        let mut values = [0.0_f64; 4];
        for ((value, &i), name) in values.iter_mut().zip(&at).zip(columns) {
            let text = record.get(i).unwrap_or("");
            *value = text.parse().map_err(|_| {
                anyhow::anyhow!("{shown}:{line}: `{name}` is not a number: {}", quoted(text))
            })?;
            if !value.is_finite() {
                bail!("{shown}:{line}: `{name}` is not finite: {}", quoted(text));
            }
        }
        let t = values[0];
        if let Some(last) = last_t_s.filter(|&last| t <= last) {
            bail!("{shown}:{line}: time does not increase ({t} s after {last} s)");
        }
        last_t_s = Some(t);
        row(values)?;
        rows += 1;
        if rows.is_multiple_of(1 << 16) {
            if let Some(p) = progress.as_deref_mut() {
                p.say(|| format!("reading {shown}: {rows} rows"));
            }
        }
    }
    if rows == 0 {
        bail!("{shown}: no samples");
    }
    Ok(rows)
}

const TRIAL: [&str; 3] = ["t_s", "x_m", "f_n"];

/// Read a whole trial, checking columns, numbers and time order.
pub fn read(path: &Path) -> Result<Trial> {
    let mut trial = Trial::default();
    each_row(path, &TRIAL, None, |[t, x, f, _]| {
        trial.push(t, x, f);
        Ok(())
    })?;
    Ok(trial)
}

/// The fastest rate the analyses (`fit`, `detect`, `diagnose`) read a trial
/// at: the device's own top rate (the ADS1220's 2 kSPS). A faster
/// recording is thinned as it is read, as [`Trial::thinned`] does.
pub const ANALYSIS_MOST_HZ: f64 = 2000.0;

/// The most samples of one trial the analyses hold: 2¹⁹, i.e. 4.4 min at
/// 2 kHz, 17 min at 500 Hz, 87 min at 100 Hz — far more than an
/// insertion. A longer recording is thinned further, by halves, so that
/// memory stays bounded whatever the file's length.
pub const ANALYSIS_MOST_SAMPLES: usize = 1 << 19;

/// The fastest sample rate a trial may have: a median time step below a
/// microsecond is no load-cell recording (more likely times in another
/// unit), and a step of 1e-310 s made the rate infinite and the thinning
/// keep one sample.
pub const FASTEST_TRIAL_HZ: f64 = 1e6;

/// Rows read before the first is dropped: the rate is the median step of
/// these, which one late sample or a gap does not move.
const PROBE_ROWS: usize = 1024;

/// A trial as the analyses read it: every `step`-th of its `rows` rows.
#[derive(Clone, Debug, PartialEq)]
pub struct Analysed {
    pub trial: Trial,
    pub rows: usize,
    pub step: usize,
}

impl Analysed {
    /// What the thinning did, for a note on stderr; `None` when every row
    /// was kept.
    pub fn thinning_note(&self, path: &Path) -> Option<String> {
        (self.step > 1).then(|| {
            format!(
                "{}: {} rows, thinned to 1 in {} ({} samples at {:.0} Hz) to stay within {} Hz and {} samples",
                path.display(),
                self.rows,
                self.step,
                self.trial.len(),
                self.trial.rate_hz(),
                ANALYSIS_MOST_HZ,
                ANALYSIS_MOST_SAMPLES
            )
        })
    }
}

/// Rows kept as they stream in, in memory bounded by
/// [`ANALYSIS_MOST_SAMPLES`]: once the probe has set the step, row `i` is
/// kept when `i % step == 0`; when the kept rows reach the bound, the
/// step doubles and every other kept row goes, which keeps exactly the
/// rows of the new step. One pass, linear time.
struct Thinner<'a> {
    /// The file, for the message when its rate is beyond any rig's.
    path: &'a Path,
    kept: Vec<[f64; 4]>,
    rows: usize,
    /// 0 until the probe has set it.
    step: usize,
}

impl<'a> Thinner<'a> {
    fn new(path: &'a Path) -> Self {
        Self {
            path,
            kept: Vec::with_capacity(PROBE_ROWS),
            rows: 0,
            step: 0,
        }
    }

    /// Take one row; an error as soon as the probe finds the rate beyond
    /// any rig's, before the rest of the file is read.
    fn push(&mut self, row: [f64; 4]) -> Result<()> {
        let i = self.rows;
        self.rows += 1;
        if self.step == 0 {
            self.kept.push(row);
            if self.kept.len() == PROBE_ROWS {
                self.set_step()?;
            }
        } else if i.is_multiple_of(self.step) {
            self.kept.push(row);
            if self.kept.len() >= ANALYSIS_MOST_SAMPLES {
                self.step *= 2;
                self.keep_every(2);
            }
        }
        Ok(())
    }

    fn set_step(&mut self) -> Result<()> {
        let t_s: Vec<f64> = self.kept.iter().map(|r| r[0]).collect();
        let step_s = median_step_s(&t_s);
        // A step of 1e-310 s (an infinite rate) is below the bound too.
        if let Some(dt) = step_s.filter(|&dt| dt < 1.0 / FASTEST_TRIAL_HZ) {
            bail!(
                "{}:2-{}: the median time step is {dt:e} s, faster than any rig ({FASTEST_TRIAL_HZ:e} Hz at most): is t_s in seconds?",
                self.path.display(),
                self.kept.len() + 1,
            );
        }
        self.step = step_to(step_s.map_or(0.0, |dt| 1.0 / dt), ANALYSIS_MOST_HZ);
        self.keep_every(self.step);
        Ok(())
    }

    fn keep_every(&mut self, n: usize) {
        let mut k: usize = 0;
        self.kept.retain(|_| {
            k += 1;
            (k - 1).is_multiple_of(n)
        });
    }

    /// The kept rows, the rows read and the step.
    fn finish(mut self) -> Result<(Vec<[f64; 4]>, usize, usize)> {
        if self.step == 0 {
            self.set_step()?;
        }
        Ok((self.kept, self.rows, self.step))
    }
}

/// Read a trial for analysis, in one pass and bounded memory (see
/// [`ANALYSIS_MOST_HZ`], [`ANALYSIS_MOST_SAMPLES`]).
pub fn read_for_analysis(path: &Path, progress: Option<&mut Progress>) -> Result<Analysed> {
    let mut thinner = Thinner::new(path);
    each_row(path, &TRIAL, progress, |row| thinner.push(row))?;
    let (kept, rows, step) = thinner.finish()?;
    let mut trial = Trial::default();
    for [t, x, f, _] in kept {
        trial.push(t, x, f);
    }
    Ok(Analysed { trial, rows, step })
}

/// An extra column of a trial CSV by name (e.g. `model_n` of `needle
/// decode --csv`), with the checks of [`read`], at the rows
/// [`read_for_analysis`] keeps of the same file.
pub fn read_column_for_analysis(path: &Path, name: &str) -> Result<Vec<f64>> {
    let mut thinner = Thinner::new(path);
    each_row(path, &["t_s", name], None, |row| thinner.push(row))?;
    Ok(thinner.finish()?.0.iter().map(|r| r[1]).collect())
}

/// Write a trial CSV (`t_s,x_m,f_n`; µs, nm and µN resolution); a trial
/// with a value that is not finite is refused before the file is touched.
pub fn write(path: &Path, trial: &Trial) -> Result<()> {
    use std::io::Write;
    let rows = || (0..trial.len()).map(|i| [trial.t_s[i], trial.x_m[i], trial.f_n[i]]);
    if let Some((i, row)) = rows()
        .enumerate()
        .find(|(_, r)| !r.iter().all(|v| v.is_finite()))
    {
        bail!(
            "{}:{}: a value is not finite ({row:?}): not written",
            path.display(),
            i + 2
        );
    }
    let file = std::fs::File::create(path)
        .with_context(|| format!("{}: cannot create", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    let failed = || format!("{}: cannot write", path.display());
    writeln!(out, "t_s,x_m,f_n").with_context(failed)?;
    for [t, x, f] in rows() {
        writeln!(out, "{t:.6},{x:.9},{f:.6}").with_context(failed)?;
    }
    out.flush().with_context(failed)
}

/// A progress line on stderr for work that lasts: nothing for the first
/// second, then at most one line a second.
pub struct Progress {
    command: String,
    started: std::time::Instant,
    last: Option<std::time::Instant>,
}

impl Progress {
    pub fn new(command: &str) -> Self {
        Self {
            command: command.to_owned(),
            started: std::time::Instant::now(),
            last: None,
        }
    }

    /// Say `what` if a second has passed since the start and since the
    /// last line.
    pub fn say(&mut self, what: impl FnOnce() -> String) {
        let now = std::time::Instant::now();
        let second = std::time::Duration::from_secs(1);
        if now - self.started >= second && self.last.is_none_or(|l| now - l >= second) {
            crate::note!(
                "needle {}: {:5.1} s: {}",
                self.command,
                (now - self.started).as_secs_f64(),
                what()
            );
            self.last = Some(now);
        }
    }
}

/// A dataset's trials that could be read, with their files.
pub type Dataset = Vec<(PathBuf, Trial)>;

/// A trial's name in its dataset (its file name), as the commands' JSON
/// names it.
pub fn name_of(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Whether `path` is named as a trial CSV (`*.csv`, in any case).
pub fn is_trial_csv(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
}

/// An entry of a command's JSON `skipped` list: a trial left out, by its
/// file's name in the dataset (as the JSON's trials name theirs), and why.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Skipped {
    pub file: String,
    pub reason: String,
}

impl Skipped {
    /// `file` left out for `reason`.
    pub fn new(file: &Path, reason: &str) -> Self {
        Self {
            file: name_of(file),
            reason: reason.to_owned(),
        }
    }
}

/// A dataset's trial that could not be read, and why (file and line).
#[derive(Clone, Debug, PartialEq)]
pub struct Unreadable {
    pub file: PathBuf,
    pub reason: String,
}

impl Unreadable {
    /// As it goes into a command's JSON `skipped` list.
    pub fn skipped(&self) -> Skipped {
        Skipped::new(&self.file, &self.reason)
    }
}

/// Every trial of a dataset, by **the one rule for bad files** that `fit`,
/// `detect` and `diagnose` share: a file that cannot be read (missing
/// columns, a non-number, time not increasing, empty, not a regular file)
/// is left out with a warning on stderr naming it and the line at fault,
/// and listed in the command's JSON `skipped`; the command goes on with
/// the others and fails only when none is left. `command` names the
/// warning's sender. Each trial is read by [`read_for_analysis`]: one
/// pass, memory bounded whatever the file's size, a note when it thinned.
pub fn read_dataset(dir: &Path, command: &str) -> Result<(Dataset, Vec<Unreadable>)> {
    let files = dataset_files(dir)?;
    let count = files.len();
    let mut trials = Vec::new();
    let mut unreadable = Vec::new();
    let mut progress = Progress::new(command);
    for (k, file) in files.into_iter().enumerate() {
        progress.say(|| format!("reading trial {} of {count}: {}", k + 1, file.display()));
        match read_for_analysis(&file, Some(&mut progress)) {
            Ok(analysed) => {
                if let Some(note) = analysed.thinning_note(&file) {
                    crate::note!("needle {command}: {note}");
                }
                trials.push((file, analysed.trial));
            }
            Err(err) => {
                crate::note!("needle {command}: {err:#} (left out)");
                unreadable.push(Unreadable {
                    file,
                    reason: format!("{err:#}"),
                });
            }
        }
    }
    if trials.is_empty() {
        bail!(
            "{}: none of its {} trial files could be read (the first: {})",
            dir.display(),
            unreadable.len(),
            unreadable.first().map_or("", |u| u.reason.as_str())
        );
    }
    Ok((trials, unreadable))
}

/// All `*.csv` files of a dataset directory, sorted by name.
pub fn dataset_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot read directory", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| is_trial_csv(p))
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("{}: no *.csv trial files", dir.display());
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &tempfile::TempDir, text: &str) -> PathBuf {
        let path = dir.path().join("t.csv");
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn reads_required_columns_in_any_order_and_ignores_extras() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(
            &dir,
            "f_n,phase,t_s,x_m\n0.5,out,0,0.001\n0.75,out,0.002,0.0011\n",
        );
        let trial = read(&path).unwrap();
        assert_eq!(trial.t_s, [0.0, 0.002]);
        assert_eq!(trial.x_m, [0.001, 0.0011]);
        assert_eq!(trial.f_n, [0.5, 0.75]);
    }

    #[test]
    fn bad_files_name_the_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("t_s,x_m\n0,0\n", "t.csv:1: no `f_n` column"),
            (
                "t_s,x_m,f_n\n0,0,0\n0.002,abc,0\n",
                "t.csv:3: `x_m` is not a number",
            ),
            (
                "t_s,x_m,f_n\n0,0,0\n0.002,0,NaN\n",
                "t.csv:3: `f_n` is not finite",
            ),
            (
                "t_s,x_m,f_n\n0,0,0\n0,0,0\n",
                "t.csv:3: time does not increase",
            ),
            ("t_s,x_m,f_n\n", "t.csv: no samples"),
        ];
        for (text, expected) in cases {
            let err = format!("{:#}", read(&write(&dir, text)).unwrap_err());
            assert!(err.contains(expected), "{err} lacks {expected}");
        }
    }

    #[test]
    fn a_long_trial_is_read_in_bounded_memory_as_every_step_th_row() {
        // 1.2 M rows at 100 Hz: past the bound twice, so the step doubles
        // twice and the kept rows are exactly every 4th.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("long.csv");
        let mut out = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        use std::io::Write;
        writeln!(out, "t_s,x_m,f_n").unwrap();
        let rows = 1_200_000;
        for i in 0..rows {
            writeln!(out, "{},{},{}", i as f64 / 100.0, i as f64 * 1e-9, i % 7).unwrap();
        }
        drop(out);
        let read = read_for_analysis(&path, None).unwrap();
        assert_eq!((read.rows, read.step), (rows, 4));
        assert!(read.trial.len() <= ANALYSIS_MOST_SAMPLES);
        assert_eq!(read.trial.len(), rows / 4);
        for (k, (&t, &f)) in read.trial.t_s.iter().zip(&read.trial.f_n).enumerate() {
            assert_eq!(t, (4 * k) as f64 / 100.0);
            assert_eq!(f, ((4 * k) % 7) as f64);
        }
        assert!(read
            .thinning_note(&path)
            .unwrap()
            .contains("1200000 rows, thinned to 1 in 4"));
    }

    #[test]
    fn a_fast_trial_is_thinned_to_the_devices_top_rate_and_a_slow_one_kept_whole() {
        let dir = tempfile::tempdir().unwrap();
        // From t = 1000 s in microseconds: steps a hair under 0.5 ms in
        // floating point halved 2 kHz to 1 kHz (and took 10 kHz 1 in 6).
        for (rate_hz, step) in [(2000.0, 1), (10_000.0, 5)] {
            let late: String = std::iter::once("t_s,x_m,f_n\n".to_owned())
                .chain((0..3000).map(|i| format!("{:.6},0,{i}\n", 1000.0 + i as f64 / rate_hz)))
                .collect();
            let read = read_for_analysis(&write(&dir, &late), None).unwrap();
            assert_eq!(read.step, step, "{rate_hz} Hz");
        }
        for (rate_hz, step) in [(10_000.0, 5), (2000.0, 1), (100.0, 1)] {
            let text: String = std::iter::once("t_s,x_m,f_n\n".to_owned())
                .chain((0..3000).map(|i| format!("{},0,{i}\n", i as f64 / rate_hz)))
                .collect();
            let path = write(&dir, &text);
            let read = read_for_analysis(&path, None).unwrap();
            assert_eq!(read.step, step, "{rate_hz} Hz");
            assert_eq!(read.trial.len(), 3000_usize.div_ceil(step));
            assert_eq!(read.trial.f_n[1], step as f64);
            let column = read_column_for_analysis(&path, "f_n").unwrap();
            assert_eq!(column, read.trial.f_n);
            assert_eq!(read.thinning_note(&path).is_some(), step > 1);
        }
    }

    /// Time steps of 1e-310 s (any trial's times scaled by 1e-308) made
    /// the rate infinite, the thinning keep one sample, and `fit` panic.
    #[test]
    fn a_trial_faster_than_any_rig_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        for scale in [1e-308, 1e-9] {
            let text: String = std::iter::once("t_s,x_m,f_n\n".to_owned())
                .chain((0..3000).map(|i| format!("{:e},0,{i}\n", i as f64 * scale / 500.0)))
                .collect();
            let path = write(&dir, &text);
            let err = read_for_analysis(&path, None).unwrap_err().to_string();
            assert!(
                err.contains(&format!("{}:2-1025: the median time step", path.display())),
                "{err}"
            );
            assert!(err.contains("is t_s in seconds?"), "{err}");
        }
        // A 1 MHz recording is thinned, not refused.
        let text: String = std::iter::once("t_s,x_m,f_n\n".to_owned())
            .chain((0..3000).map(|i| format!("{:e},0,{i}\n", i as f64 * 1e-6)))
            .collect();
        assert_eq!(
            read_for_analysis(&write(&dir, &text), None).unwrap().step,
            500
        );
    }
}
