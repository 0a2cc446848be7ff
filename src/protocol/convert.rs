//! The core's vocabulary into its wire form and back: the one place the
//! two meet. Field for field; nothing is lost either way.

use needle_wire::record as wire;

use crate::assist::AssistModes;
use crate::faults::Faults;
use crate::insertion::{Event, EventKind, Halt, HaltReason};
use crate::units::{MicroNewtons, Nanometres};

macro_rules! newtype_both_ways {
    ($($core:ty => $wire:ty),* $(,)?) => {$(
        impl From<$core> for $wire {
            #[inline]
            fn from(value: $core) -> Self {
                Self(value.0)
            }
        }
        impl From<$wire> for $core {
            #[inline]
            fn from(value: $wire) -> Self {
                Self(value.0)
            }
        }
    )*};
}

newtype_both_ways! {
    MicroNewtons => wire::MicroNewtons,
    Nanometres => wire::Nanometres,
    Faults => wire::FaultBits,
    AssistModes => wire::AssistBits,
}

macro_rules! enum_both_ways {
    ($core:ident <=> $wire:ty { $($variant:ident),* $(,)? }) => {
        impl From<$core> for $wire {
            fn from(value: $core) -> Self {
                match value {
                    $($core::$variant => Self::$variant,)*
                }
            }
        }
        impl From<$wire> for $core {
            fn from(value: $wire) -> Self {
                match value {
                    $(<$wire>::$variant => Self::$variant,)*
                }
            }
        }
    };
}

enum_both_ways!(EventKind <=> wire::EventKind {
    Contact, Puncture, Structure, Exit, Fault
});
enum_both_ways!(HaltReason <=> wire::HaltReason {
    Fault, Contact, Puncture, Structure, Exit, TargetDepth, SpeedLimit
});

impl From<Event> for wire::Event {
    fn from(e: Event) -> Self {
        Self {
            index: e.index,
            kind: e.kind.into(),
            x: e.x.into(),
            force: e.force.into(),
            confidence_permille: e.confidence_permille,
        }
    }
}

impl From<wire::Event> for Event {
    fn from(e: wire::Event) -> Self {
        Self {
            index: e.index,
            kind: e.kind.into(),
            x: e.x.into(),
            force: e.force.into(),
            confidence_permille: e.confidence_permille,
        }
    }
}

impl From<Halt> for wire::Halt {
    fn from(h: Halt) -> Self {
        Self {
            index: h.index,
            reason: h.reason.into(),
            x: h.x.into(),
            hold_x: h.hold_x.into(),
        }
    }
}

impl From<wire::Halt> for Halt {
    fn from(h: wire::Halt) -> Self {
        Self {
            index: h.index,
            reason: h.reason.into(),
            x: h.x.into(),
            hold_x: h.hold_x.into(),
        }
    }
}
