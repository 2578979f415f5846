//! A body given by its surface (an STL, OBJ or VTK file from a segmentation): the checks that
//! make it a body TetGen can fill, with errors that name the offending triangle or edge.
//!
//! A usable surface is closed (every edge borders exactly two triangles), consistently oriented
//! (the two use the edge in opposite directions), free of degenerate triangles, and does not
//! cross itself. It is one body: an outer piece and closed pieces nested in it, which are
//! cavities (a ventricle), by the even-odd rule. It is returned oriented out of the material
//! (the outer piece outward, cavities inward; a piece oriented the other way is turned, not
//! refused).

use std::collections::HashMap;

use nalgebra::Vector3;

use super::select::bounds;
use super::winding::winding_number;
use crate::{Error, InputKind, Result};

/// A checked closed surface: points (m) and outward triangles over them.
#[derive(Debug, Clone)]
pub struct ClosedSurface {
    pub points: Vec<Vector3<f64>>,
    pub triangles: Vec<[usize; 3]>,
    /// A point inside each cavity (a closed piece nested in the outer one), m.
    pub holes: Vec<Vector3<f64>>,
}

impl ClosedSurface {
    /// The volume of material it encloses (cavities excluded), m^3.
    pub fn volume(&self) -> f64 {
        super::dome::enclosed_volume(&self.points, &self.triangles)
    }
}

fn at(p: &Vector3<f64>) -> String {
    format!("({:.6e}, {:.6e}, {:.6e}) m", p.x, p.y, p.z)
}

