//! Shapes, their structured and TetGen meshes, and node selections.

pub mod cell_grid;
pub mod closed_surface;
pub mod domain;
pub mod dome;
pub mod image;
pub mod image_body;
pub mod isolated;
pub mod mesh;
pub mod quality;
pub mod select;
pub mod shapes;
pub mod surface_distance;
#[cfg(feature = "tetgen")]
pub mod tetgen;
pub mod warp;
pub mod winding;

pub use mesh::{ElementShape, Mesh};

use nalgebra::Matrix3;

/// Cofactor matrix of `a`, det(a) a^-T, without a division (defined for singular `a` too): for
/// an element Jacobian J, dN/dX det J = cof(J) dN/dxi; for a deformation gradient F,
/// dJ/dF = cof(F).
pub fn cofactor(a: &Matrix3<f64>) -> Matrix3<f64> {
    let c = |r0: usize, c0: usize, r1: usize, c1: usize| {
        a[(r0, c0)] * a[(r1, c1)] - a[(r0, c1)] * a[(r1, c0)]
    };
    Matrix3::new(
        c(1, 1, 2, 2),
        -c(1, 0, 2, 2),
        c(1, 0, 2, 1),
        -c(0, 1, 2, 2),
        c(0, 0, 2, 2),
        -c(0, 0, 2, 1),
        c(0, 1, 1, 2),
        -c(0, 0, 1, 2),
        c(0, 0, 1, 1),
    )
}
