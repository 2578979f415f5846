//! Essential boundary conditions imposed directly on nodes (Kronecker-delta shape functions),
//! and the load curves that drive them.

pub mod contact;
pub mod curve;
pub mod ebciem;
pub mod loads;
pub mod sparse_lu;

pub use curve::{CurveTable, LoadCurve};

use crate::{Error, InputKind, Result};

/// One named boundary: its nodes and, per component, the final prescribed displacement (m)
/// or `None` where the component is free.
#[derive(Debug, Clone)]
pub struct Boundary {
    pub name: String,
    pub nodes: Vec<usize>,
    pub components: [Option<f64>; 3],
    /// Final displacements node by node (m, one per entry of `nodes`: measured displacements),
    /// taking the place of `components`' values on the prescribed components.
    pub node_values: Option<Vec<[f64; 3]>>,
    pub curve: LoadCurve,
    /// Measured displacements (`[measured]`): how `node_values` come from the measured
    /// points' displacements, so that new measurements at the same points can replace them
    /// ([`Self::set_measured`]). None for other boundaries.
    pub measured: Option<std::sync::Arc<MeasuredMap>>,
}

/// How the node values of a measured boundary follow from the displacements measured at its
/// points: node k's value is the sum of w u_j over its row's (j, w) (one (j, 1) for points
/// matched to nodes, the moving least-squares fit's weights for interpolated ones).
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredMap {
    /// The measured points' positions, m, in the file's order.
    pub points: Vec<[f64; 3]>,
    /// Per node of the boundary: (measured point, weight) pairs.
    pub rows: Vec<Vec<(u32, f64)>>,
    /// The displacements in force at the points, m (the file's, or the last
    /// [`Boundary::set_measured`]'s).
    pub values: Vec<[f64; 3]>,
}

impl MeasuredMap {
    /// The node values (m) for displacements `u` (m) measured at [`Self::points`].
    pub fn node_values(&self, u: &[[f64; 3]]) -> Vec<[f64; 3]> {
        self.rows
            .iter()
            .map(|row| {
                let mut v = [0.0; 3];
                for &(j, w) in row {
                    for (c, vc) in v.iter_mut().enumerate() {
                        *vc += w * u[j as usize][c];
                    }
                }
                v
            })
            .collect()
    }
}

impl Boundary {
    /// A boundary prescribing `components` uniformly on `nodes`.
    pub fn uniform(
        name: &str,
        nodes: Vec<usize>,
        components: [Option<f64>; 3],
        curve: LoadCurve,
    ) -> Self {
        Boundary {
            name: name.into(),
            nodes,
            components,
            node_values: None,
            curve,
            measured: None,
        }
    }

    /// New measured displacements (m), one [x, y, z] per measured point in the order of the
    /// file the boundary was read from ([`MeasuredMap::points`]): its node values follow
    /// (matched or interpolated as prepared). An error for a boundary that is not measured or
    /// a count that does not match.
    pub fn set_measured(&mut self, u: &[[f64; 3]]) -> Result<()> {
        let map = self.measured.as_ref().ok_or_else(|| {
            Error::input(
                InputKind::Value,
                format!(
                    "boundary '{}' is not a [measured] boundary; set its displacement instead",
                    self.name
                ),
            )
            .key(format!("boundaries.{}", self.name))
        })?;
        if u.len() != map.points.len() {
            return Err(Error::input(
                InputKind::Value,
                format!(
                "measured '{}': {} displacements for its {} measured points; give one [ux, uy, uz] \
                 per point, in the order of its file",
                self.name,
                u.len(),
                map.points.len()
            ),
            )
            .key(format!("measured.{}", self.name)));
        }
        if let Some(j) = u.iter().position(|x| !x.iter().all(|c| c.is_finite())) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "measured '{}': the displacement of point {j} is not finite",
                    self.name
                ),
            ));
        }
        self.node_values = Some(map.node_values(u));
        if let Some(m) = self.measured.as_mut() {
            std::sync::Arc::make_mut(m).values = u.to_vec();
        }
        Ok(())
    }

    /// How messages name it: "boundary 'NAME'", or "measured set 'NAME'" for `[measured]`.
    pub fn label(&self) -> String {
        if self.measured.is_some() {
            format!("measured set '{}' ([measured.{}])", self.name, self.name)
        } else {
            format!("boundary '{}'", self.name)
        }
    }

    /// Final prescribed value (m) of component `c` at the boundary's `k`-th node; None where
    /// the component is free.
    #[inline]
    pub fn value(&self, k: usize, c: usize) -> Option<f64> {
        let v = self.components[c]?;
        Some(match &self.node_values {
            Some(vals) => vals.get(k).map_or(v, |x| x[c]),
            None => v,
        })
    }

    /// Some component is prescribed (the boundary holds the body).
    pub fn is_essential(&self) -> bool {
        self.components.iter().any(|c| c.is_some())
    }
}

