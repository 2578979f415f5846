//! Line plots as SVG (plotters, SVG backend: text stays text, so no fonts or system libraries
//! are needed): reaction force and energies against time, written next to `history.csv`.

use std::path::Path;

use plotters::prelude::*;

use crate::{Error, InputKind, Result};

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
    let fail = |e: String| {
        Error::input(
            InputKind::Value,
            format!("{}: cannot draw the plot: {e}", path.display()),
        )
    };
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

/// Writes an SVG log-log plot of `series` as markers joined by lines (points with a
/// non-positive or non-finite coordinate are left out), plus an optional dashed black `front`
/// (e.g. a Pareto front) drawn over them.
pub fn log_log_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    front: Option<&[(f64, f64)]>,
) -> Result<()> {
    let fail = |e: String| {
        Error::input(
            InputKind::Value,
            format!("{}: cannot draw the plot: {e}", path.display()),
        )
    };
    let ok = |&(x, y): &(f64, f64)| x > 0.0 && y > 0.0 && x.is_finite() && y.is_finite();
    let pts = series
        .iter()
        .flat_map(|s| s.points.iter())
        .chain(front.into_iter().flatten())
        .filter(|p| ok(p));
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !(x0.is_finite() && y0.is_finite()) {
        (x0, x1, y0, y1) = (1.0, 10.0, 1.0, 10.0);
    }
    // A decade's fifth of room on each side, and at least that much range.
    let widen = |a: f64, b: f64| (a / 1.2, (b * 1.2).max(a * 1.5));
    let ((x0, x1), (y0, y1)) = (widen(x0, x1), widen(y0, y1));
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(80)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(|e| fail(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&|v| format!("{v:.2e}"))
        .y_label_formatter(&|v| format!("{v:.2e}"))
        .draw()
        .map_err(|e| fail(e.to_string()))?;
    for (k, s) in series.iter().enumerate() {
        let c = COLOURS[k % COLOURS.len()];
        let p: Vec<(f64, f64)> = s.points.iter().cloned().filter(|p| ok(p)).collect();
        chart
            .draw_series(LineSeries::new(p.clone(), c.stroke_width(2)))
            .map_err(|e| fail(e.to_string()))?
            .label(s.name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart
            .draw_series(p.into_iter().map(|q| Circle::new(q, 4, c.filled())))
            .map_err(|e| fail(e.to_string()))?;
    }
    if let Some(front) = front {
        let p: Vec<(f64, f64)> = front.iter().cloned().filter(|p| ok(p)).collect();
        let dashes: Vec<Vec<(f64, f64)>> = p
            .windows(2)
            .flat_map(|w| {
                // Ten dashes per segment, evenly spaced in log space.
                let ((ax, ay), (bx, by)) = (w[0], w[1]);
                (0..10).map(move |i| {
                    let at = |t: f64| (ax * (bx / ax).powf(t), ay * (by / ay).powf(t));
                    vec![at(i as f64 / 10.0), at((i as f64 + 0.5) / 10.0)]
                })
            })
            .collect();
        chart
            .draw_series(
                dashes
                    .into_iter()
                    // Wider than the series' 2 px lines, so the front shows where it runs
                    // along one of them.
                    .map(|d| PathElement::new(d, BLACK.stroke_width(3))),
            )
            .map_err(|e| fail(e.to_string()))?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(3)));
        chart
            .draw_series(
                p.into_iter()
                    .map(|q| Circle::new(q, 7, BLACK.stroke_width(1))),
            )
            .map_err(|e| fail(e.to_string()))?;
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

    #[test]
    fn log_log_plot_draws_series_and_front() {
        let dir = std::env::temp_dir().join(format!("hytled-loglog-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("p.svg");
        let s = [Series {
            name: "fe/hex8",
            points: vec![(0.1, 5.0), (1.0, 1.0), (10.0, 0.2), (-1.0, 3.0)],
        }];
        log_log_plot(
            &p,
            "Error vs time",
            "wall time (s)",
            "error (%)",
            &s,
            Some(&[(0.1, 5.0), (10.0, 0.2)]),
        )
        .unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        for w in [
            "Error vs time",
            "wall time (s)",
            "fe/hex8",
            "Pareto front",
            "circle",
        ] {
            assert!(text.contains(w), "{w} missing");
        }
        log_log_plot(&p, "empty", "x", "y", &[], None).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }
}
