//! Unstructured tetrahedral meshes of boxes, cylinders and half-ellipsoids by TetGen (Si 2015, "TetGen, a
//! Delaunay-based quality tetrahedral mesh generator", ACM TOMS 41(2):11), called through the
//! `tritet` crate. Only built with the `tetgen` feature (TetGen is AGPL-3.0).
//!
//! Each shape is passed to TetGen as a piecewise linear complex (PLC) of its surface and meshed
//! with TetGen's switches `pzAfQ` plus `a<max volume>` and `q<radius-edge ratio>` (fixed by
//! tritet). Coordinates are in metres, volumes in m^3.
//!
//! * `max_volume` bounds every tetrahedron's volume (m^3); `None` leaves it unbounded.
//! * `radius_edge_ratio` is TetGen's quality bound `-q`: the largest allowed ratio of a
//!   tetrahedron's circumradius to its shortest edge (at least [`MIN_RADIUS_EDGE_RATIO`] = 1.1;
//!   smaller is better shaped but adds points, and closer to 1 TetGen may not terminate). `None` uses TetGen's default 2.0 (tritet
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

use super::dome::{enclosed_volume, zip_rings, EllipseArc};
use super::mesh::{ElementShape, Mesh};
use super::quality::tet_signed_volume;
use crate::{Error, InputKind, Result};

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
        Plc {
            points: &points,
            facets: &facets,
            regions: &[],
            holes: &[],
        },
        volume,
        max_volume,
        radius_edge_ratio,
        1e-9,
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
        return Err(Error::input(
            InputKind::Value,
            format!("cylinder radius {radius} m and height {height} m must be positive and finite"),
        ));
    }
    if n_circ < 3 {
        return Err(Error::input(
            InputKind::Value,
            format!(
            "cylinder needs at least 3 segments around the circumference, got n_circ = {n_circ}"
        ),
        ));
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
        Plc {
            points: &points,
            facets: &facets,
            regions: &[],
            holes: &[],
        },
        volume,
        max_volume,
        radius_edge_ratio,
        1e-9,
    )
}

/// A triangulated surface: vertex positions (m) and triangles (vertex indices).
pub type TriSurface = (Vec<Vector3<f64>>, Vec<[usize; 3]>);

/// Closed, outward-oriented triangulation of the surface of the half-ellipsoid
/// x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0 (`semi_axes` = [a, b, c], m) with edges of about
/// `h` (m). Returns the points (m) and the triangles (point indices, counter-clockwise seen
/// from outside).
///
/// The surface is a stack of rings from the apex to the centre of the base, every ring a
/// scaled copy of the base ellipse (a cos t, b sin t) with its points equally spaced in arc
/// length, the first at t = 0 (on the +x meridian):
/// * the apex (0, 0, c);
/// * dome rings at polar angles theta_k (apex 0, rim pi/2) equally spaced in arc length along
///   the meridian ellipse of horizontal semi-axis (a + b) / 2 and height c,
///   round(length / h) intervals (at least 2); ring k is (a sin theta_k cos t, b sin theta_k
///   sin t, c cos theta_k), so its points lie on the ellipsoid (up to rounding);
/// * the rim (a cos t, b sin t, 0), shared by the dome and the base;
/// * base rings at z = 0 (exactly) scaled by 1 - k / n_base, n_base = round((a + b) / (2 h))
///   (at least 1), and the centre (0, 0, 0).
///
/// A ring of perimeter P has max(6, round(P / h)) points. Consecutive rings are zipped into
/// triangles by merging their edges in the order of their midpoints' arc-length fractions,
/// so the triangles are consistently oriented, and each edge is shared by exactly two of them.
pub fn half_ellipsoid_surface(semi_axes: [f64; 3], h: f64) -> Result<TriSurface> {
    let [a, b, c] = semi_axes;
    super::dome::check_half_ellipsoid(semi_axes, h)?;
    let r_mean = 0.5 * (a + b);
    // Meridian (r_mean sin theta, c cos theta): arc length from the apex by Simpson's rule.
    let nt = 2048usize;
    let dth = 0.5 * std::f64::consts::PI / nt as f64;
    let speed = |t: f64| (r_mean * t.cos()).hypot(c * t.sin());
    let mut arc = vec![0.0];
    for i in 0..nt {
        let t = i as f64 * dth;
        let ds = dth / 6.0 * (speed(t) + 4.0 * speed(t + 0.5 * dth) + speed(t + dth));
        arc.push(arc[i] + ds);
    }
    let meridian = arc[nt];
    let limit = 2_000_000.0;
    let n_lat = (meridian / h).round().max(2.0);
    let n_base = (r_mean / h).round().max(1.0);
    let ellipse = EllipseArc::new(a, b);
    let rim_points = (ellipse.perimeter() / h).round().max(6.0);
    if !(n_lat * rim_points <= limit && n_base * rim_points <= limit) {
        return Err(Error::input(
            InputKind::Limit,
            format!(
            "half-ellipsoid surface edge length {h} m is too small for semi-axes {semi_axes:?} \
             m (millions of surface points); lengths are in metres"
        ),
        ));
    }
    let (n_lat, n_base) = (n_lat as usize, n_base as usize);

    let mut points: Vec<Vector3<f64>> = Vec::new();
    let mut rings: Vec<Vec<usize>> = Vec::new();
    // A ring at scale `s` (of the base ellipse) and height `z`.
    let ring = |points: &mut Vec<Vector3<f64>>, s: f64, z: f64| -> Vec<usize> {
        let m = ((s * ellipse.perimeter() / h).round() as usize).max(6);
        ellipse
            .equal_arc(m)
            .into_iter()
            .map(|t| {
                points.push(Vector3::new(a * s * t.cos(), b * s * t.sin(), z));
                points.len() - 1
            })
            .collect()
    };
    points.push(Vector3::new(0.0, 0.0, c));
    rings.push(vec![0]);
    for k in 1..n_lat {
        let target = meridian * k as f64 / n_lat as f64;
        let i = arc.partition_point(|&v| v <= target).clamp(1, nt);
        let f = (target - arc[i - 1]) / (arc[i] - arc[i - 1]);
        let theta = (i as f64 - 1.0 + f) * dth;
        let r = ring(&mut points, theta.sin(), c * theta.cos());
        rings.push(r);
    }
    let r = ring(&mut points, 1.0, 0.0);
    rings.push(r);
    for k in 1..n_base {
        let r = ring(&mut points, 1.0 - k as f64 / n_base as f64, 0.0);
        rings.push(r);
    }
    points.push(Vector3::zeros());
    rings.push(vec![points.len() - 1]);

    let mut tris = Vec::new();
    for w in rings.windows(2) {
        zip_rings(&w[0], &w[1], &mut tris);
    }
    Ok((points, tris))
}

