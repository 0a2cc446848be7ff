//! The ADS1220 driver against mocked SPI transactions: each byte it puts
//! on the bus, the sign of what it reads, saturation, a missed data-ready,
//! a converter that is not there, and a bus that fails.

use ads1220::{command, Ads1220, Config, DataRate, Error};
use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};
use embedded_hal_mock::eh1::delay::NoopDelay;
use embedded_hal_mock::eh1::digital::{Mock as Pin, State, Transaction as PinT};
use embedded_hal_mock::eh1::spi::{Mock as Spi, Transaction as SpiT};

/// The configuration bytes of the board's two rates, from the datasheet's
/// register map worked by hand: AIN1/AIN2 (MUX 0011), gain 128 (111),
/// PGA on; DR 110 normal (1000 SPS) or turbo (2000 SPS), continuous; VREF
/// REFP0/REFN0 (01); IDACs off.
const AT_1000_SPS: [u8; 4] = [0b0011_1110, 0b1100_0100, 0b0100_0000, 0x00];
const AT_2000_SPS: [u8; 4] = [0b0011_1110, 0b1101_0100, 0b0100_0000, 0x00];

fn start_expectations(registers: [u8; 4], read_back: [u8; 4]) -> Vec<SpiT<u8>> {
    let mut wreg = vec![command::WREG | 0b11];
    wreg.extend(registers);
    vec![
        SpiT::transaction_start(),
        SpiT::write_vec(vec![command::RESET]),
        SpiT::transaction_end(),
        SpiT::transaction_start(),
        SpiT::write_vec(wreg),
        SpiT::transaction_end(),
        SpiT::transaction_start(),
        SpiT::write_vec(vec![command::RREG | 0b11]),
        SpiT::read_vec(read_back.to_vec()),
        SpiT::transaction_end(),
        SpiT::transaction_start(),
        SpiT::write_vec(vec![command::START_SYNC]),
        SpiT::transaction_end(),
    ]
}

fn rdata(code: [u8; 3]) -> Vec<SpiT<u8>> {
    vec![
        SpiT::transaction_start(),
        SpiT::write_vec(vec![command::RDATA]),
        SpiT::read_vec(code.to_vec()),
        SpiT::transaction_end(),
    ]
}

#[test]
fn the_registers_are_the_datasheets_bits() {
    assert_eq!(Config::bridge(DataRate::Sps1000).registers(), AT_1000_SPS);
    assert_eq!(Config::bridge(DataRate::Turbo2000).registers(), AT_2000_SPS);
}

#[test]
fn start_resets_writes_checks_and_starts() {
    for (rate, regs) in [
        (DataRate::Sps1000, AT_1000_SPS),
        (DataRate::Turbo2000, AT_2000_SPS),
    ] {
        let mut spi = Spi::new(&start_expectations(regs, regs));
        let mut drdy = Pin::new(&[]);
        let mut adc = Ads1220::new(spi.clone(), drdy.clone());
        adc.start(&Config::bridge(rate), &mut NoopDelay::new())
            .unwrap();
        spi.done();
        drdy.done();
    }
}

#[test]
fn a_converter_that_does_not_answer_is_an_error_not_a_start() {
    // MISO stuck high: every register reads 0xFF; no START is sent.
    let mut expected = start_expectations(AT_1000_SPS, [0xFF; 4]);
    expected.truncate(expected.len() - 3);
    let mut spi = Spi::new(&expected);
    let mut drdy = Pin::new(&[]);
    let mut adc = Ads1220::new(spi.clone(), drdy.clone());
    let err = adc
        .start(&Config::bridge(DataRate::Sps1000), &mut NoopDelay::new())
        .unwrap_err();
    assert_eq!(
        err,
        Error::Readback {
            wrote: AT_1000_SPS,
            read: [0xFF; 4]
        }
    );
    spi.done();
    drdy.done();
}

