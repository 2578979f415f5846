//! `hytled sweep`: the cartesian product of varied scene values, one run each, and what each
//! run cost against how close it came to the scene's references (the speed/accuracy trade).
//!
//! Any `--set` path can be varied. A run that fails (invalid value, unstable step, inverted
//! element, singular support) is a row with its error message; the sweep goes on. Each run
//! is a unit of work with a stable id ([`runs`]): on disk before the next starts, resumable,
//! run N at a time (`--jobs`).

pub mod runs;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::io::plot::{log_log_plot, Series};
use crate::io::vtu::VtuFormat;
use crate::report::Summary;
use crate::{Error, InputKind, Result};

/// One varied scene key and its values (the text of `--set KEY=VALUE` values).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Vary {
    pub key: String,
    pub values: Vec<String>,
}

/// Parses `key.path=v1,v2,...`. Commas inside brackets or quotes belong to a value, so
/// `geometry.semi_axes=[1,2,3],[2,3,4]` gives two arrays.
pub fn parse_vary(text: &str) -> Result<Vary> {
    let bad = |why: &str| {
        Error::input(InputKind::Value, format!(
            "--vary '{text}': {why}; write --vary key.path=v1,v2,... (e.g. --vary discretization.divisions=[4,2,8],[6,3,12])"
        ))
    };
    let (key, list) = text.split_once('=').ok_or_else(|| bad("no '='"))?;
    let key = key.trim();
    if key.is_empty() {
        return Err(bad("no key before '='"));
    }
    let mut values = Vec::new();
    let (mut depth, mut quote, mut cur) = (0i32, None::<char>, String::new());
    for c in list.chars() {
        match (c, quote) {
            ('"' | '\'', None) => quote = Some(c),
            (q, Some(open)) if q == open => quote = None,
            ('[' | '{', None) => depth += 1,
            (']' | '}', None) => depth -= 1,
            (',', None) if depth == 0 => {
                values.push(std::mem::take(&mut cur));
                continue;
            }
            _ => {}
        }
        cur.push(c);
    }
    if depth != 0 || quote.is_some() {
        return Err(bad("unbalanced brackets or quotes"));
    }
    values.push(cur);
    let values: Vec<String> = values.into_iter().map(|v| v.trim().to_string()).collect();
    if values.iter().any(String::is_empty) {
        return Err(bad("an empty value"));
    }
    Ok(Vary {
        key: key.to_string(),
        values,
    })
}

/// The pseudo-key of named groups of overrides (`--preset NAME=key=v;key=v`): one varied
/// dimension whose values are the preset names.
pub const PRESET: &str = "preset";

/// The varied dimensions of a sweep: `preset` first (when presets are given), then `varies`.
pub fn dimensions(varies: &[Vary], presets: &BTreeMap<String, Vec<String>>) -> Vec<Vary> {
    let mut all = Vec::new();
    if !presets.is_empty() {
        all.push(Vary {
            key: PRESET.into(),
            values: presets.keys().cloned().collect(),
        });
    }
    all.extend(varies.iter().cloned());
    all
}

/// Parses `NAME=key.path=v;key.path=v` into the preset's name and its overrides.
pub fn parse_preset(text: &str) -> Result<(String, Vec<String>)> {
    let bad = |why: &str| {
        Error::input(
            InputKind::Value,
            format!(
            "--preset '{text}': {why}; write --preset NAME=key.path=v;key.path=v (e.g. --preset \
             mmls=discretization.method=meshless;discretization.basis=quadratic)"
        ),
        )
    };
    let (name, rest) = text.split_once('=').ok_or_else(|| bad("no '='"))?;
    let name = name.trim();
    if name.is_empty() || name.contains([',', ' ']) {
        return Err(bad("the name must be a non-empty word"));
    }
    let sets: Vec<String> = rest
        .split(';')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(String::from)
        .collect();
    if sets.iter().any(|x| !x.contains('=')) {
        return Err(bad("each override needs key.path=value"));
    }
    Ok((name.to_string(), sets))
}

/// The overrides of one combination: presets expanded to their assignments.
fn assignments(combo: &[(String, String)], presets: &BTreeMap<String, Vec<String>>) -> Vec<String> {
    combo
        .iter()
        .flat_map(|(key, v)| match (key.as_str(), presets.get(v)) {
            (PRESET, Some(sets)) => sets.clone(),
            _ => vec![format!("{key}={v}")],
        })
        .collect()
}

/// Every combination of the varied values, the last key varying fastest.
pub fn combinations(varies: &[Vary]) -> Vec<Vec<(String, String)>> {
    let mut out: Vec<Vec<(String, String)>> = vec![Vec::new()];
    for v in varies {
        out = out
            .into_iter()
            .flat_map(|c| {
                v.values.iter().map(move |x| {
                    let mut c = c.clone();
                    c.push((v.key.clone(), x.clone()));
                    c
                })
            })
            .collect();
    }
    out
}

