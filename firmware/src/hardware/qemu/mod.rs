//! The QEMU boards: replay source, UART0, semihosting.

// Linked for its side effect: the critical-section implementation (the
// defmt logger is `hardware::semihost`'s).
use cortex_m as _;

pub use super::bench::BenchMarkers;
pub use super::replay_file::{flag_given, ReplayFile};
pub use super::{exit, exit_code};

#[cfg(not(feature = "board-mps2"))]
mod lm3s6965;
#[cfg(not(feature = "board-mps2"))]
pub use lm3s6965::{take_peripherals, Uart0, BOARD};

#[cfg(feature = "board-mps2")]
mod mps2_an386;
#[cfg(feature = "board-mps2")]
pub use mps2_an386::{take_peripherals, Uart0, BOARD};

/// The sample clock of a live run: SysTick at `rate_hz`, in the core's
/// clock as QEMU models it ([`CORE_CLOCK_HZ`]).
pub struct SampleClock(cortex_m::peripheral::SYST);

/// The core clock QEMU gives both QEMU boards' SysTick.
pub const CORE_CLOCK_HZ: u32 = 12_000_000;

impl SampleClock {
    /// Start SysTick wrapping at `rate_hz`.
    pub fn start(rate_hz: u16) -> Self {
        let Some(peripherals) = cortex_m::Peripherals::take() else {
            exit(exit_code::NO_REPLAY)
        };
        let mut syst = peripherals.SYST;
        let reload = (CORE_CLOCK_HZ / u32::from(rate_hz.max(1))).clamp(2, 1 << 24) - 1;
        syst.set_clock_source(cortex_m::peripheral::syst::SystClkSource::Core);
        syst.set_reload(reload);
        syst.clear_current();
        syst.enable_counter();
        Self(syst)
    }

    /// Whether a sample period began since the last call.
    pub fn period_began(&mut self) -> bool {
        self.0.has_wrapped()
    }
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
