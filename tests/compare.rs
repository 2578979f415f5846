//! `hytled compare`: one row per method, errors per row, failures as rows.

use std::path::Path;

use hytled::comparison::{self, CompareOptions};

#[test]
fn compare_on_the_exact_cube_gives_three_accurate_rows() {
    let dir = std::env::temp_dir().join("hytled-compare-cube");
    let _ = std::fs::remove_dir_all(&dir);
    let methods = comparison::parse_methods("fe,coupled,meshless").unwrap();
    let opts = CompareOptions {
        out: Some(dir.clone()),
        ..Default::default()
    };
    let rows = comparison::run_compare(
        Path::new("cases/cube-compression.toml"),
        &[],
        &methods,
        &opts,
    )
    .unwrap();
    assert_eq!(rows.len(), 3);
    for r in &rows {
        let s = r
            .summary
            .as_ref()
            .unwrap_or_else(|| panic!("{}: {:?}", r.method, r.error));
        assert_eq!(s.method, r.method);
        assert!(s.converged);
        // Exact cube (docs/reference.md): F_z = -7.63269 N, lateral stretch 1.11574668.
        let f = s.reactions["top"][2];
        assert!(
            (f + 7.63269).abs() / 7.63269 < 0.01,
            "{}: F_z = {f}",
            r.method
        );
        let ux = s.probes["corner"].displacement[0];
        assert!(
            (ux - 0.011574668).abs() < 1e-4,
            "{}: corner u_x = {ux}",
            r.method
        );
    }
    let t = comparison::table(&rows);
    assert_eq!(t.lines().count(), 5, "{t}");
    // Steady state (the static solve, the cube's default): the equilibrium residual stands in
    // for the energy balance.
    assert_eq!(t.matches("n/a (static; residual ").count(), 3, "{t}");
    for f in [
        "compare.csv",
        "compare.md",
        "reactions.svg",
        "fe/summary.json",
        "coupled/summary.json",
    ] {
        assert!(dir.join(f).exists(), "{f} missing");
    }
    let csv = std::fs::read_to_string(dir.join("compare.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4);
}

#[test]
fn a_failing_method_is_a_row_not_the_end() {
    let methods = comparison::parse_methods("fe,meshless").unwrap();
    // The cloud file is only read by the meshless run.
    let o = vec![
        "discretization.cloud=file".to_string(),
        "discretization.cloud_file=no-such-cloud.csv".to_string(),
        "discretization.size=0.025".to_string(),
    ];
    let rows = comparison::run_compare(
        Path::new("cases/cube-compression.toml"),
        &o,
        &methods,
        &CompareOptions::default(),
    )
    .unwrap();
    assert!(rows[0].summary.is_some() && rows[0].error.is_none());
    let e = rows[1].error.as_deref().unwrap();
    assert!(e.contains("no-such-cloud.csv"), "{e}");
    assert!(comparison::table(&rows).contains("failed: "));
}

#[test]
fn unknown_method_is_an_error_naming_the_known_ones() {
    let e = comparison::parse_methods("fe,abaqus")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("'abaqus'") && e.contains("fe, coupled, meshless"),
        "{e}"
    );
}

/// Issue 22: the table shows the reaction component the scene's reference names (shear:
/// reaction.top.x), not always z.
#[test]
fn compare_table_shows_the_referenced_reaction_component() {
    let methods = comparison::parse_methods("fe").unwrap();
    let rows = comparison::run_compare(
        Path::new("cases/cylinder-shear.toml"),
        &[
            "discretization.divisions=[2,1,4]".to_string(),
            "solver.mode=relaxation".to_string(),
        ],
        &methods,
        &CompareOptions::default(),
    )
    .unwrap();
    let s = rows[0].summary.as_ref().unwrap();
    let md = comparison::table(&rows);
    assert!(md.contains("reaction top x (N)"), "{md}");
    assert!(
        md.contains(&hytled::error::tidy_exponents(&format!(
            "{:.5e}",
            s.reactions["top"][0]
        ))),
        "{md}"
    );
}

/// Issue 57: `compare --modes relaxation,static` runs each method in both steady-state solvers
/// and shows their cost side by side; both meet the exact cube (F_z = -7.63269 N).
#[test]
fn compare_shows_relaxation_and_static_side_by_side() {
    let dir = std::env::temp_dir().join("hytled-compare-modes");
    let _ = std::fs::remove_dir_all(&dir);
    let methods = comparison::parse_methods("fe").unwrap();
    let opts = CompareOptions {
        out: Some(dir.clone()),
        modes: comparison::parse_modes("relaxation,static").unwrap(),
        ..Default::default()
    };
    let rows = comparison::run_compare(
        Path::new("cases/cube-compression.toml"),
        &[],
        &methods,
        &opts,
    )
    .unwrap();
    assert_eq!(rows.len(), 2);
    let mut evaluations = Vec::new();
    for (r, mode) in rows.iter().zip(["relaxation", "static"]) {
        let s = r
            .summary
            .as_ref()
            .unwrap_or_else(|| panic!("{}: {:?}", r.label(), r.error));
        assert_eq!(s.mode, mode);
        assert_eq!(r.label(), format!("fe {mode}"));
        assert!(s.converged);
        let f = s.reactions["top"][2];
        assert!((f + 7.63269).abs() / 7.63269 < 0.01, "{mode}: F_z = {f}");
        evaluations.push(s.force_evaluations);
        assert!(dir.join(format!("fe-{mode}/summary.json")).exists());
    }
    // Newton needs far fewer force evaluations than the relaxation's steps.
    assert!(
        evaluations[1] * 10 < evaluations[0],
        "force evaluations {evaluations:?}"
    );
    let t = comparison::table(&rows);
    assert!(t.contains("| force evaluations |"), "{t}");
    assert!(
        t.contains("| fe | static |") && t.contains("| fe | relaxation |"),
        "{t}"
    );
    assert!(t.contains("n/a (static; residual "), "{t}");
    let svg = std::fs::read_to_string(dir.join("reactions.svg")).unwrap();
    assert!(svg.contains("fe static") && svg.contains("fraction of the run"));
    let e = comparison::parse_modes("newton").unwrap_err().to_string();
    assert!(
        e.contains("'newton'") && e.contains("relaxation, static"),
        "{e}"
    );
}
