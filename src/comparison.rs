//! `hytled compare`: the same scene run with each discretization (FE, coupled, meshless), and
//! with `--modes` each steady-state solver (relaxation, static), in one table of what each
//! costs (wall time, force evaluations) and how close it comes to the scene's references.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::io::plot::{line_plot, Series};
use crate::io::vtu::VtuFormat;
use crate::report::Summary;
use crate::scene;
use crate::simulation;
use crate::{Error, InputKind, Result};

/// Methods `compare` knows, in the default order.
pub const METHODS: [&str; 3] = ["fe", "coupled", "meshless"];

/// Solver modes `compare --modes` knows (scene `solver.mode`).
pub const MODES: [&str; 3] = ["relaxation", "static", "dynamic"];

/// One method's run (in one solver mode): its summary, or the error that stopped it.
#[derive(Debug, Clone, Serialize)]
pub struct CompareRow {
    pub method: String,
    /// The solver mode asked for (`--modes`); None: the scene's own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mode: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub summary: Option<Summary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Peak resident memory of the process during the run (VmHWM, reset before each run on
    /// Linux), MiB.
    pub peak_memory_mib: Option<f64>,
    /// (time s, force N) of the compared reaction component, for the overlay plot.
    #[serde(skip)]
    pub reaction_history: Vec<(f64, f64)>,
}

/// Options of a comparison.
#[derive(Debug, Clone, Default)]
pub struct CompareOptions {
    /// Write each run's outputs under DIR/METHOD plus compare.csv, compare.md, reactions.svg.
    pub out: Option<PathBuf>,
    pub vtu_format: VtuFormat,
    /// Print a line per method to stderr.
    pub progress: bool,
    /// Run each method in each of these solver modes (`solver.mode`); empty: the scene's own.
    pub modes: Vec<String>,
}

impl CompareRow {
    /// The row's name: the method, with the mode when one was asked for ("fe static").
    pub fn label(&self) -> String {
        label(&self.method, self.mode.as_deref())
    }
}

fn label(method: &str, mode: Option<&str>) -> String {
    match mode {
        Some(m) => format!("{method} {m}"),
        None => method.to_string(),
    }
}

/// Parses a comma-separated method list ("fe,coupled,meshless").
pub fn parse_methods(list: &str) -> Result<Vec<String>> {
    parse_list(list, &METHODS, "method", "no method given")
}

/// Parses a comma-separated solver-mode list ("relaxation,static").
pub fn parse_modes(list: &str) -> Result<Vec<String>> {
    parse_list(list, &MODES, "solver mode", "--modes names no mode")
}

/// The names in `list` (each of `known`, repeats dropped), or an error naming the known ones.
fn parse_list(list: &str, known: &[&str], what: &str, empty: &str) -> Result<Vec<String>> {
    let mut out: Vec<String> = Vec::new();
    for m in list.split(',').map(str::trim).filter(|m| !m.is_empty()) {
        if !known.contains(&m) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "compare: unknown {what} '{m}'; use a comma-separated list of {}",
                    known.join(", ")
                ),
            ));
        }
        if !out.iter().any(|o| o == m) {
            out.push(m.to_string());
        }
    }
    if out.is_empty() {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "compare: {empty}; use a comma-separated list of {}",
                known.join(", ")
            ),
        ));
    }
    Ok(out)
}

/// Resets the peak resident set size (Linux: "5" to /proc/self/clear_refs).
pub fn reset_peak_memory() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Peak resident set size since the last reset, MiB (None where /proc is unavailable).
pub fn peak_memory_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// The reaction component the comparison plots: the first reference's reaction, else the z
/// component of the first boundary with a prescribed displacement, else of the first rigid
/// contact body (what drives the scene), else of the first boundary.
fn compared_reaction(s: &scene::Scene) -> Option<(String, usize)> {
    for r in s.references.values() {
        let parts: Vec<&str> = r.quantity.split('.').collect();
        if parts.len() == 3 && parts[0] == "reaction" {
            let k = match parts[2] {
                "x" => 0,
                "y" => 1,
                _ => 2,
            };
            return Some((parts[1].to_string(), k));
        }
    }
    s.boundaries
        .iter()
        .find(|(_, b)| b.displacement.is_some())
        .map(|(n, _)| n)
        .or_else(|| s.contact.keys().next())
        .or_else(|| s.boundaries.keys().next())
        .map(|n| (n.clone(), 2))
}

