//! Cube under unconstrained compression against the exact homogeneous solution (docs/reference.md,
//! "Cube": a = 1.11574668, F_z = -7.63269 N).

mod common;
use common::*;

#[test]
fn cube_hex8_relaxation_matches_exact_solution() {
    let s = run_case("cases/cube-compression.toml", &[]);
    assert!(s.converged);
    let f = s.reactions["top"][2];
    assert!((f - -7.63269).abs() / 7.63269 < 0.005, "top reaction {f} N");
    // Lateral stretch a from the corner probe: u_x = (a - 1) 0.1 m.
    let a = 1.0 + s.probes["corner"].displacement[0] / 0.1;
    assert!((a - 1.11574668).abs() / 1.11574668 < 0.005, "a = {a}");
    assert!(rel_err(&s, "top_force") < 0.005);
}

#[test]
fn cube_tet4_anp_relaxation_matches_exact_solution() {
    let s = run_case(
        "cases/cube-compression.toml",
        &["discretization.element=tet4-anp"],
    );
    assert!(s.converged);
    let f = s.reactions["top"][2];
    assert!((f - -7.63269).abs() / 7.63269 < 0.005, "top reaction {f} N");
    let a = 1.0 + s.probes["corner"].displacement[1] / 0.1;
    assert!((a - 1.11574668).abs() / 1.11574668 < 0.005, "a = {a}");
}

#[test]
fn cube_reactions_balance_at_steady_state() {
    // Top and bottom reactions are equal and opposite once relaxed.
    let s = run_case("cases/cube-compression.toml", &[]);
    let (top, bottom) = (s.reactions["top"][2], s.reactions["bottom"][2]);
    assert!(
        (top + bottom).abs() < 1e-4 * top.abs(),
        "top {top} bottom {bottom}"
    );
}

#[cfg(feature = "tetgen")]
#[test]
fn cube_tet4_anp_on_a_tetgen_mesh_matches_exact_solution() {
    // An unstructured TetGen mesh (with its slivers) still passes the exact cube.
    let s = run_case(
        "cases/cube-compression.toml",
        &[
            "discretization.element=tet4-anp",
            "discretization.mesher=tetgen",
            "discretization.size=0.02",
        ],
    );
    assert!(s.mesh.min_dihedral_deg.is_some());
    let f = s.reactions["top"][2];
    assert!((f - -7.63269).abs() / 7.63269 < 0.005, "top reaction {f} N");
}

/// A probe over a node selection averages the displacement interpolated at the selected nodes
/// (the MLS or blended shape functions there, not the nodal parameters): over the top face of
/// the exact cube that is u_z = -0.02 m and u_x = u_y = (a - 1) 0.05 m, the face's centroid
/// being at x = y = 0.05 m, for every method.
#[test]
fn face_probes_average_the_exact_displacement() {
    let exact_ux = (1.11574668 - 1.0) * 0.05;
    for method in ["fe", "meshless", "coupled"] {
        let s = run_case(
            "cases/cube-compression.toml",
            &[
                &format!("discretization.method={method}"),
                "probes.face={ select = { plane = { axis = \"z\", value = 0.1 } } }",
            ],
        );
        let p = &s.probes["face"];
        println!(
            "{method}: face probe at {:?} m, u = {:?} m",
            p.position, p.displacement
        );
        for k in 0..2 {
            assert!(
                (p.position[k] - 0.05).abs() < 1e-12,
                "{method}: {:?}",
                p.position
            );
            let e = (p.displacement[k] - exact_ux).abs() / exact_ux;
            assert!(
                e < 2e-3,
                "{method}: u[{k}] = {} m, exact {exact_ux} m",
                p.displacement[k]
            );
        }
        assert!((p.position[2] - 0.1).abs() < 1e-12);
        assert!(
            (p.displacement[2] + 0.02).abs() < 1e-9,
            "{method}: {:?}",
            p.displacement
        );
    }
}
