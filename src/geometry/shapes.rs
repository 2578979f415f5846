//! Structured meshes of boxes and circular cylinders, built by extruding a 2D quadrilateral
//! mesh of the cross-section along z.
//!
//! * Hex8 meshes: each quad of each layer becomes one hexahedron.
//! * Tet4 meshes: each quad is cut into two triangles (along its shorter diagonal), each
//!   triangle is extruded into a prism, and each prism is cut into three tetrahedra by the
//!   "smallest global vertex index" rule of Dompierre, Labbe, Vallet and Camarero (1999), "How
//!   to subdivide pyramids, prisms and hexahedra into tetrahedra", Proc. 8th International
//!   Meshing Roundtable. The rule picks every quadrilateral face diagonal from the node numbers
//!   alone, so neighbouring prisms cut their shared face the same way and the mesh conforms.
//!
//! Coordinates are in metres. Node order follows [`ElementShape`]: hex bottom face 0-1-2-3
//! counter-clockwise seen from +z, top 4-7 above it; tets with positive volume.
//!
//! Nodes are numbered layer by layer: node `k * n2d + i` is cross-section node `i` at height
//! `z_k`, so a cross-section's `n2d` nodes repeat on `n_axial + 1` layers.

use nalgebra::{Vector2, Vector3};

use super::mesh::{check_mesh_memory, ElementShape, Mesh};
use crate::{Error, InputKind, Result};

/// Planar quadrilateral mesh: nodes (x, y) and quads counter-clockwise seen from +z.
struct QuadMesh2 {
    nodes: Vec<Vector2<f64>>,
    quads: Vec<[usize; 4]>,
}

/// How much the sides of the inner block of the cylinder's O-grid bulge outward: the inner
/// block maps the square [-1, 1]^2 by (1 - w) * square + w * disc, with the disc the
/// elliptical-grid map onto the circle through the square's corners. 0 keeps straight sides.
/// 0.3 raised the smallest scaled Jacobian of the hexes from 0.71 (straight) to 0.83-0.85 for
/// n_inner = 4..8 without lowering the tet dihedral angles.
const OGRID_ROUNDING: f64 = 0.3;

/// Half-width of the cylinder's inner block as a fraction of the radius. Below 0.5 so that
/// the outer blocks are not thinnest at the block corners: with n_inner = 2 n_radial, 0.45
/// gives a smallest edge of 0.091 R against 0.073 R at 0.5 (n_inner = 8), and smallest tet
/// dihedral angles of 19-20 degrees against 17.5.
const OGRID_INNER_HALF_WIDTH: f64 = 0.45;

/// Hexahedral mesh of the box [min, max] with `div` = [nx, ny, nz] cells along x, y, z.
/// (nx+1)(ny+1)(nz+1) nodes, nx*ny*nz elements.
///
/// Errors when a division is zero or when `min` is not strictly below `max` on every axis.
pub fn box_hex(min: Vector3<f64>, max: Vector3<f64>, div: [usize; 3]) -> Result<Mesh> {
    check_box_memory(div, ElementShape::Hex8)?;
    let (q, z) = box_section(min, max, div)?;
    Ok(extrude_hex(&q, &z))
}

/// Tetrahedral mesh of the box [min, max] with the structure of [`box_hex`]: each of the
/// nx*ny*nz cells is cut into 2 prisms and each prism into 3 tetrahedra (6 nx ny nz elements,
/// the same (nx+1)(ny+1)(nz+1) nodes). See the module documentation for the subdivision rule.
pub fn box_tet(min: Vector3<f64>, max: Vector3<f64>, div: [usize; 3]) -> Result<Mesh> {
    check_box_memory(div, ElementShape::Tet4)?;
    let (q, z) = box_section(min, max, div)?;
    Ok(extrude_tet(&q, &z))
}

