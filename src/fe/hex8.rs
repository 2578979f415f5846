//! Eight-node hexahedron under one-point (centroid) integration with the total-Lagrangian
//! hourglass control of Joldes, Wittek & Miller (2008), as used in TLED (Miller et al. 2007).

use nalgebra::{Matrix3, SMatrix, Vector3};

/// Natural coordinates of the nodes (VTK/ABAQUS order).
pub const XI: [[f64; 3]; 8] = [
    [-1.0, -1.0, -1.0],
    [1.0, -1.0, -1.0],
    [1.0, 1.0, -1.0],
    [-1.0, 1.0, -1.0],
    [-1.0, -1.0, 1.0],
    [1.0, -1.0, 1.0],
    [1.0, 1.0, 1.0],
    [-1.0, 1.0, 1.0],
];

/// The four hourglass base vectors (eta zeta, xi zeta, xi eta, xi eta zeta at the nodes).
pub fn gamma() -> SMatrix<f64, 8, 4> {
    SMatrix::<f64, 8, 4>::from_fn(|a, k| {
        let [x, y, z] = XI[a];
        match k {
            0 => y * z,
            1 => x * z,
            2 => x * y,
            _ => x * y * z,
        }
    })
}

/// Trilinear shape functions at natural coordinates.
pub fn shape(xi: [f64; 3]) -> [f64; 8] {
    std::array::from_fn(|a| {
        0.125 * (1.0 + xi[0] * XI[a][0]) * (1.0 + xi[1] * XI[a][1]) * (1.0 + xi[2] * XI[a][2])
    })
}

/// Natural derivatives dN_a/dxi.
pub fn shape_derivatives(xi: [f64; 3]) -> [Vector3<f64>; 8] {
    std::array::from_fn(|a| {
        let [sa, ta, ua] = XI[a];
        let (s, t, u) = (1.0 + xi[0] * sa, 1.0 + xi[1] * ta, 1.0 + xi[2] * ua);
        Vector3::new(0.125 * sa * t * u, 0.125 * s * ta * u, 0.125 * s * t * ua)
    })
}

/// Jacobian dX/dxi (columns = derivatives along xi, eta, zeta).
pub fn jacobian(x: &[Vector3<f64>; 8], xi: [f64; 3]) -> Matrix3<f64> {
    let dn = shape_derivatives(xi);
    let mut j = Matrix3::zeros();
    for a in 0..8 {
        j += x[a] * dn[a].transpose();
    }
    j
}

/// Reference-configuration data of one hexahedron.
#[derive(Debug, Clone)]
pub struct Hex8Reference {
    /// Flanagan-Belytschko mean derivatives B_a = (1/V) int dN_a/dX dV, 1/m.
    pub b: [Vector3<f64>; 8],
    /// Exact element volume, m^3.
    pub volume: f64,
}

impl Hex8Reference {
    /// Exact volume and mean derivatives by 2x2x2 Gauss quadrature, which integrates
    /// det J and adj(J) dN/dxi of a trilinear map exactly. `Err(volume)` when the Jacobian
    /// is not positive at a Gauss point or a corner (inverted or degenerate element).
    pub fn new(x: &[Vector3<f64>; 8]) -> Result<Self, f64> {
        let g = 1.0 / 3f64.sqrt();
        let mut volume = 0.0;
        let mut b = [Vector3::zeros(); 8];
        let mut min_det = f64::INFINITY;
        for &xi in XI.iter() {
            let xg = [xi[0] * g, xi[1] * g, xi[2] * g];
            let j = jacobian(x, xg);
            let det = j.determinant();
            min_det = min_det.min(det);
            // adj(J)^T = det J * J^-T; dN/dX det J = adj(J)^T... written via the cofactor matrix.
            let cof = crate::geometry::cofactor(&j);
            for (a, dn) in shape_derivatives(xg).iter().enumerate() {
                b[a] += cof * dn;
            }
            volume += det;
        }
        for &xi in XI.iter() {
            min_det = min_det.min(jacobian(x, xi).determinant());
        }
        let diag = (x[6] - x[0]).norm();
        if !(min_det > 1e-12 * diag.powi(3)) || !(volume > 0.0) {
            return Err(volume);
        }
        for ba in b.iter_mut() {
            *ba /= volume;
        }
        Ok(Hex8Reference { b, volume })
    }

