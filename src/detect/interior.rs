//! After the capsule: interior structures and exit, both seen as a sharp
//! fall of the force while the needle advances.
//!
//! - structure: a rise of at least `structure_rise` above a slowly
//!   following baseline, built over at least [`STRUCTURE_RISE_SAMPLES`],
//!   then a fall of at least `structure_drop` below the highest of the last
//!   [`SHARP_SAMPLES`] — a vessel wall loading up and giving way. The
//!   baseline follows the force upwards with a time constant of about 2 s
//!   (2^`baseline_shift` samples), so the slow growth of friction with
//!   depth is not a wall.
//! - exit: at the cutting front, a fall of at least `exit_drop` (half the
//!   cutting force) that takes the force that far below the baseline: the
//!   tip left the tissue, so cutting stopped (the paper's air "control
//!   tissue", §4.3). A wall's fall ends near the baseline; an exit's ends
//!   a cutting force under it.
//!
//! Either fall is only *pending* until the encoder has moved past where it
//! happened with the force still down: when the robot stops, cutting and
//! sliding friction vanish in one sample too, and that is neither. A
//! needle that has not advanced for 10 ms restarts the search (a sample
//! between two encoder steps of a slow needle is skipped).
//!
//! A fall that comes after a wall's rise is a structure wherever it ends: a
//! membrane below the capsule (skin on muscle) gives way to a softer layer,
//! under the level the force started from, and that is not the tip leaving
//! the tissue. And after a puncture the search starts only once the
//! capsule's own drop is over (two samples or more at 100 Hz): the puncture
//! fires on the drop's first sample, and the rest of it is no exit.

use super::{confidence_permille, event, DetectConfig, DetectInput};
use crate::insertion::{Event, EventKind};
use crate::units::{MicroNewtons, Nanometres};
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Samples over which a fall must come.
pub const SHARP_SAMPLES: usize = 3;
/// Samples a structure's rise must take at least.
pub const STRUCTURE_RISE_SAMPLES: u32 = 10;

/// A fall waiting for the encoder to move on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
struct Pending {
    event: Event,
    /// Position at the fall.
    x: Nanometres,
    /// The force must stay at or below this until confirmed.
    ceiling: MicroNewtons,
}

/// Interior detector state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct InteriorState {
    baseline: MicroNewtons,
    baseline_index: u32,
    peak_force: MicroNewtons,
    peak_x: Nanometres,
    peak_index: u32,
    /// Forces of the last samples while advancing, newest first.
    recent_force: [MicroNewtons; SHARP_SAMPLES],
    pending: Option<Pending>,
    /// A puncture's drop is still going on.
    settling: bool,
}

impl InteriorState {
    /// Start afresh from this sample (also drops a pending fall).
    pub fn restart(&mut self, s: DetectInput) {
        *self = Self {
            baseline: s.force,
            baseline_index: s.index,
            peak_force: s.force,
            peak_x: s.x,
            peak_index: s.index,
            recent_force: [s.force; SHARP_SAMPLES],
            pending: None,
            settling: false,
        };
    }

    /// Start afresh at a puncture, waiting for its drop to end.
    pub fn after_puncture(&mut self, s: DetectInput) {
        self.restart(s);
        self.settling = true;
    }
}

/// One sample after puncture, with the needle advancing.
pub fn update(c: &DetectConfig, st: &mut InteriorState, s: DetectInput) -> Option<Event> {
    if st.settling {
        // Still falling by a sharp step per sample: the drop goes on.
        let falling = st.recent_force[0].sub(s.force).0 >= c.structure_drop.0 / 2;
        st.restart(s);
        st.settling = falling;
        return None;
    }
    if let Some(p) = st.pending.take() {
        if s.force <= p.ceiling {
            if s.x > p.x {
                st.restart(s);
                return Some(Event {
                    index: s.index,
                    ..p.event
                });
            }
            st.pending = Some(p);
            return None;
        }
    }
    if let Some(p) = fall(c, st, s) {
        st.pending = Some(p);
        return None;
    }
    follow(c, st, s);
    None
}

/// A sharp fall at this sample, classified.
fn fall(c: &DetectConfig, st: &InteriorState, s: DetectInput) -> Option<Pending> {
    let before = st.recent_force.iter().copied().max().unwrap_or(s.force);
    let fall = before.sub(s.force);
    let below_baseline = st.baseline.sub(s.force);
    let rise = before.sub(st.baseline);
    let rise_samples = st.peak_index.wrapping_sub(st.baseline_index);
    let after_rise = rise >= c.structure_rise && rise_samples >= STRUCTURE_RISE_SAMPLES;
    let exit = s.at_cutting_front
        && !after_rise
        && fall >= c.exit_drop
        && below_baseline.0 >= c.exit_drop.0 / 2;
    if exit {
        let confidence = confidence_permille(fall, c.exit_drop);
        return Some(Pending {
            event: event(&s, EventKind::Exit, s.x, s.force, confidence),
            x: s.x,
            ceiling: before.sub(MicroNewtons(c.exit_drop.0 / 2)),
        });
    }
    let wall = after_rise && fall >= c.structure_drop;
    wall.then(|| {
        let confidence = confidence_permille(fall, c.structure_drop);
        Pending {
            event: event(
                &s,
                EventKind::Structure,
                st.peak_x,
                st.peak_force,
                confidence,
            ),
            x: s.x,
            ceiling: before.sub(MicroNewtons(c.structure_drop.0 / 2)),
        }
    })
}

/// No fall: move the baseline, the peak and the recent forces on.
fn follow(c: &DetectConfig, st: &mut InteriorState, s: DetectInput) {
    if s.force < st.baseline {
        st.restart(s);
        return;
    }
    // The baseline creeps up towards the force (rounding up, so it moves).
    let gap = s.force.sub(st.baseline).0;
    // In i64: a gap near i32::MAX plus the rounding would overflow i32.
    let shift = c.baseline_shift.min(30);
    let step = (i64::from(gap) + (1i64 << shift) - 1) >> shift;
    st.baseline = st.baseline.add(MicroNewtons(step as i32));
    if s.force > st.peak_force {
        st.peak_force = s.force;
        st.peak_x = s.x;
        st.peak_index = s.index;
    }
    st.recent_force.rotate_right(1);
    st.recent_force[0] = s.force;
}
