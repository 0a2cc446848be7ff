//! Pins the bytes of every frame and every command on the wire, so that no
//! change to a type any of them carries — down to a detector's state in
//! the snapshot — passes unnoticed. Each kind is encoded with typical
//! contents (the compiled configuration, the pipeline's state after a
//! loading ramp, a library tissue) and its length and CRC-32 compared with
//! the table below. When it fails you changed the wire: bump
//! [`super::PROTOCOL_VERSION`] (and teach the host the old version if its
//! captures should still decode), then paste the table it prints.

use super::command::{CommandFrame, MAX_ENCODED_COMMAND};
use super::*;
use crate::config::{DEFAULT, LIBRARY_MODELS};
use crate::hal::AdcSample;
use crate::pipeline::RawSample;
use needle_wire::{AssistBits, MicroNewtons, Nanometres};

/// The pipeline's state after a loading ramp: every counter and filter
/// away from its start.
fn stepped_state() -> PipelineState {
    let mut state = PipelineState::default();
    for i in 0..400i32 {
        DEFAULT.step(
            &mut state,
            RawSample {
                adc: Some(AdcSample {
                    counts: 20 * i * i,
                    saturated: false,
                    overrun: false,
                }),
                encoder_count: (i * 40) as u16,
            },
        );
    }
    state
}

