//! Integration points of the MTLED weak form: positions (m) and weights (m^3). MTLED
//! integrates over a background structure that need not conform to the node cloud (Horton et
//! al. 2010, "A meshless Total Lagrangian explicit dynamics algorithm for surgical simulation",
//! Int. J. Numer. Meth. Biomed. Engng 26, sect. 2.2 and 3.2): either the cells of a
//! tetrahedral mesh with a Gauss-type rule per cell, or a regular grid of cubic cells over the
//! bounding box with one point per cell.

use nalgebra::Vector3;

use crate::geometry::domain::Domain;
use crate::geometry::quality::tet_signed_volume;
use crate::geometry::{ElementShape, Mesh};
use crate::{Error, InputKind, Result};

/// Largest background grid [`grid_points`] builds; more means a unit error, not a request.
const MAX_GRID_POINTS: f64 = 20_000_000.0;

/// Integration rule per tetrahedron of a background mesh (Horton et al. 2010 sect. 3.2 use
/// one or four points per tet). Written in scene files as "1", "4" or "5".
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
pub enum TetRule {
    /// Centroid, weight V: exact for linear functions.
    #[serde(rename = "1")]
    One,
    /// Degree-2 rule of Hammer, Marlowe and Stroud (1956): four points at barycentric
    /// (a, b, b, b) and permutations, a = 0.5854101966249685, b = 0.1381966011250105, weights
    /// V/4. The default: exact for quadratics with positive weights.
    #[default]
    #[serde(rename = "4")]
    Four,
    /// Degree-3 rule of Keast (1986, "Moderate-degree tetrahedral quadrature formulas", CMAME
    /// 55): centroid with weight -4/5 V and four points at barycentric (1/2, 1/6, 1/6, 1/6)
    /// and permutations with weight 9/20 V. Exact for cubics, but the negative centroid weight
    /// makes lumped quantities built from point weights (masses) unreliable.
    #[serde(rename = "5")]
    Five,
}

impl TetRule {
    /// The rule with `n` points per tet (1, 4 or 5), None otherwise.
    pub fn from_points(n: usize) -> Option<Self> {
        match n {
            1 => Some(TetRule::One),
            4 => Some(TetRule::Four),
            5 => Some(TetRule::Five),
            _ => None,
        }
    }

    /// Points per tet.
    pub fn points(self) -> usize {
        match self {
            TetRule::One => 1,
            TetRule::Four => 4,
            TetRule::Five => 5,
        }
    }

    /// Barycentric coordinates and weight fractions (of the tet volume) of the rule.
    pub fn table(self) -> &'static [([f64; 4], f64)] {
        const A: f64 = 0.585_410_196_624_968_5;
        const B: f64 = 0.138_196_601_125_010_5;
        const Q: f64 = 0.25;
        const H: f64 = 0.5;
        const S: f64 = 1.0 / 6.0;
        match self {
            TetRule::One => &[([Q, Q, Q, Q], 1.0)],
            TetRule::Four => &[
                ([A, B, B, B], 0.25),
                ([B, A, B, B], 0.25),
                ([B, B, A, B], 0.25),
                ([B, B, B, A], 0.25),
            ],
            TetRule::Five => &[
                ([Q, Q, Q, Q], -0.8),
                ([H, S, S, S], 0.45),
                ([S, H, S, S], 0.45),
                ([S, S, H, S], 0.45),
                ([S, S, S, H], 0.45),
            ],
        }
    }
}

