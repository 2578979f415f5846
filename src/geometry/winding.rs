//! Whether a point lies inside a closed surface: the generalized winding number (the solid
//! angle the surface subtends at the point over 4 pi; Jacobson et al. 2013), 1 inside an
//! outward-oriented closed surface, 0 outside, and robust to small gaps.

use nalgebra::Vector3;

/// Signed solid angle (sr) of the triangle `a, b, c` seen from `p` (Van Oosterom and
/// Strackee 1983): positive when its normal (b - a) x (c - a) points away from `p`.
fn solid_angle(p: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>, c: &Vector3<f64>) -> f64 {
    let (a, b, c) = (a - p, b - p, c - p);
    let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
    let num = a.dot(&b.cross(&c));
    let den = la * lb * lc + a.dot(&b) * lc + a.dot(&c) * lb + b.dot(&c) * la;
    2.0 * num.atan2(den)
}

/// Winding number of the surface `faces` (polygons over `vertices`, m, fanned into
/// triangles) about `p`: 1 inside an outward-oriented closed surface, 0 outside.
pub fn winding_number<'a>(
    p: &Vector3<f64>,
    vertices: &[Vector3<f64>],
    faces: impl IntoIterator<Item = &'a [usize]>,
) -> f64 {
    let mut total = 0.0;
    for f in faces {
        for k in 1..f.len().saturating_sub(1) {
            total += solid_angle(p, &vertices[f[0]], &vertices[f[k]], &vertices[f[k + 1]]);
        }
    }
    total / (4.0 * std::f64::consts::PI)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cube_winds_once_about_inner_points_and_not_about_outer_ones() {
        let (v, t) = crate::geometry::closed_surface::tests::cube();
        for (p, w) in [
            (Vector3::new(0.5, 0.5, 0.5), 1.0),
            (Vector3::new(0.01, 0.99, 0.3), 1.0),
            (Vector3::new(1.5, 0.5, 0.5), 0.0),
            (Vector3::new(-3.0, 7.0, 0.2), 0.0),
        ] {
            let got = winding_number(&p, &v, t.iter().map(|t| t.as_slice()));
            assert!((got - w).abs() < 1e-12, "{p:?}: {got}");
        }
    }
}
