//! Fuzzing with a fixed budget (proptest, a set number of cases each, so
//! CI time is bounded): the frame decoder, the command reader, the trial
//! CSV reader and the tissue TOML loader take any bytes without panic, and
//! what they accept round-trips or is exactly what was sent. (The replay
//! reader and the settings loader are fuzzed in the core's
//! `tests/device.rs`.)

use std::sync::OnceLock;

use host_tools::frames::{decode_all, Item};
use host_tools::sim::{self, Plan};
use needle_holder::config::{DeviceConfig, LIBRARY_MODELS};
use needle_holder::model::params::LIVER1;
use needle_holder::protocol::command::{CommandReader, MAX_ENCODED_COMMAND};
use needle_holder::protocol::wire::Encoder;
use needle_holder::protocol::{Command, CommandFrame, Sample};
use needle_holder::units::Nanometres;
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
        let bytes = host_tools::twin::run(&replay).frames;
        let (items, _) = decode_all(&bytes).unwrap();
        (bytes, host_tools::frames::samples(&items))
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

    /// A damaged stream: every sample given is the device's own sample
    /// of that index — a line error costs samples, never changes one.
    #[test]
    fn a_damaged_stream_gives_only_the_devices_own_samples(damages in prop::collection::vec(damage(), 1..6)) {
        let (bytes, samples) = capture();
        let damaged = apply(bytes, &damages);
        let (items, _) = decode_all(&damaged).unwrap();
        for item in &items {
            if let Item::Sample(s) = item {
                prop_assert_eq!(Some(s), samples.get(s.index as usize), "sample {} changed", s.index);
            }
        }
    }

    /// Any bytes into the device's command reader: no panic; a frame it
    /// accepts is one the host could have sent.
    #[test]
    fn the_command_reader_takes_any_bytes(bytes in prop::collection::vec(any::<u8>(), 0..2048)) {
        let mut reader = CommandReader::default();
        for b in bytes {
            if let Some(Ok((frame, _))) = reader.push(b) {
                let mut encoder = Encoder::<MAX_ENCODED_COMMAND>::default();
                prop_assert!(!encoder.encode(&frame).is_empty());
            }
        }
    }

    /// Every command the host can send arrives as sent.
    #[test]
    fn every_command_round_trips(seq in any::<u32>(), which in 0u8..7, value in any::<i32>(), entry in 0usize..LIBRARY_MODELS.len()) {
        let mut tissue = LIBRARY_MODELS[entry];
        tissue.model.cutting.0 = value;
        let command = match which {
            0 => Command::Tare,
            1 => Command::SelectTissue(value as u8),
            2 => Command::UploadTissue(tissue),
            3 => Command::SetAssist { modes: needle_holder::assist::AssistModes(value as u8), target_depth: Nanometres(value) },
            4 => Command::Rearm,
            5 => Command::Stream(value % 2 == 0),
            _ => Command::ReadConfig,
        };
        let frame = CommandFrame { seq, command };
        let mut encoder = Encoder::<MAX_ENCODED_COMMAND>::default();
        let mut reader = CommandReader::default();
        let got: Vec<_> = encoder.encode(&frame).iter().filter_map(|&b| reader.push(b)).collect();
        prop_assert_eq!(got.len(), 1);
        prop_assert_eq!(got[0].clone().map(|(f, _)| f), Ok(frame));
    }

    /// Any text as a trial CSV: no panic; an accepted trial written and
    /// read again is what was read (at the writer's resolution).
    #[test]
    fn the_trial_reader_takes_any_text(text in "(t_s,x_m,f_n\n)?([-0-9.eE,naif \n]{0,40}\n){0,20}") {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        std::fs::write(&path, &text).unwrap();
        if let Ok(trial) = host_tools::trial::read(&path) {
            let again = dir.path().join("again.csv");
            host_tools::trial::write(&again, &trial).unwrap();
            let back = host_tools::trial::read(&again);
            // Two times within a microsecond collapse when written: then
            // the reader refuses the copy, naming the line.
            if let Ok(back) = back {
                prop_assert_eq!(back.len(), trial.len());
                for i in 0..trial.len() {
                    prop_assert!((back.t_s[i] - trial.t_s[i]).abs() <= 5e-7);
                    prop_assert!((back.x_m[i] - trial.x_m[i]).abs() <= 5e-10);
                    prop_assert!((back.f_n[i] - trial.f_n[i]).abs() <= 5e-7);
                }
            }
        }
    }

    /// Any text as a tissue library: no panic; an accepted tissue is valid
    /// and converts to the device's fixed point.
    #[test]
    fn the_tissue_loader_takes_any_text(text in "(\\[[a-z]{1,6}\\]\n)?([a-z_0-9]{1,20} = [-0-9.e\"a-z]{0,12}\n){0,20}") {
        if let Ok(tissues) = host_tools::tissue::parse(&text, std::path::Path::new("fuzz.toml")) {
            for t in tissues {
                prop_assert!(t.params.validate().is_ok());
                prop_assert!(needle_holder::config::TissueModel::from_params(&t.params).is_ok());
            }
        }
    }

    /// Liver 1's entry with one number replaced by anything: accepted
    /// exactly when the parameters are valid.
    #[test]
    fn a_tissue_with_any_number_is_accepted_only_when_valid(key in 0usize..17, value in prop_oneof![any::<f64>(), -10.0f64..10.0]) {
        let keys = [
            "a1_n_per_m", "a2_n_per_m2", "rational_a_per_n", "rational_b_m_per_n", "puncture_force_n",
            "puncture_depth_m", "puncture_drop_to_n", "relaxation", "cutting_force_n", "cp_n_per_m",
            "cn_n_per_m", "bp_ns_per_m2", "bn_ns_per_m2", "dp_n_per_m", "dn_n_per_m", "half_band_mps",
            "contact_force_n",
        ];
        let library = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../src/model/tissues.toml")).unwrap();
        let liver1: String = library.split("\n[").nth(1).map(|e| format!("[{e}")).unwrap();
        let text: String = liver1
            .lines()
            .map(|l| if l.starts_with(&format!("{} =", keys[key])) { format!("{} = {value:?}", keys[key]) } else { l.to_string() })
            .collect::<Vec<_>>()
            .join("\n");
        let parsed = host_tools::tissue::parse(&text, std::path::Path::new("fuzz.toml"));
        let mut p = LIVER1;
        let valid = match toml::from_str::<toml::Value>(&format!("v = {value:?}")) {
            Ok(_) => {
                set(&mut p, key, value);
                p.validate().is_ok()
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
