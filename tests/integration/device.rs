//! The device loop against mocked hardware: halt line transactions, frame
//! loss accounting, and no panic for any input.

use embedded_hal_mock::eh1::digital::{Mock as PinMock, State, Transaction};
use needle_holder::config::DeviceConfig;
use needle_holder::device::Device;
use needle_holder::faults::Faults;
use needle_holder::hal::{AdcSample, EncoderCounter, LoadCellAdc};
use needle_holder::pipeline::{PipelineState, RawSample};
use needle_holder::protocol::{self, Frame};
use needle_holder::replay;
use proptest::prelude::*;

struct Adc(Result<AdcSample, ()>);
impl LoadCellAdc for Adc {
    type Error = ();
    fn read(&mut self) -> Result<AdcSample, ()> {
        self.0
    }
}

struct Enc(u16);
impl EncoderCounter for Enc {
    fn count(&mut self) -> u16 {
        self.0
    }
}

fn ok(counts: i32) -> Adc {
    Adc(Ok(AdcSample {
        counts,
        saturated: false,
        overrun: false,
    }))
}

fn frames(bytes: &[u8]) -> Vec<Frame<'static>> {
    chunks(bytes).into_iter().map(|(frame, _)| frame).collect()
}

/// Each frame with its bytes as received.
fn chunks(bytes: &[u8]) -> Vec<(Frame<'static>, &[u8])> {
    bytes
        .split(|&b| b == 0)
        .filter(|chunk| !chunk.is_empty())
        .map(|chunk| {
            // Leaked: a batch borrows its bytes, and these are tests.
            let buffer = Box::leak(vec![0u8; protocol::MAX_ENCODED_FRAME].into_boxed_slice());
            (protocol::decode(chunk, buffer).expect("valid frame"), chunk)
        })
        .collect()
}

/// The samples of a stream, through the core's reconstruction.
fn samples(bytes: &[u8]) -> Vec<needle_holder::insertion::Sample> {
    let mut reconstructor = needle_holder::stream::Reconstructor::default();
    let mut out = Vec::new();
    for (frame, chunk) in chunks(bytes) {
        match &frame {
            Frame::Config(c) => reconstructor.config_frame(c, chunk),
            Frame::Snapshot(s) => reconstructor.snapshot(s.clone()),
            Frame::Batch(b) => {
                let _ = reconstructor.batch(b, |s| out.push(s));
            }
            _ => {}
        }
    }
    out
}

#[test]
fn halt_is_released_at_start_and_asserted_once_on_the_first_fault() {
    let mut pin = PinMock::new(&[Transaction::set(State::Low), Transaction::set(State::High)]);
    let mut sink = Vec::new();
    let mut device = Device::new(DeviceConfig::default(), &mut sink, pin.clone());
    device.tick(&mut ok(0), &mut Enc(0));
    device.tick(&mut Adc(Err(())), &mut Enc(1));
    // A second, different fault keeps the (already asserted) line as it is.
    device.tick(&mut ok(0), &mut Enc(30_000));
    let summary = device.finish();
    assert!(summary.halt);
    assert_eq!(
        summary.faults,
        Faults::ADC_ERROR.union(Faults::ENCODER_JUMP)
    );
    pin.done();
}

#[test]
fn a_fault_sends_an_event_a_halt_and_a_status_right_away() {
    let mut sink = Vec::new();
    let mut pin = PinMock::new(&[Transaction::set(State::Low), Transaction::set(State::High)]);
    let mut device = Device::new(DeviceConfig::default(), &mut sink, pin.clone());
    device.tick(
        &mut Adc(Ok(AdcSample {
            counts: 1 << 23,
            saturated: true,
            overrun: false,
        })),
        &mut Enc(0),
    );
    drop(device);
    pin.done();
    let frames = frames(&sink);
    assert!(matches!(frames[0], Frame::Header(_)));
    assert!(matches!(frames[1], Frame::Config(_)));
    assert!(matches!(frames[2], Frame::Snapshot(_)));
    // The batch in hand goes first, so frames stay in sample order.
    assert!(matches!(frames[3], Frame::Batch(b) if b.first_index == 0 && b.samples == 1));
    assert!(matches!(frames[4], Frame::Event(e) if e.kind == protocol::EventKind::Fault));
    assert!(
        matches!(frames[5], Frame::Halt(h) if h.reason == protocol::HaltReason::Fault && h.index == 0)
    );
    assert!(
        matches!(frames[6], Frame::Status(s) if s.halt && Faults::from(s.faults).contains(Faults::ADC_SATURATED))
    );
}

