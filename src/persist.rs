//! Settings that outlive a power cycle: the tissue in use (from the
//! library or uploaded) with its model, the load-cell calibration and the
//! assist modes, kept by the real board in a flash sector as an
//! append-only log of records.
//!
//! **Record** (little-endian, 4-byte aligned for programming):
//!
//! | bytes | field |
//! |---|---|
//! | 0..4 | magic `NHS1` |
//! | 4..6 | body length `n`, `u16` |
//! | 6 | format version, [`FORMAT_VERSION`] (2 since the tissue carries its relaxation: a version-1 log reads as `Invalid` and is erased before the next save) |
//! | 7 | `0` |
//! | 8..8+n | body: postcard of [`Settings`] |
//! | then | `0xFF` up to a multiple of 4 |
//! | then 4 | CRC-32 (ISO-HDLC) over bytes 0..8+n |
//!
//! **Log.** Records follow one another from the start of the region; the
//! first erased word (`0xFFFF_FFFF`) ends it, and the last valid record
//! wins. A save appends: programming a few hundred bytes stalls the flash
//! for microseconds at a time, so it can happen between samples. Only a
//! full (or unreadable) region is erased, and only at boot, before
//! sampling starts: erasing a 128 KiB sector stalls every flash fetch for
//! one to two seconds. (Written here rather than with `sequential-storage`,
//! whose pages are erased whenever one fills, at any moment.)
//!
//! A record cut short by a power loss fails its CRC: the one before it
//! counts, and the load says so. A region that is neither erased nor a
//! log of records is [`Loaded::Invalid`]: the device runs the compiled
//! default and says so in its config frame.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::assist::AssistModes;
use crate::calibration::LoadCell;
use crate::config::{DeviceConfig, TissueModel, TissueSource};
use crate::units::Nanometres;

/// First bytes of a record.
pub const MAGIC: [u8; 4] = *b"NHS1";
/// Record format this code reads and writes.
pub const FORMAT_VERSION: u8 = 2;
/// Bytes before the body.
const HEAD: usize = 8;
/// Largest body.
pub const MAX_BODY: usize = 192;
/// Largest record.
pub const MAX_RECORD: usize = HEAD + MAX_BODY + 3 + 4;
/// Room a region must have left for a save without an erase first.
pub const MIN_ROOM: usize = MAX_RECORD;

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// What the device keeps across power cycles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct Settings {
    /// Where the tissue came from.
    pub tissue: TissueSource,
    /// The tissue, in fixed point.
    pub model: TissueModel,
    /// Load-cell calibration (the tare is taken again at boot).
    pub load_cell: LoadCell,
    /// Assist modes.
    pub assist_modes: AssistModes,
    /// Target depth past the surface.
    pub target_depth: Nanometres,
}

impl Settings {
    /// `base` with these settings: their tissue, load-cell calibration and
    /// assist.
    pub fn applied_to(&self, base: &DeviceConfig) -> DeviceConfig {
        let mut next = base.with_tissue(&self.model);
        next.load_cell = self.load_cell;
        next.assist.modes = self.assist_modes;
        next.assist.target_depth = self.target_depth;
        next
    }

    /// The checks a command's settings pass, made again on what flash
    /// held: a record whose CRC holds can still come from another build
    /// (a `TissueModel` laid out differently under the same format
    /// version) or a debug probe, and the model's arithmetic relies on
    /// the signs and ranges [`TissueModel::check`] guarantees.
    pub fn is_valid(&self) -> bool {
        let library = match self.tissue {
            TissueSource::Library(i) => usize::from(i) < crate::config::LIBRARY_MODELS.len(),
            TissueSource::Uploaded => true,
        };
        library
            && self.model.check().is_ok()
            && self.assist_modes.is_known()
            && crate::assist::target_depth_is_valid(self.target_depth)
            && self.load_cell.gain_q16.unsigned_abs() >= crate::calibration::MIN_GAIN_Q16
            && self.load_cell.full_scale_counts > 0
    }
}

