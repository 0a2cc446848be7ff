//! defmt over RTT (SEGGER's Real-Time Transfer: a control block in RAM
//! that the probe finds by its ID and reads while the core runs), for
//! `probe-rs run`. Written here, not taken from defmt-rtt, because that
//! crate panics when its logger is entered re-entrantly, in both its modes,
//! and the firmware links no panic path. One up channel, non-blocking: a
//! log that does not fit in the buffer is cut, never waited on.

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicU32, Ordering};

use super::super::log_frames::global_logger;

/// Buffer size, a power of two: 1 KiB, as defmt-rtt's default.
const SIZE: usize = 1024;

/// The RTT control block's layout (SEGGER RTT, as probe-rs reads it).
#[repr(C)]
struct ControlBlock {
    id: [u8; 16],
    up_channels: u32,
    down_channels: u32,
    up: Channel,
}

#[repr(C)]
struct Channel {
    name: *const u8,
    buffer: *mut u8,
    size: u32,
    /// Where the target writes next (ours).
    write: AtomicU32,
    /// Where the probe reads next (the probe's).
    read: AtomicU32,
    /// Mode: 1 is "non-blocking, trim".
    flags: AtomicU32,
}

// SAFETY: the pointers are to statics; the indices are atomics.
unsafe impl Sync for ControlBlock {}

struct Buffer(UnsafeCell<[u8; SIZE]>);

// SAFETY: written only by `emit`, from inside a log (one at a time).
unsafe impl Sync for Buffer {}

static BUFFER: Buffer = Buffer(UnsafeCell::new([0; SIZE]));

static NAME: [u8; 6] = *b"defmt\0";

#[no_mangle]
static _SEGGER_RTT: ControlBlock = ControlBlock {
    id: *b"SEGGER RTT\0\0\0\0\0\0",
    up_channels: 1,
    down_channels: 0,
    up: Channel {
        name: NAME.as_ptr(),
        buffer: BUFFER.0.get().cast(),
        size: SIZE as u32,
        write: AtomicU32::new(0),
        read: AtomicU32::new(0),
        flags: AtomicU32::new(1),
    },
};

/// Copy what fits of `bytes` into the ring after the write index.
fn emit(bytes: &[u8]) {
    let up = &_SEGGER_RTT.up;
    let write = up.write.load(Ordering::Relaxed) as usize % SIZE;
    // The probe writes `read`; whatever it holds stays inside the ring.
    let read = up.read.load(Ordering::Relaxed) as usize % SIZE;
    // One slot stays empty: write == read means empty.
    let free = (read + SIZE - write - 1) % SIZE;
    let mut at = write;
    for &byte in bytes.iter().take(free) {
        // SAFETY: `at < SIZE`; only the open log writes the buffer, and
        // the probe reads only below the write index published after.
        unsafe { BUFFER.0.get().cast::<u8>().add(at).write_volatile(byte) };
        at = (at + 1) % SIZE;
    }
    up.write.store(at as u32, Ordering::Release);
}

global_logger!(emit);
