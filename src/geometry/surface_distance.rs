//! Signed distance to a closed surface (a rigid tool or the skull read from a file): the
//! closest point on its triangles (Ericson, Real-Time Collision Detection, 5.1.5) and the side
//! from the angle-weighted pseudo-normal of the closest face, edge or vertex (Baerentzen and
//! Aanaes 2005, IEEE TVCG 11(3)), which is exact for closed, consistently oriented surfaces.
//! Candidate triangles come from a k-d tree of their centroids: every triangle within distance
//! D of a point has its centroid within D + R (R the largest centroid-to-vertex distance), and
//! the triangle of the nearest centroid bounds D.

use std::collections::HashMap;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Vector3;

use super::closed_surface::ClosedSurface;

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
        for (t, n) in surface.triangles.iter().zip(&face_normals) {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edge_normals
                    .entry((a.min(b), a.max(b)))
                    .or_insert(Vector3::zeros()) += n;
                let (u, v) = (p[t[(k + 1) % 3]] - p[a], p[t[(k + 2) % 3]] - p[a]);
                let angle = u.angle(&v);
                vertex_normals[a] += n * angle;
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
            crate::Error::Input(format!("cannot index the surface's triangles: {e:?}"))
        })?;
        Ok(SurfaceDistance {
            surface,
            face_normals,
            edge_normals,
            vertex_normals,
            tree,
            reach,
        })
    }

    /// The surface it measures to.
    pub fn surface(&self) -> &ClosedSurface {
        &self.surface
    }

    /// Signed distance of `y` (m): positive inside the closed surface, minus the distance
    /// outside; with the outward unit normal at the closest point (the side's pseudo-normal).
    pub fn signed_distance(&self, y: &Vector3<f64>) -> (f64, Vector3<f64>) {
        let q = [y.x, y.y, y.z];
        let nearest = self
            .tree
            .query(&q)
            .nearest_n::<SquaredEuclidean<f64>>(std::num::NonZero::<usize>::MIN)
            .execute();
        let Some(first) = nearest.first() else {
            return (f64::NEG_INFINITY, Vector3::z());
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
        let normal = match feature {
            Feature::Face => self.face_normals[k],
            Feature::Edge(e) => {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                self.edge_normals[&(a.min(b), a.max(b))]
            }
            Feature::Vertex(v) => self.vertex_normals[t[v]],
        };
        let outward = normal.normalize();
        let inside = (y - x).dot(&normal) < 0.0;
        if inside {
            (d, outward)
        } else {
            (-d, outward)
        }
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
}
