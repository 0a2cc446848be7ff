//! The device on a serial port, for real: the CI board's firmware in QEMU
//! with its UART on a pseudo-terminal, opened through the `serialport`
//! crate like a `/dev/ttyACM0`. Every command goes to it, and each reply
//! and effect is checked in the frames that follow; `needle record` over
//! the port gives the trial CSV `needle decode --csv` gives on a capture
//! of the same replay. Nothing here skips itself.
//!
//! A test binary of its own: its devices run in real time and wait
//! seconds for a reply, which they would not get on cores the analyses'
//! tests keep busy beside them.

use std::path::{Path, PathBuf};
use std::process::Command as Process;
use std::time::{Duration, Instant};

use needle_analysis::sim::{self, Plan};
use needle_holder::assist::AssistModes;
use needle_holder::config::{DeviceConfig, TissueModel};
use needle_holder::insertion::HaltReason;
use needle_holder::model::params::{LIBRARY, LIVER1};
use needle_holder::protocol::wire::{Encoder, FRAME_CRC};
use needle_holder::protocol::{command, Command, CommandError, ConfigFrame, Status, TissueSource};
use needle_holder::units::Nanometres;
use needle_io::frames::{Item, Message};
use needle_io::link::Link;
use needle_qemu::firmware::{self, Board, QemuLive, Serial};

/// The devices here run in real time: one at a time, so that two QEMUs
/// (and their hosts) do not share the machine's cores and slow each
/// other's sample clocks.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn elf() -> PathBuf {
    firmware::ensure_qemu().expect("qemu-system-arm is needed and could not be installed");
    firmware::build(Board::Lm3s6965).expect("firmware build")
}

/// A replay of one insertion, its bridge `offset_counts` off zero.
fn replay_file(dir: &Path, plan: &Plan, offset_counts: i32) -> PathBuf {
    let (trial, _) = sim::insertion(&LIVER1, plan);
    let config = DeviceConfig::default();
    let cell = needle_holder::calibration::LoadCell {
        tare_counts: offset_counts,
        ..config.load_cell
    };
    let path = dir.join("insertion.replay");
    std::fs::write(
        &path,
        sim::to_replay(&trial, plan.rate_hz as u16, &cell, &config.encoder),
    )
    .unwrap();
    path
}

/// Read items until one matches, or fail after `within`. Every item read
/// is also kept in `SEEN` for checks that look back.
fn wait_for<T>(
    link: &mut Link,
    within: Duration,
    what: &str,
    mut pick: impl FnMut(&Item) -> Option<T>,
) -> T {
    let until = Instant::now() + within;
    while Instant::now() < until {
        let items = link.poll().unwrap();
        let mut found = None;
        for item in &items {
            if found.is_none() {
                found = pick(item);
            }
        }
        SEEN.with(|seen| seen.borrow_mut().extend(items));
        if let Some(found) = found {
            return found;
        }
    }
    panic!("no {what} within {within:?}")
}

thread_local! {
    static SEEN: std::cell::RefCell<Vec<Item>> = const { std::cell::RefCell::new(Vec::new()) };
}

fn next_config(link: &mut Link) -> ConfigFrame {
    wait_for(link, Duration::from_secs(3), "config frame", |i| match i {
        Item::Frame(Message::Config(c)) => Some(**c),
        _ => None,
    })
}

fn next_status(link: &mut Link) -> Status {
    wait_for(link, Duration::from_secs(3), "status frame", |i| match i {
        Item::Frame(Message::Status(s)) => Some(*s),
        _ => None,
    })
}

/// Send raw bytes as if they were a command; the reply to them.
fn raw_reply(link: &mut Link, bytes: &[u8]) -> Result<(), CommandError> {
    link.send_raw(bytes).unwrap();
    wait_for(link, Duration::from_secs(3), "reply", |i| match i {
        Item::Frame(Message::Reply(r)) => Some(r.result.clone()),
        _ => None,
    })
}

