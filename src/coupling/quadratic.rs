//! The quadratic FE layer of the coupled method (`element = "tet10"`): the FE-layer tets gain
//! a node on each edge that has an FE node at one end at least, and are integrated as
//! [`crate::fe::tet10`] elements (four points, mean dilatation, HRZ masses). An edge between
//! two MLS nodes (interface nodes) gets no node: its quadratic shape function is folded half
//! onto each end, so the element is linear along that edge. With the linear ramp
//! R = sum of the barycentric coordinates of the cell's interface vertices, the blended
//! functions phi_I = (1 - R) N_I + R phi_I^MLS are then conforming on every face: R = 0 on a
//! face without interface vertices (shared with a pure quadratic element), R = 1 on a face
//! whose vertices are all interface nodes (shared with a meshless cell), where the edge nodes
//! are absent, and two transition cells sharing a face fold the same edges. Both families
//! reproduce linear fields, so the blend passes the patch test.

use std::collections::HashMap;

use nalgebra::Vector3;

use super::NodeRole;
use crate::fe::{tet10, tet4};
use crate::geometry::Mesh;

/// The edge nodes of a quadratic FE layer.
#[derive(Debug, Clone)]
pub struct Quadratic {
    /// Per FE-layer cell: its ten nodes in VTK order ([`tet10::EDGES`]), None for an edge
    /// between two MLS nodes (no node there: its shape function is folded onto the ends).
    pub cells: Vec<[Option<usize>; 10]>,
    /// The edge nodes.
    pub edges: Vec<EdgeNode>,
}

/// An edge node of a quadratic FE layer and the two vertices its edge joins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EdgeNode {
    pub node: usize,
    pub ends: [usize; 2],
}

impl Quadratic {
    /// Adds the edge nodes of the FE-layer tets `fe_mesh` to `nodes` (m, at the edges'
    /// middles) and `roles` (FE nodes), numbered in the order the cells reach them.
    pub fn add_edge_nodes(
        nodes: &mut Vec<Vector3<f64>>,
        roles: &mut Vec<NodeRole>,
        fe_mesh: &Mesh,
    ) -> Self {
        let mut index: HashMap<[usize; 2], usize> = HashMap::new();
        let mut edges = Vec::new();
        let mut cells = Vec::with_capacity(fe_mesh.num_cells());
        for e in 0..fe_mesh.num_cells() {
            let c = fe_mesh.cell(e);
            let mut ids = [None; 10];
            for (id, &v) in ids.iter_mut().zip(c) {
                *id = Some(v);
            }
            for (k, &(a, b)) in tet10::EDGES.iter().enumerate() {
                let key = [c[a].min(c[b]), c[a].max(c[b])];
                if roles[key[0]] != NodeRole::Fe && roles[key[1]] != NodeRole::Fe {
                    continue;
                }
                ids[4 + k] = Some(*index.entry(key).or_insert_with(|| {
                    nodes.push(0.5 * (nodes[key[0]] + nodes[key[1]]));
                    roles.push(NodeRole::Fe);
                    edges.push(EdgeNode {
                        node: nodes.len() - 1,
                        ends: key,
                    });
                    nodes.len() - 1
                }));
            }
            cells.push(ids);
        }
        Quadratic { cells, edges }
    }

    /// The ten nodes of cell `e` when none of its edges is folded.
    pub fn full_cell(&self, e: usize) -> Option<[usize; 10]> {
        let c = self.cells.get(e)?;
        let mut ids = [0; 10];
        for (id, n) in ids.iter_mut().zip(c) {
            *id = (*n)?;
        }
        Some(ids)
    }

    /// Adds to the sorted node list `ids` the edge nodes whose two end vertices it holds
    /// (sorted, without repeats).
    pub fn extend_selection(&self, ids: &mut Vec<usize>) {
        let set: std::collections::HashSet<usize> = ids.iter().copied().collect();
        ids.extend(
            self.edges
                .iter()
                .filter(|e| set.contains(&e.ends[0]) && set.contains(&e.ends[1]))
                .map(|e| e.node),
        );
        ids.sort_unstable();
        ids.dedup();
    }

    /// Shape-function values of cell `e` at barycentric coordinates `l`, folded edges
    /// included in their ends: (node id, N) for the cell's nodes.
    pub fn values(&self, e: usize, l: [f64; 4]) -> Vec<(usize, f64)> {
        let mut n = tet10::shape(l);
        let ids = self.cells[e];
        fold(&ids, &mut n, |acc, v| *acc += v);
        ids.iter()
            .zip(n)
            .filter_map(|(&i, v)| Some((i?, v)))
            .collect()
    }

    /// At barycentric coordinates `l` of cell `e` (its nodes in `nodes`, m): the cell's node
    /// ids, shape functions N, dN/dX (1/m), the position (m) and the Jacobian determinant
    /// (6 x the volume of the straight element); `Err(det)` where it is not positive.
    pub fn point(
        &self,
        e: usize,
        nodes: &[Vector3<f64>],
        l: [f64; 4],
    ) -> std::result::Result<QuadraticPoint, f64> {
        let ids = self.cells[e];
        let vertex = |a: usize| nodes[ids[a].unwrap_or_default()];
        // A folded edge's node sits at its middle (straight edges).
        let x: [Vector3<f64>; 10] = std::array::from_fn(|a| match ids[a] {
            Some(i) => nodes[i],
            None => {
                let (p, q) = tet10::EDGES[a - 4];
                0.5 * (vertex(p) + vertex(q))
            }
        });
        let x4 = [x[0], x[1], x[2], x[3]];
        let det = 6.0 * tet4::derivatives(&x4).map_err(|v| 6.0 * v)?.1;
        let (mut d, _) = tet10::derivatives(&x, l).ok_or(det)?;
        let mut n = tet10::shape(l);
        fold(&ids, &mut n, |acc, v| *acc += v);
        fold(&ids, &mut d, |acc, v| *acc += v);
        let pos = (0..4).fold(Vector3::zeros(), |a, k| a + x[k] * l[k]);
        let keep: Vec<usize> = (0..10).filter(|&a| ids[a].is_some()).collect();
        Ok(QuadraticPoint {
            ids: keep.iter().filter_map(|&a| ids[a]).collect(),
            n: keep.iter().map(|&a| n[a]).collect(),
            dn: keep.iter().map(|&a| d[a]).collect(),
            position: pos,
            det,
        })
    }
}

/// A point of a quadratic FE-layer cell ([`Quadratic::point`]).
pub struct QuadraticPoint {
    pub ids: Vec<usize>,
    pub n: Vec<f64>,
    pub dn: Vec<Vector3<f64>>,
    pub position: Vector3<f64>,
    pub det: f64,
}

/// Adds half of each folded edge's value in `v` to each of its two corners.
fn fold<T: Copy + std::ops::Mul<f64, Output = T>>(
    ids: &[Option<usize>; 10],
    v: &mut [T; 10],
    add: impl Fn(&mut T, T),
) {
    for (k, &(a, b)) in tet10::EDGES.iter().enumerate() {
        if ids[4 + k].is_none() {
            let half = v[4 + k] * 0.5;
            add(&mut v[a], half);
            add(&mut v[b], half);
        }
    }
}
