//! Node clouds for MTLED. The meshless method only needs nodes "placed almost arbitrarily"
//! in the solid (Horton et al. 2010, "A meshless Total Lagrangian explicit dynamics algorithm
//! for surgical simulation", Int. J. Numer. Meth. Biomed. Engng 26, sect. 1 and 3.1), so
//! clouds come from a jittered lattice, a quasi-random (Halton) fill, a file, or the vertices
//! of a tetrahedral mesh.
//!
//! Generated clouds always put nodes on every boundary surface: MLS shape functions only
//! reach the surface well when nodes lie on it, and essential boundary conditions are applied
//! at surface nodes. Coordinates are in metres.

use std::f64::consts::PI;
use std::path::Path;

use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

use crate::geometry::domain::Domain;
use crate::geometry::Mesh;
use crate::{Error, InputKind, Result};

/// Largest cloud the generators build: far beyond what the explicit solver can run, so a
/// larger count means a spacing given in the wrong unit (mm for m), not a real request.
const MAX_NODES: usize = 5_000_000;

/// Interior nodes of a Halton fill stay at least this fraction of the minimum spacing inside,
/// as the jittered lattice does (there by construction), so that no interior node sits almost
/// on top of the surface layer.
const INTERIOR_CLEARANCE: f64 = 0.05;

/// A Halton fill of one surface patch or of the interior stops after this many candidates in
/// a row were rejected: the sequence then "stops producing accepted points" (the patch is
/// saturated at the minimum spacing) and more candidates would cost time for a few nodes.
/// Halton candidates are rejected in bursts: a limit of 5,000 stopped a cube's interior at
/// 0.48 / s^3 nodes per m^3, 20,000 at 0.58 / s^3 (about 6 times slower at saturation).
const MISS_LIMIT_SURFACE: u64 = 4_000;
const MISS_LIMIT_INTERIOR: u64 = 20_000;

/// Jittered regular lattice of spacing h (m) filling the domain; every node is moved by a
/// uniform random offset of up to `jitter` x h per component (jitter in [0, 0.5)), seeded.
/// Boundary surfaces always carry nodes: nodes on a face / the lateral surface are jittered only
/// tangentially (they stay exactly on the surface; edge/rim nodes stay on their edges), interior
/// nodes stay at least ~0.05 h inside.
///
/// Horton et al. (2010) sect. 3.1: MTLED accepts nodes placed almost arbitrarily; the jitter
/// makes the cloud irregular while keeping it evenly spread.
///
/// * Box: round(L/h) divisions per axis (at least 1), spacing d = L / divisions on each axis,
///   (nx+1)(ny+1)(nz+1) nodes; the jitter of each component is up to `jitter` x d.
/// * Cylinder: layers in z at spacing H / round(H/h) (first and last exactly on the caps); in
///   each layer the centre and m = round(R/h) concentric rings of radius k h' (h' = R / m),
///   ring k with max(3, round(2 pi k h' / h)) points, the outermost ring on the lateral surface.
///   Jitter is in cylindrical components: radius up to `jitter` x h', angle up to `jitter` x the
///   ring's angular step, z up to `jitter` x the layer spacing; the centre node moves within a
///   disc of radius `jitter` x h'.
///
/// Each node moves within its own lattice cell of half-width 0.5 x spacing, so the cloud is
/// duplicate-free and interior nodes stay at least (1 - jitter) x spacing (> spacing / 2) from
/// the surface. The same `seed` gives the same cloud.
///
/// Errors when the domain is invalid, h is not positive and finite, jitter is outside [0, 0.5),
/// or the lattice would have more than 5 million nodes.
pub fn jittered_lattice(
    domain: &Domain,
    h: f64,
    jitter: f64,
    seed: u64,
) -> Result<Vec<Vector3<f64>>> {
    domain.validate()?;
    if !(h.is_finite() && h > 0.0) {
        return Err(Error::input(
            InputKind::Value,
            format!("node spacing h = {h} m must be positive and finite"),
        ));
    }
    if !(0.0..0.5).contains(&jitter) {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "lattice jitter {jitter} must be in [0, 0.5) (a fraction of the spacing; 0.5 or \
             more would let neighbouring nodes swap or coincide)"
            ),
        ));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    match *domain {
        Domain::Box { min, max } => box_lattice(min, max, h, jitter, &mut rng),
        Domain::Cylinder { radius, height } => {
            cylinder_lattice(radius, height, h, jitter, &mut rng)
        }
        Domain::HalfEllipsoid { .. } => Err(unsupported_cloud("lattice")),
    }
}

/// The generated clouds do not fill the half-ellipsoid yet: use the TetGen mesh's vertices.
fn unsupported_cloud(kind: &str) -> Error {
    Error::input(
        InputKind::Unsupported,
        format!(
            "cloud = '{kind}' is not available for the half-ellipsoid; use cloud = 'mesh' (the \
         vertices of its TetGen mesh, mesher = 'tetgen') or cloud = 'file'"
        ),
    )
}

/// Divisions round(len / h), at least 1, or an error when absurdly many.
fn divisions(len: f64, h: f64, what: &str) -> Result<usize> {
    let n = (len / h).round().max(1.0);
    if !(n <= MAX_NODES as f64) {
        return Err(too_many(h, what, n));
    }
    Ok(n as usize)
}