#[test]
fn every_command_over_a_pty_is_answered_and_takes_effect() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    // Contact 6.7 s in (20 mm of approach at 3 mm/s): time for the
    // commands before it on a loaded machine, with stop-on-contact set
    // well before the needle gets there.
    let plan = Plan {
        surface_x_m: 0.02,
        ..Plan::PAPER
    };
    let replay = replay_file(dir.path(), &plan, 3_000);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let mut link = Link::open(&device.port, 115_200).unwrap();

    // Read the configuration back (the device starts with this command).
    assert_eq!(link.command(Command::ReadConfig).unwrap(), Ok(()));
    let boot = next_config(&mut link);
    assert_eq!(boot.config, DeviceConfig::default());

    // Tare, with the needle still in the air: the zero moves to the
    // bridge's offset (3000 counts, 2 mN of noise on it).
    assert_eq!(link.command(Command::Tare).unwrap(), Ok(()));
    let tared = next_config(&mut link);
    let zero = tared.config.load_cell.tare_counts;
    assert!((zero - 3_000).abs() < 1_000, "{:?}", tared.config.load_cell);
    assert_eq!(tared.config.model, boot.config.model);

    // Stop on contact (6.7 s into the replay: set it early).
    let stop = command::set_assist(AssistModes::STOP_ON_CONTACT, Nanometres::from_m(0.03));
    assert_eq!(link.command(stop).unwrap(), Ok(()));
    assert_eq!(
        next_config(&mut link).config.assist.modes,
        AssistModes::STOP_ON_CONTACT
    );

    // Select from the library; upload a tissue.
    let liver2 = LIBRARY.iter().position(|(n, _)| *n == "liver2").unwrap() as u8;
    assert_eq!(link.command(Command::SelectTissue(liver2)).unwrap(), Ok(()));
    let selected = next_config(&mut link);
    assert_eq!(selected.tissue, TissueSource::Library(liver2));
    assert_eq!(
        selected.config.load_cell, tared.config.load_cell,
        "the tare stays"
    );
    assert_ne!(selected.config.model, tared.config.model);
    let liver1 = TissueModel::from_params(&LIVER1).unwrap();
    assert_eq!(link.command(Command::UploadTissue(liver1)).unwrap(), Ok(()));
    let uploaded = next_config(&mut link);
    assert_eq!(uploaded.tissue, TissueSource::Uploaded);
    assert_eq!(uploaded.config.model, boot.config.model);

    // Refused commands change nothing.
    // A tissue that fails the device's own check (the host converts
    // tissues to fixed point; the device trusts no conversion).
    let mut pulling = liver1;
    pulling.model.cutting = needle_holder::units::MicroNewtons(-1);
    match link.command(Command::UploadTissue(pulling)).unwrap() {
        Err(CommandError::InvalidTissue { field, .. }) => {
            assert_eq!(field.as_str(), "cutting_force_n")
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        link.command(Command::SelectTissue(200)).unwrap(),
        Err(CommandError::NoSuchTissue {
            library_len: LIBRARY.len() as u8
        })
    );
    let too_deep = command::set_assist(AssistModes::TARGET_DEPTH, Nanometres::from_m(0.5));
    assert!(matches!(
        link.command(too_deep).unwrap(),
        Err(CommandError::OutOfRange { .. })
    ));
    let unknown_mode = command::set_assist(AssistModes(0x80), Nanometres::from_m(0.01));
    assert!(matches!(
        link.command(unknown_mode).unwrap(),
        Err(CommandError::OutOfRange { .. })
    ));
    // Corrupted (a bit flipped), truncated, and unknown (right CRC,
    // bytes no command) frames.
    let mut encoder = Encoder::<256>::default();
    let good = encoder
        .encode(&needle_holder::protocol::CommandFrame {
            seq: 1 << 31,
            command: Command::Rearm,
        })
        .to_vec();
    let mut flipped = good.clone();
    flipped[3] ^= 0x10;
    assert_eq!(raw_reply(&mut link, &flipped), Err(CommandError::Corrupted));
    assert_eq!(
        raw_reply(&mut link, &[&good[..4], &[0][..]].concat()),
        Err(CommandError::Corrupted)
    );
    let mut junk = vec![0xee, 0xee, 0xee];
    junk.extend(needle_holder::protocol::wire::frame_check(&junk).to_le_bytes());
    let mut framed = cobs::encode_vec(&junk);
    framed.push(0);
    assert_eq!(raw_reply(&mut link, &framed), Err(CommandError::Unknown));
    // A frame of protocol 2's CRC (no implied version byte) is corrupted here.
    let mut v2 = vec![0x01, 0x05];
    v2.extend(FRAME_CRC.checksum(&v2).to_le_bytes());
    let mut framed = cobs::encode_vec(&v2);
    framed.push(0);
    assert_eq!(raw_reply(&mut link, &framed), Err(CommandError::Corrupted));
    assert_eq!(link.command(Command::ReadConfig).unwrap(), Ok(()));
    let after = next_config(&mut link);
    assert_eq!(
        (after.tissue, after.config),
        (uploaded.tissue, uploaded.config),
        "nothing changed"
    );

    // A replayed command: the same frame again is answered, not redone;
    // an older sequence number with other content is refused.
    let seq = link.next_seq().unwrap();
    let tare_again = encoder
        .encode(&needle_holder::protocol::CommandFrame {
            seq,
            command: Command::ReadConfig,
        })
        .to_vec();
    let configs = || {
        SEEN.with(|seen| {
            seen.borrow()
                .iter()
                .filter(|i| matches!(i, Item::Frame(Message::Config(_))))
                .count()
        })
    };
    let before = configs();
    assert_eq!(raw_reply(&mut link, &tare_again), Ok(()));
    assert_eq!(configs(), before + 1, "carried out: the configuration came");
    assert_eq!(raw_reply(&mut link, &tare_again), Ok(()));
    let redone = Instant::now() + Duration::from_millis(300);
    while Instant::now() < redone {
        let items = link.poll().unwrap();
        assert!(
            !items
                .iter()
                .any(|i| matches!(i, Item::Frame(Message::Config(_)))),
            "a repeat is not carried out again"
        );
    }
    assert_eq!(configs(), before + 1, "a repeat is not carried out again");
    let stale = encoder
        .encode(&needle_holder::protocol::CommandFrame {
            seq,
            command: Command::Tare,
        })
        .to_vec();
    assert_eq!(
        raw_reply(&mut link, &stale),
        Err(CommandError::Stale { next_seq: seq + 1 })
    );

    // The halt came at the contact (perhaps while the commands above
    // were answered).
    let seen_halt = SEEN.with(|seen| {
        seen.borrow().iter().find_map(|i| match i {
            Item::Frame(Message::Halt(h)) => Some(*h),
            _ => None,
        })
    });
    let halt = seen_halt.unwrap_or_else(|| {
        wait_for(&mut link, Duration::from_secs(10), "halt", |i| match i {
            Item::Frame(Message::Halt(h)) => Some(*h),
            _ => None,
        })
    });
    assert_eq!(halt.reason, HaltReason::Contact);
    assert!(next_status(&mut link).halt);
    // Stop at 1 mm past the surface: re-arming deeper than that is refused.
    let depth = command::set_assist(AssistModes::TARGET_DEPTH, Nanometres::from_m(0.001));
    assert_eq!(link.command(depth).unwrap(), Ok(()));
    // Wait for the needle to be 1.5 mm past where it halted (the surface
    // the device found, or deeper): past the 1 mm target.
    let past_target_m = halt.x.as_m() + 0.0015;
    wait_for(
        &mut link,
        Duration::from_secs(10),
        "a sample past the target depth",
        |i| match i {
            Item::Sample(s) if s.x.as_m() > past_target_m => Some(()),
            _ => None,
        },
    );
    assert_eq!(
        link.command(Command::Rearm).unwrap(),
        Err(CommandError::HaltCausePersists {
            reason: HaltReason::TargetDepth.into()
        })
    );
    assert!(next_status(&mut link).halt, "still halted");
    let none = command::set_assist(AssistModes::NONE, Nanometres::from_m(0.03));
    assert_eq!(link.command(none).unwrap(), Ok(()));
    assert_eq!(link.command(Command::Rearm).unwrap(), Ok(()));
    // The first status after the reply says released (an older heartbeat
    // may still be in hand).
    wait_for(
        &mut link,
        Duration::from_secs(3),
        "a released status",
        |i| match i {
            Item::Frame(Message::Status(s)) if !s.halt => Some(()),
            _ => None,
        },
    );

    // Stop the stream: status goes on, samples do not; start it again.
    assert_eq!(link.command(Command::Stream(false)).unwrap(), Ok(()));
    let stopped = wait_for(
        &mut link,
        Duration::from_secs(3),
        "a stopped status",
        |i| match i {
            Item::Frame(Message::Status(s)) if !s.streaming => Some(*s),
            _ => None,
        },
    );
    let mut samples_while_stopped = 0;
    let until = Instant::now() + Duration::from_millis(1200);
    while Instant::now() < until {
        samples_while_stopped += link
            .poll()
            .unwrap()
            .iter()
            .filter(|i| matches!(i, Item::Sample(_)))
            .count();
    }
    assert_eq!(samples_while_stopped, 0);
    assert_eq!(link.command(Command::Stream(true)).unwrap(), Ok(()));
    let sample = wait_for(&mut link, Duration::from_secs(2), "sample", |i| match i {
        Item::Sample(s) => Some(*s),
        _ => None,
    });
    assert!(sample.index > stopped.samples);
    let stats = link.decoder().stats();
    assert_eq!(
        stats.withheld_samples, 0,
        "every sample the device sent was reconstructed and checked"
    );
}