/// Hexahedral mesh of the circular cylinder of radius `radius` (m) and height `height` (m),
/// axis z, base at z = 0, top at z = height, centred on x = y = 0.
///
/// The cross-section is an O-grid ("butterfly") mesh: a central block of n_inner x n_inner
/// cells (half-width 0.45 * radius at the corners, sides slightly rounded outward) and four outer blocks of
/// n_inner x n_radial cells joining it to the circle. The circle carries 4 * n_inner nodes,
/// equally spaced in angle, exactly on the radius, one of them at (radius, 0). The cross-section
/// has (n_inner + 1)^2 + 4 n_inner n_radial nodes and n_inner^2 + 4 n_inner n_radial quads,
/// repeated on n_axial + 1 layers: n_inner = 8, n_radial = 4, n_axial = 20 gives 4,389 nodes
/// and 3,840 elements.
///
/// The mesh fills the polygonal prism whose base is the 4 n_inner-gon inscribed in the circle.
///
/// Errors when a count is zero or when the radius or height is not positive and finite.
pub fn cylinder_hex(
    radius: f64,
    height: f64,
    n_inner: usize,
    n_radial: usize,
    n_axial: usize,
) -> Result<Mesh> {
    check_cylinder_memory([n_inner, n_radial, n_axial], ElementShape::Hex8)?;
    let (q, z) = cylinder_section(
        radius,
        height,
        n_inner,
        n_radial,
        n_axial,
        OGRID_INNER_HALF_WIDTH,
        OGRID_ROUNDING,
    )?;
    Ok(extrude_hex(&q, &z))
}

/// Tetrahedral mesh of the cylinder of [`cylinder_hex`] with the same nodes: each quad of the
/// cross-section is cut into 2 triangles and each extruded triangle into 3 tetrahedra
/// (6 tets per hex of [`cylinder_hex`]). See the module documentation for the subdivision rule.
pub fn cylinder_tet(
    radius: f64,
    height: f64,
    n_inner: usize,
    n_radial: usize,
    n_axial: usize,
) -> Result<Mesh> {
    check_cylinder_memory([n_inner, n_radial, n_axial], ElementShape::Tet4)?;
    let (q, z) = cylinder_section(
        radius,
        height,
        n_inner,
        n_radial,
        n_axial,
        OGRID_INNER_HALF_WIDTH,
        OGRID_ROUNDING,
    )?;
    Ok(extrude_tet(&q, &z))
}

/// [`check_mesh_memory`] for [`box_hex`] / [`box_tet`] with divisions `div`.
fn check_box_memory(div: [usize; 3], shape: ElementShape) -> Result<()> {
    let (nodes, cells) = box_counts(div, shape);
    check_mesh_memory(nodes, cells, shape)
}

/// [`check_mesh_memory`] for [`cylinder_hex`] / [`cylinder_tet`] with counts [n_inner,
/// n_radial, n_axial].
fn check_cylinder_memory(counts: [usize; 3], shape: ElementShape) -> Result<()> {
    let (nodes, cells) = cylinder_counts(counts, shape);
    check_mesh_memory(nodes, cells, shape)
}

/// Nodes and elements of [`box_hex`] / [`box_tet`] with divisions `div`, before the mesh is
/// made (f64: any divisions, no overflow).
pub fn box_counts(div: [usize; 3], shape: ElementShape) -> (f64, f64) {
    let d = div.map(|n| n as f64);
    let nodes = (d[0] + 1.0) * (d[1] + 1.0) * (d[2] + 1.0);
    (nodes, d[0] * d[1] * d[2] * tets_per_hex(shape))
}

/// Nodes and elements of [`cylinder_hex`] / [`cylinder_tet`] with counts [n_inner, n_radial,
/// n_axial], before the mesh is made.
pub fn cylinder_counts(counts: [usize; 3], shape: ElementShape) -> (f64, f64) {
    let [n, m, a] = counts.map(|k| k as f64);
    let nodes = ((n + 1.0).powi(2) + 4.0 * n * m) * (a + 1.0);
    (nodes, (n * n + 4.0 * n * m) * a * tets_per_hex(shape))
}

/// Elements per hexahedral cell of the structured meshes.
fn tets_per_hex(shape: ElementShape) -> f64 {
    match shape {
        ElementShape::Hex8 => 1.0,
        ElementShape::Tet4 => 6.0,
    }
}

/// Checks that box corners are finite with min < max on every axis (m).
pub(crate) fn check_box(min: Vector3<f64>, max: Vector3<f64>) -> Result<()> {
    for a in 0..3 {
        if !(min[a].is_finite() && max[a].is_finite() && min[a] < max[a]) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                "box corners min = [{}, {}, {}] m and max = [{}, {}, {}] m must be finite with \
                 min < max on every axis",
                min.x, min.y, min.z, max.x, max.y, max.z
            ),
            ));
        }
    }
    Ok(())
}