fn too_many(h: f64, what: &str, n: f64) -> Error {
    Error::input(InputKind::Limit, format!(
        "node spacing {h} m gives about {sci_n:.3e} nodes {what}, more than the limit of {MAX_NODES}; \
         lengths are in metres (is the spacing given in mm?)", sci_n = crate::error::Sci(n)))
}

/// Uniform in [-1, 1).
fn sym_unit(rng: &mut ChaCha8Rng) -> f64 {
    // 53 random bits: every value is an exact f64 in [0, 1).
    let u = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    2.0 * u - 1.0
}

fn box_lattice(
    min: Vector3<f64>,
    max: Vector3<f64>,
    h: f64,
    jitter: f64,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Vector3<f64>>> {
    let len = max - min;
    let n = [
        divisions(len.x, h, "along x")?,
        divisions(len.y, h, "along y")?,
        divisions(len.z, h, "along z")?,
    ];
    let total = n.iter().map(|&k| (k + 1) as f64).product::<f64>();
    if total > MAX_NODES as f64 {
        return Err(too_many(h, "in the box", total));
    }
    let d = Vector3::new(
        len.x / n[0] as f64,
        len.y / n[1] as f64,
        len.z / n[2] as f64,
    );
    // Lattice coordinate i on axis a; the last one is exactly max so that face nodes lie on
    // the face without rounding.
    let coord = |a: usize, i: usize| -> f64 {
        if i == n[a] {
            max[a]
        } else {
            min[a] + len[a] * (i as f64 / n[a] as f64)
        }
    };
    let mut nodes = Vec::with_capacity(total as usize);
    for k in 0..=n[2] {
        for j in 0..=n[1] {
            for i in 0..=n[0] {
                let idx = [i, j, k];
                let mut p = Vector3::zeros();
                for a in 0..3 {
                    // Always draw, so the random stream does not depend on the position class.
                    let u = sym_unit(rng);
                    p[a] = coord(a, idx[a]);
                    // A coordinate on a face stays put: the node then moves only tangentially.
                    if idx[a] != 0 && idx[a] != n[a] {
                        p[a] += u * jitter * d[a];
                    }
                }
                nodes.push(p);
            }
        }
    }
    Ok(nodes)
}

fn cylinder_lattice(
    radius: f64,
    height: f64,
    h: f64,
    jitter: f64,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Vector3<f64>>> {
    let nz = divisions(height, h, "along the axis")?;
    let m = divisions(radius, h, "along the radius")?;
    let hr = radius / m as f64;
    // Rough count first (sum over rings of 2 pi k h'/h is pi m (m+1) h'/h) so that a tiny h
    // is refused before looping over millions of rings.
    let rough = (nz + 1) as f64 * (1.0 + PI * m as f64 * (m + 1) as f64 * hr / h + m as f64);
    if rough > 2.0 * MAX_NODES as f64 {
        return Err(too_many(h, "in the cylinder", rough));
    }
    let ring_counts: Vec<usize> = (1..=m)
        .map(|k| ((2.0 * PI * k as f64 * hr / h).round() as usize).max(3))
        .collect();
    let per_layer = 1 + ring_counts.iter().sum::<usize>();
    let total = per_layer * (nz + 1);
    if total > MAX_NODES {
        return Err(too_many(h, "in the cylinder", total as f64));
    }
    let dz = height / nz as f64;
    let mut nodes = Vec::with_capacity(total);
    for l in 0..=nz {
        let on_cap = l == 0 || l == nz;
        let z0 = if l == nz {
            height
        } else {
            height * (l as f64 / nz as f64)
        };
        // Centre node: a uniform point of the disc of radius jitter h' (polar sampling), so
        // that it stays inside the first ring's cell.
        let (u0, u1, u2) = (sym_unit(rng), sym_unit(rng), sym_unit(rng));
        let rc = jitter * hr * (0.5 * (u0 + 1.0)).sqrt();
        let (s, c) = (PI * u1).sin_cos();
        let z = if on_cap { z0 } else { z0 + u2 * jitter * dz };
        nodes.push(Vector3::new(rc * c, rc * s, z));
        for (k, &count) in (1..=m).zip(&ring_counts) {
            let on_side = k == m;
            let step = 2.0 * PI / count as f64;
            for i in 0..count {
                let (ur, ut, uz) = (sym_unit(rng), sym_unit(rng), sym_unit(rng));
                let r = if on_side {
                    radius
                } else {
                    k as f64 * hr + ur * jitter * hr
                };
                let theta = (i as f64 + ut * jitter) * step;
                let z = if on_cap { z0 } else { z0 + uz * jitter * dz };
                let (s, c) = theta.sin_cos();
                nodes.push(Vector3::new(r * c, r * s, z));
            }
        }
    }
    Ok(nodes)
}

/// Most cells the spacing grid of [`halton_fill`] allocates (4 bytes each): a minimum
/// spacing tiny against the domain then gets cells larger than the spacing instead.
const MAX_GRID_CELLS: f64 = 16_000_000.0;

/// Dense uniform grid over the domain's bounding box for the minimum-spacing test of
/// [`halton_fill`]: cells at least `s` wide, so a candidate only has to be compared with the
/// points of the 27 surrounding cells. Points of a cell form a linked list (`head`, `next`).
struct SpacingGrid {
    s2: f64,
    origin: Vector3<f64>,
    inv_cell: f64,
    dims: [usize; 3],
    head: Vec<u32>,
    next: Vec<u32>,
    points: Vec<Vector3<f64>>,
}

const EMPTY: u32 = u32::MAX;

impl SpacingGrid {
    /// Grid for points of the box [lo, hi] at minimum spacing `s`, expecting at most
    /// `count` points.
    fn new(s: f64, lo: Vector3<f64>, hi: Vector3<f64>, count: usize) -> Self {
        let len = hi - lo;
        // Cells of side s unless that makes too many; then larger cells, whose lists are
        // longer but still short on average because the points are at most `count`.
        let cap = MAX_GRID_CELLS.min(4.0 * count as f64 + 64.0);
        let cell = s.max((len.product() / cap).cbrt());
        let n = len.map(|l| ((l / cell).ceil() + 1.0).clamp(1.0, 1e6));
        let mut dims = [n.x as usize, n.y as usize, n.z as usize];
        // Thin boxes: keep the product within the cap even when one side has few cells.
        while (dims[0] * dims[1] * dims[2]) as f64 > 2.0 * cap {
            let a = (0..3).max_by_key(|&a| dims[a]).unwrap_or(0);
            dims[a] = dims[a].div_ceil(2);
        }
        let cell = (0..3)
            .map(|a| len[a] / (dims[a] as f64 - 1.0).max(1.0))
            .fold(cell, f64::max);
        SpacingGrid {
            s2: s * s,
            origin: lo,
            inv_cell: 1.0 / cell,
            dims,
            head: vec![EMPTY; dims[0] * dims[1] * dims[2]],
            next: Vec::new(),
            points: Vec::new(),
        }
    }

    fn cell_of(&self, p: &Vector3<f64>) -> [usize; 3] {
        let mut k = [0; 3];
        for a in 0..3 {
            // Points lie in the box; the clamp only guards against rounding at its sides.
            let f = ((p[a] - self.origin[a]) * self.inv_cell).floor();
            k[a] = f.clamp(0.0, (self.dims[a] - 1) as f64) as usize;
        }
        k
    }

    fn index(&self, k: [usize; 3]) -> usize {
        (k[2] * self.dims[1] + k[1]) * self.dims[0] + k[0]
    }

    /// True when `p` is at least `s` from every stored point.
    fn is_free(&self, p: &Vector3<f64>) -> bool {
        let k = self.cell_of(p);
        let range = |a: usize| k[a].saturating_sub(1)..=(k[a] + 1).min(self.dims[a] - 1);
        for z in range(2) {
            for y in range(1) {
                for x in range(0) {
                    let mut i = self.head[self.index([x, y, z])];
                    while i != EMPTY {
                        if (self.points[i as usize] - p).norm_squared() < self.s2 {
                            return false;
                        }
                        i = self.next[i as usize];
                    }
                }
            }
        }
        true
    }

    fn insert(&mut self, p: Vector3<f64>) {
        let c = self.index(self.cell_of(&p));
        // At most MAX_NODES + 1 points are ever stored, far below u32::MAX.
        let i = self.points.len() as u32;
        self.next.push(self.head[c]);
        self.head[c] = i;
        self.points.push(p);
    }

    /// Inserts `p` if it is free; returns whether it was.
    fn try_insert(&mut self, p: Vector3<f64>) -> bool {
        if self.is_free(&p) {
            self.insert(p);
            true
        } else {
            false
        }
    }
}

/// Radical inverse of `i` in base `b`: the Halton coordinate.
fn radical_inverse(mut i: u64, b: u64) -> f64 {
    let inv = 1.0 / b as f64;
    let mut f = inv;
    let mut r = 0.0;
    while i > 0 {
        r += f * (i % b) as f64;
        i /= b;
        f *= inv;
    }
    r
}

/// Seeded Halton sequence: a seed-dependent start index and a Cranley-Patterson rotation
/// (a random shift modulo 1 per coordinate). The rotation keeps the low discrepancy and makes
/// clouds of different seeds differ everywhere, not only in their first points.
struct Halton<const D: usize> {
    index: u64,
    bases: [u64; D],
    shift: [f64; D],
}

impl<const D: usize> Halton<D> {
    fn new(bases: [u64; D], rng: &mut ChaCha8Rng) -> Self {
        let index = 1 + rng.next_u64() % (1 << 20);
        let mut shift = [0.0; D];
        for s in shift.iter_mut() {
            *s = 0.5 * (sym_unit(rng) + 1.0);
        }
        Halton {
            index,
            bases,
            shift,
        }
    }

    /// Next point of [0, 1)^D.
    fn next_point(&mut self) -> [f64; D] {
        let mut x = [0.0; D];
        for ((x, &b), &shift) in x.iter_mut().zip(&self.bases).zip(&self.shift) {
            let v = radical_inverse(self.index, b) + shift;
            *x = if v >= 1.0 { v - 1.0 } else { v };
        }
        self.index += 1;
        x
    }
}

/// Quasi-random fill: Halton sequence (bases 2, 3, 5) points in the domain, a point accepted
/// only if it is at least `min_spacing` (m) from every accepted point; surface nodes first
/// (faces / lateral surface / caps sampled with a 2-D Halton sequence (bases 2, 3) at the same
/// min spacing, plus edges/rims sampled at spacing `min_spacing`), then the interior until
/// `count` nodes or the sequence stops producing accepted points. `seed` skips/scrambles the
/// start of the sequence so different seeds give different clouds. Reproducible.
///
/// Horton et al. (2010) sect. 3.1: nodes may be placed almost arbitrarily; a quasi-random fill
/// with a minimum spacing gives an irregular cloud with no two nodes closer than
/// `min_spacing`, which keeps the MLS moment matrices well conditioned.
///
/// * `count` is the total number of nodes, surface included. A surface patch (or the interior)
///   is considered full after 4,000 (interior: 20,000) rejected candidates in a row, so fewer
///   than `count` nodes come back when `min_spacing` is too large to fit them: the fill
///   saturates near 0.58 / min_spacing^3 nodes per m^3 in the bulk (measured in a 0.1 m cube
///   at min_spacing 0.9 mm: 796,165 nodes), more in thin domains where the surface
///   layer dominates.
/// * Edges (box) and rims (cylinder) carry equally spaced nodes at spacing >= `min_spacing`
///   (edge length / floor(edge length / min_spacing); chord length on rims) including corners.
/// * Interior nodes stay at least 0.05 `min_spacing` inside the surface.
/// * "Seed" picks the start index (1 .. 2^20) of every sequence and a random shift modulo 1
///   of each coordinate (Cranley-Patterson rotation).
///
/// The minimum spacing holds exactly between generated points, and up to rounding between
/// the equally spaced edge nodes.
///
/// Errors when the domain is invalid, `count` is 0 or above 5 million, `min_spacing` is not
/// positive and finite or larger than the smallest box side / the cylinder height /
/// sqrt(3) x radius, or when the surface alone needs more than `count` nodes.
pub fn halton_fill(
    domain: &Domain,
    count: usize,
    min_spacing: f64,
    seed: u64,
) -> Result<Vec<Vector3<f64>>> {
    domain.validate()?;
    let s = min_spacing;
    if !(s.is_finite() && s > 0.0) {
        return Err(Error::input(
            InputKind::Value,
            format!("minimum node spacing {s} m must be positive and finite"),
        ));
    }
    if count == 0 || count > MAX_NODES {
        return Err(Error::input(
            InputKind::Value,
            format!("node count {count} must be between 1 and {MAX_NODES}"),
        ));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (lo, hi) = domain.bounds();
    let mut grid = SpacingGrid::new(s, lo, hi, count);
    let surface_error = |n: usize| {
        Error::input(
            InputKind::Value,
            format!(
                "the surface alone takes more than {n} nodes at the minimum spacing {s} m, more \
             than the node count {count}; a larger minimum spacing or count fits"
            ),
        )
    };

    match *domain {
        Domain::Box { min, max } => {
            let len = max - min;
            let shortest = len.min();
            if s > shortest {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                        "minimum node spacing {s} m is larger than the shortest box side \
                     {shortest} m, so the faces cannot all carry nodes"
                    ),
                ));
            }
            // Edge nodes at spacing len / floor(len / s) >= s, estimated first so that a tiny
            // spacing is refused before anything is allocated.
            let per_axis: Vec<f64> = (0..3).map(|a| (len[a] / s).floor()).collect();
            let edge_nodes = 4.0 * per_axis.iter().sum::<f64>() + 8.0;
            if !(edge_nodes <= count as f64) {
                return Err(surface_error(count));
            }
            let div: Vec<usize> = per_axis.iter().map(|&n| n.max(1.0) as usize).collect();
            let coord = |a: usize, i: usize| -> f64 {
                if i == div[a] {
                    max[a]
                } else {
                    min[a] + len[a] * (i as f64 / div[a] as f64)
                }
            };
            // Corners and edge interiors; by construction they keep the spacing, so they are
            // inserted without the test (which rounding could fail at exactly s).
            for corner in 0..8 {
                let pick = |a: usize| if corner >> a & 1 == 0 { min[a] } else { max[a] };
                grid.insert(Vector3::new(pick(0), pick(1), pick(2)));
            }
            for a in 0..3 {
                let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                for fb in [min[b], max[b]] {
                    for fc in [min[c], max[c]] {
                        for i in 1..div[a] {
                            let mut p = Vector3::zeros();
                            p[a] = coord(a, i);
                            p[b] = fb;
                            p[c] = fc;
                            grid.insert(p);
                        }
                    }
                }
            }
            // Faces: 2-D Halton in the face rectangle.
            for a in 0..3 {
                let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                for &fixed in &[min[a], max[a]] {
                    let mut seq = Halton::new([2, 3], &mut rng);
                    fill_patch(&mut grid, &mut seq, count, MISS_LIMIT_SURFACE, |u| {
                        let mut p = Vector3::zeros();
                        p[a] = fixed;
                        p[b] = min[b] + len[b] * u[0];
                        p[c] = min[c] + len[c] * u[1];
                        Some(p)
                    });
                    if grid.points.len() > count {
                        return Err(surface_error(count));
                    }
                }
            }
        }
        Domain::Cylinder { radius, height } => {
            if s > height || s > 3f64.sqrt() * radius {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                        "minimum node spacing {s} m is too large for the cylinder of radius \
                     {radius} m and height {height} m (at most the height and sqrt(3) x the \
                     radius, so that caps and rims carry nodes)"
                    ),
                ));
            }
            // Rim nodes: the most that keep the chord 2 R sin(pi / n) >= s.
            let mut n_rim = (PI / (0.5 * s / radius).min(1.0).asin()).floor();
            if !(2.0 * n_rim <= count as f64) {
                return Err(surface_error(count));
            }
            while n_rim > 3.0 && 2.0 * radius * (PI / n_rim).sin() < s {
                n_rim -= 1.0;
            }
            let n_rim = n_rim.max(3.0) as usize;
            for &z in &[0.0, height] {
                for i in 0..n_rim {
                    let (sn, cs) = (2.0 * PI * i as f64 / n_rim as f64).sin_cos();
                    grid.insert(Vector3::new(radius * cs, radius * sn, z));
                }
            }
            // Caps: 2-D Halton in the bounding square, kept inside the disc.
            for &z in &[0.0, height] {
                let mut seq = Halton::new([2, 3], &mut rng);
                fill_patch(&mut grid, &mut seq, count, MISS_LIMIT_SURFACE, |u| {
                    let x = radius * (2.0 * u[0] - 1.0);
                    let y = radius * (2.0 * u[1] - 1.0);
                    (x.hypot(y) < radius).then(|| Vector3::new(x, y, z))
                });
                if grid.points.len() > count {
                    return Err(surface_error(count));
                }
            }
            // Lateral surface: uniform in (angle, z) is uniform in area.
            let mut seq = Halton::new([2, 3], &mut rng);
            fill_patch(&mut grid, &mut seq, count, MISS_LIMIT_SURFACE, |u| {
                let (sn, cs) = (2.0 * PI * u[0]).sin_cos();
                Some(Vector3::new(radius * cs, radius * sn, height * u[1]))
            });
            if grid.points.len() > count {
                return Err(surface_error(count));
            }
        }
        Domain::HalfEllipsoid { .. } => return Err(unsupported_cloud("halton")),
    }

    // Interior: 3-D Halton in the bounding box, kept clear of the surface.
    let size = hi - lo;
    let clearance = -INTERIOR_CLEARANCE * s;
    let mut seq = Halton::new([2, 3, 5], &mut rng);
    fill_patch(&mut grid, &mut seq, count, MISS_LIMIT_INTERIOR, |u| {
        let p = lo + Vector3::new(size.x * u[0], size.y * u[1], size.z * u[2]);
        (domain.signed_distance(&p) <= clearance).then_some(p)
    });
    Ok(grid.points)
}

