//! Adaptive integration (issue 8, thesis chapter 5) through the pipeline: the exact cube with
//! MMLS + EBCIEM over a range of tolerances (thesis Table 5.4), the summary report, the
//! integration-point VTU, coupled interiors, and bad settings.
//!
//! The full tolerance study (216 nodes, tolerances 0.5 .. 0.001, about a minute on 2 cores):
//!
//!     cargo test --release --test adaptive -- --ignored --nocapture

mod common;
use common::*;

use hytled::simulation::{self, prepare, settings, Prepared};
use hytled::solver;
use nalgebra::Vector3;

/// One row of the tolerance study.
#[derive(Debug)]
struct Row {
    tolerance: f64,
    points: usize,
    deepest: usize,
    mean_mm: f64,
    max_mm: f64,
    force_error: f64,
}

/// The exact cube (docs/reference.md) meshless with MMLS + EBCIEM and adaptive integration at
/// `tolerance`: points used and the mean / largest nodal error against the exact field
/// u = ((a - 1) x, (a - 1) y, -0.2 z), a = 1.11574668.
fn cube_row(size: &str, tolerance: f64) -> Row {
    let sc = common::load_scene(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.basis=quadratic",
            "discretization.bc_method=ebciem",
            "discretization.integration=adaptive",
            &format!("discretization.size={size}"),
            &format!("discretization.tolerance={tolerance}"),
        ],
    );
    let mut prep: Prepared = prepare(&sc).unwrap();
    let out = solver::run(&mut prep.model, &settings(&sc, false)).unwrap();
    assert!(
        out.converged,
        "tolerance {tolerance}: relaxation did not converge"
    );
    let m = prep.meshless().unwrap();
    let info = m.adaptive.clone().expect("adaptive report");
    assert_eq!(info.points_after, prep.model.points().len());
    let w: f64 = prep.model.points().weights.iter().sum();
    assert!((w - 1e-3).abs() < 1e-12 * 1e-3, "weights {w} m^3");
    let a = 1.11574668 - 1.0;
    let (mut sum, mut worst) = (0.0, 0.0f64);
    for x in &m.nodes {
        let s = m.shape_values(x, &|| "node".into()).unwrap();
        let u = s
            .iter()
            .fold(Vector3::zeros(), |acc, &(i, p)| acc + out.u[i as usize] * p);
        let e = (u - Vector3::new(a * x.x, a * x.y, -0.2 * x.z)).norm();
        sum += e;
        worst = worst.max(e);
    }
    let sum_s = simulation::summarize(&sc, &prep, &out, 0.0);
    let f = sum_s.reactions["top"][2];
    Row {
        tolerance,
        points: info.points_after,
        deepest: info.deepest_level,
        mean_mm: 1e3 * sum / m.nodes.len() as f64,
        max_mm: 1e3 * worst,
        force_error: (f - -7.63269).abs() / 7.63269,
    }
}

fn print(rows: &[Row]) {
    println!(
        "| tolerance | points | deepest level | mean error (mm) | max error (mm) | F_z error (%) |"
    );
    println!("|---|---|---|---|---|---|");
    for r in rows {
        println!(
            "| {} | {} | {} | {:.5} | {:.5} | {:.4} |",
            r.tolerance,
            r.points,
            r.deepest,
            r.mean_mm,
            r.max_mm,
            100.0 * r.force_error
        );
    }
}

/// Fast version of the thesis Table 5.4 study (125 nodes): as the tolerance tightens the
/// point count grows and the nodal error does not grow.
#[test]
fn cube_error_does_not_grow_as_the_tolerance_tightens() {
    let rows: Vec<Row> = [0.5, 0.05, 0.005]
        .iter()
        .map(|&t| cube_row("0.025", t))
        .collect();
    print(&rows);
    for w in rows.windows(2) {
        assert!(w[1].points >= w[0].points, "{rows:?}");
        assert!(w[1].mean_mm <= w[0].mean_mm, "{rows:?}");
        assert!(w[1].max_mm <= w[0].max_mm, "{rows:?}");
    }
    assert!(rows[2].points > rows[0].points, "{rows:?}");
    assert!(rows[2].force_error < 1e-3, "{rows:?}");
}

/// The thesis Table 5.4 study on 216 nodes (see the module documentation for the command).
#[test]
#[ignore = "study: about a minute on 2 cores"]
fn cube_tolerance_study() {
    let rows: Vec<Row> = [0.5, 0.1, 0.05, 0.01, 0.005, 0.001]
        .iter()
        .map(|&t| cube_row("0.02", t))
        .collect();
    print(&rows);
}