/// What a region held.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Loaded {
    /// This board keeps no settings (the QEMU boards): the compiled
    /// default at every start.
    NotKept,
    /// Nothing saved yet (erased): the compiled default.
    Blank,
    /// The last saved settings.
    Saved,
    /// The last record was cut short (a power loss while saving): the one
    /// before it.
    SavedBeforeTorn,
    /// Not a log of records (another firmware's data, a record of another
    /// format, damage): the compiled default. Erased at the next boot
    /// before anything is saved.
    Invalid,
}

/// The outcome of reading a region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Load {
    /// The settings to start with, if any.
    pub settings: Option<Settings>,
    /// What the region held.
    pub loaded: Loaded,
    /// Where the next record goes; `None` when the region must be erased
    /// first (full, or invalid).
    pub next_free: Option<usize>,
}

/// Read the log in `region` (the flash sector, memory-mapped).
pub fn load(region: &[u8]) -> Load {
    let mut at = 0;
    let mut latest = None;
    let mut torn = false;
    loop {
        let head = region.get(at..at + HEAD);
        // Erased from `at` on, or no room left for another record.
        if head.is_none_or(|h| h[..4] == [0xFF; 4]) {
            let next_free = (region.len().saturating_sub(at) >= MIN_ROOM).then_some(at);
            let loaded = match (latest.is_some(), torn) {
                (false, false) if at == 0 => Loaded::Blank,
                (false, _) => Loaded::Invalid,
                (true, true) => Loaded::SavedBeforeTorn,
                (true, false) => Loaded::Saved,
            };
            return Load {
                settings: latest,
                loaded,
                next_free,
            };
        }
        let Some(head) = head else { break };
        if head[..4] != MAGIC || head[6] != FORMAT_VERSION {
            break;
        }
        let n = usize::from(u16::from_le_bytes([head[4], head[5]]));
        let len = record_len(n);
        if n > MAX_BODY || at + len > region.len() {
            break;
        }
        // Every slice checked (`get`), none indexed: the loader reads
        // whatever the sector holds and links no panic path.
        let Some(record) = region.get(at..at + len) else {
            break;
        };
        let (Some(covered), Some(crc)) = (record.get(..HEAD + n), record.get(len - 4..)) else {
            break;
        };
        let Ok(stored) = <[u8; 4]>::try_from(crc).map(u32::from_le_bytes) else {
            break;
        };
        let body = covered.get(HEAD..).unwrap_or(&[]);
        match postcard::from_bytes::<Settings>(body) {
            Ok(settings) if CRC32.checksum(covered) == stored && settings.is_valid() => {
                latest = Some(settings);
                torn = false;
            }
            // Damaged, or settings this firmware would not take: its
            // length was readable, so go on past it.
            _ => torn = true,
        }
        at += len;
    }
    Load {
        settings: latest,
        loaded: Loaded::Invalid,
        next_free: None,
    }
}

/// Bytes a record with an `n`-byte body takes.
const fn record_len(n: usize) -> usize {
    (HEAD + n).div_ceil(4) * 4 + 4
}

