//! The device: reads the sensors through the HAL traits, runs the pipeline,
//! sends frames, drives the halt line and takes commands. Generic over the
//! HAL, so the firmware and the host twin run exactly this code.

use embedded_hal::digital::OutputPin;
use embedded_io::Write;

use crate::assist::AssistModes;
use crate::calibration::ZeroTracker;
use crate::config::{DeviceConfig, TissueModel, DEFAULT_TISSUE, LIBRARY_MODELS};
use crate::faults::Faults;
use crate::hal::{EncoderCounter, LoadCellAdc};
use crate::insertion::{Event, EventKind, Halt, HaltReason, Phase, Sample};
use crate::model::params::LIBRARY;
use crate::persist::{Loaded, Settings};
use crate::pipeline::{PipelineState, RawSample};
use crate::protocol::batch::{self, samples_per_batch, BatchCheck, BatchWriter};
use crate::protocol::command::{self, CommandReader};
use crate::protocol::{
    BoardCounters, BoardFindings, Command, CommandError, CommandFrame, ConfigFrame, Frame,
    FrameEncoder, Reply, SelfTest, Snapshot, Status, TissueSource, PROTOCOL_VERSION, SCHEMA_KEY,
    STATUS_PERIOD_SAMPLES,
};
use crate::units::{MicroNewtons, Nanometres};

/// Samples between two config frames sent unasked, for a host that
/// joined mid-stream: every eighth status (4 s at 500 Hz).
const CONFIG_PERIOD_SAMPLES: u32 = 8 * STATUS_PERIOD_SAMPLES;

/// The halt line is active high: `set_high` asserts it (robot must stop).
/// Wire it through an inverting stage if the robot's input must fail safe
/// when the device loses power.
pub struct Device<W: Write, H: OutputPin> {
    config: DeviceConfig,
    tissue: TissueSource,
    state: PipelineState,
    sink: W,
    encoder: FrameEncoder,
    batch: BatchWriter,
    streaming: bool,
    halt: H,
    halt_asserted: bool,
    faults: Faults,
    samples: u32,
    frames_dropped: u32,
    /// The last sample and the faults it raised: what a re-arm checks.
    last: Option<(Sample, Faults)>,
    zero: ZeroTracker,
    commands: CommandReader,
    /// The last command taken: its sequence number, check and reply.
    last_command: (u32, u16, Result<(), CommandError>),
    /// What the board's settings store held at boot.
    stored: Loaded,
    /// Settings changed by a command and not yet handed to the store.
    unsaved: bool,
    /// What the board counts below the core, for the status frames.
    board: BoardCounters,
    /// Samples processed when a fault was last raised from outside the
    /// pipeline (a converter that stopped, a reset by the watchdog), until
    /// the next sample: a re-arm needs one, the proof that the cause is
    /// gone.
    raised_outside_at: Option<u32>,
    /// A self-test was asked for and the board has not yet answered it.
    self_test_asked: bool,
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

impl Summary {
    /// Whether the halt is asserted for a latched fault: a state nothing
    /// but a re-arm leaves, in which the robot is stopped. A board's
    /// independent watchdog may be fed in it without samples (a converter
    /// that stopped is reported, not turned into a reset loop); anywhere
    /// else only a sample feeds it.
    pub fn halted_for_fault(&self) -> bool {
        self.halt && !self.faults.is_empty()
    }
}

/// The library position of the default tissue.
pub fn default_tissue() -> TissueSource {
    let at = LIBRARY.iter().position(|(name, _)| *name == DEFAULT_TISSUE);
    at.map_or(TissueSource::Uploaded, |i| TissueSource::Library(i as u8))
}

impl<W: Write, H: OutputPin> Device<W, H> {
    /// Start the device with the compiled-in tissue, on a board that
    /// keeps no settings: halt released; header, configuration and state
    /// sent.
    pub fn new(config: DeviceConfig, sink: W, halt: H) -> Self {
        Self::restored(config, default_tissue(), Loaded::NotKept, sink, halt)
    }

    /// [`Self::new`] on a board with a settings store: `config` is made
    /// from what it held (`stored`), `tissue` says where its tissue came
    /// from.
    pub fn restored(
        config: DeviceConfig,
        tissue: TissueSource,
        stored: Loaded,
        sink: W,
        halt: H,
    ) -> Self {
        Self::restored_with(config, tissue, stored, Faults::NONE, sink, halt)
    }

