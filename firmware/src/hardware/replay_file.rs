//! The replay file, opened by the path QEMU passes on the semihosting
//! command line, read in blocks (each semihosting call traps into QEMU, so
//! one call per 6-byte record would dominate the run time).

use core::ffi::CStr;

use super::semihost::{self, Fd};
use super::{exit, exit_code};

const BLOCK: usize = 512;
const MAX_LINE: usize = 512;

/// A buffered semihosting file implementing [`embedded_io::Read`].
pub struct ReplayFile {
    fd: Fd,
    buf: [u8; BLOCK],
    start: usize,
    end: usize,
}

impl ReplayFile {
    /// Open the file named by the last word of the semihosting command line
    /// (`-semihosting-config ...,arg=needle-holder,arg=PATH`, or
    /// `-kernel ELF -append PATH`). Exits QEMU with
    /// [`exit_code::NO_REPLAY`] when there is none or it cannot be opened.
    pub fn open_from_args() -> Self {
        let mut line = [0u8; MAX_LINE];
        let Some(line) = semihost::command_line(&mut line) else {
            defmt::error!(
                "no semihosting command line (or longer than {=usize} bytes)",
                MAX_LINE
            );
            exit(exit_code::NO_REPLAY)
        };
        let Some(path) = semihost::words(line)
            .last()
            .filter(|_| semihost::words(line).count() > 1)
        else {
            defmt::error!("usage: IMAGE [--live] REPLAY_FILE");
            exit(exit_code::NO_REPLAY)
        };
        let mut cpath = [0u8; MAX_LINE + 1];
        let opened = cpath
            .get_mut(..path.len())
            .map(|dst| dst.copy_from_slice(path))
            .and_then(|()| CStr::from_bytes_until_nul(&cpath).ok())
            .and_then(|p| semihost::open(p, semihost::READ_BINARY));
        let Some(fd) = opened else {
            defmt::error!("cannot open replay file {=[u8]:a}", path);
            exit(exit_code::NO_REPLAY)
        };
        defmt::info!("replaying {=[u8]:a}", path);
        Self {
            fd,
            buf: [0; BLOCK],
            start: 0,
            end: 0,
        }
    }
}

/// Whether the semihosting command line holds `flag` (before the path).
/// (The F411 replay image has no live mode: its TIM2 is its clock.)
#[cfg_attr(feature = "board-f411", allow(dead_code))]
pub fn flag_given(flag: &str) -> bool {
    let mut line = [0u8; MAX_LINE];
    semihost::command_line(&mut line)
        .is_some_and(|line| semihost::words(line).any(|w| w == flag.as_bytes()))
}

impl embedded_io::ErrorType for ReplayFile {
    type Error = embedded_io::ErrorKind;
}

impl embedded_io::Read for ReplayFile {
    fn read(&mut self, out: &mut [u8]) -> Result<usize, Self::Error> {
        if self.start >= self.end {
            self.start = 0;
            self.end =
                semihost::read(self.fd, &mut self.buf).ok_or(embedded_io::ErrorKind::Other)?;
        }
        let waiting = self.buf.get(self.start..self.end).unwrap_or(&[]);
        let n = out.len().min(waiting.len());
        out.iter_mut().zip(waiting).for_each(|(o, &b)| *o = b);
        self.start += n;
        Ok(n)
    }
}
