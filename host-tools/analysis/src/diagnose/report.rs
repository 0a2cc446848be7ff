//! The one-page report: an HTML page with the verdict, the ranked
//! candidates and the residual figure (SVG beside it, drawn with plotters).

use std::path::Path;

use super::Diagnosis;
use anyhow::{Context, Result};

/// The diagnosis in one line: what `needle diagnose` prints on stderr and
/// the report's headline.
pub fn headline(out: &Diagnosis) -> String {
    let v = &out.verdict;
    let named = match v.effect {
        super::UNEXPLAINED if !v.closest.is_empty() => {
            format!("unexplained (closest: {})", v.closest.join(" + "))
        }
        effect => {
            let steps: Vec<&str> = v.effects.iter().map(|e| e.effect).collect();
            if steps.len() > 1 {
                format!("{} (in turn)", steps.join(" → "))
            } else {
                effect.to_owned()
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
        if !v.explained {
            "; the gap left is more than 1.5 noise floors: not explained"
        } else {
            ""
        },
    )
}

/// Write the page to `path`, showing the figure already drawn at `svg`.
pub fn write(path: &Path, svg: &Path, out: &Diagnosis) -> Result<()> {
    let mut rows = String::new();
    for c in &out.candidates {
        rows += &format!(
            "<tr><td>{}</td><td>{:.4}</td><td>{:.1} %</td><td>{:.1}</td><td>{}</td></tr>\n",
            c.effect,
            c.heldout_rms_n,
            100.0 * c.shrink,
            c.paired_t,
            if c.significant { "yes" } else { "no" },
        );
    }
    let html = format!(
        "<!doctype html><meta charset=utf-8><title>needle diagnose</title>\
         <h1>Sim-to-real gap</h1><p><b>Verdict:</b> {}.\
         <h2>The gap, effect by effect (held out)</h2>{}\
         <h2>Candidates, held out</h2><table border=1><tr><th>effect<th>held-out RMS (N)<th>shrink<th>paired t<th>significant</tr>\n{rows}</table>\
         <h2>A withheld trial: the model with and without the named effect, and the residual by phase</h2><img src=\"{}\">",
        headline(out),
        waterfall_svg(out),
        svg.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
    );
    std::fs::write(path, html).with_context(|| format!("{}: cannot write", path.display()))
}

/// The waterfall as an inline figure: a bar for the held-out RMS of the
/// nominal (each trial's spread fitted on the trial), one after each named
/// effect, the noise floor as a line and the level below which the gap
/// counts as explained ([`super::EXPLAINED_FACTOR`] noise floors) as
/// another; every bar and line labelled with its name and value.
fn waterfall_svg(out: &Diagnosis) -> String {
    let mut bars = vec![("nominal".to_owned(), out.baseline.heldout_rms_n)];
    for e in &out.verdict.effects {
        bars.push((format!("+ {}", e.effect), e.heldout_rms_after_n));
    }
    let noise = out.noise_floor_n;
    let explained = super::EXPLAINED_FACTOR * noise;
    let top = bars.iter().map(|b| b.1).fold(explained, f64::max).max(1e-9) * 1.15;
    let (w, h, left, bottom, bar_w) = (140.0 * bars.len() as f64 + 120.0, 300.0, 70.0, 250.0, 90.0);
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
            bottom + 16.0,
        );
    }
    // The two labels at either end: the lines can lie a few pixels apart.
    for (level, colour, label, label_x) in [
        (
            noise,
            "#c33",
            format!("noise floor {noise:.4} N"),
            w - 180.0,
        ),
        (
            explained,
            "#36c",
            format!(
                "explained below {explained:.4} N ({} floors)",
                super::EXPLAINED_FACTOR
            ),
            left + 4.0,
        ),
    ] {
        svg += &format!(
            "<line x1=\"{left}\" y1=\"{0:.1}\" x2=\"{1}\" y2=\"{0:.1}\" stroke=\"{colour}\" stroke-dasharray=\"4 3\"/>\
             <text x=\"{2}\" y=\"{3:.1}\" fill=\"{colour}\">{label}</text>",
            y(level),
            w - 10.0,
            label_x,
            y(level) - 4.0,
        );
    }
    svg += "</svg>";
    svg
}
