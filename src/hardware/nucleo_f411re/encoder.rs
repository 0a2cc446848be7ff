//! The quadrature encoder on TIM2 in encoder mode (both edges of A and B:
//! four counts per line), as the core's [`EncoderCounter`]. TIM2 counts in
//! 32 bits; the core unwraps 16, so the low half is what it reads.

use needle_holder::hal::EncoderCounter;
use stm32f4xx_hal::hal_02::Qei as _;
use stm32f4xx_hal::pac::TIM2;
use stm32f4xx_hal::qei::Qei;

/// TIM2 in encoder mode on PA0 (A) and PA1 (B).
pub struct Encoder(pub Qei<TIM2>);

impl EncoderCounter for Encoder {
    fn count(&mut self) -> u16 {
        // Wrapping on purpose: the core unwraps a 16-bit count.
        self.0.count() as u16
    }
}
