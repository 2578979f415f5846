//! Line plots as SVG (plotters, SVG backend: text stays text, so no fonts or system libraries
//! are needed): reaction force and energies against time, written next to `history.csv`.

use std::path::Path;

use plotters::prelude::*;

use crate::{Error, Result};

/// One named curve: (x, y) points.
pub struct Series<'a> {
    pub name: &'a str,
    pub points: Vec<(f64, f64)>,
}

const COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// Writes an SVG line plot of `series` with axis labels (units in the labels).
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    let fail = |e: String| Error::Input(format!("{}: cannot draw the plot: {e}", path.display()));
    let finite = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|(x, y)| x.is_finite() && y.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in finite {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !(x0.is_finite() && y0.is_finite()) {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    let pad = 0.05 * (y1 - y0).abs().max(1e-30 + 1e-9 * y1.abs());
    let (y0, y1) = (y0 - pad, y1 + pad);
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(80)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| fail(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .y_label_formatter(&|v| format!("{v:.3e}"))
        .draw()
        .map_err(|e| fail(e.to_string()))?;
    for (k, s) in series.iter().enumerate() {
        let c = COLOURS[k % COLOURS.len()];
        chart
            .draw_series(LineSeries::new(
                s.points
                    .iter()
                    .cloned()
                    .filter(|(x, y)| x.is_finite() && y.is_finite()),
                c.stroke_width(2),
            ))
            .map_err(|e| fail(e.to_string()))?
            .label(s.name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| fail(e.to_string()))?;
    root.present().map_err(|e| fail(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_an_svg_with_title_labels_and_legend() {
        let dir = std::env::temp_dir().join(format!("hytled-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("p.svg");
        let s = [
            Series {
                name: "top z",
                points: (0..50)
                    .map(|i| (i as f64 * 0.1, -(i as f64).powi(2)))
                    .collect(),
            },
            Series {
                name: "bottom z",
                points: vec![(0.0, 1.0), (f64::NAN, 2.0), (4.9, 3.0)],
            },
        ];
        line_plot(&p, "Reaction force", "time (s)", "force (N)", &s).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.starts_with("<svg"));
        for w in [
            "Reaction force",
            "time (s)",
            "force (N)",
            "top z",
            "bottom z",
            "polyline",
        ] {
            assert!(text.contains(w), "{w} missing");
        }
        // Empty series still give a valid (empty) plot.
        line_plot(&p, "empty", "x", "y", &[]).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }
}
