//! The ADS1220 as the core's load-cell converter: the driver's checked
//! reading becomes an `AdcSample` as it is (its code, its saturation),
//! never an overrun (the board finds those), and its errors stay errors.

use embedded_hal_mock::eh1::digital::{Mock as Pin, State, Transaction as PinT};
use embedded_hal_mock::eh1::spi::{Mock as Spi, Transaction as SpiT};
use needle_holder::ads1220::{command, Ads1220, Error};
use needle_holder::hal::{AdcSample, LoadCellAdc};

fn rdata(code: [u8; 3]) -> Vec<SpiT<u8>> {
    vec![
        SpiT::transaction_start(),
        SpiT::write_vec(vec![command::RDATA]),
        SpiT::read_vec(code.to_vec()),
        SpiT::transaction_end(),
    ]
}

#[test]
fn a_reading_is_a_sample_with_its_saturation_and_no_overrun() {
    let codes = [[0x12, 0x34, 0x56], [0x7F, 0xFF, 0xFF]];
    let mut spi = Spi::new(&codes.iter().flat_map(|&c| rdata(c)).collect::<Vec<_>>());
    let mut drdy = Pin::new(&[
        PinT::get(State::Low),
        PinT::get(State::Low),
        PinT::get(State::High),
    ]);
    let mut adc = Ads1220::new(spi.clone(), drdy.clone());
    let sample = |counts, saturated| AdcSample {
        counts,
        saturated,
        overrun: false,
    };
    assert_eq!(LoadCellAdc::read(&mut adc), Ok(sample(0x12_3456, false)));
    assert_eq!(LoadCellAdc::read(&mut adc), Ok(sample(0x7F_FFFF, true)));
    assert_eq!(LoadCellAdc::read(&mut adc), Err(Error::NotReady));
    spi.done();
    drdy.done();
}
