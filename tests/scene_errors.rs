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
    let in_file = cube_text().replace("mode = \"static\"", "mode = 1");
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

/// Issue 58: an input error's kind and facts are data, so a caller tells "no such boundary"
/// from "bad mesh" without reading the message; the message is written from them once.
#[test]
fn input_errors_carry_their_kind_and_facts() {
    use hytled::InputKind;
    let fault = |e: &hytled::Error| {
        let f = e
            .fault()
            .unwrap_or_else(|| panic!("not an input error: {e}"));
        (f.kind, f.facts.clone())
    };
    // A schema error in a file: the file, the line as written and the key.
    let text = cube_text().replace("youngs_modulus", "youngs_modulu");
    let e = hytled::scene::parse(&text, Path::new("bad.toml"), &[]).expect_err("unknown key");
    let (kind, facts) = fault(&e);
    let line = 1 + text
        .lines()
        .position(|l| l.contains("youngs_modulu"))
        .expect("the key");
    assert_eq!(kind, InputKind::Scene);
    assert_eq!(facts.line, Some(line), "{e}");
    assert_eq!(facts.file.as_deref(), Some(Path::new("bad.toml")));
    assert!(
        e.to_string().starts_with(&format!("bad.toml:{line}: ")),
        "{e}"
    );
    assert_eq!(facts.key.as_deref(), Some("material.youngs_modulu"), "{e}");
    // A value refused by validation: its key, no line (an override has none).
    let o = ["solver.dt_factor=11".to_string()];
    let e = hytled::scene::parse(&cube_text(), Path::new("bad.toml"), &o).expect_err("dt");
    let (kind, facts) = fault(&e);
    assert_eq!((kind, facts.line), (InputKind::Scene, None));
    assert_eq!(facts.key.as_deref(), Some("solver.dt_factor"));
    assert_eq!(e.kind(), "scene");
    // A selection that selects nothing.
    let sc = cube_scene(&["boundaries.bottom.select.plane.value=-0.1"]);
    let e = run_scene(&sc, &RunOptions::default()).expect_err("empty");
    assert_eq!(fault(&e).0, InputKind::Selection, "{e}");
    assert_eq!(e.kind(), "input");
    assert_eq!(
        fault(&e).1.key.as_deref(),
        Some("boundaries.bottom.select"),
        "{e}"
    );
    // A mesh file's text: the file and the line.
    let inp = "*NODE\n1, 0, 0, 0\n2, 1, 0, x\n";
    let e = hytled::io::inp::parse_inp(inp, Path::new("m.inp")).expect_err("bad number");
    let (kind, facts) = fault(&e);
    assert_eq!((kind, facts.line), (InputKind::Format, Some(3)), "{e}");
    assert!(e.to_string().starts_with("m.inp:3: "), "{e}");
    // The line-based readers keep their "FILE: line N:" wording and carry the same facts.
    let at = |e: &hytled::Error| {
        let (kind, facts) = fault(e);
        (kind, facts.file.clone(), facts.line)
    };
    let file = |name: &str| Some(std::path::PathBuf::from(name));
    let e = hytled::meshless::cloud::parse_cloud("0 0 0\n1 0 x\n", Path::new("c.xyz"))
        .expect_err("cloud");
    assert_eq!(at(&e), (InputKind::Format, file("c.xyz"), Some(2)), "{e}");
    assert!(e.to_string().starts_with("c.xyz: line 2: "), "{e}");
    let e = hytled::io::measured::parse_measured("0,0,0,1,2,3\n0,0,0,1,2\n", Path::new("u.csv"))
        .expect_err("measured");
    assert_eq!(at(&e), (InputKind::Format, file("u.csv"), Some(2)), "{e}");
    let e = hytled::io::msh::parse_msh(
        b"$MeshFormat\n2.2 1 8\n$EndMeshFormat\n",
        Path::new("b.msh"),
    )
    .expect_err("binary 2.2");
    assert_eq!(at(&e), (InputKind::Format, file("b.msh"), Some(2)), "{e}");
    assert!(e.to_string().starts_with("b.msh: line 2: "), "{e}");
    let vtk = b"# vtk DataFile Version 5.1\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 1 float\n0 0 0\nCELLS 2\n";
    let e = hytled::io::vtk::parse_vtk(vtk, Path::new("v.vtk")).expect_err("cells");
    assert_eq!(at(&e), (InputKind::Format, file("v.vtk"), Some(7)), "{e}");
    // A node cloud the meshless method cannot use: the kind, not the text, says so.
    let dir = std::env::temp_dir().join(format!("hytled-kinds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let cloud = dir.join("flat.xyz");
    std::fs::write(&cloud, "0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 2 0\n").expect("write");
    let e = hytled::meshless::cloud::read_cloud(&cloud).expect_err("coplanar");
    assert_eq!(fault(&e).0, InputKind::Mesh, "{e}");
    std::fs::remove_dir_all(&dir).ok();
    // The CLI's JSON object and a failed summary carry them too.
    let v = e.to_json();
    assert_eq!(
        (v["error"].as_str(), v["input_kind"].as_str()),
        (Some("input"), Some("mesh"))
    );
    assert!(v["facts"]["node"].is_null());
}
