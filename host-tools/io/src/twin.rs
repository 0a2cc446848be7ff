//! The host twin: the core's device loop on a replay, with fakes for the
//! hardware. Gives the same frame bytes as the firmware in QEMU.

use std::convert::Infallible;

use needle_holder::config::DeviceConfig;
use needle_holder::device::Summary;
use needle_holder::replay;

/// A halt line that remembers its level and how often it was driven high.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct RecordingPin {
    pub high: bool,
    pub times_set_high: u32,
}

impl embedded_hal::digital::ErrorType for RecordingPin {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for RecordingPin {
    fn set_high(&mut self) -> Result<(), Infallible> {
        self.high = true;
        self.times_set_high += 1;
        Ok(())
    }
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.high = false;
        Ok(())
    }
}

/// What the twin produced.
#[derive(Debug, Clone)]
pub struct TwinRun {
    pub frames: Vec<u8>,
    pub summary: Summary,
    pub halt: RecordingPin,
}

/// Run `replay` (file bytes) through the core with the default configuration.
pub fn run(replay_bytes: &[u8]) -> TwinRun {
    let mut frames = Vec::new();
    let mut halt = RecordingPin::default();
    let summary = replay::run(
        replay_bytes,
        DeviceConfig::default(),
        &mut frames,
        &mut halt,
    );
    TwinRun {
        frames,
        summary,
        halt,
    }
}