/// Tetrahedral mesh by TetGen of the half-ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0
/// (`semi_axes` = [a, b, c], m): flat base on z = 0 centred on x = y = 0, apex (0, 0, c) a
/// vertex. The PLC is the triangulated surface of [`half_ellipsoid_surface`] with edges of about
/// `h` (m), so the mesh fills the inscribed polyhedron. Points TetGen adds on the surface
/// (Steiner points on surface triangles and rim edges) are moved onto the curved surface
/// afterwards: onto the base plane z = 0 exactly, and radially in the scaled coordinates
/// (x/a, y/b, z/c) onto the ellipsoid, part of the way where the whole way would crush an
/// element (below half its TetGen volume, `SNAP_MIN_SHARE`). Every other surface vertex then lies on the base plane or
/// the ellipsoid. See the module documentation
/// for `max_volume` (m^3) and `radius_edge_ratio`.
pub fn tetgen_half_ellipsoid(
    semi_axes: [f64; 3],
    h: f64,
    max_volume: Option<f64>,
    radius_edge_ratio: Option<f64>,
) -> Result<Mesh> {
    let (points, tris) = half_ellipsoid_surface(semi_axes, h)?;
    // Volume of the inscribed polyhedron (divergence theorem, outward triangles).
    let volume = enclosed_volume(&points, &tris);
    let facets: Vec<Vec<usize>> = tris.iter().map(|t| t.to_vec()).collect();
    let mut mesh = run_tetgen(
        "half-ellipsoid",
        Plc {
            points: &points,
            facets: &facets,
            regions: &[],
            holes: &[],
        },
        volume,
        max_volume,
        radius_edge_ratio,
        // TetGen places the points it adds on the many slightly bent surface triangles up to
        // about 1e-6 x the size off their planes (2.4e-7 of the volume at h = 5 mm on the
        // brain-sized shape); they are moved onto the ellipsoid next anyway.
        1e-5,
    )?;
    snap_to_half_ellipsoid(&mut mesh, &points, semi_axes, -1.0)?;
    Ok(mesh)
}

/// [`tetgen_half_ellipsoid`] whose surface follows `outlines` (circles about the z axis on
/// the dome, [`super::dome::half_ellipsoid_outlined`]): nodes on each outline, the surface
/// graded there, and each plug (an outline with a floor) a meshed sub-volume whose tets are
/// at most the regular tet of its outline's size; the rest of the body keeps `max_volume`
/// (m^3). TetGen's quality bound grades the inside from the graded surface.
pub fn tetgen_half_ellipsoid_outlined(
    semi_axes: [f64; 3],
    h: f64,
    max_volume: Option<f64>,
    radius_edge_ratio: Option<f64>,
    outlines: &[super::dome::Outline],
) -> Result<Mesh> {
    let plc = super::dome::half_ellipsoid_outlined(semi_axes, h, outlines)?;
    let (points, tris) = (&plc.points, &plc.triangles);
    let volume = enclosed_volume(points, tris);
    let mut facets: Vec<Vec<usize>> = tris.iter().map(|t| t.to_vec()).collect();
    facets.extend(plc.inner_facets.iter().cloned());
    let mut regions = Vec::new();
    if !plc.plugs.is_empty() {
        // The body: below every plug, on the axis.
        let floor = outlines
            .iter()
            .filter_map(|o| o.floor)
            .fold(f64::INFINITY, f64::min);
        regions.push((
            Vector3::new(0.0, 0.0, 0.5 * floor),
            max_volume.unwrap_or(volume),
        ));
        for (x, size) in &plc.plugs {
            let v = size.powi(3) / (6.0 * 2f64.sqrt());
            regions.push((*x, max_volume.map_or(v, |m| m.min(v))));
        }
    }
    let mut mesh = run_tetgen(
        "half-ellipsoid",
        Plc {
            points,
            facets: &facets,
            regions: &regions,
            holes: &[],
        },
        volume,
        max_volume,
        radius_edge_ratio,
        1e-5,
    )?;
    let within = outlines
        .iter()
        .map(|o| o.radius * (1.0 + 1e-9))
        .fold(-1.0, f64::max);
    snap_to_half_ellipsoid(&mut mesh, points, semi_axes, within)?;
    Ok(mesh)
}

