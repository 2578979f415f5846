//! How much memory a run may take, and the guard that turns an allocation that would exhaust
//! the machine into an input error naming the setting to change (instead of an abort in the
//! allocator).

use std::path::{Path, PathBuf};

use crate::{Error, InputKind, Result};

/// Bytes in a GiB.
pub const GIB: f64 = 1024.0 * 1024.0 * 1024.0;

/// Share of the available memory one run may plan to hold.
pub const SHARE: f64 = 0.8;

/// Bytes one support slot (a node of one point's support, an element's node for FE points)
/// takes at the peak of the build and in the solver: its node id and dphi/dX in the build's
/// chunk and again in the point table, the solver's slot map and force buffers. The brain
/// scene (11.0 M meshless slots) measured 1.22 GiB in all, about 119 bytes per slot with
/// everything else the run holds; a 3.07 M-element tet4 cube (12.3 M slots), 1.14 GiB peak,
/// 100 bytes per slot.
pub const BYTES_PER_SLOT: f64 = 96.0;

/// Memory a run may use, bytes: the least of the system's available memory (Linux: MemAvailable
/// of /proc/meminfo), what the process's memory cgroups leave (limit minus usage, in its cgroup
/// and every parent: containers and batch jobs such as Slurm's, whose limit MemAvailable does
/// not show), the address space `ulimit -v` leaves (limit minus VmSize), and the environment's
/// `HYTLED_MEMORY_LIMIT` (bytes, for shared machines); None when none is known.
pub fn available() -> Option<f64> {
    let read = |p: &Path| std::fs::read_to_string(p).ok();
    let system = read(Path::new("/proc/meminfo")).and_then(|t| meminfo_available(&t));
    let cgroup = read(Path::new("/proc/self/cgroup")).and_then(|t| cgroup_left(&t, read));
    let address = match (
        read(Path::new("/proc/self/limits")),
        read(Path::new("/proc/self/status")),
    ) {
        (Some(l), Some(s)) => address_space_left(&l, &s),
        _ => None,
    };
    let limit = std::env::var("HYTLED_MEMORY_LIMIT")
        .ok()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|v| *v > 0.0);
    [system, cgroup, address, limit]
        .into_iter()
        .flatten()
        .reduce(f64::min)
}

/// MemAvailable of /proc/meminfo, bytes.
fn meminfo_available(meminfo: &str) -> Option<f64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024.0)
}

/// Limits at or above this are "no limit" (cgroup v1 writes 2^63 rounded down to a page).
const NO_LIMIT: f64 = (1u64 << 60) as f64;

/// The least (limit - usage) over the memory cgroups of /proc/self/cgroup and their parents,
/// bytes: cgroup v2 (`0::/path`: memory.max, "max" for none, and memory.current under
/// /sys/fs/cgroup) and v1 (`N:...memory...:/path`: memory.limit_in_bytes and
/// memory.usage_in_bytes under /sys/fs/cgroup/memory). `read` gives a file's text.
fn cgroup_left(proc_cgroup: &str, read: impl Fn(&Path) -> Option<String>) -> Option<f64> {
    let number = |p: PathBuf| -> Option<f64> {
        read(&p)?
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| *v < NO_LIMIT)
    };
    let mut least: Option<f64> = None;
    for line in proc_cgroup.lines() {
        let mut f = line.splitn(3, ':');
        let (Some(id), Some(controllers), Some(path)) = (f.next(), f.next(), f.next()) else {
            continue;
        };
        let (root, limit, usage) = if id == "0" && controllers.is_empty() {
            ("/sys/fs/cgroup", "memory.max", "memory.current")
        } else if controllers.split(',').any(|c| c == "memory") {
            (
                "/sys/fs/cgroup/memory",
                "memory.limit_in_bytes",
                "memory.usage_in_bytes",
            )
        } else {
            continue;
        };
        // The cgroup and each parent up to the root of the mount.
        let mut dir = Some(Path::new(path.trim()));
        while let Some(d) = dir {
            let at = Path::new(root).join(d.strip_prefix("/").unwrap_or(d));
            if let (Some(l), Some(u)) = (number(at.join(limit)), number(at.join(usage))) {
                let left = (l - u).max(0.0);
                least = Some(least.map_or(left, |x| x.min(left)));
            }
            dir = d.parent();
        }
    }
    least
}

