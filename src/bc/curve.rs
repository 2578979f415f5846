//! Load curves: the factor (of a load's or a prescribed displacement's final value) at a
//! load fraction tau, built in or tabulated.

use std::sync::Arc;

use crate::{Error, InputKind, Result};

/// Time history of a load or prescribed displacement, as a fraction of its final value, at the
/// load fraction tau (dynamic: t / load_time; relaxation: load step / load_steps).
#[derive(Debug, Clone, PartialEq, Default)]
pub enum LoadCurve {
    /// d(t) = d_max (10 - 15 tau + 6 tau^2) tau^3: zero velocity and acceleration at both ends
    /// (docs/reference.md, the curve of every benchmark case).
    #[default]
    Smooth,
    /// d(t) = d_max tau.
    Ramp,
    /// d(t) = d_max from the first step.
    Constant,
    /// There and back: the smooth curve to d_max over the first half of the load time and,
    /// mirrored, back to zero over the second half (loading and unloading, Horton 2010 sect. 4.7).
    SmoothReturn,
    /// Tabulated (tau, factor) pairs, linear between them.
    Table(Arc<CurveTable>),
}

impl LoadCurve {
    /// The built-in curve called `name` ("smooth", "ramp", "constant", "smooth-return").
    pub fn builtin(name: &str) -> Option<Self> {
        Some(match name {
            "smooth" => LoadCurve::Smooth,
            "ramp" => LoadCurve::Ramp,
            "constant" => LoadCurve::Constant,
            "smooth-return" => LoadCurve::SmoothReturn,
            _ => return None,
        })
    }

    /// The smallest and largest factor the curve takes at any load fraction (a table: over
    /// its points, linear between them and held beyond).
    pub fn factor_range(&self) -> (f64, f64) {
        match self {
            LoadCurve::Smooth | LoadCurve::Ramp | LoadCurve::SmoothReturn => (0.0, 1.0),
            LoadCurve::Constant => (1.0, 1.0),
            LoadCurve::Table(t) => t
                .factor
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &f| {
                    (lo.min(f), hi.max(f))
                }),
        }
    }

    /// Names of the built-in curves.
    pub const BUILTIN: [&'static str; 4] = ["smooth", "ramp", "constant", "smooth-return"];

    /// Factor of the final value at load fraction tau. The built-in curves clamp tau to
    /// [0, 1]; a table holds its first and last factor outside its range.
    #[inline]
    pub fn value(&self, tau: f64) -> f64 {
        let smooth = |t: f64| (10.0 - 15.0 * t + 6.0 * t * t) * t * t * t;
        let t = tau.clamp(0.0, 1.0);
        match self {
            LoadCurve::Smooth => smooth(t),
            LoadCurve::Ramp => t,
            LoadCurve::Constant => 1.0,
            LoadCurve::SmoothReturn => smooth(if t <= 0.5 { 2.0 * t } else { 2.0 - 2.0 * t }),
            LoadCurve::Table(table) => table.value(tau),
        }
    }
}

impl LoadCurve {
    /// The curve starts at 0, never falls and ends above 0 (smooth, ramp, a rising table;
    /// not constant, there and back, nor a table that falls or starts loaded): its factor
    /// over its factor at 1 is then a load fraction that only grows with tau.
    pub fn is_rising(&self) -> bool {
        match self {
            LoadCurve::Smooth | LoadCurve::Ramp => true,
            LoadCurve::Constant | LoadCurve::SmoothReturn => false,
            LoadCurve::Table(t) => {
                self.value(0.0) == 0.0
                    && self.value(1.0) > 0.0
                    && t.factor.windows(2).all(|w| w[1] >= w[0])
            }
        }
    }

