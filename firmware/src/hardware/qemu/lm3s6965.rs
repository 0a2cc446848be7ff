//! TI Stellaris LM3S6965 (QEMU `lm3s6965evb`): UART0 for frames, PF0 (the
//! status LED on the evaluation board) as the halt line.
//!
//! Register addresses from the LM3S6965 datasheet (DS-LM3S6965); QEMU needs
//! no UART set-up, a real board needs its clock and baud rate set first.

use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};

use heapless::spsc::Consumer;

/// Board name for logs.
pub const BOARD: &str = "lm3s6965evb";

const UART0_DR: *mut u32 = 0x4000_C000 as *mut u32;
const UART0_FR: *const u32 = 0x4000_C018 as *const u32;
const FR_TXFF: u32 = 1 << 5;
const FR_RXFE: u32 = 1 << 4;
const FR_BUSY: u32 = 1 << 3;

const SYSCTL_RCGC2: *mut u32 = 0x400F_E108 as *mut u32;
const RCGC2_GPIOF: u32 = 1 << 5;
const GPIOF_BASE: usize = 0x4002_5000;
const GPIO_DIR: usize = 0x400;
const GPIO_DEN: usize = 0x51C;
/// Data register address with only bit 0 unmasked (address bits 9:2 mask the write).
const GPIOF_DATA_PF0: *mut u32 = (GPIOF_BASE + (1 << 2)) as *mut u32;

/// UART0: frames out, commands in.
pub struct Uart0(());

/// The halt line on PF0, active high.
pub struct HaltPin(());

/// Take the UART and halt pin (call once).
pub fn take_peripherals() -> (Uart0, HaltPin) {
    // SAFETY: single-threaded start-up; these addresses are this chip's
    // clock gate and GPIO port F registers, written once here.
    unsafe {
        write_volatile(SYSCTL_RCGC2, read_volatile(SYSCTL_RCGC2) | RCGC2_GPIOF);
        let dir = (GPIOF_BASE + GPIO_DIR) as *mut u32;
        let den = (GPIOF_BASE + GPIO_DEN) as *mut u32;
        write_volatile(dir, read_volatile(dir) | 1);
        write_volatile(den, read_volatile(den) | 1);
    }
    (Uart0(()), HaltPin(()))
}

impl Uart0 {
    /// Put `byte` in the transmit FIFO if it has room.
    fn try_send(&mut self, byte: u8) -> bool {
        // SAFETY: UART0 flag and data registers; reading FR and writing DR
        // have no side effects beyond sending the byte.
        unsafe {
            if read_volatile(UART0_FR) & FR_TXFF != 0 {
                return false;
            }
            write_volatile(UART0_DR, byte as u32);
        }
        true
    }

    /// The next byte in the receive FIFO, if any.
    fn try_receive(&mut self) -> Option<u8> {
        // SAFETY: UART0 flag and data registers; reading DR takes the byte
        // out of the receive FIFO.
        unsafe { (read_volatile(UART0_FR) & FR_RXFE == 0).then(|| read_volatile(UART0_DR) as u8) }
    }

    /// Move waiting bytes from `queue` into the transmit FIFO until it is
    /// full; `true` when the queue is empty.
    pub fn send_waiting<const N: usize>(&mut self, queue: &mut Consumer<'_, u8, N>) -> bool {
        needle_holder::link::drain(queue, |byte| self.try_send(byte))
    }

    /// Bytes the host sent that wait in the receive FIFO, into `buf`.
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
        // SAFETY: reading the UART0 flag register.
        while unsafe { read_volatile(UART0_FR) } & FR_BUSY != 0 {}
        Ok(())
    }
}

impl embedded_hal::digital::ErrorType for HaltPin {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for HaltPin {
    fn set_high(&mut self) -> Result<(), Infallible> {
        // SAFETY: masked write to PF0 only.
        unsafe { write_volatile(GPIOF_DATA_PF0, 1) };
        defmt::warn!("halt asserted");
        Ok(())
    }

    fn set_low(&mut self) -> Result<(), Infallible> {
        // SAFETY: masked write to PF0 only.
        unsafe { write_volatile(GPIOF_DATA_PF0, 0) };
        Ok(())
    }
}
