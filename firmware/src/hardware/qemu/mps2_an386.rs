//! Arm MPS2 with the AN386 (Cortex-M4) image (QEMU `mps2-an386`): CMSDK
//! UART0 for frames, FPGA IO LED0 as the halt line.
//!
//! Addresses from Arm's AN386 application note (CMSDK APB UART, FPGA IO).

use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};

use heapless::spsc::Consumer;

/// Board name for logs.
pub const BOARD: &str = "mps2-an386";

const UART0_BASE: usize = 0x4000_4000;
const UART_DATA: *mut u32 = UART0_BASE as *mut u32;
const UART_STATE: *const u32 = (UART0_BASE + 0x04) as *const u32;
const UART_CTRL: *mut u32 = (UART0_BASE + 0x08) as *mut u32;
const UART_BAUDDIV: *mut u32 = (UART0_BASE + 0x10) as *mut u32;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_ENABLE: u32 = 1 << 0;
const CTRL_RX_ENABLE: u32 = 1 << 1;
/// 25 MHz / 217 ≈ 115200 Bd; the CMSDK UART rejects divisors below 16.
const BAUDDIV_115200: u32 = 217;

const FPGAIO_LED: *mut u32 = 0x4002_8000 as *mut u32;

/// CMSDK UART0 transmitter, blocking.
pub struct Uart0(());

/// The halt line on LED0, active high.
pub struct HaltPin(());

/// Take the UART and halt pin (call once).
pub fn take_peripherals() -> (Uart0, HaltPin) {
    // SAFETY: single-threaded start-up; UART0 configuration registers.
    unsafe {
        write_volatile(UART_BAUDDIV, BAUDDIV_115200);
        write_volatile(UART_CTRL, CTRL_TX_ENABLE | CTRL_RX_ENABLE);
    }
    (Uart0(()), HaltPin(()))
}

impl Uart0 {
    /// Put `byte` in the transmitter if it is free.
    fn try_send(&mut self, byte: u8) -> bool {
        // SAFETY: UART0 state and data registers.
        unsafe {
            if read_volatile(UART_STATE) & STATE_TX_FULL != 0 {
                return false;
            }
            write_volatile(UART_DATA, byte as u32);
        }
        true
    }

    /// The byte in the receive buffer, if any.
    fn try_receive(&mut self) -> Option<u8> {
        // SAFETY: UART0 state and data registers; reading DATA takes the
        // byte.
        unsafe {
            (read_volatile(UART_STATE) & STATE_RX_FULL != 0).then(|| read_volatile(UART_DATA) as u8)
        }
    }

    /// Move waiting bytes from `queue` into the transmitter until it is
    /// busy; `true` when the queue is empty.
    pub fn send_waiting<const N: usize>(&mut self, queue: &mut Consumer<'_, u8, N>) -> bool {
        needle_holder::link::drain(queue, |byte| self.try_send(byte))
    }

    /// Bytes the host sent that wait in the receive buffer, into `buf`.
    pub fn received(&mut self, buf: &mut [u8]) -> usize {
        buf.iter_mut()
            .map_while(|slot| self.try_receive().map(|byte| *slot = byte))
            .count()
    }
}

impl embedded_io::ErrorType for Uart0 {
    type Error = Infallible;
}

impl embedded_io::Write for Uart0 {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        for &byte in buf {
            while !self.try_send(byte) {}
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

impl embedded_hal::digital::ErrorType for HaltPin {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for HaltPin {
    fn set_high(&mut self) -> Result<(), Infallible> {
        // SAFETY: FPGA IO LED register, bit 0 is LED0.
        unsafe { write_volatile(FPGAIO_LED, read_volatile(FPGAIO_LED) | 1) };
        defmt::warn!("halt asserted");
        Ok(())
    }

    fn set_low(&mut self) -> Result<(), Infallible> {
        // SAFETY: as above.
        unsafe { write_volatile(FPGAIO_LED, read_volatile(FPGAIO_LED) & !1) };
        Ok(())
    }
}