    /// The smallest load fraction tau in [0, 1] at which the curve
    /// reaches `share` of its factor at 1 (bisection to rounding; 0 and 1 at the ends):
    /// the inverse of a rising curve ([`Self::is_rising`]).
    pub fn fraction_at(&self, share: f64) -> f64 {
        if !(share > 0.0) {
            return 0.0;
        }
        if share >= 1.0 {
            return 1.0;
        }
        let goal = share * self.value(1.0);
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for _ in 0..64 {
            let mid = 0.5 * (lo + hi);
            if self.value(mid) < goal {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }
}

/// A tabulated curve: factors at increasing load fractions, linear between them.
#[derive(Debug, Clone, PartialEq)]
pub struct CurveTable {
    tau: Vec<f64>,
    factor: Vec<f64>,
}

impl CurveTable {
    /// From (time s, factor) pairs whose times are mapped to load fractions by `load_time`
    /// (s): tau = t / load_time. Times must increase strictly and every number be finite;
    /// `what` names the curve in errors.
    pub fn from_times(points: &[[f64; 2]], load_time: f64, what: &str) -> Result<Self> {
        if points.is_empty() {
            return Err(Error::input(
                InputKind::Value,
                format!("{what}: a tabulated curve needs at least one point"),
            ));
        }
        if !(load_time > 0.0 && load_time.is_finite()) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "{what}: the load time {load_time} s must be positive to map the table's times"
                ),
            ));
        }
        for (k, p) in points.iter().enumerate() {
            if !p.iter().all(|v| v.is_finite()) {
                return Err(Error::input(
                    InputKind::Value,
                    format!("{what}: point {} ({:?}) is not finite", k + 1, p),
                ));
            }
            if k > 0 && !(p[0] > points[k - 1][0]) {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                        "{what}: times must increase; point {} has t = {} s after t = {} s",
                        k + 1,
                        p[0],
                        points[k - 1][0]
                    ),
                ));
            }
        }
        Ok(CurveTable {
            tau: points.iter().map(|p| p[0] / load_time).collect(),
            factor: points.iter().map(|p| p[1]).collect(),
        })
    }

    /// Factor at load fraction tau: linear between the points, the end factors beyond them.
    pub fn value(&self, tau: f64) -> f64 {
        let n = self.tau.len();
        if !(tau > self.tau[0]) {
            return self.factor[0];
        }
        if tau >= self.tau[n - 1] {
            return self.factor[n - 1];
        }
        // First point beyond tau (1..n-1).
        let k = self.tau.partition_point(|&t| t <= tau);
        let (t0, t1) = (self.tau[k - 1], self.tau[k]);
        let (f0, f1) = (self.factor[k - 1], self.factor[k]);
        f0 + (f1 - f0) * (tau - t0) / (t1 - t0)
    }
}

