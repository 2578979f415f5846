//! The output folder of one run (`--out DIR`): checked and claimed before anything is computed,
//! and written so that it holds exactly one run, whatever stops the run and whoever else writes
//! into the same folder.
//!
//! - **One run at a time.** A run holds an exclusive lock on `.hytled-lock` (an advisory file
//!   lock the operating system releases when the process ends, killed or not) from the claim to
//!   the end; a second run into a busy folder is refused at once, naming the process that holds
//!   it.
//! - **Own files only.** hytled records the files it writes in a manifest (`.hytled-manifest`,
//!   one name per line); a new run removes only those and its own hidden `.hytled-*` files, and
//!   refuses a folder that holds files of anyone else.
//! - **Never a stale result.** The claim marks the earlier summary `"status": "running"` before
//!   anything is removed; summary.json and the manifest are replaced by rename (never seen half
//!   written), and every name is in the manifest before its file appears. The run's files are
//!   written into a staging folder (`.hytled-partial`) and moved in at the end, summary.json
//!   last; a failed or interrupted run's summary says `"failed"` with the message, beside the
//!   frames it wrote before it stopped. Whatever a kill, a power cut or a full disk leaves is
//!   the next run's to remove.

use std::fs::File;
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

use crate::{Error, InputKind, Result};

const MANIFEST: &str = ".hytled-manifest";
const STAGING: &str = ".hytled-partial";
const LOCK: &str = ".hytled-lock";
/// Every name hytled gives its own bookkeeping starts with this.
const OWN_PREFIX: &str = ".hytled-";
const SUMMARY: &str = "summary.json";

/// An output folder claimed by one run; the claim (the lock) ends when this is dropped.
#[derive(Debug)]
pub struct OutDir {
    dir: PathBuf,
    _lock: File,
}

/// The folders claimed and not yet committed or failed: an out-of-memory exit marks them
/// failed ([`crate::memory::on_out_of_memory`]), so none is left saying "running".
static OPEN: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

fn out_of_memory(message: &str) {
    let dirs = match OPEN.try_lock() {
        Ok(d) => d.clone(),
        Err(_) => return,
    };
    let e = Error::input(InputKind::Value, message.to_string());
    for d in dirs {
        fail_at(&d, &e);
    }
}

impl Drop for OutDir {
    fn drop(&mut self) {
        if let Ok(mut open) = OPEN.lock() {
            open.retain(|d| d != &self.dir);
        }
    }
}

fn io(path: &Path, e: std::io::Error) -> Error {
    Error::io(path, e)
}

/// The names the manifest of `dir` lists (empty without one).
fn manifest(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join(MANIFEST))
        .map(|s| {
            s.lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.contains('/') && !l.contains('\\') && *l != "..")
                .map(String::from)
                .collect()
        })
        .unwrap_or_default()
}

/// Writes `dir/name` whole or not at all: into a hidden temporary file, then renamed over it.
fn write_atomic(dir: &Path, name: &str, text: &str) -> Result<()> {
    let hidden = name.strip_prefix(OWN_PREFIX).unwrap_or(name);
    let (tmp, path) = (
        dir.join(format!("{OWN_PREFIX}{hidden}.tmp")),
        dir.join(name),
    );
    let write = || -> std::io::Result<()> {
        let mut f = File::create(&tmp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(&path, e));
    }
    std::fs::rename(&tmp, &path).map_err(|e| io(&path, e))
}

fn write_manifest(dir: &Path, names: &[String]) -> Result<()> {
    write_atomic(dir, MANIFEST, &(names.join("\n") + "\n"))
}

fn write_status(dir: &Path, status: &str, error: Option<&Error>) -> Result<()> {
    let mut v = serde_json::json!({ "status": status, "pid": std::process::id() });
    if let (Some(e), Some(o)) = (error, v.as_object_mut()) {
        if let serde_json::Value::Object(fields) = e.to_json() {
            o.extend(fields);
        }
    }
    let text = serde_json::to_string_pretty(&v).unwrap_or_default();
    write_atomic(dir, SUMMARY, &text)
}