#[test]
fn needle_record_over_a_pty_gives_the_trial_csv_decode_gives_on_a_capture() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    // Past liver 1's 16.65 mm puncture depth, so the needle is inserted:
    // a capsule pushed 15 mm and drawn back again is never punctured.
    let plan = Plan {
        speed_mps: 0.01,
        depth_m: 0.02,
        dwell_s: 0.5,
        ..Plan::PAPER
    };
    let replay = replay_file(dir.path(), &plan, 0);
    let elf = elf();
    let needle = env!("CARGO_BIN_EXE_needle");

    // The capture: the same replay, frames to a file, as fast as QEMU goes.
    let capture = dir.path().join("capture.bin");
    let run = firmware::run_qemu(
        firmware::qemu_command(Board::Lm3s6965, &elf, &replay, Serial::File(&capture), &[]),
        Duration::from_secs(60),
    )
    .unwrap()
    .success()
    .unwrap();
    drop(run);
    let decoded = dir.path().join("decoded.csv");
    let status = Process::new(needle)
        .args(["decode", "--csv"])
        .arg(&decoded)
        .arg(&capture)
        .status()
        .unwrap();
    assert!(status.success());

    // Live on a pseudo-terminal, recorded.
    let device = QemuLive::start(Board::Lm3s6965, &elf, &replay).unwrap();
    let out = dir.path().join("recorded");
    let recorded = Process::new(needle)
        .args(["record", "--port", &device.port, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&recorded.stderr);
    assert!(recorded.status.success(), "{stderr}");
    device.wait(Duration::from_secs(30)).unwrap();

    let trial = std::fs::read_to_string(out.join("trial_000.csv")).unwrap();
    let whole = std::fs::read_to_string(&decoded).unwrap();
    assert!(
        whole.starts_with(&trial),
        "the recorded trial is the capture's first rows"
    );
    let trial_rows = trial.lines().count();
    let rest: Vec<&str> = whole.lines().skip(trial_rows).collect();
    // The trial ends where the needle left the tissue; what follows is out.
    assert!(trial.lines().last().unwrap().ends_with(",out"));
    assert!(trial.lines().any(|l| l.ends_with(",inserted")));
    assert!(
        rest.iter().all(|l| l.ends_with(",out")),
        "only samples outside follow"
    );
    assert!(!out.join("trial_001.csv").exists());
    // The raw stream is kept and decodes to the same samples.
    let kept = dir.path().join("kept.csv");
    let status = Process::new(needle)
        .args(["decode", "--csv"])
        .arg(&kept)
        .arg(out.join("stream.bin"))
        .status()
        .unwrap();
    assert!(status.success());
    assert!(std::fs::read_to_string(&kept).unwrap().starts_with(&trial));
    assert!(stderr.contains("trial_000.csv"), "{stderr}");
}

