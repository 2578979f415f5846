//! Signed distance to a closed surface (a rigid tool or the skull read from a file): the
//! closest point on its triangles (Ericson, Real-Time Collision Detection, 5.1.5) and the side
//! from the angle-weighted pseudo-normal of the closest face, edge or vertex (Baerentzen and
//! Aanaes 2005, IEEE TVCG 11(3)), which is exact for closed, consistently oriented surfaces.
//! Candidate triangles come from a k-d tree of their centroids: every triangle within distance
//! D of a point has its centroid within D + R (R the largest centroid-to-vertex distance), and
//! the triangle of the nearest centroid bounds D.
//!
//! The normal returned (the direction contact pushes along) is continuous where the surface is
//! smooth: the corner normals of the closest triangle interpolated at the closest point
//! (Phong), each corner averaging the faces round its vertex that the triangle reaches without
//! crossing a sharp edge (faces more than [`SMOOTH_ANGLE`] apart). A faceted organ or skull then has no jump of the normal at its edges, where
//! a point pressed against it would otherwise slide to and fro across the edge from one step
//! to the next and never settle (the MNI skull: error estimate stuck at 2-4e-5 m); flat faces
//! and sharp edges (a cube, a flat-ended indenter) keep their face and pseudo-normals.

use crate::InputKind;
use std::collections::HashMap;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;

use super::closed_surface::ClosedSurface;

/// Faces meeting at less than this angle (degrees) belong to one smooth surface: the normal
/// is interpolated across their edge. A tessellated cylinder of 5 or more segments is smooth;
/// a cube's or a flat-ended tool's edges (90 deg) stay sharp.
pub const SMOOTH_ANGLE: f64 = 75.0;

/// Where on a triangle its closest point lies.
#[derive(Clone, Copy)]
enum Feature {
    Face,
    /// The edge from corner k to corner (k + 1) % 3.
    Edge(usize),
    Vertex(usize),
}

/// A closed, outward surface ready for signed-distance queries.
#[derive(Debug)]
pub struct SurfaceDistance {
    surface: ClosedSurface,
    face_normals: Vec<Vector3<f64>>,
    /// Pseudo-normals of the edges (sum of the two faces' normals), keyed by (low, high)
    /// vertex index, and of the vertices (angle-weighted).
    edge_normals: HashMap<(usize, usize), Vector3<f64>>,
    vertex_normals: Vec<Vector3<f64>>,
    /// Unit normals at each triangle's corners: the angle-weighted mean of the faces round the
    /// corner's vertex that the triangle reaches without crossing a sharp edge (faces more than
    /// [`SMOOTH_ANGLE`] apart).
    corner_normals: Vec<[Vector3<f64>; 3]>,
    /// Vertices on no sharp edge.
    smooth_vertex: Vec<bool>,
    tree: ImmutableKdTree<f64, 3>,
    reach: f64,
}