/// Feeds points of `seq`, mapped by `map` (None: outside the patch, not counted as a miss),
/// to the grid until the grid holds more than `count` points or `miss_limit` mapped
/// candidates in a row were rejected.
fn fill_patch<const D: usize>(
    grid: &mut SpacingGrid,
    seq: &mut Halton<D>,
    count: usize,
    miss_limit: u64,
    map: impl Fn([f64; D]) -> Option<Vector3<f64>>,
) {
    let mut misses = 0u64;
    let mut outside = 0u64;
    // The interior stops at `count`; a surface patch goes one past it so that the caller can
    // tell "surface too large" from "exactly full".
    let stop = if D == 3 { count } else { count + 1 };
    while grid.points.len() < stop && misses < miss_limit {
        match map(seq.next_point()) {
            Some(p) => {
                outside = 0;
                if grid.try_insert(p) {
                    misses = 0;
                } else {
                    misses += 1;
                }
            }
            None => {
                // A patch that maps (almost) nothing inside would loop forever.
                outside += 1;
                if outside > 1_000 * miss_limit {
                    return;
                }
            }
        }
    }
}

/// Reads a node cloud: CSV (optional header line, comma/semicolon separated, first three
/// numeric columns are x y z) or whitespace-separated XYZ, one node per line; `#` comments and
/// blank lines skipped. Coordinates in m. Errors name the file and the 1-based line and say
/// what is wrong (e.g. "line 7: expected 3 numbers x y z, found 'abc'"); an empty cloud is an
/// error. Non-finite coordinates are an error naming the line.
///
/// Horton et al. (2010) sect. 3.1: any cloud with nodes spread through the solid will do, so
/// clouds from other tools (image-based, hand-made) are read as they are.
pub fn read_cloud(path: &Path) -> Result<Vec<Vector3<f64>>> {
    if crate::io::mesh_file::MeshFormat::from_path(path).is_some() {
        // The vertices of a mesh file (.inp, .msh, .vtk, .vtu), unused nodes dropped.
        let nodes = crate::io::mesh_file::read_mesh(path, None, 1.0)?.mesh.nodes;
        check_cloud(&nodes, path)?;
        return Ok(nodes);
    }
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let nodes = parse_cloud(&text, path)?;
    check_cloud(&nodes, path)?;
    Ok(nodes)
}