/// Integration points of a tetrahedral background mesh (Horton et al. 2010 sect. 2.2/3.2):
/// `rule` points per tet (1: centroid; 4: the degree-2 rule with a = 0.5854101966249685,
/// b = 0.1381966011250105, weights V/4; 5: the degree-3 Keast rule, centroid weight -4/5 V and
/// four points at (1/2, 1/6, 1/6, 1/6) barycentric with weight 9/20 V). Weights sum to the mesh
/// volume exactly (up to rounding). Returns (positions in m, weights in m^3, owning tet index
/// per point); the points of tet e are consecutive, in the order of the rule.
///
/// Errors when the mesh is not a Tet4 mesh, a cell refers to a missing node, or a tet has
/// non-positive volume ([`Error::InvalidElement`] naming the tet).
#[allow(clippy::type_complexity)] // the tuple is the documented API
pub fn tet_points(mesh: &Mesh, rule: TetRule) -> Result<(Vec<Vector3<f64>>, Vec<f64>, Vec<usize>)> {
    // The tets' vertices and volumes (104 bytes a tet) and each point's position, weight and
    // owner (40 bytes), before any are made.
    let tets = mesh.num_cells() as f64;
    crate::memory::check(
        tets * (104.0 + 40.0 * rule.points() as f64),
        &format!(
            "the integration points ({} background tets x {} points)",
            mesh.num_cells(),
            rule.points()
        ),
        "use fewer points per tet (discretization.tet_rule) or a coarser cloud (discretization.size)",
    )?;
    let tets = checked_tets(mesh, "tetrahedral integration points")?;
    let n = tets.len() * rule.points();
    let mut pos = Vec::with_capacity(n);
    let mut w = Vec::with_capacity(n);
    let mut owner = Vec::with_capacity(n);
    for (e, (x, volume)) in tets.iter().enumerate() {
        for (bary, frac) in rule.table() {
            pos.push(x[0] * bary[0] + x[1] * bary[1] + x[2] * bary[2] + x[3] * bary[3]);
            w.push(frac * volume);
            owner.push(e);
        }
    }
    Ok((pos, w, owner))
}

/// The vertices (m) and volume (m^3) of every tet of `mesh`, for `what` (named in errors).
///
/// Errors when the mesh is not a Tet4 mesh, a cell refers to a missing node, or a tet has
/// non-positive volume ([`Error::InvalidElement`] naming the tet).
#[allow(clippy::type_complexity)] // vertices with their volume
pub(crate) fn checked_tets(mesh: &Mesh, what: &str) -> Result<Vec<([Vector3<f64>; 4], f64)>> {
    if mesh.shape != ElementShape::Tet4 {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "{what} need a Tet4 background mesh, got a {:?} mesh",
                mesh.shape
            ),
        ));
    }
    if !mesh.cells.len().is_multiple_of(4) {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "tet mesh connectivity has {} entries, not a multiple of 4",
                mesh.cells.len()
            ),
        ));
    }
    (0..mesh.num_cells())
        .map(|e| {
            let mut x = [Vector3::zeros(); 4];
            for (xi, &i) in x.iter_mut().zip(mesh.cell(e)) {
                *xi = *mesh.nodes.get(i).ok_or_else(|| {
                    Error::input(
                        InputKind::Mesh,
                        format!(
                            "tet {e} refers to node {i}, but the mesh has {} nodes",
                            mesh.nodes.len()
                        ),
                    )
                    .element(e)
                })?;
            }
            let volume = tet_signed_volume(&x[0], &x[1], &x[2], &x[3]);
            if !(volume > 0.0) {
                return Err(Error::InvalidElement { element: e, volume });
            }
            Ok((x, volume))
        })
        .collect()
}

