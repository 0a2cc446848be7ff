//! The firmware in QEMU and the core on the host, fed the same replay, must
//! send the same bytes. These tests build the firmware images and run QEMU
//! for real (installing it when missing); nothing here skips itself.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, OnceLock};
use std::time::Duration;

use needle_analysis::sim::{self, Plan};
use needle_holder::config::DeviceConfig;
use needle_holder::faults::Faults;
use needle_holder::insertion::{EventKind, HaltReason};
use needle_holder::model::params::LIVER1;
use needle_holder::protocol::Status;
use needle_holder::replay::{Record, ReplayHeader, OVERRUN_MARK};
use needle_holder::units::MicroNewtons;
use needle_io::frames::decode_all;
use needle_io::frames::Message as Frame;
use needle_io::twin;
use needle_qemu::firmware::{self, Board, Serial};

/// One firmware build per board per test run, and one at a time (cargo
/// serialises builds anyway; this keeps the output readable).
fn elf(board: Board) -> PathBuf {
    static BUILDS: OnceLock<Mutex<Vec<(Board, PathBuf)>>> = OnceLock::new();
    let mut builds = BUILDS.get_or_init(Default::default).lock().unwrap();
    if let Some((_, path)) = builds.iter().find(|(b, _)| *b == board) {
        return path.clone();
    }
    firmware::ensure_qemu().expect("qemu-system-arm is needed and could not be installed");
    let path = firmware::build(board).expect("firmware build");
    builds.push((board, path.clone()));
    path
}

struct Outcome {
    frames: Vec<u8>,
    defmt: Vec<u8>,
    exit_code: Option<i32>,
}

fn run_in_qemu(board: Board, replay: &[u8], name: &str) -> Outcome {
    let elf = elf(board);
    let dir = tempfile::tempdir().unwrap();
    let replay_path = dir.path().join(format!("{name}.replay"));
    let frames_path = dir.path().join(format!("{name}.frames"));
    std::fs::write(&replay_path, replay).unwrap();
    let cmd = firmware::qemu_command(board, &elf, &replay_path, Serial::File(&frames_path), &[]);
    let run = firmware::run_qemu(cmd, Duration::from_secs(120)).expect("QEMU run");
    Outcome {
        frames: std::fs::read(&frames_path).unwrap_or_default(),
        defmt: run.defmt,
        exit_code: run.status.code(),
    }
}

fn liver_replay(noise_n: f64, seed: u64) -> Vec<u8> {
    let plan = Plan {
        noise_n,
        seed,
        ..Plan::PAPER
    };
    let (trial, _) = sim::insertion(&LIVER1, &plan);
    let config = DeviceConfig::default();
    sim::to_replay(&trial, 500, &config.load_cell, &config.encoder)
}

/// Index of the first differing byte, for a readable failure.
fn first_difference(a: &[u8], b: &[u8]) -> Option<usize> {
    a.iter()
        .zip(b)
        .position(|(x, y)| x != y)
        .or((a.len() != b.len()).then(|| a.len().min(b.len())))
}

fn assert_twin(board: Board, replay: &[u8], name: &str) -> (Outcome, twin::TwinRun) {
    let qemu = run_in_qemu(board, replay, name);
    assert_eq!(
        qemu.exit_code,
        Some(0),
        "{name} on {board:?}: firmware must exit 0"
    );
    let host = twin::run(replay);
    assert!(!host.frames.is_empty());
    if let Some(at) = first_difference(&qemu.frames, &host.frames) {
        panic!(
            "{name} on {board:?}: QEMU and host frames differ at byte {at} (QEMU {} bytes, host {} bytes)",
            qemu.frames.len(),
            host.frames.len()
        );
    }
    (qemu, host)
}

/// Every frame of a capture, which must decode without a skipped byte.
fn frames_of(bytes: &[u8]) -> Vec<Frame> {
    let (items, stats) = decode_all(bytes).unwrap();
    assert_eq!(stats.skipped_bytes, 0);
    items
        .into_iter()
        .filter_map(|i| match i {
            needle_io::frames::Item::Frame(f) => Some(f),
            _ => None,
        })
        .collect()
}

