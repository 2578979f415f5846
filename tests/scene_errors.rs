//! Clear errors on bad scenes: malformed TOML, unknown keys, bad overrides, empty selections,
//! inverted elements, nothing left to solve, invalid values; each names the file, line or key.

mod common;
use common::*;

use std::path::Path;
use std::process::Command;

use hytled::simulation::{run_scene, RunOptions};

fn parse_err(text: &str, overrides: &[&str]) -> String {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    hytled::scene::parse(text, Path::new("bad.toml"), &o)
        .expect_err("should fail")
        .to_string()
}

#[test]
fn malformed_toml_names_file_and_line() {
    let text = cube_text().replace("[material]", "[material\n");
    let e = parse_err(&text, &[]);
    assert!(e.starts_with("bad.toml") && e.contains("line"), "{e}");
}

#[test]
fn unknown_key_names_it_and_suggests_the_closest() {
    let e = parse_err(&cube_text().replace("youngs_modulus", "youngs_modulu"), &[]);
    assert!(
        e.contains("youngs_modulu") && e.contains("did you mean `youngs_modulus`"),
        "{e}"
    );
    let e = parse_err(&cube_text().replace("value = 0.1 }", "valu = 0.1 }"), &[]);
    assert!(
        e.contains("valu") && e.contains("did you mean `value`"),
        "{e}"
    );
    let e = parse_err(&cube_text(), &["solver.dt_facter=0.5"]);
    assert!(
        e.contains("dt_facter") && e.contains("did you mean `dt_factor`"),
        "{e}"
    );
}

#[test]
fn override_errors_name_the_key_path() {
    // A --set value of the wrong shape has no source line to point at: the key path says where.
    // A key taking a name given a number lists the names (serde said "unit variant"), in the
    // file as through --set.
    let in_file = cube_text().replace("mode = \"relaxation\"", "mode = 1");
    for (text, set, wants) in [
        (
            None,
            "solver.dt_factor=\"fast\"",
            &["after --set overrides: solver.dt_factor: invalid type"][..],
        ),
        (
            None,
            "solver.duration=1e400",
            &["--set solver.duration=1e400: 1e400 is not a finite number"],
        ),
        (
            None,
            "discretization.support=8",
            &["discretization.support: expected a name in quotes, `radius` or `nearest`"],
        ),
        (
            Some(&in_file),
            "",
            &[
                "line",
                "solver.mode: expected a name in quotes, one of `dynamic`, `relaxation`, `static`",
            ],
        ),
        (
            None,
            "solver=3",
            &["solver: invalid type: integer `3`, expected a table"],
        ),
        (
            None,
            "discretization.divisions=[1,2,3,4]",
            &["discretization.divisions: invalid length 4"],
        ),
        // serde writes 1e300 out in full (301 digits): shown as 1e300, in the file too.
        (
            None,
            "discretization.divisions=-1e300",
            &["discretization.divisions: invalid type: floating point `-1e300`, expected"],
        ),
        (
            Some(&cube_text().replace("size = 0.0125", "divisions = 1e300")),
            "",
            &["line", "invalid type: floating point `1e300`, expected"],
        ),
        (
            None,
            "solver.load_steps=2.5",
            &["solver.load_steps: invalid type: floating point `2.5`, expected a whole number, 0 or more"],
        ),
        (
            None,
            "solver.dt_factor=[1]",
            &["solver.dt_factor: invalid type: sequence, expected a number"],
        ),
        (
            None,
            "discretization.method=\"meshles\"",
            &[
                "discretization.method: unknown variant `meshles`",
                "did you mean `meshless`",
            ],
        ),
    ] {
        let sets: Vec<&str> = [set].into_iter().filter(|s| !s.is_empty()).collect();
        let e = parse_err(text.map_or(&cube_text(), |t| t), &sets);
        for w in wants {
            assert!(e.contains(w) && !e.contains("Spec"), "{set}: {e}");
        }
    }
}

#[test]
fn empty_selection_is_an_error_naming_the_boundary() {
    let sc = cube_scene(&["boundaries.bottom.select.plane.value=-0.1"]);
    let e = run_scene(&sc, &RunOptions::default())
        .expect_err("empty")
        .to_string();
    assert!(
        e.contains("boundary 'bottom'") && e.contains("selects no node"),
        "{e}"
    );
}

