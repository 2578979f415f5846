//! Results at the points a discretization shows them on: the FE nodes, the meshless
//! background vertices, the coupled nodes; their cells, and the rows that take nodal values
//! there (meshless and blended nodal values are parameters, not displacements). The VTU
//! frames, warped images and the Python fields all read them here.

use nalgebra::Vector3;

use super::Discretization;
use std::borrow::Cow;

use crate::geometry::Mesh;
use crate::material::Solid;
use crate::quadrature::SparseRow;
use crate::solver::{Fields, Model};
use crate::{Error, InputKind, Result};

/// A frame's points (m), its cells and where its quadrature points lie.
pub(super) struct FrameGeometry<'a> {
    pub points: &'a [Vector3<f64>],
    pub connectivity: Vec<usize>,
    pub offsets: Vec<usize>,
    /// VTK cell types.
    pub types: Vec<u8>,
    /// The cell of each quadrature point (None for a point in no cell, a meshless grid
    /// point); None: the points are the elements', in element order.
    /// Borrowed where the method holds it so (meshless), made for coupled cells.
    pub owner: Option<Cow<'a, [Option<usize>]>>,
}

/// The fields of one state at the points of the VTU frames ([`ResultPoints::point_fields`]):
/// reference positions (m), cells as VTK writes them (connectivity, offsets, VTK cell types),
/// displacement (m) and the nodal Cauchy stress (Pa), Green-Lagrange strain, von Mises stress
/// (Pa) and J ([`Model::nodal_fields`]; meshless: interpolated with the shape functions).
#[derive(Debug, Clone)]
pub struct PointFields {
    pub points: Vec<Vector3<f64>>,
    pub connectivity: Vec<usize>,
    pub offsets: Vec<usize>,
    pub types: Vec<u8>,
    pub displacement: Vec<Vector3<f64>>,
    pub fields: Fields,
}

/// Sums `rows` of `values` (`width` numbers per entry) into one entry per row.
fn interpolate(rows: &[SparseRow], values: &[f64], width: usize) -> Vec<f64> {
    let mut out = vec![0.0; rows.len() * width];
    for (r, row) in rows.iter().enumerate() {
        for &(i, p) in row {
            let i = i as usize;
            for c in 0..width {
                out[r * width + c] += p * values[i * width + c];
            }
        }
    }
    out
}

/// The points results are given at, for a prepared discretization ([`super::Prepared::mesh`]
/// and [`super::Prepared::method`]).
pub struct ResultPoints<'a> {
    mesh: &'a Mesh,
    method: &'a Discretization,
    /// Meshless and coupled: the row that gives each point's displacement.
    interp: Option<Vec<SparseRow>>,
}

impl<'a> ResultPoints<'a> {
    /// The points of `mesh` and `method`, with their interpolation rows.
    pub fn new(mesh: &'a Mesh, method: &'a Discretization) -> Result<Self> {
        let interp = match method {
            Discretization::Coupled { build, .. } => Some(build.vertex_weights()?),
            Discretization::Meshless { build, .. } => Some(
                build
                    .background
                    .nodes
                    .iter()
                    .enumerate()
                    .map(|(v, x)| build.shape_values(x, &|| format!("output point {v}")))
                    .collect::<Result<Vec<_>>>()?,
            ),
            Discretization::Fe => None,
        };
        Ok(ResultPoints {
            mesh,
            method,
            interp,
        })
    }

    /// The field node at result point `v` (meshless: the node at a background vertex, None
    /// where it was removed as poorly supported).
    pub fn node(&self, v: usize) -> Option<usize> {
        match self.method {
            Discretization::Meshless { build, .. } => {
                build.background_node.get(v).copied().flatten()
            }
            _ => Some(v),
        }
    }