/// Regular background grid that does not conform to the geometry (Horton et al. 2010 sect.
/// 2.2/3.2): cubic cells of edge a = (V / (ratio * nodes))^(1/3) over the domain's bounding box
/// (cell counts round(L/a) per axis, at least 1, cells then slightly non-cubic so they tile the
/// box exactly), one point per cell at its centre with weight = cell volume (m^3), kept if the
/// centre is inside the domain (on the surface counts as inside). `ratio` is the wanted
/// integration-point : node ratio (Horton et al. recommend about 2). About ratio x nodes points
/// come back; for a curved domain the total weight only approximates the volume (cells cut by
/// the surface count fully or not at all), converging as the grid refines.
///
/// Errors when the domain is invalid, `nodes` is 0, `ratio` is not positive and finite, or the
/// grid would have more than 20 million cells.
pub fn grid_points(
    domain: &Domain,
    nodes: usize,
    ratio: f64,
) -> Result<(Vec<Vector3<f64>>, Vec<f64>)> {
    domain.validate()?;
    if nodes == 0 {
        return Err(Error::input(
            InputKind::Discretization,
            "a background integration grid needs at least one node",
        ));
    }
    if !(ratio.is_finite() && ratio > 0.0) {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "integration point to node ratio {ratio} must be positive and finite (typically 2)"
            ),
        ));
    }
    let a = (domain.volume() / (ratio * nodes as f64)).cbrt();
    let (lo, hi) = domain.bounds();
    let len = hi - lo;
    let counts = len.map(|l| (l / a).round().max(1.0));
    let cells = counts.product();
    if !(cells <= MAX_GRID_POINTS) {
        return Err(Error::input(InputKind::Limit, format!(
            "integration grid of {nodes} nodes x ratio {ratio} needs {sci_cells:.3e} cells, more \
             than the limit of {sci_MAX_GRID_POINTS:.0e}; lower the ratio or the node count", sci_cells = crate::error::Sci(cells), sci_MAX_GRID_POINTS = crate::error::Sci(MAX_GRID_POINTS))));
    }
    let n = counts.map(|c| c as usize);
    let d = len.component_div(&counts);
    let weight = d.product();
    let mut pos = Vec::new();
    for k in 0..n.z {
        for j in 0..n.y {
            for i in 0..n.x {
                // Centres from the cell index (not accumulated) so rounding does not drift.
                let c = lo
                    + Vector3::new(
                        len.x * ((i as f64 + 0.5) / counts.x),
                        len.y * ((j as f64 + 0.5) / counts.y),
                        len.z * ((k as f64 + 0.5) / counts.z),
                    );
                if domain.contains(&c, 0.0) {
                    pos.push(c);
                }
            }
        }
    }
    let w = vec![weight; pos.len()];
    Ok((pos, w))
}

/// Integrates f over the points: sum of w f(x) (weights in m^3 give integrals over volume).
/// Used by tests and reports.
pub fn integrate(
    points: &[Vector3<f64>],
    weights: &[f64],
    f: impl Fn(&Vector3<f64>) -> f64,
) -> f64 {
    points.iter().zip(weights).map(|(p, w)| w * f(p)).sum()
}

/// Merges the integration points of about `tets_per_point` face-connected tets of `mesh` into
/// one: the tets are grouped by [`tet_patches`] (size `tets_per_point` rounded), and each group's
/// points become one point at their weight-weighted centroid carrying their total weight.
/// Volume and first moments stay exact, so linear integrands are integrated exactly, as by the
/// rules merged. Grouping whole tets follows the mesh's grading: on a mesh graded at a load's
/// rim a regular grid of bins sized by the mean tet merged dozens of small tets into one point
/// whose MLS support did not reach the bin's edge, leaving nodes with no point and no mass
/// (the indentation benchmark's level c4 with `tets_per_point = 2`). `owner[i]` is point i's
/// tet. Returns (positions m, weights m^3, owner = the tet of the group's first point), groups
/// in order of their first point; None for `tets_per_point` below 1.5 (nothing to merge).
pub fn cluster_tets(
    mesh: &Mesh,
    pos: &[Vector3<f64>],
    w: &[f64],
    owner: &[usize],
    tets_per_point: f64,
) -> Option<(Vec<Vector3<f64>>, Vec<f64>, Vec<usize>)> {
    let size = tets_per_point.round();
    if !(size >= 2.0) || mesh.num_cells() == 0 {
        return None;
    }
    let patch = tet_patches(mesh, size.min(usize::MAX as f64) as usize);
    let groups = patch_point_groups(Some(&patch), owner);
    let mut cpos = Vec::with_capacity(groups.len());
    let mut cw = Vec::with_capacity(groups.len());
    for g in &groups {
        let v: f64 = g.iter().map(|&i| w[i]).sum();
        cpos.push(g.iter().fold(Vector3::zeros(), |m, &i| m + pos[i] * w[i]) / v);
        cw.push(v);
    }
    let cown = groups.iter().map(|g| owner[g[0]]).collect();
    Some((cpos, cw, cown))
}