/// Refuses clouds no meshless body can be built on: coincident nodes (closer than 1e-9 x the
/// cloud's size; their MLS moment matrices and background tets are singular) and nodes that
/// do not span a volume (fewer than 4, or all on one plane or line). Node numbers in the
/// errors are 1-based in file order.
pub fn check_cloud(nodes: &[Vector3<f64>], source: &Path) -> Result<()> {
    let name = source.display();
    if nodes.len() < 4 {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
            "{name}: {} node(s); a meshless body needs at least 4 nodes spread through a volume",
            nodes.len()
        ),
        ));
    }
    let (mut lo, mut hi) = (nodes[0], nodes[0]);
    for p in nodes {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let size = (hi - lo).norm();
    let tol = 1e-9 * size;
    let mut order: Vec<usize> = (0..nodes.len()).collect();
    order.sort_by(|&a, &b| nodes[a].x.total_cmp(&nodes[b].x));
    let mut pairs = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        for &j in &order[k + 1..] {
            if nodes[j].x - nodes[i].x > tol {
                break;
            }
            if (nodes[j] - nodes[i]).norm() <= tol {
                pairs.push((i.min(j), i.max(j)));
            }
        }
    }
    if !pairs.is_empty() {
        pairs.sort_unstable();
        let list: Vec<String> = pairs
            .iter()
            .take(5)
            .map(|&(i, j)| {
                let p = nodes[i];
                format!(
                    "{} and {} at ({:e}, {:e}, {:e})",
                    i + 1,
                    j + 1,
                    p.x,
                    p.y,
                    p.z
                )
            })
            .collect();
        return Err(Error::input(
            InputKind::Mesh,
            format!(
            "{name}: {} pair(s) of coincident nodes (closer than {sci_tol:.1e} m): {}{}; remove or \
             merge them (node numbers count from 1 in file order)",
            pairs.len(),
            list.join("; "),
            if pairs.len() > 5 { "; ..." } else { "" }
        , sci_tol = crate::error::Sci(tol)),
        ));
    }
    let n = nodes.len() as f64;
    let mean = nodes.iter().sum::<Vector3<f64>>() / n;
    let cov = nodes
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<nalgebra::Matrix3<f64>>()
        / n;
    let eig = cov.symmetric_eigenvalues();
    let (min, max) = (eig.min(), eig.max());
    if !(min > 1e-12 * max) {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
            "{name}: the {} nodes lie on one plane or line (thickness {:.3e} m across a spread \
             of {:.3e} m); a meshless body needs nodes spread through a volume",
            nodes.len(),
            crate::error::Sci(min.max(0.0).sqrt()),
            crate::error::Sci(max.sqrt())),
        ));
    }
    Ok(())
}