/// Cross-section and layer heights of the box.
fn box_section(
    min: Vector3<f64>,
    max: Vector3<f64>,
    div: [usize; 3],
) -> Result<(QuadMesh2, Vec<f64>)> {
    if div.contains(&0) {
        return Err(Error::input(
            InputKind::Value,
            format!("box mesh divisions {div:?} must all be at least 1"),
        ));
    }
    check_box(min, max)?;
    let xs = linspace(min.x, max.x, div[0]);
    let ys = linspace(min.y, max.y, div[1]);
    let nx = div[0] + 1;
    let mut nodes = Vec::with_capacity(nx * (div[1] + 1));
    for &y in &ys {
        for &x in &xs {
            nodes.push(Vector2::new(x, y));
        }
    }
    let mut quads = Vec::with_capacity(div[0] * div[1]);
    for j in 0..div[1] {
        for i in 0..div[0] {
            let n0 = j * nx + i;
            quads.push([n0, n0 + 1, n0 + 1 + nx, n0 + nx]);
        }
    }
    Ok((QuadMesh2 { nodes, quads }, linspace(min.z, max.z, div[2])))
}

/// `n + 1` equally spaced values from `a` to `b`, the last exactly `b`.
fn linspace(a: f64, b: f64, n: usize) -> Vec<f64> {
    (0..=n)
        .map(|k| {
            if k == n {
                b
            } else {
                a + (b - a) * (k as f64 / n as f64)
            }
        })
        .collect()
}

/// O-grid cross-section of the cylinder (see [`cylinder_hex`]) and its layer heights.
fn cylinder_section(
    radius: f64,
    height: f64,
    n_inner: usize,
    n_radial: usize,
    n_axial: usize,
    inner_half_width: f64,
    rounding: f64,
) -> Result<(QuadMesh2, Vec<f64>)> {
    if !(radius.is_finite() && radius > 0.0 && height.is_finite() && height > 0.0) {
        return Err(Error::input(
            InputKind::Value,
            format!("cylinder radius {radius} m and height {height} m must be positive and finite"),
        ));
    }
    if n_inner == 0 || n_radial == 0 || n_axial == 0 {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "cylinder mesh counts n_inner = {n_inner}, n_radial = {n_radial}, n_axial = \
             {n_axial} must all be at least 1"
            ),
        ));
    }
    let n = n_inner;
    let m = n_radial;
    let a = inner_half_width * radius;
    let w = rounding;
    // Circle nodes sit at angles theta_t = -pi/4 + 2 pi t / (4n) + phi, t = 0 .. 4n-1, with
    // t = 0 at the inner block's corner (n, 0). For even n, t = n/2 lies at angle 0; for odd n
    // the whole section turns by phi = pi / (4n) so that t = (n-1)/2 does. Written as
    // theta_t = pi * (2t - n + odd) / (4n) so that angle 0 comes out exactly.
    let odd = (n % 2) as i64;
    let phi = odd as f64 * std::f64::consts::PI / (4 * n) as f64;
    let (sp, cp) = phi.sin_cos();
    let rotate = |p: Vector2<f64>| Vector2::new(cp * p.x - sp * p.y, sp * p.x + cp * p.y);
    // Inner block map of (xi, eta) in [-1, 1]^2.
    let inner = |xi: f64, eta: f64| -> Vector2<f64> {
        let s2 = std::f64::consts::SQRT_2;
        let disc = Vector2::new(
            xi * (1.0 - 0.5 * eta * eta).sqrt(),
            eta * (1.0 - 0.5 * xi * xi).sqrt(),
        ) * s2;
        rotate((Vector2::new(xi, eta) * (1.0 - w) + disc * w) * a)
    };
    let ni = n + 1;
    let mut nodes = Vec::with_capacity(ni * ni + 4 * n * m);
    for j in 0..=n {
        for i in 0..=n {
            let xi = -1.0 + 2.0 * i as f64 / n as f64;
            let eta = -1.0 + 2.0 * j as f64 / n as f64;
            nodes.push(inner(xi, eta));
        }
    }
    // Inner block boundary, counter-clockwise from corner (i, j) = (n, 0).
    let ring0: Vec<usize> = (0..4 * n)
        .map(|t| {
            let (i, j) = match t / n {
                0 => (n, t),
                1 => (n - (t - n), n),
                2 => (0, n - (t - 2 * n)),
                _ => (t - 3 * n, 0),
            };
            j * ni + i
        })
        .collect();
    // Ring r (1..=m) node t: linear between the block boundary and the circle.
    let ring_node = |r: usize, t: usize| -> usize {
        if r == 0 {
            ring0[t % (4 * n)]
        } else {
            ni * ni + (r - 1) * 4 * n + t % (4 * n)
        }
    };
    for r in 1..=m {
        for t in 0..4 * n {
            let num = 2 * t as i64 - n as i64 + odd;
            let theta = std::f64::consts::PI * num as f64 / (4 * n) as f64;
            let circle = Vector2::new(radius * theta.cos(), radius * theta.sin());
            if r == m {
                nodes.push(circle);
            } else {
                let p = nodes[ring0[t]];
                let s = r as f64 / m as f64;
                nodes.push(p + (circle - p) * s);
            }
        }
    }
    let mut quads = Vec::with_capacity(n * n + 4 * n * m);
    for j in 0..n {
        for i in 0..n {
            let n0 = j * ni + i;
            quads.push([n0, n0 + 1, n0 + 1 + ni, n0 + ni]);
        }
    }
    for r in 0..m {
        for t in 0..4 * n {
            // radial direction then tangential (counter-clockwise) direction: e_r x e_theta = +z
            quads.push([
                ring_node(r, t),
                ring_node(r + 1, t),
                ring_node(r + 1, t + 1),
                ring_node(r, t + 1),
            ]);
        }
    }
    Ok((QuadMesh2 { nodes, quads }, linspace(0.0, height, n_axial)))
}

