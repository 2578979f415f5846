//! Mesh quality and consistency measures: dihedral angles of tetrahedra, scaled Jacobians of
//! hexahedra, face matching (conformity), boundary faces and duplicate nodes.
//!
//! Angles are in degrees, lengths in the units of the mesh (metres in hytled).

use std::collections::HashMap;

use nalgebra::Vector3;

use super::mesh::{ElementShape, Mesh};

/// Signed volume of the tetrahedron (a, b, c, d): (b-a).((c-a)x(d-a)) / 6, positive for the
/// node order hytled uses (see [`ElementShape`]).
pub fn tet_signed_volume(
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
    d: &Vector3<f64>,
) -> f64 {
    (b - a).dot(&(c - a).cross(&(d - a))) / 6.0
}

/// The six interior dihedral angles (degrees) of a tetrahedron, one per edge, in the edge order
/// 01, 02, 03, 12, 13, 23. The angle at edge (i, j) is pi minus the angle between the outward
/// normals of the two faces sharing that edge (the faces opposite vertices k and l).
/// A degenerate face (zero normal) gives NaN angles.
pub fn tet_dihedral_angles(p: &[Vector3<f64>; 4]) -> [f64; 6] {
    // Normal of the face opposite vertex k, oriented away from vertex k.
    let normal = |k: usize| -> Vector3<f64> {
        let f: Vec<usize> = (0..4).filter(|&i| i != k).collect();
        let n = (p[f[1]] - p[f[0]]).cross(&(p[f[2]] - p[f[0]]));
        if n.dot(&(p[k] - p[f[0]])) > 0.0 {
            -n
        } else {
            n
        }
    };
    let n: [Vector3<f64>; 4] = [normal(0), normal(1), normal(2), normal(3)];
    const EDGES: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
    let mut out = [0.0; 6];
    for (m, &(i, j)) in EDGES.iter().enumerate() {
        // The two faces containing edge (i, j) are those opposite the two other vertices.
        let mut others = (0..4).filter(|&v| v != i && v != j);
        let k = others.next().unwrap();
        let l = others.next().unwrap();
        let c = n[k].dot(&n[l]) / (n[k].norm() * n[l].norm());
        out[m] = 180.0 - c.clamp(-1.0, 1.0).acos().to_degrees();
    }
    out
}

/// The smallest dihedral angle of a tet mesh, degrees, and the element that has it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MinDihedral {
    pub degrees: f64,
    pub element: usize,
}

/// Smallest interior dihedral angle (degrees) over all tetrahedra of a Tet4 mesh, and the
/// element where it occurs. `None` for a hex mesh or a mesh without elements.
/// A regular tetrahedron has 70.53 degrees everywhere; slivers tend to 0.
pub fn min_dihedral_angle(mesh: &Mesh) -> Option<MinDihedral> {
    if mesh.shape != ElementShape::Tet4 {
        return None;
    }
    let mut best: Option<MinDihedral> = None;
    for e in 0..mesh.num_cells() {
        let c = mesh.cell(e);
        let p = [
            mesh.nodes[c[0]],
            mesh.nodes[c[1]],
            mesh.nodes[c[2]],
            mesh.nodes[c[3]],
        ];
        let a = tet_dihedral_angles(&p).iter().fold(f64::INFINITY, |m, &x| {
            if x.is_nan() {
                0.0
            } else {
                m.min(x)
            }
        });
        if best.is_none_or(|b| a < b.degrees) {
            best = Some(MinDihedral {
                degrees: a,
                element: e,
            });
        }
    }
    best
}

/// Smallest scaled Jacobian over all corners of all hexahedra of a Hex8 mesh, and the element
/// where it occurs: at each corner, det[e1, e2, e3] / (|e1| |e2| |e3|) with e1..e3 the three
/// edges leaving that corner in right-handed order (Knupp 2000, "Achieving finite element mesh
/// quality via optimization of the Jacobian matrix norm and associated quantities"). 1 for a
/// cuboid, <= 0 for an inverted or degenerate corner. `None` for a tet mesh or an empty mesh.
pub fn min_scaled_jacobian(mesh: &Mesh) -> Option<(f64, usize)> {
    if mesh.shape != ElementShape::Hex8 {
        return None;
    }
    // For each corner, its three neighbours ordered so that a positive hex gives det > 0.
    const CORNERS: [[usize; 4]; 8] = [
        [0, 1, 3, 4],
        [1, 2, 0, 5],
        [2, 3, 1, 6],
        [3, 0, 2, 7],
        [4, 7, 5, 0],
        [5, 4, 6, 1],
        [6, 5, 7, 2],
        [7, 6, 4, 3],
    ];
    let mut best: Option<(f64, usize)> = None;
    for e in 0..mesh.num_cells() {
        let c = mesh.cell(e);
        let mut worst = f64::INFINITY;
        for k in CORNERS {
            let x0 = mesh.nodes[c[k[0]]];
            let e1 = mesh.nodes[c[k[1]]] - x0;
            let e2 = mesh.nodes[c[k[2]]] - x0;
            let e3 = mesh.nodes[c[k[3]]] - x0;
            let den = e1.norm() * e2.norm() * e3.norm();
            let s = if den > 0.0 {
                e1.dot(&e2.cross(&e3)) / den
            } else {
                0.0
            };
            worst = worst.min(s);
        }
        if best.is_none_or(|(b, _)| worst < b) {
            best = Some((worst, e));
        }
    }
    best
}

