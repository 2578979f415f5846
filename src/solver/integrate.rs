//! Time loops: explicit central differences (dynamics) and adaptive dynamic relaxation
//! (Joldes, Wittek & Miller 2011) written as one update
//! u(n+1) = A M^-1 (F_ext - F_int) + B u(n) + C u(n-1), with displacement conditions enforced
//! at the end of each step.

use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, Ordering};

use super::forces::NODE_BLOCK;
use super::timestep::critical_time_step;
use super::{Model, SharedMut};
use crate::material::Material;
use crate::{Error, Result};

/// Which problem the loop solves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Explicit dynamics over `duration` seconds.
    #[default]
    Dynamic,
    /// Steady state by adaptive dynamic relaxation.
    Relaxation,
}

/// How the critical step is estimated (see [`critical_step`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum StepEstimate {
    /// The per-point and nodal bounds (safe upper bounds on the largest frequency of the
    /// reference stiffness; 1.3-2.5x conservative, most where supports are large).
    Bounds,
    /// Lanczos on the reference stiffness ([`super::spectrum`]), never below the bounds' step.
    #[default]
    Global,
}

/// Integrator settings. Times in s, displacements in m.
#[derive(Debug, Clone)]
pub struct Settings {
    pub mode: Mode,
    /// Dynamic: simulated time T, s.
    pub duration: f64,
    /// Dynamic: time over which load curves run from 0 to 1, s.
    pub load_time: f64,
    /// Relaxation: pseudo-steps over which load curves run from 0 to 1 (None: the larger of
    /// 400 and the shear-wave crossing time of the body in steps, see [`auto_load_steps`]).
    pub load_steps: Option<usize>,
    /// dt = dt_factor x the critical step estimate.
    pub dt_factor: f64,
    /// How the critical step is estimated.
    pub step_estimate: StepEstimate,
    /// Mass-proportional damping coefficient (dynamic), 1/s.
    pub damping: f64,
    /// Relaxation: stop when the estimated displacement error stays below this for 100 steps, m.
    pub tolerance: f64,
    /// Relaxation: give up after this many steps (reported as not converged).
    pub max_steps: usize,
    /// Relaxation: steps between estimates of the lowest frequency.
    pub estimate_interval: usize,
    /// Relaxation: after an instability (divergence or an inverted point), start again from
    /// the unloaded state with dt_factor x [`RETRY_FACTOR`], at most this many times. The
    /// steady state does not depend on the pseudo-time step, and the reference stiffness
    /// behind the critical step does not see how deformation raises the frequencies.
    /// Dynamic runs stop at the first instability (their answer is the path).
    pub retries: usize,
    /// Estimate the critical step again at the deformed state during the run (Lanczos on the
    /// tangent stiffness, [`super::spectrum::Lanczos`]) and shorten the step where deformation
    /// has raised the frequencies, as ABAQUS/Explicit updates its stable increment: dynamic
    /// runs from the start, relaxation in the attempts after a restart. See [`StepUpdates`].
    pub step_update: bool,
    /// Rows wanted in the time history (dynamic); relaxation records every `estimate_interval` steps.
    pub history_rows: usize,
    /// Output frames wanted (dynamic: equally spaced in time; relaxation: start and end).
    pub frames: usize,
    pub progress: bool,
    /// Print a plain progress line to stderr about every this many seconds.
    pub progress_lines: Option<f64>,
    /// Dynamic: initial nodal velocities, m/s (default: at rest).
    pub initial_velocity: Option<Vec<Vector3<f64>>>,
    /// Dynamic: a rigid initial motion (velocity m/s, angular velocity rad/s, centre m), used
    /// when `initial_velocity` is not given.
    pub initial_motion: Option<[Vector3<f64>; 3]>,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            mode: Mode::Dynamic,
            duration: 3.0,
            load_time: 3.0,
            load_steps: None,
            dt_factor: 0.9,
            step_estimate: StepEstimate::Global,
            damping: 0.0,
            tolerance: 1e-7,
            max_steps: 1_000_000,
            estimate_interval: 50,
            retries: DEFAULT_RETRIES,
            step_update: true,
            history_rows: 200,
            frames: 10,
            progress: false,
            progress_lines: None,
            initial_velocity: None,
            initial_motion: None,
        }
    }
}

/// One row of the time history.
#[derive(Debug, Clone, Serialize)]
pub struct HistoryRow {
    pub step: usize,
    /// Simulated (dynamic) or pseudo (relaxation) time, s.
    pub time: f64,
    /// Reaction of each boundary, N.
    pub reactions: Vec<[f64; 3]>,
    /// Work of the boundary forces, J.
    pub external_work: f64,
    pub strain_energy: f64,
    pub kinetic_energy: f64,
}

/// One record of the dynamic-relaxation parameters.
#[derive(Debug, Clone, Serialize)]
pub struct RelaxationRecord {
    pub step: usize,
    /// Estimated lowest circular frequency, rad/s.
    pub omega_min: f64,
    /// Convergence rate in use.
    pub r: f64,
    /// Whether this estimate was accepted (agreed with the previous one).
    pub accepted: bool,
    /// Estimated distance to the converged solution, m.
    pub error_estimate: f64,
}

/// What a run produces.
#[derive(Debug, Clone)]
pub struct RunOutput {
    pub u: Vec<Vector3<f64>>,
    /// Displacements one step before the end (velocity = (u - u_prev) / dt), m.
    pub u_prev: Vec<Vector3<f64>>,
    pub f_int: Vec<Vector3<f64>>,
    /// The last step taken, s (shorter than the first after step updates; see `step_updates`).
    pub dt: f64,
    /// The critical step estimated at the reference state, s.
    pub dt_critical: f64,
    /// What sets the critical step.
    pub critical: Critical,
    pub steps: usize,
    /// Relaxation: the pseudo-steps the load took (None for dynamic runs).
    pub load_steps: Option<usize>,
    pub simulated_time: f64,
    pub converged: bool,
    pub history: Vec<HistoryRow>,
    pub relaxation: Vec<RelaxationRecord>,
    /// (time, displacement) snapshots for output frames.
    pub frames: Vec<(f64, Vec<Vector3<f64>>)>,
    pub external_work: f64,
    /// Largest |external work| reached during the run, J (the scale of the energy balance when
    /// a load comes back, when the final work is near zero).
    pub peak_external_work: f64,
    /// Kinetic energy at the start (initial velocities), J.
    pub initial_kinetic: f64,
    /// Work done against the mass-proportional damping ([`Settings::damping`]) in a dynamic
    /// run, J: sum over steps and free DOFs of c m v(n) . (u(n+1) - u(n-1)) / 2 with the
    /// central-difference velocity v(n) = (u(n+1) - u(n-1)) / (h(n) + h(n-1)), the force the
    /// update applies; zero without damping.
    pub damping_dissipation: f64,
    /// Linear (kg m/s) and angular (kg m^2/s, about the origin) momentum at the first and the
    /// last step, from the central-difference velocities.
    pub momentum: Momentum,
    pub strain_energy: f64,
    pub kinetic_energy: f64,
    /// Wall time of the estimate and every attempt, frames' writing left out, s.
    pub solve_seconds: f64,
    /// Relaxation: one note per restart after an instability (see [`Settings::retries`]).
    pub restarts: Vec<String>,
    /// Relaxation: steps taken by the attempts that a restart abandoned (their time is in
    /// `solve_seconds`).
    pub failed_steps: usize,
    /// The estimates of the critical step at the deformed state and what they did.
    pub step_updates: StepUpdates,
}

/// Estimates of the critical step during a run ([`Settings::step_update`]).
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
pub struct StepUpdates {
    /// Estimates made at the deformed state.
    pub estimates: usize,
    /// Lanczos iterations (force evaluations) they took.
    pub iterations: usize,
    /// Times the step was shortened.
    pub reductions: usize,
    /// The step the run started with, s.
    pub dt_initial: f64,
    /// The shortest step taken, s.
    pub dt_min: f64,
    /// Simulated time of the last reduction, s.
    pub last_reduction_time: f64,
}

