//! The one-page report: the verdict, the waterfall of effects, the
//! ranked candidates and a withheld trial drawn with and without the
//! named effect, in the look of every page the tools make
//! ([`crate::page`]), in one file; the same figure as SVG beside it, for
//! print (drawn with plotters).

use std::path::Path;

use super::figure::{Withheld, BASELINE_LABEL};
use super::prepare::{Prepared, PHASES};
use super::Diagnosis;
use crate::page::{self, colour, Band, Chart, Line};
use anyhow::{Context, Result};

/// Phase bands, in [`PHASES`] order; none for the approach and after,
/// where the needle is out of the tissue.
const BAND_COLOURS: [Option<&str>; 7] = [
    None,
    Some("rgba(255, 200, 0, 0.15)"),
    Some("rgba(0, 140, 255, 0.12)"),
    Some("rgba(120, 120, 120, 0.12)"),
    Some("rgba(40, 170, 120, 0.15)"),
    Some("rgba(150, 60, 255, 0.12)"),
    None,
];

/// The diagnosis in one line: what `needle diagnose` prints on stderr and
/// the report's headline.
pub fn headline(out: &Diagnosis) -> String {
    let v = &out.verdict;
    let named = match v.effect {
        super::UNEXPLAINED if !v.closest.is_empty() => {
            format!("unexplained (closest: {})", v.closest.join(" + "))
        }
        effect => {
            let steps: Vec<String> = v.effects.iter().map(|e| e.label()).collect();
            match steps.as_slice() {
                [] => effect.to_owned(),
                [one] => one.clone(),
                _ => format!("{} (in turn)", steps.join(" → ")),
            }
        }
    };
    format!(
        "{} trials; noise floor {:.4} N; held-out RMS {:.4} N → {:.4} N with {named}, shrink {:.0} %{}",
        out.trials,
        out.noise_floor_n,
        out.baseline.heldout_rms_n,
        v.heldout_rms_after_n,
        100.0 * v.shrink,
        if v.explained {
            String::new()
        } else {
            format!(
                "; the gap left is more than {:.4} N ({} noise floors or {} % of the \
                 puncture force): not explained{}",
                out.explained_below_n,
                super::EXPLAINED_FACTOR,
                100.0 * super::MODEL_TOLERANCE,
                where_left(v)
            )
        },
    )
}

/// Where most of what the named effects leave lies: the phase of most
/// squared residual and its share (`unexplained` names the phase where
/// the gap lies).
fn where_left(v: &super::Verdict) -> String {
    v.left_by_phase
        .iter()
        .max_by(|a, b| a.1.share.total_cmp(&b.1.share))
        .map(|(phase, p)| format!(", most of it in the {phase} ({:.0} %)", 100.0 * p.share))
        .unwrap_or_default()
}

/// Write the page to `path`: `p`, a withheld trial, drawn with its
/// models; `svg` names the print figure beside it.
pub fn write(
    path: &Path,
    svg: &Path,
    out: &Diagnosis,
    p: &Prepared,
    withheld: &Withheld,
) -> Result<()> {
    let mut rows = String::new();
    for c in &out.candidates {
        rows += &format!(
            "<tr><td>{}</td><td>{:.4}</td><td>{:.1} %</td><td>{:.1}</td><td>{}</td><td style=\"text-align: left\">{}</td></tr>\n",
            c.effect,
            c.heldout_rms_n,
            100.0 * c.shrink,
            c.paired_t,
            if c.significant { "yes" } else { "no" },
            page::escape(&params_line(&c.params)),
        );
    }
    let trial_rows = by_trial_rows(out);
    let charts = withheld_charts(p, withheld);
    let svg_name = svg
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let verdict_class = if out.verdict.explained { "ok" } else { "bad" };
    let verdict = page::escape(&headline(out));
    let waterfall = waterfall_svg(out);
    let (force, residual) = (page::figure(0, &charts[0]), page::figure(1, &charts[1]));
    let svg_name = page::escape(&svg_name);
    let body = format!(
        "<h1>Sim-to-real gap</h1>\n<p class=\"verdict {verdict_class}\"><b>Verdict:</b> {verdict}.</p>\n\
         <h2>The gap, effect by effect (held out)</h2>\n{waterfall}\n\
         <h2>Each trial, held out: the nominal and what the named effects leave</h2>\n\
         <table><tr><th style=\"text-align: left\">trial</th><th>nominal (N)</th><th>after (N)</th></tr>\n{trial_rows}</table>\n\
         <h2>Candidates, held out</h2>\n<table><tr><th>effect</th><th>held-out RMS (N)</th><th>shrink</th><th>paired t</th><th>significant</th><th style=\"text-align: left\">its parameters, fitted on every trial (units in the names)</th></tr>\n{rows}</table>\n\
         <h2>A withheld trial: the model with and without the named effect, and the residual by phase</h2>\n{force}{residual}\
         <p class=\"caption\">The same figure for print: <a href=\"{svg_name}\">{svg_name}</a>.</p>"
    );
    let html = page::standalone("needle diagnose", &body, &charts)?;
    std::fs::write(path, html).with_context(|| format!("{}: cannot write", path.display()))
}

