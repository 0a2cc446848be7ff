//! The settings store: flash sector 7 (0x0806_0000, 128 KiB, RM0383
//! table 5), kept out of the image by the board's memory map, holding the
//! core's settings log ([`needle_holder::persist`]).
//!
//! Read at boot; erased at boot only (before sampling starts: an erase
//! stalls every flash fetch for 1–2 s) when the log is full or unreadable;
//! appended to from `idle` after a command changed the settings
//! (programming stalls the flash for microseconds at a time).

use needle_holder::persist::{self, Load, Settings, MAX_RECORD, MIN_ROOM};
use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
use stm32f4xx_hal::pac::FLASH;

/// The sector's number.
const SECTOR: u8 = 7;
/// Its offset from the start of flash.
const OFFSET: usize = 0x6_0000;
/// Its size.
const LEN: usize = 128 * 1024;

/// The settings sector.
pub struct Store {
    flash: LockedFlash,
    /// Where the next record goes; `None` when full (or the write failed).
    next_free: Option<usize>,
}

impl Store {
    /// Read the log.
    pub fn open(flash: FLASH) -> (Self, Load) {
        let flash = LockedFlash::new(flash);
        let load = persist::load(flash.read().get(OFFSET..OFFSET + LEN).unwrap_or(&[]));
        let next_free = load.next_free;
        (Self { flash, next_free }, load)
    }

    /// At boot, before sampling: a full or unreadable log is erased, and
    /// `keep` (the settings in force) written back at its start.
    pub fn prepare(&mut self, keep: Option<&Settings>) {
        if self.next_free.is_some() {
            return;
        }
        defmt::warn!("settings sector full or unreadable: erasing it");
        if self.flash.unlocked().erase(SECTOR).is_err() {
            defmt::error!("settings sector: erase failed");
            return;
        }
        self.next_free = Some(0);
        if let Some(settings) = keep {
            self.save(settings);
        }
    }

    /// Append `settings`; whether they are kept.
    pub fn save(&mut self, settings: &Settings) -> bool {
        let Some(at) = self.next_free else {
            defmt::warn!("settings sector full: not kept until the next boot erases it");
            return false;
        };
        let mut buf = [0u8; MAX_RECORD];
        let record = persist::record(settings, &mut buf);
        let end = at + record.len();
        if record.is_empty() || end > LEN {
            self.next_free = None;
            return false;
        }
        let written = self
            .flash
            .unlocked()
            .program(OFFSET + at, record.iter())
            .is_ok();
        self.next_free = (written && LEN - end >= MIN_ROOM).then_some(end);
        if !written {
            defmt::error!("settings sector: programming failed");
        }
        written
    }
}
