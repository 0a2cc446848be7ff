//! The device: reads the sensors through the HAL traits, runs the pipeline,
//! sends frames and drives the halt line. Generic over the HAL, so the
//! firmware and the host twin run exactly this code.

use embedded_hal::digital::OutputPin;
use embedded_io::Write;

use crate::config::DeviceConfig;
use crate::faults::Faults;
use crate::hal::{EncoderCounter, LoadCellAdc};
use crate::pipeline::{PipelineState, RawSample};
use crate::protocol::{
    Event, EventKind, Frame, FrameEncoder, Halt, HaltReason, Header, Status, PROTOCOL_VERSION,
    STATUS_PERIOD_SAMPLES,
};
use crate::units::{MicroNewtons, Nanometres};

/// The halt line is active high: `set_high` asserts it (robot must stop).
/// Wire it through an inverting stage if the robot's input must fail safe
/// when the device loses power.
pub struct Device<W: Write, H: OutputPin> {
    config: DeviceConfig,
    state: PipelineState,
    sink: W,
    encoder: FrameEncoder,
    halt: H,
    halt_asserted: bool,
    faults: Faults,
    samples: u32,
    frames_dropped: u32,
}

/// Counters and flags at the end of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Summary {
    /// Samples processed.
    pub samples: u32,
    /// Frames the sink refused.
    pub frames_dropped: u32,
    /// Latched faults.
    pub faults: Faults,
    /// Halt line asserted.
    pub halt: bool,
}

impl<W: Write, H: OutputPin> Device<W, H> {
    /// Start the device: halt released, header sent.
    pub fn new(config: DeviceConfig, sink: W, halt: H) -> Self {
        let mut device = Self {
            config,
            state: PipelineState::default(),
            sink,
            encoder: FrameEncoder::default(),
            halt,
            halt_asserted: false,
            faults: Faults::NONE,
            samples: 0,
            frames_dropped: 0,
        };
        if device.halt.set_low().is_err() {
            device.faults = device.faults.union(Faults::HALT_OUTPUT);
        }
        device.send(&Frame::Header(Header {
            protocol_version: PROTOCOL_VERSION,
            sample_rate_hz: config.velocity.sample_rate_hz,
        }));
        device
    }

    /// One sample period: read both sensors, process, send, drive halt.
    pub fn tick<A: LoadCellAdc, E: EncoderCounter>(&mut self, adc: &mut A, encoder: &mut E) {
        let raw = RawSample {
            adc: adc.read().ok(),
            encoder_count: encoder.count(),
        };
        let out = self.config.step(&mut self.state, raw);
        self.samples = self.samples.saturating_add(1);
        self.send(&Frame::Sample(out.sample));
        if let Some(event) = out.event {
            self.send(&Frame::Event(event));
        }
        if let Some(halt) = out.halt {
            self.assert_halt(halt);
        }
        let at = (out.sample.index, out.sample.x, out.sample.force);
        if !self.raise_at(out.faults, at) && self.samples.is_multiple_of(STATUS_PERIOD_SAMPLES) {
            self.send_status();
        }
    }

    /// Raise faults found outside the pipeline (e.g. a truncated replay).
    pub fn raise(&mut self, faults: Faults) {
        self.raise_at(faults, (self.samples, Nanometres::ZERO, MicroNewtons::ZERO));
    }

    /// Send a final status and return the counters.
    pub fn finish(&mut self) -> Summary {
        self.send_status();
        let _ = self.sink.flush();
        self.summary()
    }

    /// Counters and flags so far.
    pub fn summary(&self) -> Summary {
        Summary {
            samples: self.samples,
            frames_dropped: self.frames_dropped,
            faults: self.faults,
            halt: self.halt_asserted,
        }
    }

    /// Latch new faults, send a fault event, assert halt, send a status.
    /// `at` is the sample (index, position, force) that raised them.
    /// Returns whether a status was sent.
    fn raise_at(&mut self, faults: Faults, at: (u32, Nanometres, MicroNewtons)) -> bool {
        let new = Faults(faults.0 & !self.faults.0);
        if new.is_empty() {
            return false;
        }
        self.faults = self.faults.union(new);
        self.send(&Frame::Event(Event {
            index: at.0,
            kind: EventKind::Fault,
            x: at.1,
            force: at.2,
            confidence_permille: 1000,
        }));
        self.assert_halt(Halt {
            index: at.0,
            reason: HaltReason::Fault,
            x: at.1,
            hold_x: at.1,
        });
        self.send_status();
        true
    }

    /// Raise the halt line (latched) and say why, once.
    fn assert_halt(&mut self, why: Halt) {
        if self.halt_asserted {
            return;
        }
        self.halt_asserted = true;
        if self.halt.set_high().is_err() {
            self.faults = self.faults.union(Faults::HALT_OUTPUT);
        }
        self.send(&Frame::Halt(why));
    }

    fn send_status(&mut self) {
        let status = Status {
            protocol_version: PROTOCOL_VERSION,
            sample_rate_hz: self.config.velocity.sample_rate_hz,
            samples: self.samples,
            frames_dropped: self.frames_dropped,
            faults: self.faults,
            halt: self.halt_asserted,
        };
        self.send(&Frame::Status(status));
    }

    fn send(&mut self, frame: &Frame) {
        let bytes = self.encoder.encode(frame);
        if bytes.is_empty() || self.sink.write_all(bytes).is_err() {
            self.frames_dropped = self.frames_dropped.saturating_add(1);
        }
    }
}
