//! Cylinder compression, extension and shear against the ABAQUS C3D20H reference of
//! `mtled-fe-coupled-ebc-cylinder.txt` Table 1 (docs/reference.md, "Cylinder"). Hex8 on the
//! 4,389-node O-grid (divisions 8, 4, 20): reaction within 3 %, probe u_x within 5 %.
//! tet4-anp: reaction within 5 % (relaxation on the same mesh split into 23,040 tets; dynamic
//! on divisions 6, 3, 16 = 9,216 tets to keep the suite fast).

mod common;
use common::*;

const CASES: [&str; 3] = [
    "cylinder-compression",
    "cylinder-extension",
    "cylinder-shear",
];

fn check_hex8(mode: &str) {
    for case in CASES {
        let s = run_case(
            &format!("cases/{case}.toml"),
            &[&format!("solver.mode={mode}")],
        );
        assert!(s.converged, "{case} {mode} did not converge");
        let (ef, eu) = (rel_err(&s, "force"), rel_err(&s, "probe_ux"));
        println!(
            "hex8 {case} {mode}: force error {:.3} %, probe error {:.3} %, {} steps",
            100.0 * ef,
            100.0 * eu,
            s.steps
        );
        assert!(
            ef < 0.03,
            "{case} {mode}: reaction error {:.3} %",
            100.0 * ef
        );
        assert!(eu < 0.05, "{case} {mode}: probe error {:.3} %", 100.0 * eu);
    }
}

#[test]
fn cylinder_hex8_relaxation_within_published_tolerances() {
    check_hex8("relaxation");
}

#[test]
fn cylinder_hex8_dynamic_within_published_tolerances() {
    check_hex8("dynamic");
}

#[test]
fn cylinder_tet4_anp_relaxation_reaction_within_5_percent() {
    for case in CASES {
        let s = run_case(
            &format!("cases/{case}.toml"),
            &["solver.mode=relaxation", "discretization.element=tet4-anp"],
        );
        let ef = rel_err(&s, "force");
        println!(
            "tet4-anp {case} relaxation: force error {:.3} %, probe error {:.3} %",
            100.0 * ef,
            100.0 * rel_err(&s, "probe_ux")
        );
        assert!(s.converged);
        assert!(ef < 0.05, "{case}: reaction error {:.3} %", 100.0 * ef);
    }
}

#[test]
fn cylinder_tet4_anp_dynamic_reaction_within_5_percent() {
    for case in CASES {
        let s = run_case(
            &format!("cases/{case}.toml"),
            &[
                "solver.mode=dynamic",
                "discretization.element=tet4-anp",
                "discretization.divisions=[6, 3, 16]",
            ],
        );
        let ef = rel_err(&s, "force");
        println!(
            "tet4-anp {case} dynamic: force error {:.3} %, probe error {:.3} %",
            100.0 * ef,
            100.0 * rel_err(&s, "probe_ux")
        );
        assert!(ef < 0.05, "{case}: reaction error {:.3} %", 100.0 * ef);
    }
}

#[test]
fn dynamic_compression_energy_balance_within_2_percent() {
    // External work of the boundary forces vs strain + kinetic energy at t = T.
    let s = run_case(
        "cases/cylinder-compression.toml",
        &["solver.mode=dynamic", "discretization.divisions=[6, 3, 16]"],
    );
    let e = &s.energy;
    let b = e.balance_error.expect("dynamic runs report the balance");
    println!(
        "W_ext {} U {} K {} balance {:.4} %",
        e.external_work,
        e.strain_energy,
        e.kinetic,
        100.0 * b
    );
    assert!(e.external_work > 0.0 && e.strain_energy > 0.0);
    assert!(b < 0.02, "energy balance error {:.3} %", 100.0 * b);
}