/// Bytes left on the line before a command, as `printf '\x01\x02' > P`
/// leaves them: the device reads them with the command's leading zero as
/// a corrupted frame, and answers `Corrupted` with sequence 0 just before
/// it reads and carries out the command itself.
fn stray_bytes(port: &str) {
    use std::io::Write;
    let mut pty = std::fs::OpenOptions::new().write(true).open(port).unwrap();
    pty.write_all(b"\x01\x02").unwrap();
}

/// `needle ARGS` against the device on `port`, after stray bytes: its
/// stdout, having asserted that it succeeded.
fn needle_after_stray_bytes(port: &str, args: &[&str]) -> String {
    stray_bytes(port);
    let out = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "needle {args:?}: {stderr}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn a_command_after_stray_bytes_is_reported_done_and_is_done() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let replay = replay_file(dir.path(), &Plan::PAPER, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let port = device.port.as_str();
    let device_args = |rest: &[&'static str]| -> Vec<&str> {
        let mut args = vec!["device", "--port", port];
        args.extend_from_slice(rest);
        args
    };
    for action in [
        &["tissue", "liver2"][..],
        &["assist", "puncture"],
        &["stream", "off"],
    ] {
        let stdout = needle_after_stray_bytes(port, &device_args(action));
        assert_eq!(stdout.trim(), "done", "{action:?}");
    }
    let config = needle_after_stray_bytes(port, &device_args(&["config"]));
    assert!(
        config.contains("tissue liver2") && config.contains("assist puncture"),
        "{config}"
    );
    // `needle record` starts the stream the same way.
    let out = dir.path().join("recorded");
    let out_arg = out.to_str().unwrap();
    needle_after_stray_bytes(
        port,
        &["record", "--port", port, "--seconds", "1", "--out", out_arg],
    );
    assert!(std::fs::metadata(out.join("stream.bin")).unwrap().len() > 0);
}