#[test]
fn summary_reports_the_refinement_and_vtu_holds_the_points() {
    let sc = common::load_scene(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.integration=adaptive",
            "discretization.size=0.05",
            "discretization.tolerance=0.01",
            "discretization.subdivision=8",
            "discretization.max_level=2",
            "solver.max_steps=20",
        ],
    );
    let mut prep = prepare(&sc).unwrap();
    let info = prep.meshless().unwrap().adaptive.clone().unwrap();
    assert_eq!(info.subdivision, 8);
    assert_eq!(info.leaves_per_level.len(), 3);
    // A leaf at level l is 1/8^l of a background cell.
    assert_eq!(
        info.leaves_per_level
            .iter()
            .enumerate()
            .map(|(l, &n)| n * 8usize.pow(2 - l as u32))
            .sum::<usize>(),
        info.points_before / 4 * 64,
        "leaves must tile the background cells: {info:?}"
    );
    let out = solver::run(&mut prep.model, &settings(&sc, false)).unwrap();
    let sum = simulation::summarize(&sc, &prep, &out, 0.0);
    let json = serde_json::to_value(&sum).unwrap();
    let a = &json["meshless"]["adaptive"];
    assert_eq!(
        a["points_after"].as_u64().unwrap() as usize,
        info.points_after
    );
    assert!(sum.table().contains("adaptive, tolerance 0.01"));
    let dir = std::env::temp_dir().join("hytled-adaptive-vtu");
    simulation::write_outputs(&dir, &sc, &mut prep, &out, &sum, Default::default()).unwrap();
    let vtu = std::fs::read_to_string(dir.join("cube-compression_integration_points.vtu")).unwrap();
    assert!(vtu.contains("Name=\"level\""));
    assert!(vtu.contains(&format!("NumberOfPoints=\"{}\"", info.points_after)));
}

#[test]
fn coupled_interior_refines_adaptively() {
    let base = [
        "discretization.method=coupled",
        "discretization.element=tet4-anp",
        "discretization.mesher=tetgen",
        "discretization.size=0.02",
        "solver.max_steps=10",
    ];
    // One point per interior tet: the adaptive rule's starting points.
    let mut one = base.to_vec();
    one.push("discretization.tets_per_point=1");
    let plain = prepare(&common::load_scene("cases/cube-compression.toml", &one)).unwrap();
    let mut o = base.to_vec();
    o.extend([
        "discretization.integration=adaptive",
        "discretization.tolerance=0.001",
    ]);
    let sc = common::load_scene("cases/cube-compression.toml", &o);
    let mut adaptive = prepare(&sc).unwrap();
    let (cp, ca) = (plain.coupled().unwrap(), adaptive.coupled().unwrap());
    let info = ca.adaptive.clone().expect("adaptive report");
    assert_eq!(info.points_before, cp.meshless_points);
    assert_eq!(info.points_after, ca.meshless_points);
    assert!(info.points_after > info.points_before, "{info:?}");
    let w = |p: &hytled::quadrature::QuadraturePoints| p.weights.iter().sum::<f64>();
    assert!((w(&ca.points) - w(&cp.points)).abs() < 1e-12 * w(&cp.points));
    // The summary's text and the interior points' VTU.
    let out = solver::run(&mut adaptive.model, &settings(&sc, false)).unwrap();
    let sum = simulation::summarize(&sc, &adaptive, &out, 0.0);
    assert!(
        sum.table().contains("interior points  adaptive"),
        "{}",
        sum.table()
    );
    let dir = std::env::temp_dir().join("hytled-adaptive-coupled-vtu");
    simulation::write_outputs(&dir, &sc, &mut adaptive, &out, &sum, Default::default()).unwrap();
    let vtu = std::fs::read_to_string(dir.join("cube-compression_integration_points.vtu")).unwrap();
    assert!(vtu.contains(&format!("NumberOfPoints=\"{}\"", info.points_after)));
}

#[test]
fn bad_adaptive_settings_are_scene_errors() {
    for (set, key) in [
        ("discretization.tolerance=0", "tolerance"),
        ("discretization.tolerance=-1", "tolerance"),
        ("discretization.subdivision=3", "subdivision"),
        ("discretization.max_level=7", "max_level"),
    ] {
        let o = vec![
            "discretization.method=meshless".to_string(),
            "discretization.integration=adaptive".to_string(),
            "discretization.subdivision=8".to_string(),
            set.to_string(),
        ];
        let e = hytled::scene::load(&path("cases/cube-compression.toml"), &o)
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(e.contains(key), "{set}: {e}");
    }
}

/// A hexahedral coupled interior keeps its Gauss points and says so.
#[test]
fn adaptive_on_a_hexahedral_coupled_interior_is_a_warning() {
    let p = prepare(&common::load_scene(
        "cases/cube-compression.toml",
        &[
            "discretization.method=coupled",
            "discretization.element=hex8",
            "discretization.integration=adaptive",
        ],
    ))
    .unwrap();
    let c = p.coupled().unwrap();
    assert!(c.adaptive.is_none());
    assert!(
        c.warnings.iter().any(|w| w.contains("hexahedral")),
        "{:?}",
        c.warnings
    );
}