/// Options of a sweep.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    /// Named groups of overrides, varied as the key `preset` (first, slowest) when present.
    pub presets: BTreeMap<String, Vec<String>>,
    /// Write sweep.csv, sweep.md, sweep.json and the plots to DIR.
    pub out: Option<PathBuf>,
    /// Run each combination this many times and keep the fastest (results are deterministic;
    /// only the wall times differ).
    pub repeat: usize,
    /// Also write each run's full outputs (VTU, CSV) to DIR/runs/<id> (its summary and row
    /// are written there always).
    pub keep_outputs: bool,
    pub vtu_format: VtuFormat,
    /// A progress bar over runs (stderr).
    pub progress: bool,
    /// Keep the rows `out` already holds for runs that finished ([`runs::finished`]) and run
    /// only the missing and failed ones.
    pub resume: bool,
    /// Runs at once, each on its share of the threads (at least 1).
    pub jobs: usize,
}

impl Default for SweepOptions {
    fn default() -> Self {
        SweepOptions {
            presets: BTreeMap::new(),
            out: None,
            repeat: 1,
            keep_outputs: false,
            vtu_format: VtuFormat::default(),
            progress: false,
            resume: false,
            jobs: 1,
        }
    }
}

/// One run of the sweep: the varied values and the run's summary, or the error that stopped it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SweepRow {
    /// 1-based run number (the order of `combinations`).
    pub run: usize,
    /// The run's stable id ([`runs::run_id`]): its folder is `runs/<id>`.
    #[serde(default)]
    pub id: String,
    pub values: BTreeMap<String, String>,
    /// Every override of the run (the sweep's fixed ones, then the varied ones).
    #[serde(default)]
    pub overrides: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub summary: Option<Summary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Peak resident memory of the run, MiB (Linux; `None` where runs share a process,
    /// `--jobs` above 1).
    pub peak_memory_mib: Option<f64>,
    /// Runs of this combination; the summary's wall times are the fastest one's.
    pub repeats: usize,
    /// On the Pareto front of error against wall time (no run is both faster and more
    /// accurate).
    pub pareto: bool,
}

impl SweepRow {
    /// The largest relative error over the scene's references (None without references).
    pub fn error_vs_reference(&self) -> Option<f64> {
        let s = self.summary.as_ref()?;
        s.reference
            .values()
            .map(|c| c.relative_error.abs())
            .fold(None, |m: Option<f64>, e| Some(m.map_or(e, |m| m.max(e))))
    }

    /// A run to trade on: it completed, converged where it relaxed (to an equilibrium
    /// residual within [`crate::report::RESIDUAL_WARNING`]), and its energy balance is within
    /// [`crate::report::ENERGY_WARNING`] (a run past that grew unstable: its time and error
    /// are no trade-off).
    pub fn trustworthy(&self) -> bool {
        self.summary.as_ref().is_some_and(|s| {
            s.converged
                && s.equilibrium_residual
                    .is_none_or(|r| r <= crate::report::RESIDUAL_WARNING)
                && s.energy
                    .balance_error
                    .is_none_or(|b| b <= crate::report::ENERGY_WARNING)
        })
    }

    /// Characteristic node spacing (volume / nodes)^(1/3), m.
    pub fn spacing(&self) -> Option<f64> {
        let s = self.summary.as_ref()?;
        (s.nodes > 0 && s.mesh.volume > 0.0).then(|| (s.mesh.volume / s.nodes as f64).cbrt())
    }

    /// Which curve the row belongs to in the plots: method/element, plus the solver mode when
    /// the sweep mixes modes.
    fn series(&self, modes_differ: bool) -> Option<String> {
        let s = self.summary.as_ref()?;
        let name = match self.values.get(PRESET) {
            Some(p) => p.clone(),
            None => format!("{}/{}", s.method, s.element),
        };
        Some(if modes_differ {
            format!("{name} {}", s.mode)
        } else {
            name
        })
    }
}

/// The sweep's dimensions (presets first) and its runs, after checking that every varied
/// key gives a valid scene with at least one of its values (a misspelt key fails here, not
/// as a table of failed rows).
pub fn prepare(
    scene_path: &Path,
    overrides: &[String],
    varies: &[Vary],
    presets: &BTreeMap<String, Vec<String>>,
) -> Result<(Vec<Vary>, Vec<runs::Planned>)> {
    let all = dimensions(varies, presets);
    let varies = &all[..];
    if varies.is_empty() {
        return Err(Error::input(
            InputKind::Value,
            "sweep: nothing to vary; give at least one --vary key.path=v1,v2,... or --preset",
        ));
    }
    for v in varies {
        let mut first_err = None;
        let ok = v.values.iter().any(|x| {
            let mut o = overrides.to_vec();
            o.extend(assignments(&[(v.key.clone(), x.clone())], presets));
            match crate::scene::load(scene_path, &o) {
                Ok(_) => true,
                Err(e) => {
                    first_err.get_or_insert(e);
                    false
                }
            }
        });
        if !ok {
            let e = first_err.map(|e| e.to_string()).unwrap_or_default();
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "sweep: no value of --vary {} gives a valid scene: {e}",
                    v.key
                ),
            ));
        }
    }
    let planned = runs::plan(overrides, varies, presets);
    Ok((all, planned))
}