/// The address space `ulimit -v` leaves: the soft "Max address space" of /proc/self/limits
/// minus VmSize of /proc/self/status, bytes; None when unlimited.
fn address_space_left(limits: &str, status: &str) -> Option<f64> {
    let line = limits
        .lines()
        .find(|l| l.starts_with("Max address space"))?;
    let soft: f64 = line
        .trim_start_matches("Max address space")
        .split_whitespace()
        .next()?
        .parse()
        .ok()?;
    let vm = status.lines().find(|l| l.starts_with("VmSize:"))?;
    let kib: f64 = vm.split_whitespace().nth(1)?.parse().ok()?;
    Some((soft - kib * 1024.0).max(0.0))
}

/// A mesh's size before it is made, for the memory checks: counts as f64 (a planned count
/// may pass any integer type) and what it is, for messages.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedMesh {
    pub nodes: f64,
    pub elements: f64,
    pub what: String,
}

/// Refuses a plan that would hold `need` bytes when that is more than [`SHARE`] of the
/// available memory: the error says what would take the memory (`what`) and how to lower it
/// (`fix`).
pub fn check(need: f64, what: &str, fix: &str) -> Result<()> {
    match available() {
        Some(avail) if need > SHARE * avail => Err(Error::input(
            InputKind::Limit,
            format!(
            "{what} would take about {}, more than {:.0} % of the {} of memory available: {fix}",
            size(need),
            100.0 * SHARE,
            size(avail)
        ),
        )),
        _ => Ok(()),
    }
}

/// A byte count for messages: "1.25 GiB", "3.4 MiB", "812 kiB" or "96 bytes".
pub fn size(bytes: f64) -> String {
    Size(bytes).to_string()
}

/// [`size`] as a Display that formats without allocating (for the out-of-memory message).
pub struct Size(pub f64);

impl std::fmt::Display for Size {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        const KIB: f64 = 1024.0;
        const MIB: f64 = 1024.0 * 1024.0;
        let bytes = self.0;
        if bytes >= GIB {
            write!(f, "{:.2} GiB", bytes / GIB)
        } else if bytes >= MIB {
            write!(f, "{:.1} MiB", bytes / MIB)
        } else if bytes >= KIB {
            write!(f, "{:.0} kiB", bytes / KIB)
        } else {
            write!(f, "{bytes:.0} bytes")
        }
    }
}

/// The system allocator, except that an allocation that fails ends the process with a clear
/// message and exit code 2 ([`crate::error::exit::INPUT`]) instead of Rust's abort ("memory
/// allocation of N bytes failed", SIGABRT, core dump). The memory plans ([`check`]) refuse the
/// large tables before they are built; this catches what they do not foresee (a mesher's own
/// structures, a limit that tightened during the run). The binary registers it with
/// `#[global_allocator]`; a library user keeps their own allocator.
pub struct ExitOnOom;

/// Whether [`ExitOnOom`] also prints the failure as the `--json` error object on stdout.
static OOM_JSON: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

impl ExitOnOom {
    /// Makes an allocation failure also print `{"status": "failed", ...}` on stdout, as
    /// `--json` commands do for every error.
    pub fn report_json(on: bool) {
        OOM_JSON.store(on, std::sync::atomic::Ordering::Relaxed);
    }
}

// SAFETY: every call is forwarded to `System` with the same arguments; only a null result is
// intercepted, and then the process ends.
unsafe impl std::alloc::GlobalAlloc for ExitOnOom {
    #[inline]
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        let p = unsafe { std::alloc::System.alloc(layout) };
        if p.is_null() {
            out_of_memory(layout.size());
        }
        p
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        let p = unsafe { std::alloc::System.alloc_zeroed(layout) };
        if p.is_null() {
            out_of_memory(layout.size());
        }
        p
    }

    #[inline]
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { std::alloc::System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            out_of_memory(new_size);
        }
        p
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
}

/// Called with the message after an allocation failed, before the process exits (see
/// [`on_out_of_memory`]).
static OOM_HOOK: std::sync::atomic::AtomicPtr<()> =
    std::sync::atomic::AtomicPtr::new(std::ptr::null_mut());
/// Set once an allocation has failed: a failure inside the hook exits at once.
static OOM_SEEN: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Registers `hook`, run with the message when [`ExitOnOom`] ends the process: the output
/// folder marks its summary failed there ([`crate::io::out_dir`]). The failed allocation is
/// usually a large one, so the hook may allocate; if it cannot, the process exits all the same.
pub fn on_out_of_memory(hook: fn(&str)) {
    OOM_HOOK.store(hook as *mut (), std::sync::atomic::Ordering::SeqCst);
}

