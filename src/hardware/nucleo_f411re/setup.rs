//! Bring the chip up and hand out the parts: clocks (100 MHz from the
//! ST-LINK's 8 MHz clock), the halt line (asserted from here until the
//! device is armed), the converter on SPI1 started at the sample rate, its
//! data-ready as a falling-edge interrupt, the encoder timer, USART2 for
//! frames, and TIM5 as the data-ready watchdog.

use embedded_hal::spi::MODE_1;
use embedded_hal_bus::spi::ExclusiveDevice;
use needle_holder::ads1220::{Ads1220, Config as AdcConfig, Error};
use stm32f4xx_hal::gpio::{Edge, PinState};
use stm32f4xx_hal::pac::{self, TIM5, USART2};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::qei::Qei;
use stm32f4xx_hal::rcc::Config;
use stm32f4xx_hal::serial::{Rx, RxListen, Tx};
use stm32f4xx_hal::timer::{CounterHz, Event};

use super::adc::{rate_for, Acquisition, Converter};
use super::encoder::Encoder;
use super::halt::HaltLine;

/// Frames' baud rate on the ST-LINK's virtual COM port.
pub const BAUD: u32 = 921_600;
/// SPI clock: APB2's 100 MHz / 16, under the ADS1220's 6.6 MHz limit.
const SPI_HZ: u32 = 6_250_000;
/// How often the watchdog looks for samples; two looks without one is an
/// `adc_timeout` (40–80 ms: 20 samples at the slowest rate).
pub const WATCHDOG_HZ: u32 = 25;

/// Everything the application runs on.
pub struct Parts {
    pub acquisition: Acquisition,
    /// Set up by `start`, or why the converter would not start.
    pub converter_started: Result<(), Error<()>>,
    pub encoder: Encoder,
    pub tx: Tx<USART2>,
    /// Commands from the host; its receive interrupt is on.
    pub rx: Rx<USART2>,
    pub halt: HaltLine,
    pub watchdog: CounterHz<TIM5>,
    /// The flash interface, for the settings store.
    pub flash: pac::FLASH,
}

/// Bring everything up for `sample_rate_hz`.
pub fn setup(mut dp: pac::Peripherals, cp: cortex_m::Peripherals, sample_rate_hz: u16) -> Parts {
    // The Nucleo's HSE is the ST-LINK's 8 MHz MCO output (bypass).
    let mut rcc = dp.RCC.freeze(
        Config::hse(8.MHz())
            .bypass_hse_oscillator()
            .sysclk(100.MHz()),
    );
    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let halt = gpioa.pa8.into_push_pull_output_in_state(PinState::High);

    let spi = dp.SPI1.spi(
        (Some(gpioa.pa5), Some(gpioa.pa6), Some(gpioa.pa7)),
        MODE_1,
        SPI_HZ.Hz(),
        &mut rcc,
    );
    let cs = gpiob.pb6.into_push_pull_output_in_state(PinState::High);
    let mut drdy = gpioa.pa10.into_pull_up_input();
    let mut syscfg = dp.SYSCFG.constrain(&mut rcc);
    drdy.make_interrupt_source(&mut syscfg);
    drdy.trigger_on_edge(&mut dp.EXTI, Edge::Falling);
    drdy.enable_interrupt(&mut dp.EXTI);
    // Chip select is a push-pull pin: setting it cannot fail.
    let device = match ExclusiveDevice::new_no_delay(spi, cs) {
        Ok(d) => d,
        Err(never) => match never {},
    };
    let mut converter: Converter = Ads1220::new(device, drdy);
    let (rate, per_sample) = rate_for(sample_rate_hz);
    let mut delay = cp.SYST.delay(&rcc.clocks);
    let converter_started = converter
        .start(&AdcConfig::bridge(rate), &mut delay)
        .map_err(|e| match e {
            Error::Spi(_) => Error::Spi(()),
            Error::Pin => Error::Pin,
            Error::NotReady => Error::NotReady,
            Error::Readback { wrote, read } => Error::Readback { wrote, read },
        });

    let encoder = Encoder(Qei::new(dp.TIM2, (gpioa.pa0, gpioa.pa1), &mut rcc));
    let (tx, mut rx) = dp
        .USART2
        .serial::<u8>((gpioa.pa2, gpioa.pa3), BAUD.bps(), &mut rcc)
        .unwrap_or_else(|_| unreachable_baud())
        .split();
    rx.listen();
    let mut watchdog = dp.TIM5.counter_hz(&mut rcc);
    // A frequency the timer takes at 100 MHz.
    let _ = watchdog.start(WATCHDOG_HZ.Hz());
    watchdog.listen(Event::Update);

    Parts {
        acquisition: Acquisition::new(converter, per_sample),
        converter_started,
        encoder,
        tx,
        rx,
        halt,
        watchdog,
        flash: dp.FLASH,
    }
}

/// 921 600 Bd from APB1's 50 MHz is within the USART's range; a build
/// that changed the clocks so it is not would stop here with the halt line
/// asserted.
fn unreachable_baud() -> ! {
    defmt::error!("USART2 cannot make {=u32} Bd", BAUD);
    loop {
        cortex_m::asm::wfi();
    }
}
