//! Force against position with the fitted model over it and the events
//! marked, like the paper's Figures 2 and 10, as SVG (`plotters`).

use std::path::Path;

use anyhow::{anyhow, Result};
use plotters::prelude::*;

/// A line to draw: label, colour, (x_m, f_n) points.
pub struct Series<'a> {
    pub label: &'a str,
    pub color: RGBColor,
    pub points: Vec<(f64, f64)>,
}

/// An event marker: label, x_m, f_n.
pub struct Marker<'a> {
    pub label: &'a str,
    pub x_m: f64,
    pub f_n: f64,
}

/// Draw force (N) against position (mm) to `path`.
pub fn force_vs_position(
    path: &Path,
    title: &str,
    series: &[Series<'_>],
    markers: &[Marker<'_>],
) -> Result<()> {
    let all = series.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut f0, mut f1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, f) in all {
        (x0, x1, f0, f1) = (x0.min(x), x1.max(x), f0.min(f), f1.max(f));
    }
    if x0 > x1 {
        return Err(anyhow!("nothing to plot"));
    }
    let pad = 0.05 * (f1 - f0).max(0.1);
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    let err = |e| drawing_error(path, e);
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(56)
        .build_cartesian_2d(x0 * 1e3..x1 * 1e3, (f0 - pad)..(f1 + pad))
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("needle position, mm")
        .y_desc("force, N")
        .draw()
        .map_err(err)?;
    for s in series {
        let color = s.color;
        // At most ~4000 points a line: the file stays small, the shape the same.
        let step = (s.points.len() / 4000).max(1);
        let points = s.points.iter().step_by(step).map(|&(x, f)| (x * 1e3, f));
        chart
            .draw_series(LineSeries::new(points, color.stroke_width(1)))
            .map_err(err)?
            .label(s.label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
    }
    for m in markers {
        let at = (m.x_m * 1e3, m.f_n);
        chart
            .draw_series(std::iter::once(Circle::new(at, 5, BLACK.filled())))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(Text::new(
                m.label.to_owned(),
                at,
                ("sans-serif", 14),
            )))
            .map_err(err)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// A plotters error as a user reads it: the file that cannot be written
/// and why, not the error's debug form.
pub fn drawing_error(
    path: &std::path::Path,
    e: DrawingAreaErrorKind<std::io::Error>,
) -> anyhow::Error {
    use plotters::drawing::DrawingAreaErrorKind as Area;
    use plotters_backend::DrawingErrorKind as Backend;
    match e {
        Area::BackendError(Backend::DrawingError(io)) => {
            anyhow!("{}: cannot write: {io}", path.display())
        }
        other => anyhow!("{}: cannot draw: {other}", path.display()),
    }
}
