//! Unstructured tetrahedral meshes of boxes and cylinders by TetGen (Si 2015, "TetGen, a
//! Delaunay-based quality tetrahedral mesh generator", ACM TOMS 41(2):11), called through the
//! `tritet` crate. Only built with the `tetgen` feature (TetGen is AGPL-3.0).
//!
//! Each shape is passed to TetGen as a piecewise linear complex (PLC) of its surface and meshed
//! with TetGen's switches `pzAfQ` plus `a<max volume>` and `q<radius-edge ratio>` (fixed by
//! tritet). Coordinates are in metres, volumes in m^3.
//!
//! * `max_volume` bounds every tetrahedron's volume (m^3); `None` leaves it unbounded.
//! * `radius_edge_ratio` is TetGen's quality bound `-q`: the largest allowed ratio of a
//!   tetrahedron's circumradius to its shortest edge (at least 1; smaller is better shaped but
//!   adds points, and values near 1 may not terminate). `None` uses TetGen's default 2.0 (tritet
//!   always asks for quality refinement). This bound does not remove slivers; check
//!   [`super::quality::min_dihedral_angle`].
//!
//! TetGen keeps process-wide state, so calls are serialized by a process-wide mutex.
//! The PLC is scaled by a power of two to unit size before meshing (exactly, so the surface
//! points come back unchanged), which keeps tritet's fixed-point formatting of the volume bound
//! (`%.15f`) accurate for volumes in m^3.

use std::sync::Mutex;

use nalgebra::Vector3;
use tritet::Tetgen;

use super::mesh::{ElementShape, Mesh};
use super::quality::tet_signed_volume;
use crate::{Error, Result};

/// Serializes calls into TetGen (not thread-safe, see tritet's `Tetgen` docs).
static TETGEN_LOCK: Mutex<()> = Mutex::new(());

/// Tetrahedral mesh of the box [min, max] by TetGen. See the module documentation for
/// `max_volume` (m^3) and `radius_edge_ratio`.
pub fn tetgen_box(
    min: Vector3<f64>,
    max: Vector3<f64>,
    max_volume: Option<f64>,
    radius_edge_ratio: Option<f64>,
) -> Result<Mesh> {
    super::shapes::check_box(min, max)?;
    let mut points = Vec::with_capacity(8);
    for &z in &[min.z, max.z] {
        points.push(Vector3::new(min.x, min.y, z));
        points.push(Vector3::new(max.x, min.y, z));
        points.push(Vector3::new(max.x, max.y, z));
        points.push(Vector3::new(min.x, max.y, z));
    }
    let facets = vec![
        vec![0, 3, 2, 1],
        vec![4, 5, 6, 7],
        vec![0, 1, 5, 4],
        vec![1, 2, 6, 5],
        vec![2, 3, 7, 6],
        vec![3, 0, 4, 7],
    ];
    let d = max - min;
    let volume = d.x * d.y * d.z;
    run_tetgen(
        "box",
        &points,
        &facets,
        volume,
        max_volume,
        radius_edge_ratio,
    )
}

/// Tetrahedral mesh by TetGen of the cylinder of radius `radius` (m) and height `height` (m),
/// axis z, base at z = 0, top at z = height, centred on x = y = 0, approximated by the prism
/// over the regular `n_circ`-gon inscribed in the circle (one vertex at (radius, 0)). The PLC
/// has the two polygons as facets and `n_circ` rectangular side facets. See the module
/// documentation for `max_volume` (m^3) and `radius_edge_ratio`.
pub fn tetgen_cylinder(
    radius: f64,
    height: f64,
    n_circ: usize,
    max_volume: Option<f64>,
    radius_edge_ratio: Option<f64>,
) -> Result<Mesh> {
    if !(radius.is_finite() && radius > 0.0 && height.is_finite() && height > 0.0) {
        return Err(Error::Input(format!(
            "cylinder radius {radius} m and height {height} m must be positive and finite"
        )));
    }
    if n_circ < 3 {
        return Err(Error::Input(format!(
            "cylinder needs at least 3 segments around the circumference, got n_circ = {n_circ}"
        )));
    }
    let mut points = Vec::with_capacity(2 * n_circ);
    for &z in &[0.0, height] {
        for k in 0..n_circ {
            let t = 2.0 * std::f64::consts::PI * k as f64 / n_circ as f64;
            points.push(Vector3::new(radius * t.cos(), radius * t.sin(), z));
        }
    }
    let n = n_circ;
    let mut facets: Vec<Vec<usize>> = Vec::with_capacity(n + 2);
    facets.push((0..n).rev().collect());
    facets.push((n..2 * n).collect());
    for k in 0..n {
        let k1 = (k + 1) % n;
        facets.push(vec![k, k1, n + k1, n + k]);
    }
    let nf = n as f64;
    let volume = 0.5 * nf * radius * radius * (2.0 * std::f64::consts::PI / nf).sin() * height;
    run_tetgen(
        "cylinder",
        &points,
        &facets,
        volume,
        max_volume,
        radius_edge_ratio,
    )
}

