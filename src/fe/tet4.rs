//! Linear tetrahedron: constant shape-function derivatives in the reference configuration.

use nalgebra::{Matrix3, Vector3};

/// Reference derivatives dN_a/dX (1/m) of the four linear shape functions and the volume (m^3).
/// Returns `Err(volume)` when the volume is not positive (inverted or degenerate element).
pub fn derivatives(x: &[Vector3<f64>; 4]) -> Result<([Vector3<f64>; 4], f64), f64> {
    let j = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    let det = j.determinant();
    let volume = det / 6.0;
    // Relative threshold: a tet flatter than this has no usable derivatives.
    let scale = (x[1] - x[0])
        .norm()
        .max((x[2] - x[0]).norm())
        .max((x[3] - x[0]).norm());
    if !(volume > 1e-12 * scale.powi(3)) {
        return Err(volume);
    }
    // Rows of J^-1 are the gradients of the barycentric coordinates of nodes 1..3.
    let jinv = j.try_inverse().ok_or(volume)?;
    let g1 = jinv.row(0).transpose();
    let g2 = jinv.row(1).transpose();
    let g3 = jinv.row(2).transpose();
    Ok(([-(g1 + g2 + g3), g1, g2, g3], volume))
}

/// Barycentric coordinates of point `p` in the tetrahedron (sum to 1).
pub fn barycentric(x: &[Vector3<f64>; 4], p: &Vector3<f64>) -> Option<[f64; 4]> {
    let j = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
    let l = j.try_inverse()? * (p - x[0]);
    Some([1.0 - l.x - l.y - l.z, l.x, l.y, l.z])
}
