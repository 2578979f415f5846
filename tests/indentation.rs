//! Issue 40: the brain-indentation benchmark (cases/brain-indentation-benchmark.toml, the
//! docs/reference.md SfePy force at 1-5 mm), the quadratic tet10 element, relaxation load stages
//! and mass scaling. Coarse Gmsh level c1 (570 vertices) here; studies/indentation has the
//! refinement.

mod common;
use common::*;
use hytled::report::Summary;

const CASE: &str = "cases/brain-indentation-benchmark.toml";
const C1: &str = "geometry.mesh=../meshes/brain-indentation-c1.msh";

/// tet10 reproduces the exact homogeneous cube (docs/reference.md "Cube") on split-prism tets in
/// relaxation, and balances its energy in a dynamic run with its HRZ masses (quasi-static:
/// the reaction within 1e-5 of the static value).
#[test]
fn tet10_reproduces_the_exact_cube() {
    let o = [
        "discretization.element=tet10",
        "discretization.divisions=[3,3,3]",
    ];
    let s = run_case("cases/cube-compression.toml", &o);
    assert!(s.converged);
    assert!(
        rel_err(&s, "top_force") < 1e-6,
        "{}",
        rel_err(&s, "top_force")
    );
    assert!(rel_err(&s, "lateral") < 1e-5, "{}", rel_err(&s, "lateral"));
    let mut d = o.to_vec();
    d.push("solver.mode=dynamic");
    let s = run_case("cases/cube-compression.toml", &d);
    assert!(
        rel_err(&s, "top_force") < 1e-5,
        "{}",
        rel_err(&s, "top_force")
    );
    let b = s.energy.balance_error.unwrap();
    assert!(b < 1e-6, "energy balance {b:e}");
}

/// With tet10 (the case's element) the force is within 2 % of the reference band at every
/// depth, 1 to 5 mm, on the coarse level (3,651 nodes), without a restart; tet4-anp on the
/// same mesh is 37-57 % stiff (+6.3 % at 9,976 nodes: studies/indentation).
#[test]
fn tet10_is_within_two_percent_at_every_depth_on_the_coarse_level() {
    let s = run_case(CASE, &[C1]);
    assert_eq!(s.element, "tet10");
    assert!(s.converged);
    assert_eq!(s.restarts, 0);
    assert_eq!(s.stages.len(), 4);
    for name in [
        "force_1mm",
        "force_2mm",
        "force_3mm",
        "force_4mm",
        "force_5mm",
    ] {
        let c = &s.reference[name];
        let band = c.band_error.expect("a band");
        println!(
            "{name}: {:.5e} N, {:.2} % from the value, {:.2} % from the band",
            c.computed,
            100.0 * c.relative_error,
            100.0 * band
        );
        assert!(band < 0.02, "{name}: {band}");
    }
    let a = run_case(CASE, &[C1, "discretization.element=tet4-anp"]);
    assert!(a.reference["force_1mm"].relative_error > 0.3);
}

/// A load stage is the state the full run would reach at that load: the force held at
/// 2 mm (stage 0.4 of 5 mm) equals a run driven to 2 mm to the relaxation tolerance, and
/// mass scaling changes the answer by no more than that while taking fewer steps (tet4-anp
/// on c1, fast; it keeps its physical masses unless asked).
#[test]
fn a_load_stage_is_the_equilibrium_at_its_load() {
    let anp = "discretization.element=tet4-anp";
    let relax = "solver.mode=relaxation";
    let staged = run_case(CASE, &[C1, anp, relax, "solver.mass_scaling=true"]);
    let at_2mm = staged.reference["force_2mm"].computed;
    let direct = run_case(
        CASE,
        &[
            C1,
            anp,
            relax,
            "solver.mass_scaling=true",
            "boundaries.plug.displacement.z=-0.002",
            "references={}",
        ],
    );
    let f = direct.reactions["plug"][2];
    assert!(
        (at_2mm - f).abs() < 1e-4 * f.abs(),
        "stage {at_2mm} vs direct {f}"
    );
    let physical = run_case(CASE, &[C1, anp, relax, "references={}"]);
    assert!(staged.steps < physical.steps);
    let f5 = staged.reactions["plug"][2];
    let g5 = physical.reactions["plug"][2];
    assert!((f5 - g5).abs() < 1e-4 * g5.abs(), "{f5} vs {g5}");
    println!(
        "steps: mass-scaled {} (with four stages), physical masses {}",
        staged.steps, physical.steps
    );
}

