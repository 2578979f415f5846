//! Time loops: explicit central differences (dynamics) and adaptive dynamic relaxation
//! (Joldes, Wittek & Miller 2011) written as one update
//! u(n+1) = A M^-1 (F_ext - F_int) + B u(n) + C u(n-1), with displacement conditions enforced
//! at the end of each step.

mod attempt;
pub(in crate::solver) use attempt::contact_conflict;
mod energy;
mod predict;
mod record;
mod relaxation;
mod schedule;
mod timeline;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::timestep::critical_time_step;
use super::Model;
use crate::material::Material;
use crate::{Error, InputKind, Result};
use attempt::{attempt, Clock};
pub use schedule::UPDATE_ALLOWANCE;

/// Which problem the loop solves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Explicit dynamics over `duration` seconds.
    #[default]
    Dynamic,
    /// Steady state by adaptive dynamic relaxation.
    Relaxation,
    /// Steady state by Newton's method with load steps ([`crate::solver::statics`]).
    Static,
}

impl Mode {
    /// A steady-state mode (relaxation or static): no physical time, loads reach their final
    /// values and the body settles.
    pub fn is_steady(self) -> bool {
        matches!(self, Mode::Relaxation | Mode::Static)
    }
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
    /// runs and mass-scaled relaxation ([`crate::solver::Model::scale_masses`]) from the
    /// start (tet10 at the driven rim of the indentation benchmark inverted at 0.9 x the
    /// reference estimate and restarted every time before), relaxation with physical masses in
    /// the attempts after a restart. See [`StepUpdates`].
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
    /// Where the time loop runs.
    pub device: Device,
    /// Relaxation: load fractions in (0, 1), ascending, at which the load stops rising until
    /// the relaxation has converged there (a load stage: its state is kept in
    /// [`RunOutput::stages`]), then goes on.
    pub stages: Vec<f64>,
    /// Relaxation: start from this state (a previous run's equilibrium, [`RunOutput::warm_start`])
    /// instead of the unloaded body, with every load, prescribed value and rigid-body position
    /// at its final value from the first step. A re-solve after a small change of the inputs
    /// then has only the change to relax. None (the default): from the unloaded state, the
    /// load coming on over `load_steps`.
    pub warm_start: Option<WarmStart>,
    /// Static: how each Newton iteration solves its linear system.
    pub static_variant: crate::solver::statics::Variant,
    /// Static, where rigid contact holds a body that no rigid body moves and the load has no
    /// stages: relax first to [`RELAXED_START_SHARE`] x `tolerance`, then solve statically
    /// from there (see [`relaxed_start_applies`]). Relaxation finds which points rest on a
    /// surface; Newton's iterations from the unloaded state swing the body across it (the
    /// MNI brain: 41 s statically from the unloaded state, 6.8 s of relaxation then 5-6 s
    /// of Newton, against 16 s of relaxation to the tolerance).
    pub relaxed_start: bool,
    /// Static, where the load steps stop short of the full load after every stage
    /// (repeated cuts where Newton's directions do not descend: the benchmark's c5 at 94.5 %,
    /// a graded rim at 76 %, points there at J = 0.002-0.06): relax from the unloaded state
    /// instead, the static solve's stages kept (see [`relaxation_fallback_applies`]); a
    /// relaxation that inverts a point and restarts, or fails, is not taken. False: the run
    /// stops at the last equilibrium (exit 4).
    pub relaxation_fallback: bool,
    /// Static: the model will be solved again from this equilibrium (a
    /// [`crate::simulation::Session`]): where the kept factor stopped contracting in the last
    /// load step, it is made again at the equilibrium, so that the next warm solve's
    /// modified-Newton steps start from the tangent there.
    pub refresh_factor: bool,
}

/// Where a warm-started relaxation begins ([`Settings::warm_start`]).
#[derive(Debug, Clone, PartialEq)]
pub struct WarmStart {
    /// Displacements (nodal parameters) to start from, m, one per node.
    pub u: Vec<Vector3<f64>>,
    /// The lowest circular frequency the previous relaxation settled on, rad/s: the
    /// convergence rate starts from it instead of from a first estimate.
    pub omega_min: Option<f64>,
}

