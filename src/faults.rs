//! Fault flags: what went wrong, latched, reported in every status frame.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// A set of faults, one bit each. Latched: once raised a bit stays set until
/// reset, and any set bit keeps the halt line asserted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct Faults(pub u16);

impl Faults {
    /// No fault.
    pub const NONE: Self = Self(0);
    /// The load-cell ADC was at full scale: force unknown.
    pub const ADC_SATURATED: Self = Self(1 << 0);
    /// The load-cell ADC returned an error.
    pub const ADC_ERROR: Self = Self(1 << 1);
    /// The encoder count moved further in one sample than the mechanics allow.
    pub const ENCODER_JUMP: Self = Self(1 << 2);
    /// The replay input ended in the middle of a record.
    pub const REPLAY_TRUNCATED: Self = Self(1 << 3);
    /// The replay input does not start with a valid header.
    pub const REPLAY_BAD_HEADER: Self = Self(1 << 4);
    /// A sample was taken late (the previous one was still being processed).
    pub const SAMPLE_OVERRUN: Self = Self(1 << 5);
    /// The halt output could not be driven.
    pub const HALT_OUTPUT: Self = Self(1 << 6);
    /// Force held above the contact threshold with the needle not
    /// advancing and out of the tissue: nothing there can push or pull.
    pub const FORCE_WITHOUT_CONTACT: Self = Self(1 << 7);
    /// Force rose while loading the capsule with the encoder standing still.
    pub const ENCODER_STUCK: Self = Self(1 << 8);
    /// The converter's data-ready never came (unplugged, unpowered, or
    /// stopped): no sample for longer than the board's timeout.
    pub const ADC_TIMEOUT: Self = Self(1 << 9);
    /// The load cell read beyond a plausible offset at boot: a load on the
    /// needle, which a tare would silently take for zero.
    pub const LOAD_AT_BOOT: Self = Self(1 << 10);
    /// The board's independent watchdog reset it: the firmware stopped
    /// taking samples (hung, locked up, or stuck in a loop). Raised at the
    /// boot after, so the halt stays asserted until the host re-arms.
    pub const WATCHDOG_RESET: Self = Self(1 << 11);
    /// The settings store's flash did not finish an operation within its
    /// longest time, or reported an error: settings a command changed
    /// may not survive a reset.
    pub const SETTINGS_STORE: Self = Self(1 << 12);

    /// Names of the bits, lowest first, for host-side display.
    pub const NAMES: [(Self, &'static str); 13] = [
        (Self::ADC_SATURATED, "adc_saturated"),
        (Self::ADC_ERROR, "adc_error"),
        (Self::ENCODER_JUMP, "encoder_jump"),
        (Self::REPLAY_TRUNCATED, "replay_truncated"),
        (Self::REPLAY_BAD_HEADER, "replay_bad_header"),
        (Self::SAMPLE_OVERRUN, "sample_overrun"),
        (Self::HALT_OUTPUT, "halt_output"),
        (Self::FORCE_WITHOUT_CONTACT, "force_without_contact"),
        (Self::ENCODER_STUCK, "encoder_stuck"),
        (Self::ADC_TIMEOUT, "adc_timeout"),
        (Self::LOAD_AT_BOOT, "load_at_boot"),
        (Self::WATCHDOG_RESET, "watchdog_reset"),
        (Self::SETTINGS_STORE, "settings_store"),
    ];

    /// Union of two sets.
    #[inline]
    pub const fn union(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
    /// True when every bit of `other` is set here.
    #[inline]
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }
    /// True when no bit is set.
    #[inline]
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// The names of the set bits (unknown bits are shown as `bit<N>`).
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        const UNKNOWN: [&str; 16] = [
            "bit0", "bit1", "bit2", "bit3", "bit4", "bit5", "bit6", "bit7", "bit8", "bit9",
            "bit10", "bit11", "bit12", "bit13", "bit14", "bit15",
        ];
        (0..16u16)
            .filter(move |bit| self.0 & (1 << bit) != 0)
            .map(|bit| {
                Self::NAMES
                    .iter()
                    .find(|(f, _)| f.0 == 1 << bit)
                    .map_or(UNKNOWN[bit as usize], |(_, name)| *name)
            })
    }
}
