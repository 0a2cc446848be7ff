//! The board's pins (the table in [`super`]), on the GPIO registers: each
//! set-up writes only its own pins' fields, and the pin handles the core
//! drives ([`ChipSelect`], [`DataReady`], and the halt line in
//! [`super::halt`]) touch only their own bit, through the set/reset and
//! input registers, which no other code shares.

use core::convert::Infallible;

use stm32f4::stm32f411 as pac;

/// USART2 on PA2 (TX) and PA3 (RX, pulled up so an unplugged line reads
/// idle), alternate function 7.
pub fn usart2(gpioa: &pac::GPIOA) {
    gpioa.afrl().modify(|_, w| w.afrl2().af7().afrl3().af7());
    gpioa.pupdr().modify(|_, w| w.pupdr3().pull_up());
    gpioa
        .moder()
        .modify(|_, w| w.moder2().alternate().moder3().alternate());
}

/// SPI1 on PA5 (SCK), PA6 (MISO), PA7 (MOSI), alternate function 5, fast
/// edges for 6.25 MHz; the converter's chip select PB6, high (idle) before
/// it becomes an output.
pub fn spi1(gpioa: &pac::GPIOA, gpiob: &pac::GPIOB) {
    gpioa
        .afrl()
        .modify(|_, w| w.afrl5().af5().afrl6().af5().afrl7().af5());
    gpioa
        .ospeedr()
        .modify(|_, w| w.ospeedr5().high_speed().ospeedr7().high_speed());
    gpioa.moder().modify(|_, w| {
        w.moder5().alternate();
        w.moder6().alternate();
        w.moder7().alternate()
    });
    gpiob.bsrr().write(|w| w.bs6().set_bit());
    gpiob.moder().modify(|_, w| w.moder6().output());
}

/// The encoder's A and B on PA0, PA1 as TIM2's channels 1 and 2
/// (alternate function 1), pulled up for open-collector encoders.
pub fn encoder(gpioa: &pac::GPIOA) {
    gpioa.afrl().modify(|_, w| w.afrl0().af1().afrl1().af1());
    gpioa
        .pupdr()
        .modify(|_, w| w.pupdr0().pull_up().pupdr1().pull_up());
    gpioa
        .moder()
        .modify(|_, w| w.moder0().alternate().moder1().alternate());
}

/// The converter's data-ready on PA10: input, pulled up, its falling edge
/// an interrupt on EXTI line 10 (EXTI15_10).
pub fn data_ready(gpioa: &pac::GPIOA, syscfg: &pac::SYSCFG, exti: &pac::EXTI) {
    gpioa.pupdr().modify(|_, w| w.pupdr10().pull_up());
    // TIM1_CH3 (alternate function 1) captures its edges; the input
    // data register and the EXTI line see the pin in that mode too.
    gpioa.afrh().modify(|_, w| w.afrh10().af1());
    gpioa.moder().modify(|_, w| w.moder10().alternate());
    // SAFETY: 0 selects port A for line 10 (RM0383 §7.2.5).
    syscfg
        .exticr3()
        .modify(|_, w| unsafe { w.exti10().bits(0) });
    exti.ftsr().modify(|_, w| w.tr10().set_bit());
    exti.rtsr().modify(|_, w| w.tr10().clear_bit());
    exti.pr().write(|w| w.pr10().clear());
    exti.imr().modify(|_, w| w.mr10().set_bit());
}

fn gpioa() -> &'static pac::gpioa::RegisterBlock {
    // SAFETY: the handles below only write BSRR (atomic set/reset of their
    // own bit) and read IDR; see the module's note.
    unsafe { &*pac::GPIOA::ptr() }
}

/// The converter's chip select, PB6, as embedded-hal's output pin.
pub struct ChipSelect(());

impl ChipSelect {
    /// After [`spi1`] made PB6 an output.
    pub fn new() -> Self {
        Self(())
    }
}

impl embedded_hal::digital::ErrorType for ChipSelect {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for ChipSelect {
    fn set_low(&mut self) -> Result<(), Infallible> {
        // SAFETY: as for `gpioa`, on port B's BSRR.
        unsafe { (*pac::GPIOB::ptr()).bsrr().write(|w| w.br6().set_bit()) };
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        // SAFETY: as for `gpioa`, on port B's BSRR.
        unsafe { (*pac::GPIOB::ptr()).bsrr().write(|w| w.bs6().set_bit()) };
        Ok(())
    }
}

/// The converter's data-ready, PA10, as embedded-hal's input pin, with its
/// EXTI line's pending flag.
pub struct DataReady(());

impl DataReady {
    /// After [`data_ready`] set the pin and its line up.
    pub fn new() -> Self {
        Self(())
    }

    fn exti() -> &'static pac::exti::RegisterBlock {
        // SAFETY: PR is write-one-to-clear: writing bit 10 alone touches no
        // other line; reading it has no effect.
        unsafe { &*pac::EXTI::ptr() }
    }

    /// Whether the line has fallen since the flag was last cleared.
    pub fn pending(&self) -> bool {
        Self::exti().pr().read().pr10().bit_is_set()
    }

    pub fn clear_pending(&mut self) {
        Self::exti().pr().write(|w| w.pr10().clear());
    }
}

impl embedded_hal::digital::ErrorType for DataReady {
    type Error = Infallible;
}

impl embedded_hal::digital::InputPin for DataReady {
    fn is_high(&mut self) -> Result<bool, Infallible> {
        Ok(gpioa().idr().read().idr10().bit_is_set())
    }

    fn is_low(&mut self) -> Result<bool, Infallible> {
        Ok(gpioa().idr().read().idr10().bit_is_clear())
    }
}