/// Where the time loop runs ([`Settings::device`]; scene `solver.device`, CLI `--device`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Device {
    /// The CPU threads (rayon).
    #[default]
    Cpu,
    /// NVIDIA GPU 0 ([`crate::solver::gpu`]).
    Gpu,
    /// The GPU kernels compiled for the CPU by g++ ([`crate::solver::gpu::emulate`]): for
    /// tests and debugging on machines without a GPU; slow.
    Emulated,
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
            device: Device::Cpu,
            stages: Vec::new(),
            warm_start: None,
            static_variant: Default::default(),
            relaxed_start: true,
            relaxation_fallback: true,
            refresh_factor: false,
        }
    }
}

/// One row of the time history.
#[derive(Debug, Clone, Serialize, Deserialize)]
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

/// The converged state of a relaxation at one of [`Settings::stages`].
#[derive(Debug, Clone)]
pub struct Stage {
    /// The load fraction held.
    pub load: f64,
    /// The step at which the relaxation converged there.
    pub step: usize,
    /// The reactions then ([`Model::reactions`]: the boundaries, then the rigid bodies), N.
    pub reactions: Vec<[f64; 3]>,
    /// Displacements (nodal parameters) then, m.
    pub u: Vec<Vector3<f64>>,
}

/// One record of the dynamic-relaxation parameters.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    /// Where the time loop ran: "cpu", or the GPU's name.
    pub device: String,
    /// Of `solve_seconds`: setting the device up (compiling its kernels, copying the model), s.
    pub device_setup_seconds: f64,
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
    /// What the time loop noticed that does not stop it (a contact that keeps changing while
    /// the relaxation does not settle); the summary's warnings carry them.
    pub notes: Vec<String>,
    /// Relaxation: steps taken by the attempts that a restart abandoned (their time is in
    /// `solve_seconds`).
    pub failed_steps: usize,
    /// The estimates of the critical step at the deformed state and what they did.
    pub step_updates: StepUpdates,
    /// Relaxation: the converged states at [`Settings::stages`], in load order.
    pub stages: Vec<Stage>,
    /// The largest nodal force component (internal forces) at any recorded row, N: the
    /// scale of the equilibrium residual of a run whose load ends at zero.
    pub peak_nodal_force: f64,
    /// Every evaluation of the internal forces, a tangent assembly and a product with the
    /// tangent counting one each (relaxation: its steps, restarts' steps and the Lanczos
    /// iterations of the step estimates).
    pub force_evaluations: usize,
    /// Static: what the Newton solve did (None in the other modes).
    pub statics: Option<crate::solver::statics::StaticReport>,
}

