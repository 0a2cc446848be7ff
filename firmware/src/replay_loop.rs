//! The QEMU boards' boot loop: feeds the replay source to the core's
//! device loop sample by sample, answers the host between samples, and
//! exits QEMU with the result. (The real board's entry point is its RTIC
//! application, `hardware/nucleo_f411re/app.rs`.) Wiring only: all logic
//! lives in the core, all register access in `hardware/`.

use crate::hardware;

#[cortex_m_rt::entry]
fn main() -> ! {
    use heapless::spsc::Queue;
    use needle_holder::config::DeviceConfig;
    use needle_holder::link::{QueueWriter, QUEUE_BYTES};
    use needle_holder::replay::Replayer;

    defmt::info!(
        "needle-holder {} on {}",
        env!("CARGO_PKG_VERSION"),
        hardware::BOARD
    );
    // `--live`: wait for the host's first command, then one sample per
    // period of the replay's rate in QEMU's clock (real time unless QEMU
    // counts instructions), as a device on a serial port does. Otherwise
    // the replay runs as fast as QEMU goes.
    let live = hardware::flag_given("--live");
    let source = hardware::ReplayFile::open_from_args();
    let (mut uart, halt) = hardware::take_peripherals();
    let mut queue: Queue<u8, QUEUE_BYTES> = Queue::new();
    let (producer, mut outgoing) = queue.split();
    let mut probe = hardware::BenchMarkers::calibrated();
    let first = if live {
        first_command(&mut uart)
    } else {
        heapless::Vec::new()
    };
    let mut replay =
        match Replayer::start(source, DeviceConfig::default(), QueueWriter(producer), halt) {
            Ok(replay) => replay,
            Err(summary) => {
                while !uart.send_waiting(&mut outgoing) {}
                report(&summary)
            }
        };
    replay.receive(&first);
    let mut clock = live.then(|| hardware::SampleClock::start(replay.sample_rate_hz()));
    let mut incoming = [0u8; 64];
    loop {
        // Between samples: the link, and what the host sent.
        while !uart.send_waiting(&mut outgoing) {}
        let n = uart.received(&mut incoming);
        replay.receive(incoming.get(..n).unwrap_or(&[]));
        if let Some(clock) = clock.as_mut() {
            if !clock.period_began() {
                continue;
            }
        }
        if !replay.step(&mut probe) {
            break;
        }
    }
    let summary = replay.finish();
    while !uart.send_waiting(&mut outgoing) {}
    let _ = embedded_io::Write::flush(&mut uart);
    report(&summary)
}

/// Log the run's counters and leave QEMU.
fn report(summary: &needle_holder::device::Summary) -> ! {
    defmt::info!(
        "replay done: {=u32} samples, {=u32} frames dropped, faults {=u16:#06x}, halt {=bool}",
        summary.samples,
        summary.frames_dropped,
        summary.faults.0,
        summary.halt
    );
    hardware::exit(0)
}

/// A live run starts when the host's first command has arrived whole (up
/// to its zero): what the device must answer first.
fn first_command(uart: &mut hardware::Uart0) -> heapless::Vec<u8, 256> {
    let mut got = heapless::Vec::<u8, 256>::new();
    loop {
        let mut byte = [0u8; 1];
        if uart.received(&mut byte) == 0 {
            continue;
        }
        if byte[0] == 0 && got.iter().any(|&b| b != 0) {
            let _ = got.push(0);
            return got;
        }
        // A longer run is no command: keep its tail, the device refuses it.
        if got.is_full() {
            got.clear();
        }
        let _ = got.push(byte[0]);
    }
}
