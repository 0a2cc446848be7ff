//! Conversions counted from the times of the converter's data-ready
//! edges, which a timer captures in hardware (input capture), whatever
//! the CPU was doing. The sample task reads the time of the latest edge
//! at each conversion it takes; the time since the one before, over the
//! conversion period, is how many edges fell. More than one: the
//! conversions before the latest were never read (the converter keeps
//! only its newest), because the task was blocked — by a lock, a flash
//! stall, a critical section — longer than a period. An edge-pending flag
//! cannot tell that: it merges every edge after the first.
//!
//! | quantity | format | range |
//! |---|---|---|
//! | captured time | timer ticks, `u16`, wrapping | a gap is measured up to 2^16 ticks (655 ms at the real board's 10 µs tick), beyond it modulo that: after a silence the board calls [`EdgeClock::resync`] |
//! | period | ticks, `u16` | ≥ 1 |

/// The times of the edges seen so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EdgeClock {
    last: Option<u16>,
    period_ticks: u16,
}

impl EdgeClock {
    /// Edges `period_ticks` apart (the converter's own oscillator: a few
    /// per cent off the timer's clock at most, which the rounding to
    /// whole periods absorbs).
    pub const fn new(period_ticks: u16) -> Self {
        Self {
            last: None,
            period_ticks: if period_ticks == 0 { 1 } else { period_ticks },
        }
    }

    /// Start again from the next capture, which counts one: after the
    /// converter was silent (an `adc_timeout`), its gap is that fault,
    /// not conversions lost.
    pub fn resync(&mut self) {
        self.last = None;
    }

    /// The edges that fell since the last call, given the time of the
    /// latest now: 0 (none new: the capture did not move), 1 (none
    /// missed), or more. The first call counts one.
    pub fn edges_since(&mut self, captured: u16) -> u32 {
        let Some(last) = self.last.replace(captured) else {
            return 1;
        };
        let elapsed = u32::from(captured.wrapping_sub(last));
        let period = u32::from(self.period_ticks);
        // `period` ≥ 1 (`new`): checked so that no panic path is linked.
        (elapsed + period / 2).checked_div(period).unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_edge_a_period_missed_ones_counted_across_the_wrap() {
        // 1000 SPS on a 10 µs tick: 100 ticks a conversion, jittered.
        let mut clock = EdgeClock::new(100);
        let mut t: u16 = 65_000;
        assert_eq!(clock.edges_since(t), 1);
        for elapsed in [103u16, 100, 97, 102] {
            t = t.wrapping_add(elapsed);
            assert_eq!(clock.edges_since(t), 1, "{elapsed}");
        }
        // Blocked for three periods and a bit: the two before the latest
        // were lost, across the counter's wrap.
        t = t.wrapping_add(302);
        assert_eq!(clock.edges_since(t), 3);
        // The capture did not move: no edge.
        assert_eq!(clock.edges_since(t), 0);
        // A converter 3 % slow over ten missed periods still counts right.
        t = t.wrapping_add(11 * 103);
        assert_eq!(clock.edges_since(t), 11);
        // After a silence, resynchronised: the gap is not counted.
        clock.resync();
        assert_eq!(clock.edges_since(t.wrapping_add(40_000)), 1);
    }
}