/// The record for `settings`, in `out`; empty if the body outgrew
/// [`MAX_BODY`] (a bug in that bound).
pub fn record<'a>(settings: &Settings, out: &'a mut [u8; MAX_RECORD]) -> &'a [u8] {
    out.fill(0xFF);
    let n = match postcard::to_slice(settings, &mut out[HEAD..HEAD + MAX_BODY]) {
        Ok(body) => body.len(),
        Err(_) => return &[],
    };
    out[..4].copy_from_slice(&MAGIC);
    out[4..6].copy_from_slice(&(n as u16).to_le_bytes());
    out[6] = FORMAT_VERSION;
    out[7] = 0;
    let len = record_len(n);
    // Checked slices: `n` is the body postcard wrote, within MAX_BODY,
    // which the compiler cannot see.
    let Some(crc) = out.get(..HEAD + n).map(|covered| CRC32.checksum(covered)) else {
        return &[];
    };
    let Some(tail) = out.get_mut(len - 4..len) else {
        return &[];
    };
    for (byte, crc_byte) in tail.iter_mut().zip(crc.to_le_bytes()) {
        *byte = crc_byte;
    }
    out.get(..len).unwrap_or(&[])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::LIBRARY_MODELS;
    use std::vec::Vec;

    fn settings(i: u8) -> Settings {
        Settings {
            tissue: TissueSource::Library(i),
            model: LIBRARY_MODELS[usize::from(i)],
            load_cell: LoadCell::TEN_NEWTON_24_BIT,
            assist_modes: AssistModes(i),
            target_depth: Nanometres(1_000_000 * (i32::from(i) + 1)),
        }
    }

    /// A region of `len` erased bytes with these records written in.
    fn region(len: usize, records: &[Settings]) -> Vec<u8> {
        let mut region = std::vec![0xFF; len];
        let mut at = 0;
        for s in records {
            let mut buf = [0; MAX_RECORD];
            let r = record(s, &mut buf);
            region[at..at + r.len()].copy_from_slice(r);
            at += r.len();
        }
        region
    }

    #[test]
    fn an_erased_region_is_blank_and_the_last_record_wins() {
        let blank = load(&[0xFF; 4096]);
        assert_eq!(
            (blank.loaded, blank.settings, blank.next_free),
            (Loaded::Blank, None, Some(0))
        );
        let all = [settings(0), settings(1), settings(2)];
        let log = region(4096, &all);
        let got = load(&log);
        assert_eq!(
            (got.loaded, got.settings),
            (Loaded::Saved, Some(settings(2)))
        );
        assert!(lens(&all).iter().all(|&n| n <= MAX_RECORD && n % 4 == 0));
        assert_eq!(got.next_free, Some(lens(&all).iter().sum()));
    }

    fn lens(all: &[Settings]) -> Vec<usize> {
        all.iter()
            .map(|s| record(s, &mut [0; MAX_RECORD]).len())
            .collect()
    }

    #[test]
    fn a_record_cut_short_falls_back_to_the_one_before() {
        let all = [settings(0), settings(1)];
        let mut log = region(4096, &all);
        let n = lens(&all);
        // Power lost half-way through the second record.
        for b in &mut log[n[0] + n[1] / 2..n[0] + n[1]] {
            *b = 0xFF;
        }
        let got = load(&log);
        assert_eq!(
            (got.loaded, got.settings),
            (Loaded::SavedBeforeTorn, Some(settings(0)))
        );
    }

    #[test]
    fn a_whole_record_of_settings_no_command_could_give_is_passed_over() {
        let mut tissue = settings(1);
        tissue.model.model.friction.half_band.0 = i32::MIN;
        let mut modes = settings(1);
        modes.assist_modes = AssistModes(0x80);
        let mut depth = settings(1);
        depth.target_depth = Nanometres(0);
        let mut gain = settings(1);
        gain.load_cell.gain_q16 = 0;
        for bad in [tissue, modes, depth, gain] {
            assert!(!bad.is_valid());
            let got = load(&region(4096, &[settings(0), bad]));
            assert_eq!(
                (got.loaded, got.settings),
                (Loaded::SavedBeforeTorn, Some(settings(0)))
            );
        }
        assert!(settings(2).is_valid());
    }

    #[test]
    fn garbage_or_another_format_is_invalid_and_asks_for_an_erase() {
        let garbage: Vec<u8> = (0..4096u32).map(|i| (i * 7919 % 251) as u8).collect();
        let got = load(&garbage);
        assert_eq!(
            (got.loaded, got.settings, got.next_free),
            (Loaded::Invalid, None, None)
        );
        let mut other = region(4096, &[settings(1)]);
        other[6] = FORMAT_VERSION + 1;
        let got = load(&other);
        assert_eq!(
            (got.loaded, got.settings, got.next_free),
            (Loaded::Invalid, None, None)
        );
    }

    #[test]
    fn a_full_region_keeps_its_settings_and_asks_for_an_erase() {
        let all = [settings(0), settings(1), settings(2)];
        for spare in [0, 8] {
            let log = region(lens(&all).iter().sum::<usize>() + spare, &all);
            let got = load(&log);
            assert_eq!(
                (got.loaded, got.settings, got.next_free),
                (Loaded::Saved, Some(settings(2)), None)
            );
        }
    }
}
