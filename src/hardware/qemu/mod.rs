//! The QEMU boards: replay source, UART0, semihosting.

// Linked for their side effects: the critical-section implementation and the
// defmt global logger.
use cortex_m as _;
use defmt_semihosting as _;

mod bench;
mod replay_file;
pub use bench::BenchMarkers;
pub use replay_file::ReplayFile;

#[cfg(not(feature = "board-mps2"))]
mod lm3s6965;
#[cfg(not(feature = "board-mps2"))]
pub use lm3s6965::{take_peripherals, BOARD};

#[cfg(feature = "board-mps2")]
mod mps2_an386;
#[cfg(feature = "board-mps2")]
pub use mps2_an386::{take_peripherals, BOARD};

/// Exit codes seen by whoever started QEMU.
pub mod exit_code {
    /// The replay file could not be opened or named.
    pub const NO_REPLAY: i32 = 2;
    /// HardFault.
    pub const HARD_FAULT: i32 = 3;
    /// Panic (the firmware is built never to panic; this is the backstop).
    pub const PANIC: i32 = 101;
}

/// Leave QEMU with `code`.
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    // Formatting PanicInfo costs ~13 KB of flash; the location is in the ELF.
    defmt::error!("panic");
    exit(exit_code::PANIC)
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    defmt::error!("HardFault at pc {=u32:#010x}", frame.pc());
    exit(exit_code::HARD_FAULT)
}