/// What [`read_cloud`] uses: parses the text of a cloud file; `source` only names the file in
/// error messages. Format and errors as [`read_cloud`]. Columns after the third are ignored
/// (ids, labels). The first data line is taken as a header when none of its first three fields
/// is a number.
pub fn parse_cloud(text: &str, source: &Path) -> Result<Vec<Vector3<f64>>> {
    Ok(parse_cloud_sets(text, source)?.0)
}

/// Named node sets: node indices by set name.
pub type NodeSets = std::collections::BTreeMap<String, Vec<usize>>;

/// As [`parse_cloud`], plus the optional fourth column: an integer set label per node. Nodes
/// with label k form the node set named "k" (usable as `select = { set = "k" }`); a fourth
/// column that is not an integer is ignored, like any later column.
pub fn parse_cloud_sets(text: &str, source: &Path) -> Result<(Vec<Vector3<f64>>, NodeSets)> {
    let mut sets: std::collections::BTreeMap<String, Vec<usize>> = Default::default();
    let name = source.display();
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut nodes = Vec::new();
    let mut first_data_line = true;
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = match raw.find('#') {
            Some(k) => &raw[..k],
            None => raw,
        }
        .trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = if line.contains([',', ';']) {
            line.split([',', ';'])
                .map(|f| f.trim().trim_matches('"').trim())
                .collect()
        } else {
            line.split_whitespace().collect()
        };
        let is_header = first_data_line
            && fields
                .iter()
                .take(3)
                .all(|f| f.is_empty() || f.parse::<f64>().is_err());
        first_data_line = false;
        if is_header {
            continue;
        }
        if fields.len() < 3 {
            return Err(Error::input(
                InputKind::Format,
                format!("{name}: line {line_no}: expected 3 numbers x y z, found '{line}'"),
            )
            .placed(source, line_no));
        }
        let mut x = [0.0; 3];
        for (v, f) in x.iter_mut().zip(&fields) {
            *v = f.parse::<f64>().map_err(|_| {
                Error::input(
                    InputKind::Format,
                    format!("{name}: line {line_no}: expected 3 numbers x y z, found '{f}'"),
                )
                .placed(source, line_no)
            })?;
            if !v.is_finite() {
                return Err(Error::input(
                    InputKind::Format,
                    format!("{name}: line {line_no}: coordinate '{f}' is not finite"),
                )
                .placed(source, line_no));
            }
        }
        if let Some(label) = fields.get(3).and_then(|f| f.parse::<i64>().ok()) {
            sets.entry(label.to_string()).or_default().push(nodes.len());
        }
        nodes.push(Vector3::new(x[0], x[1], x[2]));
    }
    if nodes.is_empty() {
        return Err(Error::input(
            InputKind::Format,
            format!("{name}: no nodes found; a node cloud needs one line 'x y z' (m) per node"),
        ));
    }
    Ok((nodes, sets))
}