/// Momentum of the nodal masses at the start and the end of a run.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct Momentum {
    pub linear_start: [f64; 3],
    pub linear_end: [f64; 3],
    pub angular_start: [f64; 3],
    pub angular_end: [f64; 3],
}

impl Momentum {
    /// |L_end - L_start| / |L_start| (None when the body starts without angular momentum).
    pub fn angular_drift(&self) -> Option<f64> {
        let (a, b) = (
            Vector3::from(self.angular_start),
            Vector3::from(self.angular_end),
        );
        (a.norm() > 0.0).then(|| (b - a).norm() / a.norm())
    }
}

/// (linear, angular about the origin) momentum with positions X + u and velocities
/// (u - u_prev) / dt.
fn momentum(
    mass: &[f64],
    x: &[Vector3<f64>],
    u: &[Vector3<f64>],
    u_prev: &[Vector3<f64>],
    dt: f64,
) -> ([f64; 3], [f64; 3]) {
    let (mut p, mut l) = (Vector3::zeros(), Vector3::zeros());
    for i in 0..mass.len() {
        let v = (u[i] - u_prev[i]) / dt;
        p += v * mass[i];
        l += (x[i] + u[i]).cross(&v) * mass[i];
    }
    (p.into(), l.into())
}

/// Dynamic-relaxation rate from the lowest frequency: k = 2 / (w_min dt), r = (k - 1) / (k + 1).
fn rate_from_omega(omega: f64, dt: f64) -> f64 {
    let k = 2.0 / (omega * dt);
    ((k - 1.0) / (k + 1.0)).clamp(0.0, 0.99999)
}

/// The bound that sets the critical step (see [`super::timestep`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Critical {
    /// The per-point bound, at this quadrature point.
    Point(usize),
    /// The nodal bound, at this node.
    Node(usize),
    /// The global (Lanczos) estimate, after this many iterations.
    Global(usize),
}

impl std::fmt::Display for Critical {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Critical::Point(p) => write!(f, "point {p}"),
            Critical::Node(n) => write!(f, "node {n}"),
            Critical::Global(k) => write!(f, "the global estimate, {k} Lanczos iterations"),
        }
    }
}

/// Critical step of the model, s, and what sets it: both the per-point and the nodal bound
/// hold for the reference stiffness, so the larger step (the tighter bound) is taken. The nodal
/// bound is much tighter where supports are large (meshless about 1.5x, blended points 2-2.4x).
pub fn stable_step<M: Material>(model: &Model<M>) -> (f64, Critical) {
    let moduli = |p: usize| model.point_moduli(p);
    if all_anp(model) {
        // Average nodal pressure: the bound that sees the averaging (timestep::anp_time_step).
        let (dt, node) = super::timestep::anp_time_step(
            &model.points,
            &model.slots,
            &model.mass,
            &model.constraints.mask,
            &moduli,
            model.forces.point_materials(),
        );
        return (dt, Critical::Node(node));
    }
    let (dt_point, crit_point) = critical_time_step(&model.points, &moduli);
    let (dt_node, crit_node) = super::timestep::nodal_time_step(
        &model.points,
        &model.slots,
        &model.mass,
        &model.constraints.mask,
        &moduli,
    );
    if dt_node > dt_point {
        (dt_node, Critical::Node(crit_node))
    } else {
        (
            dt_point,
            Critical::Point(model.point_ids[crit_point] as usize),
        )
    }
}

/// Refuses a critical step `dt` (s) that is not finite and positive, saying why: most often
/// every degree of freedom is prescribed (a mesh one element across between two constrained
/// faces), which leaves no frequency to bound the step and nothing to solve.
pub fn check_critical_step<M: Material>(model: &Model<M>, dt: f64) -> Result<()> {
    if dt.is_finite() && dt > 0.0 {
        return Ok(());
    }
    if model.constraints.mask.iter().flatten().all(|&c| c) {
        let names: Vec<&str> = model.boundaries.iter().map(|b| b.name.as_str()).collect();
        return Err(Error::Input(format!(
            "every degree of freedom of the {} nodes is prescribed by the boundaries ({}): no node is free to move, \
             so there is nothing to solve; refine the discretization (divisions, size) so that nodes lie between \
             the constrained ones, or constrain fewer components",
            model.nodes.len(),
            names.join(", ")
        )));
    }
    Err(Error::Input(format!(
        "the critical time step estimate is {dt} s; the discretization has no usable points"
    )))
}

/// The fastest dilatational wave speed of the model's materials, m/s.
fn fastest_wave<M: Material>(model: &Model<M>) -> f64 {
    model
        .forces
        .materials
        .iter()
        .map(|m| m.wave_speed())
        .fold(0.0, f64::max)
}

/// Refuses a rigid body that starts deeper inside the body than half the distance the fastest
/// wave crosses in a step of `dt` (s). The first correction pushes the surface out in one
/// step; deeper than that it reads as divergence at step 0 on every restart (the brain
/// indentation 1 mm in: "diverged at step 0", three times). Measured there (c dt =
/// 3.7e-4 m): 2e-4 m in converges, 3e-4 m diverges at step 22.
pub fn check_contact_start<M: Material>(model: &Model<M>, dt: f64) -> Result<()> {
    let Some(ct) = model.contact.as_ref() else {
        return Ok(());
    };
    let c = fastest_wave(model);
    for (b, name) in ct.names().enumerate() {
        if let Some((depth, x)) = ct.deepest_at_rest(b, 0.0).filter(|d| d.0 > 0.5 * c * dt) {
            return Err(Error::Input(format!(
            "contact '{name}' starts {depth:.3e} m inside the body (surface point at ({:.4e}, {:.4e}, {:.4e}) m), \
             deeper than the {:.3e} m a wave crosses in half a step, so the first correction cannot push the \
             surface out without tearing it: start the rigid body outside or touching the body (move it by at \
             least {depth:.3e} m)",
            x.x,
            x.y,
            x.z,
            0.5 * c * dt
        )));
        }
    }
    Ok(())
}

/// Each relaxation restart after an instability multiplies dt_factor by this.
pub const RETRY_FACTOR: f64 = 0.75;
/// A restart that fails within this fraction of where the previous attempt failed ends the
/// restarts. Where is the step over the load steps: the load's share while it grows, and past
/// 1 the pseudo-time after it in units of the loading (the default load steps scale with
/// 1 / dt, so an instability of the equilibrium path, which grows in pseudo-time whatever the
/// step, fails at the same place). Failures within the first [`MIN_LOAD`] of the load are all
/// near zero load whatever their cause, so they do not count.
const SAME_LOAD: f64 = 0.03;
const MIN_LOAD: f64 = 0.05;
/// Relaxation restarts at most (`solver.retries`): 0.9 -> 0.675 -> 0.506 x the critical step.
pub const DEFAULT_RETRIES: usize = 2;

/// Dynamic runs needing more steps than this are refused unless `max_steps` allows them (a
/// mistyped dt_factor or density would otherwise run for days without a word).
const MAX_DYNAMIC_STEPS: f64 = 1e8;

/// Lanczos iterations at most for the global estimate, and its stopping tolerance on the
/// Ritz residual (relative).
const LANCZOS_ITERATIONS: usize = 60;
const LANCZOS_TOLERANCE: f64 = 1e-3;
/// The global estimate's step is this fraction of 2 / omega_max(K_0): the reference
/// stiffness does not see how deformation raises the frequencies. Measured on the 4,208-node
/// Gmsh cylinder, tet4-anp, 20 % extension (relaxation): stable at 0.79 and divergent at 0.83
/// x the reference critical step; compression and the meshless and coupled runs tolerate more.
pub const DEFORMATION_ALLOWANCE: f64 = 0.8;

