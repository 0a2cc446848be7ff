//! The checks every file input passes before it is read: a regular file
//! (a `.csv` or `truth.json` linked to `/dev/zero`, or a `--params` naming
//! a device, would be read without end), and for the inputs read whole —
//! a tissue library, a dataset's `truth.json` — a size no such file
//! reaches; a capture may also be a pipe, but not a device. And the
//! checks every output passes before anything is read or written: it is
//! none of the command's inputs, no two outputs are one file, and its
//! directory exists.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

/// The largest text input read whole: a truth.json of thousands of trials
/// or a library of hundreds of tissues is well under a megabyte.
pub const MOST_TEXT_BYTES: u64 = 16 << 20;

/// `path`'s metadata if it is a regular file (links followed).
pub fn regular_file(path: &Path) -> Result<std::fs::Metadata> {
    let shown = path.display();
    let meta = std::fs::metadata(path).with_context(|| format!("{shown}: cannot open"))?;
    if !meta.is_file() {
        bail!("{shown}: not a regular file (a device, directory or pipe is no input)");
    }
    Ok(meta)
}

/// A small text input read whole, refused by name when it is not a
/// regular file or larger than [`MOST_TEXT_BYTES`].
pub fn read_small_text(path: &Path) -> Result<String> {
    let shown = path.display();
    let size = regular_file(path)?.len();
    if size > MOST_TEXT_BYTES {
        bail!("{shown}: {size} bytes, more than the {MOST_TEXT_BYTES} such a file may have");
    }
    let bytes = std::fs::read(path).with_context(|| format!("{shown}: cannot read"))?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let bytes = e.as_bytes();
        let line = bytes[..at].iter().filter(|&&b| b == b'\n').count() + 1;
        let column = at
            - bytes[..at]
                .iter()
                .rposition(|&b| b == b'\n')
                .map_or(0, |i| i + 1)
            + 1;
        anyhow::anyhow!(
            "{shown}:{line}: not UTF-8 text (byte 0x{:02x} at column {column})",
            bytes[at]
        )
    })
}

/// A capture (`needle decode FILE`) is a file or a pipe, read as it
/// streams. A device named as one is refused: a serial port read as a
/// file has no baud rate set (`--port` sets it), and `/dev/zero` would be
/// decoded until stopped.
pub fn not_a_device(path: &Path) -> Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let kind = std::fs::metadata(path)
            .with_context(|| format!("{}: cannot read", path.display()))?
            .file_type();
        if kind.is_char_device() || kind.is_block_device() {
            bail!(
                "{0}: a device, not a capture file (a serial port is read with --port {0})",
                path.display()
            );
        }
    }
    Ok(())
}

/// An output this process writes, held until it is dropped (the lock goes
/// with the process however it ends): a second `needle` writing the same
/// output is refused, named by what the first wrote into the lock file.
pub struct OutputLock {
    _file: std::fs::File,
    path: std::path::PathBuf,
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Take the lock for `output` in the file `lock_path`, saying `what` holds
/// it (e.g. `needle record`): two writers of one output interleaved their
/// rows, or one replaced the other's trials, each saying it succeeded.
pub fn lock_output(output: &Path, lock_path: &Path, what: &str) -> Result<OutputLock> {
    use std::io::{Read, Write};
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(lock_path)
        .with_context(|| format!("{}: cannot create", lock_path.display()))?;
    match file.try_lock() {
        Ok(()) => {
            let holder = format!("{what} (pid {})", std::process::id());
            file.set_len(0)
                .and_then(|()| file.write_all(holder.as_bytes()))
                .with_context(|| format!("{}: cannot write", lock_path.display()))?;
            Ok(OutputLock {
                _file: file,
                path: lock_path.to_path_buf(),
            })
        }
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut holder = String::new();
            let _ = file.take(200).read_to_string(&mut holder);
            let holder = if holder.trim().is_empty() {
                "another process".to_owned()
            } else {
                holder.trim().to_owned()
            };
            bail!(
                "{}: {holder} is writing it (lock {}); wait for it to end, or write elsewhere",
                output.display(),
                lock_path.display()
            )
        }
        Err(std::fs::TryLockError::Error(e)) => {
            Err(e).with_context(|| format!("{}: cannot lock", lock_path.display()))
        }
    }
}