fn last_status(frames: &[u8]) -> Status {
    frames_of(frames)
        .into_iter()
        .rev()
        .find_map(|f| match f {
            Frame::Status(s) => Some(s),
            _ => None,
        })
        .expect("a status frame")
}

#[test]
fn cortex_m3_in_qemu_matches_the_host_twin_byte_for_byte() {
    let replay = liver_replay(0.005, 7);
    let (qemu, host) = assert_twin(Board::Lm3s6965, &replay, "liver1");
    let (items, stats) = decode_all(&qemu.frames).unwrap();
    assert_eq!((stats.gaps, stats.skipped_bytes), (0, 0));
    assert_eq!(stats.samples as usize, (replay.len() - 8) / 6);
    let kinds: Vec<EventKind> = items
        .iter()
        .filter_map(|i| match i {
            needle_io::frames::Item::Frame(Frame::Event(e)) => Some(e.kind),
            _ => None,
        })
        .collect();
    assert_eq!(kinds, [EventKind::Contact, EventKind::Puncture]);
    assert!(!host.summary.halt && host.summary.faults.is_empty());
}

#[test]
fn a_simulated_trial_with_effects_replays_in_qemu_like_on_the_host() {
    use needle_analysis::sim::{effects, simulate_dataset, Sensor};
    let dir = tempfile::tempdir().unwrap();
    let sensor = Sensor {
        rate_hz: 1000.0,
        noise_n: 0.005,
        encoder_m: 1e-6,
    };
    let effects = effects::parse_list("internal_structures,tissue_motion").unwrap();
    simulate_dataset(dir.path(), "liver1", &LIVER1, &effects, 1, 11, &sensor).unwrap();
    let replay = std::fs::read(dir.path().join("trial_000.replay")).unwrap();
    let (qemu, _) = assert_twin(Board::Lm3s6965, &replay, "simulated");
    let (_, stats) = decode_all(&qemu.frames).unwrap();
    assert_eq!(stats.samples as usize, (replay.len() - 8) / 6);
}

#[test]
fn cortex_m0_image_matches_the_host_twin() {
    assert_twin(Board::Lm3s6965M0, &liver_replay(0.005, 8), "liver1-m0");
}

#[test]
fn cortex_m4f_on_mps2_matches_the_host_twin() {
    assert_twin(Board::Mps2An386, &liver_replay(0.005, 9), "liver1-m4");
}

#[test]
fn the_real_boards_image_on_netduinoplus2_matches_the_host_twin() {
    // The Nucleo-F411RE's board code (RTIC, the frame queue, USART2) with
    // the replay in place of its sensors, clocked by TIM2.
    let (qemu, _) = assert_twin(Board::NucleoF411re, &liver_replay(0.005, 10), "liver1-f411");
    assert_eq!(last_status(&qemu.frames).frames_dropped, 0);
}

#[test]
fn a_relaxing_tissue_held_still_matches_the_host_twin_on_every_board() {
    // skin_phantom relaxes at rest (one branch, 39 %, τ 1.5 s): a 5 s
    // dwell runs the relaxation through the decay factors each image
    // computed for itself with micromath.
    let (index, replay) = sim::relaxing_dwell_replay().unwrap();
    for board in [
        Board::Lm3s6965,
        Board::Lm3s6965M0,
        Board::Mps2An386,
        Board::NucleoF411re,
    ] {
        let (qemu, _) = assert_twin(board, &replay, "skin-dwell");
        // The device ran the replay's tissue, and its model relaxed over
        // the dwell: the longest run at rest after the puncture ends
        // 30-45 % under where it began.
        let tissue = frames_of(&qemu.frames).into_iter().find_map(|f| match f {
            Frame::Config(c) => Some(c.tissue),
            _ => None,
        });
        assert_eq!(
            tissue,
            Some(needle_holder::protocol::TissueSource::Library(index)),
            "{board:?}"
        );
        let (items, _) = decode_all(&qemu.frames).unwrap();
        let samples = needle_io::frames::samples(&items);
        let mut best: &[needle_holder::insertion::Sample] = &[];
        for run in
            samples.split(|s| s.v.0 != 0 || s.phase != needle_holder::insertion::Phase::Inserted)
        {
            if run.len() > best.len() {
                best = run;
            }
        }
        assert!(
            best.len() > 2000,
            "{board:?}: dwell of {} samples",
            best.len()
        );
        let (first, last) = (best[1].model.0 as f64, best[best.len() - 1].model.0 as f64);
        let fall = 1.0 - last / first;
        assert!(
            (0.30..0.45).contains(&fall),
            "{board:?}: {first} → {last} µN"
        );
    }
}