/// Step updates ([`Settings::step_update`]): the first estimate at the deformed state comes
/// after this many steps; the interval then follows how fast the estimate moves, so that
/// omega_max changes by about [`UPDATE_CHANGE`] between estimates, within
/// [`UPDATE_MIN`]..[`UPDATE_MAX`] steps. An estimate takes 7-22 force evaluations on average;
/// the default cylinder compression spends 3-7 % of its steps' force evaluations on them.
const UPDATE_FIRST: usize = 100;
const UPDATE_MIN: usize = 50;
const UPDATE_MAX: usize = 2000;
const UPDATE_CHANGE: f64 = 0.02;
/// An estimate is also due once a node may have moved this fraction of the distance the
/// fastest wave covers in a critical step (about the smallest element's size) since the last
/// one: the frequencies follow the strains, whose rate the interval's history cannot foresee
/// when the loading speeds up.
const UPDATE_TRAVEL: f64 = 0.25;
/// ... up to this many times farther where estimates due to motion alone found the
/// frequencies unchanged (back to 1 at the first estimate that finds them moving).
const UPDATE_TRAVEL_GROWTH: f64 = 64.0;
/// The step is shortened only when the new estimate is this much below it (1 % is within the
/// allowance), so small wobbles of the estimate do not re-divide the run.
const UPDATE_HYSTERESIS: f64 = 0.01;
/// The estimates at the deformed state are fresh: they keep this fraction of 2 / omega_max
/// instead of the reference estimate's [`DEFORMATION_ALLOWANCE`] (the controller above bounds
/// how far the frequencies move between estimates). With the 0.8 the 20 % compression of the
/// cylinder (fe hex8) shortened its step to 0.75x for 14 % more steps.
pub const UPDATE_ALLOWANCE: f64 = 0.95;
/// Ritz residual at which an update stops (relative; the reference estimate's is 1e-3). The
/// residual is added to the Ritz value, so a looser stop only shortens the step, by about
/// half of it.
const UPDATE_TOLERANCE: f64 = 1e-2;
/// A step that has fallen below this fraction of the initial one stops the run: a point is
/// collapsing, and the run would take over 100x the planned steps.
const UPDATE_MIN_RATIO: f64 = 0.01;

/// When the step is estimated again during a run ([`Settings::step_update`]).
struct UpdateSchedule {
    /// The next step an estimate is due at by the interval.
    next: usize,
    interval: usize,
    /// The step of the last estimate.
    last: usize,
    /// The last estimate of lambda_max, 1/s^2 (at first the reference one, where global).
    lambda: Option<f64>,
    /// The largest nodal change per step summed since the last estimate (m): a bound on how far
    /// any node has moved since, whatever the interval.
    travel: f64,
    /// Multiplies [`UPDATE_TRAVEL`].
    travel_scale: f64,
}

impl UpdateSchedule {
    fn new(reference_lambda: Option<f64>) -> Self {
        UpdateSchedule {
            next: UPDATE_FIRST,
            interval: UPDATE_FIRST,
            last: 0,
            lambda: reference_lambda,
            travel: 0.0,
            travel_scale: 1.0,
        }
    }

    /// Whether an estimate is due at `step`, and if so whether by the distance moved (`reach`:
    /// the distance the fastest wave covers in a critical step, m) rather than the interval.
    fn due(&self, step: usize, reach: f64) -> Option<bool> {
        let by_travel = self.travel > self.travel_scale * UPDATE_TRAVEL * reach
            && step >= self.last + UPDATE_MIN;
        (step >= self.next || by_travel).then_some(by_travel)
    }

    /// An estimate made at `step` (lambda_max, 1/s^2, None where it failed): the next interval
    /// aims at a change of [`UPDATE_CHANGE`] in omega_max.
    fn record(&mut self, step: usize, lambda: Option<f64>, by_travel: bool) {
        self.travel = 0.0;
        self.last = step;
        if let Some(l) = lambda {
            if let Some(l0) = self.lambda {
                let change = ((l / l0).sqrt() - 1.0).abs();
                let scale = if change > 0.0 {
                    (UPDATE_CHANGE / change).clamp(0.5, 2.0)
                } else {
                    2.0
                };
                self.interval =
                    ((self.interval as f64 * scale) as usize).clamp(UPDATE_MIN, UPDATE_MAX);
                // Motion without strain (a rigid rotation) moves nodes without moving the
                // frequencies: each estimate it triggers in vain doubles the distance.
                if change > UPDATE_CHANGE {
                    self.travel_scale = 1.0;
                } else if by_travel && change < 0.25 * UPDATE_CHANGE {
                    self.travel_scale = (2.0 * self.travel_scale).min(UPDATE_TRAVEL_GROWTH);
                }
            }
            self.lambda = Some(l);
        }
        self.next = step + self.interval;
    }
}

/// |a - b|^2 over the free components (`mask` false), m^2: the damping's work per unit
/// c m / (2 (h + h_prev)) with a = u(n+1), b = u(n-1).
#[inline(always)]
fn free_dist2(mask: [bool; 3], a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (0..3)
        .filter(|&k| !mask[k])
        .map(|k| (a[k] - b[k]).powi(2))
        .sum()
}

/// Every point of the model is an average-nodal-pressure tet.
fn all_anp<M: Material>(model: &Model<M>) -> bool {
    !model.points.is_empty()
        && model
            .points
            .kinds
            .iter()
            .all(|&k| k == crate::quadrature::PointKind::Anp)
}

/// Critical step of the model, s, and what sets it. [`StepEstimate::Bounds`]: [`stable_step`].
/// Models of tet4-anp elements only keep their own bound ([`super::timestep::anp_time_step`])
/// under either setting: their critical step falls faster with deformation than the
/// allowance covers (4,208-node Gmsh cylinder, 20 % extension: divergent at 0.83 x the
/// reference critical step; 8,743 nodes: divergent at 0.72 x), and the bound, 0.72 x the
/// global estimate there, ran every case of the tet study.
/// [`StepEstimate::Global`]: [`DEFORMATION_ALLOWANCE`] x 2 / sqrt(lambda) with lambda the Lanczos estimate of the largest
/// eigenvalue of M^-1 K_0 on the free DOFs, rounded up by its residual
/// ([`super::spectrum::largest_eigenvalue`]); the bounds' step where that is longer (the
/// bounds are safe, so a shorter global step would be a failed estimate). Costs up to 60
/// force evaluations.
pub fn critical_step<M: Material>(model: &mut Model<M>, how: StepEstimate) -> (f64, Critical) {
    let bounds = stable_step(model);
    if how == StepEstimate::Bounds || all_anp(model) {
        return bounds;
    }
    match super::spectrum::largest_eigenvalue(model, LANCZOS_ITERATIONS, LANCZOS_TOLERANCE) {
        Some(e) if DEFORMATION_ALLOWANCE * e.critical_step() > bounds.0 => (
            DEFORMATION_ALLOWANCE * e.critical_step(),
            Critical::Global(e.iterations),
        ),
        _ => bounds,
    }
}

/// Default relaxation load steps: the larger of 400 and the number of steps of length `dt` (s)
/// a shear wave (speed sqrt(mu / rho)) takes to cross the body's largest extent `length` (m).
/// Relaxation follows a fictitious dynamic path; loading it faster than the body can shear
/// drives shear shocks that tear near-incompressible meshes (measured: the cylinder at
/// nu = 0.4999 with 4,389-node tet4-anp diverged in 207 steps with 400 load steps and converged
/// with 2,000).
pub fn auto_load_steps(length: f64, mu: f64, density: f64, dt: f64) -> usize {
    let crossing = length / (mu / density).sqrt() / dt;
    if crossing.is_finite() {
        crossing.ceil().clamp(400.0, 1e7) as usize
    } else {
        400
    }
}

/// Runs the model to the end of the dynamic interval or to relaxation convergence.
/// Fails with a clear message when the solution diverges or a point inverts.
///
/// The loop runs on a worker of the current rayon pool (the global one when called from
/// outside a pool): its parallel loops then fork through the worker's own queue, which
/// allocates nothing, instead of injecting jobs from outside, which allocates a queue block
/// every 63 jobs. The time loop allocates only when it records: a history row (a fixed number
/// per dynamic run) and, in relaxation, a frequency estimate every `estimate_interval` steps;
/// the steps between allocate nothing (tests/allocation.rs).
pub fn run<M: Material>(model: &mut Model<M>, s: &Settings) -> Result<RunOutput> {
    run_on_pool(model, s, None)
}

/// Receives each output frame as the run produces it: the model (for stresses), the time (s)
/// and the displacements (m). An error from it stops the run.
pub type FrameSink<'a, M> =
    dyn FnMut(&mut Model<M>, f64, &[Vector3<f64>]) -> Result<()> + Send + 'a;

