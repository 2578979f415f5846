//! MTLED meshless discretization through the whole pipeline: patch test, exact imposition of
//! essential conditions (EBCIEM / SEBCIEM vs the correction baseline), the exact cube, energy
//! and angular momentum, node removal and bad inputs.

mod common;
use common::*;

use hytled::scene::Scene;
use hytled::simulation::{prepare, settings, Prepared};
use hytled::solver::{self, forces::deformation_gradient};
use nalgebra::{Matrix3, Vector3};

fn prepared(case: &str, overrides: &[&str]) -> Prepared {
    prepare(&common::load_scene(case, overrides))
        .unwrap_or_else(|e| panic!("{case} {overrides:?}: {e}"))
}

/// Interpolated displacement sum_j phi_j(x) u_j at `x` (m).
fn interpolate(prep: &Prepared, x: &Vector3<f64>, u: &[Vector3<f64>]) -> Vector3<f64> {
    let m = prep.meshless().expect("meshless run");
    let s = m
        .shape_values(x, &|| "test point".into())
        .expect("shape functions");
    s.iter()
        .fold(Vector3::zeros(), |a, &(i, p)| a + u[i as usize] * p)
}

#[test]
fn affine_displacement_gives_uniform_deformation_gradient_at_every_point() {
    let a = Matrix3::new(0.11, -0.03, 0.02, 0.05, -0.08, 0.01, -0.04, 0.06, 0.09);
    let b = Vector3::new(0.001, -0.002, 0.003);
    for o in [
        &["discretization.cloud=mesh"][..],
        &[
            "discretization.cloud=lattice",
            "discretization.jitter=0.3",
            "discretization.basis=quadratic",
        ][..],
        &[
            "discretization.cloud=halton",
            "discretization.integration=grid",
            "discretization.support=nearest",
            "discretization.support_nodes=10",
        ][..],
    ] {
        let mut ov = vec![
            "discretization.method=meshless",
            "discretization.size=0.025",
        ];
        ov.extend_from_slice(o);
        let prep = prepared("cases/cube-compression.toml", &ov);
        let m = &prep.model;
        let u: Vec<Vector3<f64>> = m.nodes().iter().map(|x| a * x + b).collect();
        let want = Matrix3::identity() + a;
        let mut worst = 0.0f64;
        for p in 0..m.points().len() {
            let f = deformation_gradient(m.points(), p, &u);
            worst = worst.max((f - want).amax());
        }
        assert!(
            worst < 1e-9,
            "{o:?}: largest F error {worst:e} over {} points",
            m.points().len()
        );
    }
}

#[test]
fn integration_weights_sum_to_the_background_volume() {
    let prep = prepared(
        "cases/cylinder-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.divisions=[4,2,8]",
        ],
    );
    let w = prep.model.points().total_weight();
    let tets: f64 = (0..prep.mesh.num_cells())
        .map(|e| {
            let c = prep.mesh.cell(e);
            let p = |i: usize| prep.mesh.nodes[c[i]];
            hytled::geometry::quality::tet_signed_volume(&p(0), &p(1), &p(2), &p(3))
        })
        .sum();
    assert!(
        (w - tets).abs() < 1e-12 * tets,
        "weights {w} vs tets {tets}"
    );
}

