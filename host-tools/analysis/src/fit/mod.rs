//! `needle fit`: the model's parameters from recorded trials alone (paper
//! §3), as JSON and as a tissue-library entry the firmware can load.

pub mod cutting;
pub mod drag;
pub mod jumps;
pub(crate) mod lsq;
pub mod predict;
pub mod report;
pub mod tissue;
pub mod trial;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use needle_holder::model::params::TissueParams;
use serde_json::Value;

use self::report::{mean_sd, AtSpeeds, Bound, DwellSummary, LawFit, LayerSummary};
pub use self::report::{Estimate, FitReport};
use self::report::{PunctureMargins, StiffnessLaws, TrialGeometry};
pub use self::tissue::FittedTissue;
pub use self::trial::{
    fit_tared, fit_trial, fit_trial_at, puncture_index_at, Falls, TrialFit, RELAXATION_PRIOR,
};
use needle_io::trial::{Skipped, Trial};

#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// Dataset directory (all *.csv trials in it).
    pub dir: PathBuf,
    /// Write the estimates as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a tissue-library entry (TOML, section `[fitted]`) here.
    #[arg(long)]
    pub toml: Option<PathBuf>,
    /// Draw force against position of the first trial, with the fitted
    /// model over it and the events marked: a page (in the look of the
    /// live view and the diagnosis report) unless the name ends in `.svg`,
    /// which gets an SVG figure for print.
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// The value of an estimate as the JSON has it (`value` of an object, or
/// the number).
pub fn value_of(v: &Value) -> Option<f64> {
    v.get("value")
        .and_then(Value::as_f64)
        .or_else(|| v.as_f64())
}

/// A clamped stop that held less than this share of what another trial
/// held in full is taken for a sliding force misjudged, not the spread of
/// tissue: at the 15 % spread of friction real tissue shows at least, two
/// trials' bands half a band apart are over two standard deviations of
/// their difference (at 30 %, about one: there the guard keeps more than
/// it drops).
const FAR_BELOW: f64 = 0.5;

/// Static friction over trials: identified where any trial reached the
/// band, otherwise the most extreme held force is only a bound.
fn static_estimate(
    fits: &[&TrialFit],
    pick: fn(&TrialFit) -> Option<(f64, bool)>,
    positive: bool,
) -> Estimate {
    // What a trial held in full at a stop bounds its own band from
    // below, not another trial's: tissue differs from one insertion to
    // the next (friction by 15–30 %), so a clamped stop below another
    // trial's held force is spread, unless it is far below: a sliding
    // force misjudged as clamped.
    let held = fits
        .iter()
        .filter_map(|t| pick(t))
        .filter(|e| !e.1)
        .map(|e| e.0);
    let bound = if positive {
        held.fold(f64::NAN, f64::max)
    } else {
        held.fold(f64::NAN, f64::min)
    };
    let clamped: Vec<f64> = fits
        .iter()
        .filter_map(|t| pick(t))
        .filter(|e| {
            let far_below = if positive {
                e.0 < FAR_BELOW * bound
            } else {
                e.0 > FAR_BELOW * bound
            };
            e.1 && (bound.is_nan() || !far_below)
        })
        .map(|e| e.0)
        .collect();
    if !clamped.is_empty() {
        return Estimate::of(&clamped);
    }
    let bound = bound.is_finite().then_some(bound);
    Estimate {
        bound: Some(if positive {
            Bound::Lower(bound)
        } else {
            Bound::Upper(bound)
        }),
        ..Estimate::noting(
            "not identified: the needle never stopped from a sliding friction beyond the static band",
        )
    }
}

