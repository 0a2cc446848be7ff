//! `needle live` in a real browser: Debian's headless Chromium, driven
//! over WebDriver (its ChromeDriver, by `fantoccini`), against the
//! firmware in QEMU replaying a liver insertion in real time. What a
//! researcher at the rig would do: open the page, tare with the needle
//! out of the tissue, start recording, see assist set from elsewhere,
//! watch the puncture appear and the halt line go up. The screenshot it takes
//! is the one the book shows (`target/tmp/live.png`, copied to
//! `book/src/img/live.png` by hand when the page changes).
//!
//! And the pages `needle fit --plot` and `needle diagnose --report` write,
//! opened from their files: every chart drawn, labelled as the analysis
//! says (their screenshots, `target/tmp/fit.png` and `report.png`, are the
//! book's `img/fit-page.png` and `img/report.png`).
//!
//! `.ci/test.sh` installs `chromium` and `chromium-driver`; without them
//! these tests fail, saying which is missing.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::{Client, ClientBuilder, Locator};
use hyper_util::client::legacy::connect::HttpConnector;
use needle_analysis::sim::{self, Plan};
use needle_holder::config::DeviceConfig;
use needle_holder::model::params::LIVER1;

use crate::common::needle;
use crate::live::{post, Live};

const CHROMEDRIVER: &str = "/usr/bin/chromedriver";
const CHROMIUM: &str = "/usr/bin/chromium";

/// ChromeDriver on a port of its choosing, killed when the test ends.
struct Driver(Child);

