//! USART2 (the ST-LINK's virtual COM port), 8N1, on the registers: frames
//! out a byte per transmit-empty, commands in a byte per receive-not-empty.

use stm32f4::stm32f411 as pac;

pub struct Usart2(pac::USART2);

/// BRR for `baud` from `pclk_hz` at 16× oversampling: the clock over the
/// baud rate as a 12.4 fixed-point divider (RM0383 §19.3.4), rounded,
/// within the register's 16..=0xFFFF.
fn divider(pclk_hz: u32, baud: u32) -> u16 {
    let brr = pclk_hz
        .saturating_add(baud / 2)
        .checked_div(baud)
        .unwrap_or(0);
    brr.clamp(16, 0xFFFF) as u16
}

impl Usart2 {
    /// Enabled at `baud` from APB1's `pclk1_hz`, receiving; with the
    /// receive interrupt if `rx_interrupt`.
    pub fn new(usart: pac::USART2, pclk1_hz: u32, baud: u32, rx_interrupt: bool) -> Self {
        let brr = divider(pclk1_hz, baud);
        let actual = pclk1_hz.checked_div(u32::from(brr)).unwrap_or(0);
        // Both ends' errors add up; past about 2 % bytes are lost.
        if actual.abs_diff(baud) > baud / 100 {
            defmt::warn!(
                "USART2 at {=u32} Bd for {=u32} from a {=u32} Hz clock: the link may lose bytes",
                actual,
                baud,
                pclk1_hz
            );
        }
        // SAFETY: any 16-bit value is a divider; 921 600 Bd from 50 MHz
        // is 54 (0.5 % fast), from the unmultiplied 16 MHz HSI 17 (2.1 %
        // fast, warned above).
        usart.brr().write(|w| unsafe { w.bits(brr) });
        usart.cr1().write(|w| {
            w.ue().set_bit();
            w.te().set_bit();
            w.re().set_bit();
            w.rxneie().bit(rx_interrupt)
        });
        Self(usart)
    }

    /// The next byte received, if any. A byte with a framing or parity
    /// error is dropped (the frame it belongs to then fails its CRC, and
    /// the device says so); an overrun lost bytes the same way. Noise
    /// alone is a warning (the majority vote usually got the bit right),
    /// and the CRC judges.
    pub fn read(&mut self) -> Option<u8> {
        loop {
            let sr = self.0.sr().read();
            if sr.rxne().bit_is_clear() {
                if sr.ore().bit_is_set() {
                    // Reading DR after SR clears the overrun flag.
                    let _ = self.0.dr().read();
                }
                return None;
            }
            let byte = self.0.dr().read().dr().bits() as u8;
            if sr.fe().bit_is_clear() && sr.pe().bit_is_clear() {
                return Some(byte);
            }
        }
    }

    /// Send `byte` if the transmitter takes one now.
    pub fn write(&mut self, byte: u8) -> bool {
        if self.0.sr().read().txe().bit_is_clear() {
            return false;
        }
        // SAFETY: any byte is data.
        self.0
            .dr()
            .write(|w| unsafe { w.dr().bits(u16::from(byte)) });
        true
    }

    /// Whether the last byte has left the shift register (the replay
    /// image waits for it before leaving QEMU).
    #[cfg_attr(not(feature = "f411-replay"), allow(dead_code))]
    pub fn sent(&self) -> bool {
        self.0.sr().read().tc().bit_is_set()
    }

    /// Interrupt on transmit-empty, or not.
    pub fn listen_tx(&mut self, on: bool) {
        self.0.cr1().modify(|_, w| w.txeie().bit(on));
    }
}
