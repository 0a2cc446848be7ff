//! Encoder counts to position and velocity.
//!
//! **Position.** The 16-bit hardware count is unwrapped by adding the
//! signed 16-bit difference between successive reads to an `i32` total
//! (saturating), so the count may wrap any number of times as long as the
//! needle moves less than 32767 counts per sample. A difference larger than
//! [`crate::calibration::Encoder::max_counts_per_sample`] is a glitch: it is
//! not applied (the position holds) and the caller raises a fault.
//!
//! **Velocity** is the backward difference over a window of N samples,
//! `v[n] = (x[n] − x[n−N]) · f_s / N`, in integer arithmetic:
//! - delay: N/2 samples (a pure delay for a constant acceleration);
//! - noise at 1 µm counts: the count quantisation error is uniform in
//!   ±0.5 count at each end, so the estimate has a standard deviation of
//!   1 µm · f_s / (N·√6) — 20 µm/s for N = 10 at 500 Hz, 41 µm/s at 1 kHz
//!   with N = 10; the largest error is 1 µm · f_s / N;
//! - until N samples exist it uses the ones it has.
//!
//! A longer window lowers the noise and raises the delay; the window is
//! configuration ([`VelocityConfig`]), the history is state.

use heapless::Deque;
use postcard::experimental::max_size::MaxSize;
use postcard_schema::schema::{DataModelType, NamedType, NamedValue};
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::protocol::wire::varint_len;
use crate::units::{saturate_i32, Nanometres, NanometresPerSecond};

/// Largest velocity window, samples.
pub const MAX_VELOCITY_WINDOW: usize = 32;

/// Unwraps the wrapping encoder count into an `i32` count.
#[derive(Clone, Debug, Default, Serialize, Deserialize, Schema, MaxSize)]
pub struct EncoderTracker {
    last_raw: Option<u16>,
    total_counts: i32,
}

/// Outcome of one encoder read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncoderStep {
    /// Unwrapped count since start.
    pub total_counts: i32,
    /// The raw difference exceeded the allowed step and was discarded.
    pub jumped: bool,
}

impl EncoderTracker {
    /// Feed one raw read. `max_step` is the largest plausible |difference|.
    pub fn update(&mut self, raw: u16, max_step: u16) -> EncoderStep {
        let jumped = match self.last_raw {
            None => false,
            Some(last) => {
                let delta = raw.wrapping_sub(last) as i16;
                if delta.unsigned_abs() > max_step {
                    true
                } else {
                    self.total_counts = self.total_counts.saturating_add(delta as i32);
                    false
                }
            }
        };
        self.last_raw = Some(raw);
        EncoderStep {
            total_counts: self.total_counts,
            jumped,
        }
    }
}

/// Velocity estimator configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct VelocityConfig {
    /// Sample rate, Hz.
    pub sample_rate_hz: u16,
    /// Window N, samples (clamped to 1..=[`MAX_VELOCITY_WINDOW`]).
    pub window: u8,
}

impl VelocityConfig {
    fn window(&self) -> usize {
        (self.window as usize).clamp(1, MAX_VELOCITY_WINDOW)
    }
}

/// Velocity estimator state: the last N+1 positions.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct VelocityState {
    history: Deque<i32, { MAX_VELOCITY_WINDOW + 1 }>,
}

/// Written out, as its [`MaxSize`] below: postcard-schema knows
/// heapless's `Vec` but not its `Deque`, which serde writes as the same
/// sequence.
impl Schema for VelocityState {
    const SCHEMA: &'static NamedType = &NamedType {
        name: "VelocityState",
        ty: &DataModelType::Struct(&[&NamedValue {
            name: "history",
            ty: &NamedType {
                name: "heapless::Deque<i32, N>",
                ty: &DataModelType::Seq(i32::SCHEMA),
            },
        }]),
    };
}

/// A length and up to [`MAX_VELOCITY_WINDOW`] + 1 positions (postcard
/// knows heapless 0.7's types, not this 0.8's).
impl MaxSize for VelocityState {
    const POSTCARD_MAX_SIZE: usize =
        varint_len(MAX_VELOCITY_WINDOW + 1) + (MAX_VELOCITY_WINDOW + 1) * i32::POSTCARD_MAX_SIZE;
}

impl VelocityState {
    /// Push the newest position and return the windowed velocity.
    pub fn update(&mut self, config: &VelocityConfig, x: Nanometres) -> NanometresPerSecond {
        let window = config.window();
        while self.history.len() > window {
            self.history.pop_front();
        }
        // Cannot fail: at most `window` ≤ capacity − 1 entries remain.
        let _ = self.history.push_back(x.0);
        let oldest = self.history.front().copied().unwrap_or(x.0);
        let span = (self.history.len() - 1) as i32;
        if span == 0 {
            return NanometresPerSecond::ZERO;
        }
        let scaled = (x.0 as i64 - oldest as i64) * config.sample_rate_hz as i64;
        // 64-bit division is a library call on Cortex-M (~100 instructions);
        // the product fits 32 bits for any speed below 2^31/N nm/s, and both
        // divisions truncate toward zero, so the result is the same.
        // `span` ≥ 1, so neither division can fail; the checked forms
        // say so to the compiler (no panic path is linked).
        NanometresPerSecond(match i32::try_from(scaled) {
            Ok(s) => s.checked_div(span).unwrap_or(0),
            Err(_) => saturate_i32(scaled.checked_div(span as i64).unwrap_or(0)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unwraps_across_the_16_bit_boundary_both_ways() {
        let mut t = EncoderTracker::default();
        let mut raw: u16 = 65_500;
        t.update(raw, 200);
        for _ in 0..1000 {
            raw = raw.wrapping_add(100);
            t.update(raw, 200);
        }
        assert_eq!(t.update(raw, 200).total_counts, 100_000);
        for _ in 0..1500 {
            raw = raw.wrapping_sub(100);
            t.update(raw, 200);
        }
        assert_eq!(t.update(raw, 200).total_counts, -50_000);
    }

    #[test]
    fn a_jump_is_flagged_and_not_applied() {
        let mut t = EncoderTracker::default();
        t.update(0, 200);
        t.update(150, 200);
        let step = t.update(5_000, 200);
        assert!(step.jumped);
        assert_eq!(step.total_counts, 150);
        // Motion continues from the new reading without a second fault.
        let step = t.update(5_100, 200);
        assert!(!step.jumped);
        assert_eq!(step.total_counts, 250);
    }

    #[test]
    fn constant_speed_is_exact_and_window_warms_up() {
        let cfg = VelocityConfig {
            sample_rate_hz: 500,
            window: 10,
        };
        let mut s = VelocityState::default();
        assert_eq!(s.update(&cfg, Nanometres(0)), NanometresPerSecond(0));
        // 3 mm/s at 500 Hz is 6 µm per sample.
        for n in 1..40 {
            let v = s.update(&cfg, Nanometres(6_000 * n));
            assert_eq!(v, NanometresPerSecond(3_000_000), "sample {n}");
        }
    }
}
