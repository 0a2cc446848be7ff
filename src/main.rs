//! Firmware image: boots the board, feeds the replay source to the core's
//! device loop, and exits QEMU with the result.
//!
//! Only meaningful for `target_os = "none"`; on the host this file builds
//! to a stub that says how to build the real thing. All logic lives in the
//! library; everything here is wiring, and all register access lives in
//! `hardware/`.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod hardware;

// The real board's entry point is its RTIC application
// (`hardware/nucleo_f411re/app.rs`); the QEMU boards' is this loop.
#[cfg(all(target_os = "none", not(feature = "board-f411")))]
#[cortex_m_rt::entry]
fn main() -> ! {
    use needle_holder::{config::DeviceConfig, replay};

    defmt::info!(
        "needle-holder {} on {}",
        env!("CARGO_PKG_VERSION"),
        hardware::BOARD
    );
    let source = hardware::ReplayFile::open_from_args();
    let (uart, halt) = hardware::take_peripherals();
    let mut probe = hardware::BenchMarkers::calibrated();
    let summary = replay::run_probed(source, DeviceConfig::default(), uart, halt, &mut probe);
    defmt::info!(
        "replay done: {=u32} samples, {=u32} frames dropped, faults {=u16:#06x}, halt {=bool}",
        summary.samples,
        summary.frames_dropped,
        summary.faults.0,
        summary.halt
    );
    hardware::exit(0)
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "needle-holder is the firmware image: build it with `cargo fw-m3` (or fw-m0, fw-m4) \
         and run it with `cargo run --release -p host-tools --bin needle -- demo`"
    );
    std::process::exit(2);
}
