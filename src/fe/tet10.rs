//! Quadratic 10-node tetrahedron for TLED: a linear tet mesh gains one node at the middle of
//! each edge (straight edges), each element is integrated at the four points of the
//! degree-2 rule with mean dilatation over them (one constant volume change per element:
//! the P2/P0 mixed element, which does not lock at nu = 0.49; Nagtegaal et al. 1974), and
//! masses are lumped by HRZ diagonal scaling (Hinton, Rock & Zienkiewicz 1976): 1/36 of the
//! element's mass at each corner, 4/27 at each edge node.
//!
//! Node order within an element is VTK's quadratic tetra (type 24): corners 0-3, then the
//! edges (0,1), (1,2), (0,2), (0,3), (1,3), (2,3).

use std::collections::HashMap;

use nalgebra::{Matrix3, Vector3};

use crate::geometry::{ElementShape, Mesh};
use crate::quadrature::{GroupPoint, QuadraturePoints};
use crate::{Error, InputKind, Result};

/// Corner pairs of the six edge nodes 4..9, in VTK's order.
pub const EDGES: [(usize, usize); 6] = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)];

/// HRZ lumped-mass shares of a straight-sided element's mass: each corner, each edge node.
/// Consistent-mass diagonal 1/70 and 8/105 of m, scaled to sum to m.
pub const MASS_SHARES: (f64, f64) = (1.0 / 36.0, 4.0 / 27.0);

/// Barycentric coordinates of the four points of the degree-2 rule (weights V / 4 each).
const RULE: (f64, f64) = (0.585_410_196_624_968_5, 0.138_196_601_125_010_5);

/// A quadratic tetrahedral mesh made from a linear one.
#[derive(Debug, Clone)]
pub struct Tet10Mesh {
    /// Nodes, m: the linear mesh's vertices first (same ids), then the edge nodes.
    pub nodes: Vec<Vector3<f64>>,
    /// Ten node ids per element (VTK order).
    pub cells: Vec<[usize; 10]>,
    /// Number of vertices (the first nodes).
    pub vertices: usize,
    /// For edge node `vertices + k`, its two end vertices (smaller id first).
    pub edges: Vec<[usize; 2]>,
}

impl Tet10Mesh {
    /// Adds a node at the middle of every edge of the linear tet mesh `mesh`, numbered in
    /// the order the elements first reach the edges (so the numbering follows the mesh's).
    pub fn from_tet4(mesh: &Mesh) -> Result<Self> {
        if mesh.shape != ElementShape::Tet4 {
            return Err(Error::input(
                InputKind::Mesh,
                format!(
                "element 'tet10' is built from a tetrahedral mesh, but the mesh holds {:?} cells; \
                 use a tet mesh (mesher = \"tetgen\", or a tet mesh file)",
                mesh.shape
            ),
            ));
        }
        let vertices = mesh.nodes.len();
        let mut nodes = mesh.nodes.clone();
        let mut edges: Vec<[usize; 2]> = Vec::new();
        let mut index: HashMap<[usize; 2], usize> = HashMap::with_capacity(7 * vertices);
        let mut cells = Vec::with_capacity(mesh.num_cells());
        for e in 0..mesh.num_cells() {
            let c = mesh.cell(e);
            let mut ids = [0usize; 10];
            ids[..4].copy_from_slice(c);
            for (k, &(a, b)) in EDGES.iter().enumerate() {
                let key = [c[a].min(c[b]), c[a].max(c[b])];
                ids[4 + k] = *index.entry(key).or_insert_with(|| {
                    nodes.push(0.5 * (mesh.nodes[key[0]] + mesh.nodes[key[1]]));
                    edges.push(key);
                    nodes.len() - 1
                });
            }
            cells.push(ids);
        }
        Ok(Tet10Mesh {
            nodes,
            cells,
            vertices,
            edges,
        })
    }

    /// Number of elements.
    pub fn num_cells(&self) -> usize {
        self.cells.len()
    }