/// Patches of about `size` face-connected tets of `mesh`, for mean dilatation over the
/// integration points of each patch: grown breadth first from the lowest unassigned tet until
/// the patch holds `size` tets; a patch left with fewer than half of `size` (hemmed in by
/// others) joins a neighbouring patch of at least that size through a shared face where the
/// two hold at most 1.5 x `size`. Returns
/// each tet's patch, numbered in order of their first tet; deterministic.
pub fn tet_patches(mesh: &Mesh, size: usize) -> Vec<usize> {
    let n = mesh.num_cells();
    let size = size.max(1);
    let mut faces: std::collections::HashMap<[usize; 3], Vec<usize>> =
        std::collections::HashMap::new();
    for e in 0..n {
        let c = mesh.cell(e);
        for skip in 0..4 {
            let mut f = [0usize; 3];
            for (k, a) in (0..4).filter(|&a| a != skip).enumerate() {
                f[k] = c[a];
            }
            f.sort_unstable();
            faces.entry(f).or_default().push(e);
        }
    }
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n];
    for t in faces.values() {
        if let [a, b] = t[..] {
            adj[a].push(b);
            adj[b].push(a);
        }
    }
    // The map's order is arbitrary: sorted neighbour lists make the patches deterministic.
    adj.iter_mut().for_each(|a| a.sort_unstable());
    let mut patch = vec![usize::MAX; n];
    let mut sizes = Vec::new();
    let mut queue = std::collections::VecDeque::new();
    for start in 0..n {
        if patch[start] != usize::MAX {
            continue;
        }
        let g = sizes.len();
        patch[start] = g;
        queue.clear();
        queue.push_back(start);
        let mut members = 1;
        while let Some(e) = queue.pop_front() {
            for &f in &adj[e] {
                if members < size && patch[f] == usize::MAX {
                    patch[f] = g;
                    members += 1;
                    queue.push_back(f);
                }
            }
        }
        sizes.push(members);
    }
    let big: Vec<bool> = sizes.iter().map(|&m| 2 * m >= size).collect();
    let mut target: Vec<usize> = (0..sizes.len()).collect();
    let mut total = sizes.clone();
    for e in 0..n {
        let g = patch[e];
        if !big[g] && target[g] == g {
            // Into the first big neighbour that stays within 1.5 x the size.
            let fits = |f: &&usize| {
                let h = patch[**f];
                big[h] && 2 * (total[h] + sizes[g]) <= 3 * size
            };
            if let Some(&f) = adj[e].iter().find(fits) {
                target[g] = patch[f];
                total[patch[f]] += sizes[g];
            }
        }
    }
    let mut number = vec![usize::MAX; sizes.len()];
    let mut next = 0;
    patch
        .iter()
        .map(|&g| {
            let t = target[g];
            if number[t] == usize::MAX {
                number[t] = next;
                next += 1;
            }
            number[t]
        })
        .collect()
}

