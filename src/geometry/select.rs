//! Node selections for boundaries and probes.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

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
    /// Nodes with X[axis] = value within `tolerance` (default 1e-6 x the model's bounding-box diagonal).
    Plane {
        axis: Axis,
        value: f64,
        #[serde(default)]
        tolerance: Option<f64>,
    },
    /// Nodes inside the axis-aligned box [min, max] (inclusive).
    Box { min: [f64; 3], max: [f64; 3] },
    /// Nodes within `radius` of `center`.
    Sphere { center: [f64; 3], radius: f64 },
    /// A named node set from a mesh file.
    Set(String),
}

impl Selection {
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
                    return Err(Error::Input(format!(
                        "{what}: plane {axis:?} = {value} m selects no node (tolerance {tol:.3e} m; nearest node is {nearest:.6e} m away; \
                         the model spans {:?}..{:?})",
                        lo[k], hi[k]
                    )));
                }
                sel
            }
            Selection::Box { min, max } => (0..nodes.len())
                .filter(|&i| (0..3).all(|k| nodes[i][k] >= min[k] && nodes[i][k] <= max[k]))
                .collect(),
            Selection::Sphere { center, radius } => {
                let c = Vector3::from(*center);
                (0..nodes.len())
                    .filter(|&i| (nodes[i] - c).norm() <= *radius)
                    .collect()
            }
            Selection::Set(name) => {
                let Some(lookup) = sets else {
                    return Err(Error::Input(format!(
                        "{what}: named set '{name}' is not available: built-in shapes define no node sets; \
                         select with plane, box or sphere, or read the body from a mesh file (geometry.mesh)"
                    )));
                };
                let pos = lookup(name).map_err(|m| Error::Input(format!("{what}: {m}")))?;
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
            return Err(Error::Input(format!(
                "{what}: selection {self:?} contains no node (model bounding box {:?} .. {:?} m)",
                lo.as_slice(),
                hi.as_slice()
            )));
        }
        Ok(picked)
    }
}

fn bounds(nodes: &[Vector3<f64>]) -> (Vector3<f64>, Vector3<f64>) {
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
}