/// Faces of one element with outward orientation (right-hand normal points out of a
/// positive-volume element), in the VTK node order of [`ElementShape`].
fn element_faces(shape: ElementShape) -> &'static [&'static [usize]] {
    match shape {
        ElementShape::Tet4 => &[&[0, 2, 1], &[0, 1, 3], &[1, 2, 3], &[0, 3, 2]],
        ElementShape::Hex8 => &[
            &[0, 3, 2, 1],
            &[4, 5, 6, 7],
            &[0, 1, 5, 4],
            &[1, 2, 6, 5],
            &[2, 3, 7, 6],
            &[3, 0, 4, 7],
        ],
    }
}

/// Rotates a polygon's node list so that it starts at its smallest node index.
fn canonical_rotation(f: &[usize]) -> Vec<usize> {
    let i = (0..f.len()).min_by_key(|&i| f[i]).unwrap();
    f[i..].iter().chain(f[..i].iter()).copied().collect()
}

/// Boundary faces of a mesh (faces used by exactly one element), outward oriented, after
/// matching every face of every element by its node set.
///
/// Returns `Err` with a description when the face matching is inconsistent: a face shared by
/// more than two elements, or a face shared by two elements with the same orientation (one of
/// them inverted or the two overlapping). A mesh with hanging nodes or mismatched diagonals
/// still passes this check, but then shows extra boundary faces inside the domain; compare the
/// total boundary area with the area of the geometric surface to catch that.
pub fn boundary_faces(mesh: &Mesh) -> std::result::Result<Vec<Vec<usize>>, String> {
    Ok(boundary_faces_with_cells(mesh)?
        .into_iter()
        .map(|(f, _)| f)
        .collect())
}

/// [`boundary_faces`] with the element each face belongs to: (face, element), sorted by face.
pub fn boundary_faces_with_cells(
    mesh: &Mesh,
) -> std::result::Result<Vec<(Vec<usize>, usize)>, String> {
    let faces = element_faces(mesh.shape);
    // key: sorted node set -> (oriented face of first use, use count, element of first use)
    let mut map: HashMap<Vec<usize>, (Vec<usize>, usize, usize)> = HashMap::new();
    for e in 0..mesh.num_cells() {
        let c = mesh.cell(e);
        for f in faces {
            let oriented: Vec<usize> = f.iter().map(|&i| c[i]).collect();
            let mut key = oriented.clone();
            key.sort_unstable();
            if key.windows(2).any(|w| w[0] == w[1]) {
                return Err(format!(
                    "element {e} has a face with repeated nodes {oriented:?}"
                ));
            }
            match map.get_mut(&key) {
                None => {
                    map.insert(key, (oriented, 1, e));
                }
                Some((first, count, _)) => {
                    *count += 1;
                    if *count > 2 {
                        return Err(format!(
                            "face {key:?} is shared by more than two elements (last: {e})"
                        ));
                    }
                    // The second use must run in the opposite direction.
                    let a = canonical_rotation(first);
                    let mut rev = oriented.clone();
                    rev.reverse();
                    let b = canonical_rotation(&rev);
                    if a != b {
                        return Err(format!(
                            "face {key:?} is shared by two elements with the same orientation \
                             (last: {e}); one is inverted or they overlap"
                        ));
                    }
                }
            }
        }
    }
    let mut out: Vec<(Vec<usize>, usize)> = map
        .into_values()
        .filter(|(_, n, _)| *n == 1)
        .map(|(f, _, e)| (f, e))
        .collect();
    out.sort_unstable();
    Ok(out)
}

/// True when every face of the mesh is used by one element (boundary) or by exactly two
/// elements with opposite orientation (interior). See [`boundary_faces`] for what this does
/// not catch.
pub fn check_conforming(mesh: &Mesh) -> bool {
    boundary_faces(mesh).is_ok()
}

