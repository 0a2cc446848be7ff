//! The halt line: PA8, push-pull, active high (asserted: the robot must
//! stop). It is driven high from reset until the device is armed, and a
//! panic or HardFault drives it high and leaves it there.

use stm32f4xx_hal::gpio::{Output, PushPull, PA8};
use stm32f4xx_hal::pac;

/// The halt line, as the core's [`embedded_hal::digital::OutputPin`].
pub type HaltLine = PA8<Output<PushPull>>;

/// Assert the halt line from anywhere, whatever state the program is in.
fn assert_halt_raw() {
    // SAFETY: GPIOA's bit set/reset register is write-only and atomic:
    // setting BS8 drives PA8 high without touching any other pin, and the
    // pin was made a push-pull output at boot. Nothing else runs after a
    // panic or HardFault.
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
