//! The checks every file input passes before it is read: a regular file
//! (a `.csv` or `truth.json` linked to `/dev/zero`, or a `--params` naming
//! a device, would be read without end), and for the inputs read whole —
//! a tissue library, a dataset's `truth.json` — a size no such file
//! reaches; a capture may also be a pipe, but not a device.

use std::path::Path;

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
    std::fs::read_to_string(path).with_context(|| format!("{shown}: cannot read"))
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