/// Stacks the cross-section on the layers `z` and makes one hexahedron per quad and layer.
fn extrude_hex(q: &QuadMesh2, z: &[f64]) -> Mesh {
    let n2 = q.nodes.len();
    let nodes = extrude_nodes(q, z);
    let mut cells = Vec::with_capacity(8 * q.quads.len() * (z.len() - 1));
    for k in 0..z.len() - 1 {
        for quad in &q.quads {
            let b = k * n2;
            let t = (k + 1) * n2;
            cells.extend(quad.iter().map(|&i| b + i));
            cells.extend(quad.iter().map(|&i| t + i));
        }
    }
    Mesh {
        nodes,
        shape: ElementShape::Hex8,
        cells,
    }
}

fn extrude_nodes(q: &QuadMesh2, z: &[f64]) -> Vec<Vector3<f64>> {
    let mut nodes = Vec::with_capacity(q.nodes.len() * z.len());
    for &zk in z {
        nodes.extend(q.nodes.iter().map(|p| Vector3::new(p.x, p.y, zk)));
    }
    nodes
}

/// Stacks the cross-section on the layers `z`; each quad is cut into two triangles along its
/// shorter diagonal (diagonal 0-2 on ties), each triangle extruded into a prism per layer and
/// each prism cut into three tetrahedra by [`split_prism`].
fn extrude_tet(q: &QuadMesh2, z: &[f64]) -> Mesh {
    let n2 = q.nodes.len();
    let nodes = extrude_nodes(q, z);
    let mut tris: Vec<[usize; 3]> = Vec::with_capacity(2 * q.quads.len());
    for &[a, b, c, d] in &q.quads {
        let d02 = (q.nodes[c] - q.nodes[a]).norm();
        let d13 = (q.nodes[d] - q.nodes[b]).norm();
        if d13 < d02 * (1.0 - 1e-12) {
            tris.push([a, b, d]);
            tris.push([b, c, d]);
        } else {
            tris.push([a, b, c]);
            tris.push([a, c, d]);
        }
    }
    let mut cells = Vec::with_capacity(12 * tris.len() * (z.len() - 1));
    for k in 0..z.len() - 1 {
        for tri in &tris {
            let bottom = tri.map(|i| k * n2 + i);
            let top = tri.map(|i| (k + 1) * n2 + i);
            for mut tet in split_prism(bottom, top) {
                let v = |i: usize| nodes[tet[i]];
                let vol = (v(1) - v(0)).dot(&(v(2) - v(0)).cross(&(v(3) - v(0))));
                if vol < 0.0 {
                    tet.swap(2, 3);
                }
                cells.extend_from_slice(&tet);
            }
        }
    }
    Mesh {
        nodes,
        shape: ElementShape::Tet4,
        cells,
    }
}