/// Writes the table of `rows` (sorted by run, the Pareto front marked) to `dir`
/// ([`write_outputs`]).
pub fn write_table(
    dir: &Path,
    scene_path: &Path,
    varies: &[Vary],
    presets: &BTreeMap<String, Vec<String>>,
    rows: &[SweepRow],
    planned: usize,
) -> Result<()> {
    let mut rows = rows.to_vec();
    rows.sort_by_key(|r| r.run);
    mark_pareto(&mut rows);
    write_outputs(dir, scene_path, varies, presets, &rows, planned)
}

/// Runs every combination of `varies` on `scene_path` (after `overrides`). Fails early only
/// when a varied key is unusable with every one of its values (e.g. a misspelt key).
pub fn run_sweep(
    scene_path: &Path,
    overrides: &[String],
    varies: &[Vary],
    opts: &SweepOptions,
) -> Result<Vec<SweepRow>> {
    let (all, planned) = prepare(scene_path, overrides, varies, &opts.presets)?;
    let varies = &all[..];
    let total = planned.len();
    let mut rows: Vec<SweepRow> = Vec::with_capacity(total);
    let mut todo: Vec<runs::Planned> = Vec::new();
    for p in planned {
        match opts.out.as_deref().filter(|_| opts.resume) {
            Some(out) => match runs::finished(out, &p) {
                Some(row) => rows.push(row),
                None => todo.push(p),
            },
            None => todo.push(p),
        }
    }
    if opts.resume && opts.progress {
        eprintln!(
            "sweep: resuming: {} of {total} runs finished before, {} to run",
            rows.len(),
            todo.len()
        );
    }
    let bar = progress_bar(total, opts.progress);
    bar.inc(rows.len() as u64);
    let record = |row: SweepRow, seconds: f64, rows: &mut Vec<SweepRow>| -> Result<()> {
        let label = row
            .values
            .iter()
            .map(|(key, v)| format!("{key}={v}"))
            .collect::<Vec<_>>()
            .join(" ");
        let line = format!(
            "run {}/{total} {label}: {} in {seconds:.1} s",
            row.run,
            match (&row.error, row.error_vs_reference()) {
                (Some(e), _) => format!("FAILED ({e})"),
                (None, Some(x)) => format!("error {} %", percent(x)),
                (None, None) => "done".into(),
            },
        );
        if opts.progress {
            if bar.is_hidden() {
                eprintln!("sweep: {line}");
            } else {
                bar.println(line);
            }
        }
        bar.inc(1);
        rows.push(row);
        rows.sort_by_key(|r| r.run);
        // Rewritten (atomically) after every run, so a sweep that is stopped keeps a
        // truthful table of the runs it finished.
        if let Some(dir) = &opts.out {
            write_table(dir, scene_path, varies, &opts.presets, rows, total)?;
        }
        Ok(())
    };
    if let (Some(dir), false) = (&opts.out, rows.is_empty()) {
        write_table(dir, scene_path, varies, &opts.presets, &rows, total)?;
    }
    let jobs = opts.jobs.clamp(1, todo.len().max(1));
    if jobs == 1 {
        for p in &todo {
            bar.set_message(
                p.values
                    .iter()
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect::<Vec<_>>()
                    .join(" "),
            );
            let t0 = Instant::now();
            let row = runs::execute(scene_path, p, opts, true)?;
            record(row, t0.elapsed().as_secs_f64(), &mut rows)?;
        }
    } else {
        parallel(scene_path, todo, opts, jobs, |row, t| {
            record(row, t, &mut rows)
        })?;
    }
    bar.finish_and_clear();
    mark_pareto(&mut rows);
    Ok(rows)
}