/// Runs a scene and returns the prepared model with the final displacement.
fn run(prep: &mut Prepared, sc: &Scene) -> solver::RunOutput {
    solver::run(&mut prep.model, &settings(sc, false)).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn ebciem_and_sebciem_impose_prescribed_values_and_correction_does_not() {
    // A short dynamic loading of a coarse bonded cylinder: the field next to the bonded faces
    // is far from linear, so prescribing the nodal parameters (not interpolating) leaves the
    // interpolated displacement at the constrained nodes off the prescribed value.
    let mut errors = Vec::new();
    for method in ["ebciem", "sebciem", "correction"] {
        let bc = format!("discretization.bc_method={method}");
        let ov = [
            "discretization.method=meshless",
            "discretization.divisions=[4,2,8]",
            "solver.duration=0.5",
            bc.as_str(),
        ];
        let sc = common::load_scene("cases/cylinder-compression.toml", &ov);
        let mut prep = prepare(&sc).unwrap();
        let out = run(&mut prep, &sc);
        let mut worst = 0.0f64;
        for b in prep.model.boundaries() {
            for &i in &b.nodes {
                let x = prep.model.nodes()[i];
                let u = interpolate(&prep, &x, &out.u);
                for k in 0..3 {
                    if let Some(v) = b.components[k] {
                        // The smooth curve has reached 1 at t = T = duration.
                        worst = worst.max((u[k] - v).abs());
                    }
                }
            }
        }
        errors.push((method, worst));
    }
    println!("imposition error |u(x_k) - u_bar| (m): {errors:?}");
    assert!(errors[0].1 < 1e-10, "EBCIEM error {:e} m", errors[0].1);
    assert!(errors[1].1 < 1e-10, "SEBCIEM error {:e} m", errors[1].1);
    assert!(errors[2].1 > 1e-6, "correction error {:e} m", errors[2].1);
}

/// The meshless cube compression case with `overrides`, in relaxation: the top's reaction error
/// against the exact uniaxial solution, each node's displacement error (m) against the exact
/// field u = ((a - 1) x, (a - 1) y, -0.2 z) (docs/reference.md, cube), and the model's
/// mean-dilatation groups.
fn meshless_cube_errors(overrides: &[&str]) -> (f64, Vec<f64>, usize) {
    let mut o = vec!["discretization.method=meshless"];
    o.extend_from_slice(overrides);
    let sc = common::load_scene("cases/cube-compression.toml", &o);
    let mut prep = prepare(&sc).unwrap();
    let out = run(&mut prep, &sc);
    assert!(out.converged);
    let top = prep.model.reactions(&out.f_int)[prep
        .model
        .boundaries()
        .iter()
        .position(|b| b.name == "top")
        .unwrap()];
    let err_f = (top.z - -7.63269).abs() / 7.63269;
    let a = 1.11574668;
    let errs = prep
        .model
        .nodes()
        .iter()
        .map(|x| {
            let exact = Vector3::new((a - 1.0) * x.x, (a - 1.0) * x.y, -0.2 * x.z);
            (interpolate(&prep, x, &out.u) - exact).norm()
        })
        .collect();
    (err_f, errs, prep.model.points().groups.len())
}

#[test]
fn cube_meshless_ebciem_relaxation_matches_exact_solution() {
    let (err_f, errs, _) = meshless_cube_errors(&["discretization.size=0.02"]);
    let mean = errs.iter().sum::<f64>() / errs.len() as f64;
    println!(
        "cube meshless: F_z error {:.4} %, mean nodal error {:.3e} mm",
        100.0 * err_f,
        1e3 * mean
    );
    assert!(err_f < 0.02, "reaction error {err_f}");
    assert!(mean < 0.05e-3, "mean nodal error {mean} m");
}

/// The mean-dilatation patches of a pure meshless model (`mean_dilatation_patch`, opt-in) keep
/// the patch test only to within the MLS quadrature's own error, which they amplify. MLS shape
/// functions integrated by a tet rule are not integration-consistent, so even with each point
/// its own J the TetGen
/// cube misses the exact uniaxial solution (docs/reference.md, cube) slightly; sharing J over a
/// patch softens the volumetric response and lets that error grow 2-3x in the mean (measured:
/// 0.029 -> 0.072 mm at 25 mm, 0.014 -> 0.033 mm at 12.5 mm, of a 20 mm top displacement), but
/// it falls under refinement (worst 0.71 -> 0.18 mm), and at 12.5 mm both meet the bounds of the
/// structured meshless cube test (reaction 2 %, mean nodal error 0.05 mm). This is why the
/// patches are not the meshless default (tests/surfaces.rs's STL cube: corner 3.7 % off).
#[test]
fn meshless_patches_on_tetgen_tets_keep_the_cube_close_to_exact() {
    let cube = |size: &str, patch: &str| {
        let (err_f, errs, groups) = meshless_cube_errors(&[
            "discretization.mesher=tetgen",
            "discretization.element=tet4-anp",
            &format!("discretization.size={size}"),
            "solver.mode=relaxation",
            &format!("discretization.mean_dilatation_patch={patch}"),
        ]);
        let worst = errs.iter().fold(0.0f64, |m, &e| m.max(e));
        let mean = errs.iter().sum::<f64>() / errs.len() as f64;
        println!(
            "TetGen cube meshless, size {size}, patch {patch}: {} nodes, {groups} groups, F_z \
             error {err_f:.2e}, mean / worst nodal error {:.3e} / {:.3e} mm",
            errs.len(),
            1e3 * mean,
            1e3 * worst
        );
        (err_f, mean, worst, groups)
    };
    let fine = cube("0.0125", "8");
    for (patch, (err_f, mean, _, groups)) in [("8", fine), ("1", cube("0.0125", "1"))] {
        assert_eq!(groups > 0, patch == "8");
        assert!(err_f < 0.02, "{patch}: reaction error {err_f}");
        assert!(mean < 0.05e-3, "{patch}: mean nodal error {mean} m");
    }
    let coarse = cube("0.025", "8");
    assert!(
        fine.2 < 0.5 * coarse.2,
        "worst {:e} -> {:e} m",
        coarse.2,
        fine.2
    );
}

#[test]
fn meshless_summary_reports_supports_and_bc_method() {
    let s = run_case(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.size=0.025",
            "discretization.bc_method=sebciem",
        ],
    );
    assert_eq!(s.method, "meshless");
    assert_eq!(s.bc_method.as_deref(), Some("sebciem"));
    let sn = s.support_nodes.as_ref().unwrap();
    assert!(sn.min >= 4 && sn.mean >= sn.min as f64 && sn.max as f64 >= sn.mean);
    assert_eq!(s.removed_nodes, Some(0));
    let v = serde_json::to_value(&s).unwrap();
    assert!(
        v["support_nodes"]["mean"].is_number()
            && v["removed_nodes"].is_number()
            && v["bc_method"].is_string()
    );
    // Top and bottom reactions balance at steady state.
    let (t, b) = (s.reactions["top"][2], s.reactions["bottom"][2]);
    assert!((t + b).abs() < 1e-3 * t.abs(), "top {t} bottom {b}");
}

