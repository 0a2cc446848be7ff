//! The core's integration tests, one binary for all, a module per
//! subject: `cargo test --test integration MODULE::` runs one (`model::`,
//! `device::`). The ADS1220 driver's are in its own crate
//! (`ads1220/tests/`).

mod device;
mod model;