/// Runs `todo` `jobs` at a time, each job on its own pool of its share of the threads; the
/// rows are handed to `done` (on this thread) as they finish. The first interrupt or write
/// failure stops the handing out of runs; the runs under way finish.
fn parallel(
    scene_path: &Path,
    todo: Vec<runs::Planned>,
    opts: &SweepOptions,
    jobs: usize,
    mut done: impl FnMut(SweepRow, f64) -> Result<()>,
) -> Result<()> {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::{mpsc, Mutex};
    let threads = (rayon::current_num_threads() / jobs).max(1);
    let queue = Mutex::new(std::collections::VecDeque::from(todo));
    let stop = AtomicBool::new(false);
    let (tx, rx) = mpsc::channel::<(Result<SweepRow>, f64)>();
    let mut first_err = None;
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            let tx = tx.clone();
            let (queue, stop) = (&queue, &stop);
            scope.spawn(move || {
                let pool = match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
                    Ok(p) => p,
                    Err(e) => {
                        let _ = tx.send((
                            Err(Error::input(
                                InputKind::Value,
                                format!("sweep --jobs: cannot start a thread pool: {e}"),
                            )),
                            0.0,
                        ));
                        return;
                    }
                };
                loop {
                    if stop.load(Ordering::Relaxed) {
                        return;
                    }
                    let next = queue.lock().ok().and_then(|mut q| q.pop_front());
                    let Some(p) = next else { return };
                    let t0 = Instant::now();
                    let row = pool.install(|| runs::execute(scene_path, &p, opts, false));
                    if tx.send((row, t0.elapsed().as_secs_f64())).is_err() {
                        return;
                    }
                }
            });
        }
        drop(tx);
        for (row, seconds) in rx {
            let r = row.and_then(|row| done(row, seconds));
            if let Err(e) = r {
                stop.store(true, Ordering::Relaxed);
                first_err.get_or_insert(e);
            }
        }
    });
    match first_err {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

fn progress_bar(n: usize, show: bool) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(n as u64);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "sweep {bar:30} {pos}/{len} runs, eta {eta} | {msg}",
    ) {
        bar.set_style(style);
    }
    bar
}

/// Marks the runs that no other run beats on both wall time and error vs reference, among the
/// [`SweepRow::trustworthy`] ones.
pub fn mark_pareto(rows: &mut [SweepRow]) {
    let pts: Vec<(usize, f64, f64)> = rows
        .iter()
        .enumerate()
        .filter(|(_, r)| r.trustworthy())
        .filter_map(|(i, r)| {
            let e = r.error_vs_reference()?;
            let t = r.summary.as_ref()?.wall_seconds.total;
            (e.is_finite() && t.is_finite()).then_some((i, t, e))
        })
        .collect();
    for &(i, t, e) in &pts {
        let dominated = pts
            .iter()
            .any(|&(j, tj, ej)| j != i && tj <= t && ej <= e && (tj < t || ej < e));
        rows[i].pareto = !dominated;
    }
}

/// Least-squares slope of log(error) against log(spacing): the observed convergence order.
/// None with fewer than two spacings or when they span less than a factor 1.2.
pub fn convergence_order(points: &[(f64, f64)]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(h, e)| *h > 0.0 && *e > 0.0 && h.is_finite() && e.is_finite())
        .map(|(h, e)| (h.ln(), e.ln()))
        .collect();
    let n = logs.len() as f64;
    if logs.len() < 2 {
        return None;
    }
    let mx = logs.iter().map(|p| p.0).sum::<f64>() / n;
    let my = logs.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    // Runs at (nearly) one resolution say nothing about the order: ask for a 20 % spread.
    let (lo, hi) = logs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.0), b.max(p.0))
        });
    (hi - lo > 1.2f64.ln() && sxx > 0.0).then(|| sxy / sxx)
}

/// Largest relative error below which a fitted order says nothing: the errors are at the
/// solver's tolerance or round-off, not discretization error.
const NOISE_ERROR: f64 = 1e-5;

/// What a fitted order `p` over `points` (spacing, relative error) can be trusted for.
pub fn order_remark(points: &[(f64, f64)], p: f64) -> &'static str {
    let max = points.iter().map(|x| x.1).fold(0.0f64, f64::max);
    if max < NOISE_ERROR {
        "errors below 0.001 %: solver tolerance or round-off, not a convergence order"
    } else if p < 0.0 {
        "errors grow under refinement"
    } else {
        ""
    }
}

/// Per curve: (name, [(spacing m, error)], [(wall s, error)]) of the rows with an error.
#[allow(clippy::type_complexity)]
fn curves(rows: &[SweepRow]) -> Vec<(String, Vec<(f64, f64)>, Vec<(f64, f64)>)> {
    let modes: BTreeSet<&str> = rows
        .iter()
        .filter_map(|r| Some(r.summary.as_ref()?.mode.as_str()))
        .collect();
    let mut out: BTreeMap<String, (Vec<(f64, f64)>, Vec<(f64, f64)>)> = BTreeMap::new();
    for r in rows {
        let (Some(name), Some(e), Some(h)) = (
            r.series(modes.len() > 1),
            r.error_vs_reference(),
            r.spacing(),
        ) else {
            continue;
        };
        let t = r
            .summary
            .as_ref()
            .map_or(f64::NAN, |s| s.wall_seconds.total);
        let c = out.entry(name).or_default();
        c.0.push((h, e));
        c.1.push((t, e));
    }
    out.into_iter()
        .map(|(n, (mut a, mut b))| {
            a.sort_by(|p, q| p.0.total_cmp(&q.0));
            b.sort_by(|p, q| p.0.total_cmp(&q.0));
            (n, a, b)
        })
        .collect()
}