    /// Scaled hourglass vectors G = sqrt(k) g (8x4, sqrt(N/m)) of the hourglass matrix
    /// HG = k g g^T = G G^T, g = Gamma - B X^T Gamma, k = kappa_hg V M sum(B_ij^2) / 8
    /// (Joldes et al. 2008, with M = lambda + 2 mu there; the caller picks the modulus M, Pa). The kernel applies HG u as G (G^T u): the same operations as the
    /// 8x8 product from half the stored data (the step streams these from memory).
    pub fn hourglass_vectors(
        &self,
        x: &[Vector3<f64>; 8],
        kappa_hg: f64,
        modulus: f64,
    ) -> SMatrix<f64, 8, 4> {
        let gam = gamma();
        let bm = SMatrix::<f64, 8, 3>::from_fn(|a, i| self.b[a][i]);
        let xm = SMatrix::<f64, 8, 3>::from_fn(|a, i| x[a][i]);
        let g = gam - bm * (xm.transpose() * gam);
        let sum_b2: f64 = self.b.iter().map(|v| v.norm_squared()).sum();
        let k = kappa_hg * self.volume * modulus * sum_b2 / 8.0;
        g * k.max(0.0).sqrt()
    }
}

/// Natural coordinates of a reference point `p` inside (or near) the element, by Newton's method.
pub fn natural_coordinates(x: &[Vector3<f64>; 8], p: &Vector3<f64>) -> Option<[f64; 3]> {
    let mut xi = [0.0; 3];
    for _ in 0..30 {
        let n = shape(xi);
        let mut r = -p;
        for a in 0..8 {
            r += x[a] * n[a];
        }
        let d = jacobian(x, xi).try_inverse()? * r;
        for i in 0..3 {
            xi[i] -= d[i];
        }
        if d.norm() < 1e-13 {
            return Some(xi);
        }
        if xi.iter().any(|v| v.abs() > 10.0) {
            return None;
        }
    }
    Some(xi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn distorted() -> [Vector3<f64>; 8] {
        let mut x: [Vector3<f64>; 8] =
            std::array::from_fn(|a| Vector3::new(XI[a][0], XI[a][1], XI[a][2]) * 0.01);
        x[6] += Vector3::new(0.003, 0.002, -0.001);
        x[1] += Vector3::new(-0.001, 0.002, 0.0015);
        x[4] += Vector3::new(0.002, 0.0, 0.0);
        x
    }

    #[test]
    fn volume_of_cube_and_mean_derivatives_reproduce_linear_fields() {
        let x = distorted();
        let h = Hex8Reference::new(&x).unwrap();
        // sum_a x_a (x) B_a = I for any hexahedron (mean gradient of the identity map).
        let mut m = Matrix3::zeros();
        for (xa, ba) in x.iter().zip(&h.b) {
            m += xa * ba.transpose();
        }
        assert!((m - Matrix3::identity()).norm() < 1e-12, "{m}");
        let s: Vector3<f64> = h.b.iter().sum();
        assert!(s.norm() < 1e-10);
        let cube: [Vector3<f64>; 8] =
            std::array::from_fn(|a| Vector3::new(XI[a][0], XI[a][1], XI[a][2]) * 0.5);
        assert!((Hex8Reference::new(&cube).unwrap().volume - 1.0).abs() < 1e-14);
    }

    #[test]
    fn hourglass_matrix_annihilates_linear_fields() {
        let x = distorted();
        let h = Hex8Reference::new(&x).unwrap();
        let gv = h.hourglass_vectors(&x, 0.075, 1e5);
        let hg = gv * gv.transpose();
        // g^T x = Gamma^T x - Gamma^T x B^T x = 0 for each coordinate column: no force under affine motion.
        #[allow(clippy::needless_range_loop)] // i is the coordinate of every node's position
        for i in 0..3 {
            let col = SMatrix::<f64, 8, 1>::from_fn(|a, _| x[a][i] + 0.3);
            assert!(
                (hg * col).norm() < 1e-9 * hg.norm(),
                "{}",
                (hg * col).norm()
            );
        }
        assert!(hg.norm() > 0.0);
    }

    #[test]
    fn inverted_element_is_rejected() {
        let mut x = distorted();
        x.swap(0, 4);
        x.swap(1, 5);
        x.swap(2, 6);
        x.swap(3, 7);
        assert!(Hex8Reference::new(&x).is_err());
    }
}
