//! Shared helpers for the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use hytled::report::Summary;
use hytled::simulation::{run_scene, RunOptions};

/// Path of a file in the crate.
pub fn path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Runs a committed case with `--set` style overrides.
pub fn run_case(case: &str, overrides: &[&str]) -> Summary {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let scene = hytled::scene::load(&path(case), &o).unwrap_or_else(|e| panic!("{case}: {e}"));
    run_scene(&scene, &RunOptions::default())
        .unwrap_or_else(|e| panic!("{case} {overrides:?}: {e}"))
}

/// Relative error of a reference comparison in a summary.
pub fn rel_err(s: &Summary, name: &str) -> f64 {
    s.reference
        .get(name)
        .unwrap_or_else(|| panic!("no reference '{name}'"))
        .relative_error
}
