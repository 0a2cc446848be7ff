//! Board support: the only place with registers, semihosting and `unsafe`.
//!
//! Boards, chosen at build time:
//! - `lm3s6965evb` (QEMU, Cortex-M3; the CI board, also runs the thumbv6m
//!   image),
//! - `mps2-an386` (QEMU, Cortex-M4F, feature `board-mps2`),
//! - the real board, ST Nucleo-F411RE (feature `board-f411`,
//!   [`nucleo_f411re`]): ADS1220, encoder timer, RTIC.
//!
//! In QEMU the ADC and encoder are a replay file read over semihosting
//! ([`ReplayFile`]); frames leave through UART0; defmt logs go out over
//! semihosting to QEMU's stdout. A panic or HardFault exits QEMU non-zero.

#[cfg(feature = "board-f411")]
pub mod nucleo_f411re;

#[cfg(not(feature = "board-f411"))]
mod qemu;
#[cfg(not(feature = "board-f411"))]
pub use qemu::*;