    /// [`Self::restored`] with `faults` the board found before arming (a
    /// reset by its watchdog, a load at boot, a converter that did not
    /// start) latched from the start: the halt line, which the board
    /// drives high until it arms, is then never released.
    pub fn restored_with(
        config: DeviceConfig,
        tissue: TissueSource,
        stored: Loaded,
        faults: Faults,
        sink: W,
        halt: H,
    ) -> Self {
        let mut device = Self {
            config,
            tissue,
            state: PipelineState::default(),
            sink,
            encoder: FrameEncoder::default(),
            batch: BatchWriter::new(samples_per_batch(config.velocity.sample_rate_hz)),
            streaming: true,
            halt,
            halt_asserted: false,
            faults: Faults::NONE,
            samples: 0,
            frames_dropped: 0,
            last: None,
            zero: ZeroTracker::default(),
            commands: CommandReader::default(),
            last_command: (0, 0, Ok(())),
            stored,
            unsaved: false,
            board: BoardCounters::default(),
            raised_outside_at: None,
            self_test_asked: false,
        };
        if faults.is_empty() && device.halt.set_low().is_err() {
            device.faults = device.faults.union(Faults::HALT_OUTPUT);
        }
        device.send(&Frame::Header(crate::protocol::header(
            config.velocity.sample_rate_hz,
        )));
        device.send_config();
        device.send_snapshot();
        device.raise(faults);
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
        // A sample came: what was raised outside the samples may be
        // re-armed past now.
        self.raised_outside_at = None;
        // A late conversion's counts are not a reading of this sample.
        if let Some(adc) = raw.adc.filter(|a| !a.overrun) {
            self.zero.add(adc.counts);
        }
        self.last = Some((out.sample, out.faults));
        if self.streaming && batch::push(&mut self.batch, raw, &out.sample) {
            self.flush_batch();
        }
        if let Some(event) = out.event {
            self.send(&Frame::Event(event.into()));
        }
        if let Some(halt) = out.halt {
            self.assert_halt(halt);
        }
        let at = (out.sample.index, out.sample.x, out.sample.force);
        if !self.raise_at(out.faults, at) && self.samples.is_multiple_of(STATUS_PERIOD_SAMPLES) {
            if self.samples.is_multiple_of(CONFIG_PERIOD_SAMPLES) {
                self.send_config();
            }
            self.send_snapshot();
            self.send_status();
        }
    }

    /// Whether a self-test was asked for since the last call: the board
    /// then looks and answers with [`Self::send_self_test`].
    pub fn self_test_asked(&mut self) -> bool {
        core::mem::take(&mut self.self_test_asked)
    }

    /// Send the self-test with what the board found.
    pub fn send_self_test(&mut self, board: BoardFindings) {
        let report = SelfTest {
            board,
            halt: self.halt_asserted,
            faults: self.faults.into(),
            counters: self.board,
        };
        self.send(&Frame::SelfTest(report));
    }

    /// The board's counters, which the next status frames report.
    pub fn board_counters_mut(&mut self) -> &mut BoardCounters {
        &mut self.board
    }

    /// Raise faults found outside the pipeline (e.g. a truncated replay,
    /// a converter that stopped): a re-arm waits for a sample after them.
    pub fn raise(&mut self, faults: Faults) {
        if faults.is_empty() {
            return;
        }
        self.raised_outside_at = Some(self.samples);
        self.raise_at(faults, (self.samples, Nanometres::ZERO, MicroNewtons::ZERO));
    }

    /// Send what is in hand and a final status; return the counters.
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

    /// The configuration in force.
    pub fn config(&self) -> &DeviceConfig {
        &self.config
    }

    /// The settings to keep, once after each command that changed them
    /// (tissue, calibration, assist); `None` when nothing changed since.
    pub fn settings_to_save(&mut self) -> Option<Settings> {
        core::mem::take(&mut self.unsaved).then(|| Settings {
            tissue: self.tissue,
            model: self.config.tissue_model(),
            load_cell: self.config.load_cell,
            assist_modes: self.config.assist.modes,
            target_depth: self.config.assist.target_depth,
        })
    }

    /// Take bytes from the host: every command they complete is carried
    /// out (or refused) and answered. Call between samples.
    pub fn receive(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            if let Some(frame) = self.commands.push(byte) {
                self.answer(frame);
            }
        }
    }

