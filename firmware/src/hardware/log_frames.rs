//! What every defmt logger here shares (semihosting in the replay images,
//! RTT on the real board): one log at a time inside a critical section,
//! framed by defmt's encoder, written to the logger's byte sink. A log
//! that starts while another is open — only a fault handler can, as every
//! other interrupt is masked — is dropped whole, where defmt-rtt and
//! defmt-semihosting panic: the firmware links no panic path.

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

pub struct LogFrames {
    taken: AtomicBool,
    /// Logs begun inside the open one and dropped, not yet released.
    dropped: AtomicU32,
    restore: UnsafeCell<critical_section::RestoreState>,
    encoder: UnsafeCell<defmt::Encoder>,
}

// SAFETY: `restore` and `encoder` are only touched by the log that holds
// `taken`, inside the critical section it entered.
unsafe impl Sync for LogFrames {}

impl LogFrames {
    pub const fn new() -> Self {
        Self {
            taken: AtomicBool::new(false),
            dropped: AtomicU32::new(0),
            restore: UnsafeCell::new(critical_section::RestoreState::invalid()),
            encoder: UnsafeCell::new(defmt::Encoder::new()),
        }
    }

    /// defmt's `Logger::acquire`.
    pub fn acquire(&self, emit: impl FnMut(&[u8])) {
        // SAFETY: paired with the release in `release` (or at once, for a
        // log that is dropped).
        let restore = unsafe { critical_section::acquire() };
        if self.taken.load(Ordering::Relaxed) {
            // Load and store (no read-modify-write on Cortex-M0): inside
            // the section, nothing else runs.
            let dropped = self.dropped.load(Ordering::Relaxed);
            self.dropped
                .store(dropped.saturating_add(1), Ordering::Relaxed);
            // SAFETY: leaves the section just entered.
            unsafe { critical_section::release(restore) };
            return;
        }
        self.taken.store(true, Ordering::Relaxed);
        // SAFETY: inside the critical section, this log holds `taken`.
        unsafe {
            self.restore.get().write(restore);
            (*self.encoder.get()).start_frame(emit);
        }
    }

    /// defmt's `Logger::write`.
    ///
    /// # Safety
    /// Between `acquire` and `release`, as defmt calls it.
    pub unsafe fn write(&self, bytes: &[u8], emit: impl FnMut(&[u8])) {
        if self.dropped.load(Ordering::Relaxed) > 0 || !self.taken.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: inside the open log's critical section.
        unsafe { (*self.encoder.get()).write(bytes, emit) };
    }

    /// defmt's `Logger::release`.
    ///
    /// # Safety
    /// After `acquire`, as defmt calls it.
    pub unsafe fn release(&self, emit: impl FnMut(&[u8])) {
        let dropped = self.dropped.load(Ordering::Relaxed);
        if dropped > 0 {
            // A dropped log ends inside the open one, which cannot run
            // meanwhile.
            self.dropped.store(dropped - 1, Ordering::Relaxed);
            return;
        }
        if !self.taken.load(Ordering::Relaxed) {
            return;
        }
        // SAFETY: inside the critical section `acquire` entered; leaving it
        // with the state saved there.
        unsafe {
            (*self.encoder.get()).end_frame(emit);
            let restore = self.restore.get().read();
            self.taken.store(false, Ordering::Relaxed);
            critical_section::release(restore);
        }
    }
}

/// The image's `#[defmt::global_logger]`: [`LogFrames`] writing through
/// `$emit` (a `fn(&[u8])`, called only from inside a log).
macro_rules! global_logger {
    ($emit:path) => {
        #[defmt::global_logger]
        struct Logger;

        static FRAMES: $crate::hardware::log_frames::LogFrames =
            $crate::hardware::log_frames::LogFrames::new();

        // SAFETY: `LogFrames` keeps one log at a time inside a critical
        // section.
        unsafe impl defmt::Logger for Logger {
            fn acquire() {
                FRAMES.acquire($emit);
            }

            unsafe fn flush() {}

            unsafe fn release() {
                // SAFETY: as defmt calls it.
                unsafe { FRAMES.release($emit) };
            }

            unsafe fn write(bytes: &[u8]) {
                // SAFETY: as defmt calls it.
                unsafe { FRAMES.write(bytes, $emit) };
            }
        }
    };
}

pub(crate) use global_logger;
