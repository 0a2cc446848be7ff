//! A timer's update interrupt at a rate: the board's watchdog (TIM5) and
//! the replay image's sample clock (TIM2). Their registers have the same
//! layout under different types in the peripheral access crate, hence the
//! macro.

/// Prescaler and reload for `rate_hz` updates a second from `clock_hz`:
/// the counter runs at clock / (psc + 1) and updates every arr + 1 counts;
/// the prescaler is the smallest that keeps arr within 16 bits (either
/// timer takes it), so the rate is as exact as the clock allows.
pub fn period(clock_hz: u32, rate_hz: u32) -> (u16, u32) {
    let ticks = clock_hz.checked_div(rate_hz).unwrap_or(u32::MAX).max(1);
    let psc = (ticks - 1) / 65_536;
    let arr = ticks.checked_div(psc + 1).unwrap_or(1).saturating_sub(1);
    (psc as u16, arr)
}

macro_rules! periodic_timer {
    ($name:ident, $tim:ty) => {
        /// The timer's update interrupt at a rate.
        pub struct $name($tim);

        impl $name {
            /// Updating `rate_hz` times a second from `clock_hz`, with
            /// its interrupt on.
            pub fn start(tim: $tim, clock_hz: u32, rate_hz: u32) -> Self {
                let (psc, arr) = super::timer::period(clock_hz, rate_hz);
                // SAFETY: any values are a prescaler and a reload.
                tim.psc().write(|w| unsafe { w.bits(u32::from(psc)) });
                tim.arr().write(|w| unsafe { w.bits(arr) });
                // Load them now, then forget that update.
                tim.egr().write(|w| w.ug().set_bit());
                tim.sr().write(|w| unsafe { w.bits(0) });
                tim.dier().write(|w| w.uie().set_bit());
                tim.cr1().write(|w| w.cen().set_bit());
                Self(tim)
            }

            /// Acknowledge the update interrupt.
            pub fn clear(&mut self) {
                // SAFETY: the flags are cleared by writing 0.
                self.0.sr().write(|w| unsafe { w.bits(0) });
            }

            /// No more updates.
            #[allow(dead_code)] // the replay's clock stops; the watchdog never
            pub fn stop(&mut self) {
                self.0.dier().write(|w| w.uie().clear_bit());
                self.0.cr1().write(|w| w.cen().clear_bit());
            }
        }
    };
}

#[cfg(not(feature = "f411-replay"))]
periodic_timer!(Watchdog, stm32f4::stm32f411::TIM5);
#[cfg(feature = "f411-replay")]
periodic_timer!(SampleClock, stm32f4::stm32f411::TIM2);