/// Writes the out-of-memory error and exits with code 2. Nothing here may allocate: the
/// message is formatted into a buffer on the stack (float formatting does not allocate).
#[cold]
fn out_of_memory(bytes: usize) -> ! {
    use std::io::Write;
    let mut buf = [0u8; 640];
    let len = {
        let mut w = &mut buf[..];
        let _ = write!(
            w,
            "out of memory: an allocation of {} failed. The run needs more memory than this process may \
             use (see the machine's free memory, `ulimit -v` and the job's memory limit): raise \
             discretization.size or lower its divisions, use fewer integration points (tet_rule, \
             tets_per_point, point_ratio) or smaller supports, or run on a machine with more memory",
            Size(bytes as f64)
        );
        640 - w.len()
    };
    let msg = &buf[..len];
    let mut err = std::io::stderr().lock();
    let _ = err.write_all(b"error: ");
    let _ = err.write_all(msg);
    let _ = err.write_all(b"\n");
    if OOM_JSON.load(std::sync::atomic::Ordering::Relaxed) {
        let mut out = std::io::stdout().lock();
        let _ = out.write_all(
            b"{\n  \"status\": \"failed\",\n  \"error\": \"input\",\n  \"exit_code\": 2,\n  \"message\": \"",
        );
        let _ = out.write_all(msg);
        let _ = out.write_all(b"\"\n}\n");
        let _ = out.flush();
    }
    let hook = OOM_HOOK.load(std::sync::atomic::Ordering::SeqCst);
    if !hook.is_null() && !OOM_SEEN.swap(true, std::sync::atomic::Ordering::SeqCst) {
        // SAFETY: only `on_out_of_memory` stores here, always a `fn(&str)`.
        let hook: fn(&str) = unsafe { std::mem::transmute::<*mut (), fn(&str)>(hook) };
        if let Ok(text) = std::str::from_utf8(msg) {
            hook(text);
        }
    }
    std::process::exit(crate::error::exit::INPUT as i32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn meminfo_gives_the_available_bytes() {
        let t = "MemTotal:       24684084 kB\nMemFree:  100 kB\nMemAvailable:   23122432 kB\n";
        assert_eq!(meminfo_available(t), Some(23122432.0 * 1024.0));
        assert_eq!(meminfo_available("MemTotal: 1 kB\n"), None);
    }

    #[test]
    fn cgroup_limits_of_the_group_and_its_parents_count() {
        let files: HashMap<&str, &str> = [
            // v2: the job's parent holds the limit (8 GiB, 1 GiB used), the step has none.
            ("/sys/fs/cgroup/slurm/job_7/memory.max", "8589934592\n"),
            ("/sys/fs/cgroup/slurm/job_7/memory.current", "1073741824\n"),
            ("/sys/fs/cgroup/slurm/job_7/step_0/memory.max", "max\n"),
            ("/sys/fs/cgroup/slurm/job_7/step_0/memory.current", "5\n"),
            // v1, unlimited (2^63 rounded to a page) and limited (3 GiB, 2 GiB used).
            (
                "/sys/fs/cgroup/memory/a/memory.limit_in_bytes",
                "9223372036854771712\n",
            ),
            ("/sys/fs/cgroup/memory/a/memory.usage_in_bytes", "1000\n"),
            (
                "/sys/fs/cgroup/memory/b/memory.limit_in_bytes",
                "3221225472\n",
            ),
            (
                "/sys/fs/cgroup/memory/b/memory.usage_in_bytes",
                "2147483648\n",
            ),
        ]
        .into();
        let read = |p: &Path| files.get(p.to_str()?).map(|s| s.to_string());
        let gib = 1024.0 * 1024.0 * 1024.0;
        assert_eq!(
            cgroup_left("0::/slurm/job_7/step_0\n", read),
            Some(7.0 * gib)
        );
        assert_eq!(cgroup_left("4:memory:/a\n0::/\n", read), None);
        assert_eq!(cgroup_left("4:cpu,memory:/b\n", read), Some(gib));
        assert_eq!(
            cgroup_left("4:memory:/b\n0::/slurm/job_7/step_0\n", read),
            Some(gib)
        );
        assert_eq!(cgroup_left("4:cpu:/b\nnonsense\n", read), None);
    }

    #[test]
    fn ulimit_v_leaves_the_limit_less_what_is_mapped() {
        let status = "Name: hytled\nVmPeak: 9 kB\nVmSize:   204800 kB\n";
        let limited = "Limit Soft Hard Units\nMax address space         1073741824           unlimited            bytes\n";
        let open = "Max address space         unlimited            unlimited            bytes\n";
        assert_eq!(
            address_space_left(limited, status),
            Some(1073741824.0 - 204800.0 * 1024.0)
        );
        assert_eq!(address_space_left(open, status), None);
    }
}