fn names<'a>(rows: &'a [SweepRow], f: impl Fn(&'a Summary) -> Vec<&'a String>) -> Vec<String> {
    let set: BTreeSet<&String> = rows
        .iter()
        .filter_map(|r| r.summary.as_ref())
        .flat_map(f)
        .collect();
    set.into_iter().cloned().collect()
}

/// The CSV table: the varied values, then the run's summary (SI units in the headers).
fn csv_columns(varies: &[Vary], rows: &[SweepRow]) -> (Vec<String>, Vec<Vec<String>>) {
    let reactions = names(rows, |s| s.reactions.keys().collect());
    let probes = names(rows, |s| s.probes.keys().collect());
    let refs = names(rows, |s| s.reference.keys().collect());
    let mut head: Vec<String> = vec!["run".into()];
    head.extend(varies.iter().map(|v| v.key.clone()));
    head.extend(
        [
            "method",
            "element",
            "mode",
            "nodes",
            "points",
            "spacing (m)",
            "dt (s)",
            "dt critical (s)",
            "dt factor",
            "steps",
            "force evaluations",
            "converged",
            "preprocess (s)",
            "solve (s)",
            "total (s)",
            "ms per step",
            "threads",
        ]
        .map(String::from),
    );
    for r in &reactions {
        head.extend(["x", "y", "z"].map(|c| format!("reaction {r} {c} (N)")));
    }
    for p in &probes {
        head.extend(["x", "y", "z"].map(|c| format!("probe {p} u{c} (m)")));
    }
    head.extend(refs.iter().map(|r| format!("error {r} (%)")));
    head.extend(
        [
            "max error (%)",
            "external work (J)",
            "peak external work (J)",
            "strain energy (J)",
            "kinetic energy (J)",
            "energy balance error (%)",
            "equilibrium residual",
            "angular momentum drift",
            "min dihedral (deg)",
            "removed nodes",
            "support nodes mean",
            "peak memory (MiB)",
            "pareto",
            "status",
        ]
        .map(String::from),
    );
    let f = |x: f64| format!("{x:.6e}");
    let body = rows
        .iter()
        .map(|r| {
            let mut c = vec![r.run.to_string()];
            c.extend(
                varies
                    .iter()
                    .map(|v| r.values.get(&v.key).cloned().unwrap_or_default()),
            );
            match &r.summary {
                Some(s) => {
                    c.extend([
                        s.method.clone(),
                        s.element.clone(),
                        s.mode.clone(),
                        s.nodes.to_string(),
                        s.integration_points.to_string(),
                        r.spacing().map_or(String::new(), f),
                        f(s.dt),
                        f(s.dt_critical),
                        s.dt_factor.to_string(),
                        s.steps.to_string(),
                        s.force_evaluations.to_string(),
                        s.converged.to_string(),
                        format!("{:.4}", s.wall_seconds.preprocess),
                        format!("{:.4}", s.wall_seconds.solve),
                        format!("{:.4}", s.wall_seconds.total),
                        format!("{:.5}", s.ms_per_step()),
                        s.threads.to_string(),
                    ]);
                    for name in &reactions {
                        let v = s.reactions.get(name);
                        c.extend((0..3).map(|k| v.map_or(String::new(), |v| f(v[k]))));
                    }
                    for name in &probes {
                        let v = s.probes.get(name).map(|p| p.displacement);
                        c.extend((0..3).map(|k| v.map_or(String::new(), |v| f(v[k]))));
                    }
                    for name in &refs {
                        c.push(s.reference.get(name).map_or(String::new(), |x| {
                            format!("{:.5}", 100.0 * x.relative_error)
                        }));
                    }
                    c.push(
                        r.error_vs_reference()
                            .map_or(String::new(), |e| format!("{:.5}", 100.0 * e)),
                    );
                    let e = &s.energy;
                    c.extend(
                        [
                            e.external_work,
                            e.peak_external_work,
                            e.strain_energy,
                            e.kinetic,
                        ]
                        .map(f),
                    );
                    c.push(
                        e.balance_error
                            .map_or(String::new(), |e| format!("{:.5}", 100.0 * e)),
                    );
                    c.push(
                        s.equilibrium_residual
                            .map_or(String::new(), |r| format!("{r:.3e}")),
                    );
                    c.push(
                        s.momentum
                            .and_then(|m| m.angular_drift())
                            .map_or(String::new(), |d| format!("{d:.3e}")),
                    );
                    c.push(
                        s.mesh
                            .min_dihedral_deg
                            .map_or(String::new(), |d| format!("{d:.3}")),
                    );
                    c.push(s.removed_nodes.map_or(String::new(), |n| n.to_string()));
                    c.push(
                        s.support_nodes
                            .as_ref()
                            .map_or(String::new(), |n| format!("{:.2}", n.mean)),
                    );
                }
                None => {
                    let n = 17 + 3 * reactions.len() + 3 * probes.len() + refs.len() + 11;
                    c.extend(std::iter::repeat_n(String::new(), n));
                }
            }
            c.push(
                r.peak_memory_mib
                    .map_or(String::new(), |m| format!("{m:.1}")),
            );
            c.push(r.pareto.to_string());
            c.push(status(r));
            c
        })
        .collect();
    (head, body)
}

