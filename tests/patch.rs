//! Patch tests: an affine displacement field on distorted hex8, tet4 and tet4-anp meshes gives
//! the exact uniform F at every point and zero net internal force on interior nodes.

use nalgebra::{Matrix3, Vector3};

use hytled::fe::{element_points, ElementKind};
use hytled::geometry::{shapes, Mesh};
use hytled::material::NeoHookean;
use hytled::quadrature::NodeSlots;
use hytled::solver::forces::{deformation_gradient, Forces};

fn lcg(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    ((*state >> 11) as f64) / ((1u64 << 53) as f64)
}

fn is_interior(p: &Vector3<f64>) -> bool {
    (0..3).all(|k| p[k] > 1e-9 && p[k] < 0.1 - 1e-9)
}

/// Moves interior nodes by up to 20 % of the spacing (0.025 m) in each direction.
fn distort(mut mesh: Mesh, seed: u64) -> Mesh {
    let mut st = seed;
    for p in mesh.nodes.iter_mut() {
        if is_interior(p) {
            for k in 0..3 {
                p[k] += 0.2 * 0.025 * (2.0 * lcg(&mut st) - 1.0);
            }
        }
    }
    mesh
}

/// Applies an affine field to `mesh`; checks F at every point and the net force on the nodes
/// `interior` accepts.
fn patch_test(mesh: &Mesh, kind: ElementKind, interior: impl Fn(&Vector3<f64>) -> bool) {
    let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let qp = element_points(mesh, kind, 0.075, 51342.0).expect("valid distorted mesh");
    let slots = NodeSlots::new(&qp, mesh.nodes.len());
    let a = Matrix3::new(1.1, 0.05, -0.02, 0.03, 0.92, 0.04, -0.06, 0.01, 0.85);
    let b = Vector3::new(0.003, -0.001, 0.002);
    let u: Vec<_> = mesh
        .nodes
        .iter()
        .map(|x| (a - Matrix3::identity()) * x + b)
        .collect();
    for p in 0..qp.len() {
        let f = deformation_gradient(&qp, p, &u);
        assert!((f - a).norm() < 1e-12, "{kind:?} point {p}: F = {f}");
    }
    let mut forces = Forces::new(mat, &qp, &slots, mesh.nodes.len());
    let mut out = vec![Vector3::zeros(); mesh.nodes.len()];
    forces.compute(&qp, &slots, &u, &mut out);
    let scale = out.iter().map(|f| f.norm()).fold(0.0, f64::max);
    assert!(
        scale > 1e-3,
        "boundary forces expected under a non-trivial stress"
    );
    let inner: Vec<f64> = mesh
        .nodes
        .iter()
        .zip(&out)
        .filter(|(x, _)| interior(x))
        .map(|(_, f)| f.norm())
        .collect();
    assert!(!inner.is_empty());
    let worst = inner.iter().copied().fold(0.0, f64::max);
    assert!(
        worst < 1e-10 * scale,
        "{kind:?}: interior force {worst:e} N vs boundary scale {scale:e} N"
    );
}

#[test]
fn patch_test_hex8_distorted() {
    let m = distort(
        shapes::box_hex(Vector3::zeros(), Vector3::repeat(0.1), [4, 4, 4]).unwrap(),
        1,
    );
    patch_test(&m, ElementKind::Hex8, is_interior);
}

#[test]
fn patch_test_tet4_distorted() {
    let m = distort(
        shapes::box_tet(Vector3::zeros(), Vector3::repeat(0.1), [4, 4, 4]).unwrap(),
        2,
    );
    patch_test(&m, ElementKind::Tet4, is_interior);
}

#[test]
fn patch_test_tet4_anp_distorted() {
    let m = distort(
        shapes::box_tet(Vector3::zeros(), Vector3::repeat(0.1), [4, 4, 4]).unwrap(),
        3,
    );
    patch_test(&m, ElementKind::Tet4Anp, is_interior);
}

#[test]
fn patch_test_hex8_cylinder_ogrid() {
    // The O-grid's elements are irregular; interior here means off the surface.
    let mesh = shapes::cylinder_hex(0.05, 0.1, 4, 2, 4).unwrap();
    patch_test(&mesh, ElementKind::Hex8, |x| {
        x.x.hypot(x.y) < 0.05 - 1e-9 && x.z > 1e-9 && x.z < 0.1 - 1e-9
    });
}
