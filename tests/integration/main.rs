//! The core's integration tests, one binary for all, a module per
//! subject: `cargo test --test integration MODULE::` runs one (`model::`,
//! `device::`, `ads1220::`).

mod ads1220;
mod device;
mod model;