fn frames() -> std::vec::Vec<(&'static str, Frame<'static>)> {
    static RAW: [u8; 12] = [0x80, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
    let status = Status {
        protocol_version: PROTOCOL_VERSION,
        sample_rate_hz: 500,
        samples: 1234,
        frames_dropped: 1,
        faults: FaultBits(0x0010),
        halt: false,
        streaming: true,
        next_command_seq: 7,
        board: BoardCounters {
            conversions_lost: 2,
            line_errors: 3,
        },
        schema_key: SCHEMA_KEY,
    };
    std::vec![
        ("header", Frame::Header(header(500)),),
        (
            "config",
            Frame::Config(ConfigFrame {
                tissue: TissueSource::Library(0),
                stored: crate::persist::Loaded::NotKept,
                config: DEFAULT,
            }),
        ),
        (
            "batch",
            Frame::Batch(Batch {
                first_index: 1234,
                samples: 3,
                check: [1, 2, 3, 4],
                raw: &RAW,
            }),
        ),
        (
            "snapshot",
            Frame::Snapshot(Snapshot {
                next_index: 400,
                state: stepped_state(),
            }),
        ),
        (
            "event",
            Frame::Event(Event {
                index: 321,
                kind: EventKind::Puncture,
                x: Nanometres(21_650_000),
                force: MicroNewtons(2_300_000),
                confidence_permille: 930,
            }),
        ),
        ("status", Frame::Status(status)),
        (
            "halt",
            Frame::Halt(Halt {
                index: 322,
                reason: HaltReason::SpeedLimit,
                x: Nanometres(21_700_000),
                hold_x: Nanometres(21_000_000),
            }),
        ),
        (
            "reply",
            Frame::Reply(Reply {
                seq: 7,
                result: Err(CommandError::InvalidTissue {
                    field: command::text("cutting_force_n"),
                    problem: command::text("negative"),
                }),
            }),
        ),
        (
            "selftest",
            Frame::SelfTest(SelfTest {
                board: BoardFindings {
                    adc_registers: Some(([1, 2, 3, 4], [1, 2, 3, 4])),
                    data_ready_per_s: Some(1999),
                    data_ready_expected_per_s: 2000,
                    encoder_count: Some(40),
                },
                halt: true,
                faults: FaultBits(0),
                counters: status.board,
            }),
        ),
    ]
}

/// Every variant of the enums the frames carry, one frame each: a variant
/// inserted before another renumbers it on the wire.
fn variants() -> std::vec::Vec<(&'static str, Frame<'static>)> {
    use crate::persist::Loaded;
    let event = |kind| {
        Frame::Event(Event {
            index: 1,
            kind,
            x: Nanometres(1),
            force: MicroNewtons(1),
            confidence_permille: 1,
        })
    };
    let halt = |reason| {
        Frame::Halt(Halt {
            index: 1,
            reason,
            x: Nanometres(1),
            hold_x: Nanometres(1),
        })
    };
    let refused = |result| Frame::Reply(Reply { seq: 1, result });
    let config = |tissue, stored| {
        Frame::Config(ConfigFrame {
            tissue,
            stored,
            config: DEFAULT,
        })
    };
    let text = command::text;
    let mut all = std::vec::Vec::new();
    for kind in [
        EventKind::Contact,
        EventKind::Puncture,
        EventKind::Structure,
        EventKind::Exit,
        EventKind::Fault,
    ] {
        all.push(("event_kinds", event(kind)));
    }
    for reason in [
        HaltReason::Fault,
        HaltReason::Contact,
        HaltReason::Puncture,
        HaltReason::Structure,
        HaltReason::Exit,
        HaltReason::TargetDepth,
        HaltReason::SpeedLimit,
    ] {
        all.push(("halt_reasons", halt(reason)));
    }
    for error in [
        CommandError::Corrupted,
        CommandError::Unknown,
        CommandError::Stale { next_seq: 2 },
        CommandError::NoSuchTissue { library_len: 3 },
        CommandError::InvalidTissue {
            field: text("a"),
            problem: text("b"),
        },
        CommandError::OutOfRange { field: text("c") },
        CommandError::NeedleInTissue,
        CommandError::LoadOnNeedle {
            force: MicroNewtons(4),
        },
        CommandError::HaltCausePersists {
            reason: HaltReason::Fault,
        },
    ] {
        all.push(("command_errors", refused(Err(error))));
    }
    all.push(("command_errors", refused(Ok(()))));
    for stored in [
        Loaded::NotKept,
        Loaded::Blank,
        Loaded::Saved,
        Loaded::SavedBeforeTorn,
        Loaded::Invalid,
    ] {
        all.push(("stored_settings", config(TissueSource::Uploaded, stored)));
    }
    all
}

fn commands() -> std::vec::Vec<(&'static str, Command)> {
    std::vec![
        ("tare", Command::Tare),
        ("select_tissue", Command::SelectTissue(2)),
        ("upload_tissue", Command::UploadTissue(LIBRARY_MODELS[0])),
        (
            "set_assist",
            Command::SetAssist {
                modes: AssistBits(0b101),
                target_depth: Nanometres(20_000_000),
            },
        ),
        ("rearm", Command::Rearm),
        ("stream", Command::Stream(true)),
        ("read_config", Command::ReadConfig),
        ("set_load_cell_gain", Command::SetLoadCellGain(78_000)),
        ("self_test", Command::SelfTest),
    ]
}

/// (kind, encoded length, CRC-32 of the encoded bytes).
const PINNED: &[(&str, usize, u32)] = &[
    ("header", 16, 0x43c89cdc),
    ("config", 109, 0x12f256cf),
    ("batch", 25, 0xf810f43d),
    ("snapshot", 130, 0xb016cc12),
    ("event", 18, 0x485a6c30),
    ("status", 25, 0x2995d8e8),
    ("halt", 16, 0x4860d0e9),
    ("reply", 33, 0x807a0150),
    ("selftest", 25, 0x0c9ffd9b),
    ("event_kinds", 50, 0x68df45db),
    ("halt_reasons", 63, 0x3eaef218),
    ("command_errors", 89, 0x3c0a800d),
    ("stored_settings", 540, 0xcaab7633),
    ("tare", 6, 0x4774606c),
    ("select_tissue", 7, 0x80abfee7),
    ("upload_tissue", 80, 0xbcea2f93),
    ("set_assist", 11, 0xec06c323),
    ("rearm", 6, 0x5ec16ed2),
    ("stream", 7, 0x19c3c2e9),
    ("read_config", 6, 0x55c3a626),
    ("set_load_cell_gain", 9, 0xff63ce85),
    ("self_test", 6, 0x64cfdcea),
];

/// A kind added to [`Frame`] or [`Command`], or a variant to an enum they
/// carry, does not compile here until it is in [`frames`], [`variants`] or
/// [`commands`] and pinned.
#[allow(dead_code)]
fn every_kind_is_listed(
    frame: &Frame,
    command: &Command,
    error: &CommandError,
    stored: &crate::persist::Loaded,
    source: &TissueSource,
    kind: EventKind,
    reason: HaltReason,
) {
    use crate::persist::Loaded;
    match error {
        CommandError::Corrupted
        | CommandError::Unknown
        | CommandError::Stale { .. }
        | CommandError::NoSuchTissue { .. }
        | CommandError::InvalidTissue { .. }
        | CommandError::OutOfRange { .. }
        | CommandError::NeedleInTissue
        | CommandError::LoadOnNeedle { .. }
        | CommandError::HaltCausePersists { .. } => {}
    }
    match stored {
        Loaded::NotKept
        | Loaded::Blank
        | Loaded::Saved
        | Loaded::SavedBeforeTorn
        | Loaded::Invalid => {}
    }
    match source {
        TissueSource::Library(_) | TissueSource::Uploaded => {}
    }
    match kind {
        EventKind::Contact
        | EventKind::Puncture
        | EventKind::Structure
        | EventKind::Exit
        | EventKind::Fault => {}
    }
    match reason {
        HaltReason::Fault
        | HaltReason::Contact
        | HaltReason::Puncture
        | HaltReason::Structure
        | HaltReason::Exit
        | HaltReason::TargetDepth
        | HaltReason::SpeedLimit => {}
    }
    match frame {
        Frame::Header(_)
        | Frame::Config(_)
        | Frame::Batch(_)
        | Frame::Snapshot(_)
        | Frame::Event(_)
        | Frame::Status(_)
        | Frame::Halt(_)
        | Frame::Reply(_)
        | Frame::SelfTest(_) => {}
    }
    match command {
        Command::Tare
        | Command::SelectTissue(_)
        | Command::UploadTissue(_)
        | Command::SetAssist { .. }
        | Command::Rearm
        | Command::Stream(_)
        | Command::ReadConfig
        | Command::SetLoadCellGain(_)
        | Command::SelfTest => {}
    }
}

fn crc32(bytes: &[u8]) -> u32 {
    crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(bytes)
}

#[test]
fn every_frame_and_command_kind_has_the_pinned_bytes() {
    let mut measured: std::vec::Vec<(&str, usize, u32)> = std::vec::Vec::new();
    for (kind, frame) in frames() {
        let bytes = FrameEncoder::default().encode(&frame).to_vec();
        measured.push((kind, bytes.len(), crc32(&bytes)));
    }
    // Each enum's variants together: their bytes one after the other.
    let mut by_enum: std::vec::Vec<(&str, std::vec::Vec<u8>)> = std::vec::Vec::new();
    for (name, frame) in variants() {
        let bytes = FrameEncoder::default().encode(&frame).to_vec();
        match by_enum.iter_mut().find(|(n, _)| *n == name) {
            Some((_, all)) => all.extend_from_slice(&bytes),
            None => by_enum.push((name, bytes)),
        }
    }
    for (name, bytes) in &by_enum {
        measured.push((name, bytes.len(), crc32(bytes)));
    }
    for (kind, command) in commands() {
        let frame = CommandFrame { seq: 7, command };
        let bytes = wire::Encoder::<MAX_ENCODED_COMMAND>::default()
            .encode(&frame)
            .to_vec();
        measured.push((kind, bytes.len(), crc32(&bytes)));
    }
    let table: std::string::String = measured
        .iter()
        .map(|(k, n, c)| std::format!("    (\"{k}\", {n}, 0x{c:08x}),\n"))
        .collect();
    assert_eq!(PINNED.len(), measured.len(), "pin every kind:\n{table}");
    for (pinned, got) in PINNED.iter().zip(&measured) {
        assert_eq!(
            pinned, got,
            "the bytes on the wire changed: bump PROTOCOL_VERSION, then pin:\n{table}"
        );
    }
}

/// The schema's hash, pinned with the version it belongs to: a change to
/// any type on the wire — a field renamed, added or of another type, a
/// variant no frame above carries — changes it, bytes or no bytes.
const PINNED_SCHEMA: (u16, [u8; 8]) = (6, [222, 171, 188, 224, 15, 185, 243, 205]);

#[test]
fn the_schema_key_is_pinned_with_its_version() {
    assert_eq!(
        PINNED_SCHEMA,
        (PROTOCOL_VERSION, SCHEMA_KEY),
        "the schema of the frames or commands changed: bump PROTOCOL_VERSION \
         (and SCHEMA_PATH), then pin ({PROTOCOL_VERSION}, {SCHEMA_KEY:?})"
    );
}

#[test]
fn the_schema_path_names_the_version() {
    assert_eq!(
        SCHEMA_PATH,
        std::format!("needle-holder/{PROTOCOL_VERSION}")
    );
}

#[test]
fn the_schema_key_sees_a_field_the_bytes_may_not() {
    use postcard_schema::key::Key;
    use postcard_schema::schema::{DataModelType, NamedType, NamedValue};
    use postcard_schema::Schema;
    const fn field(name: &'static str, ty: &'static NamedType) -> NamedValue {
        NamedValue { name, ty }
    }
    // The header written out field by field, and the same with one field
    // more at its end (which a frame that leaves it out encodes alike).
    struct Same;
    impl Schema for Same {
        const SCHEMA: &'static NamedType = &NamedType {
            name: "Header",
            ty: &DataModelType::Struct(&[
                &field("protocol_version", u16::SCHEMA),
                &field("sample_rate_hz", u16::SCHEMA),
                &field("schema_key", <[u8; 8]>::SCHEMA),
            ]),
        };
    }
    struct Wider;
    impl Schema for Wider {
        const SCHEMA: &'static NamedType = &NamedType {
            name: "Header",
            ty: &DataModelType::Struct(&[
                &field("protocol_version", u16::SCHEMA),
                &field("sample_rate_hz", u16::SCHEMA),
                &field("schema_key", <[u8; 8]>::SCHEMA),
                &field("extra", u8::SCHEMA),
            ]),
        };
    }
    let key = |k: Key| k.to_bytes();
    assert_eq!(
        key(Key::for_path::<Header>(SCHEMA_PATH)),
        key(Key::for_path::<Same>(SCHEMA_PATH))
    );
    assert_ne!(
        key(Key::for_path::<Header>(SCHEMA_PATH)),
        key(Key::for_path::<Wider>(SCHEMA_PATH))
    );
}
