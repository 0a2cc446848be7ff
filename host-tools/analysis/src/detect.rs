//! `needle detect`: the core's detectors (the same code as the firmware)
//! over trial CSVs, and, when the directory holds a simulator truth.json,
//! their evaluation against it: latency, misses and false alarms per kind.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use needle_holder::assist::target_depth_is_valid;
use needle_holder::config::DeviceConfig;
use needle_holder::hal::LoadCellAdc;
use needle_holder::insertion::Sample;
use needle_holder::pipeline::{PipelineState, RawSample};
use needle_holder::replay::ReplayAdc;
use needle_holder::units::Nanometres;
use needle_io::trial::{Skipped, Unreadable};
use serde::{Deserialize, Serialize};

use crate::sim::raw_record;
use needle_io::decode::{event_name, halt_reason_name};
use needle_io::device::parse_assist;
use needle_io::trial::Trial;

#[derive(Debug, clap::Args)]
pub struct DetectArgs {
    /// Dataset directory (all *.csv trials in it; truth.json if simulated).
    pub dir: PathBuf,
    /// Write the events as JSON here (default: standard output).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Tissue from the library (default liver1).
    #[arg(long)]
    pub tissue: Option<String>,
    /// Tissue library file.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Robot-assist modes to run, comma-separated: contact, puncture,
    /// structure, exit (stop on that event), depth (stop at
    /// --target-depth-mm past the surface), back-off (after a puncture
    /// stop, hold x_s2 − x_s3 behind the tip), speed-limit.
    #[arg(long, default_value = "none")]
    pub assist: String,
    /// Target depth past the surface for `--assist depth`, mm.
    #[arg(long, default_value_t = 30.0)]
    pub target_depth_mm: f64,
    /// Write the device's own samples per trial into this directory, one
    /// CSV each under the trial's name, in `needle decode --csv`'s
    /// columns (t_s,x_m,f_n,v_mps,model_n,residual_n,phase).
    #[arg(long, value_name = "OUT_DIR")]
    pub samples: Option<PathBuf>,
}

/// One detected event, in SI units.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Detected {
    pub kind: &'static str,
    pub t_s: f64,
    pub x_m: f64,
    pub f_n: f64,
    pub confidence: f64,
}

/// The halt line going up, in SI units.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HaltOut {
    pub reason: &'static str,
    pub t_s: f64,
    pub x_m: f64,
    pub hold_x_m: f64,
}

/// What the device made of one trial.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TrialDetection {
    pub events: Vec<Detected>,
    /// The first halt (the line latches), if any.
    pub halt: Option<HaltOut>,
    /// Faults raised, by name.
    pub faults: Vec<&'static str>,
}

/// Run the device pipeline over a trial, as raw readings through the
/// configured calibration: the events it fires, the halt it asserts (a
/// fault's or the assist's, whichever comes first, as the device latches
/// it) and the faults it raises.
pub fn detect_trial(trial: &Trial, config: &DeviceConfig) -> TrialDetection {
    detect_trial_samples(trial, config, |_, _| {})
}

/// [`detect_trial`], handing each sample the device computed to
/// `on_sample` with its row of the file.
pub fn detect_trial_samples(
    trial: &Trial,
    config: &DeviceConfig,
    mut on_sample: impl FnMut(usize, &Sample),
) -> TrialDetection {
    let rate = trial.rate_hz().round().clamp(1.0, 65_535.0) as u16;
    let mut config = config.with_sample_rate(rate);
    // A recording may have lost samples (a rig's gaps of up to 70 ms); the
    // device never does. The drive's 100 mm/s over the longest step, not
    // over one period, is what the encoder can move between two rows.
    let longest_step_s = trial
        .t_s
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(0.0, f64::max);
    let nm_per_count = f64::from(config.encoder.nm_per_count.max(1));
    let over_gap = (0.1 * longest_step_s * 1e9 / nm_per_count).ceil();
    if over_gap > f64::from(config.encoder.max_counts_per_sample) {
        config.encoder.max_counts_per_sample = over_gap.min(16_000.0) as u16;
    }
    let mut state = PipelineState::default();
    let mut found = TrialDetection::default();
    // The device's positions count from its first sample (its encoder's
    // zero); the file's are a stage's. Events are given in the file's, for
    // a robot in those coordinates (a stage 0.12 m off was told to hold
    // 0.12 m away) and for `diagnose`, which looks them up there.
    let x0_m = trial.x_m.first().copied().unwrap_or(0.0);
    for i in 0..trial.len() {
        let record = raw_record(
            trial.x_m[i],
            trial.f_n[i],
            &config.load_cell,
            &config.encoder,
        );
        let mut adc = ReplayAdc {
            counts: record.adc_counts,
            full_scale_counts: config.load_cell.full_scale_counts,
        };
        let raw = RawSample {
            adc: adc.read().ok(),
            encoder_count: record.encoder_count,
        };
        let out = config.step(&mut state, raw);
        let t = |index: u32| trial.t_s[index as usize];
        on_sample(i, &out.sample);
        if let Some(e) = out.event {
            found.events.push(Detected {
                kind: event_name(e.kind),
                t_s: t(e.index),
                x_m: x0_m + e.x.as_m(),
                f_n: e.force.as_n(),
                confidence: f64::from(e.confidence_permille) / 1000.0,
            });
        }
        let halt = match out.halt {
            _ if !out.faults.is_empty() => Some(("fault", out.sample.x, out.sample.x)),
            Some(h) => Some((halt_reason_name(h.reason), h.x, h.hold_x)),
            None => None,
        };
        if let (None, Some((reason, x, hold_x))) = (&found.halt, halt) {
            found.halt = Some(HaltOut {
                reason,
                t_s: t(out.sample.index),
                x_m: x0_m + x.as_m(),
                hold_x_m: x0_m + hold_x.as_m(),
            });
        }
    }
    found.faults = state.faults_seen().names().collect();
    found
}

