//! The replay file, opened by the path QEMU passes on the semihosting
//! command line, read in blocks (each semihosting call traps into QEMU, so
//! one call per 6-byte record would dominate the run time).

use core::ffi::CStr;

use semihosting::experimental::env::args;
use semihosting::fs::File;
use semihosting::io::Read as _;

use super::{exit, exit_code};

const BLOCK: usize = 512;
const MAX_PATH: usize = 256;

/// A buffered semihosting file implementing [`embedded_io::Read`].
pub struct ReplayFile {
    file: File,
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
        let Ok(argv) = args::<MAX_PATH>() else {
            defmt::error!(
                "no semihosting command line (or longer than {=usize} bytes)",
                MAX_PATH
            );
            exit(exit_code::NO_REPLAY)
        };
        let Some(Ok(path)) = (&argv).into_iter().last() else {
            defmt::error!("usage: needle-holder REPLAY_FILE");
            exit(exit_code::NO_REPLAY)
        };
        let mut cpath = [0u8; MAX_PATH];
        let len = path.len().min(MAX_PATH - 1);
        cpath[..len].copy_from_slice(&path.as_bytes()[..len]);
        let opened = CStr::from_bytes_with_nul(&cpath[..=len])
            .ok()
            .and_then(|p| File::open(p).ok());
        let Some(file) = opened else {
            defmt::error!("cannot open replay file {=str}", path);
            exit(exit_code::NO_REPLAY)
        };
        defmt::info!("replaying {=str}", path);
        Self {
            file,
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
    let Ok(argv) = args::<MAX_PATH>() else {
        return false;
    };
    (&argv).into_iter().any(|a| a.is_ok_and(|a| a == flag))
}

impl embedded_io::ErrorType for ReplayFile {
    type Error = embedded_io::ErrorKind;
}

impl embedded_io::Read for ReplayFile {
    fn read(&mut self, out: &mut [u8]) -> Result<usize, Self::Error> {
        if self.start == self.end {
            self.start = 0;
            self.end = self
                .file
                .read(&mut self.buf)
                .map_err(|_| embedded_io::ErrorKind::Other)?;
        }
        let n = out.len().min(self.end - self.start);
        out[..n].copy_from_slice(&self.buf[self.start..self.start + n]);
        self.start += n;
        Ok(n)
    }
}