/// Fit every trial of a dataset and aggregate. Files that cannot be
/// fitted are reported in `skipped` and left out.
pub fn fit_dataset(dir: &Path) -> Result<FitReport> {
    let (mut trials, unreadable) = needle_io::trial::read_dataset(dir, "fit")?;
    let total = trials.len() + unreadable.len();
    let mut fits = Vec::new();
    let mut skipped: Vec<Skipped> = unreadable
        .iter()
        .map(needle_io::trial::Unreadable::skipped)
        .collect();
    let mut progress = needle_io::trial::Progress::new("fit");
    let count = trials.len();
    for (k, (file, trial)) in trials.iter_mut().enumerate() {
        progress.say(|| format!("fitting trial {} of {count}: {}", k + 1, file.display()));
        match fit_tared(trial).with_context(|| format!("{}: cannot fit", file.display())) {
            Ok(fit) => fits.push((file.clone(), fit)),
            Err(err) => {
                needle_io::note!("needle fit: {err:#} (left out)");
                skipped.push(Skipped::new(file, &format!("{err:#}")));
            }
        }
    }
    if fits.is_empty() {
        bail!("{}: none of {total} trials could be fitted", dir.display());
    }
    let mut out = summarise(&fits, skipped);
    if let Ok(params) = out.tissue() {
        let fitted: Vec<(&Trial, &TrialFit)> = trials
            .iter()
            .filter_map(|(file, trial)| {
                let (_, fit) = fits.iter().find(|(f, _)| f == file)?;
                Some((trial, fit))
            })
            .collect();
        out.puncture_detection = Some(puncture_margins(&params, &fitted));
    }
    Ok(out)
}

/// How far to trust the puncture detector with the fitted tissue, on the
/// fitted trials themselves, as the detector reads them
/// ([`needle_holder::detect::puncture::fall`]: the fall below a peak that
/// leaks away by the expected drop per 30 ms, against the fall that
/// confirms a puncture from that peak): the largest fall while loading
/// before each trial's peak, with its margin to firing early, and the
/// smallest capsule fall within the detector's fall window after the
/// peak, with its margin to being missed.
fn puncture_margins(params: &TissueParams, fitted: &[(&Trial, &TrialFit)]) -> PunctureMargins {
    use needle_holder::detect::{puncture, DetectConfig, DetectInput};
    use needle_holder::insertion::Phase;
    use needle_holder::units::{MicroNewtons, Nanometres, NanometresPerSecond};
    let base = DetectConfig::for_tissue(params);
    let n = |m: MicroNewtons| f64::from(m.0) * 1e-6;
    let (mut largest_before_n, mut to_early_n) = (0.0_f64, f64::INFINITY);
    let (mut smallest_fall_n, mut to_miss_n) = (f64::INFINITY, f64::INFINITY);
    for (trial, fit) in fitted {
        let rate_hz = trial.rate_hz().round().clamp(1.0, f64::from(u16::MAX)) as u16;
        let c = base.at_sample_rate(rate_hz);
        let mut st = puncture::PunctureState::default();
        let (mut fall_n, mut fall_margin_n) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        // The peak the fit reports can stand samples before the fall on
        // a flat top: the fall is looked for up to the detector's own
        // window past the fall.
        let window = puncture::fall_window_samples(&c) as usize;
        let last = (fit.fallen_index.max(fit.puncture_index) + window + 2).min(trial.len());
        let loaded = (0..last).filter(|&i| trial.x_m[i] >= fit.contact_x_m);
        for i in loaded {
            let s = DetectInput {
                index: u32::try_from(i).unwrap_or(u32::MAX),
                phase: Phase::Loading,
                x: Nanometres::from_m(trial.x_m[i]),
                v: NanometresPerSecond(0),
                force: MicroNewtons::from_n(trial.f_n[i]),
                at_cutting_front: false,
            };
            let f = puncture::fall(&c, &mut st, &s);
            // Below its least peak the detector does not fire at all.
            let armed = f.peak >= c.puncture_min_peak;
            if i <= fit.puncture_index {
                if armed {
                    largest_before_n = largest_before_n.max(n(f.drop));
                    to_early_n = to_early_n.min(n(f.needed) - n(f.drop));
                }
            } else {
                let margin_n = if armed {
                    n(f.drop) - n(f.needed)
                } else {
                    n(f.peak) - n(c.puncture_min_peak)
                };
                if margin_n > fall_margin_n {
                    (fall_n, fall_margin_n) = (n(f.drop), margin_n);
                }
            }
        }
        smallest_fall_n = smallest_fall_n.min(fall_n);
        to_miss_n = to_miss_n.min(fall_margin_n);
    }
    PunctureMargins {
        threshold_n: n(puncture::needed_drop(
            &base,
            MicroNewtons::from_n(params.puncture_force_n),
        )),
        least_peak_n: n(base.puncture_min_peak),
        largest_fall_before_peak_n: largest_before_n,
        margin_to_early_n: to_early_n,
        smallest_puncture_fall_n: smallest_fall_n,
        margin_to_miss_n: to_miss_n,
        note: "on the fitted trials, as the device's detector reads them: threshold_n is the fall that confirms from the expected peak (half the expected fall less its spread, or a quarter of the peak if less); from a smaller peak a quarter of the peak confirms, and below least_peak_n (30 % of the puncture force, or four spreads of it under it) nothing fires; a margin at or below 0 means the device would report a puncture early (to_early) or miss one (to_miss) on some of them",
    }
}