/// A fraction as a percentage with three decimals, or three significant digits when smaller.
fn percent(x: f64) -> String {
    let p = 100.0 * x;
    if p.abs() >= 0.01 || p == 0.0 {
        format!("{p:.3}")
    } else {
        format!("{p:.2e}")
    }
}

fn status(r: &SweepRow) -> String {
    crate::report::row_status(r.error.as_ref(), r.summary.as_ref())
}

/// The sweep as a Markdown table (the main columns; sweep.csv has them all) followed by the
/// observed convergence orders and the Pareto front.
pub fn table(varies: &[Vary], rows: &[SweepRow]) -> String {
    let reactions = names(rows, |s| s.reactions.keys().collect());
    let mut head: Vec<String> = vec!["run".into()];
    head.extend(varies.iter().map(|v| v.key.clone()));
    head.extend(
        [
            "method",
            "nodes",
            "points",
            "dt (s)",
            "steps",
            "force evaluations",
            "total (s)",
        ]
        .map(String::from),
    );
    let first = rows.iter().find_map(|r| r.summary.as_ref());
    let comps = crate::report::reaction_columns(first, &reactions);
    head.extend(comps.iter().map(|(_, h)| h.clone()));
    let spins = rows.iter().any(|r| {
        r.summary
            .as_ref()
            .and_then(|s| s.momentum)
            .and_then(|m| m.angular_drift())
            .is_some()
    });
    if spins {
        head.push("angular momentum drift".into());
    }
    head.extend(
        [
            "max error (%)",
            "energy error (%)",
            "memory (MiB)",
            "pareto",
            "status",
        ]
        .map(String::from),
    );
    let mut s = format!("| {} |\n|{}\n", head.join(" | "), "---|".repeat(head.len()));
    for r in rows {
        let mut c = vec![r.run.to_string()];
        c.extend(
            varies
                .iter()
                .map(|v| r.values.get(&v.key).cloned().unwrap_or_default()),
        );
        match &r.summary {
            Some(x) => {
                c.extend([
                    format!("{}/{}", x.method, x.element),
                    x.nodes.to_string(),
                    x.integration_points.to_string(),
                    format!("{:.3e}", x.dt),
                    x.steps.to_string(),
                    x.force_evaluations.to_string(),
                    format!("{:.2}", x.wall_seconds.total),
                ]);
                c.extend(reactions.iter().zip(&comps).map(|(n, &(k, _))| {
                    x.reactions
                        .get(n)
                        .map_or("-".into(), |v| format!("{:.5e}", v[k]))
                }));
                if spins {
                    c.push(
                        x.momentum
                            .and_then(|m| m.angular_drift())
                            .map_or("-".into(), |d| format!("{d:.2e}")),
                    );
                }
                c.extend([
                    r.error_vs_reference().map_or("-".into(), percent),
                    x.energy.balance_error.map_or("-".into(), percent),
                ]);
            }
            None => c.extend(std::iter::repeat_n("-".to_string(), 9 + reactions.len())),
        }
        c.push(r.peak_memory_mib.map_or("-".into(), |m| format!("{m:.0}")));
        c.push(if r.pareto {
            "yes".into()
        } else {
            String::new()
        });
        c.push(status(r).replace('|', "/").replace('\n', " "));
        s.push_str(&format!("| {} |\n", c.join(" | ")));
    }
    s.push_str(&cheapest(rows));
    let curves = curves(rows);
    let orders: Vec<String> = curves
        .iter()
        .filter_map(|(n, hs, _)| {
            convergence_order(hs)
                .map(|p| format!("| {n} | {} | {p:.2} | {} |", hs.len(), order_remark(hs, p)))
        })
        .collect();
    if !orders.is_empty() {
        s.push_str(
            "\nObserved convergence order p (error ~ h^p, least squares over the runs; \
             h = (volume / nodes)^(1/3)):\n\n| series | runs | p | remark |\n|---|---|---|---|\n",
        );
        s.push_str(&(orders.join("\n") + "\n"));
    }
    crate::error::tidy_exponents(&s)
}

/// Thresholds of the "cheapest run" table: 1 % and 5 % error vs reference.
pub const THRESHOLDS: [f64; 2] = [0.01, 0.05];

