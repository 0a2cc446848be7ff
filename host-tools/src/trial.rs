//! Trial CSV files (DESIGN.md §4): header `t_s,x_m,f_n`, extra columns
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
        let mut dt: Vec<f64> = self.t_s.windows(2).map(|w| w[1] - w[0]).collect();
        if dt.is_empty() {
            return 0.0;
        }
        let mid = dt.len() / 2;
        1.0 / *dt.select_nth_unstable_by(mid, f64::total_cmp).1
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
        let ratio = self.rate_hz() / most_hz;
        if ratio.is_finite() && ratio > 1.0 {
            ratio.ceil() as usize
        } else {
            1
        }
    }

    pub fn push(&mut self, t_s: f64, x_m: f64, f_n: f64) {
        self.t_s.push(t_s);
        self.x_m.push(x_m);
        self.f_n.push(f_n);
    }
}

/// Every `step`-th value, from the first.
pub fn every(values: &[f64], step: usize) -> Vec<f64> {
    values.iter().step_by(step.max(1)).copied().collect()
}

/// A CSV reader on `path`, which must be a regular file: a `.csv` link to
/// `/dev/zero` made the reader allocate 4 GiB for a header that never
/// ends, and aborted.
fn open_csv(path: &Path) -> Result<csv::Reader<std::fs::File>> {
    let shown = path.display();
    let meta = std::fs::metadata(path).with_context(|| format!("{shown}: cannot open"))?;
    if !meta.is_file() {
        anyhow::bail!("{shown}: not a regular file (a device, directory or pipe is no trial)");
    }
    csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("{shown}: cannot open"))
}

/// Read a trial, checking columns, numbers and time order.
pub fn read(path: &Path) -> Result<Trial> {
    let shown = path.display();
    let mut reader = open_csv(path)?;
    let headers = reader
        .headers()
        .with_context(|| format!("{shown}:1: cannot read the header"))?;
    let column = |name: &str| {
        headers
            .iter()
            .position(|h| h == name)
            .with_context(|| format!("{shown}:1: no `{name}` column (need t_s,x_m,f_n)"))
    };
    let (ti, xi, fi) = (column("t_s")?, column("x_m")?, column("f_n")?);
    let mut trial = Trial::default();
    for record in reader.records() {
        let record = record.with_context(|| format!("{shown}: malformed CSV"))?;
        let line = record.position().map_or(0, |p| p.line());
        let field = |i: usize, name: &str| -> Result<f64> {
            let text = record.get(i).unwrap_or("");
            let value: f64 = text.parse().map_err(|_| {
                anyhow::anyhow!("{shown}:{line}: `{name}` is not a number: {text:?}")
            })?;
            if !value.is_finite() {
                bail!("{shown}:{line}: `{name}` is not finite: {text:?}");
            }
            Ok(value)
        };
        let (t, x, f) = (field(ti, "t_s")?, field(xi, "x_m")?, field(fi, "f_n")?);
        if let Some(&last) = trial.t_s.last() {
            if t <= last {
                bail!("{shown}:{line}: time does not increase ({t} s after {last} s)");
            }
        }
        trial.push(t, x, f);
    }
    if trial.is_empty() {
        bail!("{shown}: no samples");
    }
    Ok(trial)
}

/// An extra column of a trial CSV by name (e.g. `model_n` of `needle
/// decode --csv`), with the same checks as [`read`].
pub fn read_column(path: &Path, name: &str) -> Result<Vec<f64>> {
    let shown = path.display();
    let mut reader = open_csv(path)?;
    let at = reader
        .headers()
        .with_context(|| format!("{shown}:1: cannot read the header"))?
        .iter()
        .position(|h| h == name)
        .with_context(|| format!("{shown}:1: no `{name}` column"))?;
    let mut values = Vec::new();
    for record in reader.records() {
        let record = record.with_context(|| format!("{shown}: malformed CSV"))?;
        let line = record.position().map_or(0, |p| p.line());
        let text = record.get(at).unwrap_or("");
        match text.parse::<f64>() {
            Ok(v) if v.is_finite() => values.push(v),
            _ => bail!("{shown}:{line}: `{name}` is not a finite number: {text:?}"),
        }
    }
    Ok(values)
}

/// Write a trial CSV (`t_s,x_m,f_n`; µs, nm and µN resolution).
pub fn write(path: &Path, trial: &Trial) -> Result<()> {
    use std::io::Write;
    let file = std::fs::File::create(path)
        .with_context(|| format!("{}: cannot create", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    writeln!(out, "t_s,x_m,f_n")?;
    for i in 0..trial.len() {
        writeln!(
            out,
            "{:.6},{:.9},{:.6}",
            trial.t_s[i], trial.x_m[i], trial.f_n[i]
        )?;
    }
    out.flush()
        .with_context(|| format!("{}: cannot write", path.display()))
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
            eprintln!(
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

/// A dataset's trial that could not be read, and why (file and line).
#[derive(Clone, Debug, PartialEq)]
pub struct Unreadable {
    pub file: PathBuf,
    pub reason: String,
}

impl Unreadable {
    /// As it goes into a command's JSON `skipped` list.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({ "file": self.file.display().to_string(), "reason": self.reason })
    }
}

/// Every trial of a dataset, by **the one rule for bad files** that `fit`,
/// `detect` and `diagnose` share: a file that cannot be read (missing
/// columns, a non-number, time not increasing, empty, not a regular file)
/// is left out with a warning on stderr naming it and the line at fault,
/// and listed in the command's JSON `skipped`; the command goes on with
/// the others and fails only when none is left. `command` names the
/// warning's sender.
pub fn read_dataset(dir: &Path, command: &str) -> Result<(Dataset, Vec<Unreadable>)> {
    let files = dataset_files(dir)?;
    let count = files.len();
    let mut trials = Vec::new();
    let mut unreadable = Vec::new();
    let mut progress = Progress::new(command);
    for (k, file) in files.into_iter().enumerate() {
        progress.say(|| format!("reading trial {} of {count}: {}", k + 1, file.display()));
        match read(&file) {
            Ok(trial) => trials.push((file, trial)),
            Err(err) => {
                eprintln!("needle {command}: {err:#} (left out)");
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
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
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
}