#[test]
fn needle_record_with_standard_error_full_records_all_the_same() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let plan = Plan {
        speed_mps: 0.01,
        depth_m: 0.015,
        dwell_s: 0.5,
        ..Plan::PAPER
    };
    let replay = replay_file(dir.path(), &plan, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let out = dir.path().join("recorded");
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let status = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args(["record", "--port", &device.port, "--out"])
        .arg(&out)
        .stderr(full)
        .status()
        .unwrap();
    assert!(status.success());
    let trial = std::fs::read_to_string(out.join("trial_000.csv")).unwrap();
    assert!(trial.lines().last().unwrap().ends_with(",out"));
    assert!(std::fs::metadata(out.join("stream.bin")).unwrap().len() > 0);
}

#[test]
fn a_second_needle_record_into_one_directory_is_refused_naming_the_first() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let replay = replay_file(dir.path(), &Plan::PAPER, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let out = dir.path().join("recorded");
    std::fs::create_dir(&out).unwrap();
    // The first recording's lock, as `needle record` takes it.
    let _first =
        needle_io::input::lock_output(&out, &out.join(".needle-record.lock"), "needle record")
            .unwrap();
    let second = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args(["record", "--port", &device.port, "--seconds", "2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{err}");
    let holder = format!("needle record (pid {}) is writing it", std::process::id());
    assert!(err.contains(&holder), "{err}");
    assert!(!out.join("stream.bin").exists(), "nothing written");
}

#[test]
fn a_recording_begun_inside_an_insertion_writes_no_fragment_as_a_trial() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let plan = Plan {
        speed_mps: 0.01,
        depth_m: 0.015,
        dwell_s: 0.5,
        ..Plan::PAPER
    };
    let replay = replay_file(dir.path(), &plan, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    {
        // The device samples from its first command; wait for the needle
        // in the tissue, then let go of the port.
        let mut link = Link::open(&device.port, 115_200).unwrap();
        assert_eq!(link.command(Command::Stream(true)).unwrap(), Ok(()));
        wait_for(&mut link, Duration::from_secs(20), "loading", |i| match i {
            Item::Sample(s) if s.phase == needle_holder::insertion::Phase::Loading => Some(()),
            _ => None,
        });
    }
    let out = dir.path().join("recorded");
    let recorded = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args(["record", "--port", &device.port, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&recorded.stderr);
    assert!(recorded.status.success(), "{err}");
    assert!(
        err.contains("insertion under way when the recording began"),
        "{err}"
    );
    assert!(!out.join("trial_000.csv").exists(), "{err}");
    assert!(std::fs::metadata(out.join("stream.bin")).unwrap().len() > 0);
}

#[test]
fn a_device_that_goes_away_mid_insertion_ends_the_trial_saying_so() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (device, out, mut record, lines) = recording_paper(dir.path());
    // The device goes away (QEMU killed: its pseudo-terminal closes).
    drop(device);
    let status = wait_timeout::ChildExt::wait_timeout(&mut record, Duration::from_secs(20))
        .unwrap()
        .expect("needle record stops when the device goes away");
    let rest: Vec<String> = lines.iter().collect();
    assert!(status.success(), "{rest:?}");
    assert!(
        rest.iter().any(|l| l.contains("the device went away")),
        "{rest:?}"
    );
    assert!(
        rest.iter()
            .any(|l| l.contains("trial_000.csv") && l.contains("(the device went away)")),
        "{rest:?}"
    );
    assert!(out.join("trial_000.csv").exists());
}

/// A live device replaying the paper's insertion from `dir`, and `needle
/// record` from it into `dir/recorded` ([`record_until_loading`]): the
/// device, the output directory, the recording and its lines.
fn recording_paper(
    dir: &Path,
) -> (
    QemuLive,
    PathBuf,
    std::process::Child,
    std::sync::mpsc::Receiver<String>,
) {
    let replay = replay_file(dir, &Plan::PAPER, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let out = dir.join("recorded");
    let (record, lines) = record_until_loading(&device.port, &out);
    (device, out, record, lines)
}

/// `needle record` from `port` into `out`, once its progress line says the
/// needle is in the tissue (loading); its standard error's lines go on
/// arriving on the receiver.
fn record_until_loading(
    port: &str,
    out: &Path,
) -> (std::process::Child, std::sync::mpsc::Receiver<String>) {
    let mut record = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args(["record", "--port", port, "--out"])
        .arg(out)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let lines = collect_lines(record.stderr.take().unwrap());
    let mut seen = Vec::new();
    let until = Instant::now() + Duration::from_secs(60);
    while !seen.iter().any(|l: &String| l.ends_with("loading")) {
        assert!(Instant::now() < until, "never loading: {seen:?}");
        if let Ok(line) = lines.recv_timeout(Duration::from_secs(1)) {
            seen.push(line);
        }
    }
    (record, lines)
}

/// The lines of `stderr` read so far, collected by a thread.
fn collect_lines(stderr: impl std::io::Read + Send + 'static) -> std::sync::mpsc::Receiver<String> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut reader = std::io::BufReader::new(stderr);
        let mut buf = Vec::new();
        // Progress lines end in a carriage return, messages in a newline.
        loop {
            buf.clear();
            let mut byte = [0u8];
            loop {
                match std::io::Read::read(&mut reader, &mut byte) {
                    Ok(1) if byte[0] != b'\r' && byte[0] != b'\n' => buf.push(byte[0]),
                    Ok(1) => break,
                    _ => return,
                }
            }
            if tx.send(String::from_utf8_lossy(&buf).into_owned()).is_err() {
                return;
            }
        }
    });
    rx
}