/// All constrained degrees of freedom, flattened for the time loop.
#[derive(Debug, Clone, Default)]
pub struct Constraints {
    /// (node, component) of each constrained DOF.
    pub dofs: Vec<(u32, u8)>,
    /// Final prescribed value of each DOF, m.
    pub amplitude: Vec<f64>,
    pub curve: Vec<LoadCurve>,
    /// Per node and component: constrained or free.
    pub mask: Vec<[bool; 3]>,
}

/// Two prescribed values closer than this (m, far below any length a model resolves) are the
/// same value: an interpolated measurement's 0 can come out as -1.7e-18 m beside a symmetry
/// plane's 0.
const SAME_VALUE: f64 = 1e-15;

impl Constraints {
    /// Merges the boundaries' conditions. A DOF named by two boundaries must get the same value
    /// and curve from both; otherwise the conflict is an error naming the node and both boundaries.
    pub fn new(boundaries: &[Boundary], num_nodes: usize) -> Result<Self> {
        let mut owner: Vec<[Option<(usize, f64)>; 3]> = vec![[None; 3]; num_nodes];
        let mut c = Constraints {
            mask: vec![[false; 3]; num_nodes],
            ..Default::default()
        };
        for (bi, b) in boundaries.iter().enumerate() {
            for (at, &n) in b.nodes.iter().enumerate() {
                for k in 0..3 {
                    let Some(v) = b.value(at, k) else { continue };
                    match owner[n][k] {
                        Some((other, v0)) => {
                            let zero = v.abs() <= SAME_VALUE && v0.abs() <= SAME_VALUE;
                            let same_curve = boundaries[other].curve == b.curve || zero;
                            if (v - v0).abs() > SAME_VALUE || !same_curve {
                                return Err(Error::input(InputKind::Value, format!(
                                    "node {n} component {} is prescribed by {} ({v0} m) and by {} ({v} m); \
                                     make the selections disjoint or give both the same value and curve",
                                    ["x", "y", "z"][k],
                                    boundaries[other].label(),
                                    b.label()
                                )));
                            }
                        }
                        None => {
                            owner[n][k] = Some((bi, v));
                            c.dofs.push((n as u32, k as u8));
                            c.amplitude.push(v);
                            c.curve.push(b.curve.clone());
                            c.mask[n][k] = true;
                        }
                    }
                }
            }
        }
        Ok(c)
    }

    /// Writes each constrained component's prescribed value at load fraction `tau` into
    /// `target` (m); free components are left as they are.
    pub fn prescribe(&self, target: &mut [nalgebra::Vector3<f64>], tau: f64) {
        for (k, &(node, comp)) in self.dofs.iter().enumerate() {
            target[node as usize][comp as usize] = self.amplitude[k] * self.curve[k].value(tau);
        }
    }

    /// Number of constrained DOFs.
    pub fn len(&self) -> usize {
        self.dofs.len()
    }

    /// True when nothing is constrained.
    pub fn is_empty(&self) -> bool {
        self.dofs.is_empty()
    }
}