/// Checks the surface `triangles` over `points` (m) read from `what` (a file name, for the
/// messages) and returns it oriented outward. Points no triangle uses are dropped.
pub fn check_closed_surface(
    what: &str,
    points: Vec<Vector3<f64>>,
    triangles: Vec<[usize; 3]>,
) -> Result<ClosedSurface> {
    let bad = |msg: String| Error::input(InputKind::Mesh, format!("{what}: {msg}"));
    if triangles.len() < 4 {
        return Err(bad(format!(
            "{} triangle(s); a closed surface needs at least 4",
            triangles.len()
        )));
    }
    if let Some((k, t)) = triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&i| i >= points.len()))
    {
        return Err(bad(format!(
            "triangle {k} refers to vertex {} of {}",
            t.iter().max().copied().unwrap_or(0),
            points.len()
        )));
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        return Err(bad(format!(
            "vertex {i} has a coordinate that is not finite"
        )));
    }
    let (lo, hi) = bounds(&points);
    let diag = (hi - lo).norm();
    // Degenerate triangles: a repeated vertex or no area.
    for (k, t) in triangles.iter().enumerate() {
        let [a, b, c] = t.map(|i| points[i]);
        let area2 = (b - a).cross(&(c - a)).norm();
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || !(area2 > 1e-12 * diag * diag) {
            return Err(bad(format!(
                "triangle {k} (vertices {}, {}, {} at {}) is degenerate (no area); remove it or \
                 repair the surface (e.g. MeshLab's 'Remove Zero Area Faces')",
                t[0],
                t[1],
                t[2],
                at(&a)
            )));
        }
    }
    // Slivers: a triangle whose height is a millionth of its longest edge has an area above
    // the check above but no usable shape (a vertex almost on the opposite edge: a T-junction
    // left by a mesh tool); meshers and shape functions fail on it later, far from the cause.
    for (k, t) in triangles.iter().enumerate() {
        let [a, b, c] = t.map(|i| points[i]);
        let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
        let height = (b - a).cross(&(c - a)).norm() / longest;
        if !(height > 1e-6 * longest) {
            return Err(bad(format!(
                "triangle {k} (vertices {}, {}, {} at {}) is a sliver: {sci_height:.3e} m high against an edge of \
                 {sci_longest:.3e} m (a vertex almost on the opposite edge); remove it or repair the surface \
                 (e.g. MeshLab's 'Remove T-Vertices' or 'Remove Zero Area Faces', or remesh it)",
                t[0],
                t[1],
                t[2],
                at(&a)
            , sci_height = crate::error::Sci(height), sci_longest = crate::error::Sci(longest))));
        }
    }
    // Each directed edge once, and its reverse once.
    let mut directed: HashMap<(usize, usize), usize> = HashMap::with_capacity(3 * triangles.len());
    for (k, t) in triangles.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            if let Some(other) = directed.insert((a, b), k) {
                return Err(bad(format!(
                    "the edge from vertex {a} to vertex {b} (at {}) is used in the same direction by \
                     triangles {other} and {k}: the orientation flips there, or more than two \
                     triangles meet at the edge; orient the triangles consistently (e.g. MeshLab's \
                     'Re-Orient all faces coherently') and make the surface manifold",
                    at(&points[a])
                )));
            }
        }
    }
    for (&(a, b), &k) in &directed {
        if !directed.contains_key(&(b, a)) {
            return Err(bad(format!(
                "the surface is open: the edge from vertex {a} to vertex {b} (at {}) borders only \
                 triangle {k}; close the hole (e.g. MeshLab's 'Close Holes') or merge its vertices \
                 if they are duplicated",
                at(&points[a])
            )));
        }
    }
    if let Some(v) = pinched_vertex(&triangles, &directed) {
        return Err(bad(format!(
            "vertex {v} (at {}) joins sheets that meet only there: two bodies (or two parts of one) \
             touch at a single vertex; give one body per file and keep bodies apart (or join them \
             by a face)",
            at(&points[v])
        )));
    }
    if let Some((i, j)) = coincident_vertices(&points, &triangles, 1e-9 * diag) {
        return Err(bad(format!(
            "vertices {i} and {j} lie at the same place (at {}) without being one vertex: the \
             surface touches or crosses itself there (two pieces that meet, e.g. two bodies \
             overlapping); separate them, or merge the vertices if they are meant to be one",
            at(&points[i])
        )));
    }
    // Connected pieces: one outer piece, and pieces nested in it as cavities (even-odd).
    let piece = pieces_of(points.len(), &triangles);
    let pieces = piece.iter().max().map_or(0, |&p| p + 1);
    let crossing = self_intersection(&points, &triangles, diag);
    crate::interrupt::check(|| format!("while checking the surface {what}"))?;
    if let Some((k, m)) = crossing {
        return Err(bad(format!(
            "the surface crosses itself: triangles {k} and {m} intersect (near {}); repair it \
             (e.g. MeshLab's 'Select Self Intersecting Faces')",
            at(&points[triangles[k][0]])
        )));
    }
    // Only the points the triangles use, renumbered in order of first use.
    let mut map = vec![usize::MAX; points.len()];
    let mut kept = Vec::new();
    let mut triangles = triangles;
    for t in triangles.iter_mut() {
        for i in t.iter_mut() {
            if map[*i] == usize::MAX {
                map[*i] = kept.len();
                kept.push(points[*i]);
            }
            *i = map[*i];
        }
    }
    let members: Vec<Vec<usize>> = (0..pieces)
        .map(|p| (0..triangles.len()).filter(|&k| piece[k] == p).collect())
        .collect();
    let faces_of = |p: usize| members[p].iter().map(|&k| &triangles[k][..]);
    // Nesting depth: how many other pieces hold one of its vertices (pieces do not cross).
    let depth: Vec<usize> = (0..pieces)
        .map(|p| {
            let x = kept[triangles[members[p][0]][0]];
            (0..pieces)
                .filter(|&q| q != p && winding_number(&x, &kept, faces_of(q)).abs() > 0.5)
                .count()
        })
        .collect();
    let outer: Vec<usize> = (0..pieces).filter(|&p| depth[p] == 0).collect();
    if outer.len() > 1 {
        let k = members[outer[1]][0];
        return Err(bad(format!(
            "the file holds {} separate bodies (triangle {k}, at {}, belongs to a closed surface \
             outside the one of triangle {}); give one body per file (closed surfaces inside it \
             are cavities; a tumour or other region goes in its own file under [regions])",
            outer.len(),
            at(&kept[triangles[k][0]]),
            members[outer[0]][0]
        )));
    }
    // Outward from the material: even depths enclose material, odd ones (cavities) face in.
    for p in 0..pieces {
        let v = super::dome::enclosed_volume(
            &kept,
            &members[p].iter().map(|&k| triangles[k]).collect::<Vec<_>>(),
        );
        if (v < 0.0) == (depth[p] % 2 == 0) {
            for &k in &members[p] {
                triangles[k].swap(1, 2);
            }
        }
    }
    let holes = (0..pieces)
        .filter(|&p| depth[p] % 2 == 1)
        .map(|p| cavity_point(&kept, &triangles, &members[p]).ok_or_else(|| {
            bad(format!(
                "no point inside the cavity bounded by triangle {} could be found; the cavity is too thin",
                members[p][0]
            ))
        }))
        .collect::<Result<Vec<_>>>()?;
    Ok(ClosedSurface {
        points: kept,
        triangles,
        holes,
    })
}

