//! Issue 23, loads: gravity, point forces, dead tractions, follower pressure and tabulated load
//! curves, checked for every method against exact solutions (the homogeneous uniaxial cube,
//! docs/reference.md), the small-strain column under its own weight and global equilibrium.

use std::path::{Path, PathBuf};

use hytled::material::{uniaxial_stretch, NeoHookean};
use hytled::report::Summary;
use hytled::simulation::{run_scene, RunOptions};

mod common;
use common::ALL_METHODS;

/// A 0.1 m cube on the symmetry planes x = 0, y = 0, z = 0 (docs/reference.md, "Cube"), relaxation,
/// E = 3000 Pa, nu = 0.49, with `extra` TOML appended (loads, curves).
fn cube(extra: &str) -> String {
    format!(
        r#"name = "cube"
[geometry]
shape = "box"
min = [0.0, 0.0, 0.0]
max = [0.1, 0.1, 0.1]
[discretization]
method = "fe"
size = 0.025
[material]
youngs_modulus = 3000.0
poisson_ratio = 0.49
density = 1000.0
[boundaries.symmetry_x]
select = {{ plane = {{ axis = "x", value = 0.0 }} }}
fix = ["x"]
[boundaries.symmetry_y]
select = {{ plane = {{ axis = "y", value = 0.0 }} }}
fix = ["y"]
[boundaries.bottom]
select = {{ plane = {{ axis = "z", value = 0.0 }} }}
fix = ["z"]
[solver]
mode = "relaxation"
tolerance = 1e-10
[probes.corner]
position = [0.1, 0.1, 0.1]
{extra}
"#
    )
}

