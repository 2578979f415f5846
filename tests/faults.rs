//! Faults around a run, through the CLI as a user meets them: two runs into one output folder,
//! Ctrl-C and SIGTERM, and kills at random moments (`kill -9`, which nothing can catch). After
//! each, the folder must tell the truth (a summary that says "completed" lists only files that
//! are there, every file is the run's own) and the next run into it must succeed.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};

/// The cylinder compression, dynamic, on one thread: about 2-4 s, long enough to be caught
/// while it runs, with 40 frames to write.
fn start(out: &Path, extra: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_hytled"))
        .arg("run")
        .arg(common::path("cases/cylinder-compression.toml"))
        .args(["--threads", "1", "--set", "output.frames=40", "--out"])
        .arg(out)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("hytled starts")
}

fn fresh(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hytled-faults-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn summary(dir: &Path) -> Option<serde_json::Value> {
    std::fs::read_to_string(dir.join("summary.json"))
        .ok()
        .map(|t| serde_json::from_str(&t).unwrap_or_else(|e| panic!("summary.json: {e}: {t}")))
}

/// Waits until the run `pid` has claimed `dir` (its summary says "running") and its time loop
/// has started.
fn wait_running(dir: &Path, child: &mut Child) {
    let t0 = Instant::now();
    loop {
        let running = summary(dir).is_some_and(|v| {
            v["status"] == "running" && v["pid"].as_u64() == Some(child.id() as u64)
        });
        if running && dir.join(".hytled-partial").exists() {
            return;
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before it was seen running"
        );
        assert!(t0.elapsed() < Duration::from_secs(60), "never seen running");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// What a folder must be at any moment after any fault: every file listed by the manifest or
/// hytled's own hidden bookkeeping, summary.json valid JSON when present, and a summary that
/// says "completed" only beside all the files it lists.
fn check_truthful(dir: &Path) -> String {
    let listed: Vec<String> = std::fs::read_to_string(dir.join(".hytled-manifest"))
        .unwrap_or_default()
        .lines()
        .map(String::from)
        .collect();
    for e in std::fs::read_dir(dir).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().to_string();
        assert!(
            name.starts_with(".hytled-") || listed.contains(&name),
            "{name} is neither listed nor hytled's own: {listed:?}"
        );
    }
    let status = summary(dir).map_or("none".to_string(), |v| {
        v["status"].as_str().unwrap_or("?").to_string()
    });
    if status == "completed" {
        for n in &listed {
            assert!(dir.join(n).exists(), "completed, but {n} is missing");
        }
        let pvd = std::fs::read_to_string(dir.join("cylinder-compression.pvd")).unwrap();
        for frame in pvd.split("file=\"").skip(1) {
            let f = &frame[..frame.find('"').unwrap()];
            assert!(dir.join(f).exists(), "the .pvd lists {f}, which is missing");
        }
    }
    status
}

/// A short run (0.3 s simulated) into `dir`, which must complete and leave it truthful.
fn short_run(dir: &Path) {
    let out = start(dir, &["--set", "solver.duration=0.3"])
        .wait_with_output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(check_truthful(dir), "completed");
}

#[test]
fn a_second_run_into_a_busy_folder_is_refused_at_once_naming_the_first() {
    let d = fresh("busy");
    let mut a = start(&d, &[]);
    wait_running(&d, &mut a);
    let t0 = Instant::now();
    let b = start(&d, &["--json"]).wait_with_output().unwrap();
    assert!(t0.elapsed() < Duration::from_secs(10));
    assert_eq!(b.status.code(), Some(2));
    let err = String::from_utf8_lossy(&b.stderr);
    assert!(
        err.contains("another hytled run") && err.contains(&format!("process {}", a.id())),
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&b.stdout).unwrap();
    assert_eq!(v["status"], "failed");
    let a = a.wait_with_output().unwrap();
    assert_eq!(
        a.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&a.stderr)
    );
    assert_eq!(check_truthful(&d), "completed");
    // The folder is free again once the first run ended.
    short_run(&d);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn ctrl_c_and_sigterm_stop_between_steps_with_a_failed_summary_and_their_codes() {
    for (signal, code) in [("INT", 130), ("TERM", 143)] {
        let d = fresh(&format!("sig{signal}"));
        let mut child = start(&d, &["--json"]);
        wait_running(&d, &mut child);
        std::thread::sleep(Duration::from_millis(200));
        // The shell's own `kill`: no procps package needed.
        let killed = Command::new("sh")
            .args(["-c", &format!("kill -{signal} {}", child.id())])
            .status()
            .unwrap();
        assert!(killed.success());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{signal}: {err}");
        assert!(err.contains("interrupted by SIG"), "{err}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout)
            .unwrap_or_else(|e| panic!("{signal}: stdout is no JSON object ({e})"));
        assert_eq!(v["error"], "interrupted");
        assert_eq!(v["exit_code"], code);
        let s = summary(&d).unwrap();
        assert_eq!(s["status"], "failed", "{s}");
        assert_eq!(s["error"], "interrupted");
        assert!(s["message"].as_str().unwrap().contains("at step"), "{s}");
        assert_eq!(check_truthful(&d), "failed");
        let _ = std::fs::remove_dir_all(&d);
    }
}

#[test]
fn kills_at_random_moments_leave_a_truthful_folder_the_next_run_recovers() {
    let d = fresh("kill9");
    let mut rng = ChaCha8Rng::seed_from_u64(41);
    // A completed run first, so kills land on a folder with an earlier result to protect.
    short_run(&d);
    let mut statuses = Vec::new();
    for _ in 0..8 {
        let mut child = start(&d, &[]);
        // Most kills in the claim and the first frames, where the folder changes most.
        let ms = if rng.next_u32() % 2 == 0 {
            rng.next_u32() % 60
        } else {
            rng.next_u32() % 1500
        };
        std::thread::sleep(Duration::from_millis(ms as u64));
        let _ = child.kill();
        let _ = child.wait();
        statuses.push(check_truthful(&d));
    }
    eprintln!("after the kills: {statuses:?}");
    // A kill after the run completed leaves "completed"; any other leaves "running".
    assert!(
        statuses.iter().all(|s| s == "running" || s == "completed"),
        "{statuses:?}"
    );
    short_run(&d);
    let _ = std::fs::remove_dir_all(&d);
}

/// The library's stop request (another thread, a GUI's stop button; what the signal handlers
/// set): a run in this process stops at its first step with `Error::Interrupted` naming the
/// signal, and after `clear` runs again. The only in-process run of this test binary, so no
/// other test sees the request.
#[test]
fn a_stop_request_ends_a_library_run_and_clear_lifts_it() {
    use hytled::simulation::{run_scene, RunOptions};
    let sc = hytled::scene::load(
        &common::path("cases/cube-compression.toml"),
        &["discretization.size=0.05".to_string()],
    )
    .unwrap();
    hytled::interrupt::request(hytled::interrupt::SIGTERM);
    let e = run_scene(&sc, &RunOptions::default()).unwrap_err();
    hytled::interrupt::clear();
    assert!(
        matches!(e, hytled::Error::Interrupted { signal: 15, .. }),
        "{e}"
    );
    assert_eq!(e.exit_code(), 143);
    // Issue 56: preparation stops too, so the request is honoured before the first step.
    assert!(
        e.to_string()
            .contains("interrupted by SIGTERM before meshing"),
        "{e}"
    );
    assert_eq!(
        run_scene(&sc, &RunOptions::default()).unwrap().status,
        "converged"
    );
}

/// Issue 56: a signal during the preparation (here TetGen meshing a 2 mm cube, several
/// seconds) stops the run within a second, with the time loop's exit code and a "failed"
/// summary; TetGen's process is killed (it kept meshing for 708 s after SIGTERM).
#[test]
fn a_signal_while_meshing_stops_the_run_within_a_second() {
    let d = fresh("sig-meshing");
    let mut child = Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args(["run", "--json", "--out"])
        .arg(&d)
        .arg(common::path("cases/cube-compression.toml"))
        .args([
            "--set",
            "discretization.mesher=tetgen",
            "--set",
            "discretization.element=tet4-anp",
            "--set",
            "discretization.size=0.0025",
            "--set",
            "references={}",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Claimed (summary says running), then meshing: no staging folder before the solve.
    let t0 = Instant::now();
    while !summary(&d).is_some_and(|v| v["status"] == "running") {
        assert!(t0.elapsed() < Duration::from_secs(30), "never seen running");
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(1500));
    assert!(
        child.try_wait().unwrap().is_none(),
        "still meshing 1.5 s in"
    );
    let killed = Command::new("sh")
        .args(["-c", &format!("kill -TERM {}", child.id())])
        .status()
        .unwrap();
    assert!(killed.success());
    let t0 = Instant::now();
    let out = child.wait_with_output().unwrap();
    let stopped = t0.elapsed().as_secs_f64();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{err}");
    assert!(stopped < 1.0, "{stopped} s after SIGTERM");
    assert!(
        err.contains("interrupted by SIGTERM during TetGen"),
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["error"], "interrupted");
    let s = summary(&d).unwrap();
    assert_eq!(s["status"], "failed", "{s}");
    let _ = std::fs::remove_dir_all(&d);
}