fn unix_seconds() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// Takes the folder's lock, or says which run holds it.
fn lock(dir: &Path) -> Result<File> {
    let path = dir.join(LOCK);
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| io(&path, e))?;
    match f.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut text = String::new();
            let _ = f.read_to_string(&mut text);
            let mut it = text.split_whitespace();
            let holder = match (
                it.next().and_then(|p| p.parse::<u32>().ok()),
                it.next().and_then(|t| t.parse::<u64>().ok()),
            ) {
                (Some(pid), Some(t)) => format!(
                    "process {pid}, running for {} s",
                    unix_seconds().saturating_sub(t)
                ),
                _ => "a process that is starting".into(),
            };
            return Err(Error::input(
                InputKind::Value,
                format!(
                "--out {}: another hytled run ({holder}) is writing into this folder; wait for \
                 it to end or give another folder",
                dir.display()
            ),
            ));
        }
        Err(std::fs::TryLockError::Error(e)) => return Err(io(&path, e)),
    }
    let stamp = format!("{} {}\n", std::process::id(), unix_seconds());
    let write = |f: &mut File| -> std::io::Result<()> {
        f.set_len(0)?;
        f.rewind()?;
        f.write_all(stamp.as_bytes())
    };
    write(&mut f).map_err(|e| io(&path, e))?;
    Ok(f)
}

impl OutDir {
    /// Checks `dir` and claims it for a new run: it must be a folder (created if missing) that
    /// no other run is writing into and that holds nothing but an earlier hytled run's files;
    /// summary.json is marked `"status": "running"` (which also proves the folder writable),
    /// then those files are removed.
    pub fn open(dir: &Path) -> Result<Self> {
        if dir.exists() && !dir.is_dir() {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "--out {}: exists and is not a folder; give a folder path",
                    dir.display()
                ),
            ));
        }
        std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
        let lock = lock(dir)?;
        let own = manifest(dir);
        // A manifest, even an empty one, says hytled writes here: its summary.json is its own
        // (folders of hytled 0.x could be killed between writing the two).
        let has_manifest = dir.join(MANIFEST).exists();
        let mut foreign = Vec::new();
        let mut hidden = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(|e| io(dir, e))? {
            let entry = entry.map_err(|e| io(dir, e))?;
            let name = entry.file_name().to_string_lossy().to_string();
            if name.starts_with(OWN_PREFIX) {
                hidden.push(name);
            } else if !own.contains(&name) && !(has_manifest && name == SUMMARY) {
                foreign.push(name);
            }
        }
        if !foreign.is_empty() {
            foreign.sort();
            let shown: Vec<&str> = foreign.iter().take(5).map(String::as_str).collect();
            return Err(Error::input(
                InputKind::Value,
                format!(
                "--out {}: the folder holds {} file(s) hytled did not write ({}{}); give an empty \
                 or new folder, or one an earlier hytled run wrote",
                dir.display(),
                foreign.len(),
                shown.join(", "),
                if foreign.len() > shown.len() {
                    ", ..."
                } else {
                    ""
                }
            ),
            ));
        }
        // The order makes every moment safe to be killed at: summary.json is in the manifest
        // before it is written, and says "running" before any earlier file goes.
        let mut listed = own.clone();
        if !listed.iter().any(|n| n == SUMMARY) {
            listed.push(SUMMARY.into());
            write_manifest(dir, &listed)?;
        }
        write_status(dir, "running", None)?;
        for name in hidden
            .iter()
            .filter(|n| ![LOCK, MANIFEST].contains(&n.as_str()))
        {
            let path = dir.join(name);
            let removed = if path.is_dir() {
                std::fs::remove_dir_all(&path)
            } else {
                std::fs::remove_file(&path)
            };
            match removed {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(io(&path, e)),
                _ => {}
            }
        }
        for name in own.iter().filter(|n| n.as_str() != SUMMARY) {
            let path = dir.join(name);
            if path.is_file() {
                std::fs::remove_file(&path).map_err(|e| io(&path, e))?;
            }
        }
        write_manifest(dir, &[SUMMARY.to_string()])?;
        crate::memory::on_out_of_memory(out_of_memory);
        if let Ok(mut open) = OPEN.lock() {
            open.push(dir.to_path_buf());
        }
        Ok(OutDir {
            dir: dir.to_path_buf(),
            _lock: lock,
        })
    }

    /// A fresh, empty staging folder inside the output folder to write the run's files into.
    pub fn staging(&self) -> Result<PathBuf> {
        let s = self.dir.join(STAGING);
        if s.exists() {
            std::fs::remove_dir_all(&s).map_err(|e| io(&s, e))?;
        }
        std::fs::create_dir_all(&s).map_err(|e| io(&s, e))?;
        Ok(s)
    }

    /// Moves the staged files into the folder (summary.json last) and records them in the
    /// manifest.
    pub fn commit(&self) -> Result<()> {
        let s = self.dir.join(STAGING);
        let mut names: Vec<String> = Vec::new();
        for entry in std::fs::read_dir(&s).map_err(|e| io(&s, e))? {
            let entry = entry.map_err(|e| io(&s, e))?;
            names.push(entry.file_name().to_string_lossy().to_string());
        }
        names.sort();
        // Every name is in the manifest before its file appears, so a kill between the two
        // never leaves a file the next run would call foreign.
        let mut all = names.clone();
        if !all.iter().any(|n| n == SUMMARY) {
            all.push(SUMMARY.into());
        }
        write_manifest(&self.dir, &all)?;
        names.sort_by_key(|n| n == SUMMARY);
        for n in &names {
            let (from, to) = (s.join(n), self.dir.join(n));
            std::fs::rename(&from, &to).map_err(|e| io(&to, e))?;
        }
        std::fs::remove_dir_all(&s).map_err(|e| io(&s, e))
    }

    /// Records a failed run: the files it staged (frames written before the failure) are moved
    /// in and summary.json carries `"status": "failed"` with the error. Best effort (the run's
    /// own error is what matters).
    pub fn fail(&self, e: &Error) {
        fail_at(&self.dir, e);
    }
}

