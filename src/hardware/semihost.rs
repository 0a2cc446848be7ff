//! Semihosting for the replay images (the QEMU boards and the real
//! board's replay image): the replay file, the command line, and the defmt
//! logger, all without a panic path.
//!
//! Written on the `semihosting` crate's raw calls rather than its `File`
//! and `stdout` (and `defmt-semihosting`, built on them): those assert
//! their descriptors, and the logger panics on re-entry, in places the
//! compiler cannot remove, which links `core::panicking` into an image
//! meant never to panic. Here a failed call is an error the caller
//! handles, and a log call that finds the logger busy is dropped.

use core::cell::UnsafeCell;
use core::ffi::CStr;
use core::sync::atomic::{AtomicBool, Ordering};

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
#[defmt::global_logger]
struct Logger;

struct State {
    taken: AtomicBool,
    restore: UnsafeCell<critical_section::RestoreState>,
    encoder: UnsafeCell<defmt::Encoder>,
    out: UnsafeCell<Option<Fd>>,
}

// SAFETY: every access but `taken` happens inside the critical section
// that `acquire` enters and `release` leaves.
unsafe impl Sync for State {}

static STATE: State = State {
    taken: AtomicBool::new(false),
    restore: UnsafeCell::new(critical_section::RestoreState::invalid()),
    encoder: UnsafeCell::new(defmt::Encoder::new()),
    out: UnsafeCell::new(None),
};

/// Write encoded bytes to standard output (opened on first use).
fn emit(out: &mut Option<Fd>, bytes: &[u8]) {
    if out.is_none() {
        *out = open(c":tt", WRITE);
    }
    if let Some(fd) = *out {
        let _ = write(fd, bytes);
    }
}

// SAFETY: the critical section is entered in `acquire` and left in
// `release`, once each; the cells are only touched between them, and a
// nested `acquire` (a log from an interrupt inside a log) is refused.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        // SAFETY: paired with the release below (or at once, if busy).
        let restore = unsafe { critical_section::acquire() };
        if STATE.taken.load(Ordering::Relaxed) {
            // SAFETY: leaves the section just entered; the log is dropped.
            unsafe { critical_section::release(restore) };
            return;
        }
        STATE.taken.store(true, Ordering::Relaxed);
        // SAFETY: inside the critical section, the logger ours.
        unsafe {
            STATE.restore.get().write(restore);
            let out = &mut *STATE.out.get();
            (*STATE.encoder.get()).start_frame(|b| emit(out, b));
        }
    }

    unsafe fn flush() {}

    unsafe fn release() {
        if !STATE.taken.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: inside the critical section `acquire` entered.
        unsafe {
            let out = &mut *STATE.out.get();
            (*STATE.encoder.get()).end_frame(|b| emit(out, b));
            let restore = STATE.restore.get().read();
            STATE.taken.store(false, Ordering::Relaxed);
            critical_section::release(restore);
        }
    }

    unsafe fn write(bytes: &[u8]) {
        if !STATE.taken.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: inside the critical section `acquire` entered.
        unsafe {
            let out = &mut *STATE.out.get();
            (*STATE.encoder.get()).write(bytes, |b| emit(out, b));
        }
    }
}