impl SurfaceDistance {
    /// Indexes `surface` (checked: closed, outward).
    pub fn new(surface: ClosedSurface) -> crate::Result<Self> {
        let p = &surface.points;
        let face_normals: Vec<Vector3<f64>> = surface
            .triangles
            .iter()
            .map(|t| (p[t[1]] - p[t[0]]).cross(&(p[t[2]] - p[t[0]])).normalize())
            .collect();
        let mut edge_normals = HashMap::new();
        let mut vertex_normals = vec![Vector3::zeros(); p.len()];
        // (triangle, corner angle) round each vertex.
        let mut round: Vec<Vec<(usize, f64)>> = vec![Vec::new(); p.len()];
        for (i, (t, n)) in surface.triangles.iter().zip(&face_normals).enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edge_normals
                    .entry((a.min(b), a.max(b)))
                    .or_insert(Vector3::zeros()) += n;
                let (u, v) = (p[t[(k + 1) % 3]] - p[a], p[t[(k + 2) % 3]] - p[a]);
                let angle = u.angle(&v);
                vertex_normals[a] += n * angle;
                round[a].push((i, angle));
            }
        }
        // Smoothing groups round each vertex: its faces joined across the edges that are not
        // sharp (faces within SMOOTH_ANGLE of each other), by union-find over the fan.
        let cos_smooth = SMOOTH_ANGLE.to_radians().cos();
        let sharp = |a: usize, b: usize| {
            edge_normals
                .get(&(a.min(b), a.max(b)))
                .is_some_and(|n: &Vector3<f64>| 0.5 * n.norm_squared() - 1.0 < cos_smooth)
        };
        let tri = &surface.triangles;
        let mut smooth_vertex = vec![true; p.len()];
        let mut corner_normals: Vec<[Vector3<f64>; 3]> =
            face_normals.iter().map(|n| [*n; 3]).collect();
        let mut group: Vec<usize> = Vec::new();
        for (v, faces) in round.iter().enumerate() {
            group.clear();
            group.extend(0..faces.len());
            fn root(g: &mut [usize], mut i: usize) -> usize {
                while g[i] != i {
                    g[i] = g[g[i]];
                    i = g[i];
                }
                i
            }
            for x in 0..faces.len() {
                let tx = tri[faces[x].0];
                for y in x + 1..faces.len() {
                    let ty = tri[faces[y].0];
                    // The other vertex of an edge (v, w) both triangles have.
                    let shared = tx.iter().find(|&&w| w != v && ty.contains(&w)).copied();
                    if let Some(w) = shared {
                        if sharp(v, w) {
                            smooth_vertex[v] = false;
                        } else {
                            let (rx, ry) = (root(&mut group, x), root(&mut group, y));
                            group[rx] = ry;
                        }
                    }
                }
            }
            for x in 0..faces.len() {
                let rx = root(&mut group, x);
                let mut n = Vector3::zeros();
                for y in 0..faces.len() {
                    if root(&mut group, y) == rx {
                        n += face_normals[faces[y].0] * faces[y].1;
                    }
                }
                let (k, _) = faces[x];
                let c = tri[k].iter().position(|&w| w == v).unwrap_or(0);
                corner_normals[k][c] = n.try_normalize(0.0).unwrap_or(face_normals[k]);
            }
        }
        let centroids: Vec<[f64; 3]> = surface
            .triangles
            .iter()
            .map(|t| {
                let c = (p[t[0]] + p[t[1]] + p[t[2]]) / 3.0;
                [c.x, c.y, c.z]
            })
            .collect();
        let reach = surface
            .triangles
            .iter()
            .zip(&centroids)
            .map(|(t, c)| {
                let c = Vector3::from(*c);
                t.iter().map(|&i| (p[i] - c).norm()).fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        let tree = ImmutableKdTree::new_from_slice(&centroids).map_err(|e| {
            crate::Error::input(
                InputKind::Mesh,
                format!("cannot index the surface's triangles: {e:?}"),
            )
        })?;
        Ok(SurfaceDistance {
            surface,
            face_normals,
            edge_normals,
            vertex_normals,
            corner_normals,
            smooth_vertex,
            tree,
            reach,
        })
    }

    /// The surface it measures to.
    pub fn surface(&self) -> &ClosedSurface {
        &self.surface
    }

    /// Signed distance of `y` (m): positive inside the closed surface, minus the distance
    /// outside (the side from the pseudo-normal); with the outward unit normal at the closest
    /// point: interpolated from the closest triangle's corner normals where the surface is
    /// smooth there, the pseudo-normal of a sharp edge or vertex.
    pub fn signed_distance(&self, y: &Vector3<f64>) -> (f64, Vector3<f64>) {
        let (d, n, _) = self.closest(y);
        (d, n)
    }

    /// [`Self::signed_distance`] for contact: inside, the depth is measured along the returned
    /// normal to the tangent plane at the closest point (d / cos of the angle between the
    /// normal and the way to the closest point, which is d where the normal is the face's),
    /// so that a point pushed back by it along the normal lands on the surface in one
    /// correction.
    pub fn contact_depth(&self, y: &Vector3<f64>) -> (f64, Vector3<f64>) {
        let (d, n, x) = self.closest(y);
        if d > 0.0 {
            let cos = ((x - y) / d).dot(&n).abs();
            // Where the normal leans more than 78 deg from the way to the surface (which a
            // smooth surface's interpolated normal does not), the distance itself.
            if cos > 0.2 {
                return (d / cos, n);
            }
        }
        (d, n)
    }

    /// The signed distance, outward normal and closest point of `y`.
    fn closest(&self, y: &Vector3<f64>) -> (f64, Vector3<f64>, Vector3<f64>) {
        let q = [y.x, y.y, y.z];
        let nearest = self
            .tree
            .query(&q)
            .nearest_n::<SquaredEuclidean<f64>>(std::num::NonZero::<usize>::MIN)
            .execute();
        let Some(first) = nearest.first() else {
            return (f64::NEG_INFINITY, Vector3::z(), *y);
        };
        let bound = self.closest_on(first.item as usize, y).0;
        let r = bound + self.reach;
        let mut best = (f64::INFINITY, 0usize, Feature::Face, Vector3::zeros());
        for c in self
            .tree
            .query(&q)
            .within::<SquaredEuclidean<f64>>(r * r)
            .unsorted()
            .execute()
        {
            let k = c.item as usize;
            let (d, feature, x) = self.closest_on(k, y);
            // Ties (a vertex shared by several triangles) resolve to the lowest index, so the
            // answer does not depend on the tree's order.
            if d < best.0 || (d == best.0 && k < best.1) {
                best = (d, k, feature, x);
            }
        }
        if !best.0.is_finite() {
            let (d, f, x) = self.closest_on(first.item as usize, y);
            best = (d, first.item as usize, f, x);
        }
        let (d, k, feature, x) = best;
        let t = self.surface.triangles[k];
        let (normal, smooth) = match feature {
            Feature::Face => (self.face_normals[k], true),
            Feature::Edge(e) => {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                let n = self.edge_normals[&(a.min(b), a.max(b))];
                // |n_a + n_b|^2 = 2 + 2 cos(angle between the faces).
                let cos = 0.5 * n.norm_squared() - 1.0;
                (n, cos >= SMOOTH_ANGLE.to_radians().cos())
            }
            Feature::Vertex(v) => (self.vertex_normals[t[v]], self.smooth_vertex[t[v]]),
        };
        let inside = (y - x).dot(&normal) < 0.0;
        let outward = if smooth {
            self.interpolated_normal(k, &x)
                .unwrap_or_else(|| normal.normalize())
        } else {
            normal.normalize()
        };
        if inside {
            (d, outward, x)
        } else {
            (-d, outward, x)
        }
    }

    /// The corner normals of triangle `k` interpolated at its point `x` by barycentric weights
    /// (None for a degenerate triangle).
    fn interpolated_normal(&self, k: usize, x: &Vector3<f64>) -> Option<Vector3<f64>> {
        let t = self.surface.triangles[k];
        let p = &self.surface.points;
        let (a, b, c) = (p[t[0]], p[t[1]], p[t[2]]);
        let n = (b - a).cross(&(c - a));
        let area = n.norm_squared();
        if !(area > 0.0) {
            return None;
        }
        let w = [
            (b - x).cross(&(c - x)).dot(&n) / area,
            (c - x).cross(&(a - x)).dot(&n) / area,
            (a - x).cross(&(b - x)).dot(&n) / area,
        ];
        let m: Vector3<f64> = (0..3)
            .map(|i| self.corner_normals[k][i] * w[i].max(0.0))
            .sum();
        m.try_normalize(0.0)
    }

    /// Distance from `y` to triangle `k`, the feature its closest point lies on, and the point.
    fn closest_on(&self, k: usize, y: &Vector3<f64>) -> (f64, Feature, Vector3<f64>) {
        let t = self.surface.triangles[k];
        let p = &self.surface.points;
        let (a, b, c) = (p[t[0]], p[t[1]], p[t[2]]);
        let (x, f) = closest_point_on_triangle(y, &a, &b, &c);
        ((y - x).norm(), f, x)
    }
}

