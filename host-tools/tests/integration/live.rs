//! `needle live` over HTTP, as a browser meets it, against the firmware
//! in QEMU replaying a liver insertion in real time: the page and its
//! bundled plotting library, a clear 404, and the puncture reported to a
//! page as it happens and to a page opened after it.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use needle_analysis::sim::{self, Plan};
use needle_holder::model::params::LIVER1;

/// `needle live` stopped when the test ends, however it ends: SIGTERM,
/// as a user's `kill` would (it then stops its QEMU), and SIGKILL if it
/// has not gone in 10 s.
pub(crate) struct Live(Child);

impl Live {
    /// `needle live --replay REPLAY MORE…`, and the address it serves on.
    pub(crate) fn start(replay: &Path, more: &[&str]) -> (Self, String) {
        let mut args = vec!["live", "--replay", replay.to_str().unwrap()];
        args.extend_from_slice(more);
        Self::spawn(&args)
    }

    /// `needle ARGS…`, and the address it serves on, read from the line
    /// that gives it (the first `needle live` prints).
    pub(crate) fn spawn(args: &[&str]) -> (Self, String) {
        Self::spawn_with(args, |_| {})
    }

    /// [`Self::spawn`], with the command made as `shape` says first.
    pub(crate) fn spawn_with(args: &[&str], shape: impl FnOnce(&mut Command)) -> (Self, String) {
        let mut command = Command::new(env!("CARGO_BIN_EXE_needle"));
        shape(&mut command);
        let mut child = command
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let live = Live(child);
        let mut said = Vec::new();
        for line in BufReader::new(stdout).lines() {
            let line = line.unwrap();
            if let Some(rest) = line.split("http://").nth(1) {
                let address = rest.split('/').next().unwrap().to_string();
                assert!(
                    address.starts_with("127.0.0.1:"),
                    "loopback unless asked: {line}"
                );
                return (live, address);
            }
            said.push(line);
        }
        panic!("no address in {said:?}");
    }

    /// SIGTERM; how it exited, if it did within 10 s.
    pub(crate) fn stop(&mut self) -> Option<std::process::ExitStatus> {
        self.stop_with("-TERM")
    }