/// For each threshold, the fastest run (total wall time) of each series whose error vs
/// reference is at most the threshold, fastest series first (empty without references).
fn cheapest(rows: &[SweepRow]) -> String {
    let modes: BTreeSet<&str> = rows
        .iter()
        .filter_map(|r| Some(r.summary.as_ref()?.mode.as_str()))
        .collect();
    let mut out = String::new();
    for t in THRESHOLDS {
        let mut best: BTreeMap<String, &SweepRow> = BTreeMap::new();
        for r in rows {
            let (Some(e), Some(name), Some(s)) = (
                r.error_vs_reference(),
                r.series(modes.len() > 1),
                r.summary.as_ref(),
            ) else {
                continue;
            };
            if e > t || !r.trustworthy() {
                continue;
            }
            let faster = best.get(&name).is_none_or(|b| {
                b.summary
                    .as_ref()
                    .is_none_or(|bs| s.wall_seconds.total < bs.wall_seconds.total)
            });
            if faster {
                best.insert(name, r);
            }
        }
        let have_errors = rows.iter().any(|r| r.error_vs_reference().is_some());
        if !have_errors {
            return out;
        }
        out.push_str(&format!(
            "\nCheapest run within {:.0} % of the references, per series (fastest first):\n\n",
            100.0 * t
        ));
        if best.is_empty() {
            out.push_str("none of the runs reaches it\n");
            continue;
        }
        out.push_str("| series | run | nodes | points | total (s) | max error (%) |\n|---|---|---|---|---|---|\n");
        let mut list: Vec<(String, &SweepRow)> = best.into_iter().collect();
        list.sort_by(|a, b| {
            let t = |r: &SweepRow| {
                r.summary
                    .as_ref()
                    .map_or(f64::INFINITY, |s| s.wall_seconds.total)
            };
            t(a.1).total_cmp(&t(b.1))
        });
        for (name, r) in list {
            if let Some(s) = &r.summary {
                out.push_str(&format!(
                    "| {name} | {} | {} | {} | {:.2} | {} |\n",
                    r.run,
                    s.nodes,
                    s.integration_points,
                    s.wall_seconds.total,
                    r.error_vs_reference().map_or("-".into(), percent)
                ));
            }
        }
    }
    out
}

