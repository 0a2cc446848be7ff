//! USART2 (the ST-LINK's virtual COM port), 8N1, on the registers: frames
//! out a byte per transmit-empty; commands in by DMA ([`RxDma`]), so no
//! byte waits on the CPU.
//!
//! At 921 600 Bd a character takes 10.85 µs and USART2 holds one: read
//! byte by byte from the lowest-priority task, a character was lost
//! whenever a sample (up to 200 µs with frames to build), a flash stall
//! or a critical section outlasted it, and a 143-byte tissue upload at
//! 2 kHz got through about one time in seven. DMA1 stream 5 (channel 4,
//! RM0383 table 27) moves each byte into a circular buffer as it lands;
//! the idle-line interrupt (a character's time of silence after a burst)
//! wakes the link task, which reads what arrived.

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
    /// Enabled at `baud` from APB1's `pclk1_hz`, sending and receiving
    /// (into nothing until [`RxDma::start`]).
    pub fn new(usart: pac::USART2, pclk1_hz: u32, baud: u32) -> Self {
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
            w.re().set_bit()
        });
        Self(usart)
    }

    /// Receive by DMA from here on, with the idle-line and error
    /// interrupts (in DMA mode, errors interrupt only through EIE, RM0383
    /// §19.6.6). What the receiver flagged before (bytes a host sent
    /// during the boot, an overrun) is cleared first.
    #[cfg(not(feature = "f411-replay"))]
    fn receive_by_dma(&mut self) {
        let _ = self.0.sr().read();
        let _ = self.0.dr().read();
        self.0
            .cr3()
            .modify(|_, w| w.dmar().set_bit().eie().set_bit());
        self.0.cr1().modify(|_, w| w.idleie().set_bit());
    }

    /// The address DMA reads received bytes from.
    #[cfg(not(feature = "f411-replay"))]
    fn data_register(&self) -> u32 {
        self.0.dr().as_ptr() as u32
    }

    /// Acknowledge the idle line and count the receive errors flagged
    /// since the last call (noise and framing: the flagged byte goes to
    /// the buffer all the same; overrun: a byte is lost; either way the
    /// frame it is in fails its CRC, which the device answers). Several
    /// errors between two calls count once; so does one whose flags a
    /// transmit's SR read and the DMA's DR read cleared in between.
    #[cfg(not(feature = "f411-replay"))]
    pub fn take_line_events(&mut self) -> u32 {
        let sr = self.0.sr().read();
        let error = sr.ore().bit_is_set() || sr.nf().bit_is_set() || sr.fe().bit_is_set();
        // SR then DR clears IDLE and the error flags (RM0383 §19.6.1).
        // With a byte waiting (RXNE) the DMA's own read of DR finishes
        // the sequence: a read here would take that byte from it.
        if (error || sr.idle().bit_is_set()) && sr.rxne().bit_is_clear() {
            let _ = self.0.dr().read();
        }
        u32::from(error)
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

/// Bytes of the receive buffer: several of the longest command (a tissue
/// upload, under 200 bytes), 5.6 ms of a continuous stream at 921 600 Bd.
#[cfg(not(feature = "f411-replay"))]
pub const RX_BYTES: usize = 512;

/// USART2's receiver, through DMA1 stream 5 into a circular buffer.
#[cfg(not(feature = "f411-replay"))]
pub struct RxDma {
    dma: pac::DMA1,
    buffer: *const u8,
    ring: needle_holder::link::RxRing,
}

// SAFETY: the buffer is 'static and only this struct reads it; moving it
// to the task that owns it is moving that sole reader.
#[cfg(not(feature = "f411-replay"))]
unsafe impl Send for RxDma {}

#[cfg(not(feature = "f411-replay"))]
impl RxDma {
    /// The stream, set up (RM0383 §9.3.18) and started into `buffer`,
    /// and `usart` switched to receiving by DMA.
    pub fn start(dma: pac::DMA1, usart: &mut Usart2, buffer: &'static mut [u8; RX_BYTES]) -> Self {
        let stream = dma.st(5);
        stream.cr().modify(|_, w| w.en().clear_bit());
        // The stream is off before it is set up (a reset leaves it off;
        // a debugger's restart may not): at most a few cycles.
        let _ = (0..10_000).any(|_| stream.cr().read().en().bit_is_clear());
        // Its event flags cleared before it is enabled (RM0383 §9.5.5).
        dma.hifcr().write(|w| {
            w.ctcif5().set_bit();
            w.chtif5().set_bit();
            w.cteif5().set_bit();
            w.cdmeif5().set_bit();
            w.cfeif5().set_bit()
        });
        // SAFETY: the addresses of USART2's data register and of a
        // 'static buffer the DMA owns from here on (the CPU reads it only
        // through `buffer`, volatile); the count is the buffer's length.
        stream
            .par()
            .write(|w| unsafe { w.pa().bits(usart.data_register()) });
        stream
            .m0ar()
            .write(|w| unsafe { w.m0a().bits(buffer.as_mut_ptr() as u32) });
        stream.ndtr().write(|w| w.ndt().set(RX_BYTES as u16));
        stream.fcr().write(|w| w.dmdis().clear_bit());
        stream.cr().write(|w| {
            w.chsel().set(4);
            w.dir().peripheral_to_memory();
            w.circ().enabled();
            w.minc().set_bit();
            w.psize().bits8();
            w.msize().bits8();
            w.pl().high();
            w.en().set_bit()
        });
        usart.receive_by_dma();
        Self {
            dma,
            buffer: buffer.as_ptr(),
            ring: needle_holder::link::RxRing::new(RX_BYTES),
        }
    }

    /// Each byte that arrived since the last call, in order.
    pub fn read(&mut self, mut each: impl FnMut(u8)) {
        let remaining = usize::from(self.dma.st(5).ndtr().read().ndt().bits());
        for at in self.ring.arrived(remaining) {
            // SAFETY: `at` < RX_BYTES (the ring's indices are modulo its
            // length); the DMA writes bytes the ring has not yet given.
            each(unsafe { self.buffer.add(at).read_volatile() });
        }
    }
}