fn replay_of(records: impl IntoIterator<Item = Record>) -> Vec<u8> {
    let mut bytes = ReplayHeader {
        sample_rate_hz: 500,
        tissue: None,
    }
    .to_bytes()
    .to_vec();
    for r in records {
        bytes.extend_from_slice(&r.to_bytes());
    }
    bytes
}

/// The fault is latched and reported, the halt line is up with a `Halt`
/// frame saying `fault`, and no puncture was flagged after it.
fn assert_fault(replay: &[u8], name: &str, fault: Faults) {
    let (qemu, host) = assert_twin(Board::Lm3s6965, replay, name);
    let frames = frames_of(&qemu.frames);
    let first_fault = frames
        .iter()
        .position(|f| matches!(f, Frame::Event(e) if e.kind == EventKind::Fault))
        .expect("a fault event");
    assert!(
        !frames[first_fault..]
            .iter()
            .any(|f| matches!(f, Frame::Event(e) if e.kind == EventKind::Puncture)),
        "{name}: no puncture may follow a fault"
    );
    assert!(
        frames
            .iter()
            .any(|f| matches!(f, Frame::Halt(h) if h.reason == HaltReason::Fault)),
        "{name}: a halt frame with reason fault"
    );
    let status = last_status(&qemu.frames);
    assert!(
        Faults::from(status.faults).contains(fault),
        "{name}: faults {:?}",
        status.faults
    );
    assert!(status.halt, "{name}: halt must be asserted");
    assert!(host.halt.high, "{name}: the twin's halt pin must be high");
    let log = defmt_print(&elf(Board::Lm3s6965), &qemu.defmt);
    assert!(
        log.contains("halt asserted"),
        "{name}: defmt log lacks the halt: {log}"
    );
    assert!(log.contains("replay done"), "{name}: defmt log: {log}");
}

#[test]
fn odd_length_replay_raises_truncated_and_halts_without_panicking() {
    let mut replay = liver_replay(0.0, 1);
    replay.truncate(replay.len() - 3);
    assert_fault(&replay, "truncated", Faults::REPLAY_TRUNCATED);
}

#[test]
fn adc_stuck_at_full_scale_raises_saturated_and_halts() {
    let full = DeviceConfig::default().load_cell.full_scale_counts;
    let replay = replay_of((0..300).map(|i| Record {
        adc_counts: if i < 100 { 0 } else { full },
        encoder_count: i as u16,
    }));
    assert_fault(&replay, "saturated", Faults::ADC_SATURATED);
}

#[test]
fn encoder_jump_beyond_the_mechanics_raises_a_fault_and_halts() {
    let replay = replay_of((0..300u16).map(|i| Record {
        adc_counts: 0,
        encoder_count: if i < 150 { i * 6 } else { 20_000 + i * 6 },
    }));
    assert_fault(&replay, "jump", Faults::ENCODER_JUMP);
}

#[test]
fn a_late_sample_raises_overrun_and_halts() {
    let replay = replay_of((0..300u16).map(|i| Record {
        adc_counts: if i == 200 { OVERRUN_MARK } else { 0 },
        encoder_count: i * 6,
    }));
    assert_fault(&replay, "overrun", Faults::SAMPLE_OVERRUN);
}

