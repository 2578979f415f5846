//! Support domains: which nodes contribute to the shape functions at a point, and with what
//! weight radius (Horton et al. 2010 sect. 2.3 and 3.1; thesis sect. 2.5 and 4.4.3).
//!
//! Neighbour search uses a k-d tree (kiddo). Two rules:
//! * `Nearest { n, alpha }`: the n nodes nearest to the point; every node gets the same weight
//!   radius r = alpha x the distance to the farthest of them (Horton 2010 eq. 8: alpha = 10 and
//!   n = 8 for a linear basis, so the n nodes weigh almost the same).
//! * `Radius { dilatation }`: each node I has an influence radius r_I = dilatation x the mean
//!   distance to its neighbours (the nodes it shares a background tetrahedron with, or its 8
//!   nearest nodes when there are no tetrahedra); a point's support is every node whose sphere
//!   covers it (thesis sect. 4.4.3, D = 2; the coupled-cylinder paper uses 1.6).

use std::num::NonZero;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;

use crate::{Error, InputKind, Result};

/// How a point's support is chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SupportRule {
    /// The `n` nearest nodes, weight radius `alpha` x the largest of their distances.
    Nearest { n: usize, alpha: f64 },
    /// Nodes whose influence sphere (radius `dilatation` x mean neighbour distance) covers the point.
    Radius { dilatation: f64 },
}

/// Open range of the radius rule's dilatation (influence radius / mean neighbour distance).
pub const DILATATION: (f64, f64) = (0.5, 20.0);
/// Fewest nodes of the nearest-node rule's supports.
pub const MIN_NEAREST: usize = 4;
/// Smallest weight radius / farthest support distance of the nearest-node rule.
pub const MIN_ALPHA: f64 = 1.0;

/// Nodes in a k-d tree with, for the radius rule, their influence radii (m).
pub struct Support {
    pub nodes: Vec<Vector3<f64>>,
    pub rule: SupportRule,
    /// Influence radius of each node (radius rule), m; empty for the nearest rule.
    pub radii: Vec<f64>,
    max_radius: f64,
    tree: ImmutableKdTree<f64, 3>,
    /// Radius rule: the nodes in bands of radii within a factor 2 of each other, each with its
    /// own tree, searched to its own largest radius. One search to the largest radius of all
    /// returned every node within it: on a graded cloud (the indentation benchmark, radii
    /// 0.4-6 mm) thousands of candidates per point near the fine end.
    bands: Vec<RadiusBand>,
}

/// Nodes whose influence radii lie within a factor 2 ([`Support::bands`]).
struct RadiusBand {
    max_radius: f64,
    /// Node ids of the band, in the order of its tree's items.
    ids: Vec<u32>,
    tree: ImmutableKdTree<f64, 3>,
}

impl std::fmt::Debug for Support {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Support")
            .field("nodes", &self.nodes.len())
            .field("rule", &self.rule)
            .field("max_radius", &self.max_radius)
            .field("bands", &self.bands.len())
            .finish()
    }
}