#[test]
fn dynamic_meshless_compression_balances_energy() {
    let s = run_case(
        "cases/cylinder-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.divisions=[4,2,8]",
            "discretization.tet_rule=1",
        ],
    );
    let e = s.energy.balance_error.unwrap();
    println!("energy balance error {:.4} %", 100.0 * e);
    assert!(e < 0.02, "energy balance error {e}");
}

#[test]
fn free_spinning_meshless_body_conserves_angular_momentum() {
    // A coarse cylinder spun about its axis at 1 Hz, no boundary conditions, 20 s.
    let text = r#"
[geometry]
shape = "cylinder"
radius = 0.05
height = 0.1
[discretization]
method = "meshless"
divisions = [2, 1, 4]
tet_rule = 1
[material]
youngs_modulus = 3000.0
poisson_ratio = 0.49
density = 1000.0
[solver]
mode = "dynamic"
duration = 20.0
[output]
history_rows = 10
"#;
    let sc = hytled::scene::parse(text, std::path::Path::new("spin.toml"), &[]).unwrap();
    let mut prep = prepare(&sc).unwrap();
    let w = Vector3::new(0.0, 0.0, 2.0 * std::f64::consts::PI);
    let v0: Vec<Vector3<f64>> = prep.model.nodes().iter().map(|x| w.cross(x)).collect();
    let mut st = settings(&sc, false);
    st.initial_velocity = Some(v0.clone());
    let m = prep.model.mass().to_vec();
    let l0: Vector3<f64> = prep
        .model
        .nodes()
        .iter()
        .zip(&v0)
        .zip(&m)
        .map(|((x, v), &mi)| x.cross(v) * mi)
        .sum();
    let out = solver::run(&mut prep.model, &st).unwrap();
    let l1: Vector3<f64> = (0..m.len())
        .map(|i| {
            let x = prep.model.nodes()[i] + out.u[i];
            let v = (out.u[i] - out.u_prev[i]) / out.dt;
            x.cross(&v) * m[i]
        })
        .sum();
    let err = (l1 - l0).norm() / l0.norm();
    println!(
        "angular momentum {l0:?} -> {l1:?}, relative change {err:e}, {} steps",
        out.steps
    );
    assert!(err < 0.01, "angular momentum changed by {err}");
}