/// Mesh vertices that at least one cell uses (the default cloud: the vertices of a tet mesh).
/// Returns the nodes (m, in their mesh order) and the old->new index map (None for dropped). Unused mesh nodes would be nodes without integration points nearby, which only
/// add unknowns with no stiffness (Horton et al. 2010 sect. 3.1 use the tet vertices).
/// Connectivity entries beyond the node list are ignored rather than panicking; meshes are
/// checked for them when read.
pub fn mesh_vertices(mesh: &Mesh) -> (Vec<Vector3<f64>>, Vec<Option<usize>>) {
    let mut used = vec![false; mesh.nodes.len()];
    for &i in &mesh.cells {
        if let Some(u) = used.get_mut(i) {
            *u = true;
        }
    }
    let mut map = vec![None; mesh.nodes.len()];
    let mut nodes = Vec::new();
    for (i, p) in mesh.nodes.iter().enumerate() {
        if used[i] {
            map[i] = Some(nodes.len());
            nodes.push(*p);
        }
    }
    (nodes, map)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::ElementShape;
    use std::path::PathBuf;

    fn test_box() -> Domain {
        Domain::Box {
            min: Vector3::new(0.0, 0.0, 0.0),
            max: Vector3::new(0.1, 0.05, 0.02),
        }
    }

    fn test_cylinder() -> Domain {
        Domain::Cylinder {
            radius: 0.05,
            height: 0.1,
        }
    }

    fn min_distance(p: &[Vector3<f64>]) -> f64 {
        let mut d = f64::INFINITY;
        for i in 0..p.len() {
            for j in i + 1..p.len() {
                d = d.min((p[i] - p[j]).norm());
            }
        }
        d
    }

    /// Asserts that each box face (or cylinder cap / lateral surface) carries nodes exactly on
    /// it; returns the counts per surface.
    fn surface_counts(domain: &Domain, nodes: &[Vector3<f64>]) -> Vec<usize> {
        let on = |p: &Vector3<f64>| domain.signed_distance(p).abs() < 1e-12;
        let counts: Vec<usize> = match *domain {
            Domain::Box { min, max } => (0..3)
                .flat_map(|a| [(a, min[a]), (a, max[a])])
                .map(|(a, v)| nodes.iter().filter(|p| on(p) && p[a] == v).count())
                .collect(),
            Domain::Cylinder { radius, height } => vec![
                nodes.iter().filter(|p| on(p) && p.z == 0.0).count(),
                nodes.iter().filter(|p| on(p) && p.z == height).count(),
                nodes
                    .iter()
                    .filter(|p| on(p) && (p.x.hypot(p.y) - radius).abs() < 1e-12)
                    .count(),
            ],
            Domain::HalfEllipsoid { .. } => unreachable!("no half-ellipsoid clouds"),
        };
        assert!(counts.iter().all(|&c| c > 0), "{counts:?}");
        counts
    }

    #[test]
    fn lattice_counts_without_jitter() {
        let b = jittered_lattice(&test_box(), 0.01, 0.0, 1).unwrap();
        assert_eq!(b.len(), 11 * 6 * 3);
        // m = 5 rings of 6, 13, 19, 25, 31 points plus the centre, 11 layers.
        let c = jittered_lattice(&test_cylinder(), 0.01, 0.0, 1).unwrap();
        assert_eq!(c.len(), (1 + 6 + 13 + 19 + 25 + 31) * 11);
        println!("lattice counts: box {} cylinder {}", b.len(), c.len());
    }

    #[test]
    fn lattice_inside_on_surfaces_duplicate_free() {
        for domain in [test_box(), test_cylinder()] {
            for jitter in [0.0, 0.3, 0.49] {
                let nodes = jittered_lattice(&domain, 0.01, jitter, 7).unwrap();
                assert!(nodes.iter().all(|p| domain.contains(p, 1e-12)));
                let counts = surface_counts(&domain, &nodes);
                let dmin = min_distance(&nodes);
                assert!(dmin > 1e-4, "min distance {dmin}");
                // Off-surface nodes keep clear of it.
                let deepest_shallow = nodes
                    .iter()
                    .map(|p| domain.signed_distance(p))
                    .filter(|d| d.abs() >= 1e-12)
                    .fold(f64::NEG_INFINITY, f64::max);
                assert!(deepest_shallow <= -0.05 * 0.01, "{deepest_shallow}");
                println!(
                    "lattice {domain:?} jitter {jitter}: {} nodes, surface {counts:?}, min \
                     spacing {dmin:.4e} m, closest interior node {:.4e} m inside",
                    nodes.len(),
                    -deepest_shallow
                );
            }
        }
    }

    #[test]
    fn lattice_seeds() {
        for domain in [test_box(), test_cylinder()] {
            let a = jittered_lattice(&domain, 0.01, 0.3, 11).unwrap();
            let b = jittered_lattice(&domain, 0.01, 0.3, 11).unwrap();
            let c = jittered_lattice(&domain, 0.01, 0.3, 12).unwrap();
            assert_eq!(a, b);
            assert_ne!(a, c);
        }
    }

    #[test]
    fn lattice_rejects_bad_input() {
        let d = test_box();
        assert!(jittered_lattice(&d, 0.0, 0.1, 1).is_err());
        assert!(jittered_lattice(&d, f64::NAN, 0.1, 1).is_err());
        assert!(jittered_lattice(&d, 0.01, 0.5, 1).is_err());
        assert!(jittered_lattice(&d, 0.01, -0.1, 1).is_err());
        let e = jittered_lattice(&d, 1e-5, 0.1, 1).unwrap_err().to_string();
        assert!(e.contains("limit"), "{e}");
        let e = jittered_lattice(&test_cylinder(), 1e-5, 0.1, 1).unwrap_err();
        assert!(e.to_string().contains("limit"), "{e}");
        let bad = Domain::Cylinder {
            radius: -1.0,
            height: 1.0,
        };
        assert!(jittered_lattice(&bad, 0.01, 0.1, 1).is_err());
    }

    #[test]
    fn halton_spacing_surfaces_seeds() {
        for domain in [test_box(), test_cylinder()] {
            let s = 0.008;
            let nodes = halton_fill(&domain, 100_000, s, 3).unwrap();
            assert!(nodes.iter().all(|p| domain.contains(p, 1e-12)));
            let dmin = min_distance(&nodes);
            assert!(dmin >= s * (1.0 - 1e-12), "min distance {dmin} < {s}");
            let counts = surface_counts(&domain, &nodes);
            let density = nodes.len() as f64 * s.powi(3) / domain.volume();
            println!(
                "halton {domain:?} s {s}: {} nodes (saturated), surface {counts:?}, min spacing \
                 {dmin:.6e} m, nodes x s^3 / V = {density:.3}",
                nodes.len()
            );
            // A requested count below saturation is met exactly.
            let few = halton_fill(&domain, nodes.len() - 20, s, 3).unwrap();
            assert_eq!(few.len(), nodes.len() - 20);
            let again = halton_fill(&domain, 100_000, s, 3).unwrap();
            assert_eq!(nodes, again);
            let other = halton_fill(&domain, 100_000, s, 4).unwrap();
            assert_ne!(nodes, other);
        }
    }

    #[test]
    fn halton_rejects_bad_input() {
        let d = test_box();
        assert!(halton_fill(&d, 0, 0.01, 1).is_err());
        assert!(halton_fill(&d, 100, 0.0, 1).is_err());
        assert!(halton_fill(&d, 100, 0.03, 1).is_err()); // above the 0.02 m side
        let e = halton_fill(&d, 10, 0.005, 1).unwrap_err().to_string();
        assert!(e.contains("surface"), "{e}");
        let e = halton_fill(&d, 100, 1e-9, 1).unwrap_err().to_string();
        assert!(e.contains("surface"), "{e}");
        assert!(halton_fill(&test_cylinder(), 1000, 0.09, 1).is_err());
    }

    #[test]
    fn parse_csv_with_header_and_xyz() {
        let src = PathBuf::from("nodes.csv");
        let csv = "x,y,z,id\n# a comment\n0.1, 0.2, 0.3, 1\n\n1e-3;2;3\n";
        let n = parse_cloud(csv, &src).unwrap();
        assert_eq!(
            n,
            vec![Vector3::new(0.1, 0.2, 0.3), Vector3::new(1e-3, 2.0, 3.0)]
        );
        let xyz = "\u{feff}0 0 0\n  1\t2 3  # trailing\r\n-1 -2 -3 extra\n";
        let n = parse_cloud(xyz, &src).unwrap();
        assert_eq!(n.len(), 3);
        assert_eq!(n[2], Vector3::new(-1.0, -2.0, -3.0));
    }

    #[test]
    fn parse_errors_name_file_and_line() {
        let src = PathBuf::from("cloud.xyz");
        let e = parse_cloud("0 0 0\n1 1 1\n\n# c\n1 abc 2\n", &src)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cloud.xyz") && e.contains("line 5") && e.contains("'abc'"),
            "{e}"
        );
        let e = parse_cloud("0 0 0\n1 2\n", &src).unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
        let e = parse_cloud("0 0 0\n1 NaN 2\n", &src)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("not finite"), "{e}");
        let e = parse_cloud("0,0,inf\n", &src).unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("not finite"), "{e}");
        // A header is only allowed first.
        let e = parse_cloud("0 0 0\nx y z\n", &src).unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
        let e = parse_cloud("# only comments\n\n", &src)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no nodes"), "{e}");
        assert!(parse_cloud("x,y,z\n", &src).is_err());
        assert!(parse_cloud("", &src).is_err());
    }

    #[test]
    fn read_cloud_reports_missing_file() {
        let p = PathBuf::from("/nonexistent/hytled-cloud.csv");
        let e = read_cloud(&p).unwrap_err().to_string();
        assert!(e.contains("hytled-cloud.csv"), "{e}");
    }

    #[test]
    fn mesh_vertices_drops_unused() {
        let mesh = Mesh {
            nodes: vec![
                Vector3::new(0.0, 0.0, 0.0),
                Vector3::new(9.0, 9.0, 9.0),
                Vector3::new(1.0, 0.0, 0.0),
                Vector3::new(0.0, 1.0, 0.0),
                Vector3::new(0.0, 0.0, 1.0),
            ],
            shape: ElementShape::Tet4,
            cells: vec![0, 2, 3, 4],
        };
        let (nodes, map) = mesh_vertices(&mesh);
        assert_eq!(nodes.len(), 4);
        assert_eq!(map, vec![Some(0), None, Some(1), Some(2), Some(3)]);
        assert_eq!(nodes[3], Vector3::new(0.0, 0.0, 1.0));
        let full = crate::geometry::shapes::box_tet(
            Vector3::zeros(),
            Vector3::new(1.0, 1.0, 1.0),
            [2, 2, 2],
        )
        .unwrap();
        let (nodes, map) = mesh_vertices(&full);
        assert_eq!(nodes.len(), 27);
        assert!(map.iter().enumerate().all(|(i, &j)| j == Some(i)));
    }
}
