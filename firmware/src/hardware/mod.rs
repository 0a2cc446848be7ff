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

/// The replay source, read over semihosting: the QEMU boards' and the
/// real board's replay image's.
#[cfg(any(not(feature = "board-f411"), feature = "f411-replay"))]
mod replay_file;

/// Semihosting without a panic path, and the defmt logger over it.
#[cfg(any(not(feature = "board-f411"), feature = "f411-replay"))]
mod semihost;

/// defmt framing shared by the loggers, without a panic path.
mod log_frames;

/// Markers around each sample for `needle bench`'s instruction count.
#[cfg(any(not(feature = "board-f411"), feature = "f411-replay"))]
mod bench;

/// Exit codes seen by whoever started QEMU.
#[cfg(any(not(feature = "board-f411"), feature = "f411-replay"))]
pub mod exit_code {
    /// The replay file could not be opened or named.
    pub const NO_REPLAY: i32 = 2;
    /// HardFault.
    #[cfg_attr(feature = "board-f411", allow(dead_code))] // halt.rs says 3
    pub const HARD_FAULT: i32 = 3;
    /// Panic (the firmware is built never to panic; this is the backstop).
    #[cfg_attr(feature = "board-f411", allow(dead_code))] // halt.rs says 101
    pub const PANIC: i32 = 101;
}

/// Leave QEMU with `code`.
#[cfg(any(not(feature = "board-f411"), feature = "f411-replay"))]
pub fn exit(code: i32) -> ! {
    semihost::exit(code)
}
