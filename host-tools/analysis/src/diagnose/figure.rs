//! The report's figure: one withheld trial over time — measured force,
//! the nominal model and the model with the named effect(s) fitted on the
//! other trials — and below it the residual of each, phases shaded.

use std::path::Path;

use anyhow::Result;
use plotters::prelude::*;

use super::prepare::{Prepared, PHASES};

/// Phase band colours, in [`PHASES`] order.
const BANDS: [RGBColor; 7] = [
    RGBColor(245, 245, 245),
    RGBColor(255, 236, 200),
    RGBColor(220, 236, 255),
    RGBColor(230, 230, 230),
    RGBColor(225, 245, 220),
    RGBColor(245, 225, 245),
    RGBColor(245, 245, 245),
];

/// A withheld trial's models as the diagnosis scored it, sample by
/// sample: every shared term fitted on the other trials, the trial's own
/// levels (cutting force, friction scale, stiffness, the force held at
/// rest, where its withdrawal lets go) on itself.
pub struct Withheld {
    /// The nominal with its corrections: the baseline the gap is
    /// measured from.
    pub baseline_n: Vec<f64>,
    /// The same with the verdict's effect(s).
    pub augmented_n: Vec<f64>,
    /// What `augmented_n` adds, as its legend reads.
    pub label: String,
}

impl Withheld {
    /// The measured force `f_n` less the baseline and less the model with
    /// the effect(s).
    pub fn residuals(&self, f_n: &[f64]) -> [Vec<f64>; 2] {
        [&self.baseline_n, &self.augmented_n]
            .map(|model| f_n.iter().zip(model).map(|(f, m)| f - m).collect())
    }

    /// The legends of [`Self::residuals`]' two lines.
    pub fn residual_labels(&self) -> [String; 2] {
        let augmented = match self.label.strip_prefix("+ ") {
            Some(named) => format!("measured − (nominal + {named})"),
            None => format!("measured − {}", self.label),
        };
        [format!("measured − {NOMINAL_LABEL}"), augmented]
    }
}

/// The legend of [`Withheld::baseline_n`].
pub const BASELINE_LABEL: &str = "nominal, the trial's own levels";
/// [`BASELINE_LABEL`] in the residual's legend.
const NOMINAL_LABEL: &str = "nominal";

/// Draw `p` with its models (same samples) to `path`.
pub fn draw(path: &Path, p: &Prepared, withheld: &Withheld) -> Result<()> {
    let (augmented, label) = (&withheld.augmented_n[..], withheld.label.as_str());
    let err = |e| crate::plot::drawing_error(path, e);
    let root = SVGBackend::new(path, (1000, 720)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let (top, bottom) = root.split_vertically(400);
    let t = &p.trial.t_s;
    let (t0, t1) = (t[0], *t.last().unwrap_or(&t[0]));
    let step = (t.len() / 3000).max(1);
    let line = |ys: &[f64]| -> Vec<(f64, f64)> {
        t.iter()
            .zip(ys)
            .step_by(step)
            .map(|(a, b)| (*a, *b))
            .collect()
    };
    let range = |ys: &[&[f64]]| {
        let (lo, hi) = ys
            .iter()
            .flat_map(|y| y.iter())
            .filter(|v| v.is_finite())
            .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        let pad = 0.05 * (hi - lo).max(0.01);
        (lo - pad)..(hi + pad)
    };
    let mut chart = ChartBuilder::on(&top)
        .caption(
            format!("{} (withheld): measured, {BASELINE_LABEL}, {label}", p.file),
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(56)
        .build_cartesian_2d(
            t0..t1,
            range(&[&p.trial.f_n, &withheld.baseline_n, augmented]),
        )
        .map_err(err)?;
    chart
        .configure_mesh()
        .y_desc("force, N")
        .draw()
        .map_err(err)?;
    let series: [(&str, &[f64], RGBColor); 3] = [
        ("measured", &p.trial.f_n, RGBColor(40, 40, 40)),
        (BASELINE_LABEL, &withheld.baseline_n, RGBColor(200, 30, 30)),
        (label, augmented, RGBColor(20, 110, 200)),
    ];
    for (name, ys, color) in series {
        chart
            .draw_series(LineSeries::new(line(ys), color))
            .map_err(err)?
            .label(name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], color));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(err)?;

    let [nominal_residual, augmented_residual] = &withheld.residuals(&p.trial.f_n);
    // Headroom for the legend above the residuals.
    let y = range(&[nominal_residual, augmented_residual]);
    let y = y.start..y.end + 0.3 * (y.end - y.start);
    let mut chart = ChartBuilder::on(&bottom)
        .caption(
            "residual (measured − model), phases shaded",
            ("sans-serif", 16),
        )
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(t0..t1, y.clone())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("time, s")
        .y_desc("residual, N")
        .draw()
        .map_err(err)?;
    // Shade each run of one phase, named at its top left where it is
    // wide enough for the name.
    let mut start = 0;
    for i in 1..=t.len() {
        if i < t.len() && p.protocol_phase[i] == p.protocol_phase[start] {
            continue;
        }
        let ph = p.protocol_phase[start];
        let (from, to) = (t[start], t[i - 1]);
        let band = Rectangle::new([(from, y.start), (to, y.end)], BANDS[ph].filled());
        chart.draw_series([band]).map_err(err)?;
        if (to - from) >= 0.06 * (t1 - t0) {
            let name = Text::new(PHASES[ph], (from, y.end), ("sans-serif", 12).into_font());
            chart.draw_series([name]).map_err(err)?;
        }
        start = i;
    }
    let labels = withheld.residual_labels();
    for ((ys, colour), label) in [nominal_residual, augmented_residual]
        .into_iter()
        .zip([RGBColor(200, 30, 30), RGBColor(20, 110, 200)])
        .zip(labels)
    {
        chart
            .draw_series(LineSeries::new(line(ys), colour))
            .map_err(err)?
            .label(label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 14, y)], colour));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}