/// The integration points in the order they enter the point table, as groups: with `patches`
/// (each tet's patch, [`tet_patches`]) one group per patch in order of first appearance, points
/// in their own order within it; without, each point alone. `owner[p]`: point p's tet.
pub fn patch_point_groups(patches: Option<&[usize]>, owner: &[usize]) -> Vec<Vec<usize>> {
    let Some(patch) = patches else {
        return (0..owner.len()).map(|p| vec![p]).collect();
    };
    let mut slot = vec![usize::MAX; patch.iter().max().map_or(0, |&g| g + 1)];
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (p, &t) in owner.iter().enumerate() {
        let g = patch[t];
        if slot[g] == usize::MAX {
            slot[g] = groups.len();
            groups.push(Vec::new());
        }
        groups[slot[g]].push(p);
    }
    groups
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::{box_tet, cylinder_tet};

    fn mesh_volume(mesh: &Mesh) -> f64 {
        (0..mesh.num_cells())
            .map(|e| {
                let c = mesh.cell(e);
                let x = |i: usize| &mesh.nodes[c[i]];
                tet_signed_volume(x(0), x(1), x(2), x(3))
            })
            .sum()
    }

    const RULES: [TetRule; 3] = [TetRule::One, TetRule::Four, TetRule::Five];

    #[test]
    fn rule_counts_and_serde_names() {
        for r in RULES {
            assert_eq!(TetRule::from_points(r.points()), Some(r));
            let s = serde_json::to_string(&r).unwrap();
            assert_eq!(s, format!("\"{}\"", r.points()));
            assert_eq!(serde_json::from_str::<TetRule>(&s).unwrap(), r);
        }
        assert_eq!(TetRule::from_points(2), None);
        assert_eq!(TetRule::default(), TetRule::Four);
    }

    #[test]
    fn weights_sum_to_mesh_volume() {
        let meshes = [
            box_tet(Vector3::zeros(), Vector3::new(0.1, 0.05, 0.02), [5, 4, 3]).unwrap(),
            cylinder_tet(0.05, 0.1, 4, 2, 5).unwrap(),
        ];
        for mesh in &meshes {
            let v = mesh_volume(mesh);
            for r in RULES {
                let (p, w, owner) = tet_points(mesh, r).unwrap();
                assert_eq!(p.len(), mesh.num_cells() * r.points());
                assert_eq!(owner.len(), p.len());
                assert_eq!(owner[r.points()], 1);
                let total: f64 = w.iter().sum();
                let rel = (total - v).abs() / v;
                println!(
                    "tet rule {r:?}: {} points, weights {total:.15e} m^3, mesh {v:.15e} m^3, \
                     rel err {rel:.2e}",
                    p.len()
                );
                assert!(rel < 1e-12);
            }
        }
    }

    /// Integral over the unit cube of x^a y^b z^c.
    fn monomial(a: i32, b: i32, c: i32) -> f64 {
        1.0 / ((a + 1) * (b + 1) * (c + 1)) as f64
    }

    #[test]
    fn rules_integrate_polynomials_exactly() {
        let mesh = box_tet(Vector3::zeros(), Vector3::new(1.0, 1.0, 1.0), [3, 2, 2]).unwrap();
        let linear = |p: &Vector3<f64>| 1.0 + 2.0 * p.x - p.y + 3.0 * p.z;
        let linear_exact = 1.0 + 2.0 * 0.5 - 0.5 + 3.0 * 0.5;
        let quadratic = |p: &Vector3<f64>| {
            p.x * p.x + p.x * p.y + 2.0 * p.y * p.z - 3.0 * p.z * p.z + p.z + 1.0
        };
        let quadratic_exact = monomial(2, 0, 0) + monomial(1, 1, 0) + 2.0 * monomial(0, 1, 1)
            - 3.0 * monomial(0, 0, 2)
            + monomial(0, 0, 1)
            + 1.0;
        let cubic = |p: &Vector3<f64>| {
            p.x.powi(3) + p.x * p.y * p.z - 2.0 * p.y * p.y * p.z + p.z.powi(3) + p.x * p.y + 1.0
        };
        let cubic_exact = monomial(3, 0, 0) + monomial(1, 1, 1) - 2.0 * monomial(0, 2, 1)
            + monomial(0, 0, 3)
            + monomial(1, 1, 0)
            + 1.0;
        let err = |r: TetRule, f: &dyn Fn(&Vector3<f64>) -> f64, exact: f64| {
            let (p, w, _) = tet_points(&mesh, r).unwrap();
            (integrate(&p, &w, f) - exact).abs() / exact.abs()
        };
        let e1 = err(TetRule::One, &linear, linear_exact);
        let e4 = err(TetRule::Four, &quadratic, quadratic_exact);
        let e5 = err(TetRule::Five, &cubic, cubic_exact);
        println!(
            "unit box mesh rel errors: 1-pt linear {e1:.2e}, 4-pt quadratic {e4:.2e}, 5-pt \
             cubic {e5:.2e}"
        );
        assert!(e1 < 1e-12 && e4 < 1e-12 && e5 < 1e-12);
    }

    /// On the reference tet, where the integral of x^a y^b z^c is a! b! c! / (a+b+c+3)!, each
    /// rule is exact to its degree and not one degree further (on the symmetric box mesh the
    /// per-tet errors of odd monomials can cancel, so that check is made here).
    #[test]
    fn rules_reach_their_degree_on_one_tet() {
        let mesh = Mesh {
            nodes: vec![
                Vector3::zeros(),
                Vector3::new(1.0, 0.0, 0.0),
                Vector3::new(0.0, 1.0, 0.0),
                Vector3::new(0.0, 0.0, 1.0),
            ],
            shape: ElementShape::Tet4,
            cells: vec![0, 1, 2, 3],
        };
        let fact = |n: i32| (1..=n).product::<i32>() as f64;
        let exact = |a: i32, b: i32, c: i32| fact(a) * fact(b) * fact(c) / fact(a + b + c + 3);
        let err = |r: TetRule, a: i32, b: i32, c: i32| {
            let (p, w, _) = tet_points(&mesh, r).unwrap();
            let f = |x: &Vector3<f64>| x.x.powi(a) * x.y.powi(b) * x.z.powi(c);
            (integrate(&p, &w, f) - exact(a, b, c)).abs() / exact(a, b, c)
        };
        for (r, degree) in [(TetRule::One, 1), (TetRule::Four, 2), (TetRule::Five, 3)] {
            let mut worst_exact: f64 = 0.0;
            let mut best_next = f64::INFINITY;
            for a in 0..=degree + 1 {
                for b in 0..=degree + 1 - a {
                    for c in 0..=degree + 1 - a - b {
                        let e = err(r, a, b, c);
                        if a + b + c <= degree {
                            worst_exact = worst_exact.max(e);
                        } else if a + b + c == degree + 1 && b == 0 && c == 0 {
                            best_next = best_next.min(e);
                        }
                    }
                }
            }
            println!(
                "reference tet {r:?}: worst rel err up to degree {degree} {worst_exact:.2e}, \
                 rel err of x^{} {best_next:.2e}",
                degree + 1
            );
            assert!(worst_exact < 1e-12);
            assert!(best_next > 1e-3);
        }
    }

    #[test]
    fn tet_points_refuse_bad_meshes() {
        let mut mesh = box_tet(Vector3::zeros(), Vector3::new(1.0, 1.0, 1.0), [1, 1, 1]).unwrap();
        mesh.cells.swap(4, 5); // invert tet 1
        match tet_points(&mesh, TetRule::Four) {
            Err(Error::InvalidElement { element, volume }) => {
                assert_eq!(element, 1);
                assert!(volume < 0.0);
            }
            other => panic!("expected InvalidElement, got {other:?}"),
        }
        mesh.cells[0] = 999;
        assert!(tet_points(&mesh, TetRule::One).is_err());
        let hex = crate::geometry::shapes::box_hex(
            Vector3::zeros(),
            Vector3::new(1.0, 1.0, 1.0),
            [1, 1, 1],
        )
        .unwrap();
        assert!(tet_points(&hex, TetRule::One).is_err());
    }

    #[test]
    fn grid_on_box_is_exact() {
        let d = Domain::Box {
            min: Vector3::new(-0.01, 0.0, 0.02),
            max: Vector3::new(0.09, 0.05, 0.04),
        };
        let nodes = 1000;
        for ratio in [1.0, 2.0, 4.0] {
            let (p, w) = grid_points(&d, nodes, ratio).unwrap();
            assert!(p.iter().all(|x| d.contains(x, 0.0)));
            let total: f64 = w.iter().sum();
            let rel = (total - d.volume()).abs() / d.volume();
            let count_ratio = p.len() as f64 / (ratio * nodes as f64);
            println!(
                "box grid ratio {ratio}: {} points ({count_ratio:.3} x ratio x nodes), \
                 volume rel err {rel:.2e}",
                p.len()
            );
            assert!(rel < 1e-12);
            assert!((0.7..1.4).contains(&count_ratio));
        }
    }

    #[test]
    fn grid_on_cylinder_converges() {
        let (r, h) = (0.05, 0.1);
        let d = Domain::Cylinder {
            radius: r,
            height: h,
        };
        let exact = std::f64::consts::PI * r * r * h;
        let nodes = 1000;
        let mut errors = Vec::new();
        for ratio in [2.0, 16.0, 128.0, 1024.0] {
            let (p, w) = grid_points(&d, nodes, ratio).unwrap();
            assert!(p.iter().all(|x| d.contains(x, 0.0)));
            let total: f64 = w.iter().sum();
            let rel = (total - exact).abs() / exact;
            let count_ratio = p.len() as f64 / (ratio * nodes as f64);
            println!(
                "cylinder grid ratio {ratio}: {} points ({count_ratio:.3} x ratio x nodes), \
                 volume rel err {rel:.3e}",
                p.len()
            );
            assert!((0.8..1.25).contains(&count_ratio));
            errors.push(rel);
        }
        assert!(errors[0] < 0.05);
        assert!(errors[3] < errors[0] && errors[3] < 0.005, "{errors:?}");
    }

    #[test]
    fn grid_refuses_bad_input() {
        let d = Domain::Cylinder {
            radius: 0.05,
            height: 0.1,
        };
        assert!(grid_points(&d, 0, 2.0).is_err());
        assert!(grid_points(&d, 100, 0.0).is_err());
        assert!(grid_points(&d, 100, f64::NAN).is_err());
        let e = grid_points(&d, 10_000_000, 10.0).unwrap_err().to_string();
        assert!(e.contains("limit"), "{e}");
    }

    /// Merged points keep the volume and the first moments of the tets they replace (linear
    /// integrands stay exact), one point per bin, about `tets_per_point` times fewer points.
    #[test]
    fn clustered_points_keep_volume_and_first_moments() {
        let mesh = crate::geometry::shapes::box_tet(
            Vector3::zeros(),
            Vector3::new(0.1, 0.06, 0.04),
            [10, 6, 4],
        )
        .unwrap();
        let (p, w, o) = tet_points(&mesh, TetRule::One).unwrap();
        for k in [2.0, 3.0, 6.0] {
            let (cp, cw, co) = cluster_tets(&mesh, &p, &w, &o, k).unwrap();
            let v0: f64 = w.iter().sum();
            let v1: f64 = cw.iter().sum();
            assert!((v1 - v0).abs() < 1e-12 * v0);
            let m0 = p
                .iter()
                .zip(&w)
                .fold(Vector3::zeros(), |a, (x, &v)| a + x * v);
            let m1 = cp
                .iter()
                .zip(&cw)
                .fold(Vector3::zeros(), |a, (x, &v)| a + x * v);
            assert!((m1 - m0).norm() < 1e-12 * m0.norm());
            let ratio = p.len() as f64 / cp.len() as f64;
            assert!(ratio > 0.5 * k && ratio < 2.0 * k, "{k}: ratio {ratio}");
            assert!(co.iter().all(|&e| e < mesh.num_cells()));
            assert!(cw.iter().all(|&v| v > 0.0));
        }
        assert!(cluster_tets(&mesh, &p, &w, &o, 1.0).is_none());
        assert!(cluster_tets(&mesh, &p, &w, &o, 1.4).is_none());
    }

    /// Patches cover every tet once, are face-connected, hold at most 1.5 x the size asked
    /// for and about that many on average.
    #[test]
    fn tet_patches_are_connected_and_about_the_size_asked() {
        let mesh = cylinder_tet(0.05, 0.1, 4, 3, 8).unwrap();
        let n = mesh.num_cells();
        for size in [1, 4, 8, 20] {
            let patch = tet_patches(&mesh, size);
            assert_eq!(patch.len(), n);
            let count = patch.iter().max().unwrap() + 1;
            let mut members = vec![Vec::new(); count];
            for (e, &g) in patch.iter().enumerate() {
                members[g].push(e);
            }
            let shares_face = |a: usize, b: usize| {
                let (ca, cb) = (mesh.cell(a), mesh.cell(b));
                ca.iter().filter(|v| cb.contains(v)).count() == 3
            };
            for m in &members {
                assert!(
                    !m.is_empty() && 2 * m.len() <= 3 * size.max(1) + 1,
                    "{size}: {}",
                    m.len()
                );
                // Connected: a walk over shared faces from the first tet reaches them all.
                let mut seen = vec![m[0]];
                let mut k = 0;
                while k < seen.len() {
                    let e = seen[k];
                    for &f in m {
                        if !seen.contains(&f) && shares_face(e, f) {
                            seen.push(f);
                        }
                    }
                    k += 1;
                }
                assert_eq!(seen.len(), m.len(), "{size}: a patch is not face-connected");
            }
            let mean = n as f64 / count as f64;
            println!("size {size}: {count} patches of {n} tets, mean {mean:.2}");
            assert!(
                mean > 0.6 * size as f64 && mean <= 1.5 * size as f64,
                "{size}: {mean}"
            );
            assert_eq!(tet_patches(&mesh, size), patch, "deterministic");
        }
    }
}
