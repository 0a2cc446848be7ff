//! SPI1 as embedded-hal's bus, on the registers: master, 8-bit, mode 1
//! (the ADS1220's), polled — a conversion is 4 bytes, 5 µs at 6.25 MHz,
//! less than setting up a DMA transfer would take. Every wait is bounded:
//! a bus that stops answering is an error, never a hang.

use embedded_hal::spi::{ErrorKind, ErrorType, SpiBus};
use stm32f4::stm32f411 as pac;

/// Polls of a status flag before the bus counts as stuck: a byte takes
/// 8 × 16 = 128 APB2 clocks at the setting used, far fewer polls.
const POLLS: u32 = 10_000;

pub struct Spi1(pac::SPI1);

/// What went wrong on the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// A byte came in before the last was read.
    Overrun,
    /// Another master pulled NSS (cannot happen with software NSS).
    ModeFault,
    /// A flag never came.
    Timeout,
}

impl embedded_hal::spi::Error for Error {
    fn kind(&self) -> ErrorKind {
        match self {
            Error::Overrun => ErrorKind::Overrun,
            Error::ModeFault => ErrorKind::ModeFault,
            Error::Timeout => ErrorKind::Other,
        }
    }
}

impl Spi1 {
    /// Enabled at the fastest clock from APB2's `pclk2_hz` no faster than
    /// `most_hz` (100 MHz / 16 = 6.25 MHz for the ADS1220's 6.6 MHz).
    pub fn new(spi: pac::SPI1, pclk2_hz: u32, most_hz: u32) -> Self {
        // BR = k divides by 2^(k+1), k in 0..=7.
        let br = (0u8..7)
            .find(|&k| pclk2_hz >> (k + 1) <= most_hz)
            .unwrap_or(7);
        spi.cr1().write(|w| {
            w.cpha().second_edge();
            w.cpol().idle_low();
            w.mstr().master();
            // SAFETY: 0..=7 are the field's values.
            unsafe { w.br().bits(br) };
            w.ssm().enabled();
            w.ssi().slave_not_selected();
            w.dff().eight_bit();
            w.lsbfirst().msbfirst();
            w.spe().enabled()
        });
        Self(spi)
    }

    fn wait(&self, flag: impl Fn(&pac::spi1::sr::R) -> bool) -> Result<(), Error> {
        for _ in 0..POLLS {
            let sr = self.0.sr().read();
            if sr.ovr().bit_is_set() {
                // Reading DR then SR clears it.
                let _ = self.0.dr().read();
                let _ = self.0.sr().read();
                return Err(Error::Overrun);
            }
            if sr.modf().bit_is_set() {
                return Err(Error::ModeFault);
            }
            if flag(&sr) {
                return Ok(());
            }
        }
        Err(Error::Timeout)
    }

    /// Leave what an earlier error left: a late byte in DR (after a
    /// timeout) would shift every read after it by one; a mode fault
    /// clears SPE and MSTR.
    fn recover(&mut self) {
        let sr = self.0.sr().read();
        if sr.rxne().bit_is_set() || sr.ovr().bit_is_set() {
            let _ = self.0.dr().read();
            let _ = self.0.sr().read();
        }
        if sr.modf().bit_is_set() {
            // Reading SR (above) then writing CR1 clears it (RM0383 §20.4.8).
            self.0
                .cr1()
                .modify(|_, w| w.mstr().master().spe().enabled());
        }
    }

    /// One byte out, one in.
    fn exchange(&mut self, out: u8) -> Result<u8, Error> {
        self.recover();
        self.wait(|sr| sr.txe().bit_is_set())?;
        // SAFETY: any byte is data.
        self.0
            .dr()
            .write(|w| unsafe { w.dr().bits(u16::from(out)) });
        self.wait(|sr| sr.rxne().bit_is_set())?;
        Ok(self.0.dr().read().dr().bits() as u8)
    }
}

impl ErrorType for Spi1 {
    type Error = Error;
}

impl SpiBus for Spi1 {
    fn read(&mut self, words: &mut [u8]) -> Result<(), Error> {
        for word in words {
            *word = self.exchange(0)?;
        }
        Ok(())
    }

    fn write(&mut self, words: &[u8]) -> Result<(), Error> {
        for &word in words {
            self.exchange(word)?;
        }
        Ok(())
    }

    fn transfer(&mut self, read: &mut [u8], write: &[u8]) -> Result<(), Error> {
        // The longer of the two; zeros out past `write`, reads past `read`
        // dropped (embedded-hal's contract).
        let n = read.len().max(write.len());
        let mut out = write.iter().copied();
        let mut into = read.iter_mut();
        for _ in 0..n {
            let byte = self.exchange(out.next().unwrap_or(0))?;
            if let Some(slot) = into.next() {
                *slot = byte;
            }
        }
        Ok(())
    }

    fn transfer_in_place(&mut self, words: &mut [u8]) -> Result<(), Error> {
        for word in words {
            *word = self.exchange(*word)?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), Error> {
        self.wait(|sr| sr.bsy().bit_is_clear())
    }
}
