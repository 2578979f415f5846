//! Probes: displacement at arbitrary material points, interpolated with the shape functions of
//! the element that contains the point (FE) or with the meshless shape functions there.

use nalgebra::Vector3;

use crate::fe::{hex8, tet4};
use crate::geometry::cell_grid::CellGrid;
use crate::geometry::{ElementShape, Mesh};
use crate::{Error, InputKind, Result};

/// A material point and the interpolation that gives its displacement from nodal values.
#[derive(Debug, Clone)]
pub struct Probe {
    pub name: String,
    /// Reference position, m.
    pub position: Vector3<f64>,
    pub nodes: Vec<usize>,
    pub weights: Vec<f64>,
    /// The element whose shape functions interpolate (None: a selection's mean, or meshless or
    /// blended shape functions).
    pub element: Option<usize>,
}

/// Where a point lies in a mesh: the cell that holds it (or lies within 5 % of it) and the
/// cell's nodes with their shape-function values at the point.
#[derive(Debug, Clone)]
pub struct Location {
    pub element: usize,
    pub nodes: Vec<usize>,
    pub weights: Vec<f64>,
}

/// Locates `position` (m) among `cells` of `mesh` (ascending). A point just outside the faceted
/// surface (e.g. on the true circle of a polygonal cylinder) is accepted up to 5 % of an element
/// beyond its faces, using the element's shape functions; farther away is an error that names
/// the point by `what`.
pub fn locate_among(
    position: &Vector3<f64>,
    mesh: &Mesh,
    cells: impl Iterator<Item = usize>,
    what: &dyn Fn() -> String,
) -> Result<Location> {
    let position = *position;
    // best = (how far outside in natural coordinates, element, weights)
    let mut best: Option<(f64, usize, Vec<f64>)> = None;
    for e in cells {
        let ids = mesh.cell(e);
        let (outside, w): (f64, Vec<f64>) = match mesh.shape {
            ElementShape::Hex8 => {
                let x: [Vector3<f64>; 8] = std::array::from_fn(|a| mesh.nodes[ids[a]]);
                // Cheap bounding-box rejection before Newton.
                let (lo, hi) = x
                    .iter()
                    .fold((x[0], x[0]), |(l, h), p| (l.inf(p), h.sup(p)));
                let pad = 0.1 * (hi - lo).amax();
                if (0..3).any(|k| position[k] < lo[k] - pad || position[k] > hi[k] + pad) {
                    continue;
                }
                let Some(xi) = hex8::natural_coordinates(&x, &position) else {
                    continue;
                };
                let out = xi
                    .iter()
                    .map(|v| (v.abs() - 1.0).max(0.0))
                    .fold(0.0, f64::max)
                    / 2.0;
                (out, hex8::shape(xi).to_vec())
            }
            ElementShape::Tet4 => {
                let x: [Vector3<f64>; 4] = std::array::from_fn(|a| mesh.nodes[ids[a]]);
                let Some(l) = tet4::barycentric(&x, &position) else {
                    continue;
                };
                let out = l.iter().map(|v| (-v).max(0.0)).fold(0.0, f64::max);
                (out, l.to_vec())
            }
        };
        if best.as_ref().is_none_or(|b| outside < b.0) {
            best = Some((outside, e, w));
            if outside == 0.0 {
                break;
            }
        }
    }
    match best {
        Some((out, e, w)) if out <= 0.05 => Ok(Location {
            element: e,
            nodes: mesh.cell(e).to_vec(),
            weights: w,
        }),
        _ => Err(Error::input(
            InputKind::Selection,
            format!(
                "{} at {:?} m lies outside the mesh; move it inside the body",
                what(),
                position.as_slice()
            ),
        )),
    }
}

/// [`locate_among`] among the cells `grid` (made from `mesh`) lists near `position`: the same
/// answer in constant time (each cell that could hold the point, or lie within the accepted
/// 5 %, is among them, in ascending order).
pub fn locate_in_grid(
    position: &Vector3<f64>,
    mesh: &Mesh,
    grid: &CellGrid,
    what: &dyn Fn() -> String,
) -> Result<Location> {
    let cells = grid.candidates(position);
    locate_among(position, mesh, cells.iter().map(|&e| e as usize), what)
}

impl Probe {
    /// A probe at `position` (m) in `mesh`, interpolated with its element's shape functions
    /// ([`locate_among`] over every cell).
    pub fn locate(name: &str, position: Vector3<f64>, mesh: &Mesh) -> Result<Probe> {
        let at = locate_among(&position, mesh, 0..mesh.num_cells(), &|| {
            format!("probe '{name}'")
        })?;
        Ok(Probe {
            name: name.into(),
            position,
            nodes: at.nodes,
            weights: at.weights,
            element: Some(at.element),
        })
    }

    /// Interpolated displacement, m.
    pub fn displacement(&self, u: &[Vector3<f64>]) -> Vector3<f64> {
        self.nodes
            .iter()
            .zip(&self.weights)
            .fold(Vector3::zeros(), |acc, (&n, &w)| acc + u[n] * w)
    }
}
