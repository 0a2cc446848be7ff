//! The settings store: flash sector 7 (0x0806_0000, 128 KiB, RM0383
//! table 5), kept out of the image by the board's memory map, holding the
//! core's settings log ([`needle_holder::persist`]).
//!
//! Read at boot; erased at boot only (before sampling starts: an erase
//! stalls every flash fetch for 1–2 s) when the log is full or unreadable;
//! appended to from `idle` after a command changed the settings
//! (programming stalls the flash for microseconds at a time).

use needle_holder::persist::{self, Load, Settings, MAX_RECORD, MIN_ROOM};
use stm32f4::stm32f411::FLASH;

/// The sector's number.
const SECTOR: u8 = 7;
/// Its address.
const BASE: usize = 0x0806_0000;
/// Its size.
const LEN: usize = 128 * 1024;

/// The flash controller's unlock sequence (RM0383 §3.5.1).
const KEYS: [u32; 2] = [0x4567_0123, 0xCDEF_89AB];

/// Polls of the busy flag before an operation is given up as hung: each
/// poll takes at least three cycles, so at 100 MHz these bounds are at
/// least the operation's longest time (F411 datasheet, table 46: a
/// 128 KiB sector erase ≤ 4 s, a byte ≤ 100 µs), and longer on a slower
/// clock. While the flash works, fetches from it stall and polls are
/// fewer still.
const ERASE_POLLS: u32 = 150_000_000;
const PROGRAM_POLLS: u32 = 10_000;

/// Why settings were not kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum SaveError {
    /// No room until the next boot erases the sector.
    Full,
    /// The flash did not finish within its longest time, or flagged an
    /// error: a `settings_store` fault.
    Flash,
}

/// The settings sector, through the flash controller's registers
/// (RM0383 §3.5–3.6): unlocked for one operation at a time, every error
/// flag read back.
pub struct Store {
    flash: FLASH,
    /// Where the next record goes; `None` when full (or the write failed).
    next_free: Option<usize>,
}

impl Store {
    /// Read the log.
    pub fn open(flash: FLASH) -> (Self, Load) {
        // SAFETY: the sector is memory-mapped flash that the memory map
        // keeps out of the image; it changes only through `self`, which
        // holds no reference into it while it does.
        let sector = unsafe { core::slice::from_raw_parts(BASE as *const u8, LEN) };
        let load = persist::load(sector);
        let next_free = load.next_free;
        (Self { flash, next_free }, load)
    }

    /// At boot, before sampling: a full or unreadable log is erased, and
    /// `keep` (the settings in force) written back at its start.
    pub fn prepare(&mut self, keep: Option<&Settings>) -> Result<(), SaveError> {
        if self.next_free.is_some() {
            return Ok(());
        }
        defmt::warn!("settings sector full or unreadable: erasing it");
        if !self.erase() {
            defmt::error!("settings sector: erase failed");
            return Err(SaveError::Flash);
        }
        self.next_free = Some(0);
        match keep {
            Some(settings) => self.save(settings),
            None => Ok(()),
        }
    }

    /// Append `settings`.
    pub fn save(&mut self, settings: &Settings) -> Result<(), SaveError> {
        let Some(at) = self.next_free else {
            defmt::warn!("settings sector full: not kept until the next boot erases it");
            return Err(SaveError::Full);
        };
        let mut buf = [0u8; MAX_RECORD];
        let record = persist::record(settings, &mut buf);
        let end = at + record.len();
        if record.is_empty() || end > LEN {
            self.next_free = None;
            return Err(SaveError::Full);
        }
        let written = self.program(BASE + at, record);
        self.next_free = (written && LEN - end >= MIN_ROOM).then_some(end);
        if !written {
            defmt::error!("settings sector: programming failed");
            return Err(SaveError::Flash);
        }
        Ok(())
    }

    /// Erase the sector (1–2 s, every flash fetch stalled meanwhile).
    fn erase(&mut self) -> bool {
        self.unlocked(|flash| {
            // SAFETY: the sector number is one of the chip's (0..=7).
            flash.cr().modify(|_, w| unsafe {
                w.psize().psize32();
                w.snb().bits(SECTOR);
                w.ser().sector_erase()
            });
            flash.cr().modify(|_, w| w.strt().start());
            let erased = Self::finished(flash, ERASE_POLLS);
            // `open` read the sector through the data cache: those lines
            // are stale now (RM0383 §3.4.3: reset with the cache off).
            flash.acr().modify(|_, w| w.dcen().clear_bit());
            flash.acr().modify(|_, w| w.dcrst().set_bit());
            flash
                .acr()
                .modify(|_, w| w.dcrst().clear_bit().dcen().set_bit());
            erased
        })
    }

    /// Program `bytes` from `address`, a byte at a time (any supply
    /// voltage takes that parallelism).
    fn program(&mut self, address: usize, bytes: &[u8]) -> bool {
        self.unlocked(|flash| {
            flash.cr().modify(|_, w| w.psize().psize8().pg().program());
            bytes.iter().enumerate().all(|(i, &byte)| {
                // SAFETY: inside the settings sector (the caller checked
                // the record fits), which the image never uses; with PG
                // set a byte write is a program operation.
                unsafe { ((address + i) as *mut u8).write_volatile(byte) };
                Self::finished(flash, PROGRAM_POLLS)
            })
        })
    }

    /// Run `operation` with the controller unlocked and its old error
    /// flags cleared; lock it again after, whatever happened.
    fn unlocked(&mut self, operation: impl FnOnce(&FLASH) -> bool) -> bool {
        let flash = &self.flash;
        if flash.cr().read().lock().bit_is_set() {
            for key in KEYS {
                // SAFETY: the documented key sequence.
                flash.keyr().write(|w| unsafe { w.bits(key) });
            }
        }
        // SAFETY: the flags are cleared by writing 1 (all but BSY).
        flash.sr().write(|w| unsafe { w.bits(0xF3) });
        let done = operation(flash);
        flash.cr().write(|w| w.lock().set_bit());
        done
    }

    /// Wait for the operation in hand to end, at most `polls` polls;
    /// whether it ended, and without an error flag.
    fn finished(flash: &FLASH, polls: u32) -> bool {
        if !(0..polls).any(|_| flash.sr().read().bsy().bit_is_clear()) {
            return false;
        }
        let sr = flash.sr().read();
        let failed = sr.pgserr().bit_is_set()
            || sr.pgperr().bit_is_set()
            || sr.pgaerr().bit_is_set()
            || sr.wrperr().bit_is_set()
            || sr.operr().bit_is_set();
        // Only the end-of-operation and error flags: written back to clear.
        // SAFETY: as in `unlocked`.
        flash.sr().write(|w| unsafe { w.bits(sr.bits() & 0xF3) });
        !failed
    }
}
