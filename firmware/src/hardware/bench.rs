//! Markers for the instruction-count benchmark (`needle bench`).
//!
//! QEMU can log the address of every instruction it executes
//! (`-singlestep -d exec,nochain`); the host counts the instructions
//! between a call of [`needle_bench_begin`] and the next call of
//! [`needle_bench_end`]. The two are `#[no_mangle]` so the host finds them
//! in the ELF, and have different bodies so the linker cannot merge them.
//! One begin/end pair with nothing between runs at boot, so the host can
//! subtract the markers' own cost. On hardware they cost a few cycles.

use needle_holder::replay::TickProbe;

/// Start of a measured region.
#[no_mangle]
#[inline(never)]
pub extern "C" fn needle_bench_begin() {
    cortex_m::asm::nop();
}

/// End of a measured region.
#[no_mangle]
#[inline(never)]
pub extern "C" fn needle_bench_end() {
    cortex_m::asm::nop();
    cortex_m::asm::nop();
}

/// Marks each sample's processing.
pub struct BenchMarkers(());

impl BenchMarkers {
    /// Run the empty calibration region, then return the probe.
    pub fn calibrated() -> Self {
        needle_bench_begin();
        needle_bench_end();
        Self(())
    }
}

impl TickProbe for BenchMarkers {
    #[inline(always)]
    fn before_tick(&mut self) {
        needle_bench_begin();
    }
    #[inline(always)]
    fn after_tick(&mut self) {
        needle_bench_end();
    }
}
