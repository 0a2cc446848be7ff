//! The RTIC application: three interrupt tasks, highest priority first.
//!
//! - `sample` (EXTI10, the ADS1220's data-ready falling): read the
//!   conversion and the encoder, run the core's pipeline, queue the frame
//!   bytes, pend the drain. The converter's clock is the sample clock, so
//!   sampling never drifts against it. The first [`BootTare::SAMPLES`]
//!   conversions set the load cell's zero before the device is armed.
//! - `watchdog` (TIM5 at 25 Hz): no sample over two periods is an
//!   `adc_timeout` fault and a halt — a converter unplugged never hangs.
//!   The independent watchdog ([`super::super::iwdg`]) is fed by each
//!   sample, and here only while the device is halted for a fault: a hung
//!   chip resets, and boots into a `watchdog_reset` fault and the halt.
//! - `link` (USART2 transmit-empty and idle line, lowest): frame bytes to
//!   the wire; command bytes from it, which DMA has put in a buffer as
//!   they landed, put together into frames here, outside the sample's
//!   lock, which a whole command takes only to be carried out and
//!   answered.

#[rtic::app(device = stm32f4::stm32f411, peripherals = true)]
mod app {
    use heapless::spsc::{Consumer, Queue};
    use needle_holder::calibration::{BootTare, LoadCell, TareResult};
    use needle_holder::config::DeviceConfig;
    use needle_holder::device::{default_tissue, Device};
    use needle_holder::faults::Faults;
    use needle_holder::persist::Loaded;
    use needle_holder::protocol::command::CommandReader;
    use needle_holder::protocol::TissueSource;
    use stm32f4::stm32f411 as pac;

    use super::super::adc::{rate_for, Acquisition, Broken, Conversion, Ready};
    use super::super::capture::{EdgeCapture, TICK_HZ};
    use super::super::encoder::Encoder;
    use super::super::halt::HaltLine;
    use super::super::iwdg::{IndependentWatchdog, ResetCause};
    use super::super::link::{drain, QueueWriter, QUEUE_BYTES};
    use super::super::serial::{RxDma, Usart2, RX_BYTES};
    use super::super::setup::setup;
    use super::super::store::{SaveError, Store};
    use super::super::timer::Watchdog;
    use needle_holder::hal::EncoderCounter;
    use needle_holder::protocol::BoardFindings;
    use needle_holder::sample_clock::EdgeClock;

    type Dev = Device<QueueWriter, HaltLine>;

    /// The sample task's runs and the data-ready edges TIM1 timed, and
    /// the edges of the last whole second (the watchdog task counts it).
    #[derive(Clone, Copy, Default)]
    pub struct Seen {
        runs: u32,
        edges: u32,
        edges_per_s: Option<u32>,
        /// The converter was silent (`adc_timeout`): the next edge starts
        /// the count again, its gap not taken for lost conversions.
        resync: bool,
    }

    #[shared]
    struct Shared {
        /// The device once armed (after the boot tare, or at a fault).
        device: Option<Dev>,
        /// Its sink and halt line until then.
        unarmed: Option<(QueueWriter, HaltLine)>,
        /// What the sample task has seen, for the watchdog and the
        /// self-test.
        seen: Seen,
        config: DeviceConfig,
        /// Where the configuration came from (the tissue's source and
        /// what the settings store held) and the faults the boot found
        /// (a watchdog reset), raised when the device is armed.
        origin: (TissueSource, Loaded, Faults),
        /// Fed by the sample task, and by the watchdog task only while
        /// the device is halted for a fault.
        iwdg: IndependentWatchdog,
    }

    #[local]
    struct Local {
        acquisition: Acquisition,
        edges: EdgeCapture,
        edge_clock: EdgeClock,
        /// Conversions whose data-ready fell but that were never read.
        conversions_lost: u32,
        encoder: Encoder,
        tare: BootTare,
        serial: Usart2,
        receiver: RxDma,
        /// Receive errors (overrun, noise, framing) since boot.
        line_errors: u32,
        commands: CommandReader,
        outgoing: Consumer<'static, u8, QUEUE_BYTES>,
        watchdog: Watchdog,
        store: Store,
    }

    /// The sample rate, chosen at build time (features `rate-1khz`,
    /// `rate-2khz`; 500 Hz, the paper's, otherwise).
    const SAMPLE_RATE_HZ: u16 = if cfg!(feature = "rate-2khz") {
        2000
    } else if cfg!(feature = "rate-1khz") {
        1000
    } else {
        500
    };

