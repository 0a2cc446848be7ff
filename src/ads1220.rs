//! The ADS1220 (crate `ads1220`, the real board's load-cell converter) as
//! the core's [`LoadCellAdc`]: the driver knows its chip, the core what a
//! sample is.

pub use ads1220::*;

use embedded_hal::digital::InputPin;
use embedded_hal::spi::SpiDevice;

use crate::hal::{AdcSample, LoadCellAdc};

impl<SPI: SpiDevice, DRDY: InputPin> LoadCellAdc for Ads1220<SPI, DRDY> {
    type Error = Error<SPI::Error>;

    /// [`Ads1220::read_checked`]; never an overrun (the board raises
    /// `sample_overrun` when data-ready falls while the previous sample is
    /// in hand).
    fn read(&mut self) -> Result<AdcSample, Self::Error> {
        let reading = self.read_checked()?;
        Ok(AdcSample {
            counts: reading.counts,
            saturated: reading.saturated,
            overrun: false,
        })
    }
}
