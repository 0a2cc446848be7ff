//! One sample through the pure logic: raw readings in, sample and event out.
//! No hardware here; [`crate::device::Device`] does the reading and sending.

use crate::config::DeviceConfig;
use crate::detect::{DetectInput, DetectState};
use crate::faults::Faults;
use crate::hal::AdcSample;
use crate::insertion::{Event, Halt, Sample};
use crate::kinematics::{EncoderTracker, VelocityState};
use crate::model::phase::PhaseState;
use crate::model::relax::RelaxState;
use crate::model::{ModelConfig, ModelState};
use crate::units::MicroNewtons;
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// What the sensors gave for one sample period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawSample {
    /// The ADC conversion, or `None` when the ADC returned an error.
    pub adc: Option<AdcSample>,
    /// The encoder's wrapping count.
    pub encoder_count: u16,
}

/// Per-sample state of the pipeline.
#[derive(Clone, Debug, Default, Serialize, Deserialize, Schema, MaxSize)]
pub struct PipelineState {
    index: u32,
    encoder: EncoderTracker,
    velocity: VelocityState,
    detect: DetectState,
    phase: PhaseState,
    model: ModelState,
    last_force: MicroNewtons,
    /// Every fault raised so far: once there is one, the detectors stop.
    faults_seen: Faults,
    /// What the tissue's relaxation still holds. Last, as
    /// [`DeviceConfig::relaxation`] is: a protocol-3 snapshot is this
    /// one without it.
    relax: RelaxState,
}

/// Result of one step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepOutput {
    /// The processed sample.
    pub sample: Sample,
    /// The event detected at this sample, if any.
    pub event: Option<Event>,
    /// Faults this sample raised (not latched here; the device latches).
    pub faults: Faults,
    /// The robot-assist stop this sample calls for, if any (never on a
    /// sample that raised a fault: that one halts for the fault).
    pub halt: Option<Halt>,
}

impl PipelineState {
    /// Every fault raised so far.
    pub fn faults_seen(&self) -> Faults {
        self.faults_seen
    }

    /// What the tissue at rest holds and has relaxed.
    pub fn relax(&self) -> &RelaxState {
        &self.relax
    }

    /// The phase machine's state.
    pub fn phase(&self) -> &PhaseState {
        &self.phase
    }

    /// After a re-arm: the detectors run again (a fault stopped them).
    pub fn rearm(&mut self) {
        self.faults_seen = Faults::NONE;
    }
}

impl DeviceConfig {
    /// The model's force for a needle at rest: in the tissue, what it was
    /// applied with when it stopped (Karnopp: the applied force within the
    /// static band), which the load cell measured then; relaxed. Out of
    /// line: most samples slide, and the sample path keeps its registers.
    #[inline(never)]
    fn at_rest(
        &self,
        state: &mut PipelineState,
        x: crate::units::Nanometres,
        force: MicroNewtons,
        unrelaxed: MicroNewtons,
    ) -> MicroNewtons {
        let mut held = unrelaxed;
        if self.relaxation.hold_applied {
            if ModelConfig::holds_at_rest(&state.phase) {
                let band = || self.model.static_band(&state.phase, x);
                held = state.relax.hold(force, band);
            } else {
                state.relax.release();
            }
        }
        self.relaxation
            .at_rest(&mut state.relax, held, self.velocity.sample_rate_hz)
    }

    /// Process one raw sample: calibrate, kinematics, detectors, phase,
    /// model, robot assist.
    ///
    /// A sample whose force is unknown (ADC error, saturation, overrun) or
    /// whose position is doubtful (encoder jump) is still reported, but
    /// from the first fault on the detectors stop: the halt line is latched
    /// by then, and their inputs can no longer be trusted, so a fault never
    /// fires an event (above all, never a puncture).
    ///
    /// Never inlined: the firmware's images build their own crate for size
    /// and this one for speed, and a caller built for size would build the
    /// per-sample work inlined into it for size too.
    #[inline(never)]
    pub fn step(&self, state: &mut PipelineState, raw: RawSample) -> StepOutput {
        let index = state.index;
        state.index = state.index.saturating_add(1);

        let mut faults = Faults::NONE;
        let force = match raw.adc {
            // A late sample's timing is unknown: keep the last force.
            Some(adc) if adc.overrun => {
                faults = faults.union(Faults::SAMPLE_OVERRUN);
                state.last_force
            }
            Some(adc) => {
                if adc.saturated {
                    faults = faults.union(Faults::ADC_SATURATED);
                }
                self.load_cell.force(adc.counts)
            }
            None => {
                faults = faults.union(Faults::ADC_ERROR);
                state.last_force
            }
        };
        state.last_force = force;

        let enc = state
            .encoder
            .update(raw.encoder_count, self.encoder.max_counts_per_sample);
        if enc.jumped {
            faults = faults.union(Faults::ENCODER_JUMP);
        }
        let x = self.encoder.position(enc.total_counts);
        let v = state.velocity.update(&self.velocity, x);

        let event = if faults.union(state.faults_seen).is_empty() {
            let input = DetectInput {
                index,
                phase: state.phase.phase,
                x,
                v,
                force,
                at_cutting_front: x >= state.phase.deepest,
            };
            let found = self.detect.update(&mut state.detect, input);
            faults = faults.union(found.faults);
            // A sample that raises a fault fires no event.
            found.event.filter(|_| found.faults.is_empty())
        } else {
            None
        };
        state.faults_seen = state.faults_seen.union(faults);
        let placed = event.map(|e| (e.kind, e.x));
        self.model
            .phase
            .update(&mut state.phase, placed, x, v, force);
        let unrelaxed = self.model.expected(&mut state.model, &state.phase, x, v);
        let model = if self.model.sliding(v) {
            self.relaxation.slide(&mut state.relax, unrelaxed)
        } else {
            self.at_rest(state, x, force, unrelaxed)
        };
        let phase = state.phase.phase;
        let sample = Sample {
            index,
            x,
            v,
            force,
            model,
            residual: force.sub(model),
            phase,
        };
        // A faulty sample halts for its fault (the device does that), not
        // for the assist.
        let halt = if faults.is_empty() {
            self.assist
                .check(&state.phase, &sample, event.map(|e| e.kind))
        } else {
            None
        };
        StepOutput {
            sample,
            event,
            faults,
            halt,
        }
    }
}