/// CSV of the 5 x 5 x 5 lattice of spacing 0.025 m filling the cube, with a label column when
/// `label(k)` (k: the z layer) gives one.
fn cube_lattice_csv(label: impl Fn(usize) -> Option<i32>) -> String {
    let mut text = String::from(if label(0).is_some() {
        "x,y,z,label\n"
    } else {
        "x,y,z\n"
    });
    for i in 0..5 {
        for j in 0..5 {
            for k in 0..5 {
                let (x, y, z) = (0.025 * i as f64, 0.025 * j as f64, 0.025 * k as f64);
                text += &match label(k) {
                    Some(l) => format!("{x},{y},{z},{l}\n"),
                    None => format!("{x},{y},{z}\n"),
                };
            }
        }
    }
    text
}

#[test]
fn poorly_supported_nodes_are_removed_with_a_warning() {
    let dir = std::env::temp_dir().join(format!("hytled-cloud-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut text = cube_lattice_csv(|_| None);
    // A stray node outside the body: no integration point has it among its nearest nodes.
    text += "0.3,0.3,0.3\n";
    let file = dir.join("cloud.csv");
    std::fs::write(&file, text).unwrap();
    let f = format!("discretization.cloud_file={}", file.display());
    let s = run_case(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.cloud=file",
            f.as_str(),
            "discretization.integration=grid",
            "discretization.support=nearest",
            "discretization.bc_method=sebciem",
        ],
    );
    assert_eq!(s.removed_nodes, Some(1));
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("removed 1 meshless node")),
        "{:?}",
        s.warnings
    );
    assert_eq!(s.nodes, 125);
}