/// The body `body` with the closed surfaces `inner` (a name for messages, the surface) inside
/// its material, for TetGen: one point list (the body's, then each inner surface's), the body's
/// triangles and cavities, and the inner surfaces' triangles as internal facets. Errors name
/// the surface: one outside the body or in a cavity, or one crossing the body or another.
pub fn nest(
    body: ClosedSurface,
    inner: &[(String, ClosedSurface)],
) -> Result<(ClosedSurface, Vec<Vec<usize>>)> {
    if inner.is_empty() {
        return Ok((body, Vec::new()));
    }
    let mut points = body.points.clone();
    let mut all: Vec<[usize; 3]> = body.triangles.clone();
    let mut owner: Vec<usize> = vec![0; all.len()];
    let mut internal = Vec::new();
    for (k, (name, s)) in inner.iter().enumerate() {
        let x = s.points[s.triangles[0][0]];
        let w = winding_number(&x, &body.points, body.triangles.iter().map(|t| &t[..]));
        if w < 0.5 {
            return Err(Error::input(
                InputKind::Mesh,
                format!(
                    "region '{name}': its surface (vertex at {}) lies outside the body's material \
                 (outside the body or in a cavity); a region surface must lie inside the body",
                    at(&x)
                ),
            ));
        }
        let base = points.len();
        points.extend_from_slice(&s.points);
        for t in &s.triangles {
            let t = t.map(|i| i + base);
            all.push(t);
            owner.push(k + 1);
            internal.push(t.to_vec());
        }
    }
    let (lo, hi) = bounds(&points);
    if let Some((a, b)) = self_intersection(&points, &all, (hi - lo).norm()) {
        let name = |o: usize| {
            if o == 0 {
                "the body's surface".to_string()
            } else {
                format!("region '{}'", inner[o - 1].0)
            }
        };
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "{} and {} cross (near {}); a region surface must lie inside the body without \
             touching its surface or another region's",
                name(owner[a]),
                name(owner[b]),
                at(&points[all[a][0]])
            ),
        ));
    }
    Ok((
        ClosedSurface {
            points,
            triangles: body.triangles,
            holes: body.holes,
        },
        internal,
    ))
}

/// `surface` with every vertex moved by `distance` (m; positive out of the material) along
/// its angle-weighted normal, checked again (a distance beyond the surface's smallest radius
/// of curvature folds it: refused as a crossing). `what` names it in errors.
pub fn offset(surface: &ClosedSurface, distance: f64, what: &str) -> Result<ClosedSurface> {
    let p = &surface.points;
    let mut normals = vec![Vector3::zeros(); p.len()];
    for t in &surface.triangles {
        let n = (p[t[1]] - p[t[0]]).cross(&(p[t[2]] - p[t[0]])).normalize();
        for k in 0..3 {
            let a = t[k];
            let (u, v) = (p[t[(k + 1) % 3]] - p[a], p[t[(k + 2) % 3]] - p[a]);
            normals[a] += n * u.angle(&v);
        }
    }
    let points = p
        .iter()
        .zip(&normals)
        .map(|(x, n)| x + n.normalize() * distance)
        .collect();
    check_closed_surface(
        &format!("{what} (offset by {distance} m)"),
        points,
        surface.triangles.clone(),
    )
}

