//! `needle live`: the insertion as it happens, in a browser. A web page
//! served on `127.0.0.1` shows force against position and against time,
//! measured and the device's model, the residual, the phases, the events
//! as they fire, the halt line, faults, the tissue and the stream's
//! health — from any device link (a serial port, or the firmware in QEMU
//! on a pseudo-terminal, which the `needle` binary starts).
//!
//! `needle live --port P` watches a device; `needle live --replay FILE`
//! runs the firmware in QEMU on a replay behind the same page, so anyone
//! can try it without hardware.
//!
//! Five parts, dependencies one way: [`view`] (what the page shows,
//! bounded, updated item by item: no I/O), [`commands`] (what the page
//! may ask and what each does), [`recording`] (trial CSVs as `needle
//! record` writes them, when the page asks), the device thread here (owns
//! the link, feeds the recording and the view, publishes an update every
//! [`UPDATE_PERIOD`], does the pages' commands between reads), and
//! [`server`] (axum: the page, its bundled plotting library, the updates
//! as server-sent events, the commands as `POST /command`).

pub mod commands;
pub mod recording;
pub mod server;
pub mod view;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use needle_holder::protocol::Command;
use needle_io::decode::command_error;
use needle_io::link::Link;
use tokio::sync::{broadcast, oneshot};

use crate::commands::{Answer, Job};
use crate::recording::Recording;
use crate::view::View;

#[derive(Debug, clap::Args)]
pub struct LiveArgs {
    /// The device's serial port (e.g. /dev/ttyACM0).
    #[arg(long, required_unless_present = "replay", conflicts_with = "replay")]
    pub port: Option<String>,
    /// Serial baud rate.
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// No device: run the firmware in QEMU on this replay file, in real
    /// time, behind the same page (`needle simulate` writes replays, one a
    /// trial; `needle demo` one of liver 1 in the target directory).
    #[arg(long)]
    pub replay: Option<PathBuf>,
    /// Where to serve the page. Loopback on a free port unless asked:
    /// the page sends the device commands.
    #[arg(long, default_value = "127.0.0.1:0")]
    pub listen: SocketAddr,
    /// Where the page's Record button records to: a new directory beneath
    /// this one each time (recording-001, recording-002, …), trial CSVs
    /// and stream.bin as `needle record` writes them.
    #[arg(long, default_value = "recordings")]
    pub record_into: PathBuf,
}

/// `needle live`.
pub fn run_command(args: &LiveArgs) -> Result<()> {
    match (&args.replay, &args.port) {
        (Some(replay), _) => {
            if !replay.is_file() {
                anyhow::bail!("{}: no such replay file", replay.display());
            }
            let board = needle_qemu::firmware::Board::Lm3s6965;
            needle_qemu::firmware::ensure_qemu()?;
            let elf = needle_qemu::firmware::build(board)?;
            // Kept to the end: dropping it stops QEMU.
            let qemu = needle_qemu::firmware::QemuLive::start(board, &elf, replay)?;
            let link = Link::open(&qemu.port, args.baud)?;
            let source = format!("the firmware in QEMU, replaying {}", replay.display());
            run(link, &source, args)
        }
        (None, Some(port)) => run(Link::open(port, args.baud)?, port, args),
        (None, None) => anyhow::bail!("give --port (a device) or --replay (QEMU)"),
    }
}

/// How often the pages get what changed: 10 a second.
pub const UPDATE_PERIOD: Duration = Duration::from_millis(100);

/// Updates a page may fall behind by before it is told to start afresh
/// (a minute of them).
const UPDATES_QUEUED: usize = 600;

/// What the device thread and the pages share: the view, and the channel
/// its updates go out on (sent while the view is held, so a page that
/// takes the snapshot and subscribes under the same hold misses none).
pub struct Shared {
    view: Mutex<View>,
    updates: broadcast::Sender<Arc<str>>,
    /// Commands for the device thread, which alone writes to the link.
    commands: std::sync::mpsc::SyncSender<Asked>,
    /// `needle live` is stopping: the device thread ends the recording
    /// and returns.
    stop: AtomicBool,
}

/// Commands waiting for the device at most: each can take seconds (a
/// device that does not answer is asked three times).
const COMMANDS_QUEUED: usize = 4;

/// Why a command was not handed to the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NotAsked {
    /// As many as may wait are waiting already (4).
    Busy,
    /// The device thread has stopped: the device is gone.
    Gone,
}

/// What the page asked for, and where its answer goes.
pub struct Asked {
    pub job: Job,
    /// What was asked, in the page's words.
    pub what: String,
    pub answer: oneshot::Sender<Answer>,
}

