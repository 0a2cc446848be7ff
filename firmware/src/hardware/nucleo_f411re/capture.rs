//! TIM1 channel 3 captures the ADS1220's data-ready edges on PA10 (the
//! pin's alternate function 1; its EXTI line, the sample interrupt, sees
//! the pin all the same), at a 10 µs tick: the time of the latest edge,
//! taken by the hardware however late the sample task runs. The core's
//! [`EdgeClock`](needle_holder::sample_clock::EdgeClock) counts the edges
//! from it.

use stm32f4::stm32f411 as pac;

/// The counter's tick: 10 µs, so its 16 bits span 655 ms, longer than
/// the independent watchdog lets the sample task stop while the device
/// runs (halted by `adc_timeout`, it may stop longer: see
/// [`EdgeClock`](needle_holder::sample_clock::EdgeClock)).
pub const TICK_HZ: u32 = 100_000;

/// TIM1 capturing falling edges on channel 3.
pub struct EdgeCapture(pac::TIM1);

impl EdgeCapture {
    /// Counting at [`TICK_HZ`] from the APB2 timer clock `clock_hz`,
    /// capturing from here on (RM0383 §12.3.5).
    pub fn start(tim: pac::TIM1, clock_hz: u32) -> Self {
        let psc = (clock_hz / TICK_HZ).saturating_sub(1);
        // SAFETY: any values are a prescaler and a reload.
        tim.psc().write(|w| unsafe { w.bits(psc) });
        tim.arr().write(|w| unsafe { w.bits(0xFFFF) });
        // IC3 from TI3, no filter, every edge; falling (CC3P = 1,
        // CC3NP = 0), capture on.
        tim.ccmr2_input().modify(|_, w| w.cc3s().ti3());
        tim.ccer().modify(|_, w| {
            w.cc3p().falling_edge();
            w.cc3np().clear_bit();
            w.cc3e().set_bit()
        });
        tim.egr().write(|w| w.ug().set_bit());
        tim.cr1().write(|w| w.cen().set_bit());
        Self(tim)
    }

    /// The counter's value at the latest falling edge.
    pub fn latest(&self) -> u16 {
        self.0.ccr3().read().ccr().bits()
    }
}
