//! What loads, contact and measured displacements need of a discretization, whatever its
//! method: the nodes, the interpolation row that gives the displacement at a node's position
//! (the node itself for FE nodes; shape functions for meshless and blended nodes, which do not
//! interpolate) and the body's outward boundary faces with the rows at points on them.

use nalgebra::Vector3;

use crate::bc::loads::Face;
use crate::coupling::CoupledBuild;
use crate::fe::tet10::Tet10Mesh;
use crate::geometry::{quality, Mesh};
use crate::meshless::discretize::MeshlessBuild;
use crate::probe::locate_among;
use crate::quadrature::SparseRow;
use crate::{Error, InputKind, Result};

/// A built discretization, seen through what the pipeline shared by the methods needs
/// (issue 58's build seam): its nodes, the rows that interpolate the displacement at a node or
/// a point, the selections a node set implies, and its surface. Loads, contact, measured
/// displacements and probes are built over it once for every method.
#[derive(Clone, Copy)]
pub(crate) enum Discretized<'a> {
    /// A finite-element mesh; with quadratic (tet10) elements, its mesh is the linear split
    /// over all nodes and [`QuadraticFe`] gives the elements.
    Fe(&'a Mesh, Option<QuadraticFe<'a>>),
    Meshless(&'a MeshlessBuild),
    Coupled(&'a CoupledBuild),
}

/// Quadratic tets: the elements and the linear mesh of their vertices, where points are
/// located before the quadratic shape functions are taken at their barycentric coordinates.
#[derive(Clone, Copy)]
pub(crate) struct QuadraticFe<'a> {
    pub tets: &'a Tet10Mesh,
    pub linear: &'a Mesh,
}

impl<'a> QuadraticFe<'a> {
    /// The view of a build's quadratic tets and their linear mesh, where it has them.
    pub fn of(q: &'a Option<(Tet10Mesh, Mesh)>) -> Option<Self> {
        q.as_ref()
            .map(|(tets, linear)| QuadraticFe { tets, linear })
    }
}

/// The body's boundary: vertex positions (m) and outward faces over them, each with the cell
/// it bounds (coupled: `Some(FE-layer cell)`, or `None` for the meshless interior).
pub(crate) struct Surface {
    pub vertices: Vec<Vector3<f64>>,
    pub faces: Vec<(Vec<usize>, Option<usize>)>,
}