    #[init(local = [
        queue: Queue<u8, QUEUE_BYTES> = Queue::new(),
        received: [u8; RX_BYTES] = [0; RX_BYTES],
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        super::super::stack::paint();
        let mut base = DeviceConfig::default().with_sample_rate(SAMPLE_RATE_HZ);
        base.load_cell = LoadCell::LSB200_2LB_ADS1220;
        let parts = setup(cx.device, base.velocity.sample_rate_hz);
        // The saved tissue, calibration and assist, or the compiled
        // default (the config frame says which).
        let (mut store, load) = Store::open(parts.flash);
        let store_ready = store.prepare(load.settings.as_ref());
        defmt::info!("settings: {}", load.loaded);
        let (config, tissue) = match &load.settings {
            Some(s) => (s.applied_to(&base), s.tissue),
            None => (base, default_tissue()),
        };
        defmt::info!(
            "needle-holder {} on {} at {=u16} Hz",
            env!("CARGO_PKG_VERSION"),
            super::super::BOARD,
            config.velocity.sample_rate_hz
        );
        let mut boot_faults = Faults::NONE;
        if parts.reset_cause == ResetCause::Watchdog {
            defmt::error!("reset by the independent watchdog: watchdog_reset, halt kept");
            boot_faults = boot_faults.union(Faults::WATCHDOG_RESET);
        }
        if store_ready == Err(SaveError::Flash) {
            boot_faults = boot_faults.union(Faults::SETTINGS_STORE);
        }
        let (producer, outgoing) = cx.local.queue.split();
        let (iwdg, dbgmcu) = parts.iwdg;
        let mut shared = Shared {
            device: None,
            unarmed: Some((needle_holder::link::QueueWriter(producer), parts.halt)),
            seen: Seen::default(),
            config,
            origin: (tissue, load.loaded, boot_faults),
            iwdg: IndependentWatchdog::start(iwdg, &dbgmcu),
        };
        if let Err(e) = parts.converter_started {
            defmt::error!("ADS1220 did not start: {}", defmt::Debug2Format(&e));
            arm(
                &mut shared.device,
                &mut shared.unarmed,
                &config,
                shared.origin,
                Faults::ADC_ERROR,
            );
        }
        // Edges latched during start-up (the converter runs from
        // `setup` on; an erase above stalls for seconds): the first sample
        // waits for the next one.
        let mut acquisition = parts.acquisition;
        acquisition.converter.data_ready_pin().clear_pending();
        let mut serial = parts.serial;
        let receiver = RxDma::start(parts.dma1, &mut serial, cx.local.received);
        (
            shared,
            Local {
                acquisition,
                edges: parts.edges,
                edge_clock: EdgeClock::new(conversion_period_ticks(config.velocity.sample_rate_hz)),
                conversions_lost: 0,
                encoder: parts.encoder,
                // Beyond 0.5 N the needle is loaded, and taring would hide
                // the load.
                tare: BootTare::new(
                    i32::try_from(config.load_cell.most_tare_offset_counts()).unwrap_or(i32::MAX),
                ),
                serial,
                receiver,
                line_errors: 0,
                commands: CommandReader::default(),
                outgoing,
                watchdog: parts.watchdog,
                store,
            },
        )
    }

    /// The converter's conversions a second at the rate a sample rate
    /// sets it to.
    fn conversions_per_s(sample_rate_hz: u16) -> u32 {
        rate_for(sample_rate_hz).0.sps()
    }

    /// Timer ticks between two of the converter's conversions.
    fn conversion_period_ticks(sample_rate_hz: u16) -> u16 {
        let sps = conversions_per_s(sample_rate_hz);
        u16::try_from(TICK_HZ.checked_div(sps).unwrap_or(1)).unwrap_or(u16::MAX)
    }

    /// The device, armed now with `config` if it was not yet, with
    /// `faults` and those the boot found raised. Armed with a fault, it
    /// never releases the halt line the board held high until then.
    fn arm<'a>(
        device: &'a mut Option<Dev>,
        unarmed: &mut Option<(QueueWriter, HaltLine)>,
        config: &DeviceConfig,
        (tissue, stored, boot_faults): (TissueSource, Loaded, Faults),
        faults: Faults,
    ) -> Option<&'a mut Dev> {
        match device {
            Some(d) => d.raise(faults),
            None => {
                if let Some((sink, halt)) = unarmed.take() {
                    let faults = boot_faults.union(faults);
                    *device = Some(Device::restored_with(
                        *config, tissue, stored, faults, sink, halt,
                    ));
                }
            }
        }
        device.as_mut()
    }

    #[task(binds = EXTI15_10, priority = 3, shared = [device, unarmed, seen, config, origin, iwdg], local = [acquisition, edges, edge_clock, conversions_lost, encoder, tare])]
    fn sample(mut cx: sample::Context) {
        let acquisition = cx.local.acquisition;
        acquisition.converter.data_ready_pin().clear_pending();
        // Edges the timer captured since the last conversion taken: more
        // than one, and the converter overwrote the ones between (this
        // task was held off past a period). The sample is late.
        if cx.shared.seen.lock(|s| core::mem::take(&mut s.resync)) {
            cx.local.edge_clock.resync();
        }
        let edges = cx.local.edge_clock.edges_since(cx.local.edges.latest());
        let lost = cx.local.conversions_lost;
        if edges > 1 {
            *lost = lost.saturating_add(edges - 1);
            defmt::warn!(
                "{=u32} conversions lost ({=u32} since boot)",
                edges - 1,
                *lost
            );
            acquisition.overrun = true;
        }
        let conversion = acquisition.convert();
        let mut shared = (
            cx.shared.device,
            cx.shared.unarmed,
            cx.shared.seen,
            cx.shared.config,
            cx.shared.origin,
            cx.shared.iwdg,
        );
        let (encoder, tare) = (cx.local.encoder, cx.local.tare);
        shared.lock(|device, unarmed, seen, config, origin, iwdg| {
            seen.runs = seen.runs.wrapping_add(1);
            seen.edges = seen.edges.wrapping_add(edges);
            if !matches!(conversion, Conversion::Stale) {
                iwdg.feed();
            }
            match conversion {
                Conversion::Partial | Conversion::Stale => {}
                Conversion::Failed(e) => {
                    defmt::error!("ADS1220: {}", defmt::Debug2Format(&e));
                    if let Some(d) = arm(device, unarmed, config, *origin, Faults::ADC_ERROR) {
                        d.tick(&mut Broken, encoder);
                    }
                }
                Conversion::Sample(sample) => {
                    if let Some(d) = device.as_mut() {
                        d.board_counters_mut().conversions_lost = *lost;
                    }
                    if device.is_none() {
                        match tare.add(sample.counts) {
                            TareResult::Collecting => {}
                            TareResult::Zero(zero) => {
                                config.load_cell.tare_counts = zero;
                                defmt::info!("tare {=i32} counts: armed", zero);
                                arm(device, unarmed, config, *origin, Faults::NONE);
                            }
                            TareResult::Loaded(mean) => {
                                defmt::error!("load at boot: {=i32} counts", mean);
                                arm(device, unarmed, config, *origin, Faults::LOAD_AT_BOOT);
                            }
                        }
                    } else if let Some(d) = device.as_mut() {
                        d.tick(&mut Ready(sample), encoder);
                    }
                }
            }
            let asked = device.as_mut().is_some_and(|d| d.self_test_asked());
            if let Some(d) = device.as_mut().filter(|_| asked) {
                let findings = BoardFindings {
                    // A bus that fails reads as all zeros: a failed check.
                    adc_registers: match acquisition.converter.registers() {
                        Ok(registers) => registers,
                        Err(_) => acquisition.converter.written().map(|w| ([0; 4], w)),
                    },
                    data_ready_per_s: seen.edges_per_s,
                    data_ready_expected_per_s: conversions_per_s(config.velocity.sample_rate_hz),
                    encoder_count: Some(encoder.count()),
                };
                d.send_self_test(findings);
            }
        });
        // Data-ready fell again while this sample was in hand: the next
        // one is late.
        if acquisition.converter.data_ready_pin().pending() {
            acquisition.overrun = true;
        }
        rtic::pend(pac::Interrupt::USART2);
    }

    #[task(binds = TIM5, priority = 2, shared = [device, unarmed, seen, config, origin, iwdg], local = [watchdog, last_seen: u32 = 0, quiet: u8 = 0, ticks: u32 = 0, second_began: Option<u32> = None])]
    fn watchdog(mut cx: watchdog::Context) {
        cx.local.watchdog.clear();
        // Every 10 s, how deep the stack has been.
        *cx.local.ticks = cx.local.ticks.wrapping_add(1);
        if cx
            .local
            .ticks
            .is_multiple_of(10 * super::super::setup::WATCHDOG_HZ)
        {
            defmt::info!(
                "stack high-water mark {=usize} bytes",
                super::super::stack::high_water_bytes()
            );
        }
        let whole_second = cx
            .local
            .ticks
            .is_multiple_of(super::super::setup::WATCHDOG_HZ);
        let began = cx.local.second_began;
        let (last_seen, was_quiet) = (*cx.local.last_seen, *cx.local.quiet >= 2);
        let (seen, edges_per_s) = cx.shared.seen.lock(|s| {
            if began.is_none() || whole_second {
                s.edges_per_s = began.map(|b| s.edges.wrapping_sub(b));
                *began = Some(s.edges);
            }
            s.resync |= s.runs == last_seen && was_quiet;
            (s.runs, s.edges_per_s)
        });
        let silent = seen == *cx.local.last_seen;
        if silent {
            *cx.local.quiet = cx.local.quiet.saturating_add(1);
        } else {
            (*cx.local.last_seen, *cx.local.quiet) = (seen, 0);
        }
        let quiet = *cx.local.quiet >= 2;
        let mut shared = (
            cx.shared.device,
            cx.shared.unarmed,
            cx.shared.config,
            cx.shared.origin,
        );
        let halted_for_fault = shared.lock(|device, unarmed, config, origin| {
            if quiet {
                // Raised again on every quiet tick (a no-op while latched):
                // a re-arm with the converter still silent halts again.
                arm(device, unarmed, config, *origin, Faults::ADC_TIMEOUT);
            }
            // The sample task answers a self-test; with the converter
            // silent it does not run, and this does, with what it has.
            let asked = silent && device.as_mut().is_some_and(|d| d.self_test_asked());
            if let Some(d) = device.as_mut().filter(|_| asked) {
                d.send_self_test(BoardFindings {
                    adc_registers: None,
                    data_ready_per_s: edges_per_s,
                    data_ready_expected_per_s: conversions_per_s(config.velocity.sample_rate_hz),
                    encoder_count: None,
                });
            }
            device
                .as_ref()
                .is_some_and(|d| d.summary().halted_for_fault())
        });
        if quiet && *cx.local.quiet == 2 {
            defmt::error!("no data-ready: adc_timeout");
            rtic::pend(pac::Interrupt::USART2);
        }
        // After the raise: the tick that finds the converter silent also
        // keeps the independent watchdog from resetting the report away.
        if halted_for_fault {
            cx.shared.iwdg.lock(|iwdg| iwdg.feed());
        }
    }

    #[task(binds = USART2, priority = 1, shared = [device], local = [serial, receiver, line_errors, commands, outgoing])]
    fn link(mut cx: link::Context) {
        // A byte with a framing or noise error is in the buffer all the
        // same, an overrun loses one: either way the frame fails its CRC
        // and the device says so.
        let errors = cx.local.serial.take_line_events();
        let device = &mut cx.shared.device;
        if errors > 0 {
            let total = cx.local.line_errors.saturating_add(errors);
            *cx.local.line_errors = total;
            defmt::warn!("USART2 receive errors: {=u32}", total);
            device.lock(|device| {
                if let Some(d) = device.as_mut() {
                    d.board_counters_mut().line_errors = total;
                }
            });
        }
        let commands = cx.local.commands;
        cx.local.receiver.read(|byte| {
            if let Some(frame) = commands.push(byte) {
                // Before arming (the boot tare, half a second) there is
                // no device to answer: the host sends again.
                device.lock(|device| {
                    if let Some(d) = device.as_mut() {
                        d.answer(frame);
                    }
                });
            }
        });
        drain(cx.local.serial, cx.local.outgoing);
    }

    /// Between interrupts: settings a command changed go to flash (each
    /// programmed byte stalls the flash for microseconds, so samples keep
    /// their time).
    #[idle(shared = [device], local = [store])]
    fn idle(mut cx: idle::Context) -> ! {
        loop {
            let changed = cx
                .shared
                .device
                .lock(|device| device.as_mut().and_then(|d| d.settings_to_save()));
            if let Some(settings) = changed {
                match cx.local.store.save(&settings) {
                    Ok(()) => defmt::info!("settings saved"),
                    Err(SaveError::Full) => {}
                    Err(SaveError::Flash) => cx.shared.device.lock(|device| {
                        if let Some(d) = device.as_mut() {
                            d.raise(Faults::SETTINGS_STORE);
                        }
                    }),
                }
            }
            cortex_m::asm::wfi();
        }
    }
}
