//! The quadrature encoder on TIM2 in encoder mode (both edges of A and B:
//! four counts per line), as the core's [`EncoderCounter`]. TIM2 counts in
//! 32 bits; the core unwraps 16, so the low half is what it reads.

use needle_holder::hal::EncoderCounter;
use stm32f4::stm32f411 as pac;

/// TIM2 in encoder mode on PA0 (A) and PA1 (B).
pub struct Encoder(pac::TIM2);

impl Encoder {
    /// Counting from 0 (RM0383 §13.3.16: channels on TI1 and TI2, slave
    /// mode 3, the whole 32-bit range).
    pub fn new(tim: pac::TIM2) -> Self {
        // Each input filtered over 8 timer clocks (80 ns at 100 MHz): a
        // glitch on a cable with only the pins' weak pull-ups is not a
        // count; edges of a 1 MHz quadrature signal still are.
        tim.ccmr1_input().write(|w| {
            w.cc1s().ti1().cc2s().ti2();
            w.ic1f().fck_int_n8().ic2f().fck_int_n8()
        });
        tim.smcr().write(|w| w.sms().encoder_mode_3());
        // SAFETY: any value is a reload value.
        tim.arr().write(|w| unsafe { w.bits(u32::MAX) });
        tim.cnt().reset();
        tim.cr1().write(|w| w.cen().set_bit());
        Self(tim)
    }
}

impl EncoderCounter for Encoder {
    fn count(&mut self) -> u16 {
        // Wrapping on purpose: the core unwraps a 16-bit count.
        self.0.cnt().read().bits() as u16
    }
}
