//! Issue 23, measured displacements: a file of displacements on part of the surface, matched to
//! its nodes and ramped by a curve (the image-driven brain-shift workflow), checked on the cube
//! whose exact homogeneous field is given on its top face (docs/reference.md).

mod common;
use common::{box_inp, box_node_id, path};

use std::path::PathBuf;

use hytled::simulation::{run_scene, RunOptions};

const A: f64 = 1.11574668; // docs/reference.md: lateral stretch of the cube compressed by 20 %

fn folder(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hytled-measured-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `x, y, z, ux, uy, uz` of the exact field u = ((a - 1) x, (a - 1) y, -0.2 z) on the top face,
/// at the (n + 1)^2 nodes of a grid of spacing 0.1 / n m, each moved by `jitter` (m) within the
/// face.
fn exact_top(n: usize, jitter: f64) -> String {
    let h = 0.1 / n as f64;
    let mut s = String::from("x,y,z,ux,uy,uz\n");
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (h * i as f64, h * j as f64);
            let (px, py) = (
                x + jitter * ((i + j) % 2) as f64,
                y - jitter * (j % 2) as f64,
            );
            s += &format!(
                "{px},{py},0.1,{},{},{}\n",
                (A - 1.0) * x,
                (A - 1.0) * y,
                -0.02
            );
        }
    }
    s
}

/// Relative errors of the top force and the corner's lateral displacement against the exact
/// cube (docs/reference.md: F_z = -7.63269 N, u_x = (a - 1) 0.1 m).
fn errors(s: &hytled::report::Summary) -> (f64, f64) {
    let f = s.reactions["top"][2];
    let u = s.probes["corner"].displacement[0];
    (
        (f + 7.63269).abs() / 7.63269,
        (u - (A - 1.0) * 0.1).abs() / ((A - 1.0) * 0.1),
    )
}

/// The cube case with its top boundary replaced by `[measured.top]` from `file`.
fn run(
    dir: &std::path::Path,
    file: &str,
    extra: &[&str],
) -> hytled::Result<hytled::report::Summary> {
    let text = std::fs::read_to_string(path("cases/cube-compression.toml")).unwrap();
    let start = text.find("[boundaries.top]").unwrap();
    let end = start + text[start..].find("\n\n").unwrap();
    let text = format!(
        "{}[measured.top]\nfile = \"{file}\"\ncurve = \"smooth\"\n{}",
        &text[..start],
        &text[end..]
    );
    let scene_file = dir.join("cube.toml");
    std::fs::write(&scene_file, text).unwrap();
    // The case's exact references need its driven face; these tests compare with them here.
    let mut o: Vec<String> = vec![
        "discretization.size=0.025".into(),
        "solver.tolerance=1e-9".into(),
        "references={}".into(),
    ];
    o.extend(extra.iter().map(|s| s.to_string()));
    let sc = hytled::scene::load(&scene_file, &o)?;
    run_scene(&sc, &RunOptions::default())
}

/// The exact displacements measured at the top face's nodes (and, for the methods whose
/// top nodes differ, matched within the tolerance): the cube reproduces the exact solution,
/// and the measured boundary's reaction is the exact top force (the references of the case).
#[test]
fn measured_exact_displacements_reproduce_the_exact_cube() {
    let dir = folder("exact");
    std::fs::write(dir.join("top.csv"), exact_top(4, 0.0)).unwrap();
    std::fs::write(dir.join("top-jitter.csv"), exact_top(4, 0.002)).unwrap();
    std::fs::write(dir.join("top-fine.csv"), exact_top(8, 0.0)).unwrap();
    for (file, method, tol) in [
        ("top.csv", &["discretization.method=fe"][..], 1e-6),
        (
            "top-jitter.csv",
            &["discretization.method=fe", "measured.top.tolerance=0.003"],
            1e-6,
        ),
        (
            "top.csv",
            &[
                "discretization.method=fe",
                "discretization.element=tet4-anp",
            ],
            1e-6,
        ),
        // Meshless: integration error, as for the cube driven by its top boundary (2 %).
        ("top.csv", &["discretization.method=meshless"], 2e-2),
        (
            "top-fine.csv",
            &[
                "discretization.method=coupled",
                "discretization.size=0.0125",
            ],
            2e-2,
        ),
    ] {
        let s = run(&dir, file, method).unwrap_or_else(|e| panic!("{method:?}: {e}"));
        let (ef, eu) = errors(&s);
        println!(
            "{file} {method:?}: top force {:?} N, force error {:.4} %, lateral error {:.4} %",
            s.reactions["top"],
            100.0 * ef,
            100.0 * eu
        );
        let tol: f64 = tol;
        assert!(ef < tol && eu < tol, "{method:?}");
    }
}

