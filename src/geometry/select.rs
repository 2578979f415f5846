//! Node selections for boundaries and probes.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::{Error, InputKind, Result};

/// A coordinate axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    /// Component index 0, 1, 2.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// Positions (m) of the nodes of a named set, or an error listing the available names.
pub type SetLookup<'a> = dyn Fn(&str) -> std::result::Result<Vec<Vector3<f64>>, String> + 'a;

/// Which nodes a boundary acts on. Coordinates in metres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum Selection {
    /// Nodes with X\[axis\] = value within `tolerance` (default 1e-6 x the model's bounding-box diagonal).
    Plane {
        axis: Axis,
        value: f64,
        #[serde(default)]
        tolerance: Option<f64>,
    },
    /// Nodes inside the axis-aligned box [min, max] (inclusive).
    Box { min: [f64; 3], max: [f64; 3] },
    /// Nodes within `radius` of `center` (and 1e-9 x the model's size beyond it, rounding).
    Sphere { center: [f64; 3], radius: f64 },
    /// Nodes within `radius` of the line through `center` along `axis`, whose coordinate along
    /// the axis lies in [`min`, `max`] (inclusive, and 1e-9 x the model's size beyond, for
    /// rounding; either bound may be left out), e.g. an
    /// indenter: `{ cylinder = { axis = "z", center = [0, 0, 0], radius = 0.005, min = 0.0275 } }`.
    Cylinder {
        axis: Axis,
        center: [f64; 3],
        radius: f64,
        #[serde(default)]
        min: Option<f64>,
        #[serde(default)]
        max: Option<f64>,
    },
    /// A named node set from a mesh file.
    Set(String),
}

impl Selection {
    /// Refuses sizes no node can satisfy: a negative plane tolerance, a sphere or cylinder
    /// radius that is not positive, a box or cylinder range with min above max. The message
    /// starts with the field, for the caller to prefix with the key.
    pub fn check(&self) -> std::result::Result<(), String> {
        match self {
            Selection::Plane {
                tolerance: Some(t), ..
            } if !(*t >= 0.0) => Err(format!("plane tolerance = {t}: must be >= 0 (m)")),
            Selection::Sphere { radius, .. } | Selection::Cylinder { radius, .. }
                if !(*radius > 0.0) =>
            {
                Err(format!("radius = {radius}: must be positive (m)"))
            }
            Selection::Box { min, max } if (0..3).any(|k| !(min[k] <= max[k])) => Err(format!(
                "box min = {min:?} and max = {max:?}: each min must be at most its max (m)"
            )),
            Selection::Cylinder {
                min: Some(a),
                max: Some(b),
                ..
            } if !(a <= b) => Err(format!("cylinder min = {a} above max = {b} (m)")),
            _ => Ok(()),
        }
    }

    /// Indices of the selected nodes, ascending. An empty selection is an error that says how
    /// far the nearest node was, so the user can fix the coordinate or tolerance.
    pub fn select(&self, nodes: &[Vector3<f64>], what: &str) -> Result<Vec<usize>> {
        self.select_with(nodes, what, None)
    }

