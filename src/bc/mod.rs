//! Essential boundary conditions imposed directly on nodes (Kronecker-delta shape functions),
//! and the load curves that drive them.

use serde::{Deserialize, Serialize};

pub mod ebciem;
pub mod sparse_lu;

use crate::{Error, Result};

/// Time history of a prescribed displacement, as a fraction of its final value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum LoadCurve {
    /// d(t) = d_max (10 - 15 tau + 6 tau^2) tau^3, tau = t / T: zero velocity and acceleration at
    /// both ends (REFERENCE.md, the curve of every benchmark case).
    #[default]
    Smooth,
    /// d(t) = d_max tau.
    Ramp,
    /// d(t) = d_max from the first step.
    Constant,
    /// There and back: the smooth curve to d_max over the first half of T and, mirrored, back to
    /// zero over the second half (loading and unloading, Horton 2010 sect. 4.7).
    SmoothReturn,
}

impl LoadCurve {
    /// Fraction of the final value at normalised time tau = t / T (clamped to [0, 1]).
    #[inline]
    pub fn value(self, tau: f64) -> f64 {
        let t = tau.clamp(0.0, 1.0);
        match self {
            LoadCurve::Smooth => (10.0 - 15.0 * t + 6.0 * t * t) * t * t * t,
            LoadCurve::Ramp => t,
            LoadCurve::Constant => 1.0,
            LoadCurve::SmoothReturn => {
                let h = if t <= 0.5 { 2.0 * t } else { 2.0 - 2.0 * t };
                (10.0 - 15.0 * h + 6.0 * h * h) * h * h * h
            }
        }
    }
}

/// One named boundary: its nodes and, per component, the final prescribed displacement (m)
/// or `None` where the component is free.
#[derive(Debug, Clone)]
pub struct Boundary {
    pub name: String,
    pub nodes: Vec<usize>,
    pub components: [Option<f64>; 3],
    pub curve: LoadCurve,
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
            for &n in &b.nodes {
                for (k, comp) in b.components.iter().enumerate() {
                    let Some(v) = *comp else { continue };
                    match owner[n][k] {
                        Some((other, v0)) => {
                            let same_curve =
                                boundaries[other].curve == b.curve || (v == 0.0 && v0 == 0.0);
                            if v != v0 || !same_curve {
                                return Err(Error::Input(format!(
                                    "node {n} component {} is prescribed by boundary '{}' ({v0} m) and by boundary '{}' ({v} m); \
                                     make the selections disjoint or give both the same value and curve",
                                    ["x", "y", "z"][k], boundaries[other].name, b.name
                                )));
                            }
                        }
                        None => {
                            owner[n][k] = Some((bi, v));
                            c.dofs.push((n as u32, k as u8));
                            c.amplitude.push(v);
                            c.curve.push(b.curve);
                            c.mask[n][k] = true;
                        }
                    }
                }
            }
        }
        Ok(c)
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
    fn smooth_curve_has_zero_rate_at_ends_and_reaches_one() {
        let c = LoadCurve::Smooth;
        assert_eq!(c.value(0.0), 0.0);
        assert!((c.value(1.0) - 1.0).abs() < 1e-15);
        assert!((c.value(0.5) - 0.5).abs() < 1e-15);
        let h = 1e-6;
        assert!(((c.value(1.0) - c.value(1.0 - h)) / h).abs() < 1e-5);
        assert!(((c.value(h) - c.value(0.0)) / h).abs() < 1e-5);
    }

    #[test]
    fn return_curve_peaks_at_half_time_and_comes_back_smoothly() {
        let c = LoadCurve::SmoothReturn;
        assert_eq!(c.value(0.0), 0.0);
        assert!((c.value(0.5) - 1.0).abs() < 1e-15);
        assert!(c.value(1.0).abs() < 1e-15);
        // Symmetric about the peak and equal to the smooth curve at double speed.
        for tau in [0.1, 0.2, 0.3, 0.45] {
            assert!((c.value(tau) - c.value(1.0 - tau)).abs() < 1e-14);
            assert!((c.value(tau) - LoadCurve::Smooth.value(2.0 * tau)).abs() < 1e-15);
        }
        let h = 1e-6;
        for tau in [0.0 + h, 0.5, 1.0] {
            assert!(
                ((c.value(tau) - c.value(tau - h)) / h).abs() < 1e-4,
                "rate at {tau}"
            );
        }
    }

    #[test]
    fn conflicting_values_are_an_error_naming_both_boundaries() {
        let b = |name: &str, v: f64| Boundary {
            name: name.into(),
            nodes: vec![0, 1],
            components: [None, None, Some(v)],
            curve: LoadCurve::Smooth,
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
        let fix = |nodes: Vec<usize>| Boundary {
            name: "fix".into(),
            nodes,
            components: [Some(0.0); 3],
            curve: LoadCurve::default(),
        };
        let parts = free_parts(mesh.nodes.len(), &qp, &[fix(vec![0])]);
        assert_eq!(parts, vec![(8, na)]);
        assert!(free_parts(mesh.nodes.len(), &qp, &[fix(vec![0, na + 3])]).is_empty());
        assert!(free_parts(mesh.nodes.len(), &qp, &[]).is_empty());
    }
}