impl<'a> Discretized<'a> {
    /// The model's nodes, m.
    pub fn nodes(&self) -> &'a [Vector3<f64>] {
        match self {
            Discretized::Fe(m, _) => &m.nodes,
            Discretized::Meshless(b) => &b.nodes,
            Discretized::Coupled(b) => &b.nodes,
        }
    }

    /// The row that gives the displacement at the reference point `x` (m) of the body:
    /// meshless and coupled only (FE nodes interpolate).
    fn row_at(
        &self,
        x: &Vector3<f64>,
        cell: Option<usize>,
        what: &dyn Fn() -> String,
    ) -> Result<SparseRow> {
        match self {
            Discretized::Fe(..) => Err(Error::input(
                InputKind::Value,
                format!("{}: FE faces take their nodes' values (internal)", what()),
            )),
            Discretized::Meshless(b) => b.shape_values(x, what),
            Discretized::Coupled(b) => b.shape_values_in(cell, x, what),
        }
    }

    /// The row that gives the displacement at the reference point `x` (m), its cell found by
    /// search (a probe's position), and the element whose shape functions make it (FE).
    /// `what` names the point in errors.
    pub fn point_row(
        &self,
        x: &Vector3<f64>,
        what: &dyn Fn() -> String,
    ) -> Result<(SparseRow, Option<usize>)> {
        match self {
            Discretized::Fe(m, q) => {
                let mesh = q.map_or(*m, |q| q.linear);
                let at = locate_among(x, mesh, 0..mesh.num_cells(), what)?;
                let row = match q {
                    // The element's quadratic shape functions at the barycentric coordinates.
                    Some(q) => {
                        let l = std::array::from_fn(|k| at.weights[k]);
                        q.tets
                            .weights(at.element, l)
                            .into_iter()
                            .map(|(i, w)| (i as u32, w))
                            .collect()
                    }
                    None => at.nodes.iter().map(|&i| i as u32).zip(at.weights).collect(),
                };
                Ok((row, Some(at.element)))
            }
            Discretized::Meshless(b) => Ok((b.shape_values(x, what)?, None)),
            Discretized::Coupled(b) => Ok((b.shape_values(x, what)?, None)),
        }
    }

    /// Adds to a selection of nodes (ascending or not) the nodes it implies: a quadratic
    /// mesh's edge nodes between the vertices it holds (named sets are of the vertices).
    pub fn extend_selection(&self, ids: &mut Vec<usize>) {
        match self {
            Discretized::Fe(_, Some(q)) => q.tets.extend_selection(ids),
            Discretized::Coupled(b) => {
                if let Some(q) = &b.quadratic {
                    q.extend_selection(ids);
                }
            }
            _ => {}
        }
    }

    /// The row that gives the displacement at node `i`'s position.
    pub fn node_row(&self, i: usize) -> Result<SparseRow> {
        match self {
            Discretized::Fe(..) => Ok(vec![(i as u32, 1.0)]),
            Discretized::Meshless(b) => self.row_at(&b.nodes[i], None, &|| format!("node {i}")),
            Discretized::Coupled(b) => b.vertex_weights_of(i, &|| format!("node {i}")),
        }
    }

    /// The row that gives the displacement at vertex `i` of `surface`.
    pub fn vertex_row(&self, surface: &Surface, i: usize) -> Result<SparseRow> {
        match self {
            // FE and coupled surfaces are over the model's nodes.
            Discretized::Fe(..) | Discretized::Coupled(_) => self.node_row(i),
            Discretized::Meshless(_) => self.row_at(&surface.vertices[i], None, &|| {
                format!("boundary vertex {i}")
            }),
        }
    }

    /// The model nodes on the body's surface, ascending (meshless: the field nodes at the
    /// background tets' boundary vertices).
    pub fn surface_nodes(&self) -> Result<Vec<usize>> {
        let s = self.surface()?;
        let mut on = vec![false; s.vertices.len()];
        for (f, _) in &s.faces {
            for &i in f {
                on[i] = true;
            }
        }
        Ok(match self {
            Discretized::Meshless(b) => {
                let mut v: Vec<usize> = (0..on.len())
                    .filter(|&i| on[i])
                    .filter_map(|i| b.background_node[i])
                    .collect();
                v.sort_unstable();
                v
            }
            _ => (0..on.len()).filter(|&i| on[i]).collect(),
        })
    }

    /// The outward boundary faces: of the FE mesh; of the meshless background tets (their
    /// vertices, which include nodes removed as poorly supported); of the coupled FE layer and
    /// interior less the faces they share.
    pub fn surface(&self) -> Result<Surface> {
        let faces = |m: &Mesh, what: &str| {
            quality::boundary_faces_with_cells(m)
                .map_err(|e| Error::input(InputKind::Value, format!("{what}: {e}")))
        };
        match self {
            Discretized::Fe(m, _) => Ok(Surface {
                vertices: m.nodes.clone(),
                faces: faces(m, "mesh")?
                    .into_iter()
                    .map(|(f, e)| (f, Some(e)))
                    .collect(),
            }),
            Discretized::Meshless(b) => {
                if b.background.num_cells() == 0 {
                    return Err(Error::input(
                        InputKind::Unsupported,
                        "surface loads and contact on a meshless body need its boundary \
                         triangles: use integration = 'tets' (or a cloud with background tets)",
                    ));
                }
                Ok(Surface {
                    vertices: b.background.nodes.clone(),
                    faces: faces(&b.background, "meshless background tets")?
                        .into_iter()
                        .map(|(f, _)| (f, None))
                        .collect(),
                })
            }
            Discretized::Coupled(b) => {
                let mut all: Vec<(Vec<usize>, Option<usize>)> =
                    faces(&b.fe_mesh, "coupled FE layer")?
                        .into_iter()
                        .map(|(f, e)| (f, Some(e)))
                        .collect();
                all.extend(
                    faces(&b.interior, "coupled interior")?
                        .into_iter()
                        .map(|(f, _)| (f, None)),
                );
                // Faces on both sides of the FE layer's inner surface are inside the body.
                let key = |f: &[usize]| {
                    let mut k = f.to_vec();
                    k.sort_unstable();
                    k
                };
                let mut seen: std::collections::BTreeMap<Vec<usize>, usize> = Default::default();
                for (f, _) in &all {
                    *seen.entry(key(f)).or_default() += 1;
                }
                all.retain(|(f, _)| seen[&key(f)] == 1);
                Ok(Surface {
                    vertices: b.nodes.clone(),
                    faces: all,
                })
            }
        }
    }

    /// Face `k` of `surface`, with its interpolation rows.
    pub fn face(&self, surface: &Surface, k: usize) -> Result<Face> {
        let (ids, cell) = &surface.faces[k];
        match self {
            Discretized::Fe(m, _) => Face::interpolating(ids, &m.nodes),
            _ => {
                let x: Vec<Vector3<f64>> = ids.iter().map(|&i| surface.vertices[i]).collect();
                Face::with_shape(&x, &|p| {
                    self.row_at(p, *cell, &|| format!("boundary face {k}"))
                })
            }
        }
    }
}