#[test]
fn codes_are_sign_extended_and_full_scale_saturates() {
    let cases: [([u8; 3], i32, bool); 7] = [
        ([0x00, 0x00, 0x00], 0, false),
        ([0x00, 0x00, 0x01], 1, false),
        ([0x12, 0x34, 0x56], 0x12_3456, false),
        ([0x7F, 0xFF, 0xFE], 0x7F_FFFE, false),
        ([0xFF, 0xFF, 0xFF], -1, false),
        ([0x7F, 0xFF, 0xFF], 0x7F_FFFF, true),
        ([0x80, 0x00, 0x00], -0x80_0000, true),
    ];
    let spi_expected: Vec<SpiT<u8>> = cases.iter().flat_map(|c| rdata(c.0)).collect();
    let pin_expected: Vec<PinT> = cases.iter().map(|_| PinT::get(State::Low)).collect();
    let mut spi = Spi::new(&spi_expected);
    let mut drdy = Pin::new(&pin_expected);
    let mut adc = Ads1220::new(spi.clone(), drdy.clone());
    for (bytes, counts, saturated) in cases {
        let sample = adc.read_checked().unwrap();
        assert_eq!(sample.counts, counts, "{bytes:02x?}");
        assert_eq!(sample.saturated, saturated, "{bytes:02x?}");
    }
    spi.done();
    drdy.done();
}

#[test]
fn a_missed_data_ready_reads_nothing_and_says_so() {
    // Data-ready high: no conversion waits, and the bus is not touched.
    let mut spi = Spi::new(&[]);
    let mut drdy = Pin::new(&[PinT::get(State::High)]);
    let mut adc = Ads1220::new(spi.clone(), drdy.clone());
    assert_eq!(adc.read_checked(), Err(Error::NotReady));
    spi.done();
    drdy.done();
}

/// A bus whose every transfer fails.
struct BrokenBus;

impl ErrorType for BrokenBus {
    type Error = ErrorKind;
}

impl SpiDevice for BrokenBus {
    fn transaction(&mut self, _: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        Err(ErrorKind::ModeFault)
    }
}

#[test]
fn bus_errors_are_errors() {
    let mut drdy = Pin::new(&[PinT::get(State::Low)]);
    let mut adc = Ads1220::new(BrokenBus, drdy.clone());
    assert_eq!(adc.read_checked(), Err(Error::Spi(ErrorKind::ModeFault)));
    assert_eq!(
        adc.start(&Config::bridge(DataRate::Sps1000), &mut NoopDelay::new()),
        Err(Error::Spi(ErrorKind::ModeFault))
    );
    drdy.done();
}

fn rreg(registers: [u8; 4]) -> Vec<SpiT<u8>> {
    vec![
        SpiT::transaction_start(),
        SpiT::write_vec(vec![command::RREG | 0b11]),
        SpiT::read_vec(registers.to_vec()),
        SpiT::transaction_end(),
    ]
}

/// A started converter and the expectations of its start.
fn started(after_start: Vec<SpiT<u8>>, reads: usize) -> (Spi<u8>, Pin, Ads1220<Spi<u8>, Pin>) {
    let mut spi_expected = start_expectations(AT_1000_SPS, AT_1000_SPS);
    spi_expected.extend(after_start);
    let spi = Spi::new(&spi_expected);
    let drdy = Pin::new(&vec![PinT::get(State::Low); reads]);
    let mut adc = Ads1220::new(spi.clone(), drdy.clone());
    adc.start(&Config::bridge(DataRate::Sps1000), &mut NoopDelay::new())
        .unwrap();
    (spi, drdy, adc)
}

/// Distinct codes, as a bridge's noise gives.
fn noisy(i: usize) -> [u8; 3] {
    [0x01, (i >> 8) as u8, i as u8]
}

