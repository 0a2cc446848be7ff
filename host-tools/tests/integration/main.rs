//! `needle`'s integration tests, one binary for all (each module links
//! the three libraries and the binary once, not fifteen times). A module per
//! behaviour; `cargo test -p host-tools --test integration MODULE::` runs
//! one, e.g. `diagnose::` or `apart_validation::the_diagnosis`.
//!
//! Two are binaries of their own, each saying why: peak memory
//! (`tests/memory.rs`: the kernel counts a child's peak with the process
//! it was spawned from) and the device on a serial port
//! (`tests/serial_device.rs`: real time).

#[path = "../common/mod.rs"]
mod common;

mod apart;
mod library;

mod apart_check;
mod apart_validation;
mod broken_streams;
mod browser;
mod decode_cli;
mod detect;
mod diagnose;
mod firmware_image;
mod fit;
mod fuzz;
mod hostile_input;
mod live;
mod qemu_twin;
mod real_rig;
mod rust_target;
mod workspace;
