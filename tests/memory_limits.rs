//! Runs held to the memory: outputs, divisions, history rows, meshless point tables and
//! address-space limits are planned for and refused early with the setting to change.

mod common;
use common::*;

use std::path::Path;
use std::process::Command;

/// Issue 22: output requests are held to what the run can use: more frames or history rows than
/// steps are not allocated (1e9 rows run in a few MB), and frames that would not fit in memory
/// (here a 20 kB limit through HYTLED_MEMORY_LIMIT) are an input error naming output.frames; a
/// cylinder whose O-grid divisions give 2e11 cells is refused before meshing.
#[test]
fn output_requests_and_divisions_are_held_to_the_memory() {
    let run = |extra: &[&str], limit: Option<&str>| {
        let mut c = coarse_dynamic_cube();
        c.args(extra);
        if let Some(l) = limit {
            c.env("HYTLED_MEMORY_LIMIT", l);
        }
        c.output().unwrap()
    };
    let out = run(&["--set", "output.history_rows=1000000000"], None);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = run(&["--set", "output.frames=1000000"], None);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // 20 kB: the model of 8 elements (11 kiB) passes its check before it is built; the run
    // with its 65 frames (68 kiB) does not.
    let out = run(&["--set", "output.frames=1000000"], Some("20000"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("output.frames") && err.contains("kiB of memory available"),
        "{err}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .arg("check")
        .arg(path("cases/cylinder-compression.toml"))
        .args(["--set", "discretization.divisions=[100000,4,20]"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("2.000e11 cells"), "{err}");
}

/// Issue 22: the dynamic history is planned before the loop: 1e9 rows asked of a run of over
/// 6,000 steps hold a row per step (about 0.6 MB), which a 200 kB memory limit refuses as an input error
/// naming output.history_rows; the same run with 100 rows passes under that limit.
#[test]
fn history_rows_are_checked_against_the_memory() {
    let run = |rows: &str| {
        let mut c = coarse_dynamic_cube();
        c.args(["--set", "solver.duration=30", "--set"])
            .arg(format!("output.history_rows={rows}"))
            .args(["--set", "output.frames=1"])
            .env("HYTLED_MEMORY_LIMIT", "200000");
        c.output().unwrap()
    };
    let out = run("1000000000");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    // The rows planned are the steps (over 6,000), not the 1e9 asked for.
    let rows: f64 = err
        .split(" history rows")
        .next()
        .and_then(|h| h.rsplit(' ').next())
        .and_then(|r| r.parse().ok())
        .unwrap_or(f64::NAN);
    assert!(
        err.contains("output.history_rows") && (6000.0..1e5).contains(&rows),
        "{err}"
    );
    let out = run("100");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Issue 22: a meshless point table that would not fit is refused before the shape functions
/// are computed, naming the points, the support size and the settings that lower them.
#[test]
fn meshless_point_table_is_checked_against_the_memory() {
    let out = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .arg("run")
        .arg(path("cases/cube-compression.toml"))
        .args([
            "--set",
            "discretization.method=meshless",
            "--set",
            "discretization.size=0.025",
        ])
        // 1 MB: above the early floor (1,536 points x 4 nodes, 576 kiB), below the sampled
        // table (about 28 nodes a point).
        .env("HYTLED_MEMORY_LIMIT", "1000000")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("meshless point table")
            && err.contains("integration points x about")
            && err.contains("support_nodes"),
        "{err}"
    );
}

/// A limit MemAvailable does not show (here `ulimit -v`; a container's or a batch job's cgroup
/// likewise) is planned for: the run stops with the memory message and exit code 2 instead of
/// aborting in the allocator, as it did when only MemAvailable was read (1.14 GiB of point
/// table under a 1.43 GiB address-space limit).
#[test]
fn an_address_space_limit_is_planned_for() {
    if !Path::new("/proc/self/limits").exists() {
        println!("skipped: no /proc/self/limits (not Linux)");
        return;
    }
    let out = Command::new("bash")
        .arg("-c")
        .arg("ulimit -v 1500000 && exec \"$@\"")
        .arg("hytled")
        .arg(env!("CARGO_BIN_EXE_hytled"))
        .arg("run")
        .arg(path("cases/cube-compression.toml"))
        .args([
            "--threads",
            "2",
            "--set",
            "discretization.method=meshless",
            "--set",
            "discretization.size=0.004",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("meshless point table (375000 integration points")
            && err.contains("more than 80 % of the")
            && !err.contains("panicked"),
        "{err}"
    );
}

/// A discretization that cannot fit in memory is refused as soon as its size is known, before
/// the large tables are built (it used to abort in the allocator after seconds to minutes:
/// a 2 m cube at 12.5 mm under `ulimit -v 4000000` aborted after 7 s as fe hex8, 41 s coupled,
/// 8 s meshless; TetGen at 1 mm made 15.9 M tets in 84 s first). `HYTLED_MEMORY_LIMIT` sets
/// the memory the command may use; each row names what is refused and a stage it must not
/// reach.
#[test]
fn discretizations_too_large_for_memory_are_refused_early() {
    let half_metre = [
        "geometry.max=[0.5,0.5,0.5]",
        "boundaries.top.select.plane.value=0.5",
    ];
    let tetgen = [
        "discretization.mesher=tetgen",
        "discretization.element=tet4",
        "discretization.size=0.002",
    ];
    // (command, --set values, memory limit in bytes, what is refused, a stage not reached)
    let rows: [(&str, &[&str], &str, &str, &str); 7] = [
        (
            "run",
            &half_metre,
            "50e6",
            "the model of the structured mesh (68921 nodes, 64000 elements) would take about 83.5 MiB",
            "progress: mesh:",
        ),
        (
            "run",
            &["discretization.method=coupled", half_metre[0], half_metre[1]],
            "50e6",
            "the model of the structured mesh (68921 nodes, 64000 elements)",
            "coupled build on",
        ),
        (
            "run",
            &tetgen,
            "300e6",
            "the model of a TetGen mesh of about 1909188 tets or more (edge 0.002 m)",
            "meshing with TetGen",
        ),
        (
            "run",
            &["discretization.method=meshless", tetgen[0], tetgen[1], tetgen[2]],
            "300e6",
            "the meshless point table (at least 7636753 integration points x 4 support nodes, on a TetGen mesh of about 1909188 tets or more (edge 0.002 m))",
            "meshing with TetGen",
        ),
        (
            "run",
            &["discretization.method=meshless", half_metre[0], half_metre[1]],
            "300e6",
            "the meshless point table (at least 1536000 integration points x 4 support nodes, on the structured mesh (68921 nodes, 384000 elements))",
            "meshless cloud:",
        ),
        (
            "run",
            &[
                "discretization.method=meshless",
                "discretization.tets_per_point=100",
                half_metre[0],
                half_metre[1],
            ],
            "50e6",
            "the integration points (384000 background tets x 4 points) would take about 96.7 MiB",
            "supports and MLS shape functions",
        ),
        (
            "mesh",
            &["discretization.divisions=[200,200,200]"],
            "300e6",
            "the mesh (8120601 nodes, 8000000 hex8 elements) would take about 674.1 MiB",
            "nodes, 8000000 elements",
        ),
    ];
    let dir = std::env::temp_dir().join(format!("hytled-refused-{}", std::process::id()));
    for (command, sets, limit, refused, not_reached) in rows {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_hytled"));
        cmd.arg(command)
            .arg(path("cases/cube-compression.toml"))
            .env("HYTLED_MEMORY_LIMIT", limit);
        if command == "run" {
            cmd.args(["--threads", "2"]);
        } else {
            cmd.arg("--out").arg(dir.join("mesh.vtu"));
        }
        for s in sets {
            cmd.args(["--set", s]);
        }
        let out = cmd.output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{sets:?}: {err}");
        assert!(
            err.contains(refused) && err.contains("more than 80 % of the"),
            "{sets:?}: {err}"
        );
        assert!(!err.contains(not_reached), "{sets:?}: {err}");
    }
    assert!(!dir.join("mesh.vtu").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
