//! The real board's image with a replay in place of its sensors, for QEMU
//! `netduinoplus2`: TIM2's update interrupt at the replay's rate reads the
//! next record and runs the core's pipeline through the same
//! [`needle_holder::replay::Replayer`] the host twin's `replay::run`
//! loops over, frames through the same queue as on the board, drained
//! by `idle` onto USART2 (QEMU's second serial port). At the end of the
//! replay the device's final status goes out, the queue drains, and QEMU
//! exits 0.

#[rtic::app(device = stm32f4::stm32f411, peripherals = true)]
mod app {
    use heapless::spsc::{Consumer, Queue};
    use needle_holder::config::DeviceConfig;
    use needle_holder::replay::Replayer;

    use super::super::clocks::{self, HSI};
    use super::super::halt::HaltLine;
    use super::super::link::{QueueWriter, QUEUE_BYTES};
    use super::super::pins;
    use super::super::serial::Usart2;
    use super::super::timer::SampleClock;
    use super::super::BOARD;
    use crate::hardware::bench::BenchMarkers;
    use crate::hardware::exit;
    use crate::hardware::replay_file::ReplayFile;

    /// QEMU ignores the baud rate; 115 200 Bd is one the USART makes from
    /// HSI's 16 MHz.
    const REPLAY_BAUD: u32 = 115_200;

    #[shared]
    struct Shared {
        /// The replay has ended and its last frame is queued.
        done: bool,
    }

    #[local]
    struct Local {
        /// The replay, until it has ended.
        replay: Option<Replayer<ReplayFile, QueueWriter, HaltLine>>,
        markers: BenchMarkers,
        clock: Option<SampleClock>,
        serial: Usart2,
        outgoing: Consumer<'static, u8, QUEUE_BYTES>,
    }

    #[init(local = [queue: Queue<u8, QUEUE_BYTES> = Queue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        super::super::stack::paint();
        let dp = cx.device;
        clocks::enable_peripherals(&dp.RCC);
        let halt = HaltLine::asserted(&dp.GPIOA);
        pins::usart2(&dp.GPIOA);
        let serial = Usart2::new(dp.USART2, HSI.pclk1_hz, REPLAY_BAUD);
        let (producer, outgoing) = cx.local.queue.split();
        defmt::info!(
            "needle-holder {} on {} (replay)",
            env!("CARGO_PKG_VERSION"),
            BOARD
        );
        let source = ReplayFile::open_from_args();
        // A bad header: its fault and final status are queued already.
        let replay = Replayer::start(
            source,
            DeviceConfig::default(),
            needle_holder::link::QueueWriter(producer),
            halt,
        )
        .ok();
        let clock = replay
            .as_ref()
            .map(|r| SampleClock::start(dp.TIM2, HSI.apb1_timer_hz, u32::from(r.sample_rate_hz())));
        (
            Shared {
                done: replay.is_none(),
            },
            Local {
                replay,
                markers: BenchMarkers::calibrated(),
                clock,
                serial,
                outgoing,
            },
        )
    }

    #[task(binds = TIM2, priority = 2, shared = [done], local = [replay, markers, clock])]
    fn sample(mut cx: sample::Context) {
        let l = cx.local;
        if let Some(clock) = l.clock.as_mut() {
            clock.clear();
        }
        // None once ended: an update already pending when the timer
        // stopped finds nothing to do.
        let Some(replay) = l.replay.as_mut() else {
            return;
        };
        if replay.step(l.markers) {
            return;
        }
        let summary = replay.finish();
        defmt::info!(
            "replay done: {=u32} samples, {=u32} frames dropped, faults {=u16:#06x}, stack high-water mark {=usize} bytes",
            summary.samples,
            summary.frames_dropped,
            summary.faults.0,
            super::super::stack::high_water_bytes()
        );
        if let Some(clock) = l.clock.as_mut() {
            clock.stop();
        }
        *l.replay = None;
        cx.shared.done.lock(|d| *d = true);
    }

    /// The link's drain, at the lowest priority: bytes to USART2 while
    /// any wait, sleep until the next sample otherwise.
    #[idle(shared = [done], local = [serial, outgoing])]
    fn idle(mut cx: idle::Context) -> ! {
        loop {
            let finished = cx.shared.done.lock(|d| *d);
            super::super::link::send_waiting(cx.local.serial, cx.local.outgoing);
            if cx.local.outgoing.ready() {
                continue;
            }
            if finished {
                // The last byte out of the shift register before QEMU goes.
                while !cx.local.serial.sent() {}
                exit(0);
            }
            cortex_m::asm::wfi();
        }
    }
}
