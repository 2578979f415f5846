//! `hytled bench`: whole-run speed figures of a scene (preprocessing, time per step, per
//! point-step, real-time factor, memory) at several thread counts, with the check that every
//! thread count gives bitwise the same displacements.
//!
//! The default cases are the bonded cylinder of `cases/cylinder-compression.toml` (4,389 nodes)
//! in three discretizations: the configuration Horton et al. (2010, sect. 4.9) timed at 14.9 ms
//! per step (meshless, linear MLS, 8 nearest support nodes, 2 grid integration points per node),
//! one-point hexahedra on the same nodes, and the coupled discretization.

use std::time::Instant;

use nalgebra::Vector3;
use serde::Serialize;

use crate::scene::{self, Scene};
use crate::simulation::{self, Device, Mode};

use crate::{Error, InputKind, Result};

/// The cylinder scene the default cases start from.
const CYLINDER: &str = include_str!("../cases/cylinder-compression.toml");

/// A named scene to time.
#[derive(Debug, Clone)]
pub struct BenchCase {
    pub label: String,
    pub scene: Scene,
}

/// The default cases: (label, overrides of the cylinder scene).
pub const DEFAULT_CASES: [(&str, &[&str]); 3] = [
    (
        "meshless-horton",
        &[
            "discretization.method=meshless",
            "discretization.basis=linear",
            "discretization.integration=grid",
            "discretization.point_ratio=2",
            "discretization.support=nearest",
            "discretization.support_nodes=8",
        ],
    ),
    (
        "fe-hex8",
        &["discretization.method=fe", "discretization.element=hex8"],
    ),
    ("coupled", &["discretization.method=coupled"]),
];

/// The default cases with `extra` overrides applied after each case's own.
pub fn default_cases(extra: &[String]) -> Result<Vec<BenchCase>> {
    DEFAULT_CASES
        .iter()
        .map(|(label, sets)| {
            let mut o: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            o.extend(extra.iter().cloned());
            let scene = scene::parse(
                CYLINDER,
                std::path::Path::new("cases/cylinder-compression.toml"),
                &o,
            )?;
            Ok(BenchCase {
                label: label.to_string(),
                scene,
            })
        })
        .collect()
}

/// What to measure.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// Time steps per run (dynamic, at the scene's dt_factor).
    pub steps: usize,
    /// Thread counts, each run in its own pool.
    pub threads: Vec<usize>,
    /// Runs per thread count; the fastest is reported (shared machines are noisy).
    pub repeat: usize,
    /// Print a line per run to stderr.
    pub progress: bool,
    /// Also time each case on this device (not `Cpu`): one more row after the thread
    /// counts, its "identical" comparing with the first thread count's displacements.
    pub device: Device,
}

/// The default thread counts: 1, the powers of two below the core count, and the core count.
pub fn default_threads() -> Vec<usize> {
    let n = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut t: Vec<usize> = std::iter::successors(Some(1usize), |k| Some(k * 2))
        .take_while(|&k| k < n)
        .collect();
    t.push(n);
    t.dedup();
    t
}

/// One timed run. Times in s, memory in MiB.
#[derive(Debug, Clone, Serialize)]
pub struct BenchRow {
    pub case: String,
    pub method: String,
    /// Where the time loop ran: "cpu" or the GPU's name.
    pub device: String,
    pub nodes: usize,
    pub points: usize,
    /// Support entries (node, point) pairs summed over the points.
    pub slots: usize,
    pub threads: usize,
    pub preprocess_s: f64,
    pub solve_s: f64,
    pub steps: usize,
    pub dt_s: f64,
    pub ms_per_step: f64,
    /// Wall time per step divided by the points, ns.
    pub ns_per_point_step: f64,
    /// Simulated time / solve wall time.
    pub real_time_factor: f64,
    /// Solve speed-up over the first thread count of the case.
    pub speedup: f64,
    /// Peak resident memory of the process over this run (Linux VmHWM), MiB.
    pub peak_memory_mib: Option<f64>,
    /// Bytes the solver's arrays hold (points, slots, node maps, state), per integration point.
    pub bytes_per_point: f64,
    /// Final displacements bitwise equal to those of the first thread count.
    pub identical: bool,
}