    /// The frame's cells as one mesh over its points (reference positions, m) and the
    /// displacement (m) at each point for nodal values `u`: what `output.image` warps with.
    pub fn deformation(&self, u: &[Vector3<f64>]) -> Result<(Mesh, Vec<Vector3<f64>>)> {
        let mesh = match self.method {
            Discretization::Meshless { build: m, .. } => {
                if m.background.num_cells() == 0 {
                    return Err(Error::input(InputKind::Unsupported,
                        "output.image needs the body's cells, and this meshless cloud has no background \
                         tets (use integration = \"tets\" or cloud = \"mesh\")",
                    ));
                }
                m.background.clone()
            }
            Discretization::Coupled { build: c, .. } => {
                let fe = crate::geometry::mesh::hex_to_tets(c.fe_mesh.clone());
                let inner = crate::geometry::mesh::hex_to_tets(c.interior.clone());
                let mut cells = fe.cells;
                cells.extend_from_slice(&inner.cells);
                Mesh {
                    nodes: c.nodes.clone(),
                    shape: crate::geometry::ElementShape::Tet4,
                    cells,
                }
            }
            Discretization::Fe => self.mesh.clone(),
        };
        let flat_u: Vec<f64> = u.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
        let disp = match &self.interp {
            Some(rows) => interpolate(rows, &flat_u, 3),
            None => flat_u,
        };
        let disp: Vec<Vector3<f64>> = disp
            .chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect();
        if disp.len() != mesh.nodes.len() {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "output.image: {} displacements for the frame's {} points",
                    disp.len(),
                    mesh.nodes.len()
                ),
            ));
        }
        Ok((mesh, disp))
    }

    /// The frame's points and cells: FE mesh, meshless background tets (or vertices),
    /// coupled FE layer and interior; `owner` maps points to cells (None: one per element).
    pub(super) fn geometry(&self) -> FrameGeometry<'a> {
        let (points, (connectivity, offsets, types), owner) = match self.method {
            Discretization::Meshless { build: m, .. } => {
                let b = &m.background;
                let cells = if b.num_cells() == 0 {
                    // A cloud without tets: each vertex a VTK vertex.
                    let n = b.nodes.len();
                    ((0..n).collect(), (1..=n).collect(), vec![1u8; n])
                } else {
                    let npc = b.shape.nodes_per_cell();
                    (
                        b.cells.clone(),
                        (1..=b.num_cells()).map(|e| e * npc).collect(),
                        vec![b.shape.vtk_type(); b.num_cells()],
                    )
                };
                (&b.nodes[..], cells, Some(Cow::Borrowed(&m.owner[..])))
            }
            Discretization::Coupled { build: c, .. } => (
                &c.nodes[..],
                c.vtu_cells(),
                Some(Cow::Owned(c.owner.iter().map(|&e| Some(e)).collect())),
            ),
            Discretization::Fe => {
                let m = self.mesh;
                let npc = m.shape.nodes_per_cell();
                (
                    &m.nodes[..],
                    (
                        m.cells.clone(),
                        (1..=m.num_cells()).map(|e| e * npc).collect(),
                        vec![m.shape.vtk_type(); m.num_cells()],
                    ),
                    None,
                )
            }
        };
        FrameGeometry {
            points,
            connectivity,
            offsets,
            types,
            owner,
        }
    }

    /// Displacements (m, x y z per point) and nodal fields at the frame's points for nodal
    /// values `u` (m).
    pub(super) fn at_points(
        &self,
        model: &mut Model<Solid>,
        u: &[Vector3<f64>],
    ) -> (Vec<f64>, Fields) {
        let nodal = model.nodal_fields(u);
        let flat_u: Vec<f64> = u.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
        match (&self.interp, self.method) {
            (Some(rows), Discretization::Meshless { .. }) => {
                let mut f = Fields::zeros(rows.len());
                let (c, e, j) = (
                    interpolate(rows, &nodal.cauchy, 9),
                    interpolate(rows, &nodal.green, 9),
                    interpolate(rows, &nodal.j, 1),
                );
                for v in 0..rows.len() {
                    f.set(
                        v,
                        &nalgebra::Matrix3::from_row_slice(&c[9 * v..9 * v + 9]),
                        &nalgebra::Matrix3::from_row_slice(&e[9 * v..9 * v + 9]),
                        j[v],
                    );
                }
                (interpolate(rows, &flat_u, 3), f)
            }
            (Some(rows), _) => (interpolate(rows, &flat_u, 3), nodal),
            (None, _) => (flat_u, nodal),
        }
    }

    /// A state's fields on the frame's points, in memory: what [`super::FrameWriter::write`] writes as
    /// point data, with the frame's cells (the Python `nodal_fields`).
    pub fn point_fields(&self, model: &mut Model<Solid>, u: &[Vector3<f64>]) -> PointFields {
        let g = self.geometry();
        let (disp, fields) = self.at_points(model, u);
        PointFields {
            points: g.points.to_vec(),
            connectivity: g.connectivity,
            offsets: g.offsets,
            types: g.types,
            displacement: disp
                .chunks_exact(3)
                .map(|c| Vector3::new(c[0], c[1], c[2]))
                .collect(),
            fields,
        }
    }
}