/// Area of a planar polygonal face given by node indices (triangle or quadrilateral; for a
/// warped quadrilateral, the norm of its vector area).
pub fn face_area(mesh: &Mesh, face: &[usize]) -> f64 {
    let x = |i: usize| mesh.nodes[face[i]];
    match face.len() {
        3 => 0.5 * (x(1) - x(0)).cross(&(x(2) - x(0))).norm(),
        4 => 0.5 * (x(2) - x(0)).cross(&(x(3) - x(1))).norm(),
        _ => {
            let mut s = Vector3::zeros();
            for i in 0..face.len() {
                s += x(i).cross(&x((i + 1) % face.len()));
            }
            0.5 * s.norm()
        }
    }
}

/// First pair of distinct nodes closer than `tol` (same length unit as the mesh), if any.
/// Sort-and-sweep along x: O(n log n) for well-spread nodes.
pub fn find_duplicate_nodes(mesh: &Mesh, tol: f64) -> Option<(usize, usize)> {
    let mut order: Vec<usize> = (0..mesh.nodes.len()).collect();
    order.sort_by(|&a, &b| mesh.nodes[a].x.total_cmp(&mesh.nodes[b].x));
    for (k, &i) in order.iter().enumerate() {
        for &j in &order[k + 1..] {
            if mesh.nodes[j].x - mesh.nodes[i].x > tol {
                break;
            }
            if (mesh.nodes[j] - mesh.nodes[i]).norm() <= tol {
                return Some((i.min(j), i.max(j)));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_tet() -> Mesh {
        Mesh {
            nodes: vec![
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(1.0, 0.0, 0.0),
                Vector3::new(0.0, 1.0, 0.0),
                Vector3::new(0.0, 0.0, 1.0),
            ],
            shape: ElementShape::Tet4,
            cells: vec![0, 1, 2, 3],
        }
    }

    #[test]
    fn dihedral_angles_of_known_tets() {
        // Corner tet: three right angles at the edges through the origin, and
        // acos(1/sqrt(3)) = 54.7356 deg at the other three.
        let MinDihedral {
            degrees: a,
            element: e,
        } = min_dihedral_angle(&unit_tet()).unwrap();
        assert_eq!(e, 0);
        assert!((a - (1.0f64 / 3.0f64.sqrt()).acos().to_degrees()).abs() < 1e-10);
        // Regular tet: acos(1/3) = 70.5288 deg on every edge.
        let s = 1.0 / 2.0f64.sqrt();
        let p = [
            Vector3::new(1.0, 0.0, -s),
            Vector3::new(-1.0, 0.0, -s),
            Vector3::new(0.0, 1.0, s),
            Vector3::new(0.0, -1.0, s),
        ];
        for a in tet_dihedral_angles(&p) {
            assert!((a - (1.0f64 / 3.0).acos().to_degrees()).abs() < 1e-10);
        }
        assert!(tet_signed_volume(&p[0], &p[1], &p[2], &p[3]).abs() > 0.0);
    }

    #[test]
    fn faces_and_conformity_of_single_tet() {
        let m = unit_tet();
        assert!(check_conforming(&m));
        let b = boundary_faces(&m).unwrap();
        assert_eq!(b.len(), 4);
        let area: f64 = b.iter().map(|f| face_area(&m, f)).sum();
        assert!((area - (1.5 + 0.5 * 3.0f64.sqrt())).abs() < 1e-12);
        // The same tet twice with the same orientation is not a valid mesh.
        let mut twice = m.clone();
        twice.cells.extend_from_slice(&[0, 1, 2, 3]);
        assert!(!check_conforming(&twice));
        assert_eq!(find_duplicate_nodes(&m, 1e-9), None);
        let mut dup = m.clone();
        dup.nodes.push(Vector3::new(0.0, 1.0, 0.0));
        assert_eq!(find_duplicate_nodes(&dup, 1e-9), Some((2, 4)));
        assert!(min_scaled_jacobian(&m).is_none());
    }

    #[test]
    fn scaled_jacobian_of_unit_cube_is_one() {
        let nodes: Vec<Vector3<f64>> = [
            (0., 0., 0.),
            (1., 0., 0.),
            (1., 1., 0.),
            (0., 1., 0.),
            (0., 0., 1.),
            (1., 0., 1.),
            (1., 1., 1.),
            (0., 1., 1.),
        ]
        .iter()
        .map(|&(x, y, z)| Vector3::new(x, y, z))
        .collect();
        let m = Mesh {
            nodes,
            shape: ElementShape::Hex8,
            cells: (0..8).collect(),
        };
        let (s, _) = min_scaled_jacobian(&m).unwrap();
        assert!((s - 1.0).abs() < 1e-14);
        assert!(min_dihedral_angle(&m).is_none());
        let b = boundary_faces(&m).unwrap();
        assert_eq!(b.len(), 6);
        let area: f64 = b.iter().map(|f| face_area(&m, f)).sum();
        assert!((area - 6.0).abs() < 1e-14);
    }
}
