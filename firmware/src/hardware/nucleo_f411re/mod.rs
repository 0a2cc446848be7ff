//! ST Nucleo-F411RE (STM32F411RE, Cortex-M4F at 100 MHz): the real board.
//!
//! | signal | pin | Nucleo header |
//! |---|---|---|
//! | ADS1220 SCLK | PA5 (SPI1_SCK) | D13 (CN5-6) |
//! | ADS1220 DOUT/DRDY→MISO | PA6 (SPI1_MISO) | D12 (CN5-5) |
//! | ADS1220 DIN | PA7 (SPI1_MOSI) | D11 (CN5-4) |
//! | ADS1220 /CS | PB6 | D10 (CN5-3) |
//! | ADS1220 /DRDY | PA10 (EXTI10, falling) | D2 (CN9-3) |
//! | encoder A, B | PA0, PA1 (TIM2 CH1, CH2, encoder mode) | A0, A1 (CN8-1, CN8-2) |
//! | halt line (to the robot) | PA8, push-pull, active high | D7 (CN9-8) |
//! | frames out, commands in | PA2 (USART2_TX), PA3 (USART2_RX) at 921 600 Bd | the ST-LINK's virtual COM port |
//!
//! Split by concern as stabilizer does: [`setup`] brings the chip up and
//! hands out the parts, [`clocks`] the clock tree, [`pins`] the GPIO,
//! [`adc`] is the converter on its bus ([`spi`]), [`capture`] the timer
//! that times its data-ready edges, [`encoder`] the timer in
//! encoder mode, [`serial`] USART2 and [`link`] the frame queue and its
//! drain, [`timer`] the data-ready watchdog's tick, [`iwdg`] the
//! independent watchdog that resets a hung chip, [`halt`] the line and
//! what a panic does to it, [`store`] the settings sector in flash, [`rtt`] the
//! defmt logger; [`app`] is the RTIC application that schedules them (the
//! converter's data-ready is the sample clock).
//!
//! All of it is on the registers, through the peripheral access crate
//! (`stm32f4`), not on stm32f4xx-hal: the HAL's clock set-up (`freeze`)
//! checks every configuration at run time and links the panics for those
//! it refuses (and embedded-hal-bus's delay-less SPI device and defmt-rtt
//! link more: a real delay here, and our own RTT logger); the
//! firmware is proved, at link time, to have no panic path
//! (`host-tools/tests/integration/firmware_image.rs`). Each register write cites the
//! reference manual (RM0383) where the value is not self-evident.
//!
//! With feature `f411-replay` the same board code runs [`replay_app`]
//! instead: the replay file (over semihosting) in place of the converter
//! and the encoder, TIM2 at the replay's rate as the sample clock, on HSI
//! (QEMU `netduinoplus2` models neither the HSE nor the PLL's ready bits).

#[cfg(not(feature = "f411-replay"))]
pub mod adc;
#[cfg(not(feature = "f411-replay"))]
mod app;
#[cfg(not(feature = "f411-replay"))]
pub mod capture;
// The replay image runs on the HSI and only sends.
#[cfg_attr(feature = "f411-replay", allow(dead_code))]
pub mod clocks;
#[cfg(not(feature = "f411-replay"))]
pub mod encoder;
pub mod halt;
#[cfg(not(feature = "f411-replay"))]
pub mod iwdg;
pub mod link;
// The replay image sets up only USART2's pins.
#[cfg_attr(feature = "f411-replay", allow(dead_code))]
pub mod pins;
#[cfg(feature = "f411-replay")]
mod replay_app;
// defmt over RTT on the board (probe-rs reads it); over semihosting in
// QEMU, where the replay image runs (`hardware::semihost`).
#[cfg(not(feature = "f411-replay"))]
mod rtt;
#[cfg_attr(feature = "f411-replay", allow(dead_code))]
pub mod serial;
#[cfg(not(feature = "f411-replay"))]
pub mod setup;
#[cfg(not(feature = "f411-replay"))]
pub mod spi;
pub mod stack;
#[cfg(not(feature = "f411-replay"))]
pub mod store;
pub mod timer;

/// Board name for logs.
pub const BOARD: &str = "nucleo-f411re";
