//! The runs of a sweep as units of work that survive a stop: each has a stable id (a hash of
//! its overrides), its record and summary are on disk before its worker takes the next, and a
//! resumed sweep reruns only what is missing or failed. The same units serve `hytled sweep
//! --jobs N` (threads here) and the Python package's `hytled.sweep` (any executor).
//!
//! Layout under the sweep's `--out DIR`:
//! - `runs/<id>/row.json`: the row ([`SweepRow`]: values, overrides, summary or error, peak
//!   memory), written last and by rename, so a row file is always whole;
//! - `runs/<id>/summary.json`: the run's summary (with `--keep-outputs`, all its outputs).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::{assignments, combinations, SweepOptions, SweepRow, Vary};
use crate::comparison::run_case;
use crate::report::Summary;
use crate::{Error, InputKind, Result};

/// The record of a finished run, in its folder.
pub const ROW_FILE: &str = "row.json";

/// One run of a sweep, before it runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Planned {
    /// 1-based position in the cartesian product (the last key varying fastest).
    pub run: usize,
    /// [`run_id`] of `overrides`.
    pub id: String,
    /// The varied keys and this run's values.
    pub values: BTreeMap<String, String>,
    /// Every override of the run: the sweep's fixed ones, then the combination's (presets
    /// expanded).
    pub overrides: Vec<String>,
}

/// The stable id of a run: the first 16 hex digits of the SHA-256 of its overrides, one per
/// line (`"\n".join(overrides)` in Python's hashlib gives the same).
pub fn run_id(overrides: &[String]) -> String {
    let digest = Sha256::digest(overrides.join("\n").as_bytes());
    digest[..8].iter().map(|b| format!("{b:02x}")).collect()
}

/// Every run of the sweep over `varies` (presets already a dimension, as
/// [`super::dimensions`] gives them), in order.
pub fn plan(
    overrides: &[String],
    varies: &[Vary],
    presets: &BTreeMap<String, Vec<String>>,
) -> Vec<Planned> {
    combinations(varies)
        .into_iter()
        .enumerate()
        .map(|(k, combo)| {
            let mut o = overrides.to_vec();
            o.extend(assignments(&combo, presets));
            Planned {
                run: k + 1,
                id: run_id(&o),
                values: combo.into_iter().collect(),
                overrides: o,
            }
        })
        .collect()
}

/// The folder of run `id` under the sweep's output folder.
pub fn run_dir(out: &Path, id: &str) -> PathBuf {
    out.join("runs").join(id)
}

/// The row a finished run left in `out`: `None` where there is none, it does not parse, it
/// belongs to other overrides, or the run failed (a resumed sweep runs those again).
pub fn finished(out: &Path, p: &Planned) -> Option<SweepRow> {
    let text = std::fs::read_to_string(run_dir(out, &p.id).join(ROW_FILE)).ok()?;
    let mut row: SweepRow = serde_json::from_str(&text).ok()?;
    if row.error.is_some() || row.summary.is_none() || row.overrides != p.overrides {
        return None;
    }
    row.run = p.run;
    Some(row)
}

/// Runs `p` (`opts.repeat` times, the fastest kept) and, with `opts.out`, leaves its summary
/// and row in its folder before returning. A failed run is a row with its error; only an
/// interrupt (Ctrl-C) or a folder that cannot be written is an `Err`. `measure_memory`: the
/// peak resident memory is the process's, so it is measured only where runs do not share
/// the process ([`SweepRow::peak_memory_mib`] is `None` otherwise).
pub fn execute(
    scene_path: &Path,
    p: &Planned,
    opts: &SweepOptions,
    measure_memory: bool,
) -> Result<SweepRow> {
    let dir = opts.out.as_ref().map(|o| run_dir(o, &p.id));
    if let Some(d) = &dir {
        // A rerun of a failed run: its old row goes first, so the folder holds only what the
        // run writes (and no row says "failed" while it runs again).
        match std::fs::remove_file(d.join(ROW_FILE)) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(Error::io(d, e)),
            _ => {}
        }
    }
    let outputs = dir.as_deref().filter(|_| opts.keep_outputs);
    let mut best: Option<Summary> = None;
    let mut error = None;
    let mut peak = None;
    for r in 0..opts.repeat.max(1) {
        let (result, m) = run_case(
            scene_path,
            &p.overrides,
            outputs.filter(|_| r == 0),
            opts.vtu_format,
            None,
        );
        if measure_memory {
            peak = match (peak, m) {
                (Some(a), Some(b)) => Some(f64::max(a, b)),
                (a, b) => a.or(b),
            };
        }
        match result {
            Ok(run) => {
                let faster = best
                    .as_ref()
                    .is_none_or(|b| run.summary.wall_seconds.total < b.wall_seconds.total);
                if faster {
                    best = Some(run.summary);
                }
            }
            Err(e @ Error::Interrupted { .. }) => return Err(e),
            Err(e) => {
                error = Some(e.to_string());
                break;
            }
        }
    }
    let row = SweepRow {
        run: p.run,
        id: p.id.clone(),
        values: p.values.clone(),
        overrides: p.overrides.clone(),
        summary: if error.is_none() { best } else { None },
        error,
        peak_memory_mib: peak,
        repeats: opts.repeat.max(1),
        pareto: false,
    };
    if let Some(d) = &dir {
        std::fs::create_dir_all(d).map_err(|e| Error::io(d, e))?;
        if outputs.is_none() {
            if let Some(s) = &row.summary {
                write_atomic(&d.join("summary.json"), &to_json(s)?)?;
            }
        }
        write_atomic(&d.join(ROW_FILE), &to_json(&row)?)?;
    }
    Ok(row)
}

/// [`execute`] on a pool of `threads` threads of its own (`None`: the current pool), for a
/// worker that runs one run at a time beside others on the same machine.
pub fn execute_on(
    scene_path: &Path,
    p: &Planned,
    opts: &SweepOptions,
    threads: Option<usize>,
    measure_memory: bool,
) -> Result<SweepRow> {
    match threads {
        None => execute(scene_path, p, opts, measure_memory),
        Some(t) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(t.max(1))
                .build()
                .map_err(|e| {
                    Error::input(
                        InputKind::Value,
                        format!("sweep: cannot start {t} threads: {e}"),
                    )
                })?;
            pool.install(|| execute(scene_path, p, opts, measure_memory))
        }
    }
}

fn to_json<T: Serialize>(v: &T) -> Result<String> {
    serde_json::to_string_pretty(v)
        .map_err(|e| Error::input(InputKind::Value, format!("cannot serialise the sweep: {e}")))
}

/// Writes `path` whole or not at all ([`crate::io::vtu::write_atomically`]: a temporary file
/// beside it, renamed over it), synced first, so a sweep stopped at any moment leaves each
/// file either as it was or complete.
pub fn write_atomic(path: &Path, text: &str) -> Result<()> {
    use std::io::Write;
    crate::io::vtu::write_atomically(path, |w| {
        w.write_all(text.as_bytes())?;
        w.flush()?;
        w.get_ref().sync_all()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The id depends on the overrides and their order only, and is the SHA-256 of the lines
    /// (checked against a digest computed independently: `printf 'a=1\nb=2' | sha256sum`).
    #[test]
    fn run_ids_are_the_sha256_of_the_overrides() {
        let o = vec!["a=1".to_string(), "b=2".to_string()];
        assert_eq!(run_id(&o), "55c420c0f44ea4c6");
        assert_ne!(run_id(&o), run_id(&["b=2".into(), "a=1".into()]));
        assert_eq!(run_id(&o).len(), 16);
    }
}