    /// `kill SIGNAL`; how it exited, if it did within 10 s.
    pub(crate) fn stop_with(&mut self, signal: &str) -> Option<std::process::ExitStatus> {
        let pid = self.0.id().to_string();
        let _ = Command::new("kill").args([signal, &pid]).status();
        let until = Instant::now() + Duration::from_secs(10);
        while Instant::now() < until {
            if let Ok(Some(status)) = self.0.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        None
    }
}

impl Drop for Live {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(Some(_))) {
            return;
        }
        if self.stop().is_none() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

fn request(address: &str, path: &str) -> TcpStream {
    let mut stream = TcpStream::connect(address).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    stream
}

/// What `needle decode FILE` says, stdout and stderr.
fn decode(file: &Path) -> String {
    let decoded = crate::common::run(&["decode", file.to_str().unwrap()]);
    String::from_utf8_lossy(&decoded.stdout).into_owned()
        + &String::from_utf8_lossy(&decoded.stderr)
}

/// `command` started with SIGHUP's disposition `disposition` (default or
/// ignored), whatever this test inherits.
fn with_sighup(command: &mut Command, disposition: libc::sighandler_t) {
    use std::os::unix::process::CommandExt;
    // SAFETY: only async-signal-safe calls between fork and exec.
    unsafe {
        command.pre_exec(move || {
            libc::signal(libc::SIGHUP, disposition);
            Ok(())
        });
    }
}

fn get(address: &str, path: &str) -> String {
    let mut body = Vec::new();
    request(address, path).read_to_end(&mut body).unwrap();
    String::from_utf8_lossy(&body).into_owned()
}

/// `POST /command` of `body` as JSON: the reply, status line first.
pub(crate) fn post(address: &str, body: &str) -> String {
    post_raw(address, "application/json", body)
}

/// `POST /command` with `body` under `content_type`.
fn post_raw(address: &str, content_type: &str, body: &str) -> String {
    let length = body.len();
    let mut stream = TcpStream::connect(address).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .unwrap();
    write!(
        stream,
        "POST /command HTTP/1.1\r\nHost: {address}\r\nContent-Type: {content_type}\r\nContent-Length: {length}\r\nConnection: close\r\n\r\n{body}",
    )
    .unwrap();
    let mut reply = Vec::new();
    stream.read_to_end(&mut reply).unwrap();
    String::from_utf8_lossy(&reply).into_owned()
}

/// The `data:` lines of server-sent events from `/events` until one holds
/// `needle` (or a minute passes).
fn events_until(address: &str, needle: &str) -> Vec<String> {
    let mut lines = BufReader::new(request(address, "/events")).lines();
    let mut data = Vec::new();
    let until = Instant::now() + Duration::from_secs(60);
    while Instant::now() < until {
        let Some(Ok(line)) = lines.next() else { break };
        if let Some(json) = line.strip_prefix("data: ") {
            data.push(json.to_string());
            if json.contains(needle) {
                break;
            }
        }
    }
    data
}

#[test]
fn the_page_and_the_puncture_reach_every_page_from_the_firmware_in_qemu() {
    let dir = tempfile::tempdir().unwrap();
    // 20 mm from the liver (6.7 s at 3 mm/s): the recording begins with
    // the needle out, as a trial does.
    let plan = Plan {
        surface_x_m: 0.02,
        ..Plan::PAPER
    };
    let (_, truth, bytes) = sim::insertion_replay(&LIVER1, &plan);
    let replay = dir.path().join("liver1.replay");
    std::fs::write(&replay, bytes).unwrap();
    let recordings = dir.path().join("recordings");
    let (mut live, address) =
        Live::start(&replay, &["--record-into", recordings.to_str().unwrap()]);

    let page = get(&address, "/");
    assert!(page.starts_with("HTTP/1.1 200"), "{page}");
    assert!(page.contains("/assets/uPlot.iife.min.js") && page.contains("/assets/app.js"));
    let uplot = get(&address, "/assets/uPlot.iife.min.js");
    assert!(uplot.starts_with("HTTP/1.1 200") && uplot.len() > 40_000);
    let missing = get(&address, "/assets/nothing.js");
    assert!(missing.starts_with("HTTP/1.1 404") && missing.contains("no asset named"));

    // A recording from the page, from before contact to after the
    // puncture.
    let record = post(&address, r#"{"command":"record","on":true}"#);
    assert!(
        record.contains(r#""ok":true"#) && record.contains("recording-001"),
        "{record}"
    );
    let again = post(&address, r#"{"command":"record","on":true}"#);
    assert!(again.contains("already recording into"), "{again}");

    // Commands from the page reach the device and come back answered;
    // a request that is no command, or names what is not there, is
    // answered with what was wrong, and the server goes on.
    let tare = post(&address, r#"{"command":"tare"}"#);
    assert!(
        tare.starts_with("HTTP/1.1 200") && tare.contains(r#""ok":true"#),
        "{tare}"
    );
    assert!(tare.contains("tare: done"), "{tare}");
    let garbage = post(&address, "{not json");
    assert!(
        garbage.starts_with("HTTP/1.1 400") && garbage.contains("not a command"),
        "{garbage}"
    );
    let text = post_raw(&address, "text/plain", r#"{"command":"tare"}"#);
    assert!(
        text.starts_with("HTTP/1.1 415") && text.contains("not a command"),
        "{text}"
    );
    let spleen = post(&address, r#"{"command":"tissue","name":"spleen"}"#);
    assert!(
        spleen.starts_with("HTTP/1.1 400") && spleen.contains("no tissue `spleen`"),
        "{spleen}"
    );
    let not_a_tissue = post(
        &address,
        r#"{"command":"upload","file_name":"fit.toml","toml":"[fitted]\na1_n_per_m = \"soft\"\n","entry":null}"#,
    );
    assert!(
        not_a_tissue.starts_with("HTTP/1.1 400") && not_a_tissue.contains("fit.toml:2"),
        "{not_a_tissue}"
    );

    let seen = events_until(&address, "\"kind\":\"puncture\"");
    let puncture = seen.last().expect("events from the page's stream");
    assert!(
        puncture.contains("\"kind\":\"puncture\""),
        "no puncture within a minute: {:?}",
        &seen[seen.len().saturating_sub(3)..]
    );
    assert!(
        seen[0].contains("\"source\":\"the firmware in QEMU"),
        "a snapshot first"
    );
    let update: serde_json::Value = serde_json::from_str(puncture).unwrap();
    let event = update["events"]
        .as_array()
        .and_then(|events| events.iter().find(|e| e["kind"] == "puncture"))
        .unwrap();
    let force_n = event["force_n"].as_f64().unwrap();
    let expected_n = truth.puncture_force_n;
    assert!(
        (force_n - expected_n).abs() < 0.05 * expected_n,
        "{force_n} N against the simulation's {expected_n} N"
    );

    let stopped = post(&address, r#"{"command":"record","on":false}"#);
    assert!(stopped.contains("1 trials in"), "{stopped}");
    let into = recordings.join("recording-001");
    assert!(std::fs::metadata(into.join("stream.bin")).unwrap().len() > 10_000);
    // Begun and ended mid-stream, the stream file starts and ends with a
    // whole frame.
    let said = decode(&into.join("stream.bin"));
    assert!(said.contains(" 0 bytes skipped"), "{said}");
    let csv = std::fs::read_to_string(into.join("trial_000.csv")).unwrap();
    assert_eq!(
        csv.lines().next(),
        Some(needle_io::decode::CSV_HEADER.join(",").as_str()),
        "the columns `needle record` writes"
    );
    let trial = needle_io::trial::read(&into.join("trial_000.csv")).unwrap();
    let steps_s: Vec<f64> = trial.t_s.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(
        steps_s
            .iter()
            .all(|dt| (dt - 1.0 / plan.rate_hz).abs() < 1e-6),
        "every sample, none lost to the page"
    );
    let peak_n = trial.f_n.iter().cloned().fold(f64::MIN, f64::max);
    assert!(
        (peak_n - expected_n).abs() < 0.05 * expected_n,
        "the recorded trial peaks at {peak_n} N against the simulation's {expected_n} N"
    );
    let nothing = post(&address, r#"{"command":"record","on":false}"#);
    assert!(nothing.contains("not recording"), "{nothing}");

    // A page opened after the puncture has it from its first message.
    let later = events_until(&address, "\"kind\":\"puncture\"");
    assert!(later
        .first()
        .is_some_and(|snapshot| snapshot.contains("\"kind\":\"puncture\"")));

    // SIGTERM stops it, and the QEMU behind it, at once (a recording
    // under way is finished first: the browser test).
    let status = live
        .stop()
        .expect("needle live stops within 10 s of SIGTERM");
    assert!(status.success(), "{status}");
}

#[test]
fn needle_demo_live_serves_the_demo_insertion_behind_the_page() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let args = ["demo", "--live", "--out", out.to_str().unwrap()];
    // SIGHUP as a terminal's session has it, whatever this test inherits
    // (a CI started under `nohup` ignores it, and so would needle live).
    let (mut live, address) =
        Live::spawn_with(&args, |command| with_sighup(command, libc::SIG_DFL));
    let page = get(&address, "/");
    assert!(page.starts_with("HTTP/1.1 200"), "{page}");
    let first = events_until(&address, "liver1.replay");
    assert!(
        first
            .first()
            .is_some_and(|snapshot| snapshot.contains(&format!(
                "replaying {}",
                out.join("liver1.replay").display()
            ))),
        "{first:?}"
    );
    let record = post(&address, r#"{"command":"record","on":true}"#);
    assert!(
        record.contains(
            &out.join("recordings")
                .join("recording-001")
                .display()
                .to_string()
        ),
        "the demo's recordings beside its replay: {record}"
    );
    // A terminal closed under it: the recording finished, QEMU stopped.
    let status = live
        .stop_with("-HUP")
        .expect("needle demo --live stops within 10 s of SIGHUP");
    assert!(status.success(), "{status}");
    let into = out.join("recordings").join("recording-001");
    let files = std::fs::read_dir(&into).unwrap();
    assert!(
        files
            .map(|e| e.unwrap().file_name())
            .all(|name| !name.to_string_lossy().ends_with(".part")),
        "a trial left unfinished"
    );
    let said = decode(&into.join("stream.bin"));
    assert!(
        said.contains(" 0 bytes skipped"),
        "stream.bin ends with its last whole frame: {said}"
    );
}

#[test]
fn at_2_khz_the_page_keeps_up_decimated_and_the_recording_keeps_every_sample() {
    let dir = tempfile::tempdir().unwrap();
    let plan = Plan {
        rate_hz: 2000.0,
        speed_mps: 0.006,
        // 5 s to the tissue: the recording begins with the needle out.
        surface_x_m: 0.03,
        depth_m: 0.025,
        dwell_s: 0.5,
        ..Plan::PAPER
    };
    let (trial, _, bytes) = sim::insertion_replay(&LIVER1, &plan);
    let replay = dir.path().join("fast.replay");
    std::fs::write(&replay, bytes).unwrap();
    let recordings = dir.path().join("recordings");
    let (mut live, address) =
        Live::start(&replay, &["--record-into", recordings.to_str().unwrap()]);
    let record = post(&address, r#"{"command":"record","on":true}"#);
    assert!(record.contains(r#""ok":true"#), "{record}");

    // To the end of the replay, when the device goes away.
    let seen = events_until(&address, "\"connected\":false");
    assert!(
        seen.last()
            .is_some_and(|last| last.contains("\"connected\":false")),
        "the replay's end never reached the page"
    );
    let mut rates = Vec::new();
    let mut points = 0;
    let mut lost = 0;
    for data in &seen[1..] {
        let update: serde_json::Value = serde_json::from_str(data).unwrap();
        points += update["points"].as_array().map_or(0, Vec::len);
        if let Some(device) = update["device"].as_object() {
            rates.push(device["samples_per_s"].as_f64().unwrap());
            lost += device["samples_lost"].as_u64().unwrap()
                + device["samples_withheld"].as_u64().unwrap();
        }
    }
    // The typical second: QEMU, starved of the CPU by the tests beside
    // it, can fall behind real time and catch up in a burst.
    let mut streaming: Vec<f64> = rates.into_iter().filter(|&r| r > 0.0).collect();
    streaming.sort_by(f64::total_cmp);
    let typical = streaming[streaming.len() / 2];
    assert!(
        (1500.0..2500.0).contains(&typical),
        "the page saw {typical} samples a second from a 2 kHz device: {streaming:?}"
    );
    assert_eq!(lost, 0, "no sample lost or withheld");
    let seconds = trial.len() as f64 / plan.rate_hz;
    assert!(
        (points as f64) < 110.0 * seconds + 50.0,
        "{points} points in {seconds:.1} s: the page is given 100 a second, not 2000"
    );

    // Every sample recorded, in trials split where the needle left the
    // tissue, each as evenly spaced as the device sampled.
    let into = recordings.join("recording-001");
    let trials: Vec<_> = (0..)
        .map(|k| into.join(format!("trial_{k:03}.csv")))
        .take_while(|path| path.exists())
        .collect();
    assert!(!trials.is_empty(), "no trial recorded at 2 kHz");
    let insertion = needle_io::trial::read(&trials[0]).unwrap();
    let least_s = 2.0 * plan.depth_m / plan.speed_mps + plan.dwell_s;
    assert!(
        insertion.t_s.last().unwrap() > &least_s,
        "the first trial holds the whole insertion ({least_s:.1} s of it)"
    );
    for path in &trials {
        let recorded = needle_io::trial::read(path).unwrap();
        assert!(
            recorded
                .t_s
                .windows(2)
                .all(|w| (w[1] - w[0] - 1.0 / plan.rate_hz).abs() < 1e-7),
            "{}: a sample missing at 2 kHz",
            path.display()
        );
    }
    let status = live
        .stop()
        .expect("needle live stops within 10 s of SIGTERM");
    assert!(status.success(), "{status}");
}

#[test]
fn a_recording_that_fills_its_disk_stops_saying_so_and_the_view_goes_on() {
    // Built before the limit below, which would stop cargo too.
    needle_qemu::firmware::build(needle_qemu::firmware::Board::Lm3s6965).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let plan = Plan {
        surface_x_m: 0.02,
        ..Plan::PAPER
    };
    let (_, _, bytes) = sim::insertion_replay(&LIVER1, &plan);
    let replay = dir.path().join("liver1.replay");
    std::fs::write(&replay, bytes).unwrap();
    let recordings = dir.path().join("recordings");
    let args = [
        "live",
        "--replay",
        replay.to_str().unwrap(),
        "--record-into",
        recordings.to_str().unwrap(),
    ];
    // A full disk, as the process meets it: no file may grow past 48 KiB
    // (a write beyond fails with EFBIG; the signal that would kill the
    // process for it ignored, as a disk's ENOSPC kills nothing).
    let (mut live, address) = Live::spawn_with(&args, |command| {
        use std::os::unix::process::CommandExt;
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            command.pre_exec(|| {
                let limit = libc::rlimit {
                    rlim_cur: 48 << 10,
                    rlim_max: 48 << 10,
                };
                if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
                Ok(())
            });
        }
    });
    let record = post(&address, r#"{"command":"record","on":true}"#);
    assert!(record.contains(r#""ok":true"#), "{record}");

    let seen = events_until(&address, "recording stopped");
    let stopped = seen.last().expect("updates from the page's stream");
    assert!(
        stopped.contains("recording stopped") && stopped.contains("File too large"),
        "the page is told the recording stopped, and why: {stopped}"
    );
    // The view goes on: the device still read, the puncture still shown.
    let later = events_until(&address, "\"kind\":\"puncture\"");
    assert!(
        later
            .last()
            .is_some_and(|u| u.contains("\"kind\":\"puncture\"")),
        "no puncture after the recording stopped"
    );
    assert!(
        !later.iter().any(|u| u.contains("\"connected\":false")),
        "the device was given up with the recording"
    );
    let status = live
        .stop()
        .expect("needle live stops within 10 s of SIGTERM");
    assert!(status.success(), "{status}");
}

#[test]
fn under_nohup_a_closed_terminal_leaves_needle_live_running() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, bytes) = sim::insertion_replay(&LIVER1, &Plan::PAPER);
    let replay = dir.path().join("liver1.replay");
    std::fs::write(&replay, bytes).unwrap();
    let args = ["live", "--replay", replay.to_str().unwrap()];
    let (mut live, address) =
        Live::spawn_with(&args, |command| with_sighup(command, libc::SIG_IGN));
    let pid = live.0.id().to_string();
    let _ = Command::new("kill").args(["-HUP", &pid]).status();
    std::thread::sleep(Duration::from_secs(1));
    assert!(
        live.0.try_wait().unwrap().is_none(),
        "needle live under nohup stopped at SIGHUP"
    );
    assert!(get(&address, "/").starts_with("HTTP/1.1 200"));
    let status = live
        .stop()
        .expect("needle live stops within 10 s of SIGTERM");
    assert!(status.success(), "{status}");
}

/// The processes `pid` started (Linux: each of its threads' children).
fn children(pid: u32) -> Vec<u32> {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return Vec::new();
    };
    tasks
        .filter_map(|task| std::fs::read_to_string(task.ok()?.path().join("children")).ok())
        .flat_map(|list| {
            list.split_whitespace()
                .filter_map(|p| p.parse().ok())
                .collect::<Vec<u32>>()
        })
        .collect()
}

#[test]
fn a_killed_needle_live_takes_its_qemu_with_it() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, bytes) = sim::insertion_replay(&LIVER1, &Plan::PAPER);
    let replay = dir.path().join("liver1.replay");
    std::fs::write(&replay, bytes).unwrap();
    let (mut live, _address) = Live::start(&replay, &[]);
    let qemu: Vec<u32> = children(live.0.id())
        .into_iter()
        .filter(|pid| {
            std::fs::read_to_string(format!("/proc/{pid}/comm"))
                .is_ok_and(|name| name.starts_with("qemu-system"))
        })
        .collect();
    assert_eq!(qemu.len(), 1, "one QEMU behind needle live");
    live.0.kill().unwrap();
    live.0.wait().unwrap();
    let gone = |pid: u32| {
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .map_or(true, |stat| stat.split_whitespace().nth(2) == Some("Z"))
    };
    let until = Instant::now() + Duration::from_secs(5);
    while !gone(qemu[0]) {
        assert!(Instant::now() < until, "QEMU outlived a killed needle live");
        std::thread::sleep(Duration::from_millis(50));
    }
}