/// Detection quality for one event kind. Latencies are counted from the
/// true event's `t_s` (for a puncture or a structure, the first sample at
/// which the force has fallen), over the detections that found one.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct KindScore {
    pub kind: String,
    pub true_events: usize,
    pub detected: usize,
    pub misses: usize,
    pub false_alarms: usize,
    pub latency_samples_mean: f64,
    pub latency_samples_min: f64,
    pub latency_samples_max: f64,
    pub latency_ms_mean: f64,
    pub latency_ms_max: f64,
}

/// A true event as the scorer reads it (from `truth.json`).
#[derive(Clone, Debug, PartialEq)]
pub struct TrueEvent {
    pub kind: String,
    /// The event's sample; for a puncture or a structure, the first at
    /// which the force has fallen.
    pub t_s: f64,
    /// For a puncture or a structure, the force peak before the fall.
    pub peak_t_s: f64,
    /// Where the needle was (the file's coordinates).
    pub x_m: f64,
}

/// A detection as the scorer reads it.
#[derive(Clone, Debug, PartialEq)]
pub struct Found {
    pub kind: String,
    /// The sample at which the device reported it.
    pub t_s: f64,
    /// Where the needle was at that sample (not the position the event
    /// names, which a detector may place back along the curve).
    pub needle_x_m: f64,
}

/// A puncture counts from its peak to this many samples after the fall:
/// the device can know of it only once the force falls, and a robot told
/// to stop at puncture must be told before the needle travels on.
pub const PUNCTURE_LATE_SAMPLES: f64 = 2.0;
/// A structure (a vessel wall, a membrane) from its peak to this many
/// samples after its fall: its drop is a few tenths of a newton, so the
/// detector confirms it against the local trend over a few samples.
pub const STRUCTURE_LATE_SAMPLES: f64 = 5.0;
/// An exit into air within this many samples after the needle leaves.
pub const EXIT_LATE_SAMPLES: f64 = 2.0;
/// A contact is found once the tissue pushes back measurably, which takes
/// travel, not time (1 mm/s or 10 mm/s): from the true contact until the
/// needle is this far past it.
pub const CONTACT_TRAVEL_M: f64 = 0.002;

/// Whether `found` finds `truth` (same kind assumed), the sample period
/// being `period_s`.
pub fn finds(truth: &TrueEvent, found: &Found, period_s: f64) -> bool {
    // Times in a CSV are rounded; a thousandth of a period is no sample.
    let slack = 1e-3 * period_s;
    let within = |from: f64, late_samples: f64| {
        found.t_s >= from - slack && found.t_s <= truth.t_s + late_samples * period_s + slack
    };
    match truth.kind.as_str() {
        "puncture" => within(truth.peak_t_s, PUNCTURE_LATE_SAMPLES),
        "structure" => within(truth.peak_t_s, STRUCTURE_LATE_SAMPLES),
        "exit" => within(truth.t_s, EXIT_LATE_SAMPLES),
        _ => found.t_s >= truth.t_s - slack && found.needle_x_m <= truth.x_m + CONTACT_TRAVEL_M,
    }
}

