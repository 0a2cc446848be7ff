//! The stack's high-water mark: the free RAM below the stack is painted
//! with a pattern at start-up, and the deepest word no longer holding it
//! is how far the stack ever reached (interrupts included: RTIC runs every
//! task on the main stack).

/// What unused stack holds.
const PAINT: u32 = 0xDEAD_BEEF;
/// Left unpainted below the stack pointer at the time of painting: the
/// frame of whoever paints, and then some.
const MARGIN_BYTES: usize = 256;

extern "C" {
    /// End of static RAM (`.uninit`), where the stack may grow down to
    /// (cortex-m-rt's linker script).
    static mut __sheap: u32;
    /// Top of RAM, where the stack starts.
    static _stack_start: u32;
}

fn bounds() -> (usize, usize) {
    // Only the addresses of the linker's symbols are taken.
    (
        core::ptr::addr_of!(__sheap) as usize,
        core::ptr::addr_of!(_stack_start) as usize,
    )
}

/// Paint the free RAM below the current stack pointer.
pub fn paint() {
    let (bottom, _) = bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let mut at = bottom;
    while at + 4 <= sp.saturating_sub(MARGIN_BYTES) {
        // SAFETY: [__sheap, sp − margin) is RAM that nothing owns: above
        // every static, below the live stack.
        unsafe { core::ptr::write_volatile(at as *mut u32, PAINT) };
        at += 4;
    }
}

/// Bytes of stack used at most since [`paint`].
pub fn high_water_bytes() -> usize {
    let (bottom, top) = bounds();
    let mut at = bottom;
    // SAFETY: reads of RAM between the end of statics and the top of the
    // stack, all mapped.
    while at < top && unsafe { core::ptr::read_volatile(at as *const u32) } == PAINT {
        at += 4;
    }
    top - at
}