/// One finished run of a scene: its summary and the history of its compared reaction.
pub struct CaseRun {
    pub summary: Summary,
    /// (time s, force N) of the compared reaction component (see `compared_reaction`).
    pub reaction_history: Vec<(f64, f64)>,
}

/// Loads `scene_path` with `overrides`, prepares, runs and summarises it (outputs to `out`
/// when given). Returns the run or the error that stopped it, with the peak resident memory of
/// the run (MiB, Linux only).
pub fn run_case(
    scene_path: &Path,
    overrides: &[String],
    out: Option<&Path>,
    vtu_format: VtuFormat,
    progress_lines: Option<f64>,
) -> (Result<CaseRun>, Option<f64>) {
    let t0 = Instant::now();
    reset_peak_memory();
    let result = (|| -> Result<CaseRun> {
        let s = scene::load(scene_path, overrides)?;
        let mut prep = simulation::prepare(&s)?;
        let mut settings = simulation::settings(&s, false);
        settings.progress_lines = progress_lines;
        let out_run = simulation::solve(&mut prep, &settings)?;
        let summary = simulation::summarize(&s, &prep, &out_run, t0.elapsed().as_secs_f64());
        if let Some(dir) = out {
            simulation::write_outputs(dir, &s, &mut prep, &out_run, &summary, vtu_format)?;
        }
        let reaction_history = compared_reaction(&s)
            .and_then(|(name, k)| {
                let b = prep
                    .model
                    .reaction_names()
                    .iter()
                    .position(|b| *b == name)?;
                Some(
                    out_run
                        .history
                        .iter()
                        .filter_map(|h| Some((h.time, h.reactions.get(b)?[k])))
                        .collect(),
                )
            })
            .unwrap_or_default();
        Ok(CaseRun {
            summary,
            reaction_history,
        })
    })();
    (result, peak_memory_mib())
}

/// Runs `scene_path` once per method (the override `discretization.method=M` after
/// `overrides`), and per solver mode when `opts.modes` names some (`solver.mode=MODE` after
/// it). A run that fails is a row with its error.
pub fn run_compare(
    scene_path: &Path,
    overrides: &[String],
    methods: &[String],
    opts: &CompareOptions,
) -> Result<Vec<CompareRow>> {
    let modes: Vec<Option<&String>> = if opts.modes.is_empty() {
        vec![None]
    } else {
        opts.modes.iter().map(Some).collect()
    };
    let mut rows = Vec::new();
    for m in methods {
        for &mode in &modes {
            let label = label(m, mode.map(String::as_str));
            let t0 = Instant::now();
            if opts.progress {
                eprintln!("compare: {label} ...");
            }
            let mut o = overrides.to_vec();
            o.push(format!("discretization.method={m}"));
            o.extend(mode.map(|x| format!("solver.mode={x}")));
            let out_dir = opts.out.as_ref().map(|d| match mode {
                Some(x) => d.join(format!("{m}-{x}")),
                None => d.join(m),
            });
            // A method can take minutes: its time loop says how far it is every 10 s.
            let (result, peak) = run_case(
                scene_path,
                &o,
                out_dir.as_deref(),
                opts.vtu_format,
                opts.progress.then_some(10.0),
            );
            if opts.progress {
                eprintln!(
                    "compare: {label} {} in {:.1} s",
                    if result.is_ok() { "done" } else { "FAILED" },
                    t0.elapsed().as_secs_f64()
                );
            }
            if let Err(e @ Error::Interrupted { .. }) = result {
                return Err(e);
            }
            let (summary, error, reaction_history) = match result {
                Ok(run) => (Some(run.summary), None, run.reaction_history),
                Err(e) => (None, Some(e.to_string()), Vec::new()),
            };
            rows.push(CompareRow {
                method: m.clone(),
                mode: mode.cloned(),
                summary,
                error,
                peak_memory_mib: peak,
                reaction_history,
            });
        }
    }
    if let Some(dir) = &opts.out {
        write_outputs(dir, scene_path, &rows)?;
    }
    Ok(rows)
}