/// [`run`], handing each output frame to `sink` when it is produced instead of keeping it
/// (`RunOutput::frames` is then empty): long runs hold no frames in memory, and a run that
/// fails has already delivered the frames up to the failure. The time spent in `sink` is not
/// counted in `solve_seconds`.
pub fn run_streaming<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    sink: &mut FrameSink<'_, M>,
) -> Result<RunOutput> {
    run_on_pool(model, s, Some(sink))
}

fn run_on_pool<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    sink: Option<&mut FrameSink<'_, M>>,
) -> Result<RunOutput> {
    if rayon::current_thread_index().is_some() {
        run_on_worker(model, s, sink)
    } else {
        rayon::scope(|_| run_on_worker(model, s, sink))
    }
}

fn run_on_worker<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    mut sink: Option<&mut FrameSink<'_, M>>,
) -> Result<RunOutput> {
    let start = Instant::now();
    // Time spent handing frames to the sink (writing files), left out of solve_seconds.
    let mut sink_seconds = 0.0;
    log::info!(
        "critical step estimate ({})",
        format!("{:?}", s.step_estimate).to_lowercase()
    );
    let (dt_crit, critical) = critical_step(model, s.step_estimate);
    check_critical_step(model, dt_crit)?;
    log::info!("critical step {dt_crit:.4e} s; time loop");
    let retries = if s.mode == Mode::Relaxation {
        s.retries
    } else {
        0
    };
    let mut factor = s.dt_factor;
    let mut restarts: Vec<String> = Vec::new();
    let mut failed_steps = 0;
    // Load fraction at each failure: a shorter step that fails at the same load points to
    // the load, the mesh or the material, not the step.
    let mut failed_at: Vec<f64> = Vec::new();
    loop {
        let mut reached = (0, 0.0);
        let clock = Clock {
            start,
            sink_seconds: &mut sink_seconds,
            reached: &mut reached,
        };
        let attempt = attempt(
            model,
            s,
            (dt_crit, critical),
            factor,
            clock,
            sink.as_deref_mut(),
            !restarts.is_empty(),
        );
        match attempt {
            Ok(mut out) => {
                out.restarts = restarts;
                out.failed_steps = failed_steps;
                return Ok(out);
            }
            Err(Error::Unstable(msg)) => {
                let (steps, load) = reached;
                let same_load = failed_at
                    .last()
                    .is_some_and(|&l| l >= MIN_LOAD && (l - load).abs() <= SAME_LOAD * l);
                failed_at.push(load);
                if restarts.len() >= retries || same_load {
                    if restarts.is_empty() {
                        return Err(Error::Unstable(msg));
                    }
                    let loads: Vec<String> = failed_at
                        .iter()
                        .map(|&l| {
                            if l <= 1.0 {
                                format!("{:.1} % of the load", 100.0 * l)
                            } else {
                                format!("{l:.3} x the load steps")
                            }
                        })
                        .collect();
                    let why = if same_load {
                        "; failing at the same point of the load path with a shorter step points \
                         to the load, the mesh or the material rather than the step, so no further \
                         restart"
                    } else {
                        "; raise solver.retries or start from a smaller solver.dt_factor"
                    };
                    return Err(Error::Unstable(format!(
                        "{msg} [after {} restart(s) with shorter steps, dt_factor {} -> {factor:.4}, \
                         the attempts failing at {}{why}]",
                        restarts.len(),
                        s.dt_factor,
                        loads.join(", ")
                    )));
                }
                let next = factor * RETRY_FACTOR;
                let how = if s.step_update {
                    ", estimating the step again as the body deforms"
                } else {
                    ""
                };
                // Said as it happens where progress is shown; the summary's warnings keep it.
                if s.progress || s.progress_lines.is_some() {
                    eprintln!(
                        "warning: relaxation unstable after {steps} steps at dt_factor {factor:.4}; \
                         restarting from the unloaded state at {next:.4}{how} (restart {} of at most {retries})",
                        restarts.len() + 1
                    );
                }
                restarts.push(format!(
                    "relaxation restarted from the unloaded state with solver.dt_factor = {next:.4}{how} \
                     (restart {} of at most {retries}, solver.retries) after {steps} steps at \
                     dt_factor = {factor:.4}: {msg}",
                    restarts.len() + 1
                ));
                failed_steps += steps;
                if let Some(c) = model.contact.as_mut() {
                    c.reset_statistics();
                }
                factor = next;
            }
            Err(e) => return Err(e),
        }
    }
}

/// The run's wall clock, the time spent in the frame sink (which solve_seconds leaves out),
/// and where an instability stopped the attempt (steps taken, load fraction reached).
struct Clock<'a> {
    start: Instant,
    sink_seconds: &'a mut f64,
    reached: &'a mut (usize, f64),
}