/// An `--out` directory that exists must be one: a file named there is no
/// place for trials.
pub fn out_dir(dir: &Path) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        bail!(
            "{}: is a file, not a directory (--out names the directory the trials go to)",
            dir.display()
        );
    }
    Ok(())
}

/// Make the output directory `dir` (and its parents) if missing. A
/// dangling link is named as one: creating it fails with "File exists",
/// which says nothing of where the link points.
pub fn create_out_dir(dir: &Path) -> Result<()> {
    let shown = dir.display();
    let link = std::fs::symlink_metadata(dir).is_ok_and(|m| m.file_type().is_symlink());
    if link && !dir.exists() {
        let target = std::fs::read_link(dir).unwrap_or_default();
        bail!(
            "{shown}: a link to {}, which does not exist: make that directory, or name another",
            target.display()
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("{shown}: cannot create"))
}

/// Whether `a` and `b` name one file (the same path, a link, or the same
/// inode); a path that does not exist is no file.
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) if x == y => true,
        #[cfg(unix)]
        (Ok(x), Ok(y)) => {
            use std::os::unix::fs::MetadataExt;
            match (std::fs::metadata(x), std::fs::metadata(y)) {
                (Ok(m), Ok(n)) => m.dev() == n.dev() && m.ino() == n.ino(),
                _ => false,
            }
        }
        _ => false,
    }
}

/// Whether `path` is this process's standard output (a file, a pipe or a
/// terminal), which the command's text already goes to: `decode --csv
/// /dev/stdout > f` wrote both into `f` over each other.
pub fn is_stdout(path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(m), Ok(out)) = (std::fs::metadata(path), std::fs::metadata("/dev/stdout")) {
            return m.dev() == out.dev() && m.ino() == out.ino();
        }
    }
    false
}

/// Whether two output paths, which may not exist yet, name one file.
fn same_output(a: &Path, b: &Path) -> bool {
    same_file(a, b)
        || matches!(
            (std::path::absolute(a), std::path::absolute(b)),
            (Ok(x), Ok(y)) if x == y
        )
}

/// Check the files a command will write (`(flag, path)`), before it reads
/// or writes anything: none may be one of `inputs` (`needle fit d --json
/// d/trial_000.csv` emptied the trial it fitted, and `detect d --json
/// d/truth.json` replaced the truth it scores against), no two may be one
/// file (`diagnose --report r.svg` wrote its HTML over its own figure),
/// and each must be a file in a directory that exists (found after the
/// work, `--json /nodir/x.json` cost the whole evaluation).
pub fn check_outputs(outputs: &[(&str, &Path)], inputs: &[PathBuf]) -> Result<()> {
    for (k, &(flag, path)) in outputs.iter().enumerate() {
        let shown = path.display();
        if let Some(input) = inputs.iter().find(|i| same_file(i, path)) {
            bail!(
                "{shown}: {flag} names an input ({}); writing it would destroy what is read",
                input.display()
            );
        }
        if let Some((other, _)) = outputs[..k].iter().find(|(_, p)| same_output(p, path)) {
            bail!("{shown}: {flag} and {other} name the same file");
        }
        if path.is_dir() {
            bail!("{shown}: {flag} names a directory, not a file");
        }
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
        if let Some(dir) = dir.filter(|d| !d.is_dir()) {
            bail!("{shown}: cannot write: no directory {}", dir.display());
        }
    }
    Ok(())
}

/// The files a dataset command reads in `dir`: its trial CSVs and its
/// `truth.json`, and a `--params` library.
pub fn dataset_inputs(dir: &Path, params: Option<&Path>) -> Vec<PathBuf> {
    let mut inputs = crate::trial::dataset_files(dir).unwrap_or_default();
    inputs.push(dir.join("truth.json"));
    inputs.extend(params.map(Path::to_path_buf));
    inputs
}
