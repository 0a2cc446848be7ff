//! Writing a command's output to standard output as an error that can be
//! reported, not a panic: `print!` panics when stdout is a full disk
//! (`> /dev/full`) or a closed pipe (`| head -1`). A closed pipe ends the
//! command quietly (`main` treats it as success); any other failure is an
//! error naming standard output, and a non-zero exit.

use std::io::Write;

use anyhow::{Context, Result};

/// Write `text` to standard output and flush it.
pub fn write(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .context("cannot write to standard output")
}