    /// The four quadrature points of element `e`: node ids, dphi/dX (1/m) and weights (m^3).
    /// `Err(volume)` where the element's Jacobian is not positive at a point or a corner
    /// (an inverted or degenerate element; volume in m^3).
    pub fn element_points(&self, e: usize) -> std::result::Result<[GroupPoint; 4], f64> {
        let ids = self.cells[e];
        let x: [Vector3<f64>; 10] = std::array::from_fn(|a| self.nodes[ids[a]]);
        cell_points(&x, &ids)
    }

    /// Quadrature points of every element, each element a mean-dilatation group.
    pub fn points(&self) -> Result<QuadraturePoints> {
        let mut qp = QuadraturePoints::with_capacity(4 * self.num_cells(), 40 * self.num_cells());
        for e in 0..self.num_cells() {
            let pts = self
                .element_points(e)
                .map_err(|volume| Error::InvalidElement { element: e, volume })?;
            qp.push_group(&pts);
        }
        Ok(qp)
    }

    /// HRZ lumped masses, kg, with `density(e)` (kg/m^3) of element `e` and the element
    /// volumes from its points (`qp` as [`Self::points`] made it: four per element).
    pub fn lumped_masses(&self, qp: &QuadraturePoints, density: &dyn Fn(usize) -> f64) -> Vec<f64> {
        let mut mass = vec![0.0; self.nodes.len()];
        let (corner, edge) = MASS_SHARES;
        for (e, ids) in self.cells.iter().enumerate() {
            let m = density(e) * qp.weights[4 * e..4 * e + 4].iter().sum::<f64>();
            for &i in &ids[..4] {
                mass[i] += corner * m;
            }
            for &i in &ids[4..] {
                mass[i] += edge * m;
            }
        }
        mass
    }

    /// The linear tets of the eight-way split of each element (its four corner tets and its
    /// inner octahedron cut along the diagonal 4-9), over the same nodes: the geometry that
    /// surfaces, contact, selections and probes work on. Element `e` gives cells 8e..8e+7.
    pub fn split(&self) -> Mesh {
        // Corner tets keep the parent's orientation; the octahedron's four tets around the
        // diagonal (0,1)-(2,3) likewise (checked by the tests).
        const SUB: [[usize; 4]; 8] = [
            [0, 4, 6, 7],
            [4, 1, 5, 8],
            [6, 5, 2, 9],
            [7, 8, 9, 3],
            [4, 9, 5, 6],
            [4, 9, 6, 7],
            [4, 9, 7, 8],
            [4, 9, 8, 5],
        ];
        let mut cells = Vec::with_capacity(32 * self.num_cells());
        for ids in &self.cells {
            for s in SUB {
                cells.extend(s.iter().map(|&k| ids[k]));
            }
        }
        Mesh {
            nodes: self.nodes.clone(),
            shape: ElementShape::Tet4,
            cells,
        }
    }

    /// Adds to the sorted node list `ids` the edge nodes whose two end vertices it holds (a
    /// named set of the linear mesh, or a selection made on its vertices, then covers the
    /// quadratic element's nodes on the same faces and volumes), sorted and without repeats.
    pub fn extend_selection(&self, ids: &mut Vec<usize>) {
        let mut on = vec![false; self.nodes.len()];
        for &i in ids.iter() {
            on[i] = true;
        }
        for (k, &[a, b]) in self.edges.iter().enumerate() {
            if on[a] && on[b] {
                on[self.vertices + k] = true;
            }
        }
        *ids = (0..self.nodes.len()).filter(|&i| on[i]).collect();
    }

    /// Quadratic shape-function values at the barycentric coordinates `l` of element `e`:
    /// (node id, phi) pairs.
    pub fn weights(&self, e: usize, l: [f64; 4]) -> Vec<(usize, f64)> {
        let n = shape(l);
        self.cells[e].iter().copied().zip(n).collect()
    }
}

