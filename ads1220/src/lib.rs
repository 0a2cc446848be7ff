//! TI ADS1220: 24-bit delta-sigma ADC on SPI, the load cell's converter on
//! the needle holder's real board. A crate of its own that depends on
//! `embedded-hal` alone; the core reads it as its load-cell converter
//! (`needle_holder::ads1220`).
//!
//! Written here rather than taken from `embedded-ads1220` 0.1, which sets
//! the wrong data-rate bits, sign-extends positive codes and returns
//! `Ok(0)` on a timeout (found by trying it). Generic over
//! [`embedded_hal::spi::SpiDevice`] (SPI mode 1, up to 6.6 MHz; the device
//! owns chip select) and the data-ready pin ([`InputPin`], low while a
//! conversion waits to be read), so it runs on any HAL and is tested on the
//! host against `embedded-hal-mock` transactions (`tests/driver.rs`).
//!
//! Register bits (datasheet SBAS501, §8.6):
//! - reg 0: MUX\[7:4\], GAIN\[3:1\], PGA_BYPASS\[0\]
//! - reg 1: DR\[7:5\], MODE\[4:3\] (00 normal, 10 turbo), CM\[2\] (1 continuous),
//!   TS\[1\], BCS\[0\]
//! - reg 2: VREF\[7:6\] (01 REFP0/REFN0), FIR\[5:4\], PSW\[3\], IDAC\[2:0\]
//! - reg 3: I1MUX\[7:5\], I2MUX\[4:2\], DRDYM\[1\], reserved 0

#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

use embedded_hal::delay::DelayNs;
use embedded_hal::digital::InputPin;
use embedded_hal::spi::{Operation, SpiDevice};

/// SPI commands.
pub mod command {
    /// Reset the device (registers to their defaults).
    pub const RESET: u8 = 0x06;
    /// Start or restart conversions.
    pub const START_SYNC: u8 = 0x08;
    /// Enter power-down.
    pub const POWERDOWN: u8 = 0x02;
    /// Read the latest conversion.
    pub const RDATA: u8 = 0x10;
    /// `0010 rrnn`: read nn + 1 registers from rr.
    pub const RREG: u8 = 0x20;
    /// `0100 rrnn`: write nn + 1 registers from rr.
    pub const WREG: u8 = 0x40;
}

/// Largest code: a conversion there is at (or beyond) positive full
/// scale, and the force it stands for is unknown.
pub const FULL_SCALE_POSITIVE: i32 = 0x7F_FFFF;
/// Smallest code: negative full scale, likewise.
pub const FULL_SCALE_NEGATIVE: i32 = -0x80_0000;

/// 7/8 of full scale: the PGA's linear limit at high gain on a reference
/// at the supply ([`Config::linear_range`]).
pub const LINEAR_LIMIT_HIGH_GAIN: i32 = (1 << 23) / 8 * 7;

/// Conversions between two read-backs of the configuration registers
/// while converting: a converter that lost power or its bus since the
/// start is found within 32 ms at 1000 SPS.
pub const CHECK_EVERY: u16 = 32;

/// The same code this many conversions running is a stuck bus, not a
/// reading: a floating or shorted MISO reads 0x000000 or 0xFFFFFF, both
/// plausible forces. A bridge at gain 128 has noise of hundreds of codes,
/// so two equal codes in a row are rare and sixteen never happen; codes
/// at full scale are excepted (a real overload holds them: saturation).
pub const STUCK_RUN: u16 = 16;

/// Wait after RESET before the next command: 50 µs + 32 clocks of the
/// 4.096 MHz oscillator (58 µs), with margin.
const RESET_WAIT_US: u32 = 100;

/// PGA gain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(missing_docs)] // the variant is the gain
pub enum Gain {
    X1 = 0,
    X2 = 1,
    X4 = 2,
    X8 = 3,
    X16 = 4,
    X32 = 5,
    X64 = 6,
    X128 = 7,
}

/// Output data rate: (DR bits, MODE bits).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataRate {
    /// Normal mode, 1000 SPS (the board averages pairs for 500 Hz).
    Sps1000,
    /// Turbo mode, 2000 SPS (twice the modulator clock, more noise).
    Turbo2000,
    /// Normal mode, 20 SPS with 50/60 Hz rejection available (bench work).
    Sps20,
}

impl DataRate {
    fn bits(self) -> (u8, u8) {
        match self {
            DataRate::Sps1000 => (0b110, 0b00),
            DataRate::Turbo2000 => (0b110, 0b10),
            DataRate::Sps20 => (0b000, 0b00),
        }
    }

    /// Conversions per second.
    pub fn sps(self) -> u32 {
        match self {
            DataRate::Sps1000 => 1000,
            DataRate::Turbo2000 => 2000,
            DataRate::Sps20 => 20,
        }
    }
}