#[test]
fn bad_clouds_are_clear_errors() {
    let dir = std::env::temp_dir().join(format!("hytled-badcloud-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.xyz");
    std::fs::write(&bad, "0 0 0\n0.1 0 0\n0 0.1 oops\n").unwrap();
    let empty = dir.join("empty.xyz");
    std::fs::write(&empty, "# nothing here\n\n").unwrap();
    for (file, want) in [(&bad, "line 3"), (&empty, "empty")] {
        let f = format!("discretization.cloud_file={}", file.display());
        let sc = common::load_scene(
            "cases/cube-compression.toml",
            &[
                "discretization.method=meshless",
                "discretization.cloud=file",
                f.as_str(),
            ],
        );
        let err = prepare(&sc).err().expect("must fail").to_string();
        assert!(err.to_lowercase().contains(want), "{err}");
    }
}

/// Horton-style nearest-node supports (8 nodes, alpha = 10), one point per background tet,
/// SEBCIEM (the `auto` choice for that rule); 2,057-node cloud of the [6, 3, 16] O-grid.
fn cylinder_meshless(case: &str, mode: &str) -> hytled::report::Summary {
    let m = format!("solver.mode={mode}");
    run_case(
        case,
        &[
            "discretization.method=meshless",
            "discretization.divisions=[6,3,16]",
            "discretization.tet_rule=1",
            "discretization.support=nearest",
            m.as_str(),
        ],
    )
}

/// Reaction and probe u_x within 5 % of ABAQUS C3D20H (docs/reference.md, cylinder table; measured
/// 3.26/1.77 %, 0.54/1.20 %, 1.48/0.14 % for compression/extension/shear by relaxation, the
/// same to 0.02 % dynamically).
fn check_cylinder(case: &str, mode: &str) {
    let s = cylinder_meshless(case, mode);
    assert!(s.converged, "{case} {mode}: not converged");
    assert_eq!(s.bc_method.as_deref(), Some("sebciem"));
    let (f, p) = (rel_err(&s, "force"), rel_err(&s, "probe_ux"));
    println!(
        "{case} {mode}: force error {:.2} %, probe error {:.2} %",
        100.0 * f,
        100.0 * p
    );
    assert!(f < 0.05 && p < 0.05, "{case} {mode}: force {f}, probe {p}");
}

#[test]
fn cylinder_compression_meshless_relaxation() {
    check_cylinder("cases/cylinder-compression.toml", "relaxation");
}

#[test]
fn cylinder_extension_meshless_relaxation() {
    check_cylinder("cases/cylinder-extension.toml", "relaxation");
}

#[test]
fn cylinder_shear_meshless_relaxation() {
    check_cylinder("cases/cylinder-shear.toml", "relaxation");
}

#[test]
fn cylinder_compression_meshless_dynamic() {
    check_cylinder("cases/cylinder-compression.toml", "dynamic");
}

#[test]
fn cylinder_extension_meshless_dynamic() {
    check_cylinder("cases/cylinder-extension.toml", "dynamic");
}

#[test]
fn cylinder_shear_meshless_dynamic() {
    check_cylinder("cases/cylinder-shear.toml", "dynamic");
}

#[test]
fn cube_meshless_mmls_relaxation_matches_exact_solution() {
    // Modified MLS, quadratic basis, EBCIEM (thesis chapters 3-4; docs/reference.md cube).
    let s = run_case(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.size=0.025",
            "discretization.basis=quadratic",
        ],
    );
    assert!(s.converged);
    assert_eq!(s.element, "mmls");
    let f = rel_err(&s, "top_force");
    println!(
        "cube MMLS: force error {:.4} %, corner u_x error {:.3} %",
        100.0 * f,
        100.0 * rel_err(&s, "lateral")
    );
    assert!(f < 0.02, "force error {f}");
    assert!(rel_err(&s, "lateral") < 0.02);
}

#[test]
fn ebciem_with_nearest_supports_is_warned_about() {
    let sc = common::load_scene(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.size=0.025",
            "discretization.support=nearest",
            "discretization.bc_method=ebciem",
        ],
    );
    let prep = prepare(&sc).unwrap();
    assert!(
        prep.warnings.iter().any(|w| w.contains("sebciem")),
        "{:?}",
        prep.warnings
    );
}