/// Reads (time, factor) pairs from CSV text: two numeric columns per line, separated by a comma,
/// semicolon or blanks; an optional header line and `#` comments; lines end in LF, CR LF or CR
/// (old Mac files), and a UTF-8 byte-order mark is skipped. A line of more or fewer than two
/// numbers is an error, so a decimal comma (`0,5;1,0`) or a third column is never read as
/// something else. `source` names the file (and key) in errors with the line.
pub fn parse_curve_csv(text: &str, source: &str) -> Result<Vec<[f64; 2]>> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut out = Vec::new();
    for (i, line) in text
        .split("\r\n")
        .flat_map(|l| l.split(['\r', '\n']))
        .enumerate()
    {
        let l = line.split('#').next().unwrap_or("").trim();
        if l.is_empty() {
            continue;
        }
        let fields: Vec<&str> = l
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|f| !f.is_empty())
            .collect();
        let nums: Vec<f64> = fields.iter().filter_map(|f| f.parse().ok()).collect();
        if nums.len() != fields.len() || nums.len() != 2 {
            if out.is_empty() && nums.is_empty() {
                continue; // a header
            }
            let shown: String = l.chars().filter(|c| !c.is_control()).take(60).collect();
            let hint = if nums.len() == fields.len() && nums.len() == 4 && l.contains(',') {
                " (a decimal comma? write decimals with '.', e.g. 0.5;1.0)"
            } else if nums.len() == fields.len() && nums.len() > 2 {
                " (more than two columns: keep time and factor only)"
            } else {
                ""
            };
            return Err(Error::input(
                InputKind::Format,
                format!(
                "{source}: line {}: expected two numbers (time s, factor), found '{shown}'{hint}",
                i + 1
            ),
            )
            .line(i + 1));
        }
        out.push([nums[0], nums[1]]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rising curve's inverse gives back the share it was asked for (the static solve's
    /// load steps along the smooth curve); curves that start loaded or fall are not rising.
    #[test]
    fn a_rising_curve_is_inverted_to_rounding() {
        let table = |pts: &[[f64; 2]]| {
            LoadCurve::Table(Arc::new(CurveTable::from_times(pts, 1.0, "t").unwrap()))
        };
        let rises = table(&[[0.0, 0.0], [0.5, 2.0], [0.7, 2.0], [1.0, 4.0]]);
        for c in [LoadCurve::Smooth, LoadCurve::Ramp, rises.clone()] {
            assert!(c.is_rising(), "{c:?}");
            for k in 0..=20 {
                let share = k as f64 / 20.0;
                let tau = c.fraction_at(share);
                assert!((0.0..=1.0).contains(&tau));
                let back = c.value(tau) / c.value(1.0);
                assert!(
                    (back - share).abs() < 1e-12,
                    "{c:?} {share} -> {tau} -> {back}"
                );
            }
        }
        // The smooth curve's middle: 10 t^3 - 15 t^4 + 6 t^5 = 1/2 at t = 1/2.
        assert!((LoadCurve::Smooth.fraction_at(0.5) - 0.5).abs() < 1e-15);
        // On a flat part the first load fraction that reaches it: 2 of 4 at 0.5.
        assert!((rises.fraction_at(0.5) - 0.5).abs() < 1e-12);
        for c in [
            LoadCurve::Constant,
            LoadCurve::SmoothReturn,
            table(&[[0.0, 0.2], [1.0, 1.0]]),
            table(&[[0.0, 0.0], [0.5, 1.0], [1.0, 0.5]]),
        ] {
            assert!(!c.is_rising(), "{c:?}");
        }
    }

    /// The factor range bounds every value the curve takes (sampled densely), and is reached.
    #[test]
    fn factor_range_bounds_the_curve() {
        let table =
            CurveTable::from_times(&[[0.0, 0.2], [0.3, 1.4], [0.6, -0.5], [1.0, 0.8]], 1.0, "t")
                .unwrap();
        for (c, want) in [
            (LoadCurve::Smooth, (0.0, 1.0)),
            (LoadCurve::Ramp, (0.0, 1.0)),
            (LoadCurve::SmoothReturn, (0.0, 1.0)),
            (LoadCurve::Constant, (1.0, 1.0)),
            (LoadCurve::Table(Arc::new(table)), (-0.5, 1.4)),
        ] {
            let (lo, hi) = c.factor_range();
            assert_eq!((lo, hi), want, "{c:?}");
            let values: Vec<f64> = (-100..=1100).map(|k| c.value(k as f64 / 1000.0)).collect();
            assert!(values.iter().all(|&v| lo <= v && v <= hi), "{c:?}");
            let (vlo, vhi) = values
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            assert!(
                (vlo - lo).abs() < 1e-12 && (vhi - hi).abs() < 1e-12,
                "{c:?}"
            );
        }
    }

    #[test]
    fn smooth_curve_has_zero_rate_at_ends_and_reaches_one() {
        let c = LoadCurve::Smooth;
        assert_eq!(c.value(0.0), 0.0);
        assert!((c.value(1.0) - 1.0).abs() < 1e-15);
        assert!((c.value(0.5) - 0.5).abs() < 1e-15);
        let h = 1e-6;
        assert!(((c.value(1.0) - c.value(1.0 - h)) / h).abs() < 1e-5);
        assert!(((c.value(h) - c.value(0.0)) / h).abs() < 1e-5);
    }

    #[test]
    fn return_curve_peaks_at_half_time_and_comes_back_smoothly() {
        let c = LoadCurve::SmoothReturn;
        assert_eq!(c.value(0.0), 0.0);
        assert!((c.value(0.5) - 1.0).abs() < 1e-15);
        assert!(c.value(1.0).abs() < 1e-15);
        // Symmetric about the peak and equal to the smooth curve at double speed.
        for tau in [0.1, 0.2, 0.3, 0.45] {
            assert!((c.value(tau) - c.value(1.0 - tau)).abs() < 1e-14);
            assert!((c.value(tau) - LoadCurve::Smooth.value(2.0 * tau)).abs() < 1e-15);
        }
        let h = 1e-6;
        for tau in [0.0 + h, 0.5, 1.0] {
            assert!(
                ((c.value(tau) - c.value(tau - h)) / h).abs() < 1e-4,
                "rate at {tau}"
            );
        }
    }

    /// A table reproduces its points, is linear between them and holds its end values; times
    /// map to load fractions by the load time.
    #[test]
    fn tables_interpolate_linearly_and_hold_their_ends() {
        let t = CurveTable::from_times(&[[0.0, 0.0], [1.0, 2.0], [3.0, -1.0]], 2.0, "c").unwrap();
        let c = LoadCurve::Table(Arc::new(t));
        for (tau, want) in [
            (-1.0, 0.0),
            (0.0, 0.0),
            (0.25, 1.0),
            (0.5, 2.0),
            (1.0, 0.5),
            (1.5, -1.0),
            (9.0, -1.0),
        ] {
            assert!(
                (c.value(tau) - want).abs() < 1e-15,
                "tau {tau}: {}",
                c.value(tau)
            );
        }
        let one = CurveTable::from_times(&[[0.5, 0.7]], 1.0, "c").unwrap();
        assert_eq!((one.value(0.0), one.value(2.0)), (0.7, 0.7));
        let e = CurveTable::from_times(&[[0.0, 0.0], [0.0, 1.0]], 1.0, "curves.pull")
            .unwrap_err()
            .to_string();
        assert!(e.contains("curves.pull") && e.contains("point 2"), "{e}");
        assert!(CurveTable::from_times(&[], 1.0, "c").is_err());
    }

    #[test]
    fn curve_csv_reads_headers_separators_and_names_bad_lines() {
        let p = parse_curve_csv("time,factor\n0, 0\n# note\n0.5;0.25\n1 1\n", "f.csv").unwrap();
        assert_eq!(p, vec![[0.0, 0.0], [0.5, 0.25], [1.0, 1.0]]);
        let e = parse_curve_csv("0,0\n1,x\n", "f.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("f.csv: line 2") && e.contains("1,x"), "{e}");
    }

    /// Issue 41: old-Mac (CR) and Windows (CR LF) line endings and a byte-order mark read as
    /// written; a third column and decimal commas refused with the line, not half read.
    #[test]
    fn curve_csv_reads_every_line_ending_and_refuses_what_it_would_misread() {
        let want = vec![[0.0, 0.0], [0.5, 0.25], [1.0, 1.0]];
        for text in [
            "t,f\r0,0\r0.5,0.25\r1,1\r",
            "t,f\r\n0,0\r\n0.5,0.25\r\n1,1\r\n",
            "\u{feff}t,f\n0,0\n0.5,0.25\n1,1",
        ] {
            assert_eq!(parse_curve_csv(text, "f.csv").unwrap(), want, "{text:?}");
        }
        let e = parse_curve_csv("0,0,9\n1,1,9\n", "f.csv")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 1") && e.contains("more than two columns"),
            "{e}"
        );
        let e = parse_curve_csv("0,0;0,0\n0,5;1,0\n", "f.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1") && e.contains("decimal comma"), "{e}");
        let e = parse_curve_csv("0\r1,1\r", "f.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 1") && !e.contains('\r'), "{e}");
    }
}
