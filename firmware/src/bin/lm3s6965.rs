//! The image for QEMU's lm3s6965evb (Cortex-M3, `cargo fw-m3`; the
//! thumbv6m build of it, `cargo fw-m0`, runs there too): the CI board.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
#[path = "../hardware/mod.rs"]
mod hardware;

// Built with the real board's feature (a lint of the whole package), the
// board code is the real board's, which has its own entry point.
#[cfg(all(target_os = "none", not(feature = "board-f411")))]
#[path = "../replay_loop.rs"]
mod replay_loop;

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "this is a firmware image: build it with `cargo fw-m3` and run it with \
         `cargo run --release -p host-tools --bin needle -- demo`"
    );
    std::process::exit(2);
}