/// Voltage reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reference {
    /// Internal 2.048 V.
    Internal = 0b00,
    /// REFP0/REFN0: the bridge's own excitation, so the reading is
    /// ratiometric and excitation drift cancels.
    External0 = 0b01,
    /// AVDD − AVSS.
    Supply = 0b11,
}

/// Input pair (MUX).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Inputs {
    /// AIN1 positive, AIN2 negative (the datasheet's bridge example).
    Ain1Ain2 = 0b0011,
    /// AIN0 positive, AIN1 negative.
    Ain0Ain1 = 0b0000,
}

/// What the converter is set up to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Config {
    /// Input pair.
    pub inputs: Inputs,
    /// PGA gain.
    pub gain: Gain,
    /// Conversions per second and mode.
    pub rate: DataRate,
    /// Voltage reference.
    pub reference: Reference,
}

impl Config {
    /// The codes the PGA measures linearly, lowest and highest; a code at
    /// or beyond either is saturated. Its outputs must stay
    /// 200 mV inside the supply (SBAS501 §8.3.2.1): with the bridge's
    /// common mode at mid-supply, |V_IN| ≤ (AVDD − 0.4 V)/(G − 1), at a
    /// 3.3 V supply and gain 128 22.8 mV, where full scale on a reference
    /// at the supply (the ratiometric bridge) is 3.3 V/128 = 25.8 mV.
    /// Beyond it the reading is wrong without reaching full scale, so it
    /// counts as saturated: 7/8 of full scale (22.6 mV), a margin for the
    /// supply's tolerance, at gains of 16 and up on a reference near the
    /// supply; full scale otherwise (the PGA's range covers it).
    pub const fn linear_range(&self) -> (i32, i32) {
        let high_gain = self.gain as u8 >= Gain::X16 as u8;
        match self.reference {
            Reference::External0 | Reference::Supply if high_gain => {
                (-LINEAR_LIMIT_HIGH_GAIN, LINEAR_LIMIT_HIGH_GAIN)
            }
            _ => (FULL_SCALE_NEGATIVE, FULL_SCALE_POSITIVE),
        }
    }

    /// A load cell's bridge: AIN1/AIN2 at gain 128, ratiometric on
    /// REFP0/REFN0, continuous conversion at `rate`.
    pub const fn bridge(rate: DataRate) -> Self {
        Config {
            inputs: Inputs::Ain1Ain2,
            gain: Gain::X128,
            rate,
            reference: Reference::External0,
        }
    }

    /// The four configuration registers.
    pub fn registers(&self) -> [u8; 4] {
        let (dr, mode) = self.rate.bits();
        [
            ((self.inputs as u8) << 4) | ((self.gain as u8) << 1),
            (dr << 5) | (mode << 3) | (1 << 2),
            (self.reference as u8) << 6,
            0,
        ]
    }
}

/// The configuration registers as read back, and as written.
pub type ReadBack = ([u8; 4], [u8; 4]);

/// What can go wrong talking to the converter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error<E> {
    /// The SPI bus failed.
    Spi(E),
    /// The data-ready pin could not be read.
    Pin,
    /// Asked for a conversion while data-ready was high: none waits (the
    /// interrupt was spurious or the converter stopped).
    NotReady,
    /// The registers read back differ from those written: the converter
    /// is absent, unpowered or miswired (MISO stuck reads all ones or zeros).
    Readback {
        /// Written.
        wrote: [u8; 4],
        /// Read back.
        read: [u8; 4],
    },
    /// The same code [`STUCK_RUN`] conversions running: the data line is
    /// stuck (a converter gone, a floating MISO).
    Stuck {
        /// The code.
        code: i32,
    },
}

/// The converter on its SPI device, with its data-ready pin.
pub struct Ads1220<SPI, DRDY> {
    spi: SPI,
    drdy: DRDY,
    /// The registers written at the start, read back every
    /// [`CHECK_EVERY`] conversions (none before a start).
    written: Option<[u8; 4]>,
    /// Conversions since the last read-back.
    since_check: u16,
    /// Codes at or beyond these are saturated.
    linear_range: (i32, i32),
    /// The last code and how many conversions running gave it.
    last_code: i32,
    same_run: u16,
}

impl<SPI: SpiDevice, DRDY: InputPin> Ads1220<SPI, DRDY> {
    /// The converter on `spi` (mode 1), data-ready on `drdy`; nothing is
    /// sent until [`Self::start`].
    pub fn new(spi: SPI, drdy: DRDY) -> Self {
        Self {
            spi,
            drdy,
            written: None,
            since_check: 0,
            linear_range: (FULL_SCALE_NEGATIVE, FULL_SCALE_POSITIVE),
            last_code: i32::MIN,
            same_run: 0,
        }
    }