#[test]
fn force_with_the_needle_standing_outside_raises_a_fault_not_a_contact() {
    let load_cell = DeviceConfig::default().load_cell;
    let replay = replay_of((0..300u16).map(|i| Record {
        adc_counts: load_cell.counts_for(MicroNewtons(if i < 100 { 0 } else { 400_000 })),
        encoder_count: 1000,
    }));
    assert_fault(&replay, "no-contact", Faults::FORCE_WITHOUT_CONTACT);
}

/// Contact and loading on liver 1, then the encoder freezes while the force
/// goes on rising to beyond the puncture force and drops as at a puncture.
#[test]
fn an_encoder_stuck_while_loading_raises_a_fault_and_no_puncture() {
    let plan = Plan {
        noise_n: 0.0,
        ..Plan::PAPER
    };
    let (trial, truth) = sim::insertion(&LIVER1, &plan);
    let config = DeviceConfig::default();
    let stuck_from = trial
        .t_s
        .iter()
        .position(|&t| t > truth.contact_t_s + 2.0)
        .unwrap();
    let end = trial
        .t_s
        .iter()
        .position(|&t| t > truth.puncture_t_s + 0.5)
        .unwrap();
    let replay = replay_of((0..end).map(|i| {
        let mut r = sim::raw_record(
            trial.x_m[i],
            trial.f_n[i],
            &config.load_cell,
            &config.encoder,
        );
        if i >= stuck_from {
            r.encoder_count = sim::raw_record(
                trial.x_m[stuck_from],
                0.0,
                &config.load_cell,
                &config.encoder,
            )
            .encoder_count;
        }
        r
    }));
    assert_fault(&replay, "stuck-encoder", Faults::ENCODER_STUCK);
}

#[test]
fn garbage_instead_of_a_replay_raises_bad_header_and_halts() {
    assert_fault(
        b"this is not a replay file at all",
        "garbage",
        Faults::REPLAY_BAD_HEADER,
    );
    assert_fault(b"", "empty", Faults::REPLAY_BAD_HEADER);
}

#[test]
fn a_missing_replay_file_exits_with_code_2() {
    let elf = elf(Board::Lm3s6965);
    let dir = tempfile::tempdir().unwrap();
    let cmd = firmware::qemu_command(
        Board::Lm3s6965,
        &elf,
        &dir.path().join("does-not-exist.replay"),
        Serial::File(&dir.path().join("frames")),
        &[],
    );
    let run = firmware::run_qemu(cmd, Duration::from_secs(60)).unwrap();
    assert_eq!(run.status.code(), Some(2));
    assert!(defmt_print(&elf, &run.defmt).contains("cannot open replay file"));
}

/// Decode a defmt log with defmt-print, which the test command installs.
fn defmt_print(elf: &Path, log: &[u8]) -> String {
    use std::io::Write;
    let mut child = Command::new("defmt-print")
        .arg("-e")
        .arg(elf)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("defmt-print must be installed (cargo install defmt-print --locked)");
    child.stdin.take().unwrap().write_all(log).unwrap();
    let out = child.wait_with_output().unwrap();
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `needle demo` builds the firmware where cargo puts it: with
/// `CARGO_TARGET_DIR` set to an empty directory it builds and runs the
/// image there (not one an earlier build left in the repository's
/// `target/`), and keeps its capture there too.
#[test]
fn needle_demo_builds_and_runs_the_image_where_cargo_target_dir_points() {
    firmware::ensure_qemu().expect("qemu-system-arm is needed and could not be installed");
    let target = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_needle"))
        .arg("demo")
        .env("CARGO_TARGET_DIR", target.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("0 faults"), "{stdout}");
    let image = target.path().join("thumbv7m-none-eabi/firmware/lm3s6965");
    assert!(image.exists(), "no image at {}", image.display());
    assert!(stdout.contains(&image.display().to_string()), "{stdout}");
    assert!(target.path().join("demo/frames.bin").exists());
}