/// Table columns: header and the cell of each row.
fn columns(rows: &[CompareRow]) -> (Vec<String>, Vec<Vec<String>>) {
    let mut head: Vec<String> = [
        "method",
        "mode",
        "nodes",
        "points",
        "dt (s)",
        "steps",
        "force evaluations",
        "preprocess (s)",
        "solve (s)",
    ]
    .map(String::from)
    .to_vec();
    // Reaction, probe and reference names from the first successful run.
    let first = rows.iter().find_map(|r| r.summary.as_ref());
    let reactions: Vec<String> = first
        .map(|s| s.reactions.keys().cloned().collect())
        .unwrap_or_default();
    let probes: Vec<String> = first
        .map(|s| s.probes.keys().cloned().collect())
        .unwrap_or_default();
    let refs: Vec<String> = first
        .map(|s| s.reference.keys().cloned().collect())
        .unwrap_or_default();
    let comps = crate::report::reaction_columns(first, &reactions);
    head.extend(comps.iter().map(|(_, h)| h.clone()));
    head.extend(probes.iter().map(|p| format!("probe {p} (m)")));
    head.extend(refs.iter().map(|r| format!("error {r} (%)")));
    head.extend(["energy balance error (%)", "peak memory (MiB)", "status"].map(String::from));
    let body =
        rows.iter()
            .map(|r| {
                let mut c = vec![r.method.clone()];
                c.push(
                    r.summary
                        .as_ref()
                        .map(|s| s.mode.clone())
                        .or_else(|| r.mode.clone())
                        .unwrap_or_else(|| "-".into()),
                );
                match &r.summary {
                    Some(s) => {
                        c.push(s.nodes.to_string());
                        c.push(s.integration_points.to_string());
                        c.push(format!("{:.4e}", s.dt));
                        c.push(s.steps.to_string());
                        c.push(s.force_evaluations.to_string());
                        c.push(format!("{:.2}", s.wall_seconds.preprocess));
                        c.push(format!("{:.2}", s.wall_seconds.solve));
                        for (name, &(k, _)) in reactions.iter().zip(&comps) {
                            c.push(
                                s.reactions
                                    .get(name)
                                    .map_or("-".into(), |v| format!("{:.5e}", v[k])),
                            );
                        }
                        for name in &probes {
                            c.push(s.probes.get(name).map_or("-".into(), |p| {
                                let d = p.displacement;
                                format!("({:.4e}, {:.4e}, {:.4e})", d[0], d[1], d[2])
                            }));
                        }
                        for name in &refs {
                            c.push(s.reference.get(name).map_or("-".into(), |x| {
                                format!("{:.3}", 100.0 * x.relative_error)
                            }));
                        }
                        // A steady state has no energy balance; its equilibrium residual
                        // stands in for it.
                        c.push(match (s.energy.balance_error, s.equilibrium_residual) {
                            (Some(e), _) => format!("{:.3}", 100.0 * e),
                            (None, Some(r)) => format!("n/a ({}; residual {r:.1e})", s.mode),
                            (None, None) => format!("n/a ({})", s.mode),
                        });
                    }
                    None => {
                        let n = 7 + reactions.len() + probes.len() + refs.len() + 1;
                        c.extend(std::iter::repeat_n("-".to_string(), n));
                    }
                }
                c.push(
                    r.peak_memory_mib
                        .map_or("n/a".into(), |m| format!("{m:.0}")),
                );
                c.push(crate::report::row_status(
                    r.error.as_ref(),
                    r.summary.as_ref(),
                ));
                c
            })
            .collect();
    (head, body)
}

