//! The output folder of one run (`--out DIR`): checked before anything is computed, and written
//! so that it holds exactly one run. hytled records the files it writes in a manifest
//! (`.hytled-manifest`, one name per line); a new run removes only those, refuses a folder that
//! holds files of anyone else, writes its files into a staging folder (`.hytled-partial`) and
//! moves them in at the end. While it runs, and after it fails, `summary.json` says so
//! (`"status": "running"` / `"failed"` with the message), so no earlier result is left looking
//! current; the frames a failed run wrote before it failed are kept for debugging. A run killed while writing leaves the staging folder, which the next run removes;
//! the window in which a kill can leave a mix is the renames at the end.

use std::path::{Path, PathBuf};

use crate::{Error, Result};

const MANIFEST: &str = ".hytled-manifest";
const STAGING: &str = ".hytled-partial";
const SUMMARY: &str = "summary.json";

/// An output folder opened for one run.
#[derive(Debug)]
pub struct OutDir {
    dir: PathBuf,
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

fn write_manifest(dir: &Path, names: &[String]) -> Result<()> {
    let path = dir.join(MANIFEST);
    std::fs::write(&path, names.join("\n") + "\n").map_err(|e| io(&path, e))
}

fn write_status(dir: &Path, status: &str, error: Option<&Error>) -> Result<()> {
    let mut v = serde_json::json!({ "status": status });
    if let Some(e) = error {
        v["error"] = e.kind().into();
        v["exit_code"] = e.exit_code().into();
        v["message"] = e.to_string().into();
    }
    let path = dir.join(SUMMARY);
    let text = serde_json::to_string_pretty(&v).unwrap_or_default();
    std::fs::write(&path, text).map_err(|e| io(&path, e))
}

impl OutDir {
    /// Checks `dir` and claims it for a new run: it must be a folder (created if missing) that
    /// holds nothing but an earlier hytled run's files; those are removed, and `summary.json`
    /// is written with `"status": "running"` (which also proves the folder writable).
    pub fn open(dir: &Path) -> Result<Self> {
        if dir.exists() && !dir.is_dir() {
            return Err(Error::Input(format!(
                "--out {}: exists and is not a folder; give a folder path",
                dir.display()
            )));
        }
        std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
        let own = manifest(dir);
        let mut foreign = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(|e| io(dir, e))? {
            let entry = entry.map_err(|e| io(dir, e))?;
            let name = entry.file_name().to_string_lossy().to_string();
            if name != MANIFEST && name != STAGING && !own.contains(&name) {
                foreign.push(name);
            }
        }
        if !foreign.is_empty() {
            foreign.sort();
            let shown: Vec<&str> = foreign.iter().take(5).map(String::as_str).collect();
            return Err(Error::Input(format!(
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
            )));
        }
        let staging = dir.join(STAGING);
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| io(&staging, e))?;
        }
        for name in &own {
            let path = dir.join(name);
            if path.is_file() {
                std::fs::remove_file(&path).map_err(|e| io(&path, e))?;
            }
        }
        write_status(dir, "running", None)?;
        write_manifest(dir, &[SUMMARY.to_string()])?;
        Ok(OutDir {
            dir: dir.to_path_buf(),
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
        let s = self.dir.join(STAGING);
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
        if write_manifest(&self.dir, &all).is_ok() {
            for n in &kept {
                let _ = std::fs::rename(s.join(n), self.dir.join(n));
            }
        }
        let _ = std::fs::remove_dir_all(&s);
        let _ = write_status(&self.dir, "failed", Some(e));
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
        let mut left: Vec<String> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        left.sort();
        assert_eq!(left, [MANIFEST, "a_0000.vtu", "summary.json"]);
        // A failed run leaves its status and message, and the frames it wrote before failing
        // (not the earlier run's, and not a staged summary).
        let o = OutDir::open(&d).unwrap();
        assert!(!d.join("a_0000.vtu").exists());
        let s = o.staging().unwrap();
        for f in ["b_0000.vtu", "b.pvd", "summary.json"] {
            std::fs::write(s.join(f), "z").unwrap();
        }
        o.fail(&Error::Unstable("diverged at step 3".into()));
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
