//! Device configuration: everything fixed for a session, apart from state.

use crate::assist::{AssistConfig, AssistModes};
use crate::calibration::{Encoder, LoadCell};
use crate::detect::DetectConfig;
use crate::kinematics::VelocityConfig;
use crate::model::params::{ParamError, TissueParams, LIVER1};
use crate::model::ModelConfig;
use serde::{Deserialize, Serialize};

/// Configuration of the whole per-sample pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
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
    /// Robot assist: what halts the robot besides faults.
    pub assist: AssistConfig,
}

/// Assist modes of the firmware image, chosen by cargo features
/// (`stop-on-puncture`, `stop-on-structure`, `stop-on-exit`, `back-off`,
/// `speed-limit`); none by default, so the device records and only faults
/// halt the robot.
pub const FIRMWARE_ASSIST: AssistModes = {
    let mut m = AssistModes::NONE;
    if cfg!(feature = "stop-on-puncture") {
        m = m.union(AssistModes::STOP_ON_PUNCTURE);
    }
    if cfg!(feature = "stop-on-structure") {
        m = m.union(AssistModes::STOP_ON_STRUCTURE);
    }
    if cfg!(feature = "stop-on-exit") {
        m = m.union(AssistModes::STOP_ON_EXIT);
    }
    if cfg!(feature = "back-off") {
        m = m.union(AssistModes::BACK_OFF);
    }
    if cfg!(feature = "speed-limit") {
        m = m.union(AssistModes::SPEED_LIMIT);
    }
    m
};

/// The fastest the needle drive moves, nm/s (100 mm/s).
const MAX_DRIVE_NM_PER_S: i64 = 100_000_000;

/// The library name of the firmware's default tissue.
pub const DEFAULT_TISSUE: &str = "liver1";

/// The firmware's default: liver 1 of the paper, converted at compile time.
pub const DEFAULT: DeviceConfig = match DeviceConfig::for_tissue(&LIVER1) {
    Ok(config) => config,
    Err(_) => panic!("liver1 in the tissue library is invalid"),
};

impl Default for DeviceConfig {
    fn default() -> Self {
        DEFAULT
    }
}

impl DeviceConfig {
    /// The bench setup of the paper (10 N load cell, 1 µm encoder, 500 Hz,
    /// velocity over 10 samples) with the model and detectors of `tissue`.
    pub const fn for_tissue(tissue: &TissueParams) -> Result<Self, ParamError> {
        let model = match ModelConfig::from_params(tissue) {
            Ok(model) => model,
            Err(e) => return Err(e),
        };
        Ok(Self {
            load_cell: LoadCell::TEN_NEWTON_24_BIT,
            encoder: Encoder::ONE_MICRON,
            velocity: VelocityConfig {
                sample_rate_hz: 500,
                window: 10,
            },
            model,
            detect: DetectConfig::for_tissue(tissue),
            assist: AssistConfig::for_tissue(tissue, FIRMWARE_ASSIST),
        })
    }

    /// This configuration (calibration, rate, velocity window, assist
    /// modes and target depth) with `tissue`'s model and detectors.
    pub fn with_tissue(&self, tissue: &TissueParams) -> Result<Self, ParamError> {
        let mut next = Self {
            load_cell: self.load_cell,
            encoder: self.encoder,
            velocity: self.velocity,
            ..Self::for_tissue(tissue)?
        }
        .with_sample_rate(self.velocity.sample_rate_hz);
        next.assist.modes = self.assist.modes;
        next.assist.target_depth = self.assist.target_depth;
        Ok(next)
    }

    /// The same configuration with other assist modes.
    pub const fn with_assist(mut self, modes: AssistModes) -> Self {
        self.assist.modes = modes;
        self
    }

    /// The same configuration at another sample rate. Below 500 Hz the
    /// encoder's jump limit grows so that it still means the drive's
    /// 100 mm/s (a 100 Hz rig moves up to 1 mm between samples); it never
    /// shrinks.
    pub const fn with_sample_rate(mut self, sample_rate_hz: u16) -> Self {
        self.velocity.sample_rate_hz = sample_rate_hz;
        self.detect = self.detect.at_sample_rate(sample_rate_hz);
        let per_sample = MAX_DRIVE_NM_PER_S
            / (if sample_rate_hz == 0 {
                1
            } else {
                sample_rate_hz as i64
            })
            / (if self.encoder.nm_per_count <= 0 {
                1
            } else {
                self.encoder.nm_per_count as i64
            });
        if per_sample > self.encoder.max_counts_per_sample as i64 {
            self.encoder.max_counts_per_sample = if per_sample > 16_000 {
                16_000
            } else {
                per_sample as u16
            };
        }
        self
    }
}
