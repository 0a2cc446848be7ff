//! Bring the chip up and hand out the parts: clocks (100 MHz from the
//! ST-LINK's 8 MHz clock), the halt line (asserted from here until the
//! device is armed), the converter on SPI1 started at the sample rate, its
//! data-ready as a falling-edge interrupt, the encoder timer, USART2 for
//! frames, and TIM5 as the data-ready watchdog.

use embedded_hal_bus::spi::ExclusiveDevice;
use needle_holder::ads1220::{Ads1220, Config as AdcConfig, Error};
use stm32f4::stm32f411 as pac;

use super::adc::{rate_for, Acquisition, Converter};
use super::capture::EdgeCapture;
use super::clocks::{self, CycleDelay};
use super::encoder::Encoder;
use super::halt::HaltLine;
use super::iwdg::{self, ResetCause};
use super::pins::{self, ChipSelect, DataReady};
use super::serial::Usart2;
use super::spi::Spi1;
use super::timer::Watchdog;

/// Frames' baud rate on the ST-LINK's virtual COM port.
pub const BAUD: u32 = 921_600;
/// The ADS1220's fastest SPI clock (datasheet §7.6: 150 ns period).
const SPI_MOST_HZ: u32 = 6_600_000;
/// How often the watchdog looks for samples; two looks without one after
/// a look with some is an `adc_timeout` (80–120 ms after the last sample:
/// 40 samples at the slowest rate).
pub const WATCHDOG_HZ: u32 = 25;

/// Everything the application runs on.
pub struct Parts {
    pub acquisition: Acquisition,
    /// The times of the converter's data-ready edges.
    pub edges: EdgeCapture,
    /// Set up by `start`, or why the converter would not start.
    pub converter_started: Result<(), Error<()>>,
    pub encoder: Encoder,
    /// Frames out; commands in once [`super::serial::RxDma`] starts on
    /// `dma1`.
    pub serial: Usart2,
    pub dma1: pac::DMA1,
    pub halt: HaltLine,
    pub watchdog: Watchdog,
    /// The flash interface, for the settings store.
    pub flash: pac::FLASH,
    /// Why the chip last reset.
    pub reset_cause: ResetCause,
    /// The independent watchdog and the debug unit that freezes it,
    /// started once the settings store is ready (its erase stalls for
    /// seconds).
    pub iwdg: (pac::IWDG, pac::DBGMCU),
}

/// Bring everything up for `sample_rate_hz`.
pub fn setup(dp: pac::Peripherals, sample_rate_hz: u16) -> Parts {
    clocks::enable_peripherals(&dp.RCC);
    let halt = HaltLine::asserted(&dp.GPIOA);
    let reset_cause = iwdg::reset_cause(&dp.RCC);
    let clocks = clocks::to_100mhz(&dp.RCC, &dp.FLASH, &dp.PWR);

    pins::spi1(&dp.GPIOA, &dp.GPIOB);
    pins::data_ready(&dp.GPIOA, &dp.SYSCFG, &dp.EXTI);
    let spi = Spi1::new(dp.SPI1, clocks.pclk2_hz, SPI_MOST_HZ);
    let mut delay = CycleDelay {
        sysclk_hz: clocks.sysclk_hz,
    };
    // Chip select is a push-pull pin: setting it cannot fail.
    let device = match ExclusiveDevice::new(spi, ChipSelect::new(), delay) {
        Ok(d) => d,
        Err(never) => match never {},
    };
    let mut converter: Converter = Ads1220::new(device, DataReady::new());
    let (rate, per_sample) = rate_for(sample_rate_hz);
    let converter_started = converter
        .start(&AdcConfig::bridge(rate), &mut delay)
        .map_err(|e| match e {
            Error::Spi(_) => Error::Spi(()),
            Error::Pin => Error::Pin,
            Error::NotReady => Error::NotReady,
            Error::Readback { wrote, read } => Error::Readback { wrote, read },
            Error::Stuck { code } => Error::Stuck { code },
        });

    pins::encoder(&dp.GPIOA);
    let encoder = Encoder::new(dp.TIM2);
    pins::usart2(&dp.GPIOA);
    let serial = Usart2::new(dp.USART2, clocks.pclk1_hz, BAUD);
    let watchdog = Watchdog::start(dp.TIM5, clocks.apb1_timer_hz, WATCHDOG_HZ);

    Parts {
        acquisition: Acquisition::new(converter, per_sample),
        edges: EdgeCapture::start(dp.TIM1, clocks.pclk2_hz),
        converter_started,
        encoder,
        serial,
        dma1: dp.DMA1,
        halt,
        watchdog,
        flash: dp.FLASH,
        reset_cause,
        iwdg: (dp.IWDG, dp.DBGMCU),
    }
}
