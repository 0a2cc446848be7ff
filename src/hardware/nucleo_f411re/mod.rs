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
//! | frames out | PA2 (USART2_TX) at 921 600 Bd | the ST-LINK's virtual COM port |
//!
//! Split by concern as stabilizer does: [`setup`] brings the chip up and
//! hands out the parts, [`adc`] is the converter on its bus, [`encoder`]
//! the timer in encoder mode, [`link`] the frame queue and its drain,
//! [`halt`] the line and what a panic does to it; [`app`] is the RTIC
//! application that schedules them (the converter's data-ready is the
//! sample clock).

pub mod adc;
mod app;
pub mod encoder;
pub mod halt;
pub mod link;
pub mod setup;

// defmt over RTT (probe-rs reads it).
use defmt_rtt as _;

/// Board name for logs.
pub const BOARD: &str = "nucleo-f411re";