/// A point inside the cavity bounded by the triangles `members` (oriented out of the
/// material, so into the cavity): a little off one of its larger triangles, where the whole
/// surface winds zero times (no material).
fn cavity_point(
    points: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    members: &[usize],
) -> Option<Vector3<f64>> {
    let mut by_area: Vec<(f64, usize)> = members
        .iter()
        .map(|&k| {
            let [a, b, c] = triangles[k].map(|i| points[i]);
            ((b - a).cross(&(c - a)).norm(), k)
        })
        .collect();
    by_area.sort_by(|x, y| y.0.total_cmp(&x.0));
    for &(area2, k) in by_area.iter().take(16) {
        let [a, b, c] = triangles[k].map(|i| points[i]);
        let n = (b - a).cross(&(c - a)) / area2;
        let centre = (a + b + c) / 3.0;
        for f in [0.1, 0.01, 0.001] {
            let x = centre + n * (f * (0.5 * area2).sqrt());
            let w = winding_number(&x, points, triangles.iter().map(|t| &t[..]));
            if w.abs() < 0.1 {
                return Some(x);
            }
        }
    }
    None
}

/// A vertex whose triangles form more than one fan (sheets that meet at that vertex alone),
/// given each directed edge's triangle of a closed, consistently oriented surface.
fn pinched_vertex(
    triangles: &[[usize; 3]],
    directed: &HashMap<(usize, usize), usize>,
) -> Option<usize> {
    let mut around: HashMap<usize, usize> = HashMap::new();
    for t in triangles {
        for &v in t {
            *around.entry(v).or_default() += 1;
        }
    }
    let mut first: HashMap<usize, usize> = HashMap::new();
    for (k, t) in triangles.iter().enumerate() {
        for &v in t {
            first.entry(v).or_insert(k);
        }
    }
    let mut vertices: Vec<usize> = first.keys().copied().collect();
    vertices.sort_unstable();
    for v in vertices {
        let start = first[&v];
        let (mut k, mut steps) = (start, 0usize);
        loop {
            let t = triangles[k];
            let e = t.iter().position(|&x| x == v)?;
            // The triangle across the edge from the vertex before v to v holds v -> that vertex.
            let before = t[(e + 2) % 3];
            k = *directed.get(&(v, before))?;
            steps += 1;
            if k == start || steps > around[&v] {
                break;
            }
        }
        if steps < around[&v] {
            return Some(v);
        }
    }
    None
}

/// Two distinct vertices the triangles use within `eps` (m) of each other.
fn coincident_vertices(
    points: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    eps: f64,
) -> Option<(usize, usize)> {
    let mut used: Vec<usize> = triangles.iter().flatten().copied().collect();
    used.sort_unstable();
    used.dedup();
    let eps = eps.max(f64::MIN_POSITIVE);
    let key = |p: &Vector3<f64>| p.map(|x| (x / eps).floor() as i64);
    let mut grid: HashMap<Vector3<i64>, Vec<usize>> = HashMap::with_capacity(used.len());
    for &i in &used {
        let k = key(&points[i]);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(near) = grid.get(&(k + Vector3::new(dx, dy, dz))) {
                        if let Some(&j) = near
                            .iter()
                            .find(|&&j| (points[j] - points[i]).norm() <= eps)
                        {
                            return Some((j.min(i), j.max(i)));
                        }
                    }
                }
            }
        }
        grid.entry(k).or_default().push(i);
    }
    None
}