impl Support {
    /// Builds the search structure. `tets` (node-index quadruples) give each node its
    /// neighbours for the radius rule (flat slivers, of shape quality below 0.1, excluded);
    /// without them the 8 nearest nodes are used.
    pub fn new(
        nodes: Vec<Vector3<f64>>,
        rule: SupportRule,
        tets: Option<&[[usize; 4]]>,
    ) -> Result<Self> {
        if nodes.len() < 4 {
            return Err(Error::input(
                InputKind::Mesh,
                format!(
                    "the meshless cloud has {} nodes; at least 4 (not coplanar) are needed",
                    nodes.len()
                ),
            ));
        }
        if let Some(i) = nodes.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::input(
                InputKind::Mesh,
                format!(
                    "meshless node {i} has a non-finite coordinate {:?}",
                    nodes[i].as_slice()
                ),
            )
            .node(i));
        }
        let pts: Vec<[f64; 3]> = nodes.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = ImmutableKdTree::new_from_slice(&pts).map_err(|e| {
            Error::input(
                InputKind::Discretization,
                format!("cannot build the neighbour search tree: {e:?}"),
            )
        })?;
        match rule {
            SupportRule::Nearest { n, alpha } => {
                if n < MIN_NEAREST || !(alpha >= MIN_ALPHA) {
                    return Err(Error::input(InputKind::Value, format!(
                        "support: nearest rule needs support_nodes >= {MIN_NEAREST} and alpha >= {MIN_ALPHA} (got {n} and {alpha})"
                    )));
                }
            }
            SupportRule::Radius { dilatation } => {
                if !(dilatation > DILATATION.0 && dilatation < DILATATION.1) {
                    return Err(Error::input(InputKind::Value, format!(
                        "support: dilatation must lie in ({}, {}) (got {dilatation}); 1.6 to 2.0 is usual",
                        DILATATION.0, DILATATION.1
                    )).value(dilatation));
                }
            }
        }
        let mut s = Support {
            nodes,
            rule,
            radii: Vec::new(),
            max_radius: 0.0,
            tree,
            bands: Vec::new(),
        };
        if let SupportRule::Radius { dilatation } = rule {
            let mean = match tets {
                Some(t) => mean_tet_neighbour_distance(&s.nodes, t),
                None => vec![None; s.nodes.len()],
            };
            let radii: Vec<f64> = (0..s.nodes.len())
                .map(|i| dilatation * mean[i].unwrap_or_else(|| s.mean_nearest_distance(i, 8)))
                .collect();
            s.max_radius = radii.iter().cloned().fold(0.0, f64::max);
            s.radii = radii;
            s.rebuild_bands()?;
        }
        Ok(s)
    }

    /// The rule in words, for reports.
    pub fn describe(&self) -> String {
        match self.rule {
            SupportRule::Nearest { n, alpha } => format!("nearest {n} nodes, alpha = {alpha}"),
            SupportRule::Radius { dilatation } => {
                format!("influence radius, dilatation = {dilatation}")
            }
        }
    }

    /// The same rule on the nodes `keep` (ascending ids into `self.nodes`), each keeping its
    /// influence radius: used after removing nodes that too few supports reach.
    pub fn subset(&self, keep: &[usize]) -> Result<Self> {
        let nodes: Vec<Vector3<f64>> = keep.iter().map(|&i| self.nodes[i]).collect();
        let mut s = Support::new(nodes, SupportRule::Nearest { n: 4, alpha: 1.0 }, None)?;
        s.rule = self.rule;
        if !self.radii.is_empty() {
            s.radii = keep.iter().map(|&i| self.radii[i]).collect();
            s.max_radius = s.radii.iter().cloned().fold(0.0, f64::max);
            s.rebuild_bands()?;
        }
        Ok(s)
    }

    /// Multiplies the influence radius of nodes `ids` by `factor` (radius rule; no effect for
    /// the nearest rule).
    pub fn scale_radii(&mut self, ids: &[usize], factor: f64) {
        if self.radii.is_empty() {
            return;
        }
        for &i in ids {
            self.radii[i] *= factor;
        }
        self.max_radius = self.radii.iter().cloned().fold(0.0, f64::max);
        // The trees were built from valid nodes already: this cannot fail.
        let _ = self.rebuild_bands();
    }

    /// Groups the nodes by radius into [`Self::bands`] (factor 2 each, from the largest).
    fn rebuild_bands(&mut self) -> Result<()> {
        self.bands.clear();
        if self.radii.is_empty() || !(self.max_radius > 0.0) {
            return Ok(());
        }
        const MAX_BANDS: usize = 8;
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); MAX_BANDS];
        for (i, &r) in self.radii.iter().enumerate() {
            let b = if r > 0.0 {
                ((self.max_radius / r).log2().floor().max(0.0) as usize).min(MAX_BANDS - 1)
            } else {
                MAX_BANDS - 1
            };
            members[b].push(i as u32);
        }
        for ids in members.into_iter().filter(|m| !m.is_empty()) {
            let pts: Vec<[f64; 3]> = ids
                .iter()
                .map(|&i| {
                    let p = self.nodes[i as usize];
                    [p.x, p.y, p.z]
                })
                .collect();
            let tree = ImmutableKdTree::new_from_slice(&pts).map_err(|e| {
                Error::input(
                    InputKind::Discretization,
                    format!("cannot build the neighbour search tree: {e:?}"),
                )
            })?;
            let max_radius = ids
                .iter()
                .map(|&i| self.radii[i as usize])
                .fold(0.0, f64::max);
            self.bands.push(RadiusBand {
                max_radius,
                ids,
                tree,
            });
        }
        Ok(())
    }

    fn mean_nearest_distance(&self, i: usize, k: usize) -> f64 {
        let p = self.nodes[i];
        let k = k.min(self.nodes.len() - 1);
        let res = self
            .tree
            .query(&[p.x, p.y, p.z])
            .nearest_n::<SquaredEuclidean<f64>>(
                NonZero::new(k + 1).unwrap_or(NonZero::<usize>::MIN),
            )
            .execute();
        let d: Vec<f64> = res
            .iter()
            .filter(|r| r.item as usize != i)
            .map(|r| r.distance.sqrt())
            .collect();
        d.iter().sum::<f64>() / d.len().max(1) as f64
    }

    /// Support of point `x` (m): node ids in increasing order and the weight radius of each (m).
    /// `grow` >= 1 enlarges the support (more nearest nodes, or larger radii) when the
    /// moment matrix of the plain support is ill-conditioned.
    pub fn find(&self, x: &Vector3<f64>, grow: f64, ids: &mut Vec<usize>, radii: &mut Vec<f64>) {
        ids.clear();
        radii.clear();
        let q = [x.x, x.y, x.z];
        match self.rule {
            SupportRule::Nearest { n, alpha } => {
                let n = ((n as f64 * grow).round() as usize).clamp(1, self.nodes.len());
                let res = self
                    .tree
                    .query(&q)
                    .nearest_n::<SquaredEuclidean<f64>>(
                        NonZero::new(n).unwrap_or(NonZero::<usize>::MIN),
                    )
                    .execute();
                let dmax = res.iter().map(|r| r.distance).fold(0.0, f64::max).sqrt();
                let r = (alpha * dmax).max(f64::MIN_POSITIVE);
                ids.extend(res.iter().map(|r| r.item as usize));
                ids.sort_unstable();
                radii.resize(ids.len(), r);
            }
            SupportRule::Radius { .. } => {
                for band in &self.bands {
                    let reach = band.max_radius * grow;
                    let res = band
                        .tree
                        .query(&q)
                        .within::<SquaredEuclidean<f64>>(reach * reach)
                        .unsorted()
                        .execute();
                    for r in res {
                        let i = band.ids[r.item as usize] as usize;
                        let ri = self.radii[i] * grow;
                        if r.distance < ri * ri {
                            ids.push(i);
                        }
                    }
                }
                ids.sort_unstable();
                radii.extend(ids.iter().map(|&i| self.radii[i] * grow));
            }
        }
    }
}

