//! The ADS1220 on SPI1 (mode 1, 6.25 MHz; [`super::spi`]), chip select on PB6, data-ready
//! on PA10; and what the sample task makes of its conversions: a pair
//! averaged into one sample at 500 Hz (the converter has no 500 SPS mode;
//! averaging two 1000 SPS conversions also halves the noise power), and a
//! data-ready that fell while the last sample was still in hand reported
//! as an overrun (the chip has no overrun flag).

use core::convert::Infallible;

use embedded_hal_bus::spi::ExclusiveDevice;
use needle_holder::ads1220::{Ads1220, DataRate, Error};
use needle_holder::hal::{AdcSample, LoadCellAdc};

use super::clocks::CycleDelay;
use super::pins::{ChipSelect, DataReady};
use super::spi::Spi1;

/// SPI1 with the converter's chip select.
pub type Bus = ExclusiveDevice<Spi1, ChipSelect, CycleDelay>;

/// The converter on its bus.
pub type Converter = Ads1220<Bus, DataReady>;

/// The converter's rate and how many conversions make one sample, for a
/// sample rate the core is configured for.
pub fn rate_for(sample_rate_hz: u16) -> (DataRate, u8) {
    match sample_rate_hz {
        2000 => (DataRate::Turbo2000, 1),
        1000 => (DataRate::Sps1000, 1),
        _ => (DataRate::Sps1000, 2),
    }
}

/// Conversions averaged into samples, with the overrun flag the board
/// raises.
pub struct Acquisition {
    pub converter: Converter,
    /// Conversions per sample (1 or 2).
    pub per_sample: u8,
    /// Conversions so far of the sample being built: their sum and whether
    /// any was at full scale.
    taken: u8,
    sum: i64,
    saturated: bool,
    /// A data-ready fell while the previous sample was being processed.
    pub overrun: bool,
}

/// A sample is complete, or the converter failed.
pub enum Conversion {
    /// More conversions to come before a sample.
    Partial,
    /// The edge was stale: data-ready is high again, the conversion it
    /// announced already read (the task ran a period late and read the
    /// next one). Nothing to do; a converter that stops altogether is the
    /// watchdog's `adc_timeout`.
    Stale,
    /// A whole sample.
    Sample(AdcSample),
    /// The bus or the converter failed.
    Failed(Error<<Bus as embedded_hal::spi::ErrorType>::Error>),
}

impl Acquisition {
    pub fn new(converter: Converter, per_sample: u8) -> Self {
        Self {
            converter,
            per_sample: per_sample.max(1),
            taken: 0,
            sum: 0,
            saturated: false,
            overrun: false,
        }
    }

    /// Read the conversion data-ready announced.
    pub fn convert(&mut self) -> Conversion {
        let one = match self.converter.read() {
            Ok(s) => s,
            Err(Error::NotReady) => return Conversion::Stale,
            Err(e) => return Conversion::Failed(e),
        };
        self.sum += i64::from(one.counts);
        self.saturated |= one.saturated;
        self.taken += 1;
        if self.taken < self.per_sample {
            return Conversion::Partial;
        }
        let n = i64::from(self.taken);
        let sample = AdcSample {
            // The mean of at most two 24-bit codes fits i32; `n` ≥ 1
            // (checked_div so no panic path is linked for it).
            counts: self.sum.checked_div(n).unwrap_or(0) as i32,
            saturated: self.saturated,
            overrun: core::mem::take(&mut self.overrun),
        };
        (self.taken, self.sum, self.saturated) = (0, 0, false);
        Conversion::Sample(sample)
    }
}

/// One sample already read, handed to the core's `Device::tick` as its ADC.
pub struct Ready(pub AdcSample);

impl LoadCellAdc for Ready {
    type Error = Infallible;
    fn read(&mut self) -> Result<AdcSample, Infallible> {
        Ok(self.0)
    }
}

/// A converter that failed, handed to `Device::tick`: the core raises
/// `adc_error` and halts, as for any ADC.
pub struct Broken;

impl LoadCellAdc for Broken {
    type Error = ();
    fn read(&mut self) -> Result<AdcSample, ()> {
        Err(())
    }
}
