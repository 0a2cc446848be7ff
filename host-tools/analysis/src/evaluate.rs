//! `needle evaluate`: the detectors' evaluation harness. Simulates trials
//! over a grid of sample rates and noise levels, with and without interior
//! structures (always through the sample, so exits happen), runs the
//! device's detectors over them and prints one table row per cell: misses,
//! false alarms and latency per event kind.

use anyhow::{bail, Context, Result};
use needle_holder::config::DeviceConfig;

use crate::detect::{score_of, KindScore};
use crate::sim::{effects, Dataset, Sensor};

#[derive(Debug, clap::Args)]
pub struct EvaluateArgs {
    /// Insertions per cell (at most 1000: each is simulated to a
    /// temporary directory, ~2 MB at 2 kHz).
    #[arg(long, default_value_t = 200)]
    pub trials: usize,
    /// Sample rates, Hz, comma-separated (the device's: 50..=2000).
    #[arg(long, default_value = "500,1000,2000", value_delimiter = ',')]
    pub rates_hz: Vec<f64>,
    /// Force noise levels, N, comma-separated.
    #[arg(long, default_value = "0.002,0.005,0.01", value_delimiter = ',')]
    pub noise_n: Vec<f64>,
    /// Further unmodelled effects in every cell (as for `simulate`).
    #[arg(long, default_value = "")]
    pub effects: String,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write every cell's evaluation as JSON here too.
    #[arg(long)]
    pub json: Option<std::path::PathBuf>,
}

/// The most insertions per cell.
pub const MOST_TRIALS: usize = 1000;

/// One cell of the grid.
#[derive(Debug, serde::Serialize)]
pub struct Cell {
    pub rate_hz: f64,
    pub noise_n: f64,
    pub structures: bool,
    pub evaluation: Vec<KindScore>,
}

/// Simulate and score one cell.
pub fn cell(
    rate_hz: f64,
    noise_n: f64,
    with_structures: bool,
    extra: &str,
    trials: usize,
    seed: u64,
) -> Result<Cell> {
    let dir =
        tempfile::tempdir().context("cannot create a temporary directory (is TMPDIR one?)")?;
    let mut list = effects::parse_list(extra)?;
    if with_structures {
        list.push(effects::Effect::named("internal_structures", 1.0)?);
    }
    let sensor = Sensor {
        rate_hz,
        noise_n,
        encoder_m: 1e-6,
    };
    Dataset {
        tissue_name: "liver1",
        tissue: &needle_holder::model::params::LIVER1,
        effects: &list,
        trials,
        seed,
        sensor,
        through: true,
        form: crate::sim::Form::Standard,
        rig: crate::sim::Rig::default(),
    }
    .write(dir.path())?;
    let out = crate::detect::detect_dataset(dir.path(), &DeviceConfig::default())?;
    Ok(Cell {
        rate_hz,
        noise_n,
        structures: with_structures,
        evaluation: out.evaluation.unwrap_or_default(),
    })
}

/// The figures of one kind in a cell's evaluation (all zero if the kind
/// was neither true nor found).
pub fn kind(cell: &Cell, name: &str) -> KindScore {
    score_of(&cell.evaluation, name)
        .cloned()
        .unwrap_or_default()
}

/// `found/true, false alarms, max latency in samples` for one kind.
fn summary(cell: &Cell, name: &str) -> String {
    let k = kind(cell, name);
    if k.true_events == 0 && k.false_alarms == 0 {
        return "–".into();
    }
    format!(
        "{}/{} · {} FA · ≤{:.0}",
        k.true_events - k.misses,
        k.true_events,
        k.false_alarms,
        k.latency_samples_max
    )
}

pub fn run(args: &EvaluateArgs) -> Result<()> {
    if !(1..=MOST_TRIALS).contains(&args.trials) {
        bail!("--trials {}: must be within 1..={MOST_TRIALS} (each is simulated to a temporary directory first)", args.trials);
    }
    // Every value up front: a bad one in the middle of a run named a temp
    // file, and 1e9 Hz grew to 24 GB before anything said no.
    for &rate in &args.rates_hz {
        crate::sim::check_rate_hz("--rates-hz", rate)?;
        // Faster trials were thinned to 2 kHz by the reader, and their
        // rows labelled with a rate the detectors never ran at.
        if rate > needle_io::trial::ANALYSIS_MOST_HZ {
            bail!(
                "--rates-hz {rate}: the detectors run at the device's rates, at most {} Hz (the ADS1220's fastest)",
                needle_io::trial::ANALYSIS_MOST_HZ
            );
        }
    }
    for &noise in &args.noise_n {
        crate::sim::check_noise_n("--noise-n", noise)?;
    }
    if let Some(json) = &args.json {
        needle_io::input::check_outputs(&[("--json", json)], &[])?;
    }
    needle_io::stdout::write(
        "| rate | noise | structures | contact latency mean | puncture | structure | exit |\n\
         |---|---|---|---|---|---|---|\n",
    )?;
    let mut cells = Vec::new();
    for &rate in &args.rates_hz {
        for &noise in &args.noise_n {
            for structures in [false, true] {
                let c = cell(
                    rate,
                    noise,
                    structures,
                    &args.effects,
                    args.trials,
                    args.seed,
                )?;
                let contact = kind(&c, "contact");
                // No contact found has no latency (it printed 0 ms).
                let latency = match contact.true_events - contact.misses {
                    0 => "–".to_owned(),
                    _ => format!("{:.0} ms", contact.latency_ms_mean),
                };
                needle_io::stdout::write(&format!(
                    "| {rate:.0} Hz | {:.0} mN | {} | {latency} | {} | {} | {} |\n",
                    noise * 1e3,
                    if structures { "yes" } else { "no" },
                    summary(&c, "puncture"),
                    summary(&c, "structure"),
                    summary(&c, "exit"),
                ))?;
                cells.push(c);
            }
        }
    }
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&cells)? + "\n")
            .with_context(|| format!("{}: cannot write", path.display()))?;
    }
    Ok(())
}