impl Shared {
    /// A view of `source`, nothing seen yet, and where the device thread
    /// takes the page's commands from.
    pub fn new(source: &str) -> (Arc<Self>, std::sync::mpsc::Receiver<Asked>) {
        let (commands, asked) = std::sync::mpsc::sync_channel(COMMANDS_QUEUED);
        let shared = Arc::new(Self {
            view: Mutex::new(View::new(source)),
            updates: broadcast::channel(UPDATES_QUEUED).0,
            commands,
            stop: AtomicBool::new(false),
        });
        (shared, asked)
    }

    /// Hand `asked` to the device thread, or say why not.
    pub fn ask(&self, asked: Asked) -> Result<(), NotAsked> {
        self.commands.try_send(asked).map_err(|e| match e {
            std::sync::mpsc::TrySendError::Full(_) => NotAsked::Busy,
            std::sync::mpsc::TrySendError::Disconnected(_) => NotAsked::Gone,
        })
    }

    /// The view now, as JSON, and the updates from then on: what the view
    /// holds but has not sent goes to the pages already open first, so
    /// the new page gets it once, in its snapshot.
    pub fn subscribe(&self) -> (String, broadcast::Receiver<Arc<str>>) {
        let mut view = self.lock();
        if let Some(pending) = view.take_pending() {
            self.publish(&pending);
        }
        let snapshot = serde_json::to_string(&view.snapshot()).unwrap_or_else(|_| "{}".into());
        (snapshot, self.updates.subscribe())
    }

