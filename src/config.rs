//! Device configuration: everything fixed for a session, apart from state.

use crate::calibration::{Encoder, LoadCell};
use crate::detect::DetectConfig;
use crate::kinematics::VelocityConfig;
use crate::model::ModelConfig;

/// Configuration of the whole per-sample pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceConfig {
    /// Load-cell calibration.
    pub load_cell: LoadCell,
    /// Encoder scale and plausibility limit.
    pub encoder: Encoder,
    /// Sample rate and velocity window.
    pub velocity: VelocityConfig,
    /// Force model.
    pub model: ModelConfig,
    /// Event detectors.
    pub detect: DetectConfig,
}

impl Default for DeviceConfig {
    /// The bench setup of the paper: 10 N load cell, 1 µm encoder, 500 Hz.
    fn default() -> Self {
        Self {
            load_cell: LoadCell::TEN_NEWTON_24_BIT,
            encoder: Encoder::ONE_MICRON,
            velocity: VelocityConfig {
                sample_rate_hz: 500,
                window: 10,
            },
            model: ModelConfig,
            detect: DetectConfig::default(),
        }
    }
}

impl DeviceConfig {
    /// The same configuration at another sample rate.
    pub fn with_sample_rate(mut self, sample_rate_hz: u16) -> Self {
        self.velocity.sample_rate_hz = sample_rate_hz;
        self
    }
}