#[test]
fn a_started_converter_reads_its_registers_back_every_so_often() {
    let n = usize::from(ads1220::CHECK_EVERY);
    let mut expected = Vec::new();
    for i in 0..2 * n {
        expected.extend(rdata(noisy(i)));
        if (i + 1) % n == 0 {
            // The first read-back matches; the second finds the
            // registers at their reset values (the converter lost power).
            expected.extend(rreg(if i < n { AT_1000_SPS } else { [0; 4] }));
        }
    }
    let (mut spi, mut drdy, mut adc) = started(expected, 2 * n);
    for _ in 0..2 * n - 1 {
        assert!(adc.read_checked().is_ok());
    }
    assert_eq!(
        adc.read_checked(),
        Err(Error::Readback {
            wrote: AT_1000_SPS,
            read: [0; 4]
        })
    );
    spi.done();
    drdy.done();
}

#[test]
fn a_stuck_data_line_is_an_error_but_a_held_overload_is_saturation() {
    let stuck = usize::from(ads1220::STUCK_RUN);
    for (code, counts) in [([0xFF, 0xFF, 0xFF], -1), ([0x00, 0x00, 0x00], 0)] {
        let mut spi = Spi::new(&(0..stuck).flat_map(|_| rdata(code)).collect::<Vec<_>>());
        let mut drdy = Pin::new(&vec![PinT::get(State::Low); stuck]);
        let mut adc = Ads1220::new(spi.clone(), drdy.clone());
        for _ in 1..stuck {
            assert_eq!(adc.read_checked().unwrap().counts, counts);
        }
        assert_eq!(adc.read_checked(), Err(Error::Stuck { code: counts }));
        spi.done();
        drdy.done();
    }
    let held = 2 * stuck;
    let mut spi = Spi::new(
        &(0..held)
            .flat_map(|_| rdata([0x7F, 0xFF, 0xFF]))
            .collect::<Vec<_>>(),
    );
    let mut drdy = Pin::new(&vec![PinT::get(State::Low); held]);
    let mut adc = Ads1220::new(spi.clone(), drdy.clone());
    for _ in 0..held {
        assert!(adc.read_checked().unwrap().saturated);
    }
    spi.done();
    drdy.done();
}

#[test]
fn at_gain_128_on_the_supply_codes_past_the_pgas_linear_range_are_saturated() {
    // 7/8 of full scale: the PGA's outputs 200 mV inside a 3.3 V supply.
    let limit = ads1220::LINEAR_LIMIT_HIGH_GAIN;
    assert_eq!(limit, 7_340_032);
    assert_eq!(
        Config::bridge(DataRate::Sps1000).linear_range(),
        (-limit, limit)
    );
    let codes: [(i32, bool); 4] = [
        (limit - 1, false),
        (limit, true),
        (-limit + 1, false),
        (-limit, true),
    ];
    let bytes = |c: i32| {
        let b = c.to_be_bytes();
        [b[1], b[2], b[3]]
    };
    let expected = codes.iter().flat_map(|&(c, _)| rdata(bytes(c))).collect();
    let (mut spi, mut drdy, mut adc) = started(expected, codes.len());
    for (code, saturated) in codes {
        let sample = adc.read_checked().unwrap();
        assert_eq!((sample.counts, sample.saturated), (code, saturated));
    }
    spi.done();
    drdy.done();
}

#[test]
fn a_self_test_reads_the_registers_back_beside_those_written() {
    let (mut spi, mut drdy, mut adc) = started(rreg([0x3e, 0xc4, 0x00, 0x00]), 0);
    assert_eq!(
        adc.registers(),
        Ok(Some(([0x3e, 0xc4, 0x00, 0x00], AT_1000_SPS)))
    );
    spi.done();
    drdy.done();
    let mut idle = Ads1220::new(Spi::new(&[]), Pin::new(&[]));
    assert_eq!(idle.registers(), Ok(None), "not started: nothing written");
    let (mut spi, mut drdy) = idle.release();
    spi.done();
    drdy.done();
}