    /// Carry out (or refuse) one command frame that a [`CommandReader`]
    /// put together, and answer it. For a board that collects command
    /// bytes outside the sample's lock and takes the lock only for this.
    pub fn answer(&mut self, frame: Result<(CommandFrame, u16), CommandError>) {
        let (seq, result) = match frame {
            Err(e) => (0, Err(e)),
            Ok((frame, check)) => {
                let (last_seq, last_check, ref last_result) = self.last_command;
                if frame.seq == last_seq && check == last_check {
                    // A repeated self-test is asked again: its frame may
                    // have been lost with the reply.
                    self.self_test_asked |= matches!(frame.command, Command::SelfTest);
                    (frame.seq, last_result.clone())
                } else if frame.seq <= last_seq {
                    let next_seq = last_seq.saturating_add(1);
                    (frame.seq, Err(CommandError::Stale { next_seq }))
                } else {
                    let result = self.carry_out(frame.command);
                    let changes_settings = matches!(
                        frame.command,
                        Command::Tare
                            | Command::SelectTissue(_)
                            | Command::UploadTissue(_)
                            | Command::SetAssist { .. }
                            | Command::SetLoadCellGain(_)
                    );
                    self.unsaved |= changes_settings && result.is_ok();
                    self.last_command = (frame.seq, check, result.clone());
                    (frame.seq, result)
                }
            }
        };
        self.send(&Frame::Reply(Reply { seq, result }));
    }

    /// Do what `command` asks, or say why not (changing nothing).
    fn carry_out(&mut self, command: Command) -> Result<(), CommandError> {
        match command {
            Command::Tare => self.tare(),
            Command::SelectTissue(i) => {
                let library_len = LIBRARY_MODELS.len() as u8;
                let tissue = LIBRARY_MODELS
                    .get(usize::from(i))
                    .ok_or(CommandError::NoSuchTissue { library_len })?;
                self.change_tissue(tissue, TissueSource::Library(i))
            }
            Command::UploadTissue(tissue) => {
                tissue.check().map_err(|e| CommandError::InvalidTissue {
                    field: command::text(e.field),
                    problem: command::text(e.problem),
                })?;
                self.change_tissue(&tissue, TissueSource::Uploaded)
            }
            Command::SetAssist {
                modes,
                target_depth,
            } => {
                let (modes, target_depth) = (AssistModes::from(modes), target_depth.into());
                if !modes.is_known() {
                    return Err(CommandError::out_of_range("modes"));
                }
                if !crate::assist::target_depth_is_valid(target_depth) {
                    return Err(CommandError::out_of_range("target_depth"));
                }
                self.config.assist.modes = modes;
                self.config.assist.target_depth = target_depth;
                self.send_config();
                Ok(())
            }
            Command::Rearm => self.rearm(),
            Command::Stream(on) => {
                // Starting (again) describes the stream afresh: a host that
                // asks for it can decode from the next batch on.
                if on {
                    self.streaming = true;
                    self.send_config();
                    self.send_snapshot();
                } else {
                    self.flush_batch();
                    self.streaming = false;
                }
                self.send_status();
                Ok(())
            }
            Command::ReadConfig => {
                self.send_config();
                Ok(())
            }
            Command::SelfTest => {
                self.self_test_asked = true;
                Ok(())
            }
            Command::SetLoadCellGain(gain_q16) => {
                // The force's scale does not jump under a needle in tissue.
                if self.state.phase().phase != Phase::Out {
                    return Err(CommandError::NeedleInTissue);
                }
                if gain_q16.unsigned_abs() < command::MIN_GAIN_Q16 {
                    return Err(CommandError::out_of_range("gain"));
                }
                self.config.load_cell.gain_q16 = gain_q16;
                self.send_config();
                Ok(())
            }
        }
    }

    fn tare(&mut self) -> Result<(), CommandError> {
        if self.state.phase().phase != Phase::Out {
            return Err(CommandError::NeedleInTissue);
        }
        let Some(zero) = self.zero.mean_counts() else {
            return Err(CommandError::out_of_range(
                crate::protocol::command::NO_READING_YET,
            ));
        };
        if zero.unsigned_abs() > self.config.load_cell.most_tare_offset_counts() {
            let at_zero = crate::calibration::LoadCell {
                tare_counts: 0,
                ..self.config.load_cell
            };
            return Err(CommandError::LoadOnNeedle {
                force: at_zero.force(zero).into(),
            });
        }
        self.config.load_cell.tare_counts = zero;
        self.send_config();
        Ok(())
    }

    fn change_tissue(
        &mut self,
        tissue: &TissueModel,
        source: TissueSource,
    ) -> Result<(), CommandError> {
        self.config = self.config.with_tissue(tissue);
        self.tissue = source;
        self.send_config();
        Ok(())
    }