#[test]
fn ctrl_c_sigterm_and_sighup_stop_needle_record_with_the_stream_and_trial_whole() {
    for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        let _alone = one_at_a_time();
        let dir = tempfile::tempdir().unwrap();
        let (device, out, mut record, lines) = recording_paper(dir.path());
        // The raw stream is on disk while the recording runs.
        let streamed = std::fs::metadata(out.join("stream.bin")).unwrap().len();
        assert!(streamed > 0, "stream.bin is written as it arrives");
        // SAFETY: kill(2) on our own child's pid.
        assert_eq!(unsafe { libc::kill(record.id() as i32, signal) }, 0);
        let status = wait_timeout::ChildExt::wait_timeout(&mut record, Duration::from_secs(20))
            .unwrap()
            .expect("needle record stops at the signal");
        let rest: Vec<String> = lines.iter().collect();
        assert!(status.success(), "signal {signal}: {rest:?}");
        let trial = std::fs::read_to_string(out.join("trial_000.csv")).unwrap();
        assert!(trial.ends_with('\n'), "the trial ends with a whole row");
        let widths: Vec<usize> = trial.lines().map(|l| l.split(',').count()).collect();
        assert!(widths.iter().all(|&w| w == widths[0]), "every row whole");
        assert!(trial.lines().any(|r| r.ends_with(",loading")));
        assert!(!out.join("trial_000.csv.part").exists());
        // The kept stream decodes to the trial's rows, and more.
        let kept = dir.path().join("kept.csv");
        let decoded = Process::new(env!("CARGO_BIN_EXE_needle"))
            .args(["decode", "--csv"])
            .arg(&kept)
            .arg(out.join("stream.bin"))
            .output()
            .unwrap();
        assert!(decoded.status.success());
        assert!(std::fs::read_to_string(&kept).unwrap().starts_with(&trial));
        drop(device);
    }
}

