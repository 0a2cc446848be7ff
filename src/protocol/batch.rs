//! The compact sample stream ([`needle_wire::batch`]: raw readings,
//! batched and delta-coded) as the core fills and reads it: its readings
//! in the wire's form and back, and what of a computed sample the batch's
//! check covers.

pub use needle_wire::batch::*;

use crate::hal::AdcSample;
use crate::insertion::Sample;
use crate::pipeline::RawSample;

/// The words of `s` a batch's check folds in: position, velocity, force,
/// model and phase (the residual is force − model; the index is the
/// batch's).
#[inline(always)]
pub fn checked_words(s: &Sample) -> CheckedWords {
    [s.x.0, s.v.0, s.force.0, s.model.0, s.phase as i32]
}

impl From<AdcSample> for AdcReading {
    #[inline(always)]
    fn from(a: AdcSample) -> Self {
        Self {
            counts: a.counts,
            saturated: a.saturated,
            overrun: a.overrun,
        }
    }
}

impl From<AdcReading> for AdcSample {
    #[inline(always)]
    fn from(a: AdcReading) -> Self {
        Self {
            counts: a.counts,
            saturated: a.saturated,
            overrun: a.overrun,
        }
    }
}

impl From<RawSample> for Reading {
    #[inline(always)]
    fn from(raw: RawSample) -> Self {
        Self {
            adc: raw.adc.map(AdcReading::from),
            encoder_count: raw.encoder_count,
        }
    }
}

impl From<Reading> for RawSample {
    #[inline(always)]
    fn from(raw: Reading) -> Self {
        Self {
            adc: raw.adc.map(AdcSample::from),
            encoder_count: raw.encoder_count,
        }
    }
}

/// Add `sample` and the readings it came from to `writer`; `true` when the
/// batch is full (see [`BatchWriter::push`]). Never inlined, as
/// [`crate::config::DeviceConfig::step`]: it is built with the core, for
/// speed, not with the board's crate that calls it.
#[inline(never)]
pub fn push(writer: &mut BatchWriter, raw: RawSample, sample: &Sample) -> bool {
    writer.push(raw.into(), sample.index, checked_words(sample))
}

/// Decode a batch's readings, calling `each` for every sample in order.
pub fn read_raw_samples(
    batch: &Batch<'_>,
    mut each: impl FnMut(RawSample),
) -> Result<(), MalformedBatch> {
    read_raw(batch, |reading| each(reading.into()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::insertion::Phase;
    use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

    fn sample(index: u32) -> Sample {
        Sample {
            index,
            x: Nanometres(index as i32),
            v: NanometresPerSecond(0),
            force: MicroNewtons(0),
            model: MicroNewtons(0),
            residual: MicroNewtons(0),
            phase: Phase::Out,
        }
    }

    #[test]
    fn the_check_sees_every_field_but_the_index() {
        let base = sample(7);
        let check = |s: &Sample| {
            let mut c = BatchCheck::default();
            c.add(checked_words(s));
            c.0
        };
        for changed in [
            Sample {
                x: Nanometres(8),
                ..base
            },
            Sample {
                v: NanometresPerSecond(1),
                ..base
            },
            Sample {
                force: MicroNewtons(1),
                ..base
            },
            Sample {
                model: MicroNewtons(1),
                ..base
            },
            Sample {
                phase: Phase::Loading,
                ..base
            },
        ] {
            assert_ne!(check(&changed), check(&base), "{changed:?}");
        }
    }
}