/// One row a trial, most left first: which insertions the model misses.
fn by_trial_rows(out: &Diagnosis) -> String {
    let mut trials: Vec<(&String, f64, f64)> = out
        .baseline
        .by_trial
        .iter()
        .map(|(file, &before)| {
            let after = out
                .verdict
                .left_by_trial
                .get(file)
                .copied()
                .unwrap_or(f64::NAN);
            (file, before, after)
        })
        .collect();
    trials.sort_by(|a, b| b.2.total_cmp(&a.2));
    trials
        .iter()
        .map(|(file, before, after)| {
            let name = std::path::Path::new(file.as_str())
                .file_name()
                .map_or_else(|| file.to_string(), |n| n.to_string_lossy().into_owned());
            format!(
                "<tr><td style=\"text-align: left\">{}</td><td>{before:.4}</td><td>{after:.4}</td></tr>\n",
                page::escape(&name)
            )
        })
        .collect()
}

/// A candidate's parameters as `name = value`, four significant figures:
/// what a researcher compares with the rig (a mount's mode, a mass, a
/// relaxation time).
fn params_line(params: &std::collections::BTreeMap<&'static str, f64>) -> String {
    params
        .iter()
        .map(|(name, value)| format!("{name} = {}", four_figures(*value)))
        .collect::<Vec<_>>()
        .join(", ")
}

/// `value` to four significant figures: in decimals from a thousandth to
/// ten thousand (a relaxation time, a stiffness), else as a power of ten
/// (a presliding length, a damping). The power is the one the value has
/// once rounded (9.99996 reads 10.00).
fn four_figures(value: f64) -> String {
    if value == 0.0 {
        return "0".into();
    }
    let scientific = format!("{value:.3e}");
    let power = scientific
        .split_once('e')
        .and_then(|(_, p)| p.parse::<i32>().ok());
    match power {
        Some(p) if (-3..4).contains(&p) => {
            let decimals = (3 - p).max(0) as usize;
            format!("{value:.decimals$}")
        }
        _ => scientific,
    }
}

/// The withheld trial against time — measured, the nominal with the
/// trial's own levels, with the effect — and the residual of each
/// beneath, phases shaded.
fn withheld_charts(p: &Prepared, withheld: &Withheld) -> [Chart; 2] {
    let (augmented, label) = (&withheld.augmented_n[..], withheld.label.as_str());
    let t = &p.trial.t_s;
    let line = |name: &str, colour, dashed, ys: &[f64]| {
        Line::new(
            name,
            colour,
            dashed,
            t.iter().copied().zip(ys.iter().copied()),
        )
    };
    let [baseline_residual, augmented_residual] = withheld.residuals(&p.trial.f_n);
    let bands = phase_bands(p);
    let force = Chart {
        caption: format!("{} (withheld): measured, {BASELINE_LABEL}, {label}", p.file),
        x_label: "time (s)".into(),
        y_label: "force (N)".into(),
        lines: vec![
            line("measured", colour::MEASURED, false, &p.trial.f_n),
            line(BASELINE_LABEL, colour::MODEL, true, &withheld.baseline_n),
            line(label, colour::AUGMENTED, false, augmented),
        ],
        markers: Vec::new(),
        bands: bands.clone(),
        height: 340,
    };
    let [nominal_label, augmented_label] = withheld.residual_labels();
    let residual = Chart {
        caption: "residual (measured − model), phases shaded".into(),
        x_label: "time (s)".into(),
        y_label: "residual (N)".into(),
        lines: vec![
            line(&nominal_label, colour::MODEL, false, &baseline_residual),
            line(
                &augmented_label,
                colour::AUGMENTED,
                false,
                &augmented_residual,
            ),
        ],
        markers: Vec::new(),
        bands,
        height: 240,
    };
    [force, residual]
}

/// A band for each run of one phase, named.
fn phase_bands(p: &Prepared) -> Vec<Band> {
    let t = &p.trial.t_s;
    let mut bands = Vec::new();
    let mut start = 0;
    for i in 1..=t.len() {
        if i < t.len() && p.protocol_phase[i] == p.protocol_phase[start] {
            continue;
        }
        let phase = p.protocol_phase[start];
        if let Some(colour) = BAND_COLOURS[phase] {
            bands.push(Band {
                from: t[start],
                to: t[i - 1],
                label: PHASES[phase],
                colour,
            });
        }
        start = i;
    }
    bands
}