/// The coupled method with a quadratic FE layer (element = "tet10"): every point family,
/// quadratic elements, blended cells with folded edges and MLS, reproduces a linear field's
/// deformation gradient exactly, and the edge nodes are FE nodes carrying mass.
#[test]
fn coupled_tet10_passes_the_patch_test() {
    use hytled::coupling::NodeRole;
    use hytled::solver::forces::deformation_gradient;
    use nalgebra::{Matrix3, Vector3};
    let o: Vec<String> = [
        "discretization.method=coupled",
        "discretization.mesher=structured",
        "discretization.divisions=[6,6,6]",
        "discretization.element=tet10",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let s = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
    let p = hytled::simulation::prepare(&s).unwrap();
    let c = p.coupled().unwrap();
    let q = c.quadratic.as_ref().expect("a quadratic layer");
    assert!(!q.edges.is_empty() && c.transition_points > 0 && c.meshless_points > 0);
    let a = Matrix3::new(0.01, -0.02, 0.03, 0.015, -0.01, 0.005, -0.02, 0.01, 0.02);
    let u: Vec<Vector3<f64>> = p.model.nodes().iter().map(|x| a * x).collect();
    let qp = p.model.points();
    let worst = (0..qp.len())
        .map(|k| {
            (deformation_gradient(qp, k, &u) - Matrix3::identity() - a)
                .abs()
                .max()
        })
        .fold(0.0f64, f64::max);
    assert!(worst < 1e-12, "|F - (I + A)| = {worst:e}");
    let vol: f64 = qp.weights.iter().sum();
    assert!((vol - 1e-3).abs() < 1e-12, "volume {vol}");
    for e in &q.edges {
        assert_eq!(c.regions.node[e.node], NodeRole::Fe);
        assert!(c.lumped_volume[e.node] > 0.0);
    }
}

/// The coupled method with a quadratic layer is warned of as unverified, because it is not
/// exact on the cube (docs/methods.md): measured, the lateral stretch 6.1 % long at nu = 0.49
/// with the top driven. The test keeps the warning honest: once the layout meets the cube
/// within 3 % it fails, and the warning (or this test) must change. The tet4-anp layer (the
/// coupled default on tets) is not warned of and meets the cube within 1 %.
#[test]
fn the_quadratic_coupled_layer_is_warned_of_while_it_misses_the_cube() {
    let warned = |s: &Summary| {
        s.warnings
            .iter()
            .any(|w| w.contains("'tet10' in the coupled method is not verified"))
    };
    let cube = "cases/cube-compression.toml";
    let s = run_case(
        cube,
        &[
            "discretization.method=coupled",
            "discretization.element=tet10",
        ],
    );
    assert!(s.converged && warned(&s), "{:?}", s.warnings);
    assert!(rel_err(&s, "lateral") > 0.03, "{}", rel_err(&s, "lateral"));
    let s = run_case(
        cube,
        &[
            "discretization.method=coupled",
            "discretization.element=tet4-anp",
        ],
    );
    assert!(s.converged && !warned(&s), "{:?}", s.warnings);
    assert!(rel_err(&s, "lateral") < 0.01, "{}", rel_err(&s, "lateral"));
}

/// The coupled defaults (a tet4-anp layer around the essential boundaries, a linear MLS
/// interior whose points share their mean J over patches of about 8 tets) are within 2 % of
/// the reference band at every depth from 1 to 5 mm on level c4 (4,507 nodes), without a
/// restart; with each interior point its own J the same model locks (5.5 % above the band at
/// 5 mm: studies/indentation-patches).
#[test]
fn coupled_defaults_are_within_two_percent_at_every_depth_on_c4() {
    let c4 = "geometry.mesh=../meshes/brain-indentation-c4.msh";
    let coupled = [
        c4,
        "discretization.method=coupled",
        "discretization.element=tet4-anp",
        "solver.mode=relaxation",
    ];
    let worst_band = |s: &hytled::report::Summary| -> f64 {
        [
            "force_1mm",
            "force_2mm",
            "force_3mm",
            "force_4mm",
            "force_5mm",
        ]
        .iter()
        .map(|n| s.reference[*n].band_error.expect("a band"))
        .fold(0.0, f64::max)
    };
    let s = run_case(CASE, &coupled);
    assert!(s.converged);
    assert_eq!(s.restarts, 0);
    let w = worst_band(&s);
    println!(
        "coupled defaults on c4: {:.2} % from the band at worst",
        100.0 * w
    );
    assert!(w < 0.02, "{w}");
    let mut own_j = coupled.to_vec();
    own_j.push("discretization.mean_dilatation_patch=1");
    let l = worst_band(&run_case(CASE, &own_j));
    println!("each point its own J: {:.2} %", 100.0 * l);
    assert!(l > 0.04, "{l}");
}

/// A linear tet layer along the whole surface around a concentrated drive is warned of, with
/// the figures and the fix; the default (FE around the essential boundaries) is not.
#[test]
fn a_linear_surface_layer_around_a_concentrated_drive_is_warned_of() {
    let base = [
        C1,
        "discretization.method=coupled",
        "discretization.element=tet4-anp",
    ];
    let warned = |extra: &[&str]| -> Vec<String> {
        let mut o: Vec<String> = base.iter().map(|s| s.to_string()).collect();
        o.extend(extra.iter().map(|s| s.to_string()));
        let s = hytled::scene::load(&path(CASE), &o).unwrap();
        hytled::simulation::prepare(&s)
            .unwrap()
            .warnings
            .into_iter()
            .filter(|w| w.contains("fe_region = 'surface'"))
            .map(|w| w.message)
            .collect()
    };
    let w = warned(&[
        "discretization.fe_region=surface",
        "discretization.fe_layers=2",
    ]);
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(
        w[0].contains("boundary 'plug'") && w[0].contains("element = 'tet10'"),
        "{}",
        w[0]
    );
    assert!(warned(&[]).is_empty());
}

/// Merged interior points (`tets_per_point`) follow the mesh's grading. Levels c3 and c4 are
/// graded at the plug's rim; binning their points on a regular grid sized by the mean tet put
/// dozens of the rim's small tets into one point whose support missed the bin's edge: on c4 a
/// surface node beside the rim got no point and no mass (the run refused), on c3 one node got
/// a single point (warned). Grouping face-connected tets reaches every meshless node with at
/// least two points, with volume kept and about `tets_per_point` times fewer interior points;
/// the pure meshless interior (four points per tet, merged) on c4 as well.
#[test]
fn merged_points_follow_a_graded_mesh() {
    for (level, k) in [("c3", 2.0), ("c4", 2.0), ("c4", 3.0)] {
        let mesh = format!("geometry.mesh=../meshes/brain-indentation-{level}.msh");
        let tpp = format!("discretization.tets_per_point={k}");
        for method in ["coupled", "meshless"] {
            if method == "meshless" && (level, k) != ("c4", 2.0) {
                continue;
            }
            let o = [
                mesh.clone(),
                tpp.clone(),
                "discretization.element=tet4-anp".to_string(),
                format!("discretization.method={method}"),
            ];
            let s = hytled::scene::load(&path(CASE), &o).unwrap();
            let p = hytled::simulation::prepare(&s)
                .unwrap_or_else(|e| panic!("{level}, {k}, {method}: {e}"));
            let few: Vec<_> = p
                .warnings
                .iter()
                .filter(|w| w.contains("fewer than two"))
                .collect();
            assert!(few.is_empty(), "{level}, {k}, {method}: {few:?}");
            if let Some(c) = p.coupled() {
                let tets = c.interior.num_cells() as f64;
                let ratio = tets / c.meshless_points as f64;
                println!(
                    "{level}, {k} tets per point: {} interior tets into {} points ({ratio:.2})",
                    tets, c.meshless_points
                );
                assert!(ratio > 0.75 * k && ratio < 1.25 * k, "{ratio}");
            }
            if let Some(ml) = p.meshless() {
                let tets = ml.background.num_cells() as f64;
                let ratio = tets / ml.points.len() as f64;
                println!("meshless {level}: {ratio:.2} tets (of four points each) per point");
                assert_eq!(ml.removed_nodes, 0);
                assert!(ratio > 0.75 * k && ratio < 1.25 * k, "{ratio}");
                let v: f64 = ml.points.weights.iter().sum();
                let v0: f64 = (0..ml.background.num_cells())
                    .map(|e| {
                        let c = ml.background.cell(e);
                        let x = |i: usize| ml.background.nodes[c[i]];
                        (x(1) - x(0)).cross(&(x(2) - x(0))).dot(&(x(3) - x(0))) / 6.0
                    })
                    .sum();
                assert!((v - v0).abs() < 1e-9 * v0, "{v} {v0}");
            }
        }
    }
}