    /// Send `update` to every open page (none open is not an error).
    fn publish(&self, update: &view::Update) {
        if let Ok(json) = serde_json::to_string(update) {
            let _ = self.updates.send(json.into());
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, View> {
        // A thread that panicked while holding it left a view that is
        // still whole (every change is one assignment or push).
        self.view.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Start `link`'s stream and serve the live view on `args.listen` until
/// Ctrl-C, SIGTERM or SIGHUP; `source` names the device on the page. Prints the
/// address to open. A recording under way when it stops is finished
/// first, as `needle record` finishes one.
pub fn run(mut link: Link, source: &str, args: &LiveArgs) -> Result<()> {
    if let Err(e) = link.command(Command::Stream(true))? {
        anyhow::bail!(
            "{source}: the device refused to stream: {}",
            command_error(&e)
        );
    }
    let listen = args.listen;
    let listener = std::net::TcpListener::bind(listen)
        .with_context(|| format!("cannot listen on {listen}"))?;
    listener.set_nonblocking(true)?;
    let address = listener.local_addr()?;
    needle_io::out!("live view at http://{address}/ (Ctrl-C stops)")?;
    let (shared, asked) = Shared::new(source);
    let feeding = shared.clone();
    let recording = Recording::new(&args.record_into);
    let device = std::thread::spawn(move || feed(link, &feeding, &asked, recording));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the web server's runtime")?;
    let served = runtime.block_on(async {
        let listener = tokio::net::TcpListener::from_std(listener)?;
        tokio::select! {
            served = server::serve(listener, shared.clone()) => served,
            () = stopped() => Ok(()),
        }
    });
    shared.stop.store(true, Ordering::SeqCst);
    if device.join().is_err() {
        needle_io::note!("needle live: the device thread failed");
    }
    served
}

/// Ctrl-C, SIGTERM or SIGHUP: `run` returns, and the QEMU behind a replay
/// is stopped with it (a killed `needle live` would leave it running until
/// its replay ends).
async fn stopped() {
    #[cfg(unix)]
    let terminated = async {
        use tokio::signal::unix::{signal, SignalKind};
        // `kill`, and a terminal closed under it (unless started under
        // `nohup`, which ignores that), as `needle record` takes them.
        let on = |kind: SignalKind| async move {
            match signal(kind) {
                Ok(mut stream) => {
                    stream.recv().await;
                }
                Err(_) => std::future::pending::<()>().await,
            }
        };
        let hangup = async {
            if ignored(libc::SIGHUP) {
                std::future::pending::<()>().await;
            }
            on(SignalKind::hangup()).await;
        };
        tokio::select! {
            () = on(SignalKind::terminate()) => {}
            () = hangup => {}
        }
    };
    #[cfg(not(unix))]
    let terminated = std::future::pending::<()>();
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        () = terminated => {}
    }
}

/// Whether `signal` was set to be ignored when the process started.
#[cfg(unix)]
fn ignored(signal: libc::c_int) -> bool {
    // SAFETY: a query only (no new action given); `old` is plain data that
    // sigaction fills in.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(signal, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_IGN
    }
}

/// Read the device until its link closes or `needle live` stops, feeding
/// the recording and the view, publishing what changed every
/// [`UPDATE_PERIOD`] and doing the pages' commands between reads. The
/// link is this thread's alone: a page cannot hold up reading it, and the
/// frames read while a command waits for its reply are published with the
/// next update.
fn feed(
    mut link: Link,
    shared: &Shared,
    asked: &std::sync::mpsc::Receiver<Asked>,
    mut recording: Recording,
) {
    let mut last_update = Instant::now();
    let mut samples_then = 0u64;
    let mut rate = RateOverASecond::default();
    loop {
        let (items, problem) = match link.poll() {
            Ok(items) => (items, None),
            Err(e) => (Vec::new(), Some(format!("{e:#}"))),
        };
        let closed = link.closed() || problem.is_some();
        let stopping = shared.stop.load(Ordering::SeqCst);
        let mut view = shared.lock();
        for item in &items {
            recording.item(&mut link, &mut view, item);
            view.apply(item);
        }
        recording.check_capture(&mut link, &mut view);
        if closed {
            if let Some(problem) = &problem {
                needle_io::note!("needle live: {problem}");
            }
            view.disconnected(problem);
        }
        if closed || stopping {
            for item in link.finish() {
                recording.item(&mut link, &mut view, &item);
            }
            let why = if closed {
                "the device went away"
            } else {
                "needle live stopped"
            };
            // Not recording is no news here.
            let _ = recording.stop(&mut link, &mut view, why, "record");
        }
        if closed || stopping || last_update.elapsed() >= UPDATE_PERIOD {
            recording.show(&mut view);
            let stats = link.decoder().stats();
            let now = Instant::now();
            let per_s = rate.add(now, stats.samples - samples_then);
            samples_then = stats.samples;
            last_update = now;
            shared.publish(&view.take_update(&stats, per_s));
        }
        drop(view);
        if closed || stopping {
            return;
        }
        // One a turn: the device is read between commands.
        if let Ok(asked) = asked.try_recv() {
            let answer = answer(&mut link, shared, &mut recording, &asked);
            // A page that closed before the answer came is not an error.
            let _ = asked.answer.send(answer);
        }
    }
}

/// Do what the page asked.
fn answer(link: &mut Link, shared: &Shared, recording: &mut Recording, asked: &Asked) -> Answer {
    let what = &asked.what;
    match asked.job {
        Job::Device(command) => match link.command(command) {
            Ok(Ok(())) => Answer::done(what),
            Ok(Err(why)) => {
                Answer::not(what, format!("the device refused: {}", command_error(&why)))
            }
            Err(e) => Answer::not(what, format!("{e:#}")),
        },
        Job::Record(true) => {
            let rate_hz = shared.lock().sample_rate_hz();
            recording.start(link, rate_hz, what)
        }
        Job::Record(false) => {
            let mut view = shared.lock();
            recording.stop(link, &mut view, "stopped from the page", what)
        }
    }
}

/// Samples a second over the last second, from counts at update times.
#[derive(Default)]
struct RateOverASecond {
    counts: std::collections::VecDeque<(Instant, u64)>,
}

impl RateOverASecond {
    fn add(&mut self, now: Instant, samples: u64) -> f64 {
        self.counts.push_back((now, samples));
        while self
            .counts
            .front()
            .is_some_and(|(t, _)| now.duration_since(*t) > Duration::from_secs(1))
        {
            self.counts.pop_front();
        }
        let span = self
            .counts
            .front()
            .map_or(0.0, |(t, _)| now.duration_since(*t).as_secs_f64());
        let total: u64 = self.counts.iter().skip(1).map(|(_, n)| n).sum();
        if span > 0.0 {
            (total as f64 / span).round()
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_holder::insertion::{Phase, Sample};
    use needle_holder::units::{MicroNewtons, Nanometres, NanometresPerSecond};
    use needle_io::frames::{Item, StreamStats};

    #[test]
    fn a_page_opened_between_updates_gets_each_point_once_and_an_open_page_too() {
        let (shared, _asked) = Shared::new("test");
        let mut open = shared.updates.subscribe();
        let sample = Sample {
            index: 7,
            x: Nanometres(0),
            v: NanometresPerSecond(0),
            force: MicroNewtons(0),
            model: MicroNewtons(0),
            residual: MicroNewtons(0),
            phase: Phase::Loading,
        };
        shared.lock().apply(&Item::Sample(sample));
        let (snapshot, mut opened) = shared.subscribe();
        assert!(snapshot.contains("[0.014,"), "{snapshot}");
        let sent = open
            .try_recv()
            .expect("the open page is sent what the new one is shown");
        assert!(sent.contains("[0.014,"), "{sent}");
        let next = shared.lock().take_update(&StreamStats::default(), 0.0);
        assert!(
            next.points.is_empty(),
            "not sent again with the next update"
        );
        assert!(opened.try_recv().is_err());
    }
}