    /// As [`Selection::select`], with the named sets of a mesh file: `sets(name)` gives the
    /// positions of a set's nodes (or the list of available names as the error), and the
    /// selected nodes are those at exactly those positions (so sets survive renumbering, node
    /// removal and meshless clouds made from the mesh vertices).
    pub fn select_with(
        &self,
        nodes: &[Vector3<f64>],
        what: &str,
        sets: Option<&SetLookup>,
    ) -> Result<Vec<usize>> {
        let (lo, hi) = bounds(nodes);
        let diag = (hi - lo).norm();
        let picked: Vec<usize> = match self {
            Selection::Plane {
                axis,
                value,
                tolerance,
            } => {
                let tol = tolerance.unwrap_or(1e-6 * diag);
                let k = axis.index();
                let sel: Vec<usize> = (0..nodes.len())
                    .filter(|&i| (nodes[i][k] - value).abs() <= tol)
                    .collect();
                if sel.is_empty() {
                    let nearest = nodes
                        .iter()
                        .map(|p| (p[k] - value).abs())
                        .fold(f64::INFINITY, f64::min);
                    return Err(Error::input(InputKind::Selection, format!(
                        "{what}: plane {axis:?} = {value} m selects no node (tolerance {sci_tol:.3e} m; nearest node is {sci_nearest:.6e} m away; \
                         the model spans {axis:?} {:.6e}..{:.6e} m)",
                        crate::error::Sci(lo[k]), crate::error::Sci(hi[k]), sci_tol = crate::error::Sci(tol), sci_nearest = crate::error::Sci(nearest))));
                }
                sel
            }
            Selection::Box { min, max } => (0..nodes.len())
                .filter(|&i| (0..3).all(|k| nodes[i][k] >= min[k] && nodes[i][k] <= max[k]))
                .collect(),
            Selection::Sphere { center, radius } => {
                let c = Vector3::from(*center);
                (0..nodes.len())
                    .filter(|&i| (nodes[i] - c).norm() <= *radius + 1e-9 * diag)
                    .collect()
            }
            Selection::Cylinder {
                axis,
                center,
                radius,
                min,
                max,
            } => {
                if !(radius.is_finite() && *radius >= 0.0) {
                    return Err(Error::input(
                        InputKind::Value,
                        format!(
                            "{what}: cylinder radius {radius} m must be non-negative and finite"
                        ),
                    ));
                }
                let (lo_a, hi_a) = (
                    min.unwrap_or(f64::NEG_INFINITY),
                    max.unwrap_or(f64::INFINITY),
                );
                if lo_a.is_nan() || hi_a.is_nan() || lo_a > hi_a {
                    return Err(Error::input(InputKind::Value, format!(
                        "{what}: cylinder bounds min = {lo_a} m, max = {hi_a} m must satisfy min <= max"
                    )));
                }
                let k = axis.index();
                let c = Vector3::from(*center);
                // (distance from the axis, coordinate along it)
                let split = |p: &Vector3<f64>| -> (f64, f64) {
                    let mut d = p - c;
                    d[k] = 0.0;
                    (d.norm(), p[k])
                };
                let sel: Vec<usize> = (0..nodes.len())
                    .filter(|&i| {
                        // Within rounding (1e-9 x the model's size) of the surface: the
                        // nodes a mesher put on it (a TetGen plug's side and floor) count.
                        let (r, t) = split(&nodes[i]);
                        let tol = 1e-9 * diag;
                        r <= *radius + tol && t >= lo_a - tol && t <= hi_a + tol
                    })
                    .collect();
                if sel.is_empty() {
                    // Euclidean distance from the nearest node to the selected solid cylinder.
                    let nearest = nodes
                        .iter()
                        .map(|p| {
                            let (r, t) = split(p);
                            let dr = (r - radius).max(0.0);
                            let dt = (lo_a - t).max(t - hi_a).max(0.0);
                            dr.hypot(dt)
                        })
                        .fold(f64::INFINITY, f64::min);
                    let span = match (min, max) {
                        (Some(a), Some(b)) => format!(" ({axis:?} in [{a}, {b}] m)"),
                        (Some(a), None) => format!(" ({axis:?} >= {a} m)"),
                        (None, Some(b)) => format!(" ({axis:?} <= {b} m)"),
                        (None, None) => String::new(),
                    };
                    return Err(Error::input(InputKind::Selection, format!(
                        "{what}: cylinder along {axis:?} through {center:?} of radius {radius} m{span} \
                         selects no node (nearest node is {sci_nearest:.6e} m away; the model spans X {:.6e}..{:.6e}, \
                         Y {:.6e}..{:.6e}, Z {:.6e}..{:.6e} m)",
                        crate::error::Sci(lo.x), crate::error::Sci(hi.x), crate::error::Sci(lo.y), crate::error::Sci(hi.y), crate::error::Sci(lo.z), crate::error::Sci(hi.z), sci_nearest = crate::error::Sci(nearest))));
                }
                sel
            }
            Selection::Set(name) => {
                let Some(lookup) = sets else {
                    return Err(Error::input(InputKind::Selection, format!(
                        "{what}: named set '{name}' is not available: built-in shapes define no node sets; \
                         select with plane, box, sphere or cylinder, or read the body from a mesh file (geometry.mesh)"
                    )));
                };
                let pos = lookup(name)
                    .map_err(|m| Error::input(InputKind::Mesh, format!("{what}: {m}")))?;
                let keys: std::collections::HashSet<[u64; 3]> = pos
                    .iter()
                    .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
                    .collect();
                (0..nodes.len())
                    .filter(|&i| {
                        keys.contains(&[
                            nodes[i].x.to_bits(),
                            nodes[i].y.to_bits(),
                            nodes[i].z.to_bits(),
                        ])
                    })
                    .collect()
            }
        };
        if picked.is_empty() {
            return Err(Error::input(
                InputKind::Selection,
                format!(
                "{what}: selection {self:?} contains no node (model bounding box {:?} .. {:?} m)",
                lo.as_slice(),
                hi.as_slice()
            ),
            ));
        }
        Ok(picked)
    }
}

