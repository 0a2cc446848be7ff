//! The clock tree, on the registers (RM0383 §6): 100 MHz from the PLL, fed
//! by the ST-LINK's 8 MHz clock on the HSE pin (bypass) — or by the 16 MHz
//! HSI when that clock is missing (solder bridge SB16 open), so a board
//! without it still runs at full speed. stm32f4xx-hal's `freeze` does the
//! same for any configuration, and links panics for the configurations it
//! refuses; this does one, and panics for none.

use stm32f4::stm32f411 as pac;

/// What the clock tree ended up as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Clocks {
    /// Core and AHB.
    pub sysclk_hz: u32,
    /// APB1 (USART2, TIM2, TIM5), at most 50 MHz.
    pub pclk1_hz: u32,
    /// APB2 (SPI1), at most 100 MHz.
    pub pclk2_hz: u32,
    /// APB1's timers: twice APB1 when APB1 is divided (RM0383 §6.2).
    pub apb1_timer_hz: u32,
}

/// After reset: the HSI, no prescaler.
pub const HSI: Clocks = Clocks {
    sysclk_hz: 16_000_000,
    pclk1_hz: 16_000_000,
    pclk2_hz: 16_000_000,
    apb1_timer_hz: 16_000_000,
};

/// From the PLL: 100 MHz core and APB2, APB1 halved to its 50 MHz limit.
pub const PLL_100MHZ: Clocks = Clocks {
    sysclk_hz: 100_000_000,
    pclk1_hz: 50_000_000,
    pclk2_hz: 100_000_000,
    apb1_timer_hz: 100_000_000,
};

/// Polls of a ready bit before giving up on it: far longer than the HSE's
/// or the PLL's start-up (≤ 2 ms, datasheet §6.3) at 16 MHz.
const READY_POLLS: u32 = 200_000;

fn wait_for(ready: impl Fn() -> bool) -> bool {
    (0..READY_POLLS).any(|_| ready())
}

/// Turn on the clocks of the peripherals the board uses.
pub fn enable_peripherals(rcc: &pac::RCC) {
    rcc.ahb1enr().modify(|_, w| {
        w.gpioaen().set_bit();
        w.gpioben().set_bit();
        w.dma1en().set_bit()
    });
    rcc.apb1enr().modify(|_, w| {
        w.tim2en().set_bit();
        w.tim5en().set_bit();
        w.usart2en().set_bit();
        w.pwren().set_bit()
    });
    rcc.apb2enr().modify(|_, w| {
        w.spi1en().set_bit();
        w.syscfgen().set_bit();
        w.tim1en().set_bit()
    });
    // Two cycles before an enabled peripheral's registers answer (RM0383
    // §6.3.10 note).
    cortex_m::asm::dsb();
}

/// 100 MHz from the PLL; the HSI as it was if the PLL does not lock.
pub fn to_100mhz(rcc: &pac::RCC, flash: &pac::FLASH, pwr: &pac::PWR) -> Clocks {
    // Scale 1 regulator (100 MHz needs it; reset leaves scale 2, 84 MHz);
    // settable only while the PLL is off.
    pwr.cr().modify(|_, w| w.vos().scale1());
    rcc.cr()
        .modify(|_, w| w.hsebyp().set_bit().hseon().set_bit());
    let from_hse = wait_for(|| rcc.cr().read().hserdy().bit_is_set());
    if !from_hse {
        defmt::warn!("no 8 MHz clock on HSE (ST-LINK MCO): PLL from HSI");
        rcc.cr().modify(|_, w| w.hseon().clear_bit());
    }
    // VCO input 2 MHz (M = 4 from 8 MHz, 8 from 16), VCO 200 MHz (N = 100),
    // system 100 MHz (P = 2); Q only feeds USB, unused: 50 MHz.
    let m = if from_hse { 4 } else { 8 };
    // SAFETY: M, N, Q are within their fields' ranges (2..=63, 50..=432,
    // 2..=15, RM0383 §6.3.2).
    rcc.pllcfgr().write(|w| unsafe {
        w.pllm().bits(m);
        w.plln().bits(100);
        w.pllq().bits(4);
        w.pllp().div2();
        if from_hse {
            w.pllsrc().hse()
        } else {
            w.pllsrc().hsi()
        }
    });
    rcc.cr().modify(|_, w| w.pllon().set_bit());
    if !wait_for(|| rcc.cr().read().pllrdy().bit_is_set()) {
        defmt::error!("PLL did not lock: running on HSI at 16 MHz");
        return HSI;
    }
    // The regulator reaches scale 1 only once the PLL is on (RM0383
    // §5.4.1: VOSRDY); 100 MHz before that would overclock scale 2.
    if !wait_for(|| pwr.csr().read().vosrdy().bit_is_set()) {
        defmt::error!("regulator not at scale 1: running on HSI at 16 MHz");
        return HSI;
    }
    // 3 wait states for 90–100 MHz at 2.7–3.6 V (RM0383 table 6), before
    // the clock rises; prefetch and caches make up for them.
    flash.acr().modify(|_, w| {
        w.latency().ws3();
        w.prften().set_bit();
        w.icen().set_bit();
        w.dcen().set_bit()
    });
    if !wait_for(|| flash.acr().read().latency().is_ws3()) {
        defmt::error!("flash wait states not taken: running on HSI at 16 MHz");
        return HSI;
    }
    rcc.cfgr()
        .modify(|_, w| w.hpre().div1().ppre1().div2().ppre2().div1());
    rcc.cfgr().modify(|_, w| w.sw().pll());
    if !wait_for(|| rcc.cfgr().read().sws().is_pll()) {
        defmt::error!("system clock did not switch to the PLL");
        // Still on HSI: undivided again, as `HSI` says.
        rcc.cfgr().modify(|_, w| w.ppre1().div1());
        return HSI;
    }
    PLL_100MHZ
}

/// A busy wait in core cycles, as embedded-hal's delay (the converter's
/// reset wait at start-up).
#[derive(Clone, Copy)]
pub struct CycleDelay {
    pub sysclk_hz: u32,
}

impl embedded_hal::delay::DelayNs for CycleDelay {
    fn delay_ns(&mut self, ns: u32) {
        let cycles = u64::from(ns) * u64::from(self.sysclk_hz) / 1_000_000_000;
        // At least the time asked: one more cycle than the truncation.
        cortex_m::asm::delay(u32::try_from(cycles + 1).unwrap_or(u32::MAX));
    }
}