/// sweep.csv, sweep.md, sweep.json, error_vs_time.svg, error_vs_spacing.svg.
pub fn write_outputs(
    dir: &Path,
    scene_path: &Path,
    varies: &[Vary],
    presets: &BTreeMap<String, Vec<String>>,
    rows: &[SweepRow],
    planned: usize,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let quote = |s: &str| {
        if s.contains([',', '"', '\n']) {
            format!("\"{}\"", s.replace('"', "\"\""))
        } else {
            s.to_string()
        }
    };
    let (head, body) = csv_columns(varies, rows);
    let mut csv = head.iter().map(|h| quote(h)).collect::<Vec<_>>().join(",") + "\n";
    for r in &body {
        csv += &(r.iter().map(|c| quote(c)).collect::<Vec<_>>().join(",") + "\n");
    }
    runs::write_atomic(&dir.join("sweep.csv"), &csv)?;
    let vary_args: Vec<String> = varies
        .iter()
        .filter(|v| v.key != PRESET)
        .map(|v| format!("--vary {}={}", v.key, v.values.join(",")))
        .chain(
            presets
                .iter()
                .map(|(n, o)| format!("--preset '{n}={}'", o.join(";"))),
        )
        .collect();
    let partial = if rows.len() < planned {
        format!(
            "**Partial: {} of {planned} runs finished** (the sweep was stopped or is running).\n\n",
            rows.len()
        )
    } else {
        String::new()
    };
    let md = format!(
        "# hytled sweep {} {}\n\n{partial}SI units (m, N, s). Error: the largest relative error \
         over the scene's references.\n\n{}",
        scene_path.display(),
        vary_args.join(" "),
        table(varies, rows)
    );
    runs::write_atomic(&dir.join("sweep.md"), &md)?;
    let json = serde_json::to_string_pretty(rows)
        .map_err(|e| Error::input(InputKind::Value, format!("cannot serialise the sweep: {e}")))?;
    runs::write_atomic(&dir.join("sweep.json"), &json)?;

    let curves = curves(rows);
    if curves.is_empty() {
        return Ok(());
    }
    let mut front: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.pareto)
        .filter_map(|r| {
            Some((
                r.summary.as_ref()?.wall_seconds.total,
                r.error_vs_reference()?,
            ))
        })
        .map(|(t, e)| (t, 100.0 * e))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    let time_series: Vec<Series> = curves
        .iter()
        .map(|(n, _, te)| Series {
            name: n,
            points: te.iter().map(|&(t, e)| (t, 100.0 * e)).collect(),
        })
        .collect();
    log_log_plot(
        &dir.join("error_vs_time.svg"),
        "Error vs wall time (Pareto front dashed)",
        "wall time (s)",
        "max error vs reference (%)",
        &time_series,
        Some(&front),
    )?;
    let labels: Vec<String> = curves
        .iter()
        .map(|(n, hs, _)| match convergence_order(hs) {
            Some(p) if order_remark(hs, p).starts_with("errors below") => {
                format!("{n} (at round-off)")
            }
            Some(p) => format!("{n} (p = {p:.2})"),
            None => n.clone(),
        })
        .collect();
    let h_series: Vec<Series> = curves
        .iter()
        .zip(&labels)
        .map(|((_, hs, _), l)| Series {
            name: l,
            points: hs.iter().map(|&(h, e)| (h, 100.0 * e)).collect(),
        })
        .collect();
    log_log_plot(
        &dir.join("error_vs_spacing.svg"),
        "Error vs node spacing (observed order p)",
        "node spacing (volume / nodes)^(1/3) (m)",
        "max error vs reference (%)",
        &h_series,
        None,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stopped_sweep_says_how_many_runs_it_finished() {
        let dir = std::env::temp_dir().join(format!("hytled-partial-{}", std::process::id()));
        let varies = vec![parse_vary("solver.dt_factor=0.5,0.9").unwrap()];
        let row = SweepRow {
            run: 1,
            id: "0".into(),
            values: [("solver.dt_factor".to_string(), "0.5".to_string())].into(),
            overrides: vec!["solver.dt_factor=0.5".into()],
            summary: None,
            error: Some("unstable".into()),
            peak_memory_mib: None,
            repeats: 1,
            pareto: false,
        };
        let rows = vec![row];
        let scene = Path::new("cases/cube-compression.toml");
        write_outputs(&dir, scene, &varies, &BTreeMap::new(), &rows, 2).unwrap();
        let md = std::fs::read_to_string(dir.join("sweep.md")).unwrap();
        assert!(md.contains("Partial: 1 of 2 runs"), "{md}");
        let csv = std::fs::read_to_string(dir.join("sweep.csv")).unwrap();
        assert_eq!(csv.lines().count(), 2, "{csv}");
        assert!(csv.contains("unstable"), "{csv}");
        write_outputs(&dir, scene, &varies, &BTreeMap::new(), &rows, 1).unwrap();
        let md = std::fs::read_to_string(dir.join("sweep.md")).unwrap();
        assert!(!md.contains("Partial"), "{md}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn vary_lists_split_outside_brackets() {
        let v = parse_vary("discretization.divisions=[4,2,8], [6,3,12]").unwrap();
        assert_eq!(v.key, "discretization.divisions");
        assert_eq!(v.values, vec!["[4,2,8]", "[6,3,12]"]);
        let v = parse_vary("material.poisson_ratio=0.3,0.45,0.49").unwrap();
        assert_eq!(v.values, vec!["0.3", "0.45", "0.49"]);
        let v = parse_vary("name=\"a,b\",c").unwrap();
        assert_eq!(v.values, vec!["\"a,b\"", "c"]);
        for bad in ["novalue", "=1,2", "a=1,,2", "a=[1,2", "a=1,"] {
            let e = parse_vary(bad).unwrap_err().to_string();
            assert!(e.contains("--vary") && e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn combinations_are_the_cartesian_product_last_key_fastest() {
        let v = [
            Vary {
                key: "a".into(),
                values: vec!["1".into(), "2".into()],
            },
            Vary {
                key: "b".into(),
                values: vec!["x".into(), "y".into(), "z".into()],
            },
        ];
        let c = combinations(&v);
        assert_eq!(c.len(), 6);
        assert_eq!(
            c[0],
            vec![("a".into(), "1".into()), ("b".into(), "x".into())]
        );
        assert_eq!(c[1][1].1, "y");
        assert_eq!(
            c[3],
            vec![("a".into(), "2".into()), ("b".into(), "x".into())]
        );
    }

    #[test]
    fn convergence_order_recovers_a_power_law() {
        let pts: Vec<(f64, f64)> = [0.1, 0.05, 0.025, 0.0125]
            .iter()
            .map(|&h: &f64| (h, 3.0 * h.powf(1.7)))
            .collect();
        let p = convergence_order(&pts).unwrap();
        assert!((p - 1.7).abs() < 1e-12, "{p}");
        assert!(convergence_order(&pts[..1]).is_none());
        assert!(convergence_order(&[(0.1, 1.0), (0.1, 2.0)]).is_none());
        assert!(convergence_order(&[(0.1, 1.0), (0.105, 2.0)]).is_none());
        // Round-off-level errors fit a meaningless order, and say so.
        let noise = [(0.1, 3e-9), (0.05, 2e-8), (0.025, 9e-7)];
        let p = convergence_order(&noise).unwrap();
        assert!(p < 0.0);
        assert!(order_remark(&noise, p).contains("not a convergence order"));
        assert!(order_remark(&[(0.1, 0.02), (0.05, 0.03)], -0.5).contains("grow"));
        assert_eq!(order_remark(&pts, 2.0), "");
    }
}
