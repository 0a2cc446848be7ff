//! The firmware from the host: building its images where `cargo
//! metadata` says the target directory is, running them in QEMU
//! ([`firmware`]), the demo of the whole chain ([`demo`]) and the
//! instruction-count bench ([`mod@bench`]).

pub mod bench;
pub mod demo;
pub mod firmware;