/// A folder of its own for a test's files.
fn folder(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hytled-loads-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs scene text (written into `dir`) with `--set` overrides.
fn run(text: &str, dir: &Path, overrides: &[&str]) -> Summary {
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let scene = hytled::scene::load(&path, &o).unwrap_or_else(|e| panic!("{e}"));
    let s =
        run_scene(&scene, &RunOptions::default()).unwrap_or_else(|e| panic!("{overrides:?}: {e}"));
    assert!(
        s.converged || s.mode == "dynamic",
        "{overrides:?}: not converged"
    );
    s
}

/// Relative tolerance on displacements against an exact homogeneous solution: FE elements pass
/// the patch test (solver tolerance); meshless and coupled points carry their integration
/// error, which the displacement-driven meshless cube (tests/meshless.rs) also shows (thesis
/// Tables 3.3, 4.5: 0.007-0.03 mm on this cube). Linear MLS and coupled: 0.5 % (measured up
/// to 0.08 % and 0.05 %); quadratic MMLS: the 2 % its displacement-driven cube test allows
/// (measured: traction u_z 0.93 / 0.68 / 0.52 % at 5 / 7 / 9 nodes per edge, converging;
/// displacement-driven lateral 0.39 % at 5).
fn tolerance(method: &[&str]) -> f64 {
    if method[0].ends_with("=fe") {
        1e-6
    } else if method.contains(&"discretization.basis=quadratic") {
        2e-2
    } else {
        5e-3
    }
}

/// Gravity alone on a cube fixed at its base: in relaxation the base reaction balances the
/// weight rho g V for every method, to solver tolerance.
#[test]
fn gravity_is_balanced_by_the_supports_for_every_method() {
    let dir = folder("gravity");
    let text = r#"name = "weight"
[geometry]
shape = "box"
min = [0.0, 0.0, 0.0]
max = [0.1, 0.1, 0.1]
[discretization]
size = 0.025
[material]
youngs_modulus = 3000.0
poisson_ratio = 0.45
density = 1000.0
[boundaries.base]
select = { plane = { axis = "z", value = 0.0 } }
fix = ["all"]
[loads.weight]
gravity = [0.0, 0.0, -9.81]
curve = "ramp"
[solver]
mode = "relaxation"
tolerance = 1e-9
"#;
    let weight = 1000.0 * 9.81 * 1e-3;
    for m in ALL_METHODS {
        let s = run(text, &dir, m);
        let r = s.reactions["base"];
        let l = s.loads["weight"];
        println!("{m:?}: base reaction {r:?} N, weight {l:?} N");
        assert!((l[2] + weight).abs() < 1e-12 * weight, "{m:?}: {l:?}");
        assert!((r[2] - weight).abs() < 1e-6 * weight, "{m:?}: {r:?}");
        assert!(r[0].abs().max(r[1].abs()) < 1e-6 * weight, "{m:?}: {r:?}");
    }
}

/// A slender column (0.02 x 0.02 x 0.2 m, E = 3 MPa, nu = 0) on a frictionless base under its
/// own weight: the small-strain solution u_z = -(rho g / E) (H z - z^2 / 2) (Timoshenko and
/// Goodier, the prism under its own weight; with nu = 0 the roller base is exact) gives the
/// top u_z = -rho g H^2 / (2 E) = -6.54e-5 m; strains of 6.5e-4 make the geometric
/// nonlinearity a 1e-3 effect.
#[test]
fn a_column_under_its_own_weight_matches_the_small_strain_solution() {
    let dir = folder("column");
    let text = r#"name = "column"
[geometry]
shape = "box"
min = [0.0, 0.0, 0.0]
max = [0.02, 0.02, 0.2]
[discretization]
size = 0.005
[material]
youngs_modulus = 3.0e6
poisson_ratio = 0.0
density = 1000.0
[boundaries.base]
select = { plane = { axis = "z", value = 0.0 } }
fix = ["z"]
[boundaries.side_x]
select = { plane = { axis = "x", value = 0.0 } }
fix = ["x"]
[boundaries.side_y]
select = { plane = { axis = "y", value = 0.0 } }
fix = ["y"]
[loads.weight]
gravity = [0.0, 0.0, -9.81]
[solver]
mode = "relaxation"
tolerance = 1e-11
[probes.top]
position = [0.01, 0.01, 0.2]
[probes.middle]
position = [0.01, 0.01, 0.1]
"#;
    let (rho_g, e, h) = (1000.0 * 9.81, 3.0e6, 0.2);
    let exact = |z: f64| -(rho_g / e) * (h * z - 0.5 * z * z);
    for m in [
        &["discretization.method=fe"][..],
        &[
            "discretization.method=fe",
            "discretization.element=tet4-anp",
        ],
        &["discretization.method=meshless"],
        &[
            "discretization.method=coupled",
            "discretization.fe_layers=1",
        ],
    ] {
        let s = run(text, &dir, m);
        for (p, z) in [("top", 0.2), ("middle", 0.1)] {
            let u = s.probes[p].displacement[2];
            let err = (u - exact(z)).abs() / exact(z).abs();
            println!(
                "{m:?}: {p} u_z = {u:.6e} m, small strain {:.6e} m, error {:.3} %",
                exact(z),
                100.0 * err
            );
            assert!(err < 0.005, "{m:?} {p}: {u} vs {}", exact(z));
        }
        assert!((s.reactions["base"][2] - rho_g * 0.02 * 0.02 * 0.2).abs() < 1e-6 * rho_g * 8e-5);
    }
}

/// The cube pulled by a uniform dead traction t on its top: the exact solution is homogeneous
/// (docs/reference.md), with the first Piola stress P_zz = t = sigma_zz a^2 for the stretch lambda
/// whose lateral stress vanishes. The traction for lambda = 1.1 is applied; the corner moves
/// by ((a - 1) L, (a - 1) L, (lambda - 1) L), and the load's total is t times the area.
#[test]
fn a_cube_pulled_by_a_uniform_traction_reproduces_the_exact_solution() {
    let dir = folder("traction");
    let m = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let stretch = 1.1;
    let (a, _, sigma) = uniaxial_stretch(&m, stretch);
    let t = sigma * a * a;
    let text = cube(&format!(
        "[loads.pull]\nselect = {{ plane = {{ axis = \"z\", value = 0.1 }} }}\ntraction = [0.0, 0.0, {t}]\n"
    ));
    for method in ALL_METHODS {
        let s = run(&text, &dir, method);
        let u = s.probes["corner"].displacement;
        let want = [(a - 1.0) * 0.1, (a - 1.0) * 0.1, (stretch - 1.0) * 0.1];
        let tol = tolerance(method);
        println!("{method:?}: corner {u:?} m, exact {want:?} m");
        for k in 0..3 {
            assert!(
                (u[k] - want[k]).abs() < tol * want[k].abs(),
                "{method:?} {k}: {u:?} vs {want:?}"
            );
        }
        let total = s.loads["pull"];
        assert!((total[2] - t * 0.01).abs() < 1e-12 * t * 0.01 && total[0] == 0.0);
        assert!((s.reactions["bottom"][2] + t * 0.01).abs() < 1e-6 * t * 0.01);
    }
}

/// The cube compressed by a follower pressure p on its top: the exact homogeneous solution has
/// sigma_zz = -p (found by bisection on the stretch), and the load's total is -p times the
/// deformed top area (a L)^2: the pressure acts on the deformed face.
#[test]
fn a_cube_under_follower_pressure_reproduces_the_exact_solution() {
    let dir = folder("pressure");
    let m = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let p = 300.0;
    let (mut lo, mut hi) = (0.3, 1.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if uniaxial_stretch(&m, mid).2 < -p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let stretch = 0.5 * (lo + hi);
    let (a, _, _) = uniaxial_stretch(&m, stretch);
    let text = cube(&format!(
        "[loads.press]\nselect = {{ plane = {{ axis = \"z\", value = 0.1 }} }}\npressure = {p}\n"
    ));
    for method in ALL_METHODS {
        let s = run(&text, &dir, method);
        let u = s.probes["corner"].displacement;
        let want = [(a - 1.0) * 0.1, (a - 1.0) * 0.1, (stretch - 1.0) * 0.1];
        let tol = tolerance(method);
        println!(
            "{method:?}: corner {u:?} m, exact {want:?} m, load {:?} N",
            s.loads["press"]
        );
        for k in 0..3 {
            assert!(
                (u[k] - want[k]).abs() < tol * want[k].abs(),
                "{method:?} {k}: {u:?} vs {want:?}"
            );
        }
        let area = (a * 0.1) * (a * 0.1);
        let total = s.loads["press"][2];
        assert!(
            (total + p * area).abs() < 2.0 * tol * p * area,
            "{method:?}: {total} vs {}",
            -p * area
        );
    }
}

/// Several loads at once, with tabulated curves: gravity (inline table to a factor 0.5),
/// point forces on the top corner nodes (CSV table) and a traction: the supports balance the
/// sum of the loads' totals, and each total is its value times its table's last factor.
#[test]
fn several_loads_with_tabulated_curves_are_balanced() {
    let dir = folder("several");
    std::fs::write(dir.join("pull.csv"), "time,factor\n0,0\n1.5,0.3\n3.0,0.8\n").unwrap();
    let text = cube(
        r#"[loads.weight]
gravity = [0.0, 0.0, -9.81]
curve = "half"
[loads.corner_pull]
select = { box = { min = [0.099, 0.099, 0.099], max = [0.101, 0.101, 0.101] } }
force = [0.0, 0.0, 0.05]
curve = "from_file"
[loads.top]
select = { plane = { axis = "z", value = 0.1 } }
traction = [0.0, 0.0, 20.0]
curve = "ramp"
[curves.half]
points = [[0.0, 0.0], [3.0, 0.5]]
[curves.from_file]
file = "pull.csv"
"#,
    );
    for method in ALL_METHODS {
        let s = run(&text, &dir, method);
        let weight = s.loads["weight"];
        let pull = s.loads["corner_pull"];
        let top = s.loads["top"];
        assert!((weight[2] + 0.5 * 9.81).abs() < 1e-12 * 9.81, "{weight:?}");
        assert!((pull[2] - 0.8 * 0.05).abs() < 1e-12, "{pull:?}");
        assert!((top[2] - 20.0 * 0.01).abs() < 1e-12, "{top:?}");
        let applied = weight[2] + pull[2] + top[2];
        let supports = s.reactions["bottom"][2];
        println!("{method:?}: loads {applied:.6e} N, bottom reaction {supports:.6e} N");
        assert!(
            (supports + applied).abs() < 1e-6 * applied.abs(),
            "{method:?}"
        );
    }
}

/// A dynamic run under gravity conserves energy: the loads' work equals strain plus kinetic
/// energy (no damping), and an undefined curve name or a load with two kinds is an input
/// error naming the key.
#[test]
fn gravity_in_dynamics_keeps_the_energy_balance_and_bad_loads_are_named() {
    let dir = folder("dynamic");
    let text = cube("[loads.weight]\ngravity = [0.0, 0.0, -9.81]\ncurve = \"smooth\"\n");
    let s = run(&text, &dir, &["solver.mode=dynamic", "solver.duration=1.0"]);
    let b = s.energy.balance_error.unwrap();
    println!(
        "energy balance error {:.3e}, work {:.4e} J",
        b, s.energy.external_work
    );
    assert!(s.energy.external_work > 0.0 && b < 0.01, "{b}");
    let path = dir.join("bad.toml");
    for (extra, key) in [
        ("[loads.w]\ngravity = [0.0, 0.0, -9.81]\ncurve = \"smoth\"\n", "loads.w.curve = 'smoth'"),
        ("[loads.w]\ngravity = [0.0, 0.0, -9.81]\npressure = 3.0\n", "loads.w: give exactly one"),
        ("[loads.w]\npressure = 3.0\n", "loads.w: needs `select"),
        ("[curves.c]\npoints = [[0.0, 0.0], [0.0, 1.0]]\n[loads.w]\ngravity = [0.0, 0.0, 1.0]\ncurve = \"c\"\n", "curves.c: times must increase"),
        // Issue 41: arrays longer than their key takes are refused, not truncated.
        ("[loads.w]\ngravity = [0.0, 0.0, -9.81, 1.0]\n", "loads.w.gravity: 4 values given, it takes 3"),
        ("[curves.c]\npoints = [[0.0, 0.0, 5.0], [1.0, 1.0]]\n[loads.w]\ngravity = [0.0, 0.0, 1.0]\ncurve = \"c\"\n", "curves.c.points[0]: 3 values given, it takes 2"),
        // Issue 41: a missing or misread curve file names its key.
        ("[curves.c]\nfile = \"missing.csv\"\n[loads.w]\ngravity = [0.0, 0.0, 1.0]\ncurve = \"c\"\n", "missing.csv (curves.c.file)"),
        ("[curves.c]\nfile = \"mac.csv\"\n[loads.w]\ngravity = [0.0, 0.0, 1.0]\ncurve = \"c\"\n", "mac.csv (curves.c.file): line 2"),
    ] {
        std::fs::write(dir.join("mac.csv"), "0,0\r0,5;1,0\r").unwrap();
        std::fs::write(&path, cube(extra)).unwrap();
        let e = hytled::scene::load(&path, &[])
            .and_then(|sc| run_scene(&sc, &RunOptions::default()))
            .map(|_| ())
            .unwrap_err()
            .to_string();
        assert!(e.contains(key), "{e}");
    }
}

/// Issue 41: a load applied from t = 0 is exact from the first step. The cube falls freely
/// under constant gravity (held only against sliding sideways): every node at u_z = -g t^2 / 2
/// (central differences are exact for constant acceleration once the first step takes half
/// the acceleration term; before, u_z = -g t (t + dt) / 2, 0.43 % ahead after 234 steps).
#[test]
fn free_fall_under_constant_gravity_is_exact_from_the_first_step() {
    let dir = folder("free-fall");
    let bottom =
        "[boundaries.bottom]\nselect = { plane = { axis = \"z\", value = 0.0 } }\nfix = [\"z\"]\n";
    let text = cube("[loads.weight]\ngravity = [0.0, 0.0, -9.81]\ncurve = \"constant\"\n");
    assert!(text.contains(bottom));
    let text = text.replace(bottom, "");
    let s = run(
        &text,
        &dir,
        &["solver.mode=dynamic", "solver.duration=0.05"],
    );
    let t = s.simulated_time;
    let uz = s.probes["corner"].displacement[2];
    let exact = -0.5 * 9.81 * t * t;
    println!(
        "free fall: {} steps, t = {t} s, u_z {uz:.9e} m, exact {exact:.9e} m",
        s.steps
    );
    assert!(s.steps > 20);
    assert!(((uz - exact) / exact).abs() < 1e-9, "{uz} vs {exact}");
}

/// Issue 41, no warning without a cause: a relaxation whose load goes there and back ends at
/// zero load with forces of rounding size; measured against those, its residual read 0.50
/// (fe) and 6.6e-2 (meshless) with a warning. Measured against the largest nodal force of the
/// run it is small, for every method, and nothing is warned.
#[test]
fn a_relaxation_whose_load_returns_to_zero_warns_of_nothing() {
    for method in ALL_METHODS {
        let mut o: Vec<String> = method.iter().map(|s| s.to_string()).collect();
        if !o.iter().any(|s| s.starts_with("discretization.size")) {
            o.push("discretization.size=0.025".into());
        }
        o.extend([
            "boundaries.top.curve=smooth-return".to_string(),
            "references={}".to_string(),
        ]);
        let scene = hytled::scene::load(&common::path("cases/cube-compression.toml"), &o).unwrap();
        let s = run_scene(&scene, &RunOptions::default()).unwrap();
        assert_eq!(s.status, "converged", "{method:?}");
        assert!(s.warnings.is_empty(), "{method:?}: {:?}", s.warnings);
        assert!(s.equilibrium_residual.unwrap() < 1e-3, "{method:?}");
        // Back at zero load, the top is back where it started.
        assert!(
            s.probes["corner"].displacement[2].abs() < 1e-6,
            "{method:?}"
        );
    }
}

/// Issue 41: a relaxation whose displacement criterion is met while the body is far from
/// equilibrium (here a criterion of 1 m after 10 load steps) is "not converged", with a
/// warning that says why; the same with the criterion's default is converged.
#[test]
fn met_criterion_far_from_equilibrium_is_not_converged() {
    let case = common::path("cases/cube-compression.toml");
    let run = |o: &[&str]| {
        let o: Vec<String> = o.iter().map(|s| s.to_string()).collect();
        run_scene(
            &hytled::scene::load(&case, &o).unwrap(),
            &RunOptions::default(),
        )
        .unwrap()
    };
    let s = run(&[
        "solver.mode=relaxation",
        "discretization.size=0.025",
        "solver.tolerance=1",
        "solver.load_steps=10",
    ]);
    assert_eq!(s.status, "not converged");
    assert!(!s.converged);
    assert!(s.equilibrium_residual.unwrap() > 1e-2);
    assert!(
        s.warnings
            .iter()
            .any(|w| w.contains("displacement criterion")),
        "{:?}",
        s.warnings
    );
    let s = run(&[
        "solver.mode=relaxation",
        "discretization.size=0.025",
        "solver.load_steps=10",
    ]);
    assert_eq!(s.status, "converged");
}
