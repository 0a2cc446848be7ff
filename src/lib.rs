//! Core of the instrumented needle holder: everything that happens to a
//! sample between the load-cell ADC and the serial port.
//!
//! `no_std`, integer-only in the per-sample path, free of registers and
//! `unsafe`. The same code runs in the firmware (crate
//! `needle-holder-firmware`, `firmware/`) and on the host (`host-tools`, tests), so the two
//! produce byte-identical frames for the same input.
//!
//! Pipeline, one call of [`device::Device::tick`] per sample:
//!
//! ```text
//! ADC counts ─ calibration ─> force ─┐
//! encoder counts ─ kinematics ─> x, v ┼─> phase + model + detectors ─> frames, halt line
//! ```
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod ads1220;
pub mod assist;
pub mod calibration;
pub mod config;
pub mod detect;
pub mod device;
pub mod faults;
pub mod hal;
pub mod insertion;
pub mod kinematics;
pub mod link;
pub mod model;
pub mod persist;
pub mod pipeline;
pub mod protocol;
pub mod replay;
pub mod sample_clock;
pub mod stream;
pub mod units;
