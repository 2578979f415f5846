//! Coupled discretization from mixed inputs: a mesh file that is the FE layer (a shell whose
//! inner surface bounds the cavity) and a node cloud that fills the cavity. The interior is
//! integrated on the Delaunay tets of the interface and cloud nodes that lie in the cavity.

use nalgebra::Vector3;

use super::{assemble, CellRole, CoupledBuild, CoupledSettings, NodeRole, Regions};
use crate::geometry::quality::{boundary_faces, tet_signed_volume};
use crate::geometry::{ElementShape, Mesh};
use crate::{Error, InputKind, Result};

/// Largest accepted relative mismatch between the interior tets' volume and the volume the
/// FE layer's inner surface encloses.
const MAX_VOLUME_MISMATCH: f64 = 0.02;

/// Boundary surface components of a mesh as triangles (quads split), grouped by connectivity.
fn surface_components(mesh: &Mesh) -> Result<Vec<Vec<[usize; 3]>>> {
    let faces = boundary_faces(mesh)
        .map_err(|e| Error::input(InputKind::Mesh, format!("FE layer mesh: {e}")))?;
    // Union-find over vertices.
    let mut parent: Vec<usize> = (0..mesh.nodes.len()).collect();
    fn root(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    for f in &faces {
        for w in f.windows(2) {
            let (a, b) = (root(&mut parent, w[0]), root(&mut parent, w[1]));
            if a != b {
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<[usize; 3]>> = Default::default();
    for f in &faces {
        let r = root(&mut parent, f[0]);
        let g = groups.entry(r).or_default();
        g.push([f[0], f[1], f[2]]);
        if f.len() == 4 {
            g.push([f[0], f[2], f[3]]);
        }
    }
    Ok(groups.into_values().collect())
}

/// Winding number of the closed triangulated surface `tris` around `x` (+-1 inside, 0 outside;
/// Van Oosterom & Strackee solid angles).
fn winding(nodes: &[Vector3<f64>], tris: &[[usize; 3]], x: &Vector3<f64>) -> f64 {
    let mut omega = 0.0;
    for t in tris {
        let (a, b, c) = (nodes[t[0]] - x, nodes[t[1]] - x, nodes[t[2]] - x);
        let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
        let num = a.dot(&b.cross(&c));
        let den = la * lb * lc + a.dot(&b) * lc + a.dot(&c) * lb + b.dot(&c) * la;
        omega += 2.0 * num.atan2(den);
    }
    omega / (4.0 * std::f64::consts::PI)
}

/// Volume enclosed by a closed triangulated surface, m^3 (divergence theorem; sign dropped).
fn enclosed_volume(nodes: &[Vector3<f64>], tris: &[[usize; 3]]) -> f64 {
    tris.iter()
        .map(|t| nodes[t[0]].dot(&nodes[t[1]].cross(&nodes[t[2]])) / 6.0)
        .sum::<f64>()
        .abs()
}

fn diagonal(nodes: &[Vector3<f64>], tris: &[[usize; 3]]) -> f64 {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for &i in tris.iter().flatten() {
        lo = lo.inf(&nodes[i]);
        hi = hi.sup(&nodes[i]);
    }
    (hi - lo).norm()
}

/// Distance (m) from `x` to the triangle `a b c` (closest point by Voronoi regions; Ericson,
/// Real-Time Collision Detection, sect. 5.1.5).
fn triangle_distance(
    x: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> f64 {
    let (ab, ac, ap) = (b - a, c - a, x - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.norm();
    }
    let bp = x - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.norm();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (x - (a + ab * (d1 / (d1 - d3)))).norm();
    }
    let cp = x - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.norm();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (x - (a + ac * (d2 / (d2 - d6)))).norm();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (x - (b + (c - b) * w)).norm();
    }
    let denom = 1.0 / (va + vb + vc);
    (x - (a + ab * (vb * denom) + ac * (vc * denom))).norm()
}

/// What the mixed build measured, for the report.
#[derive(Debug, Clone)]
pub struct MixedReport {
    /// Volume the FE layer's inner surface encloses, m^3.
    pub cavity_volume: f64,
    /// Volume of the interior integration tets, m^3.
    pub interior_volume: f64,
    /// Cloud nodes dropped because they coincide with FE-layer nodes.
    pub duplicates: usize,
    /// Cloud nodes dropped because they lie outside the cavity (in or beyond the FE layer).
    pub outside: usize,
    /// Cloud nodes dropped because they lie within `min_gap` of the inner surface.
    pub near_surface: usize,
}

/// Tetrahedralizes a point set (m): the Delaunay mesher a mixed scene uses.
pub type Delaunay = dyn Fn(&[Vector3<f64>]) -> Result<Vec<[usize; 4]>>;

/// Builds the coupled discretization from the FE layer `fe` (a shell) and the `cloud` (m)
/// that fills its cavity. `delaunay` tetrahedralizes a point set. Cloud nodes closer than
/// `min_gap` (m) to the inner surface are dropped: a generated cloud knows nothing of the
/// surface, and a node just inside it makes flat interior tets (0 keeps every node).
pub fn build(
    fe: Mesh,
    cloud: &[Vector3<f64>],
    min_gap: f64,
    s: &CoupledSettings,
    delaunay: &Delaunay,
) -> Result<(CoupledBuild, MixedReport)> {
    super::check_shape(s, fe.shape)?;
    let comps = surface_components(&fe)?;
    if comps.len() < 2 {
        return Err(Error::input(InputKind::Mesh,
            "coupled with a node cloud: the FE-layer mesh has a single boundary surface, so it has no cavity for the cloud; \
             give a shell mesh (the FE layer) whose inner surface bounds the cloud, or drop cloud = 'file' to split the mesh into layers",
        ));
    }
    let outer = (0..comps.len())
        .max_by(|&a, &b| diagonal(&fe.nodes, &comps[a]).total_cmp(&diagonal(&fe.nodes, &comps[b])))
        .unwrap_or(0);
    let inner: Vec<[usize; 3]> = comps
        .iter()
        .enumerate()
        .filter(|(k, _)| *k != outer)
        .flat_map(|(_, c)| c.iter().cloned())
        .collect();
    let mut is_iface = vec![false; fe.nodes.len()];
    for &i in inner.iter().flatten() {
        is_iface[i] = true;
    }
    let iface: Vec<usize> = (0..fe.nodes.len()).filter(|&i| is_iface[i]).collect();
    let diag = diagonal(&fe.nodes, &comps[outer]);
    let tol = 1e-9 * diag;

    // Cloud nodes: drop those on FE nodes (a cloud may repeat the interface) and those outside
    // the cavity.
    let fe_tree = {
        let pts: Vec<[f64; 3]> = fe.nodes.iter().map(|p| [p.x, p.y, p.z]).collect();
        kiddo::ImmutableKdTree::<f64, 3>::new_from_slice(&pts).map_err(|e| {
            Error::input(
                InputKind::Discretization,
                format!("cannot build the FE-node search tree: {e:?}"),
            )
        })?
    };
    let (mut duplicates, mut outside, mut near_surface) = (0, 0, 0);
    let mut kept = Vec::new();
    for x in cloud {
        let nn = fe_tree
            .query(&[x.x, x.y, x.z])
            .nearest_n::<kiddo::SquaredEuclidean<f64>>(std::num::NonZero::<usize>::MIN)
            .execute();
        if nn.first().is_some_and(|r| r.distance.sqrt() <= tol) {
            duplicates += 1;
        } else if winding(&fe.nodes, &inner, x).abs() < 0.5 {
            outside += 1;
        } else if min_gap > 0.0
            && inner.iter().any(|t| {
                triangle_distance(x, &fe.nodes[t[0]], &fe.nodes[t[1]], &fe.nodes[t[2]]) < min_gap
            })
        {
            near_surface += 1;
        } else {
            kept.push(*x);
        }
    }
    if kept.is_empty() {
        return Err(Error::input(InputKind::Discretization,
            "coupled: no cloud node lies inside the FE layer's cavity; check the cloud's units and position",
        ));
    }
    // Delaunay of interface + cloud nodes; tets whose centroid is in the cavity.
    let mut pts: Vec<Vector3<f64>> = iface.iter().map(|&i| fe.nodes[i]).collect();
    pts.extend_from_slice(&kept);
    let tets = delaunay(&pts)?;
    let nf = fe.nodes.len();
    let global = |k: usize| {
        if k < iface.len() {
            iface[k]
        } else {
            nf + k - iface.len()
        }
    };
    let mut nodes = fe.nodes.clone();
    nodes.extend_from_slice(&kept);
    let mut cells = Vec::new();
    let mut interior_volume = 0.0;
    for t in &tets {
        let g = t.map(global);
        let c = (nodes[g[0]] + nodes[g[1]] + nodes[g[2]] + nodes[g[3]]) / 4.0;
        if winding(&fe.nodes, &inner, &c).abs() < 0.5 {
            continue;
        }
        let mut g = g;
        let mut v = tet_signed_volume(&nodes[g[0]], &nodes[g[1]], &nodes[g[2]], &nodes[g[3]]);
        if v < 0.0 {
            g.swap(2, 3);
            v = -v;
        }
        if v <= 1e-14 * diag.powi(3) {
            continue; // flat Delaunay sliver of cospherical nodes: no volume to integrate
        }
        interior_volume += v;
        cells.extend(g);
    }
    let cavity_volume = enclosed_volume(&fe.nodes, &inner);
    let mismatch = (interior_volume - cavity_volume).abs() / cavity_volume.max(f64::MIN_POSITIVE);
    if mismatch > MAX_VOLUME_MISMATCH {
        return Err(Error::input(InputKind::Discretization, format!(
            "coupled: the interior tets fill {sci_interior_volume:.6e} m^3 but the FE layer's inner surface encloses \
             {sci_cavity_volume:.6e} m^3 ({:.2} % apart, more than {:.0} %): the cloud and the FE layer leave gaps or overlap; \
             the cloud must fill the cavity up to the inner surface (whose nodes are added to it)",
            100.0 * mismatch,
            100.0 * MAX_VOLUME_MISMATCH
        , sci_interior_volume = crate::error::Sci(interior_volume), sci_cavity_volume = crate::error::Sci(cavity_volume))));
    }
    // Cloud nodes no interior tet uses carry no mass: drop them and renumber.
    let mut used = vec![false; nodes.len()];
    for &i in &cells {
        used[i] = true;
    }
    let mut map: Vec<usize> = (0..nf).collect();
    let mut compact = fe.nodes.clone();
    for k in nf..nodes.len() {
        if used[k] {
            map.push(compact.len());
            compact.push(nodes[k]);
        } else {
            map.push(usize::MAX);
            outside += 1;
        }
    }
    let cells: Vec<usize> = cells.iter().map(|&i| map[i]).collect();
    let n = compact.len();
    let node: Vec<NodeRole> = (0..n)
        .map(|i| match (i < nf, i < nf && is_iface[i]) {
            (true, true) => NodeRole::Interface,
            (true, false) => NodeRole::Fe,
            _ => NodeRole::Meshless,
        })
        .collect();
    let cell: Vec<CellRole> = (0..fe.num_cells())
        .map(|e| {
            if fe.cell(e).iter().any(|&i| is_iface[i]) {
                CellRole::Transition
            } else {
                CellRole::Fe
            }
        })
        .collect();
    let fe_mesh = Mesh {
        nodes: compact.clone(),
        shape: fe.shape,
        cells: fe.cells.clone(),
    };
    let interior = Mesh {
        nodes: compact.clone(),
        shape: ElementShape::Tet4,
        cells,
    };
    let warnings = vec![format!(
        "coupled interior: tets {interior_volume:.6e} m^3 vs cavity {cavity_volume:.6e} m^3 ({:+.4} %); \
         {duplicates} cloud node(s) on FE nodes, {outside} outside the cavity and {near_surface} within \
         {min_gap:.3e} m of its surface dropped",
        100.0 * (interior_volume - cavity_volume) / cavity_volume.max(f64::MIN_POSITIVE)
    )];
    let b = assemble(
        compact,
        fe_mesh,
        interior,
        Regions {
            cell,
            node,
            max_depth: 0,
        },
        s,
        warnings,
    )?;
    Ok((
        b,
        MixedReport {
            cavity_volume,
            interior_volume,
            duplicates,
            outside,
            near_surface,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_distance_matches_a_dense_sampling() {
        let (a, b, c) = (
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.2, 0.0),
            Vector3::new(0.3, 0.9, 0.1),
        );
        let n = 400;
        for x in [
            Vector3::new(0.4, 0.3, 0.5),   // above the face
            Vector3::new(-0.5, -0.2, 0.1), // near vertex a
            Vector3::new(1.5, 0.0, 0.0),   // near vertex b
            Vector3::new(0.2, 1.4, -0.3),  // near vertex c
            Vector3::new(0.5, -0.4, 0.2),  // near edge ab
            Vector3::new(-0.3, 0.5, 0.0),  // near edge ac
            Vector3::new(0.9, 0.8, 0.3),   // near edge bc
        ] {
            let mut best = f64::INFINITY;
            for i in 0..=n {
                for j in 0..=(n - i) {
                    let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                    best = best.min((x - (a + (b - a) * u + (c - a) * v)).norm());
                }
            }
            let d = triangle_distance(&x, &a, &b, &c);
            assert!(
                d <= best + 1e-12 && best - d < 5e-3,
                "{x:?}: {d} vs sampled {best}"
            );
        }
    }

    #[test]
    fn winding_and_volume_of_a_cube_surface() {
        let m = crate::geometry::shapes::box_hex(
            Vector3::zeros(),
            Vector3::new(1.0, 2.0, 3.0),
            [2, 2, 2],
        )
        .unwrap();
        let comps = surface_components(&m).unwrap();
        assert_eq!(comps.len(), 1);
        let v = enclosed_volume(&m.nodes, &comps[0]);
        assert!((v - 6.0).abs() < 1e-12, "{v}");
        assert!(
            (winding(&m.nodes, &comps[0], &Vector3::new(0.5, 0.5, 0.5)).abs() - 1.0).abs() < 1e-9
        );
        assert!(winding(&m.nodes, &comps[0], &Vector3::new(1.5, 0.5, 0.5)).abs() < 1e-9);
    }
}
