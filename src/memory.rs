//! How much memory a run may take, and the guard that turns an allocation that would exhaust
//! the machine into an input error naming the setting to change (instead of an abort in the
//! allocator).

use crate::{Error, Result};

/// Bytes in a GiB.
pub const GIB: f64 = 1024.0 * 1024.0 * 1024.0;

/// Share of the available memory one run may plan to hold.
pub const SHARE: f64 = 0.8;

/// Memory a run may use, bytes: the system's available memory (Linux: MemAvailable of
/// /proc/meminfo), or the environment's `HYTLED_MEMORY_LIMIT` (bytes) where that is smaller, for
/// shared machines; None when neither is known.
pub fn available() -> Option<f64> {
    let system = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| {
            let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
            let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kib * 1024.0)
        });
    let limit = std::env::var("HYTLED_MEMORY_LIMIT")
        .ok()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|v| *v > 0.0);
    match (system, limit) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// Refuses a plan that would hold `need` bytes when that is more than [`SHARE`] of the
/// available memory: the error says what would take the memory (`what`) and how to lower it
/// (`fix`).
pub fn check(need: f64, what: &str, fix: &str) -> Result<()> {
    match available() {
        Some(avail) if need > SHARE * avail => Err(Error::Input(format!(
            "{what} would take about {}, more than {:.0} % of the {} of memory available: {fix}",
            size(need),
            100.0 * SHARE,
            size(avail)
        ))),
        _ => Ok(()),
    }
}

/// A byte count for messages: "1.25 GiB", "3.4 MiB", "812 kiB" or "96 bytes".
pub fn size(bytes: f64) -> String {
    const KIB: f64 = 1024.0;
    const MIB: f64 = 1024.0 * 1024.0;
    if bytes >= GIB {
        format!("{:.2} GiB", bytes / GIB)
    } else if bytes >= MIB {
        format!("{:.1} MiB", bytes / MIB)
    } else if bytes >= KIB {
        format!("{:.0} kiB", bytes / KIB)
    } else {
        format!("{bytes:.0} bytes")
    }
}
