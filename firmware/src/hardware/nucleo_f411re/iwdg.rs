//! The independent watchdog (IWDG, RM0383 §17): clocked by the LSI, apart
//! from the core's clocks, and once started stoppable only by a reset. A
//! CPU that hangs, locks up or spins in a loop stops feeding it, and the
//! reset that follows leaves the halt line to its pull-up (the reset state
//! of PA8 is a floating input) and then to the firmware, which drives it
//! high from its first instructions and, seeing the watchdog's reset flag,
//! keeps it high with a `watchdog_reset` fault until the host re-arms.
//!
//! Fed by the sample task after each sample it hands the device, and by
//! the TIM5 task only while the device sits halted for a latched fault
//! (a converter that stopped must not become a reset loop that loses its
//! fault report): never from a loop that could run without the samples.

use stm32f4::stm32f411 as pac;

/// The LSI's slowest and fastest frequencies (F411 datasheet, table 39:
/// 17–47 kHz, 32 kHz typical).
const LSI_SLOWEST_HZ: u32 = 17_000;
const LSI_FASTEST_HZ: u32 = 47_000;
/// The LSI divided by 8 (PR = 1).
const PRESCALER: u32 = 8;
/// Reload, in prescaled LSI ticks: 250 ms at the typical 32 kHz.
const RELOAD: u16 = 1000;

/// The shortest and longest time from the last feed to the reset, ms,
/// over the LSI's spread: 170–470 ms.
pub const TIMEOUT_MS: (u32, u32) = (
    RELOAD as u32 * PRESCALER * 1000 / LSI_FASTEST_HZ,
    RELOAD as u32 * PRESCALER * 1000 / LSI_SLOWEST_HZ,
);

// A converter that stops is the data-ready watchdog's `adc_timeout`
// within three TIM5 periods of the last sample (the tick that still saw
// it, then two quiet ones), and that tick feeds this one: the reset must
// not come first, even on the fastest LSI, with a TIM5 period to spare.
const _: () = assert!(TIMEOUT_MS.0 > 4 * 1000 / super::setup::WATCHDOG_HZ);

/// Polls of the prescaler and reload update flags before going on
/// anyway: an update takes five LSI periods once the LSI runs (≤ 300 µs);
/// at 100 MHz this bound is far longer.
const UPDATE_POLLS: u32 = 100_000;

/// The running watchdog.
pub struct IndependentWatchdog(pac::IWDG);

impl IndependentWatchdog {
    /// Start it (it runs from here until the next reset) and have it stop
    /// while a debugger halts the core.
    pub fn start(iwdg: pac::IWDG, dbgmcu: &pac::DBGMCU) -> Self {
        dbgmcu.apb1_fz().modify(|_, w| w.dbg_iwdg_stop().set_bit());
        // ST's order: start first (it starts the LSI, which the update of
        // the prescaler and reload needs), then unlock and write them,
        // wait for the update, and reload the counter with them.
        iwdg.kr().write(|w| w.key().start());
        iwdg.kr().write(|w| w.key().unlock());
        iwdg.pr().write(|w| w.pr().divide_by8());
        iwdg.rlr().write(|w| w.rl().set(RELOAD));
        // If the update never lands, the reset values (512 ms) stay.
        let _ = (0..UPDATE_POLLS).any(|_| {
            let sr = iwdg.sr().read();
            sr.pvu().bit_is_clear() && sr.rvu().bit_is_clear()
        });
        iwdg.kr().write(|w| w.key().feed());
        Self(iwdg)
    }

    /// Reload the counter.
    pub fn feed(&mut self) {
        self.0.kr().write(|w| w.key().feed());
    }
}

/// Why the chip last reset, read from RCC_CSR (RM0383 §6.3.20) and then
/// cleared, so the next boot reads its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum ResetCause {
    /// The independent watchdog: the firmware hung.
    Watchdog,
    /// Power on, the reset pin, software, brown-out or low-power: a reset
    /// a person or the supply caused.
    Other,
}

/// The cause of the last reset; clears the flags.
pub fn reset_cause(rcc: &pac::RCC) -> ResetCause {
    let csr = rcc.csr().read();
    let cause = if csr.wdgrstf().bit_is_set() || csr.wwdgrstf().bit_is_set() {
        ResetCause::Watchdog
    } else {
        ResetCause::Other
    };
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    cause
}