/// Parts of the body that no essential boundary holds: the nodes are joined when a quadrature
/// point couples them (elements, MLS supports, blended points alike), and a part with no node in
/// a boundary that prescribes a component can move as a rigid body (in relaxation it never
/// settles if anything pushes it). Returns (nodes in the part, its lowest node) per such part,
/// largest first; empty when every part is held or no boundary prescribes anything (a free
/// body, as in a dynamic spin, is then the whole model and not reported).
pub fn free_parts(
    num_nodes: usize,
    points: &crate::quadrature::QuadraturePoints,
    boundaries: &[Boundary],
) -> Vec<(usize, usize)> {
    let held: Vec<&Boundary> = boundaries
        .iter()
        .filter(|b| b.components.iter().any(|c| c.is_some()))
        .collect();
    if held.is_empty() || num_nodes == 0 {
        return Vec::new();
    }
    let mut parent: Vec<u32> = (0..num_nodes as u32).collect();
    fn find(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let g = parent[parent[i as usize] as usize];
            parent[i as usize] = g;
            i = g;
        }
        i
    }
    for p in 0..points.len() {
        let ids = &points.nodes[points.slots(p)];
        if let Some((&first, rest)) = ids.split_first() {
            let a = find(&mut parent, first);
            for &j in rest {
                let b = find(&mut parent, j);
                if a != b {
                    parent[b as usize] = a;
                }
            }
        }
    }
    let mut is_held = vec![false; num_nodes];
    for b in &held {
        for &n in &b.nodes {
            if n < num_nodes {
                let r = find(&mut parent, n as u32) as usize;
                is_held[r] = true;
            }
        }
    }
    // Per root: node count and lowest node; nodes no point uses are not a part.
    let mut used = vec![false; num_nodes];
    for &j in &points.nodes {
        used[j as usize] = true;
    }
    let mut parts: std::collections::BTreeMap<u32, (usize, usize)> = Default::default();
    for (i, _) in used.iter().enumerate().filter(|(_, &u)| u) {
        let r = find(&mut parent, i as u32);
        if !is_held[r as usize] {
            let e = parts.entry(r).or_insert((0, i));
            e.0 += 1;
        }
    }
    let mut v: Vec<(usize, usize)> = parts.into_values().collect();
    v.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conflicting_values_are_an_error_naming_both_boundaries() {
        let b = |name: &str, v: f64| {
            Boundary::uniform(name, vec![0, 1], [None, None, Some(v)], LoadCurve::Smooth)
        };
        let err = Constraints::new(&[b("top", -0.02), b("lid", 0.01)], 2)
            .unwrap_err()
            .to_string();
        assert!(err.contains("'top'") && err.contains("'lid'"), "{err}");
        assert_eq!(
            Constraints::new(&[b("a", 0.0), b("b", 0.0)], 2)
                .unwrap()
                .len(),
            2
        );
    }

    /// Two separate blocks, a boundary on one: the other is reported as free; with a boundary on
    /// each, or none at all, nothing is.
    #[test]
    fn a_part_no_boundary_holds_is_found() {
        use crate::fe::{element_points, ElementKind};
        use crate::geometry::shapes::box_hex;
        use nalgebra::Vector3;
        let a = box_hex(Vector3::zeros(), Vector3::repeat(0.1), [2, 2, 2]).unwrap();
        let b = box_hex(
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(1.1, 0.1, 0.1),
            [1, 1, 1],
        )
        .unwrap();
        let na = a.nodes.len();
        let mut mesh = a.clone();
        mesh.nodes.extend(b.nodes.iter().cloned());
        mesh.cells.extend(b.cells.iter().map(|&i| i + na));
        let qp = element_points(&mesh, ElementKind::Hex8, 0.05, 1e5).unwrap();
        let fix = |nodes: Vec<usize>| {
            Boundary::uniform("fix", nodes, [Some(0.0); 3], LoadCurve::default())
        };
        let parts = free_parts(mesh.nodes.len(), &qp, &[fix(vec![0])]);
        assert_eq!(parts, vec![(8, na)]);
        assert!(free_parts(mesh.nodes.len(), &qp, &[fix(vec![0, na + 3])]).is_empty());
        assert!(free_parts(mesh.nodes.len(), &qp, &[]).is_empty());
    }
}
