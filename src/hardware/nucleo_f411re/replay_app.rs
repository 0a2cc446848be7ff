//! The real board's image with a replay in place of its sensors, for QEMU
//! `netduinoplus2`: TIM2's update interrupt at the replay's rate reads the
//! next record and runs the core's pipeline through the same
//! [`needle_holder::replay::Replayer`] the host twin's `replay::run`
//! loops over, frames through the same queue as on the board, drained
//! by `idle` onto USART2 (QEMU's second serial port). At the end of the
//! replay the device's final status goes out, the queue drains, and QEMU
//! exits 0.

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use heapless::spsc::{Consumer, Queue};
    use needle_holder::config::DeviceConfig;
    use needle_holder::replay::Replayer;
    use stm32f4xx_hal::gpio::PinState;
    use stm32f4xx_hal::pac::{TIM2, USART2};
    use stm32f4xx_hal::prelude::*;
    use stm32f4xx_hal::rcc::Config;
    use stm32f4xx_hal::serial::Tx;
    use stm32f4xx_hal::timer::{CounterHz, Event};
    use stm32f4xx_hal::ClearFlags;

    use super::super::halt::HaltLine;
    use super::super::link::{QueueWriter, QUEUE_BYTES};
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
        clock: CounterHz<TIM2>,
        tx: Tx<USART2>,
        outgoing: Consumer<'static, u8, QUEUE_BYTES>,
    }

    #[init(local = [queue: Queue<u8, QUEUE_BYTES> = Queue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        super::super::stack::paint();
        let dp = cx.device;
        let mut rcc = dp.RCC.freeze(Config::hsi());
        let gpioa = dp.GPIOA.split(&mut rcc);
        let halt: HaltLine = gpioa.pa8.into_push_pull_output_in_state(PinState::High);
        let tx = match dp.USART2.tx(gpioa.pa2, REPLAY_BAUD.bps(), &mut rcc) {
            Ok(tx) => tx,
            Err(_) => exit(crate::hardware::exit_code::NO_REPLAY),
        };
        let (producer, outgoing) = cx.local.queue.split();
        defmt::info!(
            "needle-holder {} on {} (replay)",
            env!("CARGO_PKG_VERSION"),
            BOARD
        );
        let source = ReplayFile::open_from_args();
        let mut clock = dp.TIM2.counter_hz(&mut rcc);
        let replay = match Replayer::start(
            source,
            DeviceConfig::default(),
            needle_holder::link::QueueWriter(producer),
            halt,
        ) {
            Ok(replay) => {
                // A rate the timer takes from 16 MHz (every u16 rate does).
                let _ = clock.start(u32::from(replay.sample_rate_hz()).Hz());
                clock.listen(Event::Update);
                Some(replay)
            }
            // A bad header: its fault and final status are queued already.
            Err(_) => None,
        };
        (
            Shared {
                done: replay.is_none(),
            },
            Local {
                replay,
                markers: BenchMarkers::calibrated(),
                clock,
                tx,
                outgoing,
            },
        )
    }

    #[task(binds = TIM2, priority = 2, shared = [done], local = [replay, markers, clock])]
    fn sample(mut cx: sample::Context) {
        let l = cx.local;
        l.clock.clear_all_flags();
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
        l.clock.unlisten(Event::Update);
        *l.replay = None;
        cx.shared.done.lock(|d| *d = true);
    }

    /// The link's drain, at the lowest priority: bytes to USART2 while
    /// any wait, sleep until the next sample otherwise.
    #[idle(shared = [done], local = [tx, outgoing])]
    fn idle(mut cx: idle::Context) -> ! {
        loop {
            let finished = cx.shared.done.lock(|d| *d);
            super::super::link::send_waiting(cx.local.tx, cx.local.outgoing);
            if cx.local.outgoing.ready() {
                continue;
            }
            if finished {
                // The last byte out of the shift register before QEMU goes.
                while cx.local.tx.flush().is_err() {}
                exit(0);
            }
            cortex_m::asm::wfi();
        }
    }
}