/// Times `case` at each thread count of `opts`.
pub fn run_case(case: &BenchCase, opts: &BenchOptions) -> Result<Vec<BenchRow>> {
    if opts.steps == 0 {
        return Err(Error::input(
            InputKind::Value,
            "bench: --steps must be at least 1",
        ));
    }
    if opts.repeat == 0 {
        return Err(Error::input(
            InputKind::Value,
            "bench: --repeat must be at least 1 (runs per thread count; the fastest is reported)",
        ));
    }
    let mut rows: Vec<BenchRow> = Vec::new();
    let mut first_u: Option<Vec<Vector3<f64>>> = None;
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    let mut threads: Vec<usize> = Vec::new();
    for &t in &opts.threads {
        if t == 0 {
            return Err(Error::input(
                InputKind::Value,
                "bench: thread counts must be at least 1",
            ));
        }
        if t > cores {
            eprintln!(
                "warning: bench: {t} threads is more than the {cores} cores here; using {cores}"
            );
        }
        if !threads.contains(&t.min(cores)) {
            threads.push(t.min(cores));
        }
    }
    // The thread counts on the CPU, then the device (if any) with the most threads.
    let mut runs: Vec<(usize, Device)> = threads.iter().map(|&t| (t, Device::Cpu)).collect();
    if opts.device != Device::Cpu {
        runs.push((*threads.last().unwrap_or(&1), opts.device));
    }
    for (t, device) in runs {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .map_err(|e| {
                Error::input(
                    InputKind::Value,
                    format!("bench: cannot start {t} threads: {e}"),
                )
            })?;
        crate::comparison::reset_peak_memory();
        let (mut row, u) = pool.install(|| time_once(case, opts.steps, t, device))?;
        for _ in 1..opts.repeat {
            let (r, _) = pool.install(|| time_once(case, opts.steps, t, device))?;
            let preprocess_s = row.preprocess_s.min(r.preprocess_s);
            if r.solve_s < row.solve_s {
                row = r;
            }
            row.preprocess_s = preprocess_s;
        }
        let identical = match &first_u {
            None => {
                first_u = Some(u);
                true
            }
            Some(f) => f.iter().zip(&u).all(|(a, b)| {
                a.iter()
                    .zip(b.iter())
                    .all(|(x, y)| x.to_bits() == y.to_bits())
            }),
        };
        let base = rows.first().map_or(row.solve_s, |r| r.solve_s);
        let row = BenchRow {
            identical,
            speedup: base / row.solve_s,
            peak_memory_mib: crate::comparison::peak_memory_mib(),
            ..row
        };
        if opts.progress {
            let on = if device == Device::Cpu {
                format!("{t} thread(s)")
            } else {
                row.device.clone()
            };
            eprintln!(
                "bench: {} on {on}: {:.3} ms per step, {:.1} ns per point-step",
                case.label, row.ms_per_step, row.ns_per_point_step
            );
        }
        rows.push(row);
    }
    Ok(rows)
}

/// One run of `steps` steps on `device`: its row and final displacements. The device's set-up
/// (kernel compilation, copies of the model) is left out of the time per step.
fn time_once(
    case: &BenchCase,
    steps: usize,
    threads: usize,
    device: Device,
) -> Result<(BenchRow, Vec<Vector3<f64>>)> {
    let t0 = Instant::now();
    let mut prep = simulation::prepare(&case.scene)?;
    let preprocess_s = t0.elapsed().as_secs_f64();
    let mut s = simulation::settings(&case.scene, false);
    s.mode = Mode::Dynamic;
    let (dt_crit, _) = simulation::critical_step(&case.scene, &mut prep)?;
    // The run divides the duration into whole steps of at most dt_factor x dt_crit.
    s.duration = steps as f64 * s.dt_factor * dt_crit * (1.0 - 1e-9);
    // As in a full 3 s run of ~8,000 steps with 200 history rows: energies every 40 steps.
    s.history_rows = (steps / 40).max(1);
    s.frames = 1;
    s.device = device;
    let out = simulation::solve(&mut prep, &s)?;
    let points = prep.model.points().len();
    let loop_s = out.solve_seconds - out.device_setup_seconds;
    let per_step = loop_s / out.steps.max(1) as f64;
    let row = BenchRow {
        case: case.label.clone(),
        method: format!(
            "{} {}",
            simulation::method_name(&prep),
            simulation::element_label(&case.scene, &prep)
        ),
        nodes: prep.model.nodes().len(),
        points,
        slots: prep.model.points().nodes.len(),
        device: out.device.clone(),
        threads,
        preprocess_s,
        solve_s: loop_s,
        steps: out.steps,
        dt_s: out.dt,
        ms_per_step: per_step * 1e3,
        ns_per_point_step: per_step * 1e9 / points.max(1) as f64,
        real_time_factor: out.simulated_time / loop_s,
        speedup: 1.0,
        peak_memory_mib: None,
        bytes_per_point: prep.model.solver_bytes() as f64 / points.max(1) as f64,
        identical: true,
    };
    Ok((row, out.u))
}

/// Markdown table of bench rows.
pub fn table(rows: &[BenchRow]) -> String {
    let mut s = String::from(
        "| case | method | device | nodes | points | threads | preprocess (s) | ms per step | ns per point-step | real-time factor | speed-up | peak memory (MiB) | bytes per point | bitwise identical |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {:.3} | {:.3} | {:.1} | {:.2} | {:.2} | {} | {:.0} | {} |\n",
            r.case,
            r.method,
            r.device,
            r.nodes,
            r.points,
            r.threads,
            r.preprocess_s,
            r.ms_per_step,
            r.ns_per_point_step,
            r.real_time_factor,
            r.speedup,
            r.peak_memory_mib.map_or("-".into(), |m| format!("{m:.0}")),
            r.bytes_per_point,
            if r.identical { "yes" } else { "NO" }
        ));
    }
    crate::error::tidy_exponents(&s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_cases_parse_and_thread_counts_start_at_one() {
        let cases = default_cases(&[]).unwrap();
        assert_eq!(cases.len(), 3);
        let t = default_threads();
        assert_eq!(t[0], 1);
        assert!(t.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn bench_reports_identical_results_for_one_and_two_threads() {
        let cases = default_cases(&["discretization.divisions=[4,2,6]".to_string()]).unwrap();
        let opts = BenchOptions {
            steps: 20,
            threads: vec![1, 2],
            repeat: 1,
            progress: false,
            device: Device::Cpu,
        };
        for c in &cases {
            let rows = run_case(c, &opts).unwrap();
            assert_eq!(rows.len(), 2);
            for r in &rows {
                assert!(
                    r.identical,
                    "{}: {} threads differ from 1",
                    r.case, r.threads
                );
                assert!(r.steps >= 20 && r.steps <= 21, "{} steps", r.steps);
                assert!(r.ms_per_step > 0.0 && r.bytes_per_point > 0.0);
            }
        }
    }
}