/// Axis-aligned bounding box (min, max) of `nodes`, m; (+inf, -inf) when empty.
pub fn bounds(nodes: &[Vector3<f64>]) -> (Vector3<f64>, Vector3<f64>) {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in nodes {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_selection_and_empty_error() {
        let nodes: Vec<_> = (0..5)
            .map(|i| Vector3::new(0.0, 0.0, 0.025 * i as f64))
            .collect();
        let s = Selection::Plane {
            axis: Axis::Z,
            value: 0.1,
            tolerance: None,
        };
        assert_eq!(s.select(&nodes, "boundary 'top'").unwrap(), vec![4]);
        let s = Selection::Plane {
            axis: Axis::Z,
            value: 0.2,
            tolerance: None,
        };
        let e = s.select(&nodes, "boundary 'top'").unwrap_err().to_string();
        assert!(
            e.contains("boundary 'top'") && e.contains("selects no node"),
            "{e}"
        );
        let s = Selection::Sphere {
            center: [1.0, 1.0, 1.0],
            radius: 0.1,
        };
        assert!(s
            .select(&nodes, "probe")
            .unwrap_err()
            .to_string()
            .contains("contains no node"));
    }

    #[test]
    fn cylinder_selection_radius_bounds_and_empty_error() {
        // A 5 x 5 x 5 lattice of spacing 1 mm.
        let mut nodes = Vec::new();
        for k in 0..5 {
            for j in 0..5 {
                for i in 0..5 {
                    nodes.push(Vector3::new(
                        0.001 * i as f64,
                        0.001 * j as f64,
                        0.001 * k as f64,
                    ));
                }
            }
        }
        let id = |i: usize, j: usize, k: usize| i + 5 * j + 25 * k;
        // Axis z through (2, 2) mm, radius 1 mm (inclusive): the centre column and its four
        // neighbours, top two layers only (z >= 3 mm, inclusive).
        let s = Selection::Cylinder {
            axis: Axis::Z,
            center: [0.002, 0.002, 0.0],
            radius: 0.001 + 1e-12,
            min: Some(0.003),
            max: None,
        };
        let mut want = Vec::new();
        for k in 3..5 {
            for (i, j) in [(2, 1), (1, 2), (2, 2), (3, 2), (2, 3)] {
                want.push(id(i, j, k));
            }
        }
        want.sort();
        assert_eq!(s.select(&nodes, "indenter").unwrap(), want);
        // Both bounds; axis x: the line y = z = 0 with radius 0 is the edge i = 0..4, j = k = 0.
        let s = Selection::Cylinder {
            axis: Axis::X,
            center: [0.5, 0.0, 0.0],
            radius: 0.0,
            min: Some(0.001),
            max: Some(0.003),
        };
        assert_eq!(
            s.select(&nodes, "edge").unwrap(),
            vec![id(1, 0, 0), id(2, 0, 0), id(3, 0, 0)]
        );
        // No bounds: the whole column.
        let s = Selection::Cylinder {
            axis: Axis::Y,
            center: [0.004, 0.0, 0.004],
            radius: 1e-9,
            min: None,
            max: None,
        };
        assert_eq!(
            s.select(&nodes, "column").unwrap(),
            (0..5).map(|j| id(4, j, 4)).collect::<Vec<_>>()
        );
        // Empty: above the model; the nearest node is 1 mm below the bottom of the cylinder.
        let s = Selection::Cylinder {
            axis: Axis::Z,
            center: [0.002, 0.002, 0.0],
            radius: 0.0005,
            min: Some(0.005),
            max: None,
        };
        let e = s
            .select(&nodes, "boundary 'indenter'")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("boundary 'indenter'")
                && e.contains("selects no node")
                && e.contains("1.000000e-3 m away")
                && e.contains("(Z >= 0.005 m)")
                && !e.contains("  "),
            "{e}"
        );
        // Bad radius, crossed bounds.
        let s = Selection::Cylinder {
            axis: Axis::Z,
            center: [0.0; 3],
            radius: -1.0,
            min: None,
            max: None,
        };
        assert!(s.select(&nodes, "x").is_err());
        let s = Selection::Cylinder {
            axis: Axis::Z,
            center: [0.0; 3],
            radius: 1.0,
            min: Some(0.003),
            max: Some(0.001),
        };
        assert!(s.select(&nodes, "x").is_err());
    }

    #[test]
    fn cylinder_selection_from_toml() {
        #[derive(Deserialize)]
        struct W {
            select: Selection,
        }
        let w: W = toml::from_str(
            "select = { cylinder = { axis = \"z\", center = [0.0, 0.0, 0.0], radius = 0.005, min = 0.0275 } }",
        )
        .unwrap();
        assert_eq!(
            w.select,
            Selection::Cylinder {
                axis: Axis::Z,
                center: [0.0; 3],
                radius: 0.005,
                min: Some(0.0275),
                max: None
            }
        );
        assert!(toml::from_str::<W>(
            "select = { cylinder = { axis = \"z\", center = [0.0, 0.0, 0.0], radius = 0.005, mni = 0.0 } }"
        )
        .is_err());
    }
}