impl RunOutput {
    /// The state a later relaxation of the same model may start from ([`Settings::warm_start`]):
    /// the final displacements and the last accepted estimate of the lowest frequency.
    pub fn warm_start(&self) -> WarmStart {
        WarmStart {
            u: self.u.clone(),
            omega_min: self
                .relaxation
                .iter()
                .rev()
                .find(|r| r.accepted)
                .map(|r| r.omega_min),
        }
    }
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

/// The bound that sets the critical step (see [`super::timestep`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, Deserialize)]
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
    if model.masses_uneven {
        // The per-point bounds (and the tet4-anp bound's deviatoric part) assume each point's
        // mass split evenly over its nodes; the nodal bound holds for any masses.
        let (dt, node) = super::timestep::nodal_time_step(
            &model.points,
            &model.slots,
            &model.mass,
            &model.constraints.mask,
            &moduli,
        );
        return (dt, Critical::Node(node));
    }
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
        return Err(Error::input(InputKind::Value, format!(
            "every degree of freedom of the {} nodes is prescribed by the boundaries ({}): no node is free to move, \
             so there is nothing to solve; refine the discretization (divisions, size) so that nodes lie between \
             the constrained ones, or constrain fewer components",
            model.nodes.len(),
            names.join(", ")
        )));
    }
    // Moduli or a density far out of range (E = 1e308 Pa, density = 1e-300 kg/m^3) make the
    // wave speed overflow, or the step underflow, before anything else goes wrong.
    let c = fastest_wave(model);
    if !(c.is_finite() && c > 0.0 && c < 1e8) {
        return Err(Error::input(InputKind::Value, format!(
            "the critical time step estimate is {sci_dt:.3e} s: the fastest dilatational wave speed of \
             the materials, sqrt((lambda + 2 mu) / density), is {sci_c:.3e} m/s; check the moduli (Pa) \
             and the density (kg/m^3) of [material] and [regions] (soft tissue: about 1e3-1e5 Pa, \
             1000 kg/m^3)", sci_dt = crate::error::Sci(dt), sci_c = crate::error::Sci(c))));
    }
    Err(Error::input(InputKind::Value, format!(
        "the critical time step estimate is {sci_dt:.3e} s (fastest wave speed {sci_c:.4e} m/s); the \
         discretization has no usable points", sci_dt = crate::error::Sci(dt), sci_c = crate::error::Sci(c))))
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
            return Err(Error::input(InputKind::Value, format!(
            "contact '{name}' starts {sci_depth:.3e} m inside the body (surface point at ({:.4e}, {:.4e}, {:.4e}) m), \
             deeper than the {:.3e} m a wave crosses in half a step, so the first correction cannot push the \
             surface out without tearing it: start the rigid body outside or touching the body (move it by at \
             least {sci_depth:.3e} m)",
            crate::error::Sci(x.x),
            crate::error::Sci(x.y),
            crate::error::Sci(x.z),
            crate::error::Sci(0.5 * c * dt), sci_depth = crate::error::Sci(depth))));
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

/// Lanczos iterations at most for the global estimate, and its stopping tolerance on the
/// Ritz residual (relative).
const LANCZOS_ITERATIONS: usize = 60;
const LANCZOS_TOLERANCE: f64 = 1e-3;
/// The global estimate's step is this fraction of 2 / omega_max(K_0): the reference
/// stiffness does not see how deformation raises the frequencies. Measured on the 4,208-node
/// Gmsh cylinder, tet4-anp, 20 % extension (relaxation): stable at 0.79 and divergent at 0.83
/// x the reference critical step; compression and the meshless and coupled runs tolerate more.
pub const DEFORMATION_ALLOWANCE: f64 = 0.8;

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
    if how == StepEstimate::Bounds || (all_anp(model) && !model.mass_scaled) {
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
    model.apply_boundary_changes()?;
    if s.mode == Mode::Static {
        if s.device != Device::Cpu {
            return Err(Error::input(
                InputKind::Unsupported,
                "solver.mode = \"static\" runs on the CPU; the GPU runs relaxation and dynamics \
                 (set solver.mode = \"relaxation\" for the GPU, or solver.device = \"cpu\")",
            ));
        }
        let mut sink = sink;
        let (pre, gave_up) = if relaxed_start_applies(model, s) {
            match relax_to_start(model, s, &mut sink)? {
                Ok(p) => (Some(p), None),
                Err(why) => (None, Some(why)),
            }
        } else {
            (None, None)
        };
        let warmed;
        let s = match &pre {
            Some(p) => {
                warmed = Settings {
                    warm_start: Some(p.warm_start()),
                    ..s.clone()
                };
                &warmed
            }
            None => s,
        };
        // The relaxed start handed the unloaded state to the sink: a warm step that fails goes
        // back to it and would hand it again.
        let mut once;
        let static_sink: Option<&mut FrameSink<'_, M>> = match sink {
            Some(inner) if pre.is_some() => {
                once = move |m: &mut Model<M>, t: f64, u: &[Vector3<f64>]| {
                    if t == 0.0 {
                        Ok(())
                    } else {
                        inner(m, t, u)
                    }
                };
                Some(&mut once)
            }
            // Reborrowed as a sink of the shorter lifetime the arm above has.
            Some(inner) => {
                let shorter: &mut FrameSink<'_, M> = inner;
                Some(shorter)
            }
            None => None,
        };
        let mut static_sink = static_sink;
        let mut cache = model.static_cache.take();
        let out =
            on_a_worker(|| super::statics::solve(model, s, static_sink.as_deref_mut(), &mut cache));
        let out = match out {
            Ok(mut out) => match out.statics.as_mut().and_then(|st| st.stop.take()) {
                Some(why) if relaxation_fallback_applies(s, &out) => {
                    // The factor is of the state the load steps stopped at: its memory (1.8 GB
                    // on the benchmark's c5) is not held through the relaxation.
                    cache = None;
                    relax_instead(model, s, out, why, static_sink.as_deref_mut())
                }
                Some(why) => {
                    out.notes.push(why);
                    Ok(out)
                }
                None => Ok(out),
            },
            Err(e) => Err(e),
        };
        model.static_cache = cache;
        let mut out = out?;
        if let Some(p) = pre {
            out.force_evaluations += p.force_evaluations;
            // The static solve's work runs from the relaxed state on; the relaxation's up to it.
            // Not where the static solve went back to the unloaded state, or fell back to a
            // relaxation from there: their work runs from it.
            if out
                .statics
                .as_ref()
                .is_some_and(|st| !st.from_unloaded && st.fallback_from.is_none())
            {
                out.external_work += p.external_work;
            }
            out.peak_external_work = out.peak_external_work.max(p.peak_external_work);
            out.solve_seconds += p.solve_seconds;
            let mut frames = p.frames;
            frames.truncate(1);
            // As the streamed frames above: the unloaded state is the relaxation's.
            frames.extend(out.frames.drain(..).filter(|f| f.0 != 0.0));
            out.frames = frames;
            if let Some(st) = out.statics.as_mut() {
                st.relaxed_start_steps = p.steps + p.failed_steps;
                st.relaxed_start_seconds = p.solve_seconds;
            }
            out.notes.extend(p.notes);
            out.restarts.extend(p.restarts);
        }
        out.notes.extend(gave_up);
        // A tool that passed between the surface's nodes presses nothing and "converges" with
        // no force, statically as in relaxation (a 20 mm ball driven 100 mm through the cube).
        let full = out.statics.as_ref().is_none_or(|st| st.load_reached >= 1.0);
        if let (Some(c), true) = (model.contact.as_ref(), full) {
            c.check_tunnelled(&out.u)?;
        }
        return Ok(out);
    }
    on_a_worker(|| run_on_worker(model, s, sink))
}