#[test]
fn meshless_vtu_frames_carry_interpolated_displacement_and_read_back() {
    let dir = std::env::temp_dir().join(format!("hytled-meshless-vtu-{}", std::process::id()));
    let sc = common::load_scene(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.size=0.025",
        ],
    );
    let opts = hytled::simulation::RunOptions {
        out: Some(dir.clone()),
        progress: false,
        vtu_format: hytled::io::vtu::VtuFormat::Ascii,
        ..Default::default()
    };
    let s = hytled::simulation::run_scene(&sc, &opts).unwrap();
    let vtk =
        vtkio::Vtk::import(dir.join("cube-compression_0001.vtu")).expect("vtkio reads the frame");
    let vtkio::model::DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
        panic!("not an unstructured grid");
    };
    // The SVG plots written next to history.csv.
    for (f, want) in [("reaction.svg", "top z"), ("energy.svg", "strain energy")] {
        let svg = std::fs::read_to_string(dir.join(f)).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.contains(want) && svg.contains("polyline"),
            "{f}"
        );
    }
    let piece = pieces[0].load_piece_data(None).unwrap();
    assert_eq!(piece.num_points(), s.nodes);
    // Displacement, nodal fields and a label per boundary; cell stress, von Mises, J and
    // J_element.
    assert_eq!(piece.data.point.len(), 6 + sc.boundaries.len());
    assert_eq!(piece.data.cell.len(), 4);
    // The top corner's interpolated displacement in the last frame is the probe's.
    let vtkio::model::Attribute::DataArray(arr) = &piece.data.point[0] else {
        panic!("no displacement array")
    };
    assert_eq!(arr.name, "displacement");
    let vals: Vec<f64> = arr.data.clone().cast_into().unwrap();
    let corner = (0..s.nodes)
        .find(|&i| {
            let p = &piece.points;
            let c: Vec<f64> = p.clone().cast_into().unwrap();
            (c[3 * i] - 0.1).abs() < 1e-12
                && (c[3 * i + 1] - 0.1).abs() < 1e-12
                && (c[3 * i + 2] - 0.1).abs() < 1e-12
        })
        .expect("corner vertex");
    let probe = s.probes["corner"].displacement;
    for k in 0..3 {
        assert!(
            (vals[3 * corner + k] - probe[k]).abs() < 1e-12,
            "{} vs {}",
            vals[3 * corner + k],
            probe[k]
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mesh_file_vertices_serve_as_a_node_cloud() {
    // A VTU written by `hytled mesh --vtu-format ascii`, read back as a cloud (vtkio).
    let dir = std::env::temp_dir().join(format!("hytled-vtu-cloud-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("box.vtu");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args([
            "mesh",
            path("cases/cube-compression.toml").to_str().unwrap(),
            "--set",
            "discretization.size=0.025",
        ])
        .args(["--vtu-format", "ascii", "--out", file.to_str().unwrap()])
        .status()
        .unwrap();
    assert!(status.success());
    let f = format!("discretization.cloud_file={}", file.display());
    let prep = prepared(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.cloud=file",
            f.as_str(),
            "discretization.size=0.025",
        ],
    );
    assert_eq!(prep.model.nodes().len(), 125);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn meshless_results_are_identical_for_any_thread_count() {
    let sc = common::load_scene(
        "cases/cylinder-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.divisions=[4,2,8]",
            "solver.duration=0.2",
        ],
    );
    let run_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut prep = prepare(&sc).unwrap();
            let out = solver::run(&mut prep.model, &settings(&sc, false)).unwrap();
            (out.u, prep.model.reactions(&out.f_int))
        })
    };
    let (u1, r1) = run_with(1);
    let (u2, r2) = run_with(2);
    assert!(
        u1.iter().zip(&u2).all(|(a, b)| a == b),
        "displacements differ"
    );
    assert_eq!(r1, r2);
}

