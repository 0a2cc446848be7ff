//! The hardware boundary: the few traits the core is generic over.
//!
//! embedded-hal 1.0 has no ADC trait, so the load cell gets its own small
//! one. The frame sink is [`embedded_io::Write`] and the halt line is
//! [`embedded_hal::digital::OutputPin`]; both come from the ecosystem.

/// One conversion of the load-cell ADC.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct AdcSample {
    /// Raw signed counts, as the converter returns them (before tare and gain).
    pub counts: i32,
    /// The converter was at (or beyond) its full scale: the force is unknown.
    pub saturated: bool,
    /// The converter's overrun flag: a conversion was overwritten before it
    /// was read, so the sample loop ran late and a sample is lost.
    pub overrun: bool,
}

/// A load-cell ADC that returns one conversion per sample period.
pub trait LoadCellAdc {
    /// Bus or converter error.
    type Error: core::fmt::Debug;
    /// The latest conversion.
    fn read(&mut self) -> Result<AdcSample, Self::Error>;
}

/// A quadrature encoder counter, as MCU timers implement it: a free-running
/// 16-bit count that wraps. The core unwraps it (see [`crate::kinematics`]).
pub trait EncoderCounter {
    /// The current count, modulo 2^16.
    fn count(&mut self) -> u16;
}

impl<T: LoadCellAdc + ?Sized> LoadCellAdc for &mut T {
    type Error = T::Error;
    fn read(&mut self) -> Result<AdcSample, Self::Error> {
        (**self).read()
    }
}

impl<T: EncoderCounter + ?Sized> EncoderCounter for &mut T {
    fn count(&mut self) -> u16 {
        (**self).count()
    }
}