/// A sink that refuses writes while told to, like a full TX queue.
struct Flaky {
    refuse: std::rc::Rc<std::cell::Cell<bool>>,
    accepted: Vec<u8>,
}
impl embedded_io::ErrorType for Flaky {
    type Error = embedded_io::ErrorKind;
}
impl embedded_io::Write for Flaky {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        if self.refuse.get() {
            return Err(embedded_io::ErrorKind::Other);
        }
        self.accepted.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[test]
fn a_refused_batch_is_counted_and_samples_resume_at_the_next_snapshot() {
    let refuse = std::rc::Rc::new(std::cell::Cell::new(false));
    let mut sink = Flaky {
        refuse: refuse.clone(),
        accepted: Vec::new(),
    };
    let mut pin = PinMock::new(&[Transaction::set(State::Low)]);
    let mut device = Device::new(DeviceConfig::default(), &mut sink, pin.clone());
    for i in 0..300 {
        // The second batch (samples 25..50) goes out on sample 49's tick.
        refuse.set(i == 49);
        device.tick(&mut ok(0), &mut Enc(i));
    }
    refuse.set(false);
    let summary = device.finish();
    pin.done();
    assert_eq!(summary.frames_dropped, 1);
    let indices: Vec<u32> = samples(&sink.accepted).iter().map(|s| s.index).collect();
    // The lost batch, and the rest until the snapshot at 250, are not
    // given: the host cannot know the state they start from.
    assert_eq!(indices, (0..25).chain(250..300).collect::<Vec<_>>());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any readings, including errors, saturation and wild encoder
    /// values: no panic, indices count up, and from the first fault on no
    /// event fires.
    #[test]
    fn the_pipeline_never_panics_and_faulty_samples_fire_no_events(
        samples in prop::collection::vec((any::<Option<i32>>(), any::<bool>(), any::<bool>(), any::<u16>()), 1..400)
    ) {
        let config = DeviceConfig::default();
        let mut state = PipelineState::default();
        let mut seen = Faults::NONE;
        for (i, (counts, saturated, overrun, encoder_count)) in samples.into_iter().enumerate() {
            let adc = counts.map(|counts| AdcSample { counts, saturated, overrun });
            let out = config.step(&mut state, RawSample { adc, encoder_count });
            prop_assert_eq!(out.sample.index, i as u32);
            prop_assert_eq!(out.sample.residual, out.sample.force.sub(out.sample.model));
            seen = seen.union(out.faults);
            if !seen.is_empty() {
                prop_assert!(out.event.is_none());
            }
        }
    }

    /// Any bytes as a replay file: no panic, and anything that is not a
    /// whole number of records after a valid header raises a fault.
    #[test]
    fn any_replay_bytes_run_without_panic(bytes in prop::collection::vec(any::<u8>(), 0..2000)) {
        let mut sink = Vec::new();
        let mut halt = RecordingPin::default();
        let summary = replay::run(bytes.as_slice(), DeviceConfig::default(), &mut sink, &mut halt);
        let valid_header = bytes.len() >= 8 && replay::ReplayHeader::parse(bytes[..8].try_into().unwrap()).is_some();
        if !valid_header {
            prop_assert!(summary.faults.contains(Faults::REPLAY_BAD_HEADER));
        } else if (bytes.len() - 8) % 6 != 0 {
            prop_assert!(summary.faults.contains(Faults::REPLAY_TRUNCATED));
        }
        prop_assert_eq!(summary.halt, !summary.faults.is_empty());
        prop_assert_eq!(halt.high, summary.halt);
    }
}

/// A pin for random input, whose transactions cannot be listed in advance.
#[derive(Default)]
struct RecordingPin {
    high: bool,
}
impl embedded_hal::digital::ErrorType for RecordingPin {
    type Error = core::convert::Infallible;
}
impl embedded_hal::digital::OutputPin for RecordingPin {
    fn set_high(&mut self) -> Result<(), Self::Error> {
        self.high = true;
        Ok(())
    }
    fn set_low(&mut self) -> Result<(), Self::Error> {
        self.high = false;
        Ok(())
    }
}

type Shared = std::rc::Rc<std::cell::RefCell<Vec<u8>>>;

/// A sink whose bytes the test can still read while the device owns it.
struct SharedSink(Shared);
impl embedded_io::ErrorType for SharedSink {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for SharedSink {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.borrow_mut().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Halt pin that notes how many bytes had been sent when it went up.
struct NotingPin(Shared, std::rc::Rc<std::cell::Cell<Option<usize>>>);
impl embedded_hal::digital::ErrorType for NotingPin {
    type Error = core::convert::Infallible;
}
impl embedded_hal::digital::OutputPin for NotingPin {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Self::Error> {
        self.1.set(Some(self.0.borrow().len()));
        Ok(())
    }
}

/// Stop on puncture with back-off: the line goes up in the tick that
/// flags the puncture (right after its event frame), and the halt frame
/// asks the robot to hold x_s2 − x_s3 = (1 − ρ)(x_s2 − x_s1) behind the tip.
#[test]
fn stop_on_puncture_halts_in_the_same_sample_and_asks_for_the_back_off() {
    use needle_holder::assist::AssistModes;
    use needle_holder::model::params::LIVER1;
    use needle_holder::protocol::{EventKind, HaltReason};
    use needle_holder::units::MicroNewtons;
    let config = DeviceConfig::default()
        .with_assist(AssistModes::STOP_ON_PUNCTURE.union(AssistModes::BACK_OFF));
    let bytes = Shared::default();
    let high_at = std::rc::Rc::new(std::cell::Cell::new(None));
    let pin = NotingPin(bytes.clone(), high_at.clone());
    let mut device = Device::new(config, SharedSink(bytes.clone()), pin);
    // Liver 1 at 3 mm/s, 500 Hz, no noise: contact at 5 mm.
    for i in 0..4000u32 {
        let x_m = f64::from(i) * 6e-6;
        let d = x_m - 0.005;
        let f = if d >= LIVER1.puncture_depth_m {
            1.0
        } else {
            LIVER1.stiffness_n(d)
        };
        let mut adc = ok(config.load_cell.counts_for(MicroNewtons::from_n(f)));
        device.tick(&mut adc, &mut Enc((x_m * 1e6).round() as u16));
    }
    let high_at = high_at.get().expect("halt asserted");
    let bytes = bytes.borrow();
    let (before, after) = (frames(&bytes[..high_at]), frames(&bytes[high_at..]));
    let Some(Frame::Event(puncture)) = before.last() else {
        panic!("the puncture event goes out just before the line goes up")
    };
    assert_eq!(puncture.kind, EventKind::Puncture);
    let Some(Frame::Halt(halt)) = after.first() else {
        panic!("a halt frame follows: {:?}", after.first())
    };
    assert_eq!(halt.reason, HaltReason::Puncture);
    assert_eq!(halt.index, puncture.index);
    let contact = before.iter().find_map(|f| match f {
        Frame::Event(e) if e.kind == EventKind::Contact => Some(*e),
        _ => None,
    });
    let m = |x: needle_wire::Nanometres| needle_holder::units::Nanometres::from(x).as_m();
    let (x_s1, x_s2) = (m(contact.unwrap().x), m(puncture.x));
    let back_off = m(halt.x) - m(halt.hold_x);
    let expected = (1.0 - LIVER1.relaxation) * (x_s2 - x_s1);
    assert!(
        (back_off - expected).abs() < 1e-6,
        "{back_off} vs {expected}"
    );
    assert!((expected - 0.5 * 0.01665).abs() < 2e-4, "{expected}");
}

/// A command's frame as the host sends it.
fn command_bytes(seq: u32, command: protocol::Command) -> Vec<u8> {
    let mut encoder =
        protocol::wire::Encoder::<{ protocol::command::MAX_ENCODED_COMMAND }>::default();
    encoder
        .encode(&protocol::CommandFrame { seq, command })
        .to_vec()
}

#[test]
fn settings_changed_by_a_command_are_handed_out_once_and_restore_the_same_configuration() {
    use needle_holder::assist::AssistModes;
    use needle_holder::persist::{self, Loaded};
    use needle_holder::units::Nanometres;
    let mut sink = Vec::new();
    let mut device = Device::new(DeviceConfig::default(), &mut sink, RecordingPin::default());
    assert_eq!(device.settings_to_save(), None, "nothing changed yet");
    device.receive(&command_bytes(1, protocol::Command::SelectTissue(3)));
    device.receive(&command_bytes(
        2,
        protocol::Command::SetAssist {
            modes: AssistModes::STOP_ON_PUNCTURE.into(),
            target_depth: Nanometres(12_000_000).into(),
        },
    ));
    // A refused command changes nothing to keep.
    device.receive(&command_bytes(3, protocol::Command::SelectTissue(200)));
    let settings = device.settings_to_save().expect("settings to keep");
    assert_eq!(device.settings_to_save(), None, "handed out once");
    let mut buf = [0u8; persist::MAX_RECORD];
    let mut region = vec![0xFF; 4096];
    let record = persist::record(&settings, &mut buf);
    region[..record.len()].copy_from_slice(record);
    let loaded = persist::load(&region);
    assert_eq!(loaded.loaded, Loaded::Saved);
    let restored = loaded
        .settings
        .unwrap()
        .applied_to(&DeviceConfig::default());
    assert_eq!(&restored, device.config());
}

proptest! {
    /// Any bytes in the settings sector: no panic.
    #[test]
    fn any_sector_contents_load_without_panic(bytes in prop::collection::vec(any::<u8>(), 0..1500)) {
        let _ = needle_holder::persist::load(&bytes);
    }
}

/// Settings a command could give: library entry `i`, assist bits, a depth.
fn settings(i: u8, modes: u8, depth_mm: i32) -> needle_holder::persist::Settings {
    use needle_holder::config::LIBRARY_MODELS;
    let i = i % LIBRARY_MODELS.len() as u8;
    needle_holder::persist::Settings {
        tissue: protocol::TissueSource::Library(i),
        model: LIBRARY_MODELS[usize::from(i)],
        load_cell: needle_holder::calibration::LoadCell::TEN_NEWTON_24_BIT,
        assist_modes: needle_holder::assist::AssistModes(
            modes & needle_holder::assist::AssistModes::ALL.0,
        ),
        target_depth: needle_holder::units::Nanometres(1_000_000 * depth_mm.clamp(1, 100)),
    }
}

/// A sector of saved records, one of them perhaps damaged: settings come
/// only from a record whose CRC holds. Undamaged, the last record is
/// loaded; with a byte of the last one changed, never what it would have
/// read as — the one before it, or nothing. Both branches are counted.
#[test]
fn settings_come_only_from_a_record_whose_crc_holds() {
    use needle_holder::persist::{self, Loaded};
    use proptest::test_runner::Config;
    let (whole, damaged) = (std::cell::Cell::new(0u32), std::cell::Cell::new(0u32));
    let strategy = (
        prop::collection::vec((any::<u8>(), any::<u8>(), 1i32..100), 1..5),
        prop::option::of((any::<prop::sample::Index>(), 1u8..=255)),
    );
    // A fixed seed: the counts printed are the same on every run.
    let mut runner = proptest::test_runner::TestRunner::new_with_rng(
        Config {
            failure_persistence: None,
            ..Config::with_cases(400)
        },
        proptest::test_runner::TestRng::deterministic_rng(
            proptest::test_runner::RngAlgorithm::ChaCha,
        ),
    );
    runner
        .run(&strategy, |(records, damage)| {
            let written: Vec<_> = records.iter().map(|&(i, m, d)| settings(i, m, d)).collect();
            let mut region = vec![0xFFu8; 4096];
            let mut at = 0;
            let mut last_at = 0;
            for s in &written {
                let mut buf = [0u8; persist::MAX_RECORD];
                let r = persist::record(s, &mut buf);
                region[at..at + r.len()].copy_from_slice(r);
                last_at = at;
                at += r.len();
            }
            let Some((index, xor)) = damage else {
                let loaded = persist::load(&region);
                prop_assert_eq!(loaded.loaded, Loaded::Saved);
                prop_assert_eq!(loaded.settings, written.last().copied());
                whole.set(whole.get() + 1);
                return Ok(());
            };
            // The bytes the CRC covers (the format in `src/persist.rs`: an
            // 8-byte head with the body's length n at 4..6, the body, pad
            // to 4 bytes, the CRC over 0..8+n): a changed pad byte is no
            // damage to the record.
            let n = usize::from(u16::from_le_bytes([
                region[last_at + 4],
                region[last_at + 5],
            ]));
            let len = at - last_at;
            let covered: Vec<usize> = (0..8 + n).chain(len - 4..len).collect();
            let byte = last_at + covered[index.index(covered.len())];
            region[byte] ^= xor;
            let loaded = persist::load(&region);
            let before = written.len().checked_sub(2).map(|k| written[k]);
            prop_assert!(
                loaded.settings.is_none() || loaded.settings == before,
                "byte {} of the last record changed, loaded {:?}",
                byte - last_at,
                loaded.settings
            );
            damaged.set(damaged.get() + 1);
            Ok(())
        })
        .unwrap();
    let (whole, damaged) = (whole.get(), damaged.get());
    println!("settings sector: {whole} whole logs loaded their last record, {damaged} damaged ones did not");
    assert!(
        whole >= 100 && damaged >= 100,
        "{whole} whole, {damaged} damaged"
    );
}

/// What the sensors and a host can put to the device between two samples.
#[derive(Clone, Debug)]
enum Input {
    /// A reading: counts (or a bus error), saturated, overrun, encoder.
    Reading(Option<i32>, bool, bool, u16),
    /// Bytes on the command line, whatever they are.
    Bytes(Vec<u8>),
    /// A well-formed command: sequence number, which, a value, and for an
    /// upload a library tissue with one byte of its wire form changed.
    Command(u32, u8, i32, usize, usize, u8),
}

fn input() -> impl Strategy<Value = Input> {
    prop_oneof![
        8 => (any::<Option<i32>>(), any::<bool>(), any::<bool>(), any::<u16>())
            .prop_map(|(c, s, o, e)| Input::Reading(c, s, o, e)),
        1 => prop::collection::vec(any::<u8>(), 0..64).prop_map(Input::Bytes),
        2 => (any::<u32>(), 0u8..8, any::<i32>(), any::<usize>(), any::<usize>(), any::<u8>())
            .prop_map(|(q, w, v, t, at, b)| Input::Command(q, w, v, t, at, b)),
    ]
}

/// A well-formed command, an upload's tissue with one byte of its wire
/// form changed.
fn any_command(which: u8, value: i32, entry: usize, at: usize, byte: u8) -> protocol::Command {
    use needle_holder::config::{TissueModel, LIBRARY_MODELS};
    use protocol::Command;
    let base = LIBRARY_MODELS[entry % LIBRARY_MODELS.len()];
    let mut buf = [0u8; 512];
    let wire = postcard::to_slice(&base, &mut buf).unwrap();
    let at = at % wire.len();
    wire[at] = byte;
    let tissue: TissueModel = postcard::from_bytes(wire).unwrap_or(base);
    match which {
        0 => Command::Tare,
        1 => Command::SelectTissue(value as u8),
        2 => Command::UploadTissue(tissue),
        3 => Command::SetAssist {
            modes: needle_wire::AssistBits(value as u8),
            target_depth: needle_wire::Nanometres(value),
        },
        4 => Command::Rearm,
        5 => Command::Stream(value % 2 == 0),
        6 => Command::SetLoadCellGain(value),
        _ => Command::ReadConfig,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any readings (any counts, errors, saturation, overruns, any encoder
    /// count), garbage and well-formed commands (uploads of damaged
    /// tissues among them) in any order: no panic — in this debug build
    /// an overflow is a panic, so none wraps on the device either — and
    /// a sample for every tick.
    #[test]
    fn the_device_takes_any_readings_and_any_commands(inputs in prop::collection::vec(input(), 1..600)) {
        let mut sink = Vec::new();
        let mut device = Device::new(DeviceConfig::default(), &mut sink, RecordingPin::default());
        let mut ticks = 0u32;
        for input in inputs {
            match input {
                Input::Reading(counts, saturated, overrun, encoder) => {
                    let adc = counts.map(|counts| AdcSample { counts, saturated, overrun }).ok_or(());
                    device.tick(&mut Adc(adc), &mut Enc(encoder));
                    ticks += 1;
                }
                Input::Bytes(bytes) => device.receive(&bytes),
                Input::Command(q, w, v, t, at, b) => device.receive(&command_bytes(q, any_command(w, v, t, at, b))),
            }
            prop_assert!(device.config().tissue_model().check().is_ok(), "the device runs a tissue that fails its own check");
        }
        prop_assert_eq!(device.finish().samples, ticks);
    }
}

#[test]
fn only_a_halt_for_a_latched_fault_may_keep_the_watchdog_fed_without_samples() {
    let mut sink = Vec::new();
    let mut device = Device::new(DeviceConfig::default(), &mut sink, RecordingPin::default());
    device.tick(&mut ok(0), &mut Enc(0));
    assert!(!device.summary().halted_for_fault(), "running");
    // The reset the board's watchdog caused, raised at the next boot.
    device.raise(Faults::WATCHDOG_RESET);
    let summary = device.summary();
    assert!(summary.halt && summary.faults.contains(Faults::WATCHDOG_RESET));
    assert!(summary.halted_for_fault());
    // A good sample and a re-arm: running again, fed by samples only.
    device.tick(&mut ok(0), &mut Enc(0));
    device.receive(&command_bytes(1, protocol::Command::Rearm));
    let summary = device.summary();
    assert!(!summary.halt && summary.faults.is_empty(), "{summary:?}");
    assert!(!summary.halted_for_fault());
}

#[test]
fn a_gain_set_by_command_scales_the_force_is_kept_and_a_tiny_one_is_refused() {
    use needle_holder::persist;
    let mut sink = Vec::new();
    let mut device = Device::new(DeviceConfig::default(), &mut sink, RecordingPin::default());
    let before = device.config().load_cell;
    device.receive(&command_bytes(1, protocol::Command::SetLoadCellGain(655)));
    assert_eq!(
        device.config().load_cell,
        before,
        "refused: nothing changed"
    );
    assert_eq!(device.settings_to_save(), None);
    let doubled = 2 * before.gain_q16;
    device.receive(&command_bytes(
        2,
        protocol::Command::SetLoadCellGain(doubled),
    ));
    assert_eq!(device.config().load_cell.gain_q16, doubled);
    let settings = device.settings_to_save().expect("the gain is kept");
    assert_eq!(settings.load_cell.gain_q16, doubled);
    let mut buf = [0u8; persist::MAX_RECORD];
    assert!(!persist::record(&settings, &mut buf).is_empty());
    for _ in 0..500 {
        device.tick(&mut ok(1000), &mut Enc(0));
    }
    drop(device);
    let replies: Vec<_> = frames(&sink)
        .into_iter()
        .filter_map(|f| match f {
            Frame::Reply(r) => Some((r.seq, r.result.is_ok())),
            _ => None,
        })
        .collect();
    assert_eq!(replies, [(1, false), (2, true)]);
    let force = samples(&sink).last().unwrap().force;
    assert_eq!(
        force,
        DeviceConfig::default().load_cell.force(2000),
        "twice the gain"
    );
}

#[test]
fn faults_found_before_arming_never_release_the_halt_and_a_rearm_waits_for_a_sample() {
    use needle_holder::persist::Loaded;
    // The line is only ever driven high: never low, not for an instant.
    let mut pin = PinMock::new(&[Transaction::set(State::High)]);
    let mut sink = Vec::new();
    let mut device = Device::restored_with(
        DeviceConfig::default(),
        needle_holder::device::default_tissue(),
        Loaded::NotKept,
        Faults::WATCHDOG_RESET,
        &mut sink,
        pin.clone(),
    );
    let summary = device.summary();
    assert!(summary.halt && summary.faults == Faults::WATCHDOG_RESET);
    // No sample since the fault: its cause is not known to be gone.
    device.receive(&command_bytes(1, protocol::Command::Rearm));
    assert!(device.summary().halt, "refused without a sample");
    drop(device);
    pin.done();
    let refused = frames(&sink)
        .into_iter()
        .any(|f| matches!(f, Frame::Reply(r) if r.seq == 1 && r.result.is_err()));
    assert!(refused);

    // A converter that stopped after arming: the same until a sample.
    let mut sink = Vec::new();
    let mut device = Device::new(DeviceConfig::default(), &mut sink, RecordingPin::default());
    device.tick(&mut ok(0), &mut Enc(0));
    device.raise(Faults::ADC_TIMEOUT);
    device.receive(&command_bytes(1, protocol::Command::Rearm));
    assert!(device.summary().halt, "no sample since adc_timeout");
    device.tick(&mut ok(0), &mut Enc(0));
    device.receive(&command_bytes(2, protocol::Command::Rearm));
    assert!(!device.summary().halt, "a sample came: released");
}

#[test]
fn a_self_test_asked_again_with_the_same_frame_is_answered_again() {
    let mut sink = Vec::new();
    let mut device = Device::new(DeviceConfig::default(), &mut sink, RecordingPin::default());
    let ask = command_bytes(1, protocol::Command::SelfTest);
    device.receive(&ask);
    assert!(device.self_test_asked());
    assert!(!device.self_test_asked(), "taken once");
    // The reply (or the self-test frame) was lost: the host sends the
    // same frame again; it is not carried out twice, but answered.
    device.receive(&ask);
    assert!(device.self_test_asked());
}