/// Cuts the prism with bottom triangle `bottom` and top triangle `top` (`top[i]` above
/// `bottom[i]`) into three tetrahedra by Dompierre et al. (1999), Table 2 / Figure 6: the prism
/// is rotated or mirrored so that its smallest global node index is V1 (V1..V3 one triangle,
/// V4..V6 the nodes across from them); then if min(V2, V6) < min(V3, V5) the tets are
/// [V1,V2,V3,V6], [V1,V2,V6,V5], [V1,V5,V6,V4], otherwise [V1,V2,V3,V5], [V1,V5,V3,V6],
/// [V1,V5,V6,V4]. Every quadrilateral face is thus cut along the diagonal through its smallest
/// node, whichever prism it belongs to. The tets are not yet oriented.
fn split_prism(bottom: [usize; 3], top: [usize; 3]) -> [[usize; 4]; 3] {
    let p = [bottom[0], bottom[1], bottom[2], top[0], top[1], top[2]];
    // Vertex permutations taking each of the 6 vertices to V1 (0-based positions in `p`).
    const PERM: [[usize; 6]; 6] = [
        [0, 1, 2, 3, 4, 5],
        [1, 2, 0, 4, 5, 3],
        [2, 0, 1, 5, 3, 4],
        [3, 5, 4, 0, 2, 1],
        [4, 3, 5, 1, 0, 2],
        [5, 4, 3, 2, 1, 0],
    ];
    let imin = (0..6).min_by_key(|&i| p[i]).unwrap();
    let v = PERM[imin].map(|i| p[i]);
    let [v1, v2, v3, v4, v5, v6] = v;
    if v2.min(v6) < v3.min(v5) {
        [[v1, v2, v3, v6], [v1, v2, v6, v5], [v1, v5, v6, v4]]
    } else {
        [[v1, v2, v3, v5], [v1, v5, v3, v6], [v1, v5, v6, v4]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::quality::{
        boundary_faces, face_area, find_duplicate_nodes, min_dihedral_angle, min_scaled_jacobian,
        tet_signed_volume, MinDihedral,
    };
    use std::f64::consts::PI;

    /// Element volumes (m^3): tets exactly, hexes by the element's own 2x2x2 Gauss volume
    /// (exact for trilinear hexes); an inverted hex yields its non-positive volume.
    fn volumes(mesh: &Mesh) -> Vec<f64> {
        (0..mesh.num_cells())
            .map(|e| {
                let c = mesh.cell(e);
                let x = |i: usize| mesh.nodes[c[i]];
                match mesh.shape {
                    ElementShape::Tet4 => tet_signed_volume(&x(0), &x(1), &x(2), &x(3)),
                    ElementShape::Hex8 => {
                        let xs: [Vector3<f64>; 8] = std::array::from_fn(x);
                        crate::fe::hex8::Hex8Reference::new(&xs).map_or_else(|v| v, |h| h.volume)
                    }
                }
            })
            .collect()
    }

    /// Checks shared by every mesh: all nodes used, no duplicates, positive volumes summing to
    /// `volume`, consistent face matching, boundary area equal to `area` (which rules out
    /// mismatched faces inside the domain). Returns (min volume, boundary faces).
    fn check_mesh(mesh: &Mesh, volume: f64, area: f64) {
        let mut used = vec![false; mesh.nodes.len()];
        for &i in &mesh.cells {
            used[i] = true;
        }
        assert!(used.iter().all(|&u| u), "unused nodes");
        let (lo, hi) = mesh.bounding_box();
        let size = (hi - lo).norm();
        assert_eq!(find_duplicate_nodes(mesh, 1e-9 * size), None);
        let v = volumes(mesh);
        let vmin = v.iter().cloned().fold(f64::INFINITY, f64::min);
        let vmean = volume / mesh.num_cells() as f64;
        assert!(vmin > 1e-3 * vmean, "element volume {vmin} vs mean {vmean}");
        let total: f64 = v.iter().sum();
        assert!(
            ((total - volume) / volume).abs() < 1e-12,
            "volume {total} vs {volume}"
        );
        let b = boundary_faces(mesh).expect("face matching");
        let a: f64 = b.iter().map(|f| face_area(mesh, f)).sum();
        assert!(
            ((a - area) / area).abs() < 1e-12,
            "boundary area {a} vs {area}"
        );
        if mesh.shape == ElementShape::Hex8 {
            let (s, _) = min_scaled_jacobian(mesh).unwrap();
            assert!(s > 0.0);
        }
    }

    /// Area (m^2) and perimeter (m) of the regular n-gon inscribed in a circle of radius r.
    fn polygon(r: f64, n: usize) -> (f64, f64) {
        let n = n as f64;
        (
            0.5 * n * r * r * (2.0 * PI / n).sin(),
            2.0 * n * r * (PI / n).sin(),
        )
    }

    #[test]
    fn box_counts_volume_and_faces() {
        let lo = Vector3::new(-0.01, 0.02, 0.0);
        let hi = Vector3::new(0.03, 0.05, 0.1);
        let d = hi - lo;
        let vol = d.x * d.y * d.z;
        let area = 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
        let h = box_hex(lo, hi, [4, 3, 5]).unwrap();
        assert_eq!(h.nodes.len(), 5 * 4 * 6);
        assert_eq!(h.num_cells(), 60);
        check_mesh(&h, vol, area);
        assert_eq!(h.bounding_box(), (lo, hi));
        let (s, _) = min_scaled_jacobian(&h).unwrap();
        assert!((s - 1.0).abs() < 1e-12);
        let t = box_tet(lo, hi, [4, 3, 5]).unwrap();
        assert_eq!(t.nodes.len(), 5 * 4 * 6);
        assert_eq!(t.num_cells(), 360);
        check_mesh(&t, vol, area);
        let a = min_dihedral_angle(&t).unwrap().degrees;
        assert!(a > 20.0, "box_tet min dihedral {a}");
    }

    #[test]
    fn box_rejects_bad_input() {
        let lo = Vector3::zeros();
        let hi = Vector3::new(1.0, 1.0, 1.0);
        assert!(box_hex(lo, hi, [0, 1, 1]).is_err());
        assert!(box_tet(lo, hi, [1, 1, 0]).is_err());
        assert!(box_hex(hi, lo, [1, 1, 1]).is_err());
        assert!(box_hex(lo, Vector3::new(1.0, 0.0, 1.0), [1, 1, 1]).is_err());
        assert!(box_hex(lo, Vector3::new(f64::NAN, 1.0, 1.0), [1, 1, 1]).is_err());
    }

    #[test]
    fn cylinder_rejects_bad_input() {
        assert!(cylinder_hex(0.0, 1.0, 2, 2, 2).is_err());
        assert!(cylinder_hex(1.0, -1.0, 2, 2, 2).is_err());
        assert!(cylinder_tet(1.0, 1.0, 0, 2, 2).is_err());
        assert!(cylinder_tet(1.0, 1.0, 2, 0, 2).is_err());
        assert!(cylinder_hex(1.0, 1.0, 2, 2, 0).is_err());
        assert!(cylinder_hex(f64::INFINITY, 1.0, 2, 2, 2).is_err());
    }

    #[test]
    fn niftysim_reference_cylinder_counts() {
        let m = cylinder_hex(0.05, 0.1, 8, 4, 20).unwrap();
        assert_eq!(m.nodes.len(), 4389);
        assert_eq!(m.num_cells(), 3840);
        let t = cylinder_tet(0.05, 0.1, 8, 4, 20).unwrap();
        assert_eq!(t.nodes.len(), 4389);
        assert_eq!(t.num_cells(), 6 * 3840);
    }

    /// Nodes on the circle: exactly 4 n_inner per layer, at the radius, one at angle 0.
    fn check_circumference(mesh: &Mesh, r: f64, n_inner: usize, n_layers: usize) {
        let on: Vec<&Vector3<f64>> = mesh
            .nodes
            .iter()
            .filter(|p| (p.x.hypot(p.y) - r).abs() < 0.01 * r)
            .collect();
        assert_eq!(on.len(), 4 * n_inner * n_layers);
        for p in &on {
            assert!((p.x.hypot(p.y) - r).abs() <= 1e-12 * r);
        }
        assert!(on.iter().any(|p| p.x == r && p.y == 0.0 && p.z == 0.0));
        // Everything else stays well inside.
        let rmax_inner = mesh
            .nodes
            .iter()
            .map(|p| p.x.hypot(p.y))
            .filter(|&d| d < 0.99 * r)
            .fold(0.0, f64::max);
        assert!(rmax_inner < 0.99 * r);
    }

    #[test]
    fn cylinders_fill_the_polygonal_prism() {
        for &(r, h, ni, nr, na) in &[
            (0.05, 0.1, 8, 4, 20),
            (0.05, 0.1, 4, 2, 10),
            (0.02, 0.03, 3, 2, 3),
            (1.0, 0.5, 1, 1, 1),
            (0.01, 0.04, 5, 3, 2),
        ] {
            let (a, p) = polygon(r, 4 * ni);
            let vol = a * h;
            let area = 2.0 * a + p * h;
            let nodes = ((ni + 1) * (ni + 1) + 4 * ni * nr) * (na + 1);
            let m = cylinder_hex(r, h, ni, nr, na).unwrap();
            assert_eq!(m.nodes.len(), nodes);
            assert_eq!(m.num_cells(), (ni * ni + 4 * ni * nr) * na);
            check_mesh(&m, vol, area);
            check_circumference(&m, r, ni, na + 1);
            let (lo, hi) = m.bounding_box();
            assert_eq!((lo.z, hi.z), (0.0, h));
            let t = cylinder_tet(r, h, ni, nr, na).unwrap();
            assert_eq!(t.nodes.len(), nodes);
            assert_eq!(t.num_cells(), 6 * m.num_cells());
            check_mesh(&t, vol, area);
            check_circumference(&t, r, ni, na + 1);
            let (sj, _) = min_scaled_jacobian(&m).unwrap();
            let dih = min_dihedral_angle(&t).unwrap().degrees;
            println!(
                "cylinder r={r} h={h} n_inner={ni} n_radial={nr} n_axial={na}: \
                 hex min scaled Jacobian {sj:.3}, tet min dihedral {dih:.2} deg"
            );
        }
    }

    #[test]
    fn cylinder_tet_min_dihedral_above_15_degrees() {
        let t = cylinder_tet(0.05, 0.1, 4, 2, 10).unwrap();
        let MinDihedral {
            degrees: a,
            element: e,
        } = min_dihedral_angle(&t).unwrap();
        println!("cylinder_tet(0.05, 0.1, 4, 2, 10): min dihedral {a:.2} deg at element {e}");
        assert!(a > 15.0, "min dihedral {a} deg at element {e}");
    }

    #[test]
    fn prism_split_follows_smallest_index_rule() {
        // Every quad face must be cut along the diagonal through its smallest node.
        for perm in permutations6() {
            let bottom = [perm[0], perm[1], perm[2]];
            let top = [perm[3], perm[4], perm[5]];
            let tets = split_prism(bottom, top);
            let edges: Vec<(usize, usize)> = tets
                .iter()
                .flat_map(|t| {
                    (0..4).flat_map(move |i| {
                        (i + 1..4).map(move |j| (t[i].min(t[j]), t[i].max(t[j])))
                    })
                })
                .collect();
            for s in 0..3 {
                let (a, b) = (bottom[s], bottom[(s + 1) % 3]);
                let (c, d) = (top[(s + 1) % 3], top[s]);
                let quad = [a, b, c, d];
                let k = (0..4).min_by_key(|&i| quad[i]).unwrap();
                let diag = (quad[k], quad[(k + 2) % 4]);
                let diag = (diag.0.min(diag.1), diag.0.max(diag.1));
                assert!(edges.contains(&diag), "{perm:?}: face {quad:?}");
                let other = (quad[(k + 1) % 4], quad[(k + 3) % 4]);
                let other = (other.0.min(other.1), other.0.max(other.1));
                assert!(!edges.contains(&other), "{perm:?}: face {quad:?}");
            }
        }
    }

    fn permutations6() -> Vec<[usize; 6]> {
        let mut out = Vec::new();
        let mut a = [0, 1, 2, 3, 4, 5];
        fn heap(k: usize, a: &mut [usize; 6], out: &mut Vec<[usize; 6]>) {
            if k == 1 {
                out.push(*a);
                return;
            }
            for i in 0..k {
                heap(k - 1, a, out);
                if k.is_multiple_of(2) {
                    a.swap(i, k - 1);
                } else {
                    a.swap(0, k - 1);
                }
            }
        }
        heap(6, &mut a, &mut out);
        out
    }
}