/// The four quadrature points of the element with nodes `x` (m) and ids `ids`: node ids,
/// dphi/dX (1/m) and weights (m^3); `Err(volume)` where the Jacobian is not positive at a
/// point or a corner.
pub fn cell_points(
    x: &[Vector3<f64>; 10],
    ids: &[usize; 10],
) -> std::result::Result<[GroupPoint; 4], f64> {
    let (a, b) = RULE;
    let mut volume = 0.0;
    let mut pts: Vec<GroupPoint> = Vec::with_capacity(4);
    let mut bad = false;
    for q in 0..4 {
        let mut l = [b; 4];
        l[q] = a;
        match derivatives(x, l) {
            Some((d, det)) => {
                let w = det / 24.0;
                volume += w;
                pts.push((ids.to_vec(), d.to_vec(), w));
            }
            None => bad = true,
        }
    }
    // Positive at the corners as well: a curved element can fold between its points.
    let scale = (x[1] - x[0])
        .norm()
        .max((x[2] - x[0]).norm())
        .max((x[3] - x[0]).norm());
    for q in 0..4 {
        let mut l = [0.0; 4];
        l[q] = 1.0;
        bad |= derivatives(x, l).is_none_or(|(_, det)| !(det > 6e-12 * scale.powi(3)));
    }
    if bad || !(volume > 1e-12 * scale.powi(3)) {
        return Err(volume);
    }
    Ok(pts
        .try_into()
        .unwrap_or_else(|_| unreachable!("four points")))
}

/// Quadratic shape functions at barycentric coordinates `l`: corners L_a (2 L_a - 1), edges
/// 4 L_a L_b.
pub fn shape(l: [f64; 4]) -> [f64; 10] {
    let mut n = [0.0; 10];
    for a in 0..4 {
        n[a] = l[a] * (2.0 * l[a] - 1.0);
    }
    for (k, &(a, b)) in EDGES.iter().enumerate() {
        n[4 + k] = 4.0 * l[a] * l[b];
    }
    n
}