impl Driver {
    fn start() -> (Self, u16) {
        for program in [CHROMEDRIVER, CHROMIUM] {
            assert!(
                Path::new(program).exists(),
                "{program} is missing: install Debian's chromium and chromium-driver (.ci/test.sh does)"
            );
        }
        let mut child = Command::new(CHROMEDRIVER)
            .arg("--port=0")
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let stdout = BufReader::new(child.stdout.take().unwrap());
        let driver = Driver(child);
        for line in stdout.lines() {
            let line = line.unwrap();
            if let Some(port) = line.split("started successfully on port ").nth(1) {
                let port = port.trim_end_matches('.').trim().parse().unwrap();
                return (driver, port);
            }
        }
        panic!("ChromeDriver ended without saying its port");
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Headless Chromium as this machine's closed network needs it: no
/// sandbox (CI runs as root), no background connections, a profile of
/// its own.
async fn browser(port: u16, profile: &Path) -> Client {
    let options = serde_json::json!({
        "binary": CHROMIUM,
        "args": [
            "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
            "--no-first-run", "--disable-background-networking",
            "--disable-component-update", "--disable-sync",
            "--window-size=1280,1900",
            format!("--user-data-dir={}", profile.display()),
        ],
    });
    let mut capabilities = serde_json::Map::new();
    capabilities.insert("goog:chromeOptions".into(), options);
    ClientBuilder::new(HttpConnector::new())
        .capabilities(capabilities)
        .connect(&format!("http://127.0.0.1:{port}"))
        .await
        .expect("a session of headless Chromium")
}

/// The text of the first element `css` finds once `done` holds of it,
/// polled every 100 ms; the test fails naming what it waited for.
async fn wait_for(
    browser: &Client,
    css: &str,
    within: Duration,
    done: impl Fn(&str) -> bool,
) -> String {
    let until = Instant::now() + within;
    let mut last = None;
    while Instant::now() < until {
        if let Ok(element) = browser.find(Locator::Css(css)).await {
            if let Ok(text) = element.text().await {
                if done(&text) {
                    return text;
                }
                last = Some(text);
            }
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("`{css}` not as awaited within {within:?}; last seen: {last:?}");
}

async fn click(browser: &Client, css: &str) {
    let button = browser.find(Locator::Css(css)).await.unwrap();
    button.click().await.unwrap();
}

#[test]
fn a_tare_clicked_in_the_page_reaches_the_device_and_the_puncture_is_listed() {
    // The needle starts 40 mm from the liver (13 s at 3 mm/s), time to
    // load the page and tare before contact, and the load cell reads
    // 10 mN with the needle out (below the 50 mN that counts as
    // contact), so a tare moves the device's zero.
    let plan = Plan {
        surface_x_m: 0.04,
        ..Plan::PAPER
    };
    let (mut trial, truth) = sim::insertion(&LIVER1, &plan);
    const OFFSET_N: f64 = 0.01;
    trial.f_n.iter_mut().for_each(|f_n| *f_n += OFFSET_N);
    let config = DeviceConfig::default();
    let bytes = sim::to_replay(
        &trial,
        plan.rate_hz as u16,
        &config.load_cell,
        &config.encoder,
    );
    let dir = tempfile::tempdir().unwrap();
    let replay = dir.path().join("liver1-offset.replay");
    std::fs::write(&replay, bytes).unwrap();

    let recordings = dir.path().join("recordings");
    let (_driver, port) = Driver::start();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let (screenshot, mut live) = runtime.block_on(async {
        // Chromium up first: the replay's clock starts with `needle live`.
        let browser = browser(port, &dir.path().join("profile")).await;
        let (live, address) =
            Live::start(&replay, &["--record-into", recordings.to_str().unwrap()]);
        browser.goto(&format!("http://{address}/")).await.unwrap();
        let second = Duration::from_secs(1);
        wait_for(&browser, "#connection", 20 * second, |t| t == "live").await;
        let zero = wait_for(&browser, "#zero", 20 * second, |t| t.ends_with("counts")).await;
        let phase = wait_for(&browser, "#phase", 5 * second, |t| t != "–").await;
        assert_eq!(
            phase, "out",
            "the needle reached the tissue before the page could tare"
        );

        click(&browser, "#tare").await;
        wait_for(&browser, "#replies li", 10 * second, |t| {
            t.contains("tare: done")
        })
        .await;
        let tared = wait_for(&browser, "#zero", 5 * second, |t| t != zero).await;
        click(&browser, "#record-on").await;
        wait_for(&browser, "#recording", 5 * second, |t| {
            t.contains("recording-001")
        })
        .await;

        // Assist set from elsewhere (a script, another page) shows in
        // this page's controls; stop-on-puncture raises the halt line.
        let asked = post(
            &address,
            r#"{"command":"assist","modes":"puncture","depth_mm":30}"#,
        );
        assert!(asked.contains(r#""ok":true"#), "{asked}");
        let until = Instant::now() + 5 * second;
        loop {
            let box_ = browser
                .find(Locator::Css("#assist-modes input[value=puncture]"))
                .await
                .unwrap();
            if box_.is_selected().await.unwrap() {
                break;
            }
            assert!(
                Instant::now() < until,
                "the page's puncture box never ticked"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }

        let row = wait_for(&browser, "#events tr.puncture", 60 * second, |_| true).await;
        let halt = wait_for(&browser, "#halt", 5 * second, |t| t.starts_with("HALT")).await;
        assert!(halt.contains("puncture"), "{halt}");
        // Let the plots draw the fall after the puncture.
        tokio::time::sleep(2 * second).await;
        let png = browser.screenshot().await.unwrap();
        browser.close().await.unwrap();
        ((zero, tared, row, png), live)
    });
    let (zero, tared, row, png) = screenshot;

    let counts = |text: &str| -> i64 { text.trim_end_matches(" counts").parse().unwrap() };
    // Q16.16 µN a count.
    let n_per_count = f64::from(config.load_cell.gain_q16) / 65_536.0 * 1e-6;
    let moved_n = (counts(&tared) - counts(&zero)) as f64 * n_per_count;
    assert!(
        (moved_n - OFFSET_N).abs() < 0.003,
        "the tare moved the zero by {moved_n} N ({zero} → {tared}); the load cell read {OFFSET_N} N"
    );

    // The row: insertion, kind, time, depth, force, confidence.
    let cells: Vec<&str> = row.split_whitespace().collect();
    assert_eq!(cells.get(1), Some(&"puncture"), "{row}");
    let force_n: f64 = cells[4].parse().unwrap();
    let expected_n = truth.puncture_force_n;
    assert!(
        (force_n - expected_n).abs() < 0.05 * expected_n,
        "the page lists {force_n} N against the simulation's {expected_n} N: {row}"
    );

    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("live.png");
    std::fs::write(&out, &png).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 20_000);
    eprintln!("the page, as Chromium drew it: {}", out.display());

    // SIGTERM with the needle in the tissue: the recording begun from the
    // page is finished first, the trial in hand written whole.
    let status = live
        .stop()
        .expect("needle live stops within 10 s of SIGTERM");
    assert!(status.success(), "{status}");
    let into = recordings.join("recording-001");
    let recorded = needle_io::trial::read(&into.join("trial_000.csv")).unwrap();
    let peak_n = recorded.f_n.iter().cloned().fold(f64::MIN, f64::max);
    // Tared: the 10 mN the load cell read with the needle out is gone.
    assert!(
        (peak_n - expected_n).abs() < 0.05 * expected_n,
        "the recorded trial peaks at {peak_n} N against the simulation's {expected_n} N"
    );
    let left: Vec<String> = std::fs::read_dir(&into)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(!left.iter().any(|name| name.ends_with(".part")), "{left:?}");
}

/// The legends' labels of every chart on the page, once each has drawn.
async fn legends(browser: &Client, charts: usize) -> Vec<String> {
    let until = Instant::now() + Duration::from_secs(10);
    loop {
        let drawn = browser.find_all(Locator::Css(".uplot")).await.unwrap();
        if drawn.len() == charts {
            break;
        }
        assert!(
            Instant::now() < until,
            "{} of {charts} charts drawn",
            drawn.len()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut labels = Vec::new();
    for label in browser
        .find_all(Locator::Css(".u-legend .u-label"))
        .await
        .unwrap()
    {
        labels.push(label.text().await.unwrap());
    }
    labels
}

#[test]
fn the_fit_and_the_diagnosis_draw_their_pages_in_the_live_views_look() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let data = path("trials");
    needle(&[
        "simulate",
        "--out",
        &data,
        "--effects",
        "depth_dependent_cutting",
        "--trials",
        "6",
    ]);
    let fit = path("fit.html");
    needle(&["fit", &data, "--json", &path("fit.json"), "--plot", &fit]);
    let report = path("gap.html");
    needle(&[
        "diagnose",
        &data,
        "--json",
        &path("gap.json"),
        "--report",
        &report,
    ]);

    let (_driver, port) = Driver::start();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let out = Path::new(env!("CARGO_TARGET_TMPDIR"));
    runtime.block_on(async {
        let browser = browser(port, &dir.path().join("profile")).await;

        browser.goto(&format!("file://{fit}")).await.unwrap();
        let labels = legends(&browser, 1).await;
        assert_eq!(labels, ["measured", "fitted model"]);
        let page = browser.source().await.unwrap();
        for text in ["puncture force", "stiffness a1", "value ± spread"] {
            assert!(page.contains(text), "the fit's page lacks {text}");
        }
        std::fs::write(out.join("fit.png"), browser.screenshot().await.unwrap()).unwrap();

        browser.goto(&format!("file://{report}")).await.unwrap();
        let labels = legends(&browser, 2).await;
        assert_eq!(
            labels,
            [
                "measured",
                "nominal, the trial's own levels",
                "+ depth_dependent_cutting",
                "measured − nominal",
                "measured − (nominal + depth_dependent_cutting)"
            ]
        );
        let verdict = browser
            .find(Locator::Css(".verdict"))
            .await
            .unwrap()
            .text()
            .await
            .unwrap();
        assert!(
            verdict.contains("with depth_dependent_cutting"),
            "{verdict}"
        );
        std::fs::write(out.join("report.png"), browser.screenshot().await.unwrap()).unwrap();
        browser.close().await.unwrap();
    });
    eprintln!("the pages, as Chromium drew them: {}", out.display());
}