/// Tetrahedra below this shape quality (see [`tet_quality`]; 1 for the regular tetrahedron)
/// do not make their vertices neighbours for the influence radius.
///
/// The Delaunay tetrahedralization of a generated or file cloud fills the convex hull of the
/// nodes. Where the surface is curved, the hull is closed by flat slivers between surface nodes
/// that may be far apart: on a cylinder, the hull joins nodes of the lateral surface that are
/// close in angle whatever their distance along the axis, up to the full height (Halton cloud,
/// h = 0.0125 m, radius 0.05 m: 864 tet edges longer than 3 cm, the longest 0.1 m, in tets of
/// quality below 0.06). Counting those as neighbours doubled the influence radii of the rim
/// nodes (mean 0.052 m against 0.024 m inside) and raised those of the lateral surface by half;
/// the wide, overlapping rim supports made the EBCIEM matrix Phi M^-1 V nearly singular
/// (condition 8e6, near-null vectors alternating along the rim) and the corrected system
/// unstable at any time step (eigenvalues of P M^-1 K down to -1.3e6 s^-2). Without the slivers
/// the rim radii are 0.022 m and the condition 5e2, as on a regular lattice. The tets of
/// structured and TetGen meshes (the `mesh` cloud, the coupled interior) have quality above 0.2
/// in the shipped scenes, so this changes nothing there; the Delaunay cube has 8 tets below.
const MIN_NEIGHBOUR_TET_QUALITY: f64 = 0.1;

/// Shape quality of a tetrahedron: 6 sqrt(2) |V| / l_rms^3 with l_rms the root mean square of
/// its six edge lengths; 1 for the regular tetrahedron, 0 for a flat one.
fn tet_quality(p: &[Vector3<f64>; 4]) -> f64 {
    let v = ((p[1] - p[0]).dot(&(p[2] - p[0]).cross(&(p[3] - p[0]))) / 6.0).abs();
    let mut l2 = 0.0;
    for a in 0..4 {
        for b in a + 1..4 {
            l2 += (p[a] - p[b]).norm_squared();
        }
    }
    let l_rms = (l2 / 6.0).sqrt();
    if l_rms > 0.0 {
        6.0 * std::f64::consts::SQRT_2 * v / (l_rms * l_rms * l_rms)
    } else {
        0.0
    }
}