/// The connected piece of each triangle (sharing vertices), numbered 0.. in order of first
/// appearance; `n_points` is the number of vertices the triangles index.
pub(crate) fn pieces_of(n_points: usize, triangles: &[[usize; 3]]) -> Vec<usize> {
    let mut parent: Vec<usize> = (0..n_points).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for t in triangles {
        for e in 0..2 {
            let (a, b) = (root(&mut parent, t[e]), root(&mut parent, t[e + 1]));
            parent[a] = b;
        }
    }
    let mut piece_of_root: HashMap<usize, usize> = HashMap::new();
    triangles
        .iter()
        .map(|t| {
            let r = root(&mut parent, t[0]);
            let n = piece_of_root.len();
            *piece_of_root.entry(r).or_insert(n)
        })
        .collect()
}

/// Whether segment p q crosses triangle a b c (at a point strictly inside both, within
/// rounding `eps` of the triangle's size).
fn segment_crosses(
    p: &Vector3<f64>,
    q: &Vector3<f64>,
    [a, b, c]: [&Vector3<f64>; 3],
    eps: f64,
) -> bool {
    let n = (b - a).cross(&(c - a));
    let (dp, dq) = (n.dot(&(p - a)), n.dot(&(q - a)));
    let scale = eps * n.norm();
    if !((dp > scale && dq < -scale) || (dp < -scale && dq > scale)) {
        return false;
    }
    let x = p + (q - p) * (dp / (dp - dq));
    let inside =
        |u: &Vector3<f64>, v: &Vector3<f64>| n.dot(&(v - u).cross(&(x - u))) > scale * 1e-3;
    inside(a, b) && inside(b, c) && inside(c, a)
}