/// Node ids of a mesh file work too, and the errors say which line fails and why: a point
/// beyond the tolerance (with its distance), two points on one node, an unknown id.
#[test]
fn measured_ids_and_errors() {
    let dir = folder("ids");
    // The 4 x 4 x 4-cell cube as an ABAQUS file; node ids start at 101.
    let n = 4;
    let h = 0.1 / n as f64;
    let id = |i, j, k| box_node_id(n, 101, i, j, k);
    let inp = box_inp(n, 101, &[("ALL", 0..n)]);
    std::fs::write(dir.join("cube.inp"), inp).unwrap();
    let mut ids = String::from("id,ux,uy,uz\n");
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 * h, j as f64 * h);
            ids += &format!(
                "{},{},{},-0.02\n",
                id(i, j, n),
                (A - 1.0) * x,
                (A - 1.0) * y
            );
        }
    }
    std::fs::write(dir.join("ids.csv"), ids).unwrap();
    let mesh = format!(
        "geometry={{ mesh = \"{}\" }}",
        dir.join("cube.inp").display()
    );
    let s = run(&dir, "ids.csv", &[&mesh, "probes={}"]).unwrap();
    println!("ids: top force {:?} N", s.reactions["top"]);
    assert!((s.reactions["top"][2] + 7.63269).abs() < 1e-5 * 7.63269);

    std::fs::write(dir.join("far.csv"), "0.05,0.05,0.12,0,0,-0.01\n").unwrap();
    let e = run(&dir, "far.csv", &[]).unwrap_err().to_string();
    assert!(
        e.contains("far.csv line 1")
            && e.contains("beyond the tolerance")
            && e.contains("2.000e-2 m from"),
        "{e}"
    );
    std::fs::write(
        dir.join("twice.csv"),
        "0.05,0.05,0.1,0,0,-0.01\n0.0501,0.05,0.1,0,0,-0.01\n",
    )
    .unwrap();
    let e = run(&dir, "twice.csv", &[]).unwrap_err().to_string();
    assert!(
        e.contains("twice.csv line 2") && e.contains("line 1 already took"),
        "{e}"
    );
    std::fs::write(dir.join("unknown.csv"), "7,0,0,-0.01\n").unwrap();
    let e = run(&dir, "unknown.csv", &[&mesh]).unwrap_err().to_string();
    assert!(
        e.contains("unknown.csv line 1") && e.contains("no node 7"),
        "{e}"
    );
}

/// A rigid plate pressing measured nodes further than their measured displacement is a
/// conflict (the contact would undo the measurement): an error naming both, not a run that
/// "converges" with a contact force of zero.
#[test]
fn a_tool_pressing_measured_nodes_is_refused_naming_both() {
    let dir = folder("conflict");
    std::fs::write(dir.join("top.csv"), exact_top(4, 0.0)).unwrap();
    for mode in ["solver.mode=relaxation", "solver.mode=static"] {
        let e = run(
            &dir,
            "top.csv",
            &[
                "contact.plate={ shape = \"plane\", point = [0.0, 0.0, 0.1], normal = [0.0, 0.0, -1.0], motion = [0.0, 0.0, -0.03] }",
                mode,
            ],
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("contact 'plate'")
                && e.contains("'top'")
                && e.contains("prescribes that node"),
            "{mode}: {e}"
        );
    }
}

/// Issue 42, measured displacements interpolated: the exact field sampled on grids that share
/// no point with the mesh (7 x 7 and 23 x 23 over the top face, offset and jittered) and
/// interpolated onto the top face's nodes reproduces the exact cube (the fit holds linear
/// fields exactly), for fe and meshless; the matching of one point per node refuses the same
/// files. A grid away from the body is an error that says so.
#[test]
fn scattered_measurements_are_interpolated_onto_the_surface_nodes() {
    let dir = folder("interpolated");
    let grid = |n: usize, jitter: f64| {
        let mut s = String::from("x,y,z,ux,uy,uz\n");
        for j in 0..n {
            for i in 0..n {
                let h = 0.1 / (n - 1) as f64;
                let x = (h * i as f64 + jitter * ((i * 7 + j * 3) % 5) as f64).min(0.1);
                let y = (h * j as f64 + jitter * ((i * 2 + j * 5) % 5) as f64).min(0.1);
                s += &format!("{x},{y},0.1,{},{},-0.02\n", (A - 1.0) * x, (A - 1.0) * y);
            }
        }
        s
    };
    std::fs::write(dir.join("coarse.csv"), grid(7, 0.001)).unwrap();
    std::fs::write(dir.join("fine.csv"), grid(23, 0.0003)).unwrap();
    for file in ["coarse.csv", "fine.csv"] {
        for method in ["discretization.method=fe", "discretization.method=meshless"] {
            let s = run(&dir, file, &[method, "measured.top.interpolate=true"])
                .unwrap_or_else(|e| panic!("{file} {method}: {e}"));
            let (ef, eu) = errors(&s);
            println!("{file} {method}: force {ef:.2e}, corner {eu:.2e}");
            let tol = if method.ends_with("fe") { 1e-6 } else { 2e-2 };
            assert!(ef < tol && eu < tol, "{file} {method}: {ef:e} {eu:e}");
        }
    }
    let e = run(&dir, "fine.csv", &["discretization.method=fe"])
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("fine.csv"), "{e}");
    let mut far = String::from("x,y,z,ux,uy,uz\n");
    for k in 0..9 {
        far += &format!("{},{},0.5,0,0,0\n", 0.01 * k as f64, 0.02 * (k % 3) as f64);
    }
    std::fs::write(dir.join("far.csv"), far).unwrap();
    let e = run(&dir, "far.csv", &["measured.top.interpolate=true"])
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("far.csv") && e.contains("no surface node lies within"),
        "{e}"
    );
}