    /// Release the halt line unless the last sample would raise it again.
    fn rearm(&mut self) -> Result<(), CommandError> {
        if !self.halt_asserted {
            return Ok(());
        }
        if self.raised_outside_at.is_some() {
            return Err(CommandError::HaltCausePersists {
                reason: HaltReason::Fault.into(),
            });
        }
        if let Some((sample, faults)) = self.last {
            if !faults.is_empty() {
                return Err(CommandError::HaltCausePersists {
                    reason: HaltReason::Fault.into(),
                });
            }
            if let Some(halt) = self.config.assist.check(self.state.phase(), &sample, None) {
                return Err(CommandError::HaltCausePersists {
                    reason: halt.reason.into(),
                });
            }
        }
        if self.halt.set_low().is_err() {
            return Err(CommandError::HaltCausePersists {
                reason: HaltReason::Fault.into(),
            });
        }
        self.halt_asserted = false;
        self.faults = Faults::NONE;
        self.state.rearm();
        self.send_snapshot();
        self.send_status();
        Ok(())
    }

    /// Latch new faults, send a fault event, assert halt, send a status.
    /// `at` is the sample (index, position, force) that raised them.
    /// Returns whether a status was sent.
    #[inline]
    fn raise_at(&mut self, faults: Faults, at: (u32, Nanometres, MicroNewtons)) -> bool {
        let new = Faults(faults.0 & !self.faults.0);
        if new.is_empty() {
            return false;
        }
        self.latch(new, at);
        true
    }

    /// [`Self::raise_at`] with faults not yet latched: out of line, as
    /// rare as faults are.
    #[inline(never)]
    fn latch(&mut self, new: Faults, at: (u32, Nanometres, MicroNewtons)) {
        self.faults = self.faults.union(new);
        let fault = Event {
            index: at.0,
            kind: EventKind::Fault,
            x: at.1,
            force: at.2,
            confidence_permille: 1000,
        };
        self.send(&Frame::Event(fault.into()));
        self.assert_halt(Halt {
            index: at.0,
            reason: HaltReason::Fault,
            x: at.1,
            hold_x: at.1,
        });
        self.send_status();
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
        self.send(&Frame::Halt(why.into()));
    }

    fn send_status(&mut self) {
        let status = Status {
            protocol_version: PROTOCOL_VERSION,
            sample_rate_hz: self.config.velocity.sample_rate_hz,
            samples: self.samples,
            frames_dropped: self.frames_dropped,
            faults: self.faults.into(),
            halt: self.halt_asserted,
            streaming: self.streaming,
            next_command_seq: self.last_command.0.saturating_add(1),
            board: self.board,
            schema_key: SCHEMA_KEY,
        };
        self.send(&Frame::Status(status));
    }

    /// Send the configuration; batches from here on are checked with it.
    fn send_config(&mut self) {
        self.flush_batch();
        let frame = ConfigFrame {
            tissue: self.tissue,
            stored: self.stored,
            config: self.config,
        };
        let bytes = self.encoder.encode(&Frame::Config(frame));
        self.batch
            .set_seed(BatchCheck::seed(bytes.split_last().map_or(&[], |(_, b)| b)));
        deliver(&mut self.sink, &mut self.frames_dropped, bytes);
    }

    /// The pipeline's state, for a host to continue from (only while
    /// streaming: without samples it has nothing to continue).
    fn send_snapshot(&mut self) {
        if !self.streaming {
            return;
        }
        let snapshot = Snapshot {
            next_index: self.samples,
            state: self.state.clone(),
        };
        self.send(&Frame::Snapshot(snapshot));
    }

    /// Send the batch in hand, if any.
    fn flush_batch(&mut self) {
        if self.batch.is_empty() {
            return;
        }
        let bytes = self.encoder.encode(&Frame::Batch(self.batch.frame()));
        deliver(&mut self.sink, &mut self.frames_dropped, bytes);
        self.batch.clear();
    }

    /// Send one frame, after the batch in hand (so frames stay in sample
    /// order).
    fn send(&mut self, frame: &Frame<'_>) {
        self.flush_batch();
        let bytes = self.encoder.encode(frame);
        deliver(&mut self.sink, &mut self.frames_dropped, bytes);
    }
}

/// Encoded frame bytes to the sink; a frame that did not encode (empty) or
/// that the sink refused counts as dropped.
fn deliver<W: Write>(sink: &mut W, frames_dropped: &mut u32, bytes: &[u8]) {
    if bytes.is_empty() || sink.write_all(bytes).is_err() {
        *frames_dropped = frames_dropped.saturating_add(1);
    }
}