/// Ericson's closest point on triangle a b c to p, with the feature it lies on.
fn closest_point_on_triangle(
    p: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> (Vector3<f64>, Feature) {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (*a, Feature::Vertex(0));
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (*b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (a + ab * v, Feature::Edge(0));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (*c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (a + ac * w, Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, Feature::Edge(1));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    (a + ab * v + ac * w, Feature::Face)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::closed_surface::check_closed_surface;

    /// The signed distance to the unit cube, from its definition, at points inside, outside,
    /// near faces, edges and corners (where the sign needs the pseudo-normals).
    #[test]
    fn signed_distance_to_a_cube_matches_its_definition() {
        let (p, t) = crate::geometry::closed_surface::tests::cube();
        let s = SurfaceDistance::new(check_closed_surface("cube", p, t).unwrap()).unwrap();
        let exact = |y: &Vector3<f64>| {
            let q = y.map(|v| (v - 0.5).abs() - 0.5);
            let outside = q.map(|v| v.max(0.0)).norm();
            let inside = q.x.max(q.y).max(q.z).min(0.0);
            -(outside + inside)
        };
        let mut k = 0u64;
        for i in 0..9 {
            for j in 0..9 {
                for l in 0..9 {
                    k += 1;
                    let y = Vector3::new(i as f64, j as f64, l as f64) * 0.2 - Vector3::repeat(0.3)
                        + Vector3::new(1e-3, 2e-3, 3e-3) * (k % 7) as f64;
                    let (d, n) = s.signed_distance(&y);
                    assert!((d - exact(&y)).abs() < 1e-12, "{y:?}: {d} vs {}", exact(&y));
                    assert!((n.norm() - 1.0).abs() < 1e-12);
                }
            }
        }
        // Just inside the bottom face: depth 1e-3, pushed out along -z.
        let (d, n) = s.signed_distance(&Vector3::new(0.4, 0.6, 1e-3));
        assert!((d - 1e-3).abs() < 1e-15 && (n + Vector3::z()).norm() < 1e-12);
    }

    /// A unit sphere: the octahedron with each face split into 4^levels, projected.
    fn sphere(levels: usize) -> SurfaceDistance {
        let mut p: Vec<Vector3<f64>> = vec![
            Vector3::x(),
            -Vector3::x(),
            Vector3::y(),
            -Vector3::y(),
            Vector3::z(),
            -Vector3::z(),
        ];
        let mut t: Vec<[usize; 3]> = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        for _ in 0..levels {
            let mut mid = HashMap::new();
            let mut split = |a: usize, b: usize, p: &mut Vec<Vector3<f64>>| {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    p.push(((p[a] + p[b]) * 0.5).normalize());
                    p.len() - 1
                })
            };
            t = t
                .iter()
                .flat_map(|&[a, b, c]| {
                    let (ab, bc, ca) = (
                        split(a, b, &mut p),
                        split(b, c, &mut p),
                        split(c, a, &mut p),
                    );
                    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
                })
                .collect();
        }
        SurfaceDistance::new(check_closed_surface("sphere", p, t).unwrap()).unwrap()
    }

    /// Issue 57: on a faceted smooth surface the contact normal has no jump at the edges (a
    /// point pressed against the MNI skull slid to and fro across them and the relaxation
    /// never settled below 2e-5 m), and it is nearer the true normal than the faces' are;
    /// a point pushed back along it by the contact depth lands on the surface.
    #[test]
    fn the_contact_normal_is_continuous_on_a_faceted_sphere() {
        let s = sphere(3);
        // Depth of the points below the surface, m: their closest points lie on either side of
        // the edge, O(h) apart.
        let h = 1e-4;
        let (mut worst_jump, mut worst_face_jump) = (0.0f64, 0.0f64);
        let (mut worst_error, mut worst_face_error) = (0.0f64, 0.0f64);
        let mut landed = 0.0f64;
        for (k, t) in s.surface().triangles.iter().enumerate() {
            let p = &s.surface().points;
            for e in 0..3 {
                let (a, b) = (p[t[e]], p[t[(e + 1) % 3]]);
                // Just inside, either side of the middle of the edge.
                let m = (a + b) * 0.5;
                let across = (m - (p[t[0]] + p[t[1]] + p[t[2]]) / 3.0).normalize();
                let y0 = m * (1.0 - h) - across * 1e-7;
                let y1 = m * (1.0 - h) + across * 1e-7;
                let ((d0, n0), (_, n1)) = (s.contact_depth(&y0), s.contact_depth(&y1));
                worst_jump = worst_jump.max((n0 - n1).norm());
                worst_face_jump = worst_face_jump.max((s.face_normals[k] - n1).norm());
                // Pushed back along the normal by the depth: on the surface, or off it by the
                // bend of the next face where the push crosses the edge.
                let (after, _) = s.signed_distance(&(y0 + n0 * d0));
                landed = landed.max(after.abs());
            }
            // Inside the face, near a corner: the normal against the sphere's.
            let y = (p[t[0]] * 0.8 + p[t[1]] * 0.1 + p[t[2]] * 0.1) * (1.0 - 1e-3);
            let (d, n) = s.contact_depth(&y);
            let x = y.normalize();
            // Pushed back along the tilted normal by the contact depth: on the face.
            let (after, _) = s.signed_distance(&(y + n * d));
            assert!(after.abs() < 1e-15, "{after}");
            assert!(d > s.signed_distance(&y).0);
            worst_error = worst_error.max((n - x).norm());
            worst_face_error = worst_face_error.max((s.face_normals[k] - x).norm());
        }
        println!(
            "jump {worst_jump:.2e} (faces {worst_face_jump:.2e}), error {worst_error:.2e} \
             (faces {worst_face_error:.2e}), landed {landed:.2e}"
        );
        assert!(
            worst_jump < 1e-3,
            "normal jumps by {worst_jump} across an edge"
        );
        assert!(worst_face_jump > 0.09);
        assert!(worst_error < 0.5 * worst_face_error);
        assert!(landed < 1e-2 * h, "{landed}");
    }

    /// Sharp edges stay sharp: a cube's faces keep their own normals up to the edges, and its
    /// contact depth is the distance.
    #[test]
    fn a_cube_keeps_its_face_normals() {
        let (p, t) = crate::geometry::closed_surface::tests::cube();
        let s = SurfaceDistance::new(check_closed_surface("cube", p, t).unwrap()).unwrap();
        for (y, n) in [
            (Vector3::new(0.02, 0.97, 1e-3), -Vector3::z()),
            (Vector3::new(0.5, 0.5, 0.999), Vector3::z()),
            (Vector3::new(0.999, 0.01, 0.98), Vector3::x()),
        ] {
            let (d, m) = s.contact_depth(&y);
            assert!((m - n).norm() < 1e-12, "{y:?}: {m:?}");
            assert!((d - s.signed_distance(&y).0).abs() < 1e-15);
        }
        // At an edge, its pseudo-normal (the bisector).
        let (_, m) = s.contact_depth(&Vector3::new(1.0 + 1e-3, 0.5, 1.0 + 1e-3));
        assert!((m - Vector3::new(1.0, 0.0, 1.0).normalize()).norm() < 1e-12);
    }
}
