//! The real board's image, ST Nucleo-F411RE (`cargo fw-f411`; feature
//! `board-f411`): its entry point is the RTIC application in
//! `hardware/nucleo_f411re/app.rs`. With `f411-replay`, the same board
//! code with the replay in place of its sensors, for QEMU's netduinoplus2.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
#[path = "../hardware/mod.rs"]
mod hardware;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "this is a firmware image: build it with `cargo fw-f411` and run it with \
         `cargo run --release -p host-tools --bin needle -- demo`"
    );
    std::process::exit(2);
}