/// The first pair of triangles sharing no vertex whose interiors cross, found through a grid
/// of the triangles' bounding boxes (cells of about the mean triangle size).
fn self_intersection(
    points: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    diag: f64,
) -> Option<(usize, usize)> {
    let boxes: Vec<(Vector3<f64>, Vector3<f64>)> = triangles
        .iter()
        .map(|t| bounds(&t.map(|i| points[i])))
        .collect();
    let mean = boxes.iter().map(|(l, h)| (h - l).amax()).sum::<f64>() / boxes.len() as f64;
    let cell = mean.max(1e-12 * diag);
    let (lo, _) = bounds(points);
    let key = |p: &Vector3<f64>| ((p - lo) / cell).map(|x| x.floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (k, (l, h)) in boxes.iter().enumerate() {
        let (kl, kh) = (key(l), key(h));
        // A needle across the model would fill the grid: such triangles are few; cap the cells.
        let cells = (0..3)
            .map(|d| (kh[d] - kl[d] + 1) as usize)
            .product::<usize>();
        if cells > 4096 {
            continue;
        }
        for x in kl.x..=kh.x {
            for y in kl.y..=kh.y {
                for z in kl.z..=kh.z {
                    grid.entry([x, y, z]).or_default().push(k);
                }
            }
        }
    }
    let eps = 1e-9;
    for (visited, members) in grid.values().enumerate() {
        // A stop request ends the search (the caller then stops); checked every 4,096 cells.
        if visited % 4096 == 0 && crate::interrupt::requested().is_some() {
            return None;
        }
        for (i, &k) in members.iter().enumerate() {
            for &m in &members[i + 1..] {
                let (tk, tm) = (triangles[k], triangles[m]);
                if tk.iter().any(|v| tm.contains(v)) {
                    continue;
                }
                let (bk, bm) = (&boxes[k], &boxes[m]);
                if (0..3).any(|d| bk.1[d] < bm.0[d] || bm.1[d] < bk.0[d]) {
                    continue;
                }
                let pk = tk.map(|i| &points[i]);
                let pm = tm.map(|i| &points[i]);
                let crosses = (0..3).any(|e| segment_crosses(pk[e], pk[(e + 1) % 3], pm, eps))
                    || (0..3).any(|e| segment_crosses(pm[e], pm[(e + 1) % 3], pk, eps));
                if crosses {
                    return Some((k.min(m), k.max(m)));
                }
            }
        }
    }
    None
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The unit cube as 12 outward triangles.
    pub(crate) fn cube() -> (Vec<Vector3<f64>>, Vec<[usize; 3]>) {
        let p: Vec<Vector3<f64>> = (0..8)
            .map(|i| Vector3::new((i & 1) as f64, ((i >> 1) & 1) as f64, (i >> 2) as f64))
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let t = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        (p, t)
    }

    #[test]
    fn a_cube_passes_and_an_inward_one_is_turned() {
        let (p, t) = cube();
        let s = check_closed_surface("cube.stl", p.clone(), t.clone()).unwrap();
        assert!((s.volume() - 1.0).abs() < 1e-14);
        let inward = t.iter().map(|t| [t[0], t[2], t[1]]).collect();
        let s = check_closed_surface("cube.stl", p, inward).unwrap();
        assert!((s.volume() - 1.0).abs() < 1e-14);
    }

    /// A cube with a cubic cavity (given either way round): the material's volume, the cavity
    /// turned to face into itself, and a hole point inside the cavity.
    #[test]
    fn a_nested_surface_is_a_cavity() {
        let (p, t) = cube();
        for inner_flipped in [false, true] {
            let (mut p2, mut t2) = (p.clone(), t.clone());
            p2.extend(p.iter().map(|x| x / 3.0 + Vector3::repeat(1.0 / 3.0)));
            t2.extend(t.iter().map(|t| {
                let t = t.map(|i| i + 8);
                if inner_flipped {
                    [t[0], t[2], t[1]]
                } else {
                    t
                }
            }));
            let s = check_closed_surface("c.stl", p2, t2).unwrap();
            assert!(
                (s.volume() - (1.0 - 1.0 / 27.0)).abs() < 1e-14,
                "{}",
                s.volume()
            );
            assert_eq!(s.holes.len(), 1);
            let h = s.holes[0];
            assert!(h.iter().all(|&x| x > 1.0 / 3.0 && x < 2.0 / 3.0), "{h}");
        }
    }

    #[test]
    fn open_flipped_degenerate_split_and_crossing_surfaces_are_refused_naming_where() {
        let (p, t) = cube();
        let err = |p: Vec<Vector3<f64>>, t: Vec<[usize; 3]>| {
            check_closed_surface("s.stl", p, t).unwrap_err().to_string()
        };
        let mut open = t.clone();
        open.pop();
        let e = err(p.clone(), open);
        assert!(
            e.starts_with("s.stl: ") && e.contains("open") && e.contains("borders only triangle"),
            "{e}"
        );
        let mut flipped = t.clone();
        flipped[3] = [flipped[3][0], flipped[3][2], flipped[3][1]];
        let e = err(p.clone(), flipped);
        assert!(
            e.contains("same direction") && e.contains("triangles"),
            "{e}"
        );
        let mut degenerate = t.clone();
        degenerate[0][1] = degenerate[0][0];
        let e = err(p.clone(), degenerate);
        assert!(e.contains("triangle 0") && e.contains("degenerate"), "{e}");
        // Two separate cubes.
        let (mut p2, mut t2) = (p.clone(), t.clone());
        p2.extend(p.iter().map(|x| x + Vector3::new(3.0, 0.0, 0.0)));
        t2.extend(t.iter().map(|t| t.map(|i| i + 8)));
        let e = err(p2, t2);
        assert!(
            e.contains("2 separate bodies") && e.contains("triangle 12"),
            "{e}"
        );
        // A cube with one top corner pushed down through the bottom: its faces cross.
        let mut crossing = p.clone();
        crossing[7] = Vector3::new(0.3, 0.3, -0.5);
        let e = err(crossing, t.clone());
        assert!(e.contains("crosses itself"), "{e}");
    }
}
