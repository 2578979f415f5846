//! CSV output for time histories and other tables of numbers.

use std::io::Write;
use std::path::Path;

use super::vtu::{write_atomically, write_f64};
use crate::{Error, InputKind, Result};

/// Writes a table of numbers as CSV: one header line, then one line per row.
///
/// Numbers are written with the fewest digits that parse back to exactly the same `f64`
/// (scientific notation for very small or large magnitudes; `NaN`, `inf`, `-inf` for
/// non-finite values). Header fields containing a comma, quote or line break are quoted as in
/// RFC 4180. Every row must have as many values as the header has fields (when the header is
/// empty, rows may have any length). The file appears at `path` only once fully written.
pub fn write_csv(path: &Path, header: &[String], rows: &[Vec<f64>]) -> Result<()> {
    if !header.is_empty() {
        if let Some((i, r)) = rows
            .iter()
            .enumerate()
            .find(|(_, r)| r.len() != header.len())
        {
            return Err(Error::input(
                InputKind::Format,
                format!(
                    "{}: CSV row {i} has {} values but the header has {} columns",
                    path.display(),
                    r.len(),
                    header.len()
                ),
            ));
        }
    }
    write_atomically(path, |w| {
        if !header.is_empty() {
            for (k, h) in header.iter().enumerate() {
                if k > 0 {
                    w.write_all(b",")?;
                }
                if h.contains([',', '"', '\n', '\r']) {
                    write!(w, "\"{}\"", h.replace('"', "\"\""))?;
                } else {
                    w.write_all(h.as_bytes())?;
                }
            }
            w.write_all(b"\n")?;
        }
        for row in rows {
            for (k, &x) in row.iter().enumerate() {
                if k > 0 {
                    w.write_all(b",")?;
                }
                write_f64(w, x)?;
            }
            w.write_all(b"\n")?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_round_trips_exactly() {
        let dir = std::env::temp_dir().join(format!("hytled-csv-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("history.csv");
        let header = vec![
            "time_s".to_string(),
            "force, N".to_string(),
            "u\"x\"".to_string(),
        ];
        let rows: Vec<Vec<f64>> = (0..200)
            .map(|i| {
                let t = i as f64 * 1e-5 / 3.0;
                vec![t, (t * 1e3).sin() * 1e-9, -(i as f64).exp() * 1e10 / 7.0]
            })
            .chain([
                vec![0.0, -0.0, f64::MIN_POSITIVE],
                vec![f64::MAX, f64::MIN, 5e-324],
                vec![0.1, 1e15, 123_456_789.123_456_79],
                vec![f64::INFINITY, f64::NEG_INFINITY, 1e-4],
            ])
            .collect();
        write_csv(&path, &header, &rows).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next().unwrap(), "time_s,\"force, N\",\"u\"\"x\"\"\"");
        let mut n = 0;
        for (line, row) in lines.zip(&rows) {
            let back: Vec<f64> = line.split(',').map(|s| s.parse::<f64>().unwrap()).collect();
            assert_eq!(back.len(), row.len());
            for (a, b) in back.iter().zip(row) {
                assert_eq!(a.to_bits(), b.to_bits(), "{line}");
            }
            n += 1;
        }
        assert_eq!(n, rows.len());

        let bad = write_csv(&dir.join("bad.csv"), &header, &[vec![1.0, 2.0]]);
        assert!(
            matches!(&bad, Err(e @ Error::Input(_)) if e.to_string().contains("row 0")),
            "{bad:?}"
        );
        assert!(!dir.join("bad.csv").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