#[test]
fn garbage_from_the_host_does_not_disturb_the_samples() {
    let _alone = one_at_a_time();
    // A host that sends garbage continuously. In QEMU
    // the device's clock is real time, so the stream's completeness is
    // what can be checked: 2 s of random bytes at full speed while it
    // samples at 500 Hz, and not one sample lost.
    use rand::{Rng, SeedableRng};
    let dir = tempfile::tempdir().unwrap();
    let replay = replay_file(dir.path(), &Plan::PAPER, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let mut link = Link::open(&device.port, 115_200).unwrap();
    assert_eq!(link.command(Command::ReadConfig).unwrap(), Ok(()));
    let mut rng = rand::rngs::StdRng::seed_from_u64(19);
    let mut garbage = vec![0u8; 512];
    let (mut first, mut last, mut corrupted_replies) = (None, 0u32, 0);
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(2) {
        rng.fill(&mut garbage[..]);
        // As fast as the line takes it: a write that times out means the
        // pseudo-terminal is full (QEMU reads what the guest drains).
        let _ = link.send_raw(&garbage);
        for item in link.poll().unwrap() {
            match item {
                Item::Sample(s) => {
                    first.get_or_insert(s.index);
                    last = s.index;
                }
                Item::Frame(Message::Reply(r)) if r.result == Err(CommandError::Corrupted) => {
                    corrupted_replies += 1
                }
                _ => {}
            }
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    let stats = link.decoder().stats();
    let samples = last - first.expect("samples arrived");
    let rate = f64::from(samples) / elapsed;
    println!(
        "flooded for {elapsed:.2} s: {samples} samples ({rate:.0}/s), {corrupted_replies} garbage frames refused, {} lost, {} withheld",
        stats.lost_samples, stats.withheld_samples
    );
    // The rate is printed, not asserted: QEMU's clock is real time on a
    // shared machine. What must hold is that sampling went on.
    assert!(samples > 100, "{samples} samples while flooded");
    assert_eq!(
        (stats.lost_samples, stats.withheld_samples),
        (0, 0),
        "no sample lost or withheld"
    );
    assert!(corrupted_replies > 0, "the garbage was read and refused");
}

/// The first line of `record`'s standard error that says it asked for
/// the stream again, within 30 s, and the lines before it.
fn asked_again(lines: &std::sync::mpsc::Receiver<String>) -> (String, Vec<String>) {
    let until = Instant::now() + Duration::from_secs(30);
    let mut seen = Vec::new();
    loop {
        assert!(Instant::now() < until, "record never asked: {seen:?}");
        if let Ok(line) = lines.recv_timeout(Duration::from_millis(200)) {
            if line.contains("the device's stream is off") {
                let refused = line.contains("refused") || line.contains("no answer");
                assert!(line.contains("asked for it again") && !refused, "{line}");
                return (line, seen);
            }
            seen.push(line);
        }
    }
}

/// Samples arrive again (`stream.bin` grows by more than heartbeats
/// would), and `record` stops whole at Ctrl-C.
fn streams_on_then_stops(out: &Path, mut record: std::process::Child) {
    let before = std::fs::metadata(out.join("stream.bin")).unwrap().len();
    std::thread::sleep(Duration::from_secs(2));
    let after = std::fs::metadata(out.join("stream.bin")).unwrap().len();
    assert!(after > before + 2000, "{before} -> {after} bytes");
    // SAFETY: kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(record.id() as i32, libc::SIGINT) }, 0);
    let status = wait_timeout::ChildExt::wait_timeout(&mut record, Duration::from_secs(20))
        .unwrap()
        .expect("needle record stops at the signal");
    assert!(status.success());
}

#[test]
fn needle_record_asks_for_the_stream_again_when_it_stops() {
    // A device whose stream went off left `needle record`
    // waiting forever in silence. Here another program turns the stream
    // off mid-insertion.
    use std::io::Write;
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (device, out, record, lines) = recording_paper(dir.path());
    let off = Encoder::<256>::default()
        .encode(&needle_holder::protocol::CommandFrame {
            seq: 3 << 29,
            command: Command::Stream(false),
        })
        .to_vec();
    let mut pty = std::fs::OpenOptions::new()
        .write(true)
        .open(&device.port)
        .unwrap();
    pty.write_all(&[&[0][..], &off].concat()).unwrap();
    asked_again(&lines);
    streams_on_then_stops(&out, record);
    drop(device);
}

#[test]
fn needle_record_goes_on_after_the_device_is_reset() {
    // After a reset the device (a live replay waits for
    // its host's first command, as at power-on) sent nothing, and `needle
    // record` waited forever in silence.
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (device, out, record, lines) = recording_paper(dir.path());
    device.reset().unwrap();
    let (_, before) = asked_again(&lines);
    assert!(
        before.iter().any(|l| l.contains("nothing from the device")),
        "{before:?}"
    );
    streams_on_then_stops(&out, record);
    drop(device);
}

/// A replay of `seconds` at rest at 500 Hz, unloaded for the first
/// `loaded_from_s` and 0.5 N on the cell after, with a little noise on it
/// (a pattern of mean 0.4 mN).
fn hung_mass_replay(dir: &Path, seconds: usize, loaded_from_s: usize) -> PathBuf {
    let rate_hz = 500u16;
    let n = seconds * usize::from(rate_hz);
    let loaded_from = loaded_from_s * usize::from(rate_hz);
    let trial = needle_io::trial::Trial {
        t_s: (0..n).map(|i| i as f64 / f64::from(rate_hz)).collect(),
        x_m: vec![0.0; n],
        f_n: (0..n)
            .map(|i| if i < loaded_from { 0.0 } else { 0.5 } + 2e-4 * ((i * 7) % 5) as f64)
            .collect(),
    };
    let config = DeviceConfig::default();
    let replay = dir.join("hung_mass.replay");
    std::fs::write(
        &replay,
        sim::to_replay(&trial, rate_hz, &config.load_cell, &config.encoder),
    )
    .unwrap();
    replay
}

#[test]
fn needle_device_calibrate_sets_the_gain_that_reads_the_mass_and_the_device_keeps_it() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    // 20 s at rest with 0.5 N on the cell: a 100 g mass (0.981 N) on a
    // cell whose gain is half what it should be.
    let replay = hung_mass_replay(dir.path(), 20, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let port = device.port.as_str();
    let out = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args([
            "device",
            "--port",
            port,
            "calibrate",
            "--mass-g",
            "100",
            "--loaded",
            "--seconds",
            "1",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("gain 1.192093 → 2.3"), "{stdout}");
    // The device now reads the mass's weight, and says so in its config.
    let mut link = Link::open(port, 115_200).unwrap();
    assert_eq!(link.command(Command::ReadConfig).unwrap(), Ok(()));
    let gain_q16 = next_config(&mut link).config.load_cell.gain_q16;
    // The mean load: 0.5 N plus the noise pattern's mean, 0.4 mN.
    let expected = 78_125.0 * 0.1 * 9.806_65 / 0.5004;
    assert!(
        (f64::from(gain_q16) / expected - 1.0).abs() < 1e-4,
        "{gain_q16} vs {expected}"
    );
    let force_n = wait_for(&mut link, Duration::from_secs(3), "sample", |i| match i {
        Item::Sample(s) => Some(s.force.as_n()),
        _ => None,
    });
    assert!((force_n - 0.980_665).abs() < 2e-3, "{force_n} N");
}

#[test]
fn needle_device_calibrate_asks_tares_and_measures_only_once_the_mass_hangs() {
    use std::io::Write;
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    // 2 s unloaded, then 0.5 N: the samples from before the second
    // answer (unloaded, streamed while the person was hanging the mass)
    // must not enter the measurement.
    let replay = hung_mass_replay(dir.path(), 30, 2);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let mut calibrate = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args([
            "device",
            "--port",
            &device.port,
            "calibrate",
            "--mass-g",
            "100",
            "--seconds",
            "1",
        ])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut answer = calibrate.stdin.take().unwrap();
    // Unloaded: Enter at once (the tare); the mass hangs from 2 s on;
    // Enter again at 5 s.
    answer.write_all(b"\n").unwrap();
    std::thread::sleep(Duration::from_secs(5));
    // (A needle that stopped already is reported below, with its words.)
    let _ = answer.write_all(b"\n");
    drop(answer);
    let out = calibrate.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("Take every load off") && stderr.contains("Hang the 100 g"),
        "{stderr}"
    );
    // Only loaded samples: 0.5 N (the noise's mean, 0.4 mN, the tare
    // took away for the most part); a mean with unloaded samples in it
    // would be far less, with a spread of tenths of a newton.
    let read = |after: &str| -> f64 {
        let at = stdout.find(after).expect(after) + after.len();
        stdout[at..]
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    assert!((read("mass read ") - 0.5).abs() < 1e-3, "{stdout}");
    assert!(read("N ± ") < 1e-3, "{stdout}");
}

#[test]
fn needle_device_selftest_reads_the_boards_checklist() {
    let _alone = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let replay = replay_file(dir.path(), &Plan::PAPER, 0);
    let device = QemuLive::start(Board::Lm3s6965, &elf(), &replay).unwrap();
    let out = Process::new(env!("CARGO_BIN_EXE_needle"))
        .args(["device", "--port", &device.port, "selftest"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The CI board replays: no converter to read, its rate as configured,
    // its encoder where the replay starts, nothing failed.
    for line in [
        "converter registers not read (a replay board",
        "configured 500 a second)",
        "encoder count",
        "ok   halt line released (no fault)",
        "link since boot: 0 receive errors; 0 conversions lost",
    ] {
        assert!(stdout.contains(line), "{line:?} in {stdout}");
    }
}
