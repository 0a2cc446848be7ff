//! The halt line: PA8, push-pull, active high (asserted: the robot must
//! stop). Firmware drives it high from its first instructions until the
//! device is armed; during a reset and until then the pin floats, and the
//! pull-up the wiring requires holds it high — so a reset by the
//! independent watchdog ([`super::iwdg`]), which a hung chip gets, is a
//! stop too. A panic or HardFault drives it high and leaves it there (and
//! the watchdog, no longer fed, resets the chip into a `watchdog_reset`
//! fault).

use core::convert::Infallible;

use stm32f4::stm32f411 as pac;

/// The halt line, as the core's [`embedded_hal::digital::OutputPin`].
pub struct HaltLine(());

impl HaltLine {
    /// PA8 made a push-pull output, driven high (asserted) before it is
    /// one, so the robot never sees it low at boot.
    pub fn asserted(gpioa: &pac::GPIOA) -> Self {
        assert_halt_raw();
        gpioa.moder().modify(|_, w| w.moder8().output());
        Self(())
    }
}

impl embedded_hal::digital::ErrorType for HaltLine {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for HaltLine {
    fn set_high(&mut self) -> Result<(), Infallible> {
        assert_halt_raw();
        Ok(())
    }

    fn set_low(&mut self) -> Result<(), Infallible> {
        // SAFETY: as in `assert_halt_raw`, resetting BR8 only.
        unsafe { (*pac::GPIOA::ptr()).bsrr().write(|w| w.br8().set_bit()) };
        Ok(())
    }
}

/// Assert the halt line from anywhere, whatever state the program is in.
fn assert_halt_raw() {
    // SAFETY: GPIOA's bit set/reset register is write-only and atomic:
    // setting BS8 drives PA8 high without touching any other pin. Nothing
    // else runs after a panic or HardFault.
    unsafe { (*pac::GPIOA::ptr()).bsrr().write(|w| w.bs8().set_bit()) };
}

/// Stay here with the halt asserted (on the board), or leave QEMU with
/// `code` (the replay image, so a test sees it).
fn stop(_code: i32) -> ! {
    #[cfg(feature = "f411-replay")]
    crate::hardware::exit(_code);
    #[cfg(not(feature = "f411-replay"))]
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    // Nothing else runs from here on: a task of higher priority than the
    // one that panicked would otherwise go on, and arming releases the
    // line.
    cortex_m::interrupt::disable();
    assert_halt_raw();
    defmt::error!("panic: halt asserted");
    stop(101) // exit_code::PANIC
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &cortex_m_rt::ExceptionFrame) -> ! {
    assert_halt_raw();
    defmt::error!("HardFault at pc {=u32:#010x}: halt asserted", frame.pc());
    stop(3)
}