#[test]
fn inverted_element_is_an_error_naming_it() {
    let mut mesh = hytled::geometry::shapes::box_hex(
        nalgebra::Vector3::zeros(),
        nalgebra::Vector3::repeat(0.1),
        [2, 2, 2],
    )
    .unwrap();
    // Turn element 3 inside out by swapping its bottom and top faces.
    let c = &mut mesh.cells[3 * 8..4 * 8];
    for a in 0..4 {
        c.swap(a, a + 4);
    }
    let e = hytled::fe::element_points(&mesh, hytled::fe::ElementKind::Hex8, 0.01, 1e5)
        .expect_err("inverted")
        .to_string();
    assert!(e.contains("element 3") && e.contains("volume"), "{e}");
    assert!(e.contains("inverted or degenerate"), "{e}");
    // A node 1e6 m away: a positive but needle-thin volume, not called "non-positive".
    let mut tets = hytled::geometry::shapes::box_tet(
        nalgebra::Vector3::zeros(),
        nalgebra::Vector3::repeat(0.1),
        [1, 1, 1],
    )
    .unwrap();
    let far = tets.cells[0];
    tets.nodes[far].x = 1e6;
    let e = hytled::fe::element_points(&tets, hytled::fe::ElementKind::Tet4, 0.01, 1e5)
        .expect_err("needle")
        .to_string();
    assert!(
        !e.contains("non-positive") && e.contains("far from the others"),
        "{e}"
    );
}

/// A mesh one cell thick between two fixed faces leaves no free degree of freedom: no frequency
/// bounds the step and there is nothing to solve. The error says so (it said "critical time
/// step inf s; no usable points", and `check` called the scene valid).
#[test]
fn a_model_with_every_node_prescribed_is_refused_with_the_reason() {
    let o = ["discretization.divisions=[1,1,1]".to_string()];
    let sc = hytled::scene::load(&path("cases/cylinder-compression.toml"), &o).unwrap();
    let e = run_scene(&sc, &RunOptions::default())
        .expect_err("nothing free")
        .to_string();
    assert!(
        e.contains("every degree of freedom of the 16 nodes is prescribed")
            && e.contains("(bottom, top)")
            && e.contains("refine the discretization"),
        "{e}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["check", "cases/cylinder-compression.toml", "--set", &o[0]])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("every degree of freedom"), "{err}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("valid"));
}

#[test]
fn invalid_values_are_clear_errors() {
    let e = parse_err(
        &cube_text().replace("poisson_ratio = 0.49", "poisson_ratio = 0.5"),
        &[],
    );
    assert!(e.contains("poisson_ratio"), "{e}");
    let e = parse_err(
        &cube_text(),
        &["references.top_force.quantity=reaction.lid.z"],
    );
    assert!(e.contains("reaction.lid.z"), "{e}");
    for (sets, want) in [
        (vec!["discretization.tets_per_point=0.5"], "between 1"),
        (vec!["discretization.tets_per_point=nan"], "finite"),
        (
            vec![
                "discretization.tets_per_point=3",
                "discretization.integration=grid",
            ],
            "integration = 'tets'",
        ),
        (
            vec!["solver.time_step=exact"],
            "expected `bounds` or `global`",
        ),
        (
            vec!["discretization.dilatation=1e300"],
            "discretization.dilatation = 1e300: must lie in (0.5, 20)",
        ),
        (
            vec!["discretization.support_nodes=3"],
            "discretization.support_nodes = 3: at least 4",
        ),
        (
            vec!["discretization.alpha=0.5"],
            "discretization.alpha = 0.5: must be at least 1",
        ),
        (
            vec!["solver.dt_factor=11"],
            "solver.dt_factor = 11: at most 10",
        ),
        (
            vec!["boundaries.symmetry_x.select.plane.tolerance=-1"],
            "boundaries.symmetry_x.select: plane tolerance = -1: must be >= 0",
        ),
        (
            vec!["boundaries.top.select={box={min=[0,0,0.2],max=[1,1,0.1]}}"],
            "boundaries.top.select: box min = [0.0, 0.0, 0.2] and max = [1.0, 1.0, 0.1]",
        ),
        (
            vec!["boundaries.top.select={sphere={center=[0,0,0],radius=0}}"],
            "boundaries.top.select: radius = 0: must be positive",
        ),
        (
            vec!["discretization.size=1e-300"],
            "discretization.size = 1e-300 m gives about",
        ),
    ] {
        let e = parse_err(&cube_text(), &sets);
        assert!(e.contains(want), "{sets:?}: {e}");
    }
}