/// dN/dX (1/m) of the ten shape functions at barycentric coordinates `l` of the element with
/// nodes `x`, and the Jacobian determinant det(dX/dxi) (6 x the volume for a straight one);
/// None where it is not positive.
pub fn derivatives(x: &[Vector3<f64>; 10], l: [f64; 4]) -> Option<([Vector3<f64>; 10], f64)> {
    // dN/dL_c, then with xi = (L1, L2, L3) and L0 = 1 - xi: dN/dxi_k = dN/dL_k+1 - dN/dL_0.
    let mut dl = [[0.0; 4]; 10];
    for a in 0..4 {
        dl[a][a] = 4.0 * l[a] - 1.0;
    }
    for (k, &(a, b)) in EDGES.iter().enumerate() {
        dl[4 + k][a] = 4.0 * l[b];
        dl[4 + k][b] = 4.0 * l[a];
    }
    let dxi: [Vector3<f64>; 10] = std::array::from_fn(|i| {
        Vector3::new(
            dl[i][1] - dl[i][0],
            dl[i][2] - dl[i][0],
            dl[i][3] - dl[i][0],
        )
    });
    let mut jac = Matrix3::zeros();
    for i in 0..10 {
        jac += x[i] * dxi[i].transpose();
    }
    let det = jac.determinant();
    if !(det > 0.0) {
        return None;
    }
    let jinv_t = jac.try_inverse()?.transpose();
    Some((std::array::from_fn(|i| jinv_t * dxi[i]), det))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_tet() -> Mesh {
        Mesh {
            nodes: vec![
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(0.02, 0.001, 0.0),
                Vector3::new(0.003, 0.015, 0.002),
                Vector3::new(0.004, 0.002, 0.018),
            ],
            shape: ElementShape::Tet4,
            cells: vec![0, 1, 2, 3],
        }
    }

    /// Volume of linear tet `e` of `mesh`, m^3; panics where it is not positive.
    fn volume(mesh: &Mesh, e: usize) -> f64 {
        let c = mesh.cell(e);
        let x: [Vector3<f64>; 4] = std::array::from_fn(|a| mesh.nodes[c[a]]);
        crate::fe::tet4::derivatives(&x).expect("a positive tet").1
    }

    #[test]
    fn shape_functions_reproduce_quadratic_fields() {
        let m = Tet10Mesh::from_tet4(&one_tet()).unwrap();
        let x: [Vector3<f64>; 10] = std::array::from_fn(|a| m.nodes[m.cells[0][a]]);
        // f = 3 + x - 2 y + 5 z + 7 x y - 4 z^2 + 2 x z and its gradient.
        let f = |p: &Vector3<f64>| {
            3.0 + p.x - 2.0 * p.y + 5.0 * p.z + 7.0 * p.x * p.y - 4.0 * p.z * p.z + 2.0 * p.x * p.z
        };
        let g = |p: &Vector3<f64>| {
            Vector3::new(
                1.0 + 7.0 * p.y + 2.0 * p.z,
                -2.0 + 7.0 * p.x,
                5.0 - 8.0 * p.z + 2.0 * p.x,
            )
        };
        for l in [
            [0.1, 0.2, 0.3, 0.4],
            [0.585, 0.138, 0.139, 0.138],
            [0.25; 4],
        ] {
            let n = shape(l);
            let (d, det) = derivatives(&x, l).unwrap();
            let p: Vector3<f64> = (0..4).map(|a| x[a] * l[a]).sum();
            let val: f64 = (0..10).map(|i| n[i] * f(&x[i])).sum();
            let grad: Vector3<f64> = (0..10).map(|i| d[i] * f(&x[i])).sum();
            assert!((n.iter().sum::<f64>() - 1.0).abs() < 1e-14);
            assert!((val - f(&p)).abs() < 1e-13, "{val} {}", f(&p));
            assert!(
                (grad - g(&p)).norm() < 1e-10 * g(&p).norm(),
                "{grad} {}",
                g(&p)
            );
            let v0 = (x[1] - x[0]).dot(&(x[2] - x[0]).cross(&(x[3] - x[0])));
            assert!((det - v0).abs() < 1e-14 * v0);
        }
    }

    #[test]
    fn points_integrate_the_volume_and_masses_sum_to_it() {
        let mesh = one_tet();
        let m = Tet10Mesh::from_tet4(&mesh).unwrap();
        let qp = m.points().unwrap();
        let v = volume(&mesh, 0);
        assert_eq!(qp.len(), 4);
        assert_eq!(qp.groups, vec![[0, 4]]);
        assert!((qp.total_weight() - v).abs() < 1e-14 * v);
        let mass = m.lumped_masses(&qp, &|_| 1000.0);
        assert!((mass.iter().sum::<f64>() - 1000.0 * v).abs() < 1e-12 * 1000.0 * v);
        // HRZ: the diagonal of the consistent mass, integral of N_i^2 (1/70 and 8/105 of the
        // volume for a straight element), scaled to the total.
        let total = 4.0 / 70.0 + 6.0 * 8.0 / 105.0;
        assert!((MASS_SHARES.0 - 1.0 / 70.0 / total).abs() < 1e-15);
        assert!((MASS_SHARES.1 - 8.0 / 105.0 / total).abs() < 1e-15);
    }

    #[test]
    fn split_covers_the_element_with_positive_tets() {
        let mesh = one_tet();
        let m = Tet10Mesh::from_tet4(&mesh).unwrap();
        let s = m.split();
        // Each sub-tet positive (volume() refuses others), together the element.
        let v: f64 = (0..8).map(|e| volume(&s, e)).sum();
        let v0 = volume(&mesh, 0);
        assert!((v - v0).abs() < 1e-14 * v0);
    }

    #[test]
    fn shared_edges_get_one_node_and_selections_take_their_edges() {
        let mut mesh = one_tet();
        mesh.nodes.push(Vector3::new(0.01, 0.01, -0.02));
        mesh.cells.extend([0, 2, 1, 4]);
        let m = Tet10Mesh::from_tet4(&mesh).unwrap();
        // 5 vertices, 6 + 6 - 3 shared edges.
        assert_eq!(m.nodes.len(), 5 + 9);
        let mut ids = vec![0, 1, 2];
        m.extend_selection(&mut ids);
        assert_eq!(ids.len(), 6);
        for &i in &ids[3..] {
            let [a, b] = m.edges[i - m.vertices];
            assert!(a <= 2 && b <= 2);
            assert!((m.nodes[i] - 0.5 * (m.nodes[a] + m.nodes[b])).norm() < 1e-18);
        }
    }
}
