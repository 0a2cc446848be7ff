//! Fuzzing with a fixed budget (proptest, a set number of cases each, so
//! CI time is bounded): the frame decoder, the command reader, the trial
//! CSV reader and the tissue TOML loader take any bytes without panic, and
//! what they accept round-trips or is exactly what was sent. (The replay
//! reader and the settings loader are fuzzed in the core's
//! `tests/integration/device.rs`.)

use crate::library;

use library::liver1_entry;
use std::sync::OnceLock;

use needle_analysis::sim::{self, Plan};
use needle_holder::config::{DeviceConfig, LIBRARY_MODELS};
use needle_holder::insertion::Sample;
use needle_holder::model::params::LIVER1;
use needle_holder::protocol::command::{CommandReader, MAX_ENCODED_COMMAND};
use needle_holder::protocol::wire::Encoder;
use needle_holder::protocol::{Command, CommandFrame};
use needle_io::frames::{decode_all, Item};
use proptest::prelude::*;

/// A short insertion through the host twin: its bytes and its samples.
fn capture() -> &'static (Vec<u8>, Vec<Sample>) {
    static CAPTURE: OnceLock<(Vec<u8>, Vec<Sample>)> = OnceLock::new();
    CAPTURE.get_or_init(|| {
        let plan = Plan {
            depth_m: 0.008,
            dwell_s: 0.0,
            speed_mps: 0.01,
            ..Plan::PAPER
        };
        let (trial, _) = sim::insertion(&LIVER1, &plan);
        let config = DeviceConfig::default();
        let replay = sim::to_replay(&trial, 500, &config.load_cell, &config.encoder);
        let bytes = needle_io::twin::run(&replay).frames;
        let (items, _) = decode_all(&bytes).unwrap();
        (bytes, needle_io::frames::samples(&items))
    })
}

/// A damaged copy of a stream: bytes flipped, stretches dropped or
/// repeated.
#[derive(Clone, Debug)]
enum Damage {
    Flip { at: usize, bit: u8 },
    Drop { at: usize, len: usize },
    Repeat { at: usize, len: usize },
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        (any::<usize>(), 0u8..8).prop_map(|(at, bit)| Damage::Flip { at, bit }),
        (any::<usize>(), 1usize..400).prop_map(|(at, len)| Damage::Drop { at, len }),
        (any::<usize>(), 1usize..2000).prop_map(|(at, len)| Damage::Repeat { at, len }),
    ]
}

