//! The QEMU boards: replay source, UART0, semihosting.

// Linked for their side effects: the critical-section implementation and the
// defmt global logger.
use cortex_m as _;
use defmt_semihosting as _;

pub use super::bench::BenchMarkers;
pub use super::replay_file::ReplayFile;
pub use super::{exit, exit_code};

#[cfg(not(feature = "board-mps2"))]
mod lm3s6965;
#[cfg(not(feature = "board-mps2"))]
pub use lm3s6965::{take_peripherals, BOARD};

#[cfg(feature = "board-mps2")]
mod mps2_an386;
#[cfg(feature = "board-mps2")]
pub use mps2_an386::{take_peripherals, BOARD};

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