/// Score detections against truth events, per kind.
pub fn score(truth: &[TrueEvent], found: &[Found], rate_hz: f64, kinds: &[&str]) -> Vec<KindScore> {
    let period_s = 1.0 / rate_hz;
    kinds
        .iter()
        .map(|&kind| {
            let true_events: Vec<&TrueEvent> = truth.iter().filter(|e| e.kind == kind).collect();
            let mut used = vec![false; true_events.len()];
            let mut s = KindScore {
                kind: kind.to_owned(),
                true_events: true_events.len(),
                ..Default::default()
            };
            let mut latencies = Vec::new();
            for f in found.iter().filter(|e| e.kind == kind) {
                s.detected += 1;
                let hit = (0..true_events.len())
                    .find(|&k| !used[k] && finds(true_events[k], f, period_s));
                match hit {
                    Some(k) => {
                        used[k] = true;
                        latencies.push(f.t_s - true_events[k].t_s);
                    }
                    None => s.false_alarms += 1,
                }
            }
            s.misses = used.iter().filter(|u| !**u).count();
            if !latencies.is_empty() {
                let mean = latencies.iter().sum::<f64>() / latencies.len() as f64;
                let max = latencies.iter().copied().fold(f64::MIN, f64::max);
                let min = latencies.iter().copied().fold(f64::MAX, f64::min);
                (s.latency_ms_mean, s.latency_ms_max) = (mean * 1e3, max * 1e3);
                (s.latency_samples_mean, s.latency_samples_max) = (mean * rate_hz, max * rate_hz);
                s.latency_samples_min = min * rate_hz;
            }
            s
        })
        .collect()
}

/// The needle's position at the row at `t_s` (a detection's own row).
fn needle_x_at(trial: &needle_io::trial::Trial, t_s: f64) -> f64 {
    let i = trial.t_s.partition_point(|&t| t < t_s);
    trial
        .x_m
        .get(i)
        .or(trial.x_m.last())
        .copied()
        .unwrap_or(0.0)
}

/// Merge per-trial scores.
fn merge(total: &mut [KindScore], part: &[KindScore]) {
    for (t, p) in total.iter_mut().zip(part) {
        let (n0, n1) = (
            (t.true_events - t.misses) as f64,
            (p.true_events - p.misses) as f64,
        );
        if n0 + n1 > 0.0 {
            t.latency_samples_mean =
                (t.latency_samples_mean * n0 + p.latency_samples_mean * n1) / (n0 + n1);
            t.latency_ms_mean = (t.latency_ms_mean * n0 + p.latency_ms_mean * n1) / (n0 + n1);
        }
        if n1 > 0.0 {
            t.latency_samples_min = if n0 > 0.0 {
                t.latency_samples_min.min(p.latency_samples_min)
            } else {
                p.latency_samples_min
            };
        }
        t.latency_samples_max = t.latency_samples_max.max(p.latency_samples_max);
        t.latency_ms_max = t.latency_ms_max.max(p.latency_ms_max);
        t.true_events += p.true_events;
        t.detected += p.detected;
        t.misses += p.misses;
        t.false_alarms += p.false_alarms;
    }
}

/// A dataset's `truth.json` as scoring reads it: each trial's file and
/// its events' kinds and times (the simulator's other fields are not
/// read). Typed, so that an event of no known kind or without a time is
/// refused by line, not dropped: a dropped event was scored as a false
/// alarm.
#[derive(Debug, Deserialize)]
struct Truth {
    trials: Vec<TruthTrial>,
}

#[derive(Debug, Deserialize)]
struct TruthTrial {
    file: String,
    events: Vec<TruthEvent>,
}

#[derive(Debug, Deserialize)]
struct TruthEvent {
    kind: TruthKind,
    t_s: f64,
    /// Absent (a hand-written truth): the peak is taken as the event's
    /// own sample.
    peak_t_s: Option<f64>,
    /// Absent: a contact is scored by time alone.
    x_m: Option<f64>,
}

#[derive(Debug, Deserialize, Clone, Copy)]
#[serde(rename_all = "snake_case")]
enum TruthKind {
    Contact,
    Puncture,
    Structure,
    Exit,
}

impl TruthKind {
    fn name(self) -> &'static str {
        match self {
            Self::Contact => "contact",
            Self::Puncture => "puncture",
            Self::Structure => "structure",
            Self::Exit => "exit",
        }
    }
}

/// `dir/truth.json`, if there is one.
fn read_truth(dir: &Path) -> Result<Option<Truth>> {
    let path = dir.join("truth.json");
    if !path.exists() {
        return Ok(None);
    }
    let text = needle_io::input::read_small_text(&path)?;
    serde_json::from_str(&text).map(Some).map_err(|e| {
        anyhow::anyhow!(
            "{}:{}: {} (a truth.json lists trials, each with its file and events of kind contact, puncture, structure or exit at t_s)",
            path.display(),
            e.line(),
            e
        )
    })
}