/// Mean ± sd of per-trial fits, with the per-trial geometry and the trials
/// left out: `needle fit`'s JSON.
pub fn summarise(fits: &[(PathBuf, TrialFit)], skipped: Vec<Skipped>) -> FitReport {
    let all: Vec<&TrialFit> = fits.iter().map(|(_, f)| f).collect();
    let col = |get: fn(&TrialFit) -> f64| all.iter().map(|t| get(t)).collect::<Vec<f64>>();
    let stiffness_fit = stiffness_laws(&all);
    let (cp, bp, insertion) =
        split_by_speed(&all, |t| t.insertion, |t| (t.cp_n_per_m, t.bp_ns_per_m2));
    let (cn, bn, withdrawal) =
        split_by_speed(&all, |t| t.withdrawal, |t| (t.cn_n_per_m, t.bn_ns_per_m2));
    let (relaxation, cutting) = relaxation_and_cutting(&all);
    let drags: Vec<f64> = all
        .iter()
        .filter_map(|t| t.let_go_x_m.map(|x| t.contact_x_m - x))
        .collect();
    let let_go = (!drags.is_empty()).then(|| Estimate::of(&drags));
    let dwell = dwell_summary(&all);
    let layers = layer_summaries(&all);
    FitReport {
        trials: all.len(),
        a1_n_per_m: Estimate::of(&col(|t| t.polynomial.p1)),
        a2_n_per_m2: Estimate::of(&col(|t| t.polynomial.p2)),
        rational_a_per_n: Estimate::of(&col(|t| t.rational.p1)),
        rational_b_m_per_n: Estimate::of(&col(|t| t.rational.p2)),
        stiffness_fit,
        puncture_force_n: Estimate::of(&col(|t| t.puncture_force_n)),
        puncture_depth_m: Estimate::of(&col(|t| t.puncture_depth_m)),
        puncture_drop_to_n: Estimate::of(&col(|t| t.puncture_drop_to_n)),
        puncture_drop_n: Estimate::of(&col(|t| t.puncture_force_n - t.puncture_drop_to_n)),
        cutting_force_n: cutting,
        cp_n_per_m: cp,
        cn_n_per_m: cn,
        bp_ns_per_m2: bp,
        bn_ns_per_m2: bn,
        insertion_friction: insertion,
        withdrawal_friction: withdrawal,
        dp_n_per_m: static_estimate(&all, |t| t.dp, true),
        dn_n_per_m: static_estimate(&all, |t| t.dn, false),
        relaxation,
        let_go_before_contact_m: let_go,
        dwell_relaxation: dwell,
        layers,
        noise_n: Estimate::of(&col(|t| t.noise_n)),
        per_trial: fits
            .iter()
            .map(|(file, t)| TrialGeometry {
                file: needle_io::trial::name_of(file),
                contact_x_m: t.contact_x_m,
                puncture_x_m: t.puncture_x_m,
                puncture_force_n: t.puncture_force_n,
                relaxed_surface_x_m: t.relaxed_x_m,
                tare_n: t.tare_n,
            })
            .collect(),
        skipped,
        puncture_detection: None,
    }
}