fn apply(bytes: &[u8], damages: &[Damage]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    for d in damages {
        if out.is_empty() {
            break;
        }
        match *d {
            Damage::Flip { at, bit } => {
                let at = at % out.len();
                out[at] ^= 1 << bit;
            }
            Damage::Drop { at, len } => {
                let at = at % out.len();
                let end = (at + len).min(out.len());
                out.drain(at..end);
            }
            Damage::Repeat { at, len } => {
                let at = at % out.len();
                let end = (at + len).min(out.len());
                let copy = out[at..end].to_vec();
                out.splice(end..end, copy);
            }
        }
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    /// Any bytes: no panic.
    #[test]
    fn the_frame_decoder_takes_any_bytes(bytes in prop::collection::vec(any::<u8>(), 0..4096)) {
        let _ = decode_all(&bytes);
    }

    /// Any bytes into the device's command reader: no panic.
    #[test]
    fn the_command_reader_takes_any_bytes(bytes in prop::collection::vec(any::<u8>(), 0..2048)) {
        let mut reader = CommandReader::default();
        for b in bytes {
            let _ = reader.push(b);
        }
    }

    /// Every command the host can send arrives as sent.
    #[test]
    fn every_command_round_trips(seq in any::<u32>(), which in 0u8..8, value in any::<i32>(), entry in 0usize..LIBRARY_MODELS.len()) {
        let mut tissue = LIBRARY_MODELS[entry];
        tissue.model.cutting.0 = value;
        let command = match which {
            0 => Command::Tare,
            1 => Command::SelectTissue(value as u8),
            2 => Command::UploadTissue(tissue),
            3 => Command::SetAssist { modes: needle_wire::AssistBits(value as u8), target_depth: needle_wire::Nanometres(value) },
            4 => Command::Rearm,
            5 => Command::Stream(value % 2 == 0),
            6 => Command::SetLoadCellGain(value),
            _ => Command::ReadConfig,
        };
        let frame = CommandFrame { seq, command };
        let mut encoder = Encoder::<MAX_ENCODED_COMMAND>::default();
        let mut reader = CommandReader::default();
        let got: Vec<_> = encoder.encode(&frame).iter().filter_map(|&b| reader.push(b)).collect();
        prop_assert_eq!(got.len(), 1);
        prop_assert_eq!(got[0].clone().map(|(f, _)| f), Ok(frame));
    }

    /// Any text as a trial CSV or a tissue library: no panic.
    #[test]
    fn the_trial_and_tissue_readers_take_any_text(text in "(t_s,x_m,f_n\n)?([-0-9.eE,naif \n]{0,40}\n){0,20}") {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        std::fs::write(&path, &text).unwrap();
        let _ = needle_io::trial::read(&path);
        let _ = needle_io::tissue::parse(&text, std::path::Path::new("fuzz.toml"));
    }

    /// Liver 1's entry with one number replaced by anything: the loader
    /// accepts it exactly when the core's check (`TissueModel::validated`,
    /// whose rules `src/model/params.rs` and `src/config.rs` test case by
    /// case) does — it
    /// adds no rule of its own and drops none. A consistency property,
    /// not a test of the rules.
    #[test]
    fn the_loader_accepts_a_number_exactly_when_the_cores_check_does(key in 0usize..17, value in prop_oneof![any::<f64>(), -10.0f64..10.0]) {
        let keys = [
            "a1_n_per_m", "a2_n_per_m2", "rational_a_per_n", "rational_b_m_per_n", "puncture_force_n",
            "puncture_depth_m", "puncture_drop_to_n", "relaxation", "cutting_force_n", "cp_n_per_m",
            "cn_n_per_m", "bp_ns_per_m2", "bn_ns_per_m2", "dp_n_per_m", "dn_n_per_m", "half_band_mps",
            "contact_force_n",
        ];
        let liver1 = liver1_entry();
        let text: String = liver1
            .lines()
            .map(|l| if l.starts_with(&format!("{} =", keys[key])) { format!("{} = {value:?}", keys[key]) } else { l.to_string() })
            .collect::<Vec<_>>()
            .join("\n");
        let parsed = needle_io::tissue::parse(&text, std::path::Path::new("fuzz.toml"));
        let mut p = LIVER1;
        let valid = match toml::from_str::<toml::Value>(&format!("v = {value:?}")) {
            Ok(_) => {
                set(&mut p, key, value);
                needle_holder::config::TissueModel::validated(&p).is_ok()
            }
            Err(_) => false,
        };
        prop_assert_eq!(parsed.is_ok(), valid, "{} = {:?}: {:?}", keys[key], value, parsed.err().map(|e| e.to_string()));
    }
}

fn set(p: &mut needle_holder::model::params::TissueParams, key: usize, v: f64) {
    let fields = [
        &mut p.a1_n_per_m,
        &mut p.a2_n_per_m2,
        &mut p.rational_a_per_n,
        &mut p.rational_b_m_per_n,
        &mut p.puncture_force_n,
        &mut p.puncture_depth_m,
        &mut p.puncture_drop_to_n,
        &mut p.relaxation,
        &mut p.cutting_force_n,
        &mut p.cp_n_per_m,
        &mut p.cn_n_per_m,
        &mut p.bp_ns_per_m2,
        &mut p.bn_ns_per_m2,
        &mut p.dp_n_per_m,
        &mut p.dn_n_per_m,
        &mut p.half_band_mps,
        &mut p.contact_force_n,
    ];
    *fields.into_iter().nth(key).unwrap() = v;
}

/// Run `property` over `cases` values of `strategy`; it returns whether
/// the case reached the branch under test. Prints how many did, and fails
/// unless at least `least` did: a property whose branch never runs proves
/// nothing.
fn counted<S: Strategy>(
    name: &str,
    cases: u32,
    least: u32,
    strategy: S,
    property: impl Fn(S::Value) -> Result<bool, TestCaseError>,
) {
    let reached = std::cell::Cell::new(0u32);
    // A fixed seed: the counts printed are the same on every run.
    let mut runner = proptest::test_runner::TestRunner::new_with_rng(
        ProptestConfig {
            failure_persistence: None,
            ..ProptestConfig::with_cases(cases)
        },
        proptest::test_runner::TestRng::deterministic_rng(
            proptest::test_runner::RngAlgorithm::ChaCha,
        ),
    );
    runner
        .run(&strategy, |value| {
            if property(value)? {
                reached.set(reached.get() + 1);
            }
            Ok(())
        })
        .unwrap();
    println!(
        "{name}: {} of {cases} cases reached the branch",
        reached.get()
    );
    assert!(
        reached.get() >= least,
        "{name}: {} of {cases}",
        reached.get()
    );
}

/// A change to a text: a character replaced, removed or put in.
#[derive(Clone, Debug)]
enum TextDamage {
    Replace(prop::sample::Index, char),
    Remove(prop::sample::Index),
    Insert(prop::sample::Index, char),
}

fn text_damage() -> impl Strategy<Value = TextDamage> {
    let c = prop::sample::select(vec![
        '-', '0', '7', '.', 'e', 'E', ',', 'n', 'a', 'i', ' ', '\n', '"', '=', '[', 'x',
    ]);
    prop_oneof![
        (any::<prop::sample::Index>(), c.clone()).prop_map(|(i, c)| TextDamage::Replace(i, c)),
        any::<prop::sample::Index>().prop_map(TextDamage::Remove),
        (any::<prop::sample::Index>(), c).prop_map(|(i, c)| TextDamage::Insert(i, c)),
    ]
}

fn damage_text(text: &str, damages: &[TextDamage]) -> String {
    let mut chars: Vec<char> = text.chars().collect();
    for d in damages {
        if chars.is_empty() {
            break;
        }
        match d {
            TextDamage::Replace(i, c) => {
                let at = i.index(chars.len());
                chars[at] = *c;
            }
            TextDamage::Remove(i) => {
                chars.remove(i.index(chars.len()));
            }
            TextDamage::Insert(i, c) => chars.insert(i.index(chars.len() + 1), *c),
        }
    }
    chars.into_iter().collect()
}

/// A trial a rig could record: times 1–20 ms apart, a needle moving less
/// than a millimetre a sample, forces within the load cell's 10 N, each
/// written with up to 9 decimals.
fn trial_text() -> impl Strategy<Value = String> {
    prop::collection::vec((1e-3..20e-3f64, -1e-3..1e-3f64, -10.0..10.0f64), 2..60).prop_map(
        |rows| {
            let (mut t, mut x) = (0.0, 0.0);
            let mut text = String::from("t_s,x_m,f_n\n");
            for (dt, dx, f) in rows {
                text += &format!("{t:.6},{x:.9},{f:.6}\n");
                t += dt;
                x += dx;
            }
            text
        },
    )
}

/// A valid trial, damaged in up to three places or not at all: what the
/// reader accepts, written and read again, is what it read (at the
/// writer's resolution). Counted: the accepted cases.
#[test]
fn an_accepted_trial_round_trips() {
    let strategy = (trial_text(), prop::collection::vec(text_damage(), 0..4));
    counted("trial round trip", 400, 100, strategy, |(text, damages)| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        std::fs::write(&path, damage_text(&text, &damages)).unwrap();
        let Ok(trial) = needle_io::trial::read(&path) else {
            return Ok(false);
        };
        let again = dir.path().join("again.csv");
        needle_io::trial::write(&again, &trial).unwrap();
        let back = needle_io::trial::read(&again);
        prop_assert!(back.is_ok(), "{:?}", back.err());
        let back = back.unwrap();
        prop_assert_eq!(back.len(), trial.len());
        for i in 0..trial.len() {
            prop_assert!((back.t_s[i] - trial.t_s[i]).abs() <= 5e-7);
            prop_assert!((back.x_m[i] - trial.x_m[i]).abs() <= 5e-10);
            prop_assert!((back.f_n[i] - trial.f_n[i]).abs() <= 5e-7);
        }
        Ok(true)
    });
}