    /// Reset, write `config`, check it reads back, and start continuous
    /// conversions (data-ready falls at the configured rate from here on).
    pub fn start(
        &mut self,
        config: &Config,
        delay: &mut impl DelayNs,
    ) -> Result<(), Error<SPI::Error>> {
        self.spi.write(&[command::RESET]).map_err(Error::Spi)?;
        delay.delay_us(RESET_WAIT_US);
        let wrote = config.registers();
        let [a, b, c, d] = wrote;
        self.spi
            .write(&[command::WREG | 0b11, a, b, c, d])
            .map_err(Error::Spi)?;
        self.check_registers(wrote)?;
        self.spi.write(&[command::START_SYNC]).map_err(Error::Spi)?;
        self.written = Some(wrote);
        self.linear_range = config.linear_range();
        Ok(())
    }

    /// The configuration registers as read back now, and as written at
    /// the start (`None` before a start): for a self-test.
    pub fn registers(&mut self) -> Result<Option<ReadBack>, Error<SPI::Error>> {
        let Some(wrote) = self.written else {
            return Ok(None);
        };
        Ok(Some((self.read_registers()?, wrote)))
    }

    /// The configuration registers written at the start (`None` before).
    pub fn written(&self) -> Option<[u8; 4]> {
        self.written
    }

    /// The four configuration registers, by RREG.
    fn read_registers(&mut self) -> Result<[u8; 4], Error<SPI::Error>> {
        let mut read = [0; 4];
        self.spi
            .transaction(&mut [
                Operation::Write(&[command::RREG | 0b11]),
                Operation::Read(&mut read),
            ])
            .map_err(Error::Spi)?;
        Ok(read)
    }

    /// Read the configuration registers back and compare them with
    /// `wrote`.
    fn check_registers(&mut self, wrote: [u8; 4]) -> Result<(), Error<SPI::Error>> {
        let read = self.read_registers()?;
        if read != wrote {
            return Err(Error::Readback { wrote, read });
        }
        Ok(())
    }

    /// After each conversion read: a code stuck for [`STUCK_RUN`]
    /// conversions, or registers that no longer read back, is an error.
    fn check_health(&mut self, code: i32) -> Result<(), Error<SPI::Error>> {
        let full_scale = code >= FULL_SCALE_POSITIVE || code <= FULL_SCALE_NEGATIVE;
        if code == self.last_code && !full_scale {
            self.same_run = self.same_run.saturating_add(1);
        } else {
            (self.last_code, self.same_run) = (code, 1);
        }
        if self.same_run >= STUCK_RUN {
            return Err(Error::Stuck { code });
        }
        if let Some(wrote) = self.written {
            self.since_check = self.since_check.saturating_add(1);
            if self.since_check >= CHECK_EVERY {
                self.since_check = 0;
                self.check_registers(wrote)?;
            }
        }
        Ok(())
    }

    /// Data-ready is low: a conversion waits to be read.
    pub fn ready(&mut self) -> Result<bool, Error<SPI::Error>> {
        self.drdy.is_low().map_err(|_| Error::Pin)
    }

    /// The conversion waiting, by RDATA (a command, not bare clocks: bytes
    /// on DIN during a bare read could be taken for one).
    pub fn read_counts(&mut self) -> Result<i32, Error<SPI::Error>> {
        if !self.ready()? {
            return Err(Error::NotReady);
        }
        let mut data = [0; 3];
        self.spi
            .transaction(&mut [
                Operation::Write(&[command::RDATA]),
                Operation::Read(&mut data),
            ])
            .map_err(Error::Spi)?;
        Ok(sign_extend_24(data))
    }

    /// The data-ready pin, for the board to clear its interrupt.
    pub fn data_ready_pin(&mut self) -> &mut DRDY {
        &mut self.drdy
    }

    /// Give back the bus and the pin.
    pub fn release(self) -> (SPI, DRDY) {
        (self.spi, self.drdy)
    }
}

/// A 24-bit two's-complement code, MSB first, as an i32.
pub fn sign_extend_24([hi, mid, lo]: [u8; 3]) -> i32 {
    i32::from_be_bytes([hi, mid, lo, 0]) >> 8
}

/// One conversion, read and checked ([`Ads1220::read_checked`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reading {
    /// The code, sign-extended.
    pub counts: i32,
    /// Beyond the PGA's linear range ([`Config::linear_range`]): the force
    /// it stands for is unknown.
    pub saturated: bool,
}

impl<SPI: SpiDevice, DRDY: InputPin> Ads1220<SPI, DRDY> {
    /// The latest conversion, checked: a stuck code or registers that no
    /// longer read back are errors, a code past the linear range is
    /// saturated. The chip has no overrun flag: a board that keeps time
    /// finds one when data-ready falls while a reading is in hand.
    pub fn read_checked(&mut self) -> Result<Reading, Error<SPI::Error>> {
        let counts = self.read_counts()?;
        self.check_health(counts)?;
        Ok(Reading {
            counts,
            saturated: counts <= self.linear_range.0 || counts >= self.linear_range.1,
        })
    }
}
