//! The command line as scripts see it: errors without panics, exit codes and JSON status,
//! output folders, progress lines, signals while writing, labelled tables, bench and compare.

mod common;
use common::*;

use std::process::Command;

use hytled::simulation::{prepare, run_scene, RunOptions};

#[test]
fn cli_reports_errors_without_panicking() {
    let dir = std::env::temp_dir().join(format!("hytled-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        cube_text().replace("density = 1000.0", "density = \"heavy\""),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .arg("run")
        .arg(&bad)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(2),
        "input errors exit with 2: {stderr}"
    );
    assert!(
        stderr.contains("error:") && stderr.contains("bad.toml") && !stderr.contains("panicked"),
        "{stderr}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["run", "no/such/file.toml"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no/such/file.toml") && !stderr.contains("panicked"),
        "{stderr}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["run", "--set", "solver.mode=sideways"])
        .arg(path("cases/cube-compression.toml"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("sideways") && !stderr.contains("panicked"),
        "{stderr}"
    );
}

#[test]
fn cli_json_summary_has_the_documented_fields_and_outputs_are_written() {
    let dir = std::env::temp_dir().join(format!("hytled-json-{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["run", "--json", "--threads", "1", "--out"])
        .arg(&dir)
        .arg(path("cases/cube-compression.toml"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "scene",
        "method",
        "element",
        "nodes",
        "integration_points",
        "dt",
        "dt_critical",
        "steps",
        "simulated_time",
        "converged",
        "wall_seconds",
        "reactions",
        "probes",
        "energy",
        "reference",
    ] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
    for key in ["preprocess", "solve", "total"] {
        assert!(v["wall_seconds"][key].as_f64().is_some());
    }
    let fz = v["reactions"]["top"][2].as_f64().unwrap();
    assert!((fz + 7.63269).abs() < 0.005 * 7.63269);
    assert!(
        v["reference"]["top_force"]["relative_error"]
            .as_f64()
            .unwrap()
            < 0.005
    );
    // The cube solves statically by default: relaxation.csv comes with relaxation only.
    assert_eq!(v["mode"], "static");
    assert!(!dir.join("relaxation.csv").exists());
    for f in [
        "summary.json",
        "history.csv",
        "cube-compression.pvd",
        "cube-compression_0000.vtu",
        "cube-compression_0001.vtu",
    ] {
        assert!(dir.join(f).exists(), "missing output {f}");
    }
    // The final frame reads back in a VTK reader.
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["run", "--threads", "1", "--vtu-format", "ascii", "--out"])
        .arg(dir.join("ascii"))
        .arg(path("cases/cube-compression.toml"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let vtk = vtkio::Vtk::import(dir.join("ascii").join("cube-compression_0001.vtu"))
        .expect("vtkio reads the frame");
    if let vtkio::model::DataSet::UnstructuredGrid { pieces, .. } = vtk.data {
        let piece = pieces[0].load_piece_data(None).unwrap();
        assert_eq!(piece.num_points(), 729);
        // Displacement, five nodal fields and a label per boundary (four in the case).
        assert_eq!(piece.data.point.len(), 6 + 4);
        // Cauchy stress, von Mises stress, J and J_element.
        assert_eq!(piece.data.cell.len(), 4);
    } else {
        panic!("not an unstructured grid");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 22: exit codes scripts can use (0 success, 2 input, 3 unstable, 4 not converged,
/// 5 file system), the summary's status, a JSON error object on stdout with --json, and
/// --threads capped at the cores with a warning.
#[test]
fn exit_codes_and_json_status_tell_scripts_what_happened() {
    let run = |args: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
            .arg("run")
            .arg(path("cases/cube-compression.toml"))
            .args(["--set", "discretization.size=0.05"])
            .args(args)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).to_string(),
            String::from_utf8_lossy(&out.stderr).to_string(),
        )
    };
    let json = |s: &str| -> serde_json::Value {
        serde_json::from_str(s).unwrap_or_else(|e| panic!("not JSON ({e}): {s}"))
    };
    // Completed dynamic run.
    let (code, out, _) = run(&[
        "--json",
        "--set",
        "solver.mode=dynamic",
        "--set",
        "solver.duration=0.3",
    ]);
    assert_eq!(code, Some(0));
    assert_eq!(json(&out)["status"], "completed");
    // Converged relaxation.
    let (code, out, _) = run(&["--json", "--set", "solver.mode=relaxation"]);
    assert_eq!(code, Some(0));
    assert_eq!(json(&out)["status"], "converged");
    // Relaxation stopped by max_steps: the summary, its status and exit code 4.
    let (code, out, err) = run(&[
        "--json",
        "--set",
        "solver.mode=relaxation",
        "--set",
        "solver.max_steps=30",
    ]);
    assert_eq!(code, Some(4), "{err}");
    let v = json(&out);
    assert_eq!(v["status"], "not converged");
    assert_eq!(v["converged"], false);
    assert!(
        err.contains("did not converge") && err.contains("max_steps"),
        "{err}"
    );
    let (code, out, _) = run(&[
        "--set",
        "solver.mode=relaxation",
        "--set",
        "solver.max_steps=30",
    ]);
    assert_eq!(code, Some(4));
    assert!(out.contains("not converged"), "{out}");
    // Divergence: 3, and a JSON error object on stdout.
    let (code, out, err) = run(&[
        "--json",
        "--set",
        "solver.mode=relaxation",
        "--set",
        "solver.dt_factor=4",
    ]);
    assert_eq!(code, Some(3), "{err}");
    let v = json(&out);
    assert_eq!(v["status"], "failed");
    assert_eq!(v["error"], "unstable");
    assert_eq!(v["exit_code"], 3);
    assert!(v["message"].as_str().unwrap().contains("dt_factor"));
    // Input error: 2 (a bad value, and a usage error from clap).
    let (code, out, _) = run(&["--json", "--set", "material.poisson_ratio=0.7"]);
    assert_eq!(code, Some(2));
    assert_eq!(json(&out)["error"], "scene");
    // Issue 58: the kind and the facts, for a script to act on.
    assert_eq!(json(&out)["input_kind"], "scene");
    assert_eq!(json(&out)["facts"]["key"], "material");
    let (code, _, _) = run(&["--no-such-flag"]);
    assert_eq!(code, Some(2));
    // A file that cannot be read: 5.
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["run", "--json", "no/such/scene.toml"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(5));
    assert_eq!(json(&String::from_utf8_lossy(&out.stdout))["error"], "io");
    // More threads than cores: capped, with a warning, and the run succeeds.
    let (code, out, err) = run(&["--json", "--threads", "100000"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("more than the") && err.contains("cores"),
        "{err}"
    );
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    assert_eq!(json(&out)["threads"], cores);
}

/// `bench` refuses counts that would time nothing, before any run: exit 2 and a
/// message naming the flag.
#[test]
fn bench_flags_that_time_nothing_are_refused() {
    for (flag, value, says) in [
        ("--steps", "0", "--steps must be at least 1"),
        ("--repeat", "0", "--repeat must be at least 1"),
        ("--threads", "0", "thread counts must be at least 1"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
            .args(["bench", "cases/cube-compression.toml", flag, value])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{flag} {value}: {err}");
        assert!(err.contains(says), "{flag} {value}: {err}");
    }
}

/// Issue 22: an output folder holds exactly one run. A rerun with fewer frames leaves no old
/// frames; a failed rerun leaves summary.json with "status": "failed", the frames it wrote
/// before failing (written as they are produced) and no earlier results; a
/// folder with files hytled did not write, or a path that is a file, is refused before any
/// computing (exit 2).
#[test]
fn an_output_folder_holds_exactly_one_run() {
    let dir = std::env::temp_dir().join(format!("hytled-outfolder-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = |args: &[&str]| {
        coarse_dynamic_cube()
            .arg("--out")
            .arg(&dir)
            .args(args)
            .output()
            .unwrap()
    };
    let frames = || {
        let mut v: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .filter(|n| n.ends_with(".vtu") && n.starts_with("cube-compression_0"))
            .collect();
        v.sort();
        v
    };
    let status = || -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
    };
    assert!(run(&["--set", "output.frames=10"]).status.success());
    assert_eq!(frames().len(), 11);
    assert_eq!(status()["status"], "completed");
    assert!(run(&["--set", "output.frames=3"]).status.success());
    assert_eq!(frames().len(), 4, "{:?}", frames());
    let pvd = std::fs::read_to_string(dir.join("cube-compression.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 4);
    // A diverging rerun: no stale results, the failure recorded, and the frames it wrote up to
    // the divergence (at step 3, t = 0.06 s, with 0.02 s steps) kept for debugging, with their
    // .pvd; the earlier run's frames (t = 0, 0.1, 0.2, 0.3 s) are gone.
    let out = run(&["--set", "solver.dt_factor=4", "--set", "output.frames=10"]);
    assert_eq!(out.status.code(), Some(3));
    let pvd = std::fs::read_to_string(dir.join("cube-compression.pvd")).unwrap();
    let listed: Vec<&str> = pvd
        .split("file=\"")
        .skip(1)
        .filter_map(|r| r.split('"').next())
        .collect();
    assert!(!listed.is_empty() && listed.len() < 11, "{pvd}");
    assert_eq!(
        frames(),
        listed,
        "the folder holds exactly the failed run's frames"
    );
    let times: Vec<f64> = pvd
        .split("timestep=\"")
        .skip(1)
        .filter_map(|r| r.split('"').next()?.parse().ok())
        .collect();
    assert!(times.iter().all(|&t| t < 0.1), "{times:?}");
    let s = status();
    assert_eq!(s["status"], "failed");
    assert!(s["message"].as_str().unwrap().contains("diverged"), "{s}");
    // Someone else's file: refused before computing, and left alone.
    std::fs::write(dir.join("notes.txt"), "mine").unwrap();
    let t = std::time::Instant::now();
    let out = run(&["--set", "discretization.size=0.01"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("notes.txt") && err.contains("did not write"),
        "{err}"
    );
    assert!(t.elapsed().as_secs_f64() < 5.0, "checked before the solve");
    assert!(dir.join("notes.txt").exists());
    // A path that is a file.
    let file = dir.join("notes.txt");
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .arg("run")
        .arg(path("cases/cube-compression.toml"))
        .arg("--out")
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a folder"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 22: a dynamic run that would take more than 1e8 steps (here a dt_factor of 1e-12: about
/// 1e15) is refused at once with the settings to check, unless solver.max_steps allows it.
#[test]
fn an_unbounded_dynamic_run_is_refused_before_it_starts() {
    let sc = cube_scene(&[
        "solver.mode=dynamic",
        "solver.dt_factor=1e-12",
        "discretization.size=0.05",
    ]);
    let t = std::time::Instant::now();
    let e = run_scene(&sc, &RunOptions::default())
        .expect_err("1e15 steps")
        .to_string();
    assert!(t.elapsed().as_secs_f64() < 5.0);
    assert!(
        e.contains("steps") && e.contains("dt_factor") && e.contains("max_steps"),
        "{e}"
    );
}

/// Issue 22: with stderr not a terminal (here a pipe), progress comes as plain lines
/// (`--progress-every`, default 10 s there): step, time or load, error estimate, time left;
/// before them, the preparation's stages (meshing, points, critical step).
#[test]
fn batch_runs_print_plain_progress_lines() {
    for (mode, want) in [("dynamic", "left"), ("relaxation", "error estimate")] {
        let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
            .arg("run")
            .arg(path("cases/cube-compression.toml"))
            .args(["--set", "discretization.size=0.05", "--set"])
            .arg(format!("solver.mode={mode}"))
            .args(["--set", "solver.duration=0.5", "--progress-every", "0"])
            .output()
            .unwrap();
        assert!(out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        let lines: Vec<&str> = err
            .lines()
            .filter(|l| l.starts_with("progress: "))
            .collect();
        assert!(!lines.is_empty(), "{err}");
        assert!(
            lines.iter().any(|l| l.contains(want) && l.contains("step")),
            "{err}"
        );
        assert!(
            !err.contains('\r') && !err.contains('\u{1b}'),
            "no bar control codes: {err}"
        );
        // The preparation's stages come first, with the time since the start.
        let stages: Vec<&str> = err
            .lines()
            .take_while(|l| !l.contains(" step ") || l.contains("critical"))
            .collect();
        assert!(
            stages
                .iter()
                .any(|l| l.starts_with("progress: preparing the fe discretization ("))
                && stages
                    .iter()
                    .any(|l| l.starts_with("progress: critical step ") && l.contains("s elapsed)")),
            "{err}"
        );
    }
}

/// Issue 22, a run killed while it writes: a complete run, then a rerun into the same folder
/// killed (SIGKILL) as soon as its first frame is on disk. The folder then holds no result of
/// either run that looks current: the earlier frames are gone and summary.json says "running";
/// the frames written so far are in the staging folder only. The next run is not refused (the
/// killed run's files are hytled's own) and leaves exactly one run.
#[test]
fn a_run_killed_while_writing_leaves_no_stale_results() {
    let dir = std::env::temp_dir().join(format!("hytled-killed-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let names = || {
        let mut v: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        v.sort();
        v
    };
    let status = || -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
    };
    let complete_run = |extra: &[&str]| {
        let out = coarse_dynamic_cube()
            .args(extra)
            .arg("--out")
            .arg(&dir)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(status()["status"], "completed");
    };
    complete_run(&[]);
    // A long run (3,000 s of simulated time, 200 frames) killed at its first staged frame.
    let mut child = coarse_dynamic_cube()
        .args([
            "--set",
            "solver.duration=3000",
            "--set",
            "solver.max_steps=100000000",
        ])
        .args(["--set", "output.frames=200", "--out"])
        .arg(&dir)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let staging = dir.join(".hytled-partial");
    let t0 = std::time::Instant::now();
    let staged = loop {
        let n = std::fs::read_dir(&staging)
            .map(|d| d.filter(|e| e.is_ok()).count())
            .unwrap_or(0);
        if n > 0 {
            break true;
        }
        if child.try_wait().unwrap().is_some() || t0.elapsed().as_secs() > 60 {
            break false;
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    };
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(staged, "the run should have staged a frame before it ended");
    assert_eq!(
        status()["status"],
        "running",
        "no stale 'completed' summary"
    );
    let left = names();
    assert!(
        !left
            .iter()
            .any(|n| n.ends_with(".vtu") || n.ends_with(".pvd") || n.ends_with(".csv")),
        "the earlier run's results are gone: {left:?}"
    );
    // The next run takes the folder and leaves exactly one run.
    complete_run(&["--set", "output.frames=3"]);
    let left = names();
    assert!(!left.iter().any(|n| n == ".hytled-partial"), "{left:?}");
    let frames = left
        .iter()
        .filter(|n| n.ends_with(".vtu") && n.starts_with("cube-compression_0"))
        .count();
    assert_eq!(frames, 4, "{left:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 22, readability: reaction and probe columns are labelled, relaxation's time is called a
/// pseudo-time and its energy difference is put down to damping, and `hytled table` shows "-"
/// (not NaN) for a scene without references.
#[test]
fn summaries_and_tables_are_labelled() {
    let sc = cube_scene(&["discretization.size=0.05", "solver.mode=relaxation"]);
    let s = run_scene(&sc, &RunOptions::default()).unwrap();
    let t = s.table();
    let line = |start: &str| {
        t.lines()
            .find(|l| l.starts_with(start))
            .unwrap_or("")
            .to_string()
    };
    let r = line("reactions (N)");
    assert!(r.split_whitespace().skip(2).eq(["x", "y", "z"]), "{t}");
    assert!(line("probes (m)").contains("u_x"), "{t}");
    assert!(line("steps").contains("pseudo-time"), "{t}");
    assert!(line("energy (J)").contains("damping"), "{t}");
    let mut v = serde_json::to_value(&s).unwrap();
    v["reference"] = serde_json::json!({});
    let md = hytled::report::markdown_table(&[v]);
    // Without a reference the reaction column still shows the largest reaction, named
    // (issue 41: it was blank), and the columns of the comparison are "-", not NaN.
    let (name, k, x) = s
        .reactions
        .iter()
        .flat_map(|(n, r)| (0..3).map(move |k| (n.clone(), k, r[k])))
        .fold(("".to_string(), 0, 0.0f64), |b, c| {
            if c.2.abs() > b.2.abs() {
                c
            } else {
                b
            }
        });
    assert!(name == "top" || name == "bottom", "{name}");
    let axis = ["x", "y", "z"][k];
    assert!(
        md.contains(&format!("| {x:.4} ({name}.{axis}) | - | - | - |")),
        "{md}"
    );
    assert!(!md.contains("NaN"), "{md}");
}

/// Issue 22: frames are written while the run goes (the model computes their stresses between
/// steps); that must not change the run. Reactions and step counts with 30 streamed frames are
/// bitwise those of a run that writes nothing, for hex8, tet4-anp (nodal averages) and MLS.
#[test]
fn streaming_frames_does_not_change_the_run() {
    for set in [
        "discretization.element=hex8",
        "discretization.element=tet4-anp",
        "discretization.method=meshless",
    ] {
        let sc = cube_scene(&[
            "solver.mode=dynamic",
            "solver.duration=0.3",
            "discretization.size=0.05",
            "output.frames=30",
            set,
        ]);
        let plain = run_scene(&sc, &RunOptions::default()).unwrap();
        let dir = std::env::temp_dir().join(format!("hytled-stream-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let written = run_scene(
            &sc,
            &RunOptions {
                out: Some(dir.clone()),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(plain.steps, written.steps, "{set}");
        assert_eq!(
            serde_json::to_string(&plain.reactions).unwrap(),
            serde_json::to_string(&written.reactions).unwrap(),
            "{set}"
        );
        let vtus = std::fs::read_dir(&dir)
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .path()
                    .extension()
                    .is_some_and(|x| x == "vtu")
            })
            .count();
        assert_eq!(vtus, 31, "{set}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Issue 41: `bench --device gpu` on a machine without a GPU says so at once, before any
/// timing (it ran the CPU timings first). Where a GPU is present this is the GPU benchmark,
/// not a test.
#[test]
fn bench_on_a_missing_gpu_says_so_before_any_timing() {
    if hytled::solver::gpu::probe().is_ok() {
        return;
    }
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["bench", "--device", "gpu"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("--device gpu"), "{err}");
    assert!(!err.contains("bench:") && out.stdout.is_empty(), "{err}");
}

/// Issue 41, what a user reads: a relaxation scene that sets `output.frames` is told that
/// relaxation writes its unloaded, staged and converged states only; its plots call their axis
/// the relaxation's pseudo-time, a dynamic run's plain time.
#[test]
fn relaxation_says_what_its_frames_and_time_axis_are() {
    let frames_warned = |o: &[&str]| {
        let o: Vec<String> = o.iter().map(|s| s.to_string()).collect();
        let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
        prepare(&sc)
            .unwrap()
            .warnings
            .iter()
            .any(|w| w.contains("output.frames = 40 applies to dynamic runs"))
    };
    assert!(frames_warned(&[
        "discretization.size=0.05",
        "output.frames=40"
    ]));
    assert!(!frames_warned(&["discretization.size=0.05"]));
    assert!(!frames_warned(&[
        "discretization.size=0.05",
        "output.frames=40",
        "solver.mode=dynamic",
        "solver.duration=0.1",
    ]));
    for (mode, label) in [
        ("relaxation", "pseudo-time of the relaxation (s)"),
        ("dynamic", "\ntime (s)\n"),
    ] {
        let dir = std::env::temp_dir().join(format!("hytled-axis-{mode}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let sc = cube_scene(&[
            "discretization.size=0.05",
            &format!("solver.mode={mode}"),
            "solver.duration=0.3",
        ]);
        let opts = RunOptions {
            out: Some(dir.clone()),
            ..RunOptions::default()
        };
        run_scene(&sc, &opts).unwrap();
        for plot in ["reaction.svg", "energy.svg"] {
            let svg = std::fs::read_to_string(dir.join(plot)).unwrap();
            assert!(svg.contains(label), "{mode} {plot}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Issue 41: `hytled compare` says what each method is doing while it prepares and runs (it
/// was silent for the 30 s of a meshless run).
#[test]
fn compare_shows_each_methods_stages_as_it_goes() {
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .arg("compare")
        .arg(path("cases/cube-compression.toml"))
        .args([
            "--methods",
            "fe,meshless",
            "--set",
            "discretization.size=0.05",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{err}");
    for line in [
        "compare: meshless ...",
        "progress: preparing the meshless discretization",
        "progress: supports and MLS shape functions",
        "static: 100.0 % of the load",
    ] {
        assert!(err.contains(line), "{line}: {err}");
    }
}