/// One pass of the time loop at `dt_factor` x the critical step `critical.0` (s). With
/// `restarted`, the frame of step 0 already went to the sink and is not sent again (it is the
/// same on every attempt: the prescribed state at load 0).
fn attempt<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    critical: (f64, Critical),
    dt_factor: f64,
    clock: Clock<'_>,
    mut sink: Option<&mut FrameSink<'_, M>>,
    restarted: bool,
) -> Result<RunOutput> {
    let Clock {
        start,
        sink_seconds,
        reached,
    } = clock;
    let (dt_crit, critical) = critical;
    let n = model.nodes.len();
    // The fastest wave bounds how far a node may move in one step.
    let c = fastest_wave(model);
    let dynamic = s.mode == Mode::Dynamic;
    // Added to the instability messages: the global estimate has the smaller margin.
    let hint = if matches!(critical, Critical::Global(_)) {
        " or set solver.time_step = \"bounds\" (1.3-2.5x shorter steps that keep more margin for deformation)"
    } else {
        ""
    };
    // Heavy damping holds the body back while a driven boundary moves on: the elements next
    // to it are crushed whatever the step (the [8,4,20] cylinder compressed in 0.15 s at
    // c = 1e5 1/s inverts with the step cut to 1/70 of the initial). Said where c T is large
    // enough for that to be a cause.
    let damping_hint = if dynamic && s.damping * s.load_time > 100.0 {
        format!(
            "; or lower solver.damping (c = {} 1/s, c x load time = {:.3e}): a boundary driven faster than \
             the damped body can follow crushes the elements next to it",
            s.damping,
            s.damping * s.load_time
        )
    } else {
        String::new()
    };
    let mut dt = dt_factor * dt_crit;
    let total_steps = if dynamic {
        let steps = (s.duration / dt).ceil().max(1.0);
        if !(steps <= MAX_DYNAMIC_STEPS || steps <= s.max_steps as f64) {
            return Err(Error::Input(format!(
                "the dynamic run needs {steps:.3e} steps (duration {:.4e} s / dt {dt:.4e} s), more than \
                 {MAX_DYNAMIC_STEPS:.0e}: check solver.duration, solver.dt_factor ({}) and the material's \
                 density, or set solver.max_steps to at least that many to run it anyway",
                s.duration, dt_factor
            )));
        }
        let k = steps as usize;
        dt = s.duration / k as f64;
        k
    } else {
        s.max_steps
    };
    check_contact_start(model, dt)?;
    let (lo, hi) = model.nodes.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(l, h), p| (l.inf(p), h.sup(p)),
    );
    let size = (hi - lo).norm();
    let load_steps = s.load_steps.unwrap_or_else(|| {
        // The slowest shear wave sets how fast the load may come.
        model
            .forces
            .materials
            .iter()
            .map(|m| auto_load_steps((hi - lo).max(), m.lame().1, m.density(), dt))
            .max()
            .unwrap_or(400)
    });
    // Dynamic: the load at time t (s); relaxation: at pseudo-step `step`, or once the step
    // has been shortened (`varied`), at the pseudo-time t in steps of the first length, so
    // that the load comes as fast in pseudo-time as planned.
    let dt0 = dt;
    let varied = std::cell::Cell::new(false);
    let load_frac = |step: usize, t: f64| -> f64 {
        if dynamic {
            if s.load_time > 0.0 {
                t / s.load_time
            } else {
                1.0
            }
        } else if load_steps > 0 {
            if varied.get() {
                t / dt0 / load_steps as f64
            } else {
                step as f64 / load_steps as f64
            }
        } else {
            1.0
        }
    };
    // An instability stops the attempt: where (steps, load fraction) goes to the restarts.
    let mut unstable = |step: usize, t: f64, msg: String| {
        *reached = (step, load_frac(step, t));
        Error::Unstable(msg)
    };

    let has_loads = !model.loads.is_empty();
    if has_loads && model.f_ext.len() != n {
        model.f_ext = vec![Vector3::zeros(); n];
    }
    let zero = vec![Vector3::zeros(); n];
    let mut u = zero.clone();
    let mut u_prev = zero.clone();
    let mut u_next = zero.clone();
    let mut f = zero.clone();
    let mut u_ref = zero.clone();
    let mut f_ref = zero.clone();
    let cons = model.constraints.clone();
    let cons = &cons;
    let prescribe = |target: &mut [Vector3<f64>], tau: f64| {
        for (k, &(node, comp)) in cons.dofs.iter().enumerate() {
            target[node as usize][comp as usize] = cons.amplitude[k] * cons.curve[k].value(tau);
        }
    };
    prescribe(&mut u, load_frac(0, 0.0));
    if let Some(corr) = model.corrector.as_mut() {
        // Only the displacements matter here; the constraint force is recomputed every step.
        corr.correct(&mut u, load_frac(0, 0.0), 1.0);
    }
    u_prev.copy_from_slice(&u);
    let rigid: Option<Vec<Vector3<f64>>> = s
        .initial_motion
        .map(|[v, w, c]| model.nodes.iter().map(|x| v + w.cross(&(x - c))).collect());
    let initial = s.initial_velocity.as_ref().or(rigid.as_ref());
    if let (true, Some(v0)) = (dynamic, initial) {
        if v0.len() != n {
            return Err(Error::Input(format!(
                "initial velocity has {} entries for {n} nodes",
                v0.len()
            )));
        }
        // Backward difference: u(-1) = u(0) - v0 dt on the free DOFs.
        for i in 0..n {
            for k in 0..3 {
                if !cons.mask[i][k] {
                    u_prev[i][k] = u[i][k] - v0[i][k] * dt;
                }
            }
        }
    }

    let (linear_start, angular_start) = momentum(&model.mass, &model.nodes, &u, &u_prev, dt);

    // More frames or rows than steps would only repeat them.
    let frames_wanted = s.frames.max(1).min(total_steps.max(1));
    let frame_steps: Vec<usize> = if dynamic {
        (0..=frames_wanted)
            .map(|k| (k * total_steps) / frames_wanted)
            .collect()
    } else {
        vec![0]
    };
    // The frames' times: a shortened step re-divides the rest of the run and moves the frames
    // still to come to the steps nearest these times.
    let frame_times: Vec<f64> = frame_steps.iter().map(|&k| k as f64 * dt).collect();
    let mut frame_steps = frame_steps;
    let frame_bytes = if sink.is_some() {
        0.0
    } else {
        (frame_steps.len() + 1) as f64 * n as f64 * 24.0
    };
    let mut history_every = if dynamic {
        (total_steps / s.history_rows.max(1)).max(1)
    } else {
        s.estimate_interval.max(1)
    };
    // Relaxation records a row per estimate and usually stops long before max_steps, so only
    // the dynamic history (a row count fixed in advance) is planned for.
    let rows = if dynamic {
        (total_steps / history_every + 2) as f64
    } else {
        0.0
    };
    let row_bytes = (std::mem::size_of::<HistoryRow>()
        + model.boundaries.len() * std::mem::size_of::<[f64; 3]>()
        + 16) as f64;
    let history_bytes = rows * row_bytes;
    let fix = if frame_bytes >= history_bytes {
        "lower output.frames"
    } else {
        "lower output.history_rows"
    };
    crate::memory::check(
        frame_bytes + history_bytes + model.solver_bytes() as f64,
        &format!(
            "the run ({} output frames of {n} nodes: {}; {rows:.0} history rows: {}; and the \
             model)",
            frame_steps.len(),
            crate::memory::size(frame_bytes),
            crate::memory::size(history_bytes)
        ),
        fix,
    )?;
    // Frame buffers are allocated here so that the loop only copies into them.
    let kept = if sink.is_some() {
        0
    } else {
        frame_steps.len() + usize::from(!dynamic)
    };
    let mut frame_bufs: Vec<Vec<Vector3<f64>>> = (0..kept).map(|_| zero.clone()).collect();
    let mut frames: Vec<(f64, Vec<Vector3<f64>>)> = Vec::with_capacity(frame_bufs.len());
    // A few rows more than planned: re-dividing the run after a shortened step rounds the
    // row spacing.
    let mut history = Vec::with_capacity(if dynamic {
        s.history_rows.min(total_steps) + 8
    } else {
        1024
    });
    let mut relaxation = Vec::new();

    let pb = if s.progress {
        let pb = ProgressBar::with_draw_target(
            Some(total_steps as u64),
            ProgressDrawTarget::stderr_with_hz(5),
        );
        let tmpl = if dynamic {
            "{bar:40} {pos}/{len} steps {elapsed} (eta {eta}) {msg}"
        } else {
            "{spinner} relaxation step {pos} {elapsed} {msg}"
        };
        pb.set_style(
            ProgressStyle::with_template(tmpl).unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        pb
    } else {
        ProgressBar::hidden()
    };

    let mut external_work = 0.0f64;
    let mut peak_external_work = 0.0f64;
    let mut damping_dissipation = 0.0f64;
    // Per node block, sum of m |u(n+1) - u(n-1)|^2 over free DOFs, summed in block order after
    // the parallel update (a sum across threads would depend on their count). The late nodes
    // are final only after their correction: their share of a step is summed in the next
    // step's parallel update, where u_next still holds u(n-1) until it is overwritten (a
    // serial pass after the correction cost the two-thread meshless cylinder 10 %: the second
    // worker falls asleep). `late_factor`: c / (2 (h + h_prev)) of the step whose late share
    // is pending.
    let damped = dynamic && s.damping > 0.0;
    let nblocks = if damped { n.div_ceil(NODE_BLOCK) } else { 0 };
    let mut damp_blocks = vec![0.0f64; nblocks];
    let mut damp_late_blocks = vec![0.0f64; nblocks];
    let mut late_factor: Option<f64> = None;
    let mut initial_kinetic = 0.0f64;
    // Dynamic relaxation state.
    let r_load = (1.0 - 10.0 / load_steps.max(20) as f64).clamp(0.5, 0.999);
    let mut r = r_load;
    let mut omega_prev: Option<f64> = None;
    let mut ref_step = usize::MAX;
    let mut below = 0usize;
    let mut converged = dynamic;
    let mut err_est = f64::INFINITY;
    let mut finish = false;
    let mut step = 0usize;
    let mut last_line = 0.0f64;
    let mut max_rate = c * dt;
    // Variable step (dynamic, after a shortened step): u holds the state at `time(step)`,
    // u_prev the one a step of dt_prev before; steps from `base.0` on are dt long.
    let mut total_steps = total_steps;
    let mut dt_prev = dt;
    let mut base = (0usize, 0.0f64);
    let time = |base: (usize, f64), dt: f64, step: usize| base.1 + (step - base.0) as f64 * dt;
    let mut crit_now = dt_crit;
    let mut history_base = 0usize;
    let mut updates = StepUpdates {
        dt_initial: dt,
        dt_min: dt,
        ..Default::default()
    };
    // Relaxation updates its step only after a restart: runs that converge at the first
    // attempt keep their fixed step (and their results).
    let mut lanczos = (s.step_update && (dynamic || restarted))
        .then(|| super::spectrum::Lanczos::new(model, LANCZOS_ITERATIONS));
    // Relaxation: the lowest frequency behind the rate in use (rad/s), to set the rate again
    // for a shorter step.
    let mut omega_in_use: Option<f64> = None;
    // The first estimate compares with the reference one where that was global.
    let mut schedule = UpdateSchedule::new(
        matches!(critical, Critical::Global(_))
            .then(|| (2.0 * DEFORMATION_ALLOWANCE / dt_crit).powi(2)),
    );
    // With a corrector, the nodes it moves and the prescribed ones change after the update:
    // their step change is measured after the correction (a short serial loop), every other
    // node's during the update. A parallel pass over all nodes after the correction cost as
    // much as the correction itself on two threads (the idle worker had gone to sleep).
    // Contact corrections move their nodes after the update too.
    let late: Vec<u32> = if model.corrector.is_some() || model.contact.is_some() {
        let mut l = model.corrected_nodes();
        l.extend(cons.dofs.iter().map(|&(node, _)| node));
        l.sort_unstable();
        l.dedup();
        l
    } else {
        Vec::new()
    };
    let mut is_late = vec![false; n];
    for &i in &late {
        is_late[i as usize] = true;
    }
    let is_late = &is_late;

    loop {
        let due = schedule.due(step, c * crit_now);
        if let Some((lz, by_travel)) = lanczos.as_mut().zip(due).filter(|_| step < total_steps) {
            let t_now = time(base, dt, step);
            let estimate = lz.estimate(model, Some(&u), UPDATE_TOLERANCE);
            schedule.record(step, estimate.map(|e| e.lambda_max), by_travel);
            if let Some(e) = estimate {
                updates.estimates += 1;
                updates.iterations += e.iterations;
                let crit = UPDATE_ALLOWANCE * e.critical_step();
                crit_now = crit;
                // Only ever shorter: lengthening it again after the peak of a compression let
                // fe hex8 at 80 % diverge while unloading (the step taken at 0.9 x an estimate
                // that the rebound outran).
                let target = dt_factor * crit;
                if target < dt * (1.0 - UPDATE_HYSTERESIS) {
                    if target < UPDATE_MIN_RATIO * updates.dt_initial {
                        return Err(unstable(step, t_now, format!(
                            "the critical step fell to {crit:.4e} s at step {step}, t = {t_now:.6} s, below {:.0} % of \
                             the initial step {:.4e} s: a point is collapsing under the load (the largest frequency \
                             has risen {:.0}x). Refine where the body is compressed most, use a slower load, or \
                             check the boundary conditions",
                            100.0 * UPDATE_MIN_RATIO, updates.dt_initial,
                            (dt_crit / DEFORMATION_ALLOWANCE / e.critical_step()).max(1.0)
                        )));
                    }
                    if dynamic {
                        let remaining = s.duration - t_now;
                        let k = (remaining / target).ceil().max(1.0);
                        if !(step as f64 + k <= MAX_DYNAMIC_STEPS
                            || step as f64 + k <= s.max_steps as f64)
                        {
                            return Err(unstable(step, t_now, format!(
                                "the critical step fell to {crit:.4e} s at step {step}, t = {t_now:.6} s, and the rest of \
                                 the run would need {k:.3e} more steps: use a slower load or a coarser mesh where \
                                 the body is compressed most, or set solver.max_steps to run it anyway"
                            )));
                        }
                        let k = k as usize;
                        let new_dt = remaining / k as f64;
                        for (fs, &ft) in frame_steps.iter_mut().zip(&frame_times) {
                            if *fs > step {
                                let r = ((ft - t_now) / new_dt).round().max(1.0) as usize;
                                *fs = step + r.min(k);
                            }
                        }
                        history_every =
                            ((history_every as f64 * dt / new_dt).round() as usize).max(1);
                        history_base = step;
                        total_steps = step + k;
                        pb.set_length(total_steps as u64);
                        dt = new_dt;
                    } else {
                        // Relaxation: no end to divide; the load follows pseudo-time, and the
                        // rate is set again for the new step.
                        varied.set(true);
                        dt = target;
                        if let Some(w) = omega_in_use {
                            r = rate_from_omega(w, dt);
                        }
                    }
                    base = (step, t_now);
                    max_rate = c * dt;
                    updates.reductions += 1;
                    updates.last_reduction_time = t_now;
                    updates.dt_min = updates.dt_min.min(dt);
                }
            }
        }
        let t = time(base, dt, step);
        // Point stage only: nodal forces are gathered in the update loop below (one pass over
        // the nodes instead of two), or here on the steps that record them first.
        model.forces.compute_points(&model.points, &model.slots, &u);
        let (min_j, p_min) = model.forces.min_j();
        if !(min_j > 0.0) {
            // Where: the centroid of the point's supporting nodes (reference configuration).
            let sl = model.points.slots(p_min);
            let near = sl
                .clone()
                .map(|k| model.nodes[model.points.nodes[k] as usize])
                .sum::<Vector3<f64>>()
                / sl.len().max(1) as f64;
            let id = model.point_ids[p_min];
            return Err(unstable(step, t, format!(
                "integration point {id} near ({:.4e}, {:.4e}, {:.4e}) m inverted (J = {min_j:.4}) at step {step}, t = {t:.6} s \
                 (dt = {dt:.4e} s, {:.3} x the critical estimate {dt_crit:.4e} s; one-point FE meshes number points as their elements). \
                 The load is too large or fast for this discretization, or the step too large: reduce solver.dt_factor \
                 (large compression shortens the elements below the estimate, {}){hint}, refine, or use a slower load{damping_hint}",
                near.x, near.y, near.z,
                dt / crit_now, estimated_at(updates.estimates, schedule.last), dt_crit = crit_now
            )));
        }
        if has_loads {
            model.loads.apply(&u, load_frac(step, t), &mut model.f_ext);
        }
        let at_end =
            (dynamic && step == total_steps) || finish || (!dynamic && step >= total_steps);
        let record = (step - history_base).is_multiple_of(history_every) || at_end;
        if record {
            model.forces.gather(&mut f);
            let se = model.forces.strain_energy(&model.points, &model.slots, &u);
            let ke = kinetic(&model.mass, &u, &u_prev, dt_prev);
            if step == 0 {
                initial_kinetic = ke;
            }
            if dynamic
                && step > 0
                && ke > 10.0 * (external_work.abs() + se + initial_kinetic) + 1e-12
            {
                return Err(unstable(step, t, format!(
                    "kinetic energy {ke:.4e} J exceeds ten times the work done on the body ({external_work:.4e} J) at step {step}, t = {t:.6} s: \
                     the integration is unstable with dt = {dt:.4e} s ({:.3} x the critical estimate {dt_crit:.4e} s); reduce solver.dt_factor{hint}",
                    dt / crit_now, dt_crit = crit_now
                )));
            }
            let reactions = model
                .reactions(&f)
                .iter()
                .map(|v| [v.x, v.y, v.z])
                .collect();
            history.push(HistoryRow {
                step,
                time: t,
                reactions,
                external_work,
                strain_energy: se,
                kinetic_energy: ke,
            });
        }
        if frame_steps.binary_search(&step).is_ok() && !(restarted && step == 0 && sink.is_some()) {
            if let Some(sink) = sink.as_mut() {
                let t0 = Instant::now();
                sink(model, t, &u)?;
                *sink_seconds += t0.elapsed().as_secs_f64();
            } else if let Some(mut buf) = frame_bufs.pop() {
                buf.copy_from_slice(&u);
                frames.push((t, buf));
            }
        }
        if at_end {
            if !dynamic && !finish {
                converged = false;
            }
            break;
        }

        // Update coefficients.
        let (a, b, cc) = if dynamic && dt == dt_prev {
            let h = 0.5 * s.damping * dt;
            (dt * dt / (1.0 + h), 2.0 / (1.0 + h), -(1.0 - h) / (1.0 + h))
        } else if dynamic {
            // Central differences with a step change: v(n+1/2) from v(n-1/2) over the mean of
            // the two steps, with the damping at that mean.
            let h_avg = 0.5 * (dt + dt_prev);
            let h = 0.5 * s.damping * h_avg;
            let q = dt / dt_prev * (1.0 - h) / (1.0 + h);
            (dt * h_avg / (1.0 + h), 1.0 + q, -q)
        } else {
            let a = 0.25 * ((1.0 + r) * dt).powi(2);
            (a, 1.0 + r * r, -r * r)
        };
        // Parallel over node blocks, from both ends as the point stage (`two_ended`); max is
        // order-independent, so the result is thread-count independent.
        let (mass, forces) = (&model.mass, &model.forces);
        let f_ext = has_loads.then_some(model.f_ext.as_slice());
        let (u_cur, u_old) = (&u, &u_prev);
        let un_all = SharedMut(u_next.as_mut_ptr());
        let f_all = SharedMut(f.as_mut_ptr());
        let damp_all = SharedMut(damp_blocks.as_mut_ptr());
        let damp_late_all = SharedMut(damp_late_blocks.as_mut_ptr());
        let late_pending = late_factor.is_some();
        let (mut max_du, mut max_u) = super::two_ended::for_each_item(
            n.div_ceil(NODE_BLOCK),
            (0.0f64, 0.0f64),
            |blk| {
                let n0 = blk * NODE_BLOCK;
                let len = NODE_BLOCK.min(n - n0);
                // SAFETY: u_next and f hold n vectors and are borrowed mutably for the loop;
                // block blk is nodes n0..n0 + len, which no other item touches.
                let (un_b, f_b) = unsafe {
                    (
                        std::slice::from_raw_parts_mut(un_all.get().add(n0), len),
                        std::slice::from_raw_parts_mut(f_all.get().add(n0), len),
                    )
                };
                if !record {
                    forces.node_forces(n0, f_b);
                }
                let mut acc = (0.0f64, 0.0f64);
                let (mut damp, mut damp_late) = (0.0f64, 0.0f64);
                for (j, (un, fi)) in un_b.iter_mut().zip(f_b.iter()).enumerate() {
                    let i = n0 + j;
                    if late_pending && is_late[i] {
                        // The last step's share: u_cur = u(n), un = u(n-2) before the write.
                        damp_late += mass[i] * free_dist2(cons.mask[i], &u_cur[i], un);
                    }
                    // The net force F_int - F_ext (bitwise F_int without loads).
                    let fi = match f_ext {
                        Some(e) => fi - e[i],
                        None => *fi,
                    };
                    let inv_m = a / mass[i];
                    let mask = cons.mask[i];
                    let mut mdu = 0.0f64;
                    for k in 0..3 {
                        if !mask[k] {
                            let v = -inv_m * fi[k] + b * u_cur[i][k] + cc * u_old[i][k];
                            un[k] = v;
                            mdu = nan_max(mdu, (v - u_cur[i][k]).abs());
                        }
                    }
                    if !is_late[i] {
                        acc = (
                            nan_max(acc.0, mdu),
                            nan_max(acc.1, nan_max(un.x.abs(), nan_max(un.y.abs(), un.z.abs()))),
                        );
                        if damped {
                            damp += mass[i] * free_dist2(mask, un, &u_old[i]);
                        }
                    }
                }
                if damped {
                    // SAFETY: both hold one slot per block; only block blk writes slot blk.
                    unsafe {
                        *damp_all.get().add(blk) = damp;
                        *damp_late_all.get().add(blk) = damp_late;
                    }
                }
                acc
            },
            |x, y| (nan_max(x.0, y.0), nan_max(x.1, y.1)),
        );
        let next_load = load_frac(step + 1, time(base, dt, step + 1));
        prescribe(&mut u_next, next_load);
        if let Some(corr) = model.corrector.as_mut() {
            corr.correct(&mut u_next, next_load, a);
            external_work += corr.work(&u_next, &u_prev);
        }
        if let Some(ct) = model.contact.as_mut() {
            ct.correct(&mut u_next, next_load, a, &model.mass, &cons.mask);
            external_work += ct.work(&u_next, &u_prev);
        }
        if !late.is_empty() {
            // The predictor's change includes the part the correction takes back (it never
            // vanishes next to a constrained boundary), so measure the corrected change.
            for &i in &late {
                let (a, b) = (u_next[i as usize], u[i as usize]);
                let d = a - b;
                max_du = nan_max(max_du, nan_max(d.x.abs(), nan_max(d.y.abs(), d.z.abs())));
                max_u = nan_max(max_u, nan_max(a.x.abs(), nan_max(a.y.abs(), a.z.abs())));
            }
        }
        if damped {
            // c m v(n) . (u(n+1) - u(n-1)) / 2 with v(n) = (u(n+1) - u(n-1)) / (h + h_prev):
            // this step's other nodes and the last step's late nodes.
            if let Some(fl) = late_factor {
                damping_dissipation += fl * damp_late_blocks.iter().sum::<f64>();
            }
            let factor = s.damping / (2.0 * (dt + dt_prev));
            damping_dissipation += factor * damp_blocks.iter().sum::<f64>();
            late_factor = (!late.is_empty()).then_some(factor);
        }
        // Work of the boundary forces: sum (F_int + M a) . (u(n+1) - u(n-1)) / 2 over constrained DOFs.
        for &(node, comp) in cons.dofs.iter() {
            let (i, k) = (node as usize, comp as usize);
            let inertia = if dynamic && dt == dt_prev {
                model.mass[i] * (u_next[i][k] - 2.0 * u[i][k] + u_prev[i][k]) / (dt * dt)
            } else if dynamic {
                let (vn, vp) = (
                    (u_next[i][k] - u[i][k]) / dt,
                    (u[i][k] - u_prev[i][k]) / dt_prev,
                );
                model.mass[i] * (vn - vp) / (0.5 * (dt + dt_prev))
            } else {
                0.0
            };
            external_work += (f[i][k] + inertia) * 0.5 * (u_next[i][k] - u_prev[i][k]);
        }
        // Work of the loads on the DOFs the integrator moves.
        if has_loads {
            for (i, fe) in model.f_ext.iter().enumerate() {
                for k in 0..3 {
                    if !cons.mask[i][k] {
                        external_work += fe[k] * 0.5 * (u_next[i][k] - u_prev[i][k]);
                    }
                }
            }
        }
        peak_external_work = peak_external_work.max(external_work.abs());
        for &(node, comp) in cons.dofs.iter() {
            max_u = nan_max(max_u, u_next[node as usize][comp as usize].abs());
        }
        if max_u.is_finite() && max_du.is_finite() && (max_u > 10.0 * size || max_du > max_rate) {
            // A body in fast rigid motion (a free body faster than its own waves, or carried
            // far) is not diverging: judge the step's change without its rigid part, and the
            // size by the deformed body's extent. Only here, so normal steps pay nothing.
            let (change, extent) = deformation_change(&model.mass, &model.nodes, &u, &u_next);
            max_du = change;
            if change <= max_rate && extent <= 10.0 * size {
                max_u = 0.0;
            }
        }
        if !max_u.is_finite() || !max_du.is_finite() || max_u > 10.0 * size || max_du > max_rate {
            return Err(unstable(step, t, format!(
                "the solution diverged at step {step}, t = {t:.6} s (largest displacement {max_u:.3e} m, largest change in one step {max_du:.3e} m): \
                 dt = {dt:.4e} s is {:.3} x the critical estimate {dt_crit:.4e} s ({}); reduce solver.dt_factor (default 0.9; \
                 the estimate holds for the body as it was when made, and large compression lowers the critical step){hint}",
                dt / crit_now, estimated_at(updates.estimates, schedule.last), dt_crit = crit_now
            )));
        }

        schedule.travel += max_du;
        if !dynamic && load_frac(step + 1, time(base, dt, step + 1)) >= 1.0 {
            if ref_step == usize::MAX {
                // Initial guess: Rayleigh quotient of the loaded shape over all DOFs.
                let num: f64 = u.iter().zip(&f).map(|(x, y)| x.dot(y)).sum();
                let den: f64 = u
                    .iter()
                    .zip(&model.mass)
                    .map(|(x, m)| m * x.norm_squared())
                    .sum();
                if num > 0.0 && den > 0.0 {
                    r = rate_from_omega((num / den).sqrt(), dt);
                    omega_in_use = Some((num / den).sqrt());
                }
                u_ref.copy_from_slice(&u);
                f_ref.copy_from_slice(&f);
                ref_step = step;
            } else if step >= ref_step + s.estimate_interval.max(1) {
                // w_min^2 = du.dF / du.M.du over free DOFs against the saved reference.
                let (mut num, mut den) = (0.0, 0.0);
                for i in 0..n {
                    for k in 0..3 {
                        if !cons.mask[i][k] {
                            let du = u[i][k] - u_ref[i][k];
                            num += du * (f[i][k] - f_ref[i][k]);
                            den += model.mass[i] * du * du;
                        }
                    }
                }
                if num > 0.0 && den > 0.0 {
                    let omega = (num / den).sqrt();
                    let accepted = omega_prev.is_some_and(|w| (omega - w).abs() <= 0.05 * omega);
                    if accepted {
                        r = rate_from_omega(omega, dt);
                        omega_in_use = Some(omega);
                    }
                    omega_prev = Some(omega);
                    let rp = r + 0.2 * (1.0 - r);
                    relaxation.push(RelaxationRecord {
                        step,
                        omega_min: omega,
                        r,
                        accepted,
                        error_estimate: max_du * rp / (1.0 - rp),
                    });
                }
                u_ref.copy_from_slice(&u);
                f_ref.copy_from_slice(&f);
                ref_step = step;
            }
            let rp = r + 0.2 * (1.0 - r);
            err_est = max_du * rp / (1.0 - rp);
            if err_est < s.tolerance {
                below += 1;
                if below >= 100 {
                    finish = true;
                    converged = true;
                }
            } else {
                below = 0;
            }
        }

        std::mem::swap(&mut u_prev, &mut u);
        std::mem::swap(&mut u, &mut u_next);
        dt_prev = dt;
        step += 1;
        if step.is_multiple_of(64) {
            pb.set_position(step as u64);
            if !dynamic && s.progress {
                pb.set_message(format!("error estimate {err_est:.2e} m, r = {r:.5}"));
            }
            if let Some(every) = s.progress_lines {
                let elapsed = start.elapsed().as_secs_f64();
                if elapsed >= last_line + every {
                    last_line = elapsed;
                    let t = time(base, dt, step);
                    if dynamic {
                        let eta = elapsed * (total_steps.saturating_sub(step)) as f64 / step as f64;
                        eprintln!(
                            "progress: step {step} of {total_steps} ({:.1} %), t = {t:.4e} s, {elapsed:.0} s elapsed, about {eta:.0} s left",
                            100.0 * step as f64 / total_steps as f64
                        );
                    } else {
                        let est = if err_est.is_finite() {
                            format!("error estimate {err_est:.2e} m")
                        } else {
                            "no error estimate yet".into()
                        };
                        eprintln!(
                            "progress: relaxation step {step} (load {:.0} %), {est} (tolerance {:.1e} m), {elapsed:.0} s elapsed",
                            100.0 * load_frac(step, t).min(1.0),
                            s.tolerance
                        );
                    }
                }
            }
        }
    }
    pb.finish_and_clear();
    if let Some(fl) = late_factor {
        // The last update's late share: u = u(N), u_next = u(N-2) after the final swap.
        let m_d2: f64 = late
            .iter()
            .map(|&i| i as usize)
            .map(|i| model.mass[i] * free_dist2(cons.mask[i], &u[i], &u_next[i]))
            .sum();
        damping_dissipation += fl * m_d2;
    }
    let solve_seconds = start.elapsed().as_secs_f64() - *sink_seconds;
    if !dynamic {
        if let Some(sink) = sink.as_mut() {
            sink(model, step as f64 * dt, &u)?;
        } else {
            let mut buf = frame_bufs.pop().unwrap_or_else(|| zero.clone());
            buf.copy_from_slice(&u);
            frames.push((step as f64 * dt, buf));
        }
    }
    let last = history.last().cloned();
    let (strain_energy, kinetic_energy) = last
        .map(|h| (h.strain_energy, h.kinetic_energy))
        .unwrap_or((0.0, 0.0));
    let (linear_end, angular_end) = momentum(&model.mass, &model.nodes, &u, &u_prev, dt_prev);
    Ok(RunOutput {
        momentum: Momentum {
            linear_start,
            linear_end,
            angular_start,
            angular_end,
        },
        u,
        u_prev,
        f_int: f,
        dt,
        dt_critical: dt_crit,
        critical,
        steps: step,
        load_steps: (!dynamic).then_some(load_steps),
        simulated_time: time(base, dt, step),
        converged,
        history,
        relaxation,
        frames,
        external_work,
        peak_external_work,
        initial_kinetic,
        damping_dissipation,
        strain_energy,
        kinetic_energy,
        solve_seconds,
        restarts: Vec::new(),
        failed_steps: 0,
        step_updates: updates,
    })
}