/// Mean distance from each node to the nodes it shares a tetrahedron of quality at least
/// [`MIN_NEIGHBOUR_TET_QUALITY`] with (None for nodes in no such tet).
fn mean_tet_neighbour_distance(nodes: &[Vector3<f64>], tets: &[[usize; 4]]) -> Vec<Option<f64>> {
    let mut nbr: Vec<Vec<u32>> = vec![Vec::new(); nodes.len()];
    for t in tets {
        if t.iter().all(|&a| a < nodes.len())
            && tet_quality(&t.map(|a| nodes[a])) < MIN_NEIGHBOUR_TET_QUALITY
        {
            continue;
        }
        for &a in t {
            for &b in t {
                if a != b && a < nodes.len() && b < nodes.len() {
                    nbr[a].push(b as u32);
                }
            }
        }
    }
    nbr.into_iter()
        .enumerate()
        .map(|(i, mut v)| {
            v.sort_unstable();
            v.dedup();
            if v.is_empty() {
                return None;
            }
            let s: f64 = v
                .iter()
                .map(|&j| (nodes[j as usize] - nodes[i]).norm())
                .sum();
            Some(s / v.len() as f64)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice(n: usize, h: f64) -> Vec<Vector3<f64>> {
        let mut v = Vec::new();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    v.push(Vector3::new(i as f64, j as f64, k as f64) * h);
                }
            }
        }
        v
    }

    #[test]
    fn nearest_rule_matches_brute_force() {
        let nodes = lattice(5, 0.1);
        let s = Support::new(
            nodes.clone(),
            SupportRule::Nearest { n: 8, alpha: 10.0 },
            None,
        )
        .unwrap();
        let x = Vector3::new(0.123, 0.211, 0.307);
        let (mut ids, mut r) = (Vec::new(), Vec::new());
        s.find(&x, 1.0, &mut ids, &mut r);
        let mut d: Vec<(f64, usize)> = nodes
            .iter()
            .enumerate()
            .map(|(i, p)| ((p - x).norm(), i))
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut want: Vec<usize> = d[..8].iter().map(|t| t.1).collect();
        want.sort_unstable();
        assert_eq!(ids, want);
        assert!((r[0] - 10.0 * d[7].0).abs() < 1e-12);
    }

    #[test]
    fn radius_rule_covers_point_with_each_nodes_own_sphere() {
        let nodes = lattice(6, 0.1);
        let s = Support::new(nodes.clone(), SupportRule::Radius { dilatation: 1.6 }, None).unwrap();
        // Interior lattice node: 6 neighbours at h and 2 at sqrt(2) h among its 8 nearest.
        let i = 1 + 6 * (2 + 6 * 2);
        let mean = (6.0 * 0.1 + 2.0 * 0.1 * 2f64.sqrt()) / 8.0;
        assert!(
            (s.radii[i] - 1.6 * mean).abs() < 1e-12,
            "{} vs {}",
            s.radii[i],
            1.6 * mean
        );
        let x = Vector3::new(0.25, 0.25, 0.25);
        let (mut ids, mut r) = (Vec::new(), Vec::new());
        s.find(&x, 1.0, &mut ids, &mut r);
        let want: Vec<usize> = (0..nodes.len())
            .filter(|&j| (nodes[j] - x).norm() < s.radii[j])
            .collect();
        assert_eq!(ids, want);
        assert!(ids.len() >= 8);
    }

    #[test]
    fn flat_sliver_tets_do_not_make_neighbours() {
        // Lattice index (i * 3 + j) * 3 + k for (i, j, k) h: node 0 at the origin, nodes 2, 6
        // and 8 on the plane x = 0 with it, so [0, 2, 6, 8] is flat.
        let nodes = lattice(3, 0.1);
        let rule = SupportRule::Radius { dilatation: 1.6 };
        let good = [[0, 1, 3, 9]];
        let with_sliver = [[0, 1, 3, 9], [0, 2, 6, 8]];
        let a = Support::new(nodes.clone(), rule, Some(&good)).unwrap();
        let b = Support::new(nodes.clone(), rule, Some(&with_sliver)).unwrap();
        let none = Support::new(nodes.clone(), rule, None).unwrap();
        assert_eq!(a.radii, b.radii);
        // Node 0's neighbours are 1, 3, 9 at h: the sliver's 2 h and 2.83 h edges are ignored.
        assert!((b.radii[0] - 1.6 * 0.1).abs() < 1e-12, "{}", b.radii[0]);
        // Nodes only in the sliver fall back to their 8 nearest nodes.
        for i in [2, 6, 8] {
            assert_eq!(b.radii[i], none.radii[i]);
        }
        let q = |t: [usize; 4]| tet_quality(&t.map(|i| nodes[i]));
        assert!(q([0, 2, 6, 8]).abs() < 1e-12);
        assert!(q([0, 1, 3, 9]) > MIN_NEIGHBOUR_TET_QUALITY);
    }

    #[test]
    fn too_few_nodes_is_an_error() {
        let e = Support::new(
            lattice(1, 1.0),
            SupportRule::Radius { dilatation: 2.0 },
            None,
        );
        assert!(e.is_err());
    }
}
