//! The core's integration tests, one binary for all, a module per
//! subject: `cargo test --test integration MODULE::` runs one (`model::`,
//! `device::`). The ADS1220 driver's own tests are in its crate
//! (`ads1220/tests/`); here, only its reading as the core's.

mod ads1220_adapter;
mod device;
mod model;