/// Runs `f` on a worker of the current rayon pool (the global one when called from outside a
/// pool), so that its parallel loops fork through the worker's own queue ([`run`]).
fn on_a_worker<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    if rayon::current_thread_index().is_some() {
        f()
    } else {
        rayon::scope(|_| f())
    }
}

/// The fallback to relaxation ([`Settings::relaxation_fallback`]) applies where the load steps
/// stopped short of the full load after every stage, on the CPU (the stages' states come from
/// the load steps).
pub fn relaxation_fallback_applies(s: &Settings, out: &RunOutput) -> bool {
    let stages = s.stages.iter().filter(|&&l| l > 0.0 && l < 1.0).count();
    s.mode == Mode::Static
        && s.relaxation_fallback
        && s.device == Device::Cpu
        && !out.converged
        && out.stages.len() == stages
}

/// The fallback to relaxation: where the load steps of `stopped` stopped short of the full
/// load (`why`), relaxation from the unloaded state to the run's tolerance, with no stage to
/// stop at. A relaxation that is unstable, or restarts after an instability, leaves `stopped`
/// as the output, with notes that say so. Otherwise the output is
/// the relaxation's, with `stopped`'s stages (converged static states) and frames, its
/// static report (with the fallback's steps and time) and the force evaluations and time of
/// both. The relaxation's frames are not handed on: the static solve handed the unloaded
/// state and the stages; the relaxation's end goes to `sink` as the full load (t = 1).
fn relax_instead<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    mut stopped: RunOutput,
    why: String,
    sink: Option<&mut FrameSink<'_, M>>,
) -> Result<RunOutput> {
    let reached = stopped.statics.as_ref().map_or(0.0, |st| st.load_reached);
    // The stages are the static solve's: the relaxation does not stop at them (the
    // benchmark's c5 converges at each of its four in relaxation).
    let relax = Settings {
        mode: Mode::Relaxation,
        warm_start: None,
        stages: Vec::new(),
        ..s.clone()
    };
    let said = format!(
        "static solve: the load steps stopped at {:.4} % of the load; relaxing from the \
         unloaded state instead (solver.relaxation_fallback)",
        100.0 * reached
    );
    log::info!("{said}");
    if s.progress || s.progress_lines.is_some() {
        eprintln!("{said}");
    }
    let mut none = |_: &mut Model<M>, _: f64, _: &[Vector3<f64>]| Ok(());
    let streaming = sink.is_some();
    let relaxed = on_a_worker(|| {
        if streaming {
            run_on_worker(model, &relax, Some(&mut none))
        } else {
            run_on_worker(model, &relax, None)
        }
    });
    // A relaxation that inverted a point on its way and restarted is not taken: the cube
    // pressed 120 mm through its 100 mm height "converged" so, after one restart, to a
    // tangled mesh whose one-point hexahedra keep J > 0; the static solve's stop is the better
    // answer there (the 0.6 mm rim and c5 relax without a restart).
    let refused = match &relaxed {
        Ok(r) if !r.restarts.is_empty() => Some(format!(
            "inverted a point and restarted ({}); its answer is not taken (the load may exceed \
             what the mesh and the material hold); solver.mode = \"relaxation\" gives it",
            r.restarts.join("; ")
        )),
        Err(Error::Unstable(msg)) => Some(format!("was unstable ({msg})")),
        _ => None,
    };
    if let Some(how) = refused {
        stopped.notes.push(why);
        stopped.notes.push(format!(
            "static solve: the relaxation it fell back to (solver.relaxation_fallback) {how}; \
             the result is the static solve's last equilibrium"
        ));
        return Ok(stopped);
    }
    let mut r = relaxed?;
    if let Some(sink) = sink {
        sink(model, 1.0, &r.u)?;
    }
    let mut notes = std::mem::take(&mut stopped.notes);
    notes.push(format!(
        "{}; relaxed from the unloaded state instead ({} steps, {:.2} s, \
         solver.relaxation_fallback): the result is relaxation's, the stages the static solve's",
        why.split(", written as the result").next().unwrap_or(&why),
        r.steps + r.failed_steps,
        r.solve_seconds
    ));
    if !r.converged {
        notes.push(format!(
            "static solve: the relaxation it fell back to (solver.relaxation_fallback) did not \
             converge in {} steps (solver.max_steps)",
            r.steps
        ));
    }
    notes.extend(std::mem::take(&mut r.notes));
    r.notes = notes;
    let end = r.frames.pop();
    let mut frames = std::mem::take(&mut stopped.frames);
    if let Some((_, u)) = end {
        frames.push((1.0, u));
    }
    r.frames = frames;
    r.stages = stopped.stages;
    r.force_evaluations += stopped.force_evaluations;
    r.peak_nodal_force = r.peak_nodal_force.max(stopped.peak_nodal_force);
    if let Some(mut st) = stopped.statics.take() {
        st.fallback_from = Some(reached);
        st.fallback_steps = r.steps + r.failed_steps;
        st.fallback_seconds = r.solve_seconds;
        r.statics = Some(st);
    }
    // Both parts' solve times; the sink's time above is left out, as in the runs themselves.
    r.solve_seconds += stopped.solve_seconds;
    Ok(r)
}