/// Meshes the PLC (`points` in m, `facets` as point-index polygons) enclosing `volume` (m^3)
/// and checks that the tetrahedra fill exactly that volume.
fn run_tetgen(
    what: &str,
    points: &[Vector3<f64>],
    facets: &[Vec<usize>],
    volume: f64,
    max_volume: Option<f64>,
    radius_edge_ratio: Option<f64>,
) -> Result<Mesh> {
    if !tritet::TETGEN_IS_AVAILABLE {
        return Err(Error::Input(
            "hytled was built with its `tetgen` feature but the tritet crate without TetGen; \
             enable tritet's `with_tetgen` feature in Cargo.toml \
             (tritet = { version = \"3.4\", optional = true, features = [\"with_tetgen\"] })"
                .into(),
        ));
    }
    if let Some(q) = radius_edge_ratio {
        if !(q.is_finite() && (1.0..=1e6).contains(&q)) {
            return Err(Error::Input(format!(
                "TetGen radius-edge ratio bound {q} must lie in [1, 1e6] (TetGen's default is 2; \
                 values near 1 may not terminate)"
            )));
        }
    }
    // Scale to unit size by a power of two (exact in floating point).
    let extent = points
        .iter()
        .flat_map(|p| p.iter())
        .fold(0.0f64, |m, &x| m.max(x.abs()));
    let scale = 2.0f64.powi(-(extent.log2().floor() as i32));
    let scaled_volume = volume * scale.powi(3);
    let scaled_max_volume = match max_volume {
        None => None,
        Some(v) if !(v.is_finite() && v > 0.0) => {
            return Err(Error::Input(format!(
                "TetGen maximum element volume {v} m^3 must be positive and finite"
            )));
        }
        Some(v) => {
            let sv = v * scale.powi(3);
            if sv < 1e-9 * scaled_volume.max(1e-3) {
                return Err(Error::Input(format!(
                    "TetGen maximum element volume {v:e} m^3 is too small for the {what} of \
                     volume {volume:e} m^3 (over a billion elements); use a larger value"
                )));
            }
            // Larger than the domain: no constraint (also keeps tritet's "a%.15f" short).
            if sv >= scaled_volume {
                None
            } else {
                Some(sv)
            }
        }
    };

    let fail = |msg: &str| Error::Input(format!("TetGen failed to mesh the {what}: {msg}"));
    let facet_npoints: Vec<usize> = facets.iter().map(|f| f.len()).collect();
    let _guard = TETGEN_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let mut tg = Tetgen::new(points.len(), Some(facet_npoints), None, None).map_err(fail)?;
    for (i, p) in points.iter().enumerate() {
        let p = p * scale;
        tg.set_point(i, 0, p.x, p.y, p.z).map_err(fail)?;
    }
    for (f, facet) in facets.iter().enumerate() {
        for (m, &p) in facet.iter().enumerate() {
            tg.set_facet_point(f, m, p).map_err(fail)?;
        }
    }
    tg.generate_mesh(false, false, scaled_max_volume, radius_edge_ratio)
        .map_err(fail)?;

    let npoint = tg.out_npoint();
    let ncell = tg.out_ncell();
    if npoint < 4 || ncell == 0 {
        return Err(fail(&format!(
            "it returned {npoint} points and {ncell} tetrahedra"
        )));
    }
    if tg.out_cell_npoint() < 4 {
        return Err(fail(&format!(
            "it returned {}-node cells",
            tg.out_cell_npoint()
        )));
    }
    let nodes: Vec<Vector3<f64>> = (0..npoint)
        .map(|i| Vector3::new(tg.out_point(i, 0), tg.out_point(i, 1), tg.out_point(i, 2)) / scale)
        .collect();
    let mut cells = Vec::with_capacity(4 * ncell);
    let mut total = 0.0;
    for e in 0..ncell {
        let mut c = [0usize; 4];
        for (m, cm) in c.iter_mut().enumerate() {
            *cm = tg.out_cell_point(e, m);
        }
        if c.iter().any(|&i| i >= npoint) {
            return Err(fail(&format!(
                "tetrahedron {e} refers to a point beyond the {npoint} it returned"
            )));
        }
        let mut v = tet_signed_volume(&nodes[c[0]], &nodes[c[1]], &nodes[c[2]], &nodes[c[3]]);
        if v < 0.0 {
            c.swap(2, 3);
            v = -v;
        }
        if v.is_nan() || v <= 0.0 {
            return Err(fail(&format!("tetrahedron {e} is degenerate")));
        }
        total += v;
        cells.extend_from_slice(&c);
    }
    if ((total - volume) / volume).abs() > 1e-9 {
        return Err(fail(&format!(
            "its tetrahedra fill {total:e} m^3 instead of {volume:e} m^3"
        )));
    }
    Ok(Mesh {
        nodes,
        shape: ElementShape::Tet4,
        cells,
    })
}