/// Runs `f` on this thread while, with more than one thread in the pool, another worker
/// spins until it returns. A worker idle for a few tens of microseconds goes to sleep, and
/// waking it costs about as much again on a virtual machine: serial parts of a step as long
/// as the SEBCIEM solve (about 50 us on the meshless cylinder) otherwise made the next
/// parallel loop wait for its second thread. [`super::Corrector::correct`] runs its serial
/// parts through this.
pub fn keep_warm<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    if rayon::current_num_threads() < 2 {
        return f();
    }
    let done = AtomicBool::new(false);
    let (r, ()) = rayon::join(
        || {
            let r = f();
            done.store(true, Ordering::Release);
            r
        },
        // Popped by this thread itself when no worker took it: `done` is then already set.
        || {
            while !done.load(Ordering::Acquire) {
                std::hint::spin_loop();
            }
        },
    );
    r
}

/// Where the critical step in an instability message was estimated: the reference state, or
/// the deformed state at a step ([`Settings::step_update`]).
fn estimated_at(estimates: usize, step: usize) -> String {
    if estimates > 0 {
        format!("made at step {step}")
    } else {
        "made at the reference state".into()
    }
}

/// The largest component of one step's displacement change `u_next - u` (m) left after
/// removing its mass-weighted best-fit rigid motion (translation a and small rotation theta
/// about the centre of mass of the current positions: I theta = sum m r x (du - a)), and the
/// diagonal of the deformed body's bounding box (m). Serial and in node order: it runs only
/// on steps the quick divergence test flags.
fn deformation_change(
    mass: &[f64],
    nodes: &[Vector3<f64>],
    u: &[Vector3<f64>],
    u_next: &[Vector3<f64>],
) -> (f64, f64) {
    let (mut m_sum, mut mx, mut mdu) = (0.0, Vector3::zeros(), Vector3::zeros());
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for i in 0..nodes.len() {
        let x = nodes[i] + u[i];
        m_sum += mass[i];
        mx += x * mass[i];
        mdu += (u_next[i] - u[i]) * mass[i];
        let y = nodes[i] + u_next[i];
        lo = lo.inf(&y);
        hi = hi.sup(&y);
    }
    let (c, a) = (mx / m_sum, mdu / m_sum);
    let (mut inertia, mut l) = (nalgebra::Matrix3::zeros(), Vector3::zeros());
    for i in 0..nodes.len() {
        let r = nodes[i] + u[i] - c;
        inertia += (nalgebra::Matrix3::identity() * r.norm_squared() - r * r.transpose()) * mass[i];
        l += r.cross(&(u_next[i] - u[i] - a)) * mass[i];
    }
    let theta = inertia
        .try_inverse()
        .map_or(Vector3::zeros(), |inv| inv * l);
    let mut change = 0.0f64;
    for i in 0..nodes.len() {
        let r = nodes[i] + u[i] - c;
        let d = u_next[i] - u[i] - a - theta.cross(&r);
        change = nan_max(change, d.amax());
    }
    (change, (hi - lo).norm())
}

/// max that propagates NaN (f64::max drops it), so divergence cannot hide.
#[inline]
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// Kinetic energy with the backward-difference velocity (u(n) - u(n-1)) / dt, J. Fixed-order sum.
fn kinetic(mass: &[f64], u: &[Vector3<f64>], u_prev: &[Vector3<f64>], dt: f64) -> f64 {
    mass.iter()
        .zip(u.iter().zip(u_prev))
        .map(|(m, (a, b))| 0.5 * m * ((a - b) / dt).norm_squared())
        .sum()
}