/// `needle detect`'s result over a dataset (its JSON).
#[derive(Clone, Debug, Serialize)]
pub struct Detection {
    /// Each trial read, in the dataset's order.
    pub trials: Vec<TrialResult>,
    /// The files left out.
    pub skipped: Vec<Skipped>,
    /// Per event kind, with a `truth.json` beside the trials.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub evaluation: Option<Vec<KindScore>>,
}

/// One trial's file and what the device made of it.
#[derive(Clone, Debug, Serialize)]
pub struct TrialResult {
    pub file: String,
    #[serde(flatten)]
    pub detection: TrialDetection,
}

impl Detection {
    /// The evaluation of `kind`, if there is one.
    pub fn kind(&self, kind: &str) -> Option<&KindScore> {
        score_of(self.evaluation.as_deref()?, kind)
    }
}

/// The score of `kind` among `scores`.
pub fn score_of<'a>(scores: &'a [KindScore], kind: &str) -> Option<&'a KindScore> {
    scores.iter().find(|k| k.kind == kind)
}

/// Detect over a dataset; with truth.json, also score.
pub fn detect_dataset(dir: &Path, config: &DeviceConfig) -> Result<Detection> {
    detect_dataset_to(dir, config, None)
}

/// Where `--samples` writes: a directory of its own, made if missing,
/// that holds no CSV yet (a trial's samples beside the trials would be
/// read as a trial by the next command, and one written over would be
/// lost).
fn samples_dir(dir: &Path, out: &Path) -> Result<()> {
    let shown = out.display();
    if out.exists() && !out.is_dir() {
        anyhow::bail!("{shown}: --samples names a file, not a directory");
    }
    if out.is_dir() {
        if needle_io::input::same_file(dir, out) {
            anyhow::bail!("{shown}: --samples names the dataset itself: its trials would be read as trials by the next command; name another directory");
        }
        let held = needle_io::trial::dataset_files(out).unwrap_or_default();
        if let Some(first) = held.first() {
            anyhow::bail!(
                "{shown}: --samples already holds {} CSV file(s) ({}): name an empty or new directory",
                held.len(),
                first.display()
            );
        }
    }
    needle_io::input::create_out_dir(out)
}

/// One trial through the device, its samples written to `out/NAME` as
/// they come (as `NAME.part`, renamed once whole; removed if a write
/// fails, which ends the run naming the file).
fn detect_writing_samples(
    trial: &Trial,
    config: &DeviceConfig,
    out: &Path,
    name: &str,
) -> Result<TrialDetection> {
    let path = out.join(name);
    let part = out.join(format!("{name}.part"));
    let failed = || format!("{}: cannot write", path.display());
    let mut w = csv::Writer::from_path(&part).with_context(failed)?;
    let mut result = w.write_record(needle_io::decode::CSV_HEADER);
    let detection = detect_trial_samples(trial, config, |i, s| {
        if result.is_ok() {
            // The file's time and coordinates: the device counts positions
            // from its first sample.
            let row = needle_io::decode::csv_row_at(s, trial.t_s[i], trial.x_m[0] + s.x.as_m());
            result = w.write_record(row);
        }
    });
    let whole = result
        .map_err(std::io::Error::from)
        .and_then(|()| w.flush())
        .and_then(|()| std::fs::rename(&part, &path));
    if let Err(e) = whole {
        let _ = std::fs::remove_file(&part);
        return Err(e).with_context(failed);
    }
    Ok(detection)
}