/// How well each stiffness law fits the loading curves, and the better.
fn stiffness_laws(all: &[&TrialFit]) -> StiffnessLaws {
    let stats = |fit: fn(&TrialFit) -> trial::StiffnessFit| {
        let (rms, _) = mean_sd(&all.iter().map(|t| fit(t).rms_n).collect::<Vec<_>>());
        let (r2, _) = mean_sd(&all.iter().map(|t| fit(t).r2).collect::<Vec<_>>());
        (rms, r2)
    };
    let (poly_rms, poly_r2) = stats(|t| t.polynomial);
    let (rat_rms, rat_r2) = stats(|t| t.rational);
    // A NaN rms (a trial the rational law could not fit) is no win.
    let better = if rat_rms < poly_rms && rational_mean_holds(all) {
        "rational"
    } else {
        "polynomial"
    };
    StiffnessLaws {
        polynomial: LawFit {
            rms_n: poly_rms,
            r2: poly_r2,
        },
        rational: LawFit {
            rms_n: rat_rms,
            r2: rat_r2,
        },
        better,
    }
}

/// ρ and the cutting force, from the trials that place x_s3 where any do.
fn relaxation_and_cutting(all: &[&TrialFit]) -> (Estimate, Estimate) {
    let col = |get: fn(&TrialFit) -> f64| all.iter().map(|t| get(t)).collect::<Vec<f64>>();
    let identified: Vec<&TrialFit> = all
        .iter()
        .copied()
        .filter(|t| t.relaxation_identified)
        .collect();
    // Trials that place x_s3 (strokes in the cut track, a needle let go
    // inside the tissue) give ρ and the cutting
    // force; the others' cutting carries friction × (x_s3 − x_s1).
    if identified.len() == all.len() {
        (
            Estimate::of(&col(|t| t.relaxation)),
            Estimate::of(&col(|t| t.cutting_force_n)),
        )
    } else if !identified.is_empty() {
        let note = format!(
            "from the {} of {} trials that place x_s3 (strokes in the cut track, or the needle let go inside the tissue)",
            identified.len(),
            all.len()
        );
        let (rho, rho_sd) = mean_sd(&identified.iter().map(|t| t.relaxation).collect::<Vec<_>>());
        let (cut, cut_sd) = mean_sd(
            &identified
                .iter()
                .map(|t| t.cutting_force_n)
                .collect::<Vec<_>>(),
        );
        (
            Estimate {
                value: Some(rho),
                sd: rho_sd,
                ..Estimate::noting(note.clone())
            },
            Estimate {
                value: Some(cut),
                sd: cut_sd,
                ..Estimate::noting(note)
            },
        )
    } else {
        let note = format!("not identified: on withdrawal the tissue held the needle until it was behind the contact point (dragged out), so where the surface relaxed to is not seen (a stop into a dwell does not show it: the static band holds the tip's force with the shaft's); the prior ρ = {RELAXATION_PRIOR} is used, and the cutting force carries c_p·(x_s3 − x_s1)'s error");
        let (at_prior, sd) = mean_sd(&col(|t| t.cutting_force_n));
        (
            Estimate {
                model_uses: Some(RELAXATION_PRIOR),
                ..Estimate::noting(note)
            },
            Estimate {
                value: Some(at_prior),
                sd,
                ..Estimate::noting("confounded with friction × x_s3 (see relaxation)")
            },
        )
    }
}

/// The relaxation read in the trials' dwells, if any has one.
fn dwell_summary(all: &[&TrialFit]) -> Option<DwellSummary> {
    let dwells: Vec<_> = all.iter().filter_map(|t| t.dwell).collect();
    let over_dwells = |get: fn(&trial::DwellRelaxation) -> f64| {
        Estimate::of(&dwells.iter().map(get).collect::<Vec<_>>())
    };
    (!dwells.is_empty()).then(|| DwellSummary {
        trials: dwells.len(),
        duration_s: over_dwells(|d| d.duration_s),
        fraction: over_dwells(|d| d.fraction),
        tau_s: over_dwells(|d| d.tau_s),
        gain: over_dwells(|d| d.gain),
        fall_n: over_dwells(|d| d.fraction * d.start_level_n),
    })
}

