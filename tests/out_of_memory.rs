//! An allocation that fails ends the process with a message and exit code 2, not an abort
//! (`hytled::memory::ExitOnOom`, the binary's global allocator). The failing allocation runs
//! in a child process: this test binary started again with `HYTLED_OOM_CHILD` set.

use std::process::Command;

#[global_allocator]
static ALLOCATOR: hytled::memory::ExitOnOom = hytled::memory::ExitOnOom;

const CHILD: &str = "HYTLED_OOM_CHILD";
const OUT: &str = "HYTLED_OOM_OUT";

#[test]
fn a_failed_allocation_exits_with_a_message() {
    if std::env::var_os(CHILD).is_some() {
        hytled::memory::ExitOnOom::report_json(true);
        // A run's claimed output folder, with its staging folder, as `hytled run --out` has.
        let dir = std::path::PathBuf::from(std::env::var_os(OUT).expect("the folder"));
        let claimed = hytled::io::out_dir::OutDir::open(&dir).expect("claim the folder");
        std::fs::write(claimed.staging().unwrap().join("run_0000.vtu"), b"frame").unwrap();
        // 2^50 bytes (1 PiB): more than any machine's memory, so malloc returns null.
        let v: Vec<u8> = Vec::with_capacity(1 << 50);
        // Not reached: the allocator has exited. Keeps the allocation from being elided.
        println!("allocated {}", v.capacity());
        std::process::exit(0);
    }
    let dir = std::env::temp_dir().join(format!("hytled-oom-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(std::env::current_exe().expect("test binary path"))
        .args([
            "--exact",
            "a_failed_allocation_exits_with_a_message",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD, "1")
        .env(OUT, &dir)
        .output()
        .expect("run the child");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(2),
        "stderr: {stderr}\nstdout: {stdout}"
    );
    assert!(
        stderr.contains("error: out of memory: an allocation of 1048576.00 GiB failed"),
        "{stderr}"
    );
    assert!(stderr.contains("discretization.size"), "{stderr}");
    assert!(!stdout.contains("allocated"), "{stdout}");
    // The --json error object, after the test harness's own lines.
    let json = &stdout[stdout.find('{').expect("a JSON object on stdout")..];
    let v: serde_json::Value = serde_json::from_str(json).expect("valid JSON");
    assert_eq!(v["status"], "failed");
    assert_eq!(v["exit_code"], 2);
    assert!(v["message"]
        .as_str()
        .is_some_and(|m| m.starts_with("out of memory: an allocation of")));
    // Issue 56: the claimed folder's summary says failed, with the message; the staging
    // folder is gone and the frame written before the failure kept.
    let summary = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    let v: serde_json::Value = serde_json::from_str(&summary).expect("valid JSON");
    assert_eq!(v["status"], "failed", "{summary}");
    assert!(summary.contains("out of memory"), "{summary}");
    assert!(!dir.join(".hytled-partial").exists());
    assert!(dir.join("run_0000.vtu").exists());
}