/// [`detect_dataset`], writing each trial's device samples into
/// `samples` when given.
pub fn detect_dataset_to(
    dir: &Path,
    config: &DeviceConfig,
    samples: Option<&Path>,
) -> Result<Detection> {
    if let Some(out) = samples {
        samples_dir(dir, out)?;
    }
    let truth = read_truth(dir)?;
    let kinds = ["contact", "puncture", "structure", "exit"];
    let mut total: Vec<KindScore> = score(&[], &[], 1.0, &kinds);
    let mut trials = Vec::new();
    let (dataset, unreadable) = needle_io::trial::read_dataset(dir, "detect")?;
    if let Some(truth) = &truth {
        warn_if_truth_disagrees(dir, truth, &dataset, &unreadable);
    }
    for (file, trial) in dataset {
        let name = needle_io::trial::name_of(&file);
        let detection = match samples {
            Some(out) => detect_writing_samples(&trial, config, out, &name)?,
            None => detect_trial(&trial, config),
        };
        let events = &detection.events;
        if let Some(t) = truth
            .as_ref()
            .and_then(|t| t.trials.iter().find(|t| t.file == name))
        {
            let true_events: Vec<TrueEvent> = t
                .events
                .iter()
                .map(|e| TrueEvent {
                    kind: e.kind.name().to_owned(),
                    t_s: e.t_s,
                    peak_t_s: e.peak_t_s.unwrap_or(e.t_s),
                    x_m: e.x_m.unwrap_or(f64::INFINITY),
                })
                .collect();
            let found: Vec<Found> = events
                .iter()
                .map(|e| Found {
                    kind: e.kind.to_owned(),
                    t_s: e.t_s,
                    needle_x_m: needle_x_at(&trial, e.t_s),
                })
                .collect();
            merge(
                &mut total,
                &score(&true_events, &found, trial.rate_hz(), &kinds),
            );
        }
        trials.push(TrialResult {
            file: name,
            detection,
        });
    }
    Ok(Detection {
        trials,
        skipped: unreadable.iter().map(Unreadable::skipped).collect(),
        evaluation: truth.is_some().then_some(total),
    })
}

/// Say so when `truth.json` and the CSVs beside it do not describe the
/// same trials (a simulation over an older one, a file added or removed):
/// trials without truth go unscored, truth without a trial counts nothing.
fn warn_if_truth_disagrees(
    dir: &Path,
    truth: &Truth,
    dataset: &[(std::path::PathBuf, needle_io::trial::Trial)],
    unreadable: &[Unreadable],
) {
    let listed: std::collections::BTreeSet<&str> =
        truth.trials.iter().map(|t| t.file.as_str()).collect();
    let present: std::collections::BTreeSet<String> = dataset
        .iter()
        .map(|(f, _)| f)
        .chain(unreadable.iter().map(|u| &u.file))
        .map(|f| needle_io::trial::name_of(f))
        .collect();
    let untold: Vec<&String> = present
        .iter()
        .filter(|f| !listed.contains(f.as_str()))
        .collect();
    let missing: Vec<&&str> = listed.iter().filter(|f| !present.contains(**f)).collect();
    if !untold.is_empty() || !missing.is_empty() {
        needle_io::note!(
            "needle detect: {}: truth.json and the CSVs disagree: no truth for {untold:?}, no CSV for {missing:?}; scoring only the trials both have",
            dir.display()
        );
    }
}

pub fn run(args: &DetectArgs) -> Result<()> {
    if let Some(json) = &args.json {
        let inputs = needle_io::input::dataset_inputs(&args.dir, args.params.as_deref());
        needle_io::input::check_outputs(&[("--json", json)], &inputs)?;
    }
    let tissue = needle_io::tissue::resolve(args.tissue.as_deref(), args.params.as_deref())?;
    let mut config = DeviceConfig::for_tissue(&tissue.params)
        .map_err(|e| anyhow::anyhow!("tissue `{}`: {e}", tissue.name))?
        .with_assist(parse_assist(&args.assist)?);
    // The device's own range (`needle device assist --depth-mm`): 1e308 mm
    // meant no halt at all, 1e-320 a halt at contact.
    let depth = Nanometres::from_m(args.target_depth_mm * 1e-3);
    if !(args.target_depth_mm.is_finite() && target_depth_is_valid(depth)) {
        anyhow::bail!(
            "--target-depth-mm {:?}: must be between 0.1 and 100 mm, as on the device",
            args.target_depth_mm
        );
    }
    config.assist.target_depth = depth;
    let out = detect_dataset_to(&args.dir, &config, args.samples.as_deref())?;
    if let Some(eval) = &out.evaluation {
        needle_io::note!("| kind | true | detected | misses | false alarms | latency mean (samples / ms) | latency max (samples / ms) |");
        needle_io::note!("|---|---|---|---|---|---|---|");
        for k in eval {
            needle_io::note!(
                "| {} | {} | {} | {} | {} | {:.1} / {:.1} | {:.1} / {:.1} |",
                k.kind,
                k.true_events,
                k.detected,
                k.misses,
                k.false_alarms,
                k.latency_samples_mean,
                k.latency_ms_mean,
                k.latency_samples_max,
                k.latency_ms_max,
            );
        }
    }
    let text = serde_json::to_string_pretty(&out)? + "\n";
    match &args.json {
        Some(path) => {
            std::fs::write(path, text).with_context(|| format!("{}: cannot write", path.display()))
        }
        None => needle_io::stdout::write(&text),
    }
}