/// An element the snap leaves below this share of the volume TetGen gave it has the moves of
/// its snapped nodes halved (again, up to [`SNAP_HALVINGS`] times). Coarse brain meshes
/// (h = 7 and 8 mm) had an element inverted by the full move, and at 7.5 / 9 / 10 / 15 mm
/// elements flattened to 1.01 / 0.69 / 1.13 / 1.48 deg dihedral angles (critical steps 2.5 to
/// 4.5x shorter than with this bound). With 0.5: 3 to 41 points move part of the way at
/// h >= 7 mm, the smallest angle is 3.9-5.2 deg there, and the meshes at h <= 6.5 mm are
/// bitwise those of the full move (no element falls below half its volume there).
const SNAP_MIN_SHARE: f64 = 0.5;
/// Halvings of a snapped node's move at most; after them the node stays where TetGen put it.
const SNAP_HALVINGS: u32 = 12;

/// Moves the surface points TetGen added (not among `input`) onto the half-ellipsoid. Where
/// that would crush an element below [`SNAP_MIN_SHARE`] of its volume, its moved nodes go only
/// part of the way (the move halved until no element is crushed, or back to TetGen's place):
/// those few points then lie slightly inside the curved surface.
///
/// Dome points within `vertical_within` (m) of the z axis move vertically instead (the dome is
/// nearly flat there), so the points TetGen adds on an outline's chords stay in the plane of
/// their plug's side.
fn snap_to_half_ellipsoid(
    mesh: &mut Mesh,
    input: &[Vector3<f64>],
    semi_axes: [f64; 3],
    vertical_within: f64,
) -> Result<()> {
    let s = Vector3::from(semi_axes);
    let given: std::collections::HashSet<[u64; 3]> = input
        .iter()
        .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
        .collect();
    let faces = super::quality::boundary_faces(mesh).map_err(|m| {
        Error::input(
            InputKind::Mesh,
            format!("TetGen's half-ellipsoid mesh: {m}"),
        )
    })?;
    let flat = 1e-9 * s.z;
    // Per node: 1 = on a base triangle, 2 = on a dome triangle.
    let mut on = vec![0u8; mesh.nodes.len()];
    for f in &faces {
        let base = f.iter().all(|&i| mesh.nodes[i].z.abs() <= flat);
        for &i in f {
            on[i] |= if base { 1 } else { 2 };
        }
    }
    let original = mesh.nodes.clone();
    let cells: Vec<[usize; 4]> = mesh
        .cells
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    let volume = |nodes: &[Vector3<f64>], e: usize| {
        let c = cells[e];
        tet_signed_volume(&nodes[c[0]], &nodes[c[1]], &nodes[c[2]], &nodes[c[3]])
    };
    let v0: Vec<f64> = (0..cells.len()).map(|e| volume(&original, e)).collect();
    // Per node: its place on the surface (None: not moved) and how many times its move was halved.
    let mut target: Vec<Option<Vector3<f64>>> = vec![None; mesh.nodes.len()];
    for (i, p) in original.iter().enumerate() {
        if on[i] == 0 || given.contains(&[p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]) {
            continue;
        }
        let mut q = *p;
        if on[i] & 1 != 0 {
            q.z = 0.0;
        }
        if on[i] & 2 != 0 && on[i] & 1 == 0 && q.x.hypot(q.y) <= vertical_within {
            // Straight up: a point on an outline's chord stays on its plug's side.
            q.z = s.z
                * (1.0 - (q.x / s.x).powi(2) - (q.y / s.y).powi(2))
                    .max(0.0)
                    .sqrt();
        } else if on[i] & 2 != 0 {
            let r = q.component_div(&s).norm();
            q /= r;
            if on[i] & 1 != 0 {
                q.z = 0.0;
            }
        }
        target[i] = Some(q);
    }
    if target.iter().all(Option::is_none) {
        return Ok(());
    }
    let mut halved = vec![0u32; mesh.nodes.len()];
    let mut nodes = original.clone();
    loop {
        for (i, t) in target.iter().enumerate() {
            if let Some(q) = t {
                nodes[i] = if halved[i] == 0 {
                    *q
                } else if halved[i] > SNAP_HALVINGS {
                    original[i]
                } else {
                    original[i] + (q - original[i]) * 0.5f64.powi(halved[i] as i32)
                };
            }
        }
        let mut changed = false;
        for e in 0..cells.len() {
            if volume(&nodes, e) >= SNAP_MIN_SHARE * v0[e] {
                continue;
            }
            for &i in &cells[e] {
                if target[i].is_some() && halved[i] <= SNAP_HALVINGS {
                    halved[i] += 1;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    for e in 0..cells.len() {
        let v = volume(&nodes, e);
        if !(v > 0.0) {
            return Err(Error::input(InputKind::Mesh, format!(
                "TetGen's half-ellipsoid mesh: element {e} has volume {sci_v:e} m^3 after moving the surface \
                 points TetGen added onto the curved surface; try another size", sci_v = crate::error::Sci(v))).element(e).value(v));
        }
    }
    mesh.nodes = nodes;
    let partial = halved.iter().filter(|&&k| k > 0).count();
    if partial > 0 {
        log::info!(
            "{partial} of the surface points TetGen added moved only part of the way onto the curved \
             surface (the full move would crush an element below {SNAP_MIN_SHARE} of its volume)"
        );
    }
    Ok(())
}

/// Tetrahedral mesh by TetGen of the body a checked closed surface encloses (its triangles the
/// PLC's facets; TetGen may add points on them). See the module documentation for
/// `max_volume` (m^3) and `radius_edge_ratio`.
///
/// `what` names the surface in messages (its file). TetGen keeps every triangle, so a surface
/// finer than `max_volume` asks sets the mesh's size: that is warned of, and the memory plan
/// counts [`TETS_PER_FACET`] tetrahedra a triangle.
pub fn tetgen_surface(
    surface: &super::closed_surface::ClosedSurface,
    internal: &[Vec<usize>],
    max_volume: Option<f64>,
    radius_edge_ratio: Option<f64>,
    what: &str,
) -> Result<Mesh> {
    let mut facets: Vec<Vec<usize>> = surface.triangles.iter().map(|t| t.to_vec()).collect();
    facets.extend(internal.iter().cloned());
    if let Some(v) = max_volume.filter(|v| *v > 0.0) {
        let by_size = surface.volume() / v;
        let by_surface = TETS_PER_FACET * facets.len() as f64;
        if by_surface > 4.0 * by_size.max(1.0) {
            log::warn!(
                "{what}: its {} triangles are much finer than discretization.size: TetGen keeps every \
                 triangle, so the mesh will have about {by_surface:.3e} tetrahedra rather than the {by_size:.3e} \
                 the size asks for (more memory and a shorter stable step); decimate or remesh the surface to \
                 about {:.0} triangles, or lower discretization.size to match it",
                facets.len(),
                (by_size / TETS_PER_FACET).max(4.0)
            );
        }
    }
    run_tetgen(
        what,
        Plc {
            points: &surface.points,
            facets: &facets,
            regions: &[],
            holes: &surface.holes,
        },
        surface.volume(),
        max_volume,
        radius_edge_ratio,
        // TetGen snaps vertices closer than its tolerance together and puts the points it adds
        // on a facet within its tolerance of it: 1.9e-7 of the volume on a labelled ball,
        // 2.4-3.7e-6 on labelled balls, an 11-voxel cube and a hollow shell (issue 56: 1e-6
        // refused them). A cavity filled or a piece of the body lost is far more.
        SURFACE_VOLUME_TOLERANCE,
    )
}

/// Tetrahedra TetGen makes per facet of a surface finer than the volume bound (it keeps every
/// facet and grades the inside from them): 7.5 measured on a 19,200-triangle ball of radius
/// 50 mm at a size of 10 and 20 mm (144,000-148,000 tets); the plan takes 6.
pub const TETS_PER_FACET: f64 = 6.0;

/// Largest relative difference between the volume TetGen's tets fill and the volume the
/// surface encloses, for a mesh of a closed surface (see [`tetgen_surface`]).
pub const SURFACE_VOLUME_TOLERANCE: f64 = 1e-4;

/// The smallest radius-edge ratio bound accepted: TetGen's refinement need not terminate below
/// about this (measured on the brain half-ellipsoid at h = 4 mm: 1.1 meshed 31,657 nodes in
/// 1.6 s, 1.05 ran past 60 s).
pub const MIN_RADIUS_EDGE_RATIO: f64 = 1.1;

/// A piecewise linear complex: points (m), facets (point-index polygons) and regions (a point
/// inside each, m, and its tets' largest volume, m^3; none: `max_volume` everywhere).
struct Plc<'a> {
    points: &'a [Vector3<f64>],
    facets: &'a [Vec<usize>],
    regions: &'a [(Vector3<f64>, f64)],
    /// A point inside each cavity, m (TetGen removes the tets around it up to the facets).
    holes: &'a [Vector3<f64>],
}

/// Meshes the PLC enclosing `volume` (m^3)
/// and checks that the tetrahedra fill that volume within the relative `volume_tolerance`.
fn run_tetgen(
    what: &str,
    plc: Plc,
    volume: f64,
    max_volume: Option<f64>,
    radius_edge_ratio: Option<f64>,
    volume_tolerance: f64,
) -> Result<Mesh> {
    let Plc {
        points,
        facets,
        regions,
        holes,
    } = plc;
    if !tritet::TETGEN_IS_AVAILABLE {
        return Err(Error::input(
            InputKind::Unsupported,
            "hytled was built with its `tetgen` feature but the tritet crate without TetGen; \
             enable tritet's `with_tetgen` feature in Cargo.toml \
             (tritet = { version = \"3.4\", optional = true, features = [\"with_tetgen\"] })",
        ));
    }
    if let Some(q) = radius_edge_ratio {
        if !(q.is_finite() && (MIN_RADIUS_EDGE_RATIO..=1e6).contains(&q)) {
            return Err(Error::input(InputKind::Value, format!(
                "TetGen radius-edge ratio bound {q} must lie in [{MIN_RADIUS_EDGE_RATIO}, 1e6] (TetGen's \
                 default is 2; closer to 1 TetGen may not terminate: on the brain at h = 4 mm, 1.1 meshed in \
                 1.6 s and 1.05 ran past 60 s)"
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
            return Err(Error::input(
                InputKind::Value,
                format!("TetGen maximum element volume {v} m^3 must be positive and finite"),
            ));
        }
        Some(v) => {
            let sv = v * scale.powi(3);
            if sv < 1e-9 * scaled_volume.max(1e-3) {
                // A body of a cubic metre or more is rarely tissue: most often a file in mm.
                let units = if volume >= 1.0 {
                    "; a body of that volume is over a metre across: if its file is in millimetres, \
                     set its units = 0.001"
                } else {
                    ""
                };
                return Err(Error::input(InputKind::Limit, format!(
                    "TetGen maximum element volume {sci_v:e} m^3 is too small for the {what} of \
                     volume {sci_volume:e} m^3 (over a billion elements); use a larger value{units}", sci_v = crate::error::Sci(v), sci_volume = crate::error::Sci(volume))));
            }
            // Each tet is at most the bound, so the volume over it is the fewest tets TetGen
            // makes; a tet has at least about a sixth of a vertex of its own.
            let tets = (volume / v).max(TETS_PER_FACET * facets.len() as f64);
            super::mesh::check_mesh_memory(tets / 6.0, tets, ElementShape::Tet4).map_err(|e| {
                if volume >= 1.0 {
                    Error::input(InputKind::Mesh, format!(
                        "{e}\n(the {what} encloses {sci_volume:.3e} m^3, a body over a metre across: if its file \
                         is in millimetres, set its units = 0.001)", sci_volume = crate::error::Sci(volume)))
                } else {
                    e
                }
            })?;
            // Larger than the domain: no constraint (also keeps tritet's "a%.15f" short).
            if sv >= scaled_volume {
                None
            } else {
                Some(sv)
            }
        }
    };

    let fail = |msg: &str| {
        Error::input(
            InputKind::Mesh,
            format!("TetGen failed to mesh the {what}: {msg}"),
        )
    };
    let _guard = TETGEN_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let scaled_max_volume = if regions.is_empty() {
        scaled_max_volume
    } else {
        None
    };
    // In a child process: TetGen's failed asserts abort (issue 56: SIGABRT on a UV sphere's
    // thin pole triangles), it prints on stdout, and it cannot be stopped from inside.
    let (out, printed) = super::isolated::run(&format!("TetGen meshing the {what}"), || {
        let facet_npoints: Vec<usize> = facets.iter().map(|f| f.len()).collect();
        let nregion = (!regions.is_empty()).then_some(regions.len());
        let nhole = (!holes.is_empty()).then_some(holes.len());
        let mut tg = Tetgen::new(points.len(), Some(facet_npoints), nregion, nhole)?;
        for (k, x) in holes.iter().enumerate() {
            let x = x * scale;
            tg.set_hole(k, x.x, x.y, x.z)?;
        }
        for (i, p) in points.iter().enumerate() {
            let p = p * scale;
            tg.set_point(i, 0, p.x, p.y, p.z)?;
        }
        // Each region its own volume bound (TetGen's `-a` without a number: then the global
        // bound does not apply, so the caller gives the rest of the body a region too).
        for (k, (x, v)) in regions.iter().enumerate() {
            let x = x * scale;
            tg.set_region(k, k as i32 + 1, x.x, x.y, x.z, Some(v * scale.powi(3)))?;
        }
        for (f, facet) in facets.iter().enumerate() {
            for (m, &p) in facet.iter().enumerate() {
                tg.set_facet_point(f, m, p)?;
            }
        }
        tg.generate_mesh(false, false, scaled_max_volume, radius_edge_ratio)?;
        Ok(tetgen_output(&tg))
    })?;
    let (nodes, cell_list, cell_npoint) = from_output(&out, scale);
    let npoint = nodes.len();
    let ncell = cell_list.len() / cell_npoint.max(1);
    if npoint < 4 || ncell == 0 {
        return Err(fail(&format!(
            "it returned {npoint} points and {ncell} tetrahedra: {}",
            tetgen_status(&printed)
        )));
    }
    if cell_npoint < 4 {
        return Err(fail(&format!("it returned {cell_npoint}-node cells")));
    }
    let mut cells = Vec::with_capacity(4 * ncell);
    let mut total = 0.0;
    for e in 0..ncell {
        let mut c = [0usize; 4];
        for (m, cm) in c.iter_mut().enumerate() {
            *cm = cell_list[e * cell_npoint + m];
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
    if ((total - volume) / volume).abs() > volume_tolerance {
        return Err(fail(&format!(
            "its tetrahedra fill {sci_total:e} m^3 instead of {sci_volume:e} m^3 (relative difference {:.2e}, more than \
             {sci_volume_tolerance:e}): a cavity was filled or a part of the body lost; check the surface for \
             pieces that touch or nearly touch",
            crate::error::Sci((total - volume) / volume), sci_total = crate::error::Sci(total), sci_volume = crate::error::Sci(volume), sci_volume_tolerance = crate::error::Sci(volume_tolerance))));
    }
    Ok(Mesh {
        nodes,
        shape: ElementShape::Tet4,
        cells,
    })
}

/// TetGen's output as an [`super::isolated::Output`]: the points (as TetGen gives them,
/// scaled) and `[nodes per cell, cell nodes...]`.
fn tetgen_output(tg: &Tetgen) -> super::isolated::Output {
    let (npoint, ncell, k) = (tg.out_npoint(), tg.out_ncell(), tg.out_cell_npoint());
    let mut reals = Vec::with_capacity(3 * npoint);
    for i in 0..npoint {
        reals.extend([tg.out_point(i, 0), tg.out_point(i, 1), tg.out_point(i, 2)]);
    }
    let mut ints = Vec::with_capacity(1 + k * ncell);
    ints.push(k as u64);
    for e in 0..ncell {
        ints.extend((0..k.min(4)).map(|m| tg.out_cell_point(e, m) as u64));
    }
    ints[0] = k.min(4) as u64;
    super::isolated::Output { reals, ints }
}

/// Points (divided by `scale`), cell node indices and nodes per cell of [`tetgen_output`].
fn from_output(
    out: &super::isolated::Output,
    scale: f64,
) -> (Vec<Vector3<f64>>, Vec<usize>, usize) {
    let nodes = out
        .reals
        .chunks_exact(3)
        .map(|p| Vector3::new(p[0], p[1], p[2]) / scale)
        .collect();
    let k = out.ints.first().map_or(0, |&k| k as usize);
    let cells = out.ints.iter().skip(1).map(|&i| i as usize).collect();
    (nodes, cells, k)
}

/// What TetGen's "status = N" line (tritet prints it when TetGen stops) means, and the fix.
fn tetgen_status(printed: &str) -> String {
    let code = printed.lines().rev().find_map(|l| {
        l.trim()
            .strip_prefix("status = ")?
            .trim()
            .parse::<i32>()
            .ok()
    });
    let meaning = match code {
        Some(1) => "TetGen ran out of memory (its status 1): raise discretization.size or run where more memory is free".to_string(),
        Some(2) => "TetGen met an internal error (its status 2): the surface is probably nearly degenerate somewhere; remesh it".to_string(),
        Some(3) => "TetGen found facets that cross each other (its status 3): the surface intersects itself, or two \
                    surfaces (the body's and a region's, or two regions') cross or coincide; separate them"
            .to_string(),
        Some(4) => "TetGen found an input feature smaller than its tolerance (its status 4): vertices or facets \
                    nearly on top of each other; clean the surface"
            .to_string(),
        Some(5) => "TetGen found two facets very close to each other (its status 5): surfaces that nearly touch; \
                    move them apart"
            .to_string(),
        Some(10) => "TetGen found an input error (its status 10)".to_string(),
        Some(n) => format!("TetGen stopped with status {n}"),
        None if printed.is_empty() => "TetGen said nothing".to_string(),
        None => format!("TetGen printed: \"{}\"", printed.replace('\n', " / ")),
    };
    meaning
}

/// Delaunay tetrahedralization of a point cloud (TetGen, no added points): the convex hull
/// of `points` (m) split into tetrahedra with positive volume, as node-index quadruples.
/// Tetrahedra flatter than 1e-10 x the mean volume (cospherical lattice points) are dropped;
/// they carry no volume. For a convex domain whose surface carries nodes this is a tet mesh
/// of the domain.
pub fn delaunay(points: &[Vector3<f64>]) -> Result<Vec<[usize; 4]>> {
    let fail = |msg: &str| {
        Error::input(
            InputKind::Mesh,
            format!("TetGen failed to tetrahedralize the node cloud: {msg}"),
        )
    };
    if points.len() < 4 {
        return Err(fail(&format!(
            "{} points; at least 4 are needed",
            points.len()
        )));
    }
    let _guard = TETGEN_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let (out, _) = super::isolated::run("TetGen tetrahedralizing the node cloud", || {
        let mut tg = Tetgen::new(points.len(), None, None, None)?;
        for (i, p) in points.iter().enumerate() {
            tg.set_point(i, 0, p.x, p.y, p.z)?;
        }
        tg.generate_delaunay(false)?;
        Ok(tetgen_output(&tg))
    })?;
    let (returned, cell_list, k) = from_output(&out, 1.0);
    if returned.len() != points.len() || k < 4 {
        return Err(fail(&format!(
            "it returned {} points for {} (duplicate nodes?)",
            returned.len(),
            points.len()
        )));
    }
    let ncell = cell_list.len() / k;
    let mut tets = Vec::with_capacity(ncell);
    let mut vols = Vec::with_capacity(ncell);
    for e in 0..ncell {
        let mut c = [0usize; 4];
        for (m, cm) in c.iter_mut().enumerate() {
            *cm = cell_list[e * k + m];
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
        let a = min_dihedral_angle(&m).unwrap().degrees;
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
        let a = min_dihedral_angle(&m).unwrap().degrees;
        println!(
            "tetgen_cylinder(0.05, 0.1, 32, V/2000, q = 1.4): {} nodes, {} tets, min dihedral \
             {a:.2} deg",
            m.nodes.len(),
            m.num_cells()
        );
        assert!(a > 0.0);
    }

    const BRAIN: [f64; 3] = [0.04625, 0.03125, 0.0285];

    /// |(x/a, y/b, z/c)| - 1 (0 on the ellipsoid).
    fn ellipsoid_residual(p: &Vector3<f64>, s: [f64; 3]) -> f64 {
        p.component_div(&Vector3::from(s)).norm() - 1.0
    }

    #[test]
    fn half_ellipsoid_surface_is_closed_oriented_and_on_the_shape() {
        for h in [0.004, 0.009, 0.03] {
            let (p, t) = half_ellipsoid_surface(BRAIN, h).unwrap();
            // Closed, consistently oriented, a sphere's Euler characteristic.
            crate::geometry::dome::assert_closed_sphere(&t);
            // Outward: positive enclosed volume, a little below the exact one.
            let v = enclosed_volume(&p, &t);
            let exact = 2.0 / 3.0 * PI * BRAIN[0] * BRAIN[1] * BRAIN[2];
            assert!(v > 0.0 && v < exact, "{v} vs {exact}");
            // Every triangle's normal points away from the centroid of the base.
            for tri in &t {
                let n = (p[tri[1]] - p[tri[0]]).cross(&(p[tri[2]] - p[tri[0]]));
                let m = (p[tri[0]] + p[tri[1]] + p[tri[2]]) / 3.0;
                let inside = Vector3::new(0.0, 0.0, 0.3 * BRAIN[2]);
                assert!(n.dot(&(m - inside)) > 0.0, "{tri:?}");
            }
            // Points on the base plane (exactly) or the ellipsoid; the apex is a vertex.
            for q in &p {
                assert!(q.z >= 0.0);
                assert!(
                    q.z == 0.0 || ellipsoid_residual(q, BRAIN).abs() < 1e-14,
                    "{q:?}"
                );
                if q.z == 0.0 {
                    assert!(ellipsoid_residual(q, BRAIN) < 1e-14);
                }
            }
            assert!(p.contains(&Vector3::new(0.0, 0.0, BRAIN[2])));
            assert!(p.contains(&Vector3::new(BRAIN[0], 0.0, 0.0)));
            println!(
                "half_ellipsoid_surface(h = {h}): {} points, {} triangles, volume {:.4} of exact",
                p.len(),
                t.len(),
                v / exact
            );
        }
        assert!(half_ellipsoid_surface([0.1, 0.0, 0.1], 0.01).is_err());
        assert!(half_ellipsoid_surface(BRAIN, 0.0).is_err());
        assert!(half_ellipsoid_surface(BRAIN, 1e-9).is_err());
    }

    #[test]
    fn tetgen_half_ellipsoid_fills_the_shape() {
        let h = 0.005;
        let exact = 2.0 / 3.0 * PI * BRAIN[0] * BRAIN[1] * BRAIN[2];
        let max_volume = h * h * h / (6.0 * 2f64.sqrt());
        let m = tetgen_half_ellipsoid(BRAIN, h, Some(max_volume), None).unwrap();
        assert_eq!(m.shape, ElementShape::Tet4);
        // All tets positive (checked in `volume`), total within 2 % of 2/3 pi a b c.
        let v = volume(&m);
        assert!(((v - exact) / exact).abs() < 0.02, "volume {v} vs {exact}");
        // Boundary nodes: on the base plane exactly or on the ellipsoid.
        let faces = boundary_faces(&m).unwrap();
        let mut on_surface = vec![false; m.nodes.len()];
        for f in &faces {
            for &i in f {
                on_surface[i] = true;
            }
        }
        for (i, p) in m.nodes.iter().enumerate() {
            if on_surface[i] {
                assert!(
                    p.z == 0.0 || ellipsoid_residual(p, BRAIN).abs() < 1e-14,
                    "boundary node {i} at {p:?} is off the surface"
                );
            } else {
                assert!(p.z > 0.0 && ellipsoid_residual(p, BRAIN) < 0.0, "{p:?}");
            }
        }
        assert!(m.nodes.contains(&Vector3::new(0.0, 0.0, BRAIN[2])));
        assert_eq!(find_duplicate_nodes(&m, 1e-9), None);
        let a = min_dihedral_angle(&m).unwrap().degrees;
        println!(
            "tetgen_half_ellipsoid(h = {h}): {} nodes, {} tets, volume {:.4} % off exact, \
             min dihedral {a:.2} deg",
            m.nodes.len(),
            m.num_cells(),
            100.0 * (v / exact - 1.0)
        );
        assert!(a > 0.0);
    }

    /// Coarse sizes where moving TetGen's added surface points the whole way onto the dome
    /// inverted an element (7, 8 mm) or flattened one to under 1.5 deg (7.5, 9 mm): valid
    /// meshes with every angle above 3 deg, and all but a few surface points on the surface,
    /// those few inside it.
    #[test]
    fn coarse_half_ellipsoids_keep_their_elements_whole() {
        for h in [0.007, 0.0075, 0.008, 0.009] {
            let max_volume = h * h * h / (6.0 * 2f64.sqrt());
            let m = tetgen_half_ellipsoid(BRAIN, h, Some(max_volume), None)
                .unwrap_or_else(|e| panic!("h = {h}: {e}"));
            let exact = 2.0 / 3.0 * PI * BRAIN[0] * BRAIN[1] * BRAIN[2];
            let v = volume(&m);
            assert!(
                ((v - exact) / exact).abs() < 0.02,
                "h = {h}: volume {v} vs {exact}"
            );
            let a = min_dihedral_angle(&m).unwrap().degrees;
            let faces = boundary_faces(&m).unwrap();
            let mut surface: Vec<usize> = faces.iter().flatten().cloned().collect();
            surface.sort_unstable();
            surface.dedup();
            let off: Vec<f64> = surface
                .iter()
                .map(|&i| m.nodes[i])
                .filter(|p| p.z != 0.0 && ellipsoid_residual(p, BRAIN).abs() >= 1e-14)
                .map(|p| ellipsoid_residual(&p, BRAIN))
                .collect();
            println!(
                "h = {h}: {} nodes, min dihedral {a:.2} deg, {} of {} surface nodes inside the dome \
                 (residual down to {:.2e})",
                m.nodes.len(),
                off.len(),
                surface.len(),
                off.iter().cloned().fold(0.0, f64::min)
            );
            assert!(a > 3.0, "h = {h}: {a} deg");
            assert!(
                off.len() * 50 < surface.len() && off.iter().all(|&r| r < 0.0),
                "{off:?}"
            );
        }
    }

    /// The plug {r <= 5 mm, z >= 27.5 mm} under a graded outline: a valid mesh whose tets lie
    /// each inside or outside the plug (none crosses its side or floor), with the outline's
    /// ring of nodes on the surface, every surface node on the shape, and small tets at the
    /// rim, large ones far away.
    #[test]
    fn outlined_half_ellipsoid_meshes_the_plug_as_a_sub_volume() {
        use crate::geometry::dome::{Grading, Outline};
        let (r, floor) = (0.005, 0.0275);
        let h = 0.008;
        let outline = Outline {
            radius: r,
            floor: Some(floor),
            grading: Some(Grading {
                size: 0.002,
                growth: 1.25,
            }),
        };
        let max_volume = h * h * h / (6.0 * 2f64.sqrt());
        let m =
            tetgen_half_ellipsoid_outlined(BRAIN, h, Some(max_volume), None, &[outline]).unwrap();
        let exact = 2.0 / 3.0 * PI * BRAIN[0] * BRAIN[1] * BRAIN[2];
        let v = volume(&m);
        assert!(((v - exact) / exact).abs() < 0.02, "volume {v} vs {exact}");
        let eps = 1e-12;
        // The plug is a prism over the floor's polygon (the outline's chords): the convex
        // hull of the nodes on the floor, counter-clockwise (monotone chain).
        let mut floor_pts: Vec<(f64, f64)> = m
            .nodes
            .iter()
            .filter(|p| (p.z - floor).abs() < eps && p.x.hypot(p.y) <= r + eps)
            .map(|p| (p.x, p.y))
            .collect();
        floor_pts.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
            (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
        };
        let mut hull: Vec<(f64, f64)> = Vec::new();
        for pass in 0..2 {
            let start = hull.len();
            let pts: Vec<(f64, f64)> = if pass == 0 {
                floor_pts.clone()
            } else {
                floor_pts.iter().rev().cloned().collect()
            };
            for q in pts {
                while hull.len() >= start + 2
                    && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
                {
                    hull.pop();
                }
                hull.push(q);
            }
            hull.pop();
        }
        assert!(hull.len() >= 15, "floor polygon of {} corners", hull.len());
        // Signed distance inside the polygon (positive inside), m.
        let depth = |x: f64, y: f64| {
            (0..hull.len())
                .map(|k| {
                    let (a, b) = (hull[k], hull[(k + 1) % hull.len()]);
                    cross(a, b, (x, y)) / (b.0 - a.0).hypot(b.1 - a.1)
                })
                .fold(f64::INFINITY, f64::min)
        };
        // Strictly inside or outside: beyond rounding (the points TetGen adds on the outline's
        // chords move straight up onto the dome, staying on the side's plane).
        let tol = 1e-12;
        let inside = |p: &Vector3<f64>| depth(p.x, p.y) > tol && p.z > floor + tol;
        let outside = |p: &Vector3<f64>| depth(p.x, p.y) < -tol || p.z < floor - tol;
        let mut plug_tets = 0;
        let mut plug_volume = 0.0;
        let mut rim = f64::INFINITY;
        let mut far = 0.0f64;
        for e in 0..m.num_cells() {
            let c = m.cell(e);
            let p: Vec<Vector3<f64>> = c.iter().map(|&i| m.nodes[i]).collect();
            let (any_in, any_out) = (p.iter().any(inside), p.iter().any(outside));
            assert!(!(any_in && any_out), "tet {e} crosses the plug: {p:?}");
            let edge = (0..4)
                .flat_map(|i| (i + 1..4).map(move |j| (i, j)))
                .map(|(i, j)| (p[i] - p[j]).norm())
                .fold(0.0, f64::max);
            if !any_out {
                plug_tets += 1;
                plug_volume += tet_signed_volume(&p[0], &p[1], &p[2], &p[3]);
                rim = rim.min(edge);
            }
            if p.iter().all(|q| q.z < 0.01) {
                far = far.max(edge);
            }
        }
        // The plug's volume: the cylinder of 1 mm under the cap, within the faceting.
        let cap = PI * r * r * (0.0285 - floor);
        assert!(plug_tets > 20, "{plug_tets} tets in the plug");
        assert!(
            plug_volume > 0.6 * cap && plug_volume < cap,
            "plug volume {plug_volume} vs at most {cap}"
        );
        // The outline: surface nodes on the circle at 2 mm spacing.
        let faces = boundary_faces(&m).unwrap();
        let mut surface: Vec<usize> = faces.iter().flatten().cloned().collect();
        surface.sort_unstable();
        surface.dedup();
        let ring = surface
            .iter()
            .filter(|&&i| {
                (m.nodes[i].x.hypot(m.nodes[i].y) - r).abs() < eps && m.nodes[i].z > floor
            })
            .count();
        assert!(ring >= 15, "{ring} outline nodes");
        for &i in &surface {
            let p = m.nodes[i];
            assert!(
                p.z == 0.0 || ellipsoid_residual(&p, BRAIN) <= 1e-14,
                "{p:?}"
            );
        }
        assert!(
            far > 2.0 * 0.002,
            "graded: longest edge near the base {far}"
        );
        let a = min_dihedral_angle(&m).unwrap().degrees;
        println!(
            "outlined half-ellipsoid: {} nodes, {} tets ({plug_tets} in the plug), {ring} outline \
             nodes, min dihedral {a:.2} deg, edges in the plug from {rim:.2e} m, near the base up \
             to {far:.2e} m",
            m.nodes.len(),
            m.num_cells()
        );
        assert!(a > 1.0);
    }

    #[test]
    fn tetgen_rejects_bad_input() {
        let lo = Vector3::zeros();
        let hi = Vector3::new(1.0, 1.0, 1.0);
        assert!(tetgen_box(hi, lo, None, None).is_err());
        assert!(tetgen_box(lo, hi, Some(-1.0), None).is_err());
        assert!(tetgen_box(lo, hi, Some(1e-20), None).is_err());
        assert!(tetgen_box(lo, hi, None, Some(0.5)).is_err());
        let e = tetgen_box(lo, hi, None, Some(1.05))
            .unwrap_err()
            .to_string();
        assert!(e.contains("must lie in [1.1, 1e6]"), "{e}");
        assert!(tetgen_cylinder(1.0, 1.0, 2, None, None).is_err());
        assert!(tetgen_cylinder(0.0, 1.0, 8, None, None).is_err());
        assert!(tetgen_half_ellipsoid([1.0, -1.0, 1.0], 0.1, None, None).is_err());
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
