//! `needle`'s integration tests, one binary for all (each module links
//! the library and the binary once, not fifteen times). A module per
//! behaviour; `cargo test -p host-tools --test integration MODULE::` runs
//! one, e.g. `diagnose::` or `apart_validation::the_diagnosis`.
//!
//! Peak memory is measured apart, in `tests/memory.rs`: a child's peak as
//! the kernel reports it counts the process it was spawned from, so
//! nothing else may run beside it.

#[path = "../common/mod.rs"]
mod common;

mod apart;
mod library;

mod apart_check;
mod apart_validation;
mod broken_streams;
mod decode_cli;
mod detect;
mod diagnose;
mod firmware_image;
mod fit;
mod fuzz;
mod hostile_input;
mod qemu_twin;
mod real_rig;
mod rust_target;
mod serial_device;
