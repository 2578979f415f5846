//! Measured displacements (the image-driven brain-shift workflow: displacements of the exposed
//! surface registered from intra-operative images): one point per line, either its position and
//! displacement, `x, y, z, ux, uy, uz`, or a node id of the mesh file and the displacement,
//! `id, ux, uy, uz`. Metres; comma, semicolon or blank separated; an optional header line and
//! `#` comments.

use std::path::Path;

use nalgebra::Vector3;

use crate::{Error, InputKind, Result};

/// Where a measured displacement applies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MeasuredAt {
    /// A position, m (matched to the nearest surface node).
    Position(Vector3<f64>),
    /// A node id of the mesh file.
    Node(u64),
}

/// One measured displacement and the line it came from (1-based).
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    pub line: usize,
    pub at: MeasuredAt,
    /// Displacement, m.
    pub u: Vector3<f64>,
}

/// Parses measured displacements; `source` names the file in errors (with the line). Every
/// data line has the same form: 6 numbers (position and displacement) or 4 (an integer node id
/// and the displacement). An empty file is an error.
pub fn parse_measured(text: &str, source: &Path) -> Result<Vec<Measured>> {
    let name = source.display();
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut out: Vec<Measured> = Vec::new();
    let mut width = None;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let body = raw.split('#').next().unwrap_or("").trim();
        if body.is_empty() {
            continue;
        }
        let fields: Vec<&str> = body
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|f| !f.is_empty())
            .collect();
        let numbers: Vec<f64> = fields.iter().filter_map(|f| f.parse().ok()).collect();
        if out.is_empty() && width.is_none() && numbers.is_empty() {
            continue; // header
        }
        let shown: String = body.chars().take(60).collect();
        if numbers.len() != fields.len() || !(numbers.len() == 6 || numbers.len() == 4) {
            return Err(Error::input(
                InputKind::Format,
                format!(
                "{name}: line {line}: expected x, y, z, ux, uy, uz (6 numbers) or id, ux, uy, uz \
                 (4), found '{shown}'"
            ),
            )
            .placed(source, line));
        }
        if *width.get_or_insert(numbers.len()) != numbers.len() {
            return Err(Error::input(
                InputKind::Format,
                format!(
                "{name}: line {line}: {} numbers where the earlier lines have {}; use one form \
                 for the whole file",
                numbers.len(),
                width.unwrap_or(0)
            ),
            )
            .placed(source, line));
        }
        if let Some(v) = numbers.iter().find(|v| !v.is_finite()) {
            return Err(Error::input(
                InputKind::Format,
                format!("{name}: line {line}: {v} is not a finite number"),
            )
            .placed(source, line));
        }
        let (at, u) = if numbers.len() == 6 {
            (
                MeasuredAt::Position(Vector3::new(numbers[0], numbers[1], numbers[2])),
                Vector3::new(numbers[3], numbers[4], numbers[5]),
            )
        } else {
            let id = fields[0].parse::<u64>().map_err(|_| {
                Error::input(
                    InputKind::Format,
                    format!(
                        "{name}: line {line}: node id '{}' is not a non-negative integer",
                        fields[0]
                    ),
                )
                .placed(source, line)
            })?;
            (
                MeasuredAt::Node(id),
                Vector3::new(numbers[1], numbers[2], numbers[3]),
            )
        };
        out.push(Measured { line, at, u });
    }
    if out.is_empty() {
        return Err(Error::input(
            InputKind::Format,
            format!("{name}: no measured displacement in the file"),
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_forms_read_and_errors_name_the_line() {
        let p = Path::new("m.csv");
        let m = parse_measured(
            "x,y,z,ux,uy,uz\n0,0,1, 0,0,-0.001\n# c\n1 0 1 0.0 0 -0.002\n",
            p,
        )
        .unwrap();
        assert_eq!(m.len(), 2);
        assert_eq!(m[1].line, 4);
        assert_eq!(m[1].at, MeasuredAt::Position(Vector3::new(1.0, 0.0, 1.0)));
        assert_eq!(m[1].u, Vector3::new(0.0, 0.0, -0.002));
        let m = parse_measured("12;0;0;-1e-3\n", p).unwrap();
        assert_eq!(m[0].at, MeasuredAt::Node(12));
        for (text, want) in [
            ("0,0,1,0,0\n", "line 1: expected"),
            ("0,0,1,0,0,0\n5,0,0,0\n", "line 2: 4 numbers"),
            ("1.5,0,0,0\n", "node id '1.5'"),
            ("# nothing\n", "no measured"),
            ("0,0,1,0,0,inf\n", "not a finite"),
        ] {
            let e = parse_measured(text, p).unwrap_err().to_string();
            assert!(e.contains("m.csv") && e.contains(want), "{text:?}: {e}");
        }
    }
}