/// Each further layer's puncture, over the trials that reach it.
fn layer_summaries(all: &[&TrialFit]) -> Vec<LayerSummary> {
    let most_layers = all.iter().map(|t| t.layers.len()).max().unwrap_or(0);
    (0..most_layers)
        .map(|k| {
            let of: Vec<_> = all.iter().filter_map(|t| t.layers.get(k)).collect();
            LayerSummary {
                layer: k + 2,
                trials: of.len(),
                puncture_force_n: Estimate::of(&of.iter().map(|l| l.force_n).collect::<Vec<_>>()),
                drop_to_n: Estimate::of(&of.iter().map(|l| l.drop_to_n).collect::<Vec<_>>()),
            }
        })
        .collect()
}

/// Friction coefficients c and b of one direction. Trials with strokes
/// both ways give them per trial (`per_trial`). Trials at one speed each
/// give only c + b·v at it ([`trial::AtSpeed`]): over trials at speeds
/// spread by 1.5× or more a straight line in v splits them; at one speed
/// they are confounded, and the combination is reported with c = 0 (the
/// paper found c ≈ 0 in liver) so the model still holds at that speed.
/// Returns (c, b, the speeds and coefficients where trials ran at one).
fn split_by_speed(
    all: &[&TrialFit],
    at: fn(&TrialFit) -> Option<trial::AtSpeed>,
    per_trial: fn(&TrialFit) -> (f64, f64),
) -> (Estimate, Estimate, Option<AtSpeeds>) {
    let seen: Vec<trial::AtSpeed> = all.iter().filter_map(|t| at(t)).collect();
    if seen.len() < all.len() || seen.is_empty() {
        let stroked: Vec<&&TrialFit> = all.iter().filter(|t| at(t).is_none()).collect();
        let c = Estimate::of(&stroked.iter().map(|t| per_trial(t).0).collect::<Vec<_>>());
        let b = Estimate::of(&stroked.iter().map(|t| per_trial(t).1).collect::<Vec<_>>());
        return (c, b, None);
    }
    let speeds: Vec<f64> = seen.iter().map(|a| a.speed_mps.abs()).collect();
    let (lo, hi) = speeds
        .iter()
        .fold((f64::INFINITY, 0.0_f64), |(l, h), &v| (l.min(v), h.max(v)));
    let listed = Some(AtSpeeds {
        speed_mps: seen.iter().map(|a| a.speed_mps).collect(),
        n_per_m: seen.iter().map(|a| a.n_per_m).collect(),
    });
    let mut line = lsq::Lsq::<2>::default();
    for a in &seen {
        line.add([1.0, a.speed_mps], a.n_per_m);
    }
    match line.solve().filter(|_| hi >= 1.5 * lo) {
        Some([c, b]) => {
            let sd = (line.sse(&[c, b]) / (seen.len() as f64 - 2.0).max(1.0)).sqrt();
            let line = |value| Estimate {
                value: Some(value),
                residual_sd: Some(sd),
                ..Estimate::noting("from c + b·v over trials at several speeds")
            };
            (line(c), line(b), listed)
        }
        None => {
            let (k, _) = mean_sd(&seen.iter().map(|a| a.n_per_m).collect::<Vec<_>>());
            let v = seen.iter().map(|a| a.speed_mps).sum::<f64>() / seen.len() as f64;
            let note = format!(
                "not separable: every trial ran at about {:.2} mm/s, where c + b·v = {k:.2} N/m; written as damping alone (c = 0)",
                v.abs() * 1e3
            );
            let said = |value| Estimate {
                value: Some(value),
                ..Estimate::noting(note.clone())
            };
            (said(0.0), said(k / v), listed)
        }
    }
}

