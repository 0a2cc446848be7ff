//! The two ways a command talks: its output on standard output, and notes
//! (progress, warnings, messages) on standard error. `println!` and
//! `eprintln!` panic when their stream breaks (`> /dev/full`, a closed
//! pipe, `2>&1 | head -1`); these never do.
//!
//! - Output that cannot be written is an error the command returns: a
//!   closed pipe ends it quietly (`main` treats it as success, as Unix
//!   tools do), anything else names standard output and exits non-zero.
//! - A note that cannot be written is dropped: standard error is where a
//!   failure would be reported, so there is nowhere left to say it, and a
//!   recording or a fit must not stop because nobody reads its progress.
//!
//! `host-tools/tests/integration/broken_streams.rs` runs every subcommand with each
//! stream closed, full, and a broken pipe; a test there also checks that
//! no `print!`-family macro is used anywhere else in the tools.

use std::io::Write;

use anyhow::{Context, Result};

/// Write `text` to standard output and flush it.
pub fn write(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .context("cannot write to standard output")
}

/// Standard output for many small writes, buffered; a failure names
/// standard output and keeps its kind (a closed pipe stays one).
pub fn buffered() -> std::io::BufWriter<Named> {
    std::io::BufWriter::new(Named(std::io::stdout()))
}

/// Standard output whose errors say they are standard output's.
pub struct Named(std::io::Stdout);

impl Write for Named {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.write(buf).map_err(name)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.0.flush().map_err(name)
    }
}

fn name(e: std::io::Error) -> std::io::Error {
    std::io::Error::new(e.kind(), format!("cannot write to standard output: {e}"))
}

/// Write `text` to standard error, if it can be written.
pub fn note(text: &str) {
    let mut err = std::io::stderr().lock();
    let _ = err.write_all(text.as_bytes()).and_then(|()| err.flush());
}

/// `println!` that returns an error instead of panicking (see the module).
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::stdout::write(&format!("{}\n", format_args!($($arg)*)))
    };
}

/// `eprintln!` that never panics (see the module).
#[macro_export]
macro_rules! note {
    ($($arg:tt)*) => {
        $crate::stdout::note(&format!("{}\n", format_args!($($arg)*)))
    };
}

/// `eprint!` that never panics: a progress line rewritten in place.
#[macro_export]
macro_rules! note_inline {
    ($($arg:tt)*) => {
        $crate::stdout::note(&format!($($arg)*))
    };
}