/// The waterfall as an inline figure: a bar for the held-out RMS of the
/// nominal (each trial's spread fitted on the trial), one after each named
/// effect, the noise floor as a line and the level below which the gap
/// counts as explained ([`Diagnosis::explained_below_n`]) as
/// another; every bar and line labelled with its name and value.
fn waterfall_svg(out: &Diagnosis) -> String {
    let mut bars = vec![("nominal".to_owned(), out.baseline.heldout_rms_n)];
    for e in &out.verdict.effects {
        bars.push((format!("+ {}", e.label()), e.heldout_rms_after_n));
    }
    let noise = out.noise_floor_n;
    let explained = out.explained_below_n;
    let top = bars.iter().map(|b| b.1).fold(explained, f64::max).max(1e-9) * 1.15;
    // The two levels' labels right of the bars, clear of their values;
    // room for the longer of them.
    let (h, left, bottom, bar_w) = (316.0, 70.0, 250.0, 90.0);
    let labels_x = left + 20.0 + 140.0 * bars.len() as f64;
    let w = labels_x + 340.0;
    let y = |v: f64| bottom - (v / top) * (bottom - 20.0);
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" font-family=\"sans-serif\" font-size=\"12\">\
         <text x=\"10\" y=\"14\">held-out RMS (N)</text>\
         <line x1=\"{left}\" y1=\"{bottom}\" x2=\"{}\" y2=\"{bottom}\" stroke=\"black\"/>",
        w - 10.0
    );
    for (k, (label, v)) in bars.iter().enumerate() {
        let x = left + 20.0 + 140.0 * k as f64;
        svg += &format!(
            "<rect x=\"{x}\" y=\"{:.1}\" width=\"{bar_w}\" height=\"{:.1}\" fill=\"{}\"/>\
             <text x=\"{x}\" y=\"{:.1}\">{v:.4} N</text>\
             <text x=\"{x}\" y=\"{:.1}\">{label}</text>",
            y(*v),
            bottom - y(*v),
            if k == 0 { "#888" } else { "#4a7" },
            y(*v) - 4.0,
            // Every other name a line lower: an effect's name is wider
            // than its bar's spacing.
            bottom + 16.0 + 16.0 * (k % 2) as f64,
        );
    }
    let explained_label = if explained > super::EXPLAINED_FACTOR * noise {
        format!(
            "explained below {explained:.4} N ({} % of the puncture force)",
            100.0 * super::MODEL_TOLERANCE
        )
    } else {
        format!(
            "explained below {explained:.4} N ({} noise floors)",
            super::EXPLAINED_FACTOR
        )
    };
    // Each label above its line, but the lower one's below it where the
    // two lines lie closer than a line of text.
    let close = (y(noise) - y(explained)).abs() < 16.0;
    for (level, colour, label) in [
        (noise, "#c33", format!("noise floor {noise:.4} N")),
        (explained, "#36c", explained_label),
    ] {
        let below = close && level <= noise.min(explained);
        svg += &format!(
            "<line x1=\"{left}\" y1=\"{0:.1}\" x2=\"{1}\" y2=\"{0:.1}\" stroke=\"{colour}\" stroke-dasharray=\"4 3\"/>\
             <text x=\"{labels_x}\" y=\"{2:.1}\" fill=\"{colour}\">{label}</text>",
            y(level),
            w - 10.0,
            if below { y(level) + 14.0 } else { y(level) - 4.0 },
        );
    }
    svg += "</svg>";
    svg
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Four significant figures whatever the size, zero as zero.
    #[test]
    fn parameters_read_to_four_figures() {
        assert_eq!(four_figures(25.198421), "25.20");
        assert_eq!(four_figures(0.0003), "3.000e-4");
        assert_eq!(four_figures(0.002), "0.002000");
        assert_eq!(four_figures(-5193.3233), "-5193");
        assert_eq!(four_figures(0.00007), "7.000e-5");
        assert_eq!(four_figures(0.0), "0");
        assert_eq!(four_figures(-0.0), "0");
        assert_eq!(four_figures(9.99996), "10.00");
        assert_eq!(four_figures(99999.5), "1.000e5");
        assert_eq!(four_figures(12345.6), "1.235e4");
        assert_eq!(four_figures(-0.0005), "-5.000e-4");
        assert_eq!(four_figures(f64::NAN), "NaN");
        let params = std::collections::BTreeMap::from([("mount_hz", 25.198), ("mass_kg", 0.15)]);
        assert_eq!(params_line(&params), "mass_kg = 0.1500, mount_hz = 25.20");
    }

    /// A gap left open says the phase it mostly lies in, with its share.
    #[test]
    fn a_gap_left_open_names_the_phase_it_lies_in() {
        let share = |share| super::super::PhaseShare { rms_n: 0.1, share };
        let verdict = super::super::Verdict {
            effect: "viscoelasticity",
            shrink: 0.14,
            second: "none",
            effects: Vec::new(),
            heldout_rms_after_n: 0.0888,
            explained: false,
            closest: vec!["viscoelasticity"],
            left_by_phase: [
                ("dwell", share(0.01)),
                ("insertion", share(0.714)),
                ("loading", share(0.26)),
            ]
            .into_iter()
            .collect(),
            left_by_trial: Default::default(),
        };
        assert_eq!(where_left(&verdict), ", most of it in the insertion (71 %)");
    }
}