#[test]
fn removing_a_node_that_carries_a_boundary_condition_is_an_error() {
    let dir = std::env::temp_dir().join(format!("hytled-bccloud-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut text = cube_lattice_csv(|_| None);
    // Outside the body but on the plane z = 0, so the bottom boundary selects it.
    text += "0.3,0.3,0.0\n";
    let file = dir.join("cloud.csv");
    std::fs::write(&file, text).unwrap();
    let f = format!("discretization.cloud_file={}", file.display());
    let sc = common::load_scene(
        "cases/cube-compression.toml",
        &[
            "discretization.method=meshless",
            "discretization.cloud=file",
            f.as_str(),
            "discretization.integration=grid",
            "discretization.support=nearest",
        ],
    );
    let err = prepare(&sc).err().expect("must fail").to_string();
    assert!(
        err.contains("carries a boundary condition") && err.contains("125"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cloud_label_column_gives_sets_for_boundaries() {
    let dir = std::env::temp_dir().join(format!("hytled-labels-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Label 1 on the bottom layer, 2 on the top, 0 inside.
    let text = cube_lattice_csv(|k| {
        Some(match k {
            0 => 1,
            4 => 2,
            _ => 0,
        })
    });
    let file = dir.join("labelled.csv");
    std::fs::write(&file, text).unwrap();
    let f = format!("discretization.cloud_file={}", file.display());
    let base = vec![
        "discretization.method=meshless",
        "discretization.cloud=file",
        f.as_str(),
        "discretization.tet_rule=1",
    ];
    let planes = run_case("cases/cube-compression.toml", &base);
    let mut with_sets = base.clone();
    with_sets.extend([
        "boundaries.bottom.select={ set = \"1\" }",
        "boundaries.top.select={ set = \"2\" }",
        // The exact reference needs the driven face as a plane; with sets, the published value
        // (docs/reference.md) stands in.
        "references.top_force={ quantity = \"reaction.top.z\", value = -7.63269 }",
        "references.lateral={ quantity = \"probe.corner.x\", value = 0.011574668 }",
    ]);
    let sets = run_case("cases/cube-compression.toml", &with_sets);
    assert_eq!(planes.reactions["top"], sets.reactions["top"]);
    assert!(rel_err(&sets, "top_force") < 0.02);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Regression: irregular clouds on the cylinder with EBCIEM (the `auto` choice for radius
/// supports). The Delaunay tetrahedralization of a cylinder cloud closes its convex hull with
/// flat slivers that join lateral-surface nodes up to the full height apart. Counting those as
/// neighbours doubled the influence radii on the rims (the EBCIEM matrix Phi M^-1 V got a
/// condition number of 8e6 and the corrected system negative eigenvalues: divergence at step 14
/// for Halton, at any dt_factor), and hull faces joining a top-rim node to two bottom-rim nodes
/// were taken as constrained boundary triangles (jittered lattice: inversion within 400 steps).
///
/// Measured at size 0.0125 m (593 / 576 nodes), relaxation: Halton force 8.25 %, probe u_x
/// 7.24 %, 1,223 steps; lattice jitter 0.3 force 10.11 %, probe 6.39 %, 1,720 steps. The
/// regular lattice (jitter 0) at this size gives 11.49 % / 9.36 %, so the bounds are those of
/// the resolution, not of the cloud. Influence radii: largest / median 1.15 (Halton) and 1.17
/// (lattice); before the fix the rim radii reached 0.066 m against 0.024 m inside (Halton).
#[test]
fn cylinder_irregular_clouds_with_ebciem_converge() {
    for cloud in [
        &["discretization.cloud=halton"][..],
        &["discretization.cloud=lattice", "discretization.jitter=0.3"][..],
    ] {
        let mut ov = vec![
            "discretization.method=meshless",
            "discretization.size=0.0125",
            "solver.mode=relaxation",
        ];
        ov.extend_from_slice(cloud);
        let prep = prepared("cases/cylinder-compression.toml", &ov);
        let mut radii = prep.meshless().unwrap().support.radii.clone();
        radii.sort_by(f64::total_cmp);
        let spread = radii[radii.len() - 1] / radii[radii.len() / 2];
        let s = run_case("cases/cylinder-compression.toml", &ov);
        let (f, p) = (rel_err(&s, "force"), rel_err(&s, "probe_ux"));
        println!(
            "{cloud:?}: radii largest / median {spread:.3}, {} steps, force error {:.2} %, \
             probe error {:.2} %",
            s.steps,
            100.0 * f,
            100.0 * p
        );
        assert!(spread < 1.4, "{cloud:?}: influence radii spread {spread}");
        assert!(s.converged, "{cloud:?}: not converged");
        assert_eq!(s.bc_method.as_deref(), Some("ebciem"));
        assert!(f < 0.12 && p < 0.10, "{cloud:?}: force {f}, probe {p}");
    }
}