/// [`OutDir::fail`] on the folder `dir`.
fn fail_at(dir: &Path, e: &Error) {
    {
        let s = dir.join(STAGING);
        // What the run wrote before it failed (the frames up to a divergence and their .pvd)
        // is kept for debugging; a staged summary would claim a result, so it is dropped.
        let mut kept: Vec<String> = std::fs::read_dir(&s)
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().to_string())
                    .filter(|n| n != SUMMARY)
                    .collect()
            })
            .unwrap_or_default();
        kept.sort();
        let mut all = kept.clone();
        all.push(SUMMARY.into());
        if write_manifest(dir, &all).is_ok() {
            for n in &kept {
                let _ = std::fs::rename(s.join(n), dir.join(n));
            }
        }
        let _ = std::fs::remove_dir_all(&s);
        let _ = write_status(dir, "failed", Some(e));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fresh(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("hytled-outdir-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn a_rerun_replaces_only_its_own_files() {
        let d = fresh("rerun");
        let o = OutDir::open(&d).unwrap();
        let s = o.staging().unwrap();
        for f in ["a_0000.vtu", "a_0001.vtu", "a.pvd", "summary.json"] {
            std::fs::write(s.join(f), "x").unwrap();
        }
        o.commit().unwrap();
        drop(o);
        assert!(d.join("a_0001.vtu").exists() && !d.join(STAGING).exists());
        // A killed run's staging folder is no obstacle and is removed.
        std::fs::create_dir_all(d.join(STAGING)).unwrap();
        std::fs::write(d.join(STAGING).join("half.vtu"), "x").unwrap();
        let o = OutDir::open(&d).unwrap();
        assert!(!d.join("a_0001.vtu").exists(), "old frames removed");
        assert!(!d.join(STAGING).exists());
        let text = std::fs::read_to_string(d.join("summary.json")).unwrap();
        assert!(text.contains("running"), "{text}");
        let s = o.staging().unwrap();
        std::fs::write(s.join("a_0000.vtu"), "y").unwrap();
        o.commit().unwrap();
        drop(o);
        let mut left: Vec<String> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        left.sort();
        assert_eq!(left, [LOCK, MANIFEST, "a_0000.vtu", "summary.json"]);
        // A failed run leaves its status and message, and the frames it wrote before failing
        // (not the earlier run's, and not a staged summary).
        let o = OutDir::open(&d).unwrap();
        assert!(!d.join("a_0000.vtu").exists());
        let s = o.staging().unwrap();
        for f in ["b_0000.vtu", "b.pvd", "summary.json"] {
            std::fs::write(s.join(f), "z").unwrap();
        }
        o.fail(&Error::Unstable("diverged at step 3".into()));
        drop(o);
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(v["status"], "failed");
        assert_eq!(v["exit_code"], 3);
        assert!(d.join("b_0000.vtu").exists() && d.join("b.pvd").exists());
        assert!(!d.join(STAGING).exists());
        // ... and they are its own: the next run removes them.
        OutDir::open(&d).unwrap();
        assert!(!d.join("b_0000.vtu").exists() && !d.join("b.pvd").exists());
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_busy_folder_is_refused_naming_the_run_that_holds_it() {
        let d = fresh("busy");
        let first = OutDir::open(&d).unwrap();
        let s = first.staging().unwrap();
        std::fs::write(s.join("a_0000.vtu"), "x").unwrap();
        let e = OutDir::open(&d).unwrap_err().to_string();
        assert!(
            e.contains("another hytled run")
                && e.contains(&format!("process {}", std::process::id())),
            "{e}"
        );
        assert!(
            s.join("a_0000.vtu").exists(),
            "the busy run's files untouched"
        );
        drop(first);
        // Released with the claim (and by the system when a process dies).
        OutDir::open(&d).unwrap();
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn whatever_a_kill_leaves_is_the_next_runs_to_remove() {
        let d = fresh("leftover");
        std::fs::create_dir_all(d.join(STAGING)).unwrap();
        // A kill between writing a temporary file and its rename, and an empty manifest beside
        // a "running" summary (what a kill in the claim of hytled before the atomic writes
        // left, refused by every later run), and a half-staged run.
        std::fs::write(d.join(".hytled-summary.json.tmp"), "{\"sta").unwrap();
        std::fs::write(d.join(STAGING).join("b_0003.vtu"), "x").unwrap();
        std::fs::write(d.join(MANIFEST), "").unwrap();
        std::fs::write(d.join(SUMMARY), "{\"status\": \"running\"}").unwrap();
        let o = OutDir::open(&d).unwrap();
        let mut left: Vec<String> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        left.sort();
        assert_eq!(left, [LOCK, MANIFEST, SUMMARY]);
        assert_eq!(manifest(&d), [SUMMARY]);
        drop(o);
        // Without a manifest a summary.json is someone else's.
        std::fs::remove_file(d.join(MANIFEST)).unwrap();
        let e = OutDir::open(&d).unwrap_err().to_string();
        assert!(e.contains("summary.json"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn foreign_files_and_file_paths_are_refused() {
        let d = fresh("foreign");
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("thesis.tex"), "mine").unwrap();
        let e = OutDir::open(&d).unwrap_err().to_string();
        assert!(
            e.contains("thesis.tex") && e.contains("did not write"),
            "{e}"
        );
        assert!(d.join("thesis.tex").exists(), "nothing removed");
        let f = d.join("thesis.tex");
        let e = OutDir::open(&f).unwrap_err().to_string();
        assert!(e.contains("not a folder"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }
}