/// The relaxed start's tolerance over the run's ([`Settings::relaxed_start`]): the MNI
/// brain's Newton polish took 50 iterations (6.1 s) from a relaxation to 100 x and 45 (4.9
/// s) from 30 x, the relaxations 6.8 and 8.1 s.
pub const RELAXED_START_SHARE: f64 = 100.0;

/// A static solve starts from a loose relaxation ([`Settings::relaxed_start`]) where it is
/// on, on the CPU, from the unloaded state, with rigid contact whose bodies all stay where
/// they are, and without load stages (a warm start has no intermediate states to give them).
pub fn relaxed_start_applies<M: Material>(model: &Model<M>, s: &Settings) -> bool {
    s.mode == Mode::Static
        && s.relaxed_start
        && s.warm_start.is_none()
        && s.device == Device::Cpu
        && s.stages.iter().all(|&l| !(l > 0.0 && l < 1.0))
        && model
            .contact
            .as_ref()
            .is_some_and(|c| c.motion_curves().next().is_none())
}

/// The relaxed start: relaxation to [`RELAXED_START_SHARE`] x the tolerance from the unloaded
/// state, its first frame (the unloaded state) handed to `sink`. Where the relaxation does not
/// converge or is unstable, the note that says so (the static solve then starts from the
/// unloaded state, as without it).
fn relax_to_start<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    sink: &mut Option<&mut FrameSink<'_, M>>,
) -> Result<std::result::Result<RunOutput, String>> {
    let loose = Settings {
        mode: Mode::Relaxation,
        tolerance: s.tolerance * RELAXED_START_SHARE,
        frames: 2,
        history_rows: 0,
        ..s.clone()
    };
    log::info!(
        "static solve: relaxing to {:.1e} m first (contact at rest)",
        loose.tolerance
    );
    let out = on_a_worker(|| run_on_worker(model, &loose, None));
    let why = match out {
        Ok(mut o) if o.converged => {
            if let (Some(sink), Some((t, u))) = (sink.as_mut(), o.frames.first()) {
                sink(model, *t, u)?;
                o.frames.clear();
            }
            return Ok(Ok(o));
        }
        Ok(o) => format!("it did not converge in {} steps", o.steps),
        Err(Error::Unstable(msg)) => format!("it was unstable ({msg})"),
        Err(e) => return Err(e),
    };
    if let Some(c) = model.contact.as_mut() {
        c.reset_statistics();
    }
    Ok(Err(format!(
        "static solve: the relaxed start (relaxation to {:.1e} m, solver.relaxed_start) was \
         given up, {why}; solved from the unloaded state (its steps are not counted in the \
         force evaluations)",
        loose.tolerance
    )))
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
    let t_setup = Instant::now();
    let mut gpu = match s.device {
        Device::Cpu => None,
        Device::Gpu | Device::Emulated => {
            let tables = crate::solver::gpu::Tables::new(model, &model.constraints)?;
            let backend = if s.device == Device::Gpu {
                crate::solver::gpu::cuda()?
            } else {
                Box::new(crate::solver::gpu::emulate::Emulator::new()?)
            };
            let r = crate::solver::gpu::Resident::new(backend, &tables)?;
            log::info!("time loop on {}", r.describe());
            Some(r)
        }
    };
    let device_setup_seconds = t_setup.elapsed().as_secs_f64();
    let device = gpu
        .as_ref()
        .map_or_else(|| "cpu".to_string(), |g| g.describe());
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
            gpu: gpu.as_mut(),
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
                if let Some(c) = model.contact.as_ref() {
                    c.check_tunnelled(&out.u)?;
                }
                out.device = device;
                out.device_setup_seconds = device_setup_seconds;
                out.restarts = restarts;
                out.failed_steps = failed_steps;
                out.force_evaluations = out.steps
                    + failed_steps
                    + out.step_updates.iterations
                    + match critical {
                        Critical::Global(k) => k,
                        _ => 0,
                    };
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
                let from = if s.warm_start.is_some() {
                    "the warm start's state"
                } else {
                    "the unloaded state"
                };
                let how = if s.step_update {
                    ", estimating the step again as the body deforms"
                } else {
                    ""
                };
                // Said as it happens where progress is shown; the summary's warnings keep it.
                if s.progress || s.progress_lines.is_some() {
                    eprintln!(
                        "warning: relaxation unstable after {steps} steps at dt_factor {factor:.4}; \
                         restarting from {from} at {next:.4}{how} (restart {} of at most {retries})",
                        restarts.len() + 1
                    );
                }
                restarts.push(format!(
                    "relaxation restarted from {from} with solver.dt_factor = {next:.4}{how} \
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
