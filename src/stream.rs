//! The receiving end of the compact stream: raw readings back to samples.
//!
//! The device sends its configuration, snapshots of its pipeline's state
//! and batches of raw readings ([`crate::protocol`]); this runs the same
//! pipeline on them from the same state and configuration and gets the
//! device's samples bit for bit. Each batch's check is compared with the
//! samples computed here: only a batch that matches is handed out. After a
//! lost frame or a mismatch, samples are withheld until the next snapshot
//! puts the state back in step (at most one status period): a sample is
//! either the device's own or reported missing, never guessed.

use crate::config::DeviceConfig;
use crate::insertion::Sample;
use crate::pipeline::PipelineState;
use crate::protocol::batch::{self, Batch, BatchCheck, MAX_BATCH_SAMPLES};
use crate::protocol::{ConfigFrame, Snapshot};

/// Why a batch's samples could not be given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Withheld {
    /// No configuration or state yet, or frames before this batch were
    /// lost: waiting for the next snapshot.
    OutOfStep,
    /// The batch's bytes do not decode to its samples.
    Malformed,
    /// The samples computed here do not match the device's check: this
    /// core or configuration differs from the device's.
    CheckMismatch,
}

/// Turns the stream's frames back into samples.
#[derive(Clone, Debug, Default)]
pub struct Reconstructor {
    config: Option<DeviceConfig>,
    seed: BatchCheck,
    state: Option<PipelineState>,
    next_index: u32,
}

impl Reconstructor {
    /// The device (re)started: forget everything.
    pub fn restart(&mut self) {
        *self = Self::default();
    }

    /// The configuration in force from now on; `wire_bytes` are the
    /// frame as received (COBS-encoded, without its closing zero).
    pub fn config_frame(&mut self, frame: &ConfigFrame, wire_bytes: &[u8]) {
        self.config = Some(frame.config);
        self.seed = BatchCheck::seed(wire_bytes);
    }

    /// The configuration in force, once one has arrived.
    pub fn config(&self) -> Option<&DeviceConfig> {
        self.config.as_ref()
    }

    /// Continue from the device's state.
    pub fn snapshot(&mut self, snapshot: Snapshot) {
        self.next_index = snapshot.next_index;
        self.state = Some(snapshot.state);
    }

    /// Frames were lost (the caller saw a gap): withhold samples until
    /// the next snapshot.
    pub fn lose_step(&mut self) {
        self.state = None;
    }

    /// The samples of `batch`, each passed to `each` in order, once the
    /// whole batch is computed and matches the device's check.
    pub fn batch(
        &mut self,
        batch: &Batch<'_>,
        mut each: impl FnMut(Sample),
    ) -> Result<(), Withheld> {
        let (Some(config), Some(state)) = (self.config.as_ref(), self.state.as_mut()) else {
            return Err(Withheld::OutOfStep);
        };
        if batch.first_index != self.next_index {
            self.state = None;
            return Err(Withheld::OutOfStep);
        }
        let mut trial = state.clone();
        let mut samples = heapless::Vec::<Sample, MAX_BATCH_SAMPLES>::new();
        let mut check = self.seed;
        let mut overflow = false;
        let decoded = batch::read_raw_samples(batch, |raw| {
            let out = config.step(&mut trial, raw);
            check.add(batch::checked_words(&out.sample));
            overflow |= samples.push(out.sample).is_err();
        });
        if decoded.is_err() || overflow {
            self.state = None;
            return Err(Withheld::Malformed);
        }
        if check.0.to_le_bytes() != batch.check {
            self.state = None;
            return Err(Withheld::CheckMismatch);
        }
        *state = trial;
        self.next_index = batch.first_index.wrapping_add(u32::from(batch.samples));
        samples.into_iter().for_each(&mut each);
        Ok(())
    }
}
