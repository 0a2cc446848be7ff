//! The look of every page the tools write or serve — the live view
//! (`needle live`), the sim-to-real report (`needle diagnose --report`),
//! the fit's plot (`needle fit --plot`): one stylesheet, one plotting
//! library, and static charts drawn from typed descriptions.
//!
//! uPlot 1.6.32 (MIT, `assets/uPlot-LICENSE`), as published on npm, is
//! bundled: a rig may be offline, and a report is one file that opens
//! anywhere.

use anyhow::Result;
use serde::Serialize;

/// The shared stylesheet.
pub const STYLE_CSS: &str = include_str!("../assets/page.css");
/// uPlot, its stylesheet and its licence.
pub const UPLOT_JS: &str = include_str!("../assets/uPlot.iife.min.js");
pub const UPLOT_CSS: &str = include_str!("../assets/uPlot.min.css");
pub const UPLOT_LICENSE: &str = include_str!("../assets/uPlot-LICENSE");
/// Static charts from [`Chart`]s, and the x-y line drawing the live view
/// shares with them.
pub const CHARTS_JS: &str = include_str!("../assets/charts.js");

/// Points a line keeps at most: the file stays small, the shape the same.
pub const POINTS_PER_LINE: usize = 4000;

/// A chart of lines over shaded bands, with labelled markers.
#[derive(Clone, Debug, Serialize)]
pub struct Chart {
    pub caption: String,
    pub x_label: String,
    pub y_label: String,
    pub lines: Vec<Line>,
    pub markers: Vec<Marker>,
    pub bands: Vec<Band>,
    /// Pixels.
    pub height: u32,
}

/// A line, its points in the order drawn (x need not be sorted).
#[derive(Clone, Debug, Serialize)]
pub struct Line {
    pub label: String,
    /// A CSS colour.
    pub colour: &'static str,
    pub dashed: bool,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
}

impl Line {
    /// `points`, at most [`POINTS_PER_LINE`] of them evenly taken.
    pub fn new(
        label: &str,
        colour: &'static str,
        dashed: bool,
        points: impl ExactSizeIterator<Item = (f64, f64)>,
    ) -> Self {
        let step = points.len().div_ceil(POINTS_PER_LINE).max(1);
        let (x, y) = points.step_by(step).unzip();
        Self {
            label: label.to_owned(),
            colour,
            dashed,
            x,
            y,
        }
    }
}

/// A point named on the chart.
#[derive(Clone, Debug, Serialize)]
pub struct Marker {
    pub label: String,
    pub x: f64,
    pub y: f64,
}

/// A shaded stretch of x, named once on the chart.
#[derive(Clone, Debug, Serialize)]
pub struct Band {
    pub from: f64,
    pub to: f64,
    pub label: &'static str,
    /// A CSS colour, translucent.
    pub colour: &'static str,
}

/// The colours lines take on every page: what was measured, the model
/// the device or the fit runs, and a model with more to it.
pub mod colour {
    pub const MEASURED: &str = "rgb(20, 60, 200)";
    pub const MODEL: &str = "#d22";
    pub const AUGMENTED: &str = "#2a7";
    pub const NEUTRAL: &str = "#555";
}

/// Where chart `index` of the page goes, under its caption.
pub fn figure(index: usize, chart: &Chart) -> String {
    format!(
        "<figure><figcaption>{}</figcaption><div id=\"chart-{index}\"></div></figure>\n",
        escape(&chart.caption)
    )
}

/// A page that holds everything it shows (styles, plotting library,
/// data): `body` (HTML, with a [`figure`] for each of `charts`).
pub fn standalone(title: &str, body: &str, charts: &[Chart]) -> Result<String> {
    // No `<` in the data: `</script>` would end the script, and `<!--`
    // would change how the rest of it is read.
    let data = serde_json::to_string(charts)?.replace('<', "\\u003c");
    Ok(format!(
        "<!doctype html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n\
         <style>\n{UPLOT_CSS}\n{STYLE_CSS}</style>\n</head>\n<body>\n{body}\n\
         <script>\n{UPLOT_JS}\n</script>\n<script>\nconst NEEDLE_CHARTS = {data};\n{CHARTS_JS}</script>\n\
         </body>\n</html>\n",
        escape(title)
    ))
}

/// `text` as HTML text (file names come from the user).
pub fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_page_carries_its_data_whole_and_no_script_can_be_closed_by_it() {
        let chart = Chart {
            caption: "a <b> & c".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            lines: vec![Line::new(
                "</script><!--<script>alert(1)</script>",
                colour::MEASURED,
                false,
                (0..10_000).map(|i| (f64::from(i), 1.0)),
            )],
            markers: vec![],
            bands: vec![],
            height: 200,
        };
        assert!(
            (3000..=POINTS_PER_LINE).contains(&chart.lines[0].x.len()),
            "decimated to at most 4000 points: {}",
            chart.lines[0].x.len()
        );
        let body = figure(0, &chart);
        assert!(body.contains("a &lt;b&gt; &amp; c"));
        let page = standalone("t<", &body, &[chart]).unwrap();
        assert!(page.contains("<title>t&lt;</title>"));
        assert_eq!(
            page.matches("</script>").count(),
            2,
            "only the page's own scripts end"
        );
        assert!(page.contains("uPlot") && page.contains("NEEDLE_CHARTS"));
        assert!(!page.contains("<!--"), "no comment opened by the data");
    }
}
