//! Semihosting for the replay images (the QEMU boards and the real
//! board's replay image): the replay file, the command line, and the defmt
//! logger, all without a panic path.
//!
//! Written on the `semihosting` crate's raw calls rather than its `File`
//! and `stdout` (and `defmt-semihosting`, built on them): those assert
//! their descriptors, and the logger panics on re-entry, in places the
//! compiler cannot remove, which links `core::panicking` into an image
//! meant never to panic. Here a failed call is an error the caller
//! handles, and a log call that finds the logger busy is dropped
//! ([`super::log_frames`]).

use core::cell::UnsafeCell;
use core::ffi::CStr;

use super::log_frames::global_logger;

use semihosting::sys::arm_compat::syscall::{
    syscall, syscall_readonly, OperationNumber, ParamRegR, ParamRegW,
};

// Parameter blocks are plain words: addresses and lengths the host reads
// (and, for a read or the command line, buffers and a length it writes).

/// A file the host opened for us.
#[derive(Clone, Copy)]
pub struct Fd(usize);

/// SYS_OPEN's mode for reading, binary.
pub const READ_BINARY: usize = 1;
/// SYS_OPEN's mode for writing (":tt" is the host's standard output).
const WRITE: usize = 4;

/// Open `path`; `None` when the host cannot.
pub fn open(path: &CStr, mode: usize) -> Option<Fd> {
    let block = [path.as_ptr() as usize, mode, path.count_bytes()];
    // SAFETY: SYS_OPEN reads the block and the path, both alive here.
    let ret =
        unsafe { syscall_readonly(OperationNumber::SYS_OPEN, ParamRegR::ptr(block.as_ptr())) };
    let fd = ret.usize();
    (fd != usize::MAX).then_some(Fd(fd))
}

/// Read into `buf`; the bytes read (0 at the end), `None` on an error.
pub fn read(fd: Fd, buf: &mut [u8]) -> Option<usize> {
    let len = buf.len();
    let mut block = [fd.0, buf.as_mut_ptr() as usize, len];
    // SAFETY: SYS_READ writes at most `len` bytes into `buf`.
    let ret = unsafe {
        syscall(
            OperationNumber::SYS_READ,
            ParamRegW::ptr(block.as_mut_ptr()),
        )
    };
    // It returns the bytes *not* read.
    len.checked_sub(ret.usize())
}

/// Write all of `bytes`; whether the host took them.
pub fn write(fd: Fd, bytes: &[u8]) -> bool {
    let block = [fd.0, bytes.as_ptr() as usize, bytes.len()];
    // SAFETY: SYS_WRITE reads the block and `bytes`, both alive here.
    let ret =
        unsafe { syscall_readonly(OperationNumber::SYS_WRITE, ParamRegR::ptr(block.as_ptr())) };
    ret.usize() == 0
}

/// The command line QEMU was given (`-semihosting-config ...,arg=...`),
/// into `buf`; `None` when there is none or it does not fit.
pub fn command_line(buf: &mut [u8]) -> Option<&[u8]> {
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: SYS_GET_CMDLINE writes at most `buf.len()` bytes into `buf`
    // and the length back into the block's second word.
    let ret = unsafe {
        syscall(
            OperationNumber::SYS_GET_CMDLINE,
            ParamRegW::ptr(block.as_mut_ptr()),
        )
    };
    if ret.usize() != 0 {
        return None;
    }
    buf.get(..block[1])
}

/// The words of the command line, the program's name first.
pub fn words(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|&b| b == b' ' || b == 0)
        .filter(|w| !w.is_empty())
}

/// Leave QEMU with `code`.
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

/// The defmt logger: frames over semihosting to QEMU's standard output.
/// Standard output, opened on first use.
struct Out(UnsafeCell<Option<Fd>>);

// SAFETY: only touched from inside a log, which holds the critical section.
unsafe impl Sync for Out {}

static OUT: Out = Out(UnsafeCell::new(None));

/// Write encoded bytes to standard output.
fn emit(bytes: &[u8]) {
    // SAFETY: called only by `FRAMES` from inside the open log.
    let out = unsafe { &mut *OUT.0.get() };
    if out.is_none() {
        *out = open(c":tt", WRITE);
    }
    if let Some(fd) = *out {
        let _ = write(fd, bytes);
    }
}

global_logger!(emit);