/// The comparison as a Markdown table (units in the headers, SI).
pub fn table(rows: &[CompareRow]) -> String {
    let (head, body) = columns(rows);
    let mut s = format!("| {} |\n|{}\n", head.join(" | "), "---|".repeat(head.len()));
    for r in body {
        s.push_str(&format!("| {} |\n", r.join(" | ")));
    }
    crate::error::tidy_exponents(&s)
}

/// compare.csv, compare.md and reactions.svg (the compared reaction of every method against time).
pub fn write_outputs(dir: &Path, scene_path: &Path, rows: &[CompareRow]) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let (head, body) = columns(rows);
    let quote = |s: &str| {
        if s.contains([',', '"', '\n']) {
            format!("\"{}\"", s.replace('"', "\"\""))
        } else {
            s.to_string()
        }
    };
    let mut csv = head.iter().map(|h| quote(h)).collect::<Vec<_>>().join(",") + "\n";
    for r in &body {
        csv += &(r.iter().map(|c| quote(c)).collect::<Vec<_>>().join(",") + "\n");
    }
    let p = dir.join("compare.csv");
    std::fs::write(&p, csv).map_err(|e| Error::io(&p, e))?;
    let p = dir.join("compare.md");
    let md = format!(
        "# hytled compare {}\n\nSI units (m, N, s).\n\n{}",
        scene_path.display(),
        table(rows)
    );
    std::fs::write(&p, md).map_err(|e| Error::io(&p, e))?;
    let labels: Vec<String> = rows.iter().map(CompareRow::label).collect();
    let modes: std::collections::BTreeSet<&str> = rows
        .iter()
        .filter_map(|r| r.summary.as_ref())
        .map(|s| s.mode.as_str())
        .collect();
    // A static solve's history runs over the load fraction, a relaxation's over pseudo-time:
    // with both in one plot each run's abscissa is scaled to end at 1.
    let mixed = modes.len() > 1;
    let series: Vec<Series> = rows
        .iter()
        .zip(&labels)
        .filter(|(r, _)| !r.reaction_history.is_empty())
        .map(|(r, name)| {
            let end = r.reaction_history.last().map_or(1.0, |p| p.0);
            let scale = if mixed && end > 0.0 { 1.0 / end } else { 1.0 };
            Series {
                name,
                points: r
                    .reaction_history
                    .iter()
                    .map(|&(t, f)| (t * scale, f))
                    .collect(),
            }
        })
        .collect();
    if !series.is_empty() {
        let abscissa = if mixed {
            "fraction of the run (static: load; relaxation: pseudo-time)"
        } else if modes.contains("relaxation") {
            "pseudo-time of the relaxation (s)"
        } else if modes.contains("static") {
            "load fraction"
        } else {
            "time (s)"
        };
        line_plot(
            &dir.join("reactions.svg"),
            "Reaction force by method",
            abscissa,
            "force (N)",
            &series,
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_lists() {
        assert_eq!(
            parse_methods("fe, meshless").unwrap(),
            vec!["fe", "meshless"]
        );
        let e = parse_methods("fe,hybrid").unwrap_err().to_string();
        assert!(
            e.contains("unknown method 'hybrid'") && e.contains("coupled"),
            "{e}"
        );
        assert!(parse_methods(" , ").is_err());
    }

    #[test]
    fn mode_lists() {
        assert_eq!(
            parse_modes("relaxation, static,relaxation").unwrap(),
            vec!["relaxation", "static"]
        );
        let e = parse_modes("implicit").unwrap_err().to_string();
        assert!(
            e.contains("unknown solver mode 'implicit'") && e.contains("relaxation, static"),
            "{e}"
        );
        assert!(parse_modes(",").is_err());
    }
}
