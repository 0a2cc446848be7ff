//! The real board's image with a replay in place of its sensors, for QEMU
//! `netduinoplus2`: TIM2's update interrupt at the replay's rate reads the
//! next record and runs the core's pipeline exactly as the host twin's
//! [`needle_holder::replay::run`] does (same header handling, same device
//! configuration), frames through the same queue as on the board, drained
//! by `idle` onto USART2 (QEMU's second serial port). At the end of the
//! replay the device's final status goes out, the queue drains, and QEMU
//! exits 0.

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use heapless::spsc::{Consumer, Queue};
    use needle_holder::config::DeviceConfig;
    use needle_holder::device::Device;
    use needle_holder::faults::Faults;
    use needle_holder::replay::{read_header, read_record, ReplayAdc, ReplayEncoder};
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
    use crate::hardware::bench::{needle_bench_begin, needle_bench_end, BenchMarkers};
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
        device: Device<QueueWriter, HaltLine>,
        source: ReplayFile,
        adc: ReplayAdc,
        encoder: ReplayEncoder,
        clock: CounterHz<TIM2>,
        tx: Tx<USART2>,
        outgoing: Consumer<'static, u8, QUEUE_BYTES>,
    }

    #[init(local = [queue: Queue<u8, QUEUE_BYTES> = Queue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        super::super::stack::paint();
        // The markers' own cost, once, for `needle bench` to subtract.
        let _ = BenchMarkers::calibrated();
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
        let mut source = ReplayFile::open_from_args();
        // As `replay::run`: the replay's rate, or the default's and a
        // bad-header fault.
        let config = DeviceConfig::default();
        let header = read_header(&mut source);
        let rate = match header {
            Ok(Some(h)) => h.sample_rate_hz,
            _ => config.velocity.sample_rate_hz,
        };
        let mut device = Device::new(config.with_sample_rate(rate), QueueWriter(producer), halt);
        let mut clock = dp.TIM2.counter_hz(&mut rcc);
        let done = !matches!(header, Ok(Some(_)));
        if done {
            device.raise(Faults::REPLAY_BAD_HEADER);
            device.finish();
        } else {
            // A rate the timer takes from 16 MHz (every u16 rate does).
            let _ = clock.start(u32::from(rate).Hz());
            clock.listen(Event::Update);
        }
        (
            Shared { done },
            Local {
                device,
                source,
                adc: ReplayAdc {
                    counts: 0,
                    full_scale_counts: config.load_cell.full_scale_counts,
                },
                encoder: ReplayEncoder::default(),
                clock,
                tx,
                outgoing,
            },
        )
    }

    #[task(binds = TIM2, priority = 2, shared = [done], local = [device, source, adc, encoder, clock, ended: bool = false])]
    fn sample(mut cx: sample::Context) {
        let l = cx.local;
        l.clock.clear_all_flags();
        // An update already pending when the timer was stopped.
        if *l.ended {
            return;
        }
        match read_record(l.source) {
            Ok(Some(record)) => {
                l.adc.counts = record.adc_counts;
                l.encoder.count = record.encoder_count;
                needle_bench_begin();
                l.device.tick(l.adc, l.encoder);
                needle_bench_end();
            }
            end => {
                if end.is_err() {
                    l.device.raise(Faults::REPLAY_TRUNCATED);
                }
                let summary = l.device.finish();
                defmt::info!(
                    "replay done: {=u32} samples, {=u32} frames dropped, faults {=u16:#06x}, stack high-water mark {=usize} bytes",
                    summary.samples,
                    summary.frames_dropped,
                    summary.faults.0,
                    super::super::stack::high_water_bytes()
                );
                l.clock.unlisten(Event::Update);
                *l.ended = true;
                cx.shared.done.lock(|d| *d = true);
            }
        }
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