/// Liver 1's library entry, damaged in up to three places or not at all:
/// an accepted tissue passes the core's check and converts to the
/// device's fixed point; a refused one is named by file. Counted: the
/// accepted cases.
#[test]
fn an_accepted_tissue_is_valid_and_converts() {
    let liver1 = liver1_entry();
    let strategy = prop::collection::vec(text_damage(), 0..4);
    counted("tissue loader", 400, 100, strategy, |damages| {
        let text = damage_text(&liver1, &damages);
        match needle_io::tissue::parse(&text, std::path::Path::new("fuzz.toml")) {
            Ok(tissues) => {
                for t in &tissues {
                    prop_assert!(t.params.validate().is_ok());
                    prop_assert!(needle_holder::config::TissueModel::from_params(&t.params).is_ok());
                }
                Ok(!tissues.is_empty())
            }
            Err(e) => {
                prop_assert!(e.to_string().contains("fuzz.toml"), "{e}");
                Ok(false)
            }
        }
    });
}

/// A command frame the host sends, after random bytes, perhaps with its
/// own bytes changed: the reader gives that frame or refuses it, never
/// another command. Counted: frames given whole (undamaged) and damaged
/// frames refused.
#[test]
fn a_damaged_command_frame_is_refused_never_misread() {
    let strategy = (
        any::<u32>(),
        0usize..LIBRARY_MODELS.len(),
        prop::collection::vec(any::<u8>(), 0..40),
        prop::option::of((any::<prop::sample::Index>(), 1u8..=255)),
    );
    let (given, refused) = (std::cell::Cell::new(0), std::cell::Cell::new(0));
    counted(
        "command reader",
        400,
        300,
        strategy,
        |(seq, entry, noise, damage)| {
            let frame = CommandFrame {
                seq,
                command: Command::UploadTissue(LIBRARY_MODELS[entry]),
            };
            let mut encoder = Encoder::<MAX_ENCODED_COMMAND>::default();
            let mut bytes = encoder.encode(&frame).to_vec();
            if let Some((at, xor)) = damage {
                let at = at.index(bytes.len() - 1); // not the closing zero
                bytes[at] ^= xor;
            }
            let mut reader = CommandReader::default();
            let mut answers: Vec<_> = noise
                .iter()
                .chain(&[0])
                .filter_map(|&b| reader.push(b))
                .collect();
            let before = answers.len();
            answers.extend(bytes.iter().filter_map(|&b| reader.push(b)));
            let mine = &answers[before..];
            let accepted: Vec<_> = mine.iter().filter_map(|a| a.as_ref().ok()).collect();
            for (got, _) in &accepted {
                prop_assert_eq!(*got, frame, "a frame read as another command");
            }
            match (damage.is_some(), accepted.len()) {
                (false, 1) => given.set(given.get() + 1),
                (true, 0) => refused.set(refused.get() + 1),
                _ => {}
            }
            Ok(damage.is_none() && accepted.len() == 1 || damage.is_some() && accepted.is_empty())
        },
    );
    println!(
        "command reader: {} whole frames given, {} damaged refused",
        given.get(),
        refused.get()
    );
    assert!(given.get() >= 100 && refused.get() >= 100);
}

/// A damaged stream: every sample given is the device's own sample of
/// that index — a line error costs samples, never changes one. Counted:
/// the damaged streams that still gave samples.
#[test]
fn a_damaged_stream_gives_only_the_devices_own_samples() {
    let strategy = prop::collection::vec(damage(), 1..6);
    counted("damaged stream", 400, 300, strategy, |damages| {
        let (bytes, samples) = capture();
        let damaged = apply(bytes, &damages);
        let (items, _) = decode_all(&damaged).unwrap();
        let mut given = 0;
        for item in &items {
            if let Item::Sample(s) = item {
                prop_assert_eq!(
                    Some(s),
                    samples.get(s.index as usize),
                    "sample {} changed",
                    s.index
                );
                given += 1;
            }
        }
        Ok(given > 0)
    });
}
