//! A body given by its surface (an STL, OBJ or VTK file from a segmentation): the checks that
//! make it a body TetGen can fill, with errors that name the offending triangle or edge.
//!
//! A usable surface is closed (every edge borders exactly two triangles), consistently oriented
//! (the two use the edge in opposite directions), free of degenerate triangles, one connected
//! piece, and does not cross itself. It is returned oriented outward (positive enclosed
//! volume; a surface oriented inward throughout is turned, not refused).

use std::collections::HashMap;

use nalgebra::Vector3;

use super::select::bounds;
use crate::{Error, Result};

/// A checked closed surface: points (m) and outward triangles over them.
#[derive(Debug, Clone)]
pub struct ClosedSurface {
    pub points: Vec<Vector3<f64>>,
    pub triangles: Vec<[usize; 3]>,
}

impl ClosedSurface {
    /// The volume it encloses, m^3.
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
    let bad = |msg: String| Error::Input(format!("{what}: {msg}"));
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
    // One connected piece (nested or separate bodies are not one body).
    let mut parent: Vec<usize> = (0..points.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for t in &triangles {
        for e in 0..2 {
            let (a, b) = (root(&mut parent, t[e]), root(&mut parent, t[e + 1]));
            parent[a] = b;
        }
    }
    let first = root(&mut parent, triangles[0][0]);
    if let Some(k) = (0..triangles.len()).find(|&k| root(&mut parent, triangles[k][0]) != first) {
        return Err(bad(format!(
            "the file holds more than one closed surface (triangle {k}, at {}, is not connected to \
             triangle 0); give one closed surface per file (nested surfaces as regions are not \
             supported yet)",
            at(&points[triangles[k][0]])
        )));
    }
    if let Some((k, m)) = self_intersection(&points, &triangles, diag) {
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
    let mut s = ClosedSurface {
        points: kept,
        triangles,
    };
    if s.volume() < 0.0 {
        for t in s.triangles.iter_mut() {
            t.swap(1, 2);
        }
    }
    Ok(s)
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
    for members in grid.values() {
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
        assert!(e.contains("more than one closed surface"), "{e}");
        // A cube with one top corner pushed down through the bottom: its faces cross.
        let mut crossing = p.clone();
        crossing[7] = Vector3::new(0.3, 0.3, -0.5);
        let e = err(crossing, t.clone());
        assert!(e.contains("crosses itself"), "{e}");
    }
}