/// Delaunay tetrahedralization of a point cloud (TetGen, no added points): the convex hull
/// of `points` (m) split into tetrahedra with positive volume, as node-index quadruples.
/// Tetrahedra flatter than 1e-10 x the mean volume (cospherical lattice points) are dropped;
/// they carry no volume. For a convex domain whose surface carries nodes this is a tet mesh
/// of the domain.
pub fn delaunay(points: &[Vector3<f64>]) -> Result<Vec<[usize; 4]>> {
    let fail = |msg: &str| {
        Error::Input(format!(
            "TetGen failed to tetrahedralize the node cloud: {msg}"
        ))
    };
    if points.len() < 4 {
        return Err(fail(&format!(
            "{} points; at least 4 are needed",
            points.len()
        )));
    }
    let _guard = TETGEN_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let mut tg = Tetgen::new(points.len(), None, None, None).map_err(fail)?;
    for (i, p) in points.iter().enumerate() {
        tg.set_point(i, 0, p.x, p.y, p.z).map_err(fail)?;
    }
    tg.generate_delaunay(false).map_err(fail)?;
    if tg.out_npoint() != points.len() || tg.out_cell_npoint() < 4 {
        return Err(fail(&format!(
            "it returned {} points for {} (duplicate nodes?)",
            tg.out_npoint(),
            points.len()
        )));
    }
    let mut tets = Vec::with_capacity(tg.out_ncell());
    let mut vols = Vec::with_capacity(tg.out_ncell());
    for e in 0..tg.out_ncell() {
        let mut c = [0usize; 4];
        for (m, cm) in c.iter_mut().enumerate() {
            *cm = tg.out_cell_point(e, m);
        }
        if c.iter().any(|&i| i >= points.len()) {
            return Err(fail(&format!(
                "tetrahedron {e} refers to a point out of range"
            )));
        }
        let mut v = tet_signed_volume(&points[c[0]], &points[c[1]], &points[c[2]], &points[c[3]]);
        if v < 0.0 {
            c.swap(2, 3);
            v = -v;
        }
        tets.push(c);
        vols.push(v);
    }
    let mean = vols.iter().sum::<f64>() / vols.len().max(1) as f64;
    let keep: Vec<[usize; 4]> = tets
        .into_iter()
        .zip(vols)
        .filter(|(_, v)| *v > 1e-10 * mean)
        .map(|(t, _)| t)
        .collect();
    if keep.is_empty() {
        return Err(fail("all points are coplanar"));
    }
    Ok(keep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::quality::{
        boundary_faces, face_area, find_duplicate_nodes, min_dihedral_angle,
    };
    use std::f64::consts::PI;

    fn volume(m: &Mesh) -> f64 {
        (0..m.num_cells())
            .map(|e| {
                let c = m.cell(e);
                let v = tet_signed_volume(
                    &m.nodes[c[0]],
                    &m.nodes[c[1]],
                    &m.nodes[c[2]],
                    &m.nodes[c[3]],
                );
                assert!(v > 0.0, "element {e} volume {v}");
                v
            })
            .sum()
    }

    fn surface(m: &Mesh) -> f64 {
        boundary_faces(m)
            .expect("face matching")
            .iter()
            .map(|f| face_area(m, f))
            .sum()
    }

    #[test]
    fn tetgen_box_fills_the_box() {
        let lo = Vector3::new(-0.01, 0.02, 0.0);
        let hi = Vector3::new(0.03, 0.05, 0.1);
        let d = hi - lo;
        let v = d.x * d.y * d.z;
        let m = tetgen_box(lo, hi, Some(v / 500.0), Some(1.5)).unwrap();
        assert_eq!(m.shape, ElementShape::Tet4);
        assert!(m.num_cells() >= 500, "{} tets", m.num_cells());
        assert!(((volume(&m) - v) / v).abs() < 1e-10);
        let area = 2.0 * (d.x * d.y + d.y * d.z + d.z * d.x);
        assert!(((surface(&m) - area) / area).abs() < 1e-10);
        assert_eq!(find_duplicate_nodes(&m, 1e-9 * d.norm()), None);
        let (lo2, hi2) = m.bounding_box();
        assert_eq!((lo2, hi2), (lo, hi));
        let (a, _) = min_dihedral_angle(&m).unwrap();
        println!(
            "tetgen_box(max_volume = V/500, q = 1.5): {} nodes, {} tets, min dihedral {a:.2} deg",
            m.nodes.len(),
            m.num_cells()
        );
        assert!(a > 0.0);
        // Defaults: TetGen's q = 2 and no volume bound still give a valid mesh.
        let m = tetgen_box(lo, hi, None, None).unwrap();
        assert!(((volume(&m) - v) / v).abs() < 1e-10);
    }

    #[test]
    fn tetgen_cylinder_fills_the_polygonal_prism() {
        let (r, h, n) = (0.05, 0.1, 32);
        let v = 0.5 * n as f64 * r * r * (2.0 * PI / n as f64).sin() * h;
        let m = tetgen_cylinder(r, h, n, Some(v / 2000.0), Some(1.4)).unwrap();
        assert!(m.num_cells() >= 2000, "{} tets", m.num_cells());
        assert!(((volume(&m) - v) / v).abs() < 1e-10);
        let area = 0.5 * n as f64 * r * r * (2.0 * PI / n as f64).sin() * 2.0
            + 2.0 * n as f64 * r * (PI / n as f64).sin() * h;
        assert!(((surface(&m) - area) / area).abs() < 1e-10);
        assert!(m.nodes.iter().any(|p| p.x == r && p.y == 0.0 && p.z == 0.0));
        assert!(m.nodes.iter().all(|p| p.x.hypot(p.y) <= r * (1.0 + 1e-12)));
        let (a, _) = min_dihedral_angle(&m).unwrap();
        println!(
            "tetgen_cylinder(0.05, 0.1, 32, V/2000, q = 1.4): {} nodes, {} tets, min dihedral \
             {a:.2} deg",
            m.nodes.len(),
            m.num_cells()
        );
        assert!(a > 0.0);
    }

    #[test]
    fn tetgen_rejects_bad_input() {
        let lo = Vector3::zeros();
        let hi = Vector3::new(1.0, 1.0, 1.0);
        assert!(tetgen_box(hi, lo, None, None).is_err());
        assert!(tetgen_box(lo, hi, Some(-1.0), None).is_err());
        assert!(tetgen_box(lo, hi, Some(1e-20), None).is_err());
        assert!(tetgen_box(lo, hi, None, Some(0.5)).is_err());
        assert!(tetgen_cylinder(1.0, 1.0, 2, None, None).is_err());
        assert!(tetgen_cylinder(0.0, 1.0, 8, None, None).is_err());
    }

    #[test]
    fn tetgen_from_several_threads() {
        let handles: Vec<_> = (0..4)
            .map(|k| {
                std::thread::spawn(move || {
                    tetgen_cylinder(0.01 * (k + 1) as f64, 0.02, 12, None, None)
                        .map(|m| m.num_cells())
                })
            })
            .collect();
        for h in handles {
            assert!(h.join().unwrap().unwrap() > 0);
        }
    }
}