/// Whether the rational law at the trials' mean parameters is, within a
/// tenth, the trials' own laws' mean force at their mean puncture depth.
/// Each trial's rational fit can be good while its two parameters trade
/// off along a ridge (loading curves bent by a moving tissue): their means
/// then put the pole inside the loading range, or the whole curve at a
/// fraction of the force, and the polynomial, linear in its parameters, is
/// the law whose mean is a law of the mean. Measured against the laws,
/// not the puncture forces: a tissue punctured near its pole spreads its
/// puncture force far more than its stiffness (the paper's liver, 2.3 ±
/// 0.8 N), and the puncture forces' mean is then no law's force at the
/// mean depth.
fn rational_mean_holds(all: &[&TrialFit]) -> bool {
    let mean =
        |get: fn(&TrialFit) -> f64| mean_sd(&all.iter().map(|t| get(t)).collect::<Vec<_>>()).0;
    let depth_m = mean(|t| t.puncture_depth_m);
    let force_n = |a: f64, b: f64| {
        let den = a * depth_m + b;
        (den > 0.0).then(|| depth_m / den)
    };
    let at_mean = force_n(mean(|t| t.rational.p1), mean(|t| t.rational.p2));
    let each: Option<Vec<f64>> = all
        .iter()
        .map(|t| force_n(t.rational.p1, t.rational.p2))
        .collect();
    match (at_mean, each) {
        (Some(at_mean), Some(each)) => {
            let laws_n = mean_sd(&each).0;
            (at_mean - laws_n).abs() <= 0.1 * laws_n.abs()
        }
        _ => false,
    }
}

/// The estimates as a tissue-library entry (keys of `TissueParams`), as
/// `needle fit --toml` writes it.
pub fn to_toml(fit: &FitReport) -> String {
    fit.fitted().to_toml()
}

pub fn run(args: &FitArgs) -> Result<()> {
    let outputs = [
        ("--json", &args.json),
        ("--toml", &args.toml),
        ("--plot", &args.plot),
    ];
    let outputs: Vec<(&str, &Path)> = outputs
        .iter()
        .filter_map(|(flag, p)| p.as_deref().map(|p| (*flag, p)))
        .collect();
    needle_io::input::check_outputs(&outputs, &needle_io::input::dataset_inputs(&args.dir, None))?;
    let fit = fit_dataset(&args.dir)?;
    let fitted = fit.fitted();
    // Never a file its own loader refuses; said before any output.
    let checked = fitted.checked();
    if let (Some(path), Err(e)) = (&args.toml, &checked) {
        bail!("{}: not written: {e:#}", path.display());
    }
    let text = serde_json::to_string_pretty(&fit)?;
    match &args.json {
        Some(path) => std::fs::write(path, text + "\n")
            .with_context(|| format!("{}: cannot write", path.display()))?,
        None => needle_io::stdout::write(&(text + "\n"))?,
    }
    for (_, note) in &fitted.notes {
        needle_io::note!("needle fit: note: {note}");
    }
    if let Some(path) = &args.toml {
        std::fs::write(path, fitted.to_toml())
            .with_context(|| format!("{}: cannot write", path.display()))?;
    }
    if let Some(path) = &args.plot {
        plot_first_trial(&args.dir, &fit, checked?, path)?;
    }
    Ok(())
}

/// The first fitted trial with the fitted model over it.
fn plot_first_trial(dir: &Path, fit: &FitReport, params: TissueParams, path: &Path) -> Result<()> {
    let first = &fit
        .per_trial
        .first()
        .context("no fitted trial to plot")?
        .file;
    let trial = needle_io::trial::read_for_analysis(&dir.join(first), None)?.trial;
    let geometry = fit_trial(&trial)?;
    // As the diagnosis draws it: the force settles the samples the
    // encoder cannot place (beside a jump, at a rest's edges).
    let velocity = predict::NeedleVelocity {
        force_sd_n: geometry.noise_n,
        ..predict::needle_velocity(&trial)
    };
    let model = predict::predict_total_at(&params, &geometry, (&trial, &trial.x_m), &velocity);
    let measured: Vec<(f64, f64)> = trial
        .x_m
        .iter()
        .copied()
        .zip(trial.f_n.iter().copied())
        .collect();
    let fitted: Vec<(f64, f64)> = trial.x_m.iter().copied().zip(model).collect();
    let title = format!("{first}: force against position");
    let markers = [
        ("contact", geometry.contact_x_m, 0.0),
        ("puncture", geometry.puncture_x_m, geometry.puncture_force_n),
        ("relaxed surface", geometry.relaxed_x_m, 0.0),
    ];
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"))
    {
        return plot_svg(path, &title, measured, fitted, &markers);
    }
    plot_page(path, &title, fit, measured, fitted, &markers)
}

