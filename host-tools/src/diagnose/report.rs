//! The one-page report: an HTML page with the verdict, the ranked
//! candidates and the residual figure (SVG beside it, drawn with plotters).

use std::path::Path;

use anyhow::{Context, Result};
use serde_json::Value;

/// The diagnosis in one line: what `needle diagnose` prints on stderr and
/// the report's headline.
pub fn headline(out: &Value) -> String {
    let num = |v: &Value| v.as_f64().unwrap_or(0.0);
    let v = &out["verdict"];
    let closest: Vec<&str> = v["closest"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    let named = match v["effect"].as_str().unwrap_or("none") {
        "unexplained" if !closest.is_empty() => {
            format!("unexplained (closest: {})", closest.join(" + "))
        }
        effect => match v["second"].as_str().filter(|&s| s != "none") {
            Some(second) => format!("{effect} (+ {second})"),
            None => effect.to_owned(),
        },
    };
    format!(
        "{} trials; noise floor {:.4} N; held-out RMS {:.4} N → {:.4} N with {named}, shrink {:.0} %{}",
        out["trials"],
        num(&out["noise_floor_n"]),
        num(&out["baseline"]["heldout_rms_n"]),
        num(&v["heldout_rms_after_n"]),
        100.0 * num(&v["shrink"]),
        if v["explained"].as_bool() == Some(false) {
            "; the gap left is more than 1.5 noise floors: not explained"
        } else {
            ""
        },
    )
}

/// Write the page to `path`, showing the figure already drawn at `svg`.
pub fn write(path: &Path, svg: &Path, out: &Value) -> Result<()> {
    let mut rows = String::new();
    for c in out["candidates"].as_array().into_iter().flatten() {
        rows += &format!(
            "<tr><td>{}</td><td>{:.4}</td><td>{:.1} %</td><td>{:.1}</td><td>{}</td></tr>\n",
            c["effect"].as_str().unwrap_or("?"),
            c["heldout_rms_n"].as_f64().unwrap_or(0.0),
            100.0 * c["shrink"].as_f64().unwrap_or(0.0),
            c["paired_t"].as_f64().unwrap_or(0.0),
            if c["significant"].as_bool().unwrap_or(false) {
                "yes"
            } else {
                "no"
            },
        );
    }
    let html = format!(
        "<!doctype html><meta charset=utf-8><title>needle diagnose</title>\
         <h1>Sim-to-real gap</h1><p><b>Verdict:</b> {}.\
         <h2>Candidates, held out</h2><table border=1><tr><th>effect<th>held-out RMS (N)<th>shrink<th>paired t<th>significant</tr>\n{rows}</table>\
         <h2>A withheld trial: the model with and without the named effect, and the residual by phase</h2><img src=\"{}\">",
        headline(out),
        svg.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
    );
    std::fs::write(path, html).with_context(|| format!("{}: cannot write", path.display()))
}