/// The plot as an SVG figure (plotters).
fn plot_svg(
    path: &Path,
    title: &str,
    measured: Vec<(f64, f64)>,
    fitted: Vec<(f64, f64)>,
    markers: &[(&str, f64, f64)],
) -> Result<()> {
    use crate::plot::{force_vs_position, Marker, Series};
    let markers: Vec<Marker> = markers
        .iter()
        .map(|&(label, x_m, f_n)| Marker { label, x_m, f_n })
        .collect();
    let series = [
        Series {
            label: "measured",
            color: plotters::style::RGBColor(20, 60, 200),
            points: measured,
        },
        Series {
            label: "fitted model",
            color: plotters::style::RGBColor(220, 30, 30),
            points: fitted,
        },
    ];
    force_vs_position(path, title, &series, &markers)
}

/// The plot as a page, with the fit's main estimates beneath.
fn plot_page(
    path: &Path,
    title: &str,
    fit: &FitReport,
    measured: Vec<(f64, f64)>,
    fitted: Vec<(f64, f64)>,
    markers: &[(&str, f64, f64)],
) -> Result<()> {
    use crate::page::{self, colour, Chart, Line, Marker};
    let mm = |points: Vec<(f64, f64)>| points.into_iter().map(|(x, f)| (x * 1e3, f));
    let chart = Chart {
        caption: format!("{title}: measured (solid) and the fitted model (dashed)"),
        x_label: "needle position (mm)".into(),
        y_label: "force (N)".into(),
        lines: vec![
            Line::new("measured", colour::MEASURED, false, mm(measured)),
            Line::new("fitted model", colour::MODEL, true, mm(fitted)),
        ],
        markers: markers
            .iter()
            .map(|&(label, x_m, f_n)| Marker {
                label: label.to_owned(),
                x: x_m * 1e3,
                y: f_n,
            })
            .collect(),
        bands: Vec::new(),
        height: 420,
    };
    let mut rows = String::new();
    for (name, estimate, unit) in [
        ("stiffness a1", &fit.a1_n_per_m, "N/m"),
        ("stiffness a2", &fit.a2_n_per_m2, "N/m²"),
        ("puncture force", &fit.puncture_force_n, "N"),
        ("puncture depth", &fit.puncture_depth_m, "m"),
        ("cutting force", &fit.cutting_force_n, "N"),
        ("friction C_p", &fit.cp_n_per_m, "N/m"),
        ("friction C_n", &fit.cn_n_per_m, "N/m"),
        ("sensor noise", &fit.noise_n, "N"),
    ] {
        let value = match (estimate.value, estimate.sd, estimate.model_uses) {
            (Some(v), Some(sd), _) => format!("{v:.4} ± {sd:.4}"),
            (Some(v), None, _) => format!("{v:.4}"),
            (None, _, Some(used)) => format!("not identified (the model uses {used:.4})"),
            (None, _, None) => "not identified".to_owned(),
        };
        rows += &format!("<tr><td>{name}</td><td>{value}</td><td>{unit}</td></tr>\n");
    }
    let body = format!(
        "<h1>needle fit</h1>\n<p>{} trials fitted; the first drawn.</p>\n{}\
         <h2>Estimates over the trials</h2>\n<table><tr><th>parameter</th><th>value ± spread</th><th>unit</th></tr>\n{rows}</table>\n\
         <p class=\"caption\">Every estimate, with its note, is in the fit's JSON (<code>--json</code>).</p>",
        fit.trials,
        page::figure(0, &chart),
    );
    let html = page::standalone("needle fit", &body, &[chart])?;
    std::fs::write(path, html).with_context(|| format!("{}: cannot write", path.display()))
}
