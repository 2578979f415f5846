//! One pass of the time loop from the unloaded state at a fixed dt_factor (the caller,
//! [`super::run`], restarts relaxation with a shorter step after an instability).

use std::time::Instant;

use nalgebra::Vector3;

use super::energy::{free_dist2, kinetic, momentum, Ledger};
use super::predict::{nan_max, Predictor};
use super::record::{Progress, Recorder, Report, PROGRESS_STEPS};
use super::relaxation::Relaxation;
use super::schedule::{
    UpdateSchedule, UPDATE_ALLOWANCE, UPDATE_HYSTERESIS, UPDATE_MIN_RATIO, UPDATE_TOLERANCE,
};
use super::timeline::Timeline;
use super::{
    auto_load_steps, check_contact_start, fastest_wave, Critical, FrameSink, HistoryRow, Mode,
    Momentum, RunOutput, Settings, Stage, StepUpdates, DEFORMATION_ALLOWANCE, LANCZOS_ITERATIONS,
};
use crate::bc::Constraints;
use crate::material::Material;
use crate::solver::forces::NODE_BLOCK;
use crate::solver::gpu::Resident;
use crate::solver::spectrum::Lanczos;
use crate::solver::Model;
use crate::{Error, InputKind, Result};

/// The run's wall clock, the time spent in the frame sink (which solve_seconds leaves out),
/// where an instability stopped the attempt (steps taken, load fraction reached), and the
/// device the loop runs on (None: the CPU), which outlives the attempts.
pub(super) struct Clock<'a> {
    pub(super) start: Instant,
    pub(super) sink_seconds: &'a mut f64,
    pub(super) reached: &'a mut (usize, f64),
    pub(super) gpu: Option<&'a mut Resident>,
}

/// One pass of the time loop at `dt_factor` x the critical step `critical.0` (s). With
/// `restarted`, the frame of step 0 already went to the sink and is not sent again (it is the
/// same on every attempt: the prescribed state at load 0).
pub(super) fn attempt<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    critical: (f64, Critical),
    dt_factor: f64,
    clock: Clock<'_>,
    mut sink: Option<&mut FrameSink<'_, M>>,
    restarted: bool,
) -> Result<RunOutput> {
    let mut pass = Pass::new(
        model,
        s,
        critical,
        dt_factor,
        clock,
        sink.is_some(),
        restarted,
    )?;
    loop {
        crate::interrupt::check(|| match s.mode {
            Mode::Relaxation | Mode::Static => format!(
                "at step {} of the relaxation, {:.1} % of the load",
                pass.step,
                100.0 * pass.time.load(pass.step).min(1.0)
            ),
            Mode::Dynamic => format!(
                "at step {} of the dynamic run, t = {:.6e} s",
                pass.step,
                crate::error::Sci(pass.time.time(pass.step))
            ),
        })?;
        let t0 = pass.gpu.is_some().then(Instant::now);
        pass.update_step()?;
        if let (Some(g), Some(t0)) = (pass.gpu.as_mut(), t0) {
            g.note("host: step updates (Lanczos)", t0.elapsed().as_secs_f64());
        }
        pass.check_points()?;
        let t0 = pass.gpu.is_some().then(Instant::now);
        let (at_end, recorded) = pass.record(&mut sink)?;
        if let (Some(g), Some(t0)) = (pass.gpu.as_mut(), t0) {
            g.note(
                "host: records (energies, frames)",
                t0.elapsed().as_secs_f64(),
            );
        }
        if at_end {
            break;
        }
        pass.advance(recorded)?;
    }
    pass.finish(sink)
}

/// The error of a rigid body pushing into nodes the boundary conditions prescribe: which body,
/// where, which boundaries hold the node, and what to do.
pub(in crate::solver) fn contact_conflict<M: Material>(
    model: &Model<M>,
    c: &crate::bc::contact::Conflict,
    step: usize,
    load: f64,
) -> Error {
    let name = model
        .contact
        .as_ref()
        .and_then(|ct| ct.names().nth(c.body))
        .unwrap_or("?");
    let holders: Vec<String> = model
        .boundaries
        .iter()
        .filter(|b| {
            b.nodes.contains(&(c.node as usize))
                && (0..3).any(|k| c.normal[k].abs() > 1e-3 && b.components[k].is_some())
        })
        .map(|b| format!("'{}'", b.name))
        .collect();
    let by = match holders.as_slice() {
        [] => "the essential boundary conditions prescribe".to_string(),
        [one] => format!("boundary {one} prescribes"),
        [rest @ .., last] => format!("boundaries {} and {last} prescribe", rest.join(", ")),
    };
    Error::input(InputKind::Value, format!(
        "contact '{name}' pushes {:.3e} m into the surface point at ({:.4e}, {:.4e}, {:.4e}) m (node {}) at \
         step {step} ({:.1} % of its curve), but {by} that node along the push: the contact \
         cannot move it without undoing that condition, so the rigid body would pass through the tissue. Leave these nodes out of the \
         contact (its select) or out of the boundary, or stop the rigid body before it reaches them",
        crate::error::Sci(c.depth),
        crate::error::Sci(c.x.x),
        crate::error::Sci(c.x.y),
        crate::error::Sci(c.x.z),
        c.node,
        100.0 * load.min(1.0)
    ))
}

/// The added advice of the instability messages.
struct Hints {
    /// Where the critical step came from the global estimate, which has the smaller margin:
    /// the bounds are the alternative.
    estimate: &'static str,
    /// Where heavy damping may be the cause.
    damping: String,
}

impl Hints {
    fn new(s: &Settings, critical: Critical) -> Self {
        let estimate = if matches!(critical, Critical::Global(_)) {
            " or set solver.time_step = \"bounds\" (1.3-2.5x shorter steps that keep more margin for deformation)"
        } else {
            ""
        };
        // Heavy damping holds the body back while a driven boundary moves on: the elements
        // next to it are crushed whatever the step (the [8,4,20] cylinder compressed in 0.15 s
        // at c = 1e5 1/s inverts with the step cut to 1/70 of the initial). Said where c T is
        // large enough for that to be a cause.
        let damping = if s.mode == Mode::Dynamic && s.damping * s.load_time > 100.0 {
            format!(
                "; or lower solver.damping (c = {} 1/s, c x load time = {:.3e}): a boundary driven faster than \
                 the damped body can follow crushes the elements next to it",
                s.damping,
                s.damping * s.load_time
            )
        } else {
            String::new()
        };
        Hints { estimate, damping }
    }
}

/// The state of one pass: the central-difference displacements u(n-1), u(n), u(n+1) (m), the
/// internal forces (N), and what watches, records and adjusts the loop.
struct Pass<'a, M: Material> {
    model: &'a mut Model<M>,
    s: &'a Settings,
    /// The reference critical step (s) and the bound that set it.
    dt_crit: f64,
    critical: Critical,
    dt_factor: f64,
    start: Instant,
    sink_seconds: &'a mut f64,
    reached: &'a mut (usize, f64),
    restarted: bool,
    /// The fastest wave speed, m/s: it bounds how far a node may move in one step.
    c: f64,
    /// The reference body's bounding-box diagonal, m.
    size: f64,
    dynamic: bool,
    damped: bool,
    has_loads: bool,
    hints: Hints,
    time: Timeline,
    load_steps: usize,
    cons: Constraints,
    u: Vec<Vector3<f64>>,
    u_prev: Vec<Vector3<f64>>,
    u_next: Vec<Vector3<f64>>,
    f: Vec<Vector3<f64>>,
    /// Linear and angular momentum at the start.
    momentum_start: ([f64; 3], [f64; 3]),
    rec: Recorder,
    progress: Progress,
    ledger: Ledger,
    relax: Relaxation,
    step: usize,
    /// The critical step now, s: the reference one until an update estimates it anew.
    crit_now: f64,
    updates: StepUpdates,
    lanczos: Option<Lanczos>,
    schedule: UpdateSchedule,
    /// Nodes whose step change is measured after the corrections (see [`Pass::new`]).
    late: Vec<u32>,
    is_late: Vec<bool>,
    /// The device the loop runs on (`--device gpu`); None on the CPU. Its state is the loop's:
    /// `u`, `u_prev`, `u_next` and `f` here are copies, current only where a phase reads them
    /// back.
    gpu: Option<&'a mut Resident>,
    /// The point stage ran on the device and its smallest J is not checked yet.
    j_pending: bool,
    /// Relaxation: the load stages converged so far, and the index of the next stage in
    /// `s.stages`.
    stages: Vec<Stage>,
    next_stage: usize,
    /// A stage has just converged: the next step writes a frame.
    stage_frame: bool,
    /// The largest nodal force component at any recorded row so far, N.
    peak_force: f64,
    /// Relaxation with contact: whether the points in contact keep changing once the load is
    /// full ([`SettleWatch`]).
    settle: SettleWatch,
    /// The collapsing step has been warned of ([`collapse_note`]).
    collapse_said: bool,
    /// Device runs: the host does what follows the update (corrections, loads, damping) on
    /// copies of the state.
    assisted: bool,
    /// Device runs with corrections alone: the copies are of the corrections' nodes (their
    /// window, with the late nodes) only.
    windowed: bool,
}

impl<'a, M: Material> Pass<'a, M> {
    /// The step, load steps, initial state (prescribed values at load 0, initial velocity),
    /// and the recorder, whose memory plan may refuse the run.
    fn new(
        model: &'a mut Model<M>,
        s: &'a Settings,
        (dt_crit, critical): (f64, Critical),
        dt_factor: f64,
        clock: Clock<'a>,
        streaming: bool,
        restarted: bool,
    ) -> Result<Self> {
        let Clock {
            start,
            sink_seconds,
            reached,
            mut gpu,
        } = clock;
        let n = model.nodes.len();
        let c = fastest_wave(model);
        let dynamic = s.mode == Mode::Dynamic;
        let warm = s.warm_start.as_ref();
        if let Some(w) = warm {
            if dynamic {
                return Err(Error::input(InputKind::Value,
                    "a warm start continues a relaxation from its equilibrium; a dynamic run's answer \
                     is its path from the initial state, so it cannot start from another run's end",
                ));
            }
            if w.u.len() != n {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                    "the warm start has {} displacements for the model's {n} nodes: it comes from \
                     another model; start from the unloaded state",
                    w.u.len()
                ),
                ));
            }
            if let Some(i) = w.u.iter().position(|x| !x.iter().all(|c| c.is_finite())) {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                        "the warm start's displacement of node {i} is not finite; start from the \
                     unloaded state"
                    ),
                ));
            }
        }
        let hints = Hints::new(s, critical);
        let mut time = Timeline::new(s, dt_factor * dt_crit, dt_factor)?;
        let dt = time.dt;
        // A warm start begins deformed, the rigid bodies at their final positions: the check
        // of the unloaded body against them does not apply.
        if warm.is_none() {
            check_contact_start(model, dt)?;
        }
        let (lo, hi) = model.nodes.iter().fold(
            (
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            ),
            |(l, h), p| (l.inf(p), h.sup(p)),
        );
        let size = (hi - lo).norm();
        let load_steps = if warm.is_some() {
            // Everything at its final value from the first step (Timeline: 0 load steps is
            // the full load).
            0
        } else {
            s.load_steps.unwrap_or_else(|| {
                // The slowest shear wave sets how fast the load may come.
                model
                    .forces
                    .materials
                    .iter()
                    .map(|m| auto_load_steps((hi - lo).max(), m.lame().1, m.density(), dt))
                    .max()
                    .unwrap_or(400)
            })
        };
        time.load_steps = load_steps;
        if warm.is_some() {
            // Load stages lie below the full load the warm start begins at.
            time.cap = 1.0;
        }

        let has_loads = !model.loads.is_empty();
        if has_loads && model.f_ext.len() != n {
            model.f_ext = vec![Vector3::zeros(); n];
        }
        let zero = vec![Vector3::zeros(); n];
        let mut u = warm.map_or_else(|| zero.clone(), |w| w.u.clone());
        let mut u_prev = zero.clone();
        let u_next = zero.clone();
        let cons = model.constraints.clone();
        cons.prescribe(&mut u, time.load(0));
        if let Some(corr) = model.corrector.as_mut() {
            // Only the displacements matter here; the constraint force is recomputed every step.
            corr.correct(&mut u, time.load(0), 1.0);
        }
        u_prev.copy_from_slice(&u);
        let rigid: Option<Vec<Vector3<f64>>> = s
            .initial_motion
            .map(|[v, w, c]| model.nodes.iter().map(|x| v + w.cross(&(x - c))).collect());
        let initial = s.initial_velocity.as_ref().or(rigid.as_ref());
        if let (true, Some(v0)) = (dynamic, initial) {
            if v0.len() != n {
                return Err(Error::input(
                    InputKind::Value,
                    format!("initial velocity has {} entries for {n} nodes", v0.len()),
                ));
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

        let momentum_start = momentum(&model.mass, &model.nodes, &u, &u_prev, dt);
        let rec = Recorder::plan(
            s,
            (n, model.boundaries.len()),
            (time.total_steps, dt),
            model.solver_bytes(),
            streaming,
        )?;
        let progress = Progress::new(s, time.total_steps);
        let damped = dynamic && s.damping > 0.0;
        let ledger = Ledger::new(if damped { n.div_ceil(NODE_BLOCK) } else { 0 });
        let mut relax = Relaxation::new(
            if dynamic { 0 } else { n },
            load_steps,
            s.estimate_interval,
            s.tolerance,
        );
        if let Some(w) = warm.and_then(|w| w.omega_min) {
            relax.start_at(w, dt);
        }
        let updates = StepUpdates {
            dt_initial: dt,
            dt_min: dt,
            ..Default::default()
        };
        // Relaxation updates its step only after a restart: runs that converge at the first
        // attempt keep their fixed step (and their results).
        let lanczos = (s.step_update && (dynamic || restarted || model.mass_scaled))
            .then(|| Lanczos::new(model, LANCZOS_ITERATIONS));
        // The first estimate compares with the reference one where that was global.
        let schedule = UpdateSchedule::new(
            matches!(critical, Critical::Global(_))
                .then(|| (2.0 * DEFORMATION_ALLOWANCE / dt_crit).powi(2)),
        );
        // With a corrector, the nodes it moves and the prescribed ones change after the
        // update: their step change is measured after the correction (a short serial loop),
        // every other node's during the update. A parallel pass over all nodes after the
        // correction cost as much as the correction itself on two threads (the idle worker
        // had gone to sleep). Contact corrections move their nodes after the update too.
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
        let assisted = model.corrector.is_some() || model.contact.is_some() || has_loads || damped;
        if let Some(g) = gpu.as_mut() {
            if damped && !late.is_empty() {
                return Err(Error::input(InputKind::Unsupported,
                    "--device gpu does not run damped dynamics with EBCIEM / SEBCIEM corrections                      or contact yet; set solver.damping = 0 or run with --device cpu",
                ));
            }
            g.set_mask(&cons.mask, &is_late)?;
            g.set_state(&u_prev, &u, &u_next)?;
        }
        let window = match (&model.corrector, gpu.is_some()) {
            (Some(c), true) if model.contact.is_none() && !has_loads && !damped => c.window(),
            _ => None,
        };
        let windowed = window.is_some();
        if let (Some(g), Some(mut w)) = (gpu.as_mut(), window) {
            w.extend_from_slice(&late);
            w.sort_unstable();
            w.dedup();
            g.set_window(&w)?;
        }
        Ok(Pass {
            model,
            s,
            dt_crit,
            critical,
            dt_factor,
            start,
            sink_seconds,
            reached,
            restarted,
            c,
            size,
            dynamic,
            damped,
            has_loads,
            hints,
            time,
            load_steps,
            cons,
            u,
            u_prev,
            u_next,
            f: zero,
            momentum_start,
            rec,
            progress,
            ledger,
            relax,
            step: 0,
            crit_now: dt_crit,
            updates,
            lanczos,
            schedule,
            late,
            is_late,
            assisted,
            windowed,
            gpu,
            j_pending: false,
            stages: Vec::new(),
            next_stage: 0,
            stage_frame: false,
            peak_force: 0.0,
            settle: SettleWatch::default(),
            collapse_said: false,
        })
    }

    /// Notes where an instability stopped the attempt (steps taken, load fraction reached:
    /// the restarts compare them) and makes its error.
    fn unstable(&mut self, msg: String) -> Error {
        *self.reached = (self.step, self.time.load(self.step));
        Error::Unstable(msg)
    }

    /// Where the schedule says so, estimates the critical step at the deformed state and
    /// shortens the step when it has fallen ([`Settings::step_update`]).
    fn update_step(&mut self) -> Result<()> {
        let step = self.step;
        let due = self.schedule.due(step, self.c * self.crit_now);
        let Some((lz, by_travel)) = self
            .lanczos
            .as_mut()
            .zip(due)
            .filter(|_| step < self.time.total_steps)
        else {
            return Ok(());
        };
        let t_now = self.time.time(step);
        if let Some(g) = self.gpu.as_mut() {
            g.download_u(1, &mut self.u)?;
        }
        let estimate = lz.estimate(self.model, Some(&self.u), UPDATE_TOLERANCE);
        self.schedule
            .record(step, estimate.map(|e| e.lambda_max), by_travel);
        let Some(e) = estimate else { return Ok(()) };
        self.updates.estimates += 1;
        self.updates.iterations += e.iterations;
        let crit = UPDATE_ALLOWANCE * e.critical_step();
        self.crit_now = crit;
        // Only ever shorter: lengthening it again after the peak of a compression let fe hex8
        // at 80 % diverge while unloading (the step taken at 0.9 x an estimate that the
        // rebound outran).
        let target = self.dt_factor * crit;
        if target >= self.time.dt * (1.0 - UPDATE_HYSTERESIS) {
            return Ok(());
        }
        if target < UPDATE_MIN_RATIO * self.updates.dt_initial {
            let msg = format!(
                "the critical step fell to {sci_crit:.4e} s at step {step}, t = {t_now:.6} s, below {:.0} % of \
                 the initial step {:.4e} s: a point is collapsing under the load (the largest frequency \
                 has risen {:.0}x). Refine where the body is compressed most, use a slower load, or \
                 check the boundary conditions",
                100.0 * UPDATE_MIN_RATIO,
                crate::error::Sci(self.updates.dt_initial),
                (self.dt_crit / DEFORMATION_ALLOWANCE / e.critical_step()).max(1.0)
            , sci_crit = crate::error::Sci(crit));
            return Err(self.unstable(msg));
        }
        let old_dt = self.time.dt;
        if let Err(k) = self.time.shorten(step, target, self.s) {
            let msg = format!(
                "the critical step fell to {sci_crit:.4e} s at step {step}, t = {t_now:.6} s, and the rest of \
                 the run would need {sci_k:.3e} more steps: use a slower load or a coarser mesh where \
                 the body is compressed most, or set solver.max_steps to run it anyway", sci_crit = crate::error::Sci(crit), sci_k = crate::error::Sci(k));
            return Err(self.unstable(msg));
        }
        if self.dynamic {
            let left = self.time.total_steps - step;
            self.rec.redivide(step, t_now, (old_dt, self.time.dt), left);
            self.progress.set_length(self.time.total_steps);
        } else {
            self.relax.shorten(self.time.dt);
        }
        self.updates.reductions += 1;
        self.updates.last_reduction_time = t_now;
        self.updates.dt_min = self.updates.dt_min.min(self.time.dt);
        if !self.dynamic && !self.collapse_said && collapsing(&self.updates) {
            self.collapse_said = true;
            let note = collapse_note(self.model, &self.u, &self.updates, step);
            if self.s.progress || self.s.progress_lines.is_some() {
                eprintln!("warning: {note}");
            }
            self.settle.notes.push(note);
        }
        Ok(())
    }

    /// The point stage of the internal forces at u(n), stopping at an inverted point. Nodal
    /// forces are gathered in the update ([`Pass::advance`]: one pass over the nodes instead of
    /// two), or by [`Pass::record`] on the steps that record them first.
    fn check_points(&mut self) -> Result<()> {
        if let Some(g) = self.gpu.as_mut() {
            // Checked where the host next reads the device (record or advance): one wait per
            // step instead of two.
            g.points()?;
            self.j_pending = true;
            return Ok(());
        }
        let model = &mut *self.model;
        model
            .forces
            .compute_points(&model.points, &model.slots, &self.u);
        let (min_j, p_min) = model.forces.min_j();
        self.inverted(min_j, p_min)
    }

    /// The error of an inverted point where the smallest J `min_j` (of point `p_min`) is not
    /// positive.
    fn inverted(&mut self, min_j: f64, p_min: usize) -> Result<()> {
        if min_j > 0.0 {
            return Ok(());
        }
        let model = &*self.model;
        let near = model.point_centroid(p_min);
        let id = model.point_ids[p_min];
        let (step, t, dt, crit) = (
            self.step,
            self.time.time(self.step),
            self.time.dt,
            self.crit_now,
        );
        let msg = format!(
            "integration point {id} near ({:.4e}, {:.4e}, {:.4e}) m inverted (J = {min_j:.4}) at step {step}, t = {t:.6} s \
             (dt = {sci_dt:.4e} s, {:.3} x the critical estimate {sci_crit:.4e} s; one-point FE meshes number points as their elements). \
             The load is too large or fast for this discretization, or the step too large: reduce solver.dt_factor \
             (large compression shortens the elements below the estimate, {}){}, refine, or use a slower load{}",
            crate::error::Sci(near.x),
            crate::error::Sci(near.y),
            crate::error::Sci(near.z),
            dt / crit,
            estimated_at(self.updates.estimates, self.schedule.last),
            self.hints.estimate,
            self.hints.damping
        , sci_dt = crate::error::Sci(dt), sci_crit = crate::error::Sci(crit));
        Err(self.unstable(msg))
    }

    /// The external loads at this step; where a row is due (or the run ends here), the nodal
    /// forces, energies and reactions; where a frame is due, the frame. Returns whether the
    /// run ends at this step and whether the nodal forces were gathered.
    fn record(&mut self, sink: &mut Option<&mut FrameSink<'_, M>>) -> Result<(bool, bool)> {
        let (step, t) = (self.step, self.time.time(self.step));
        if self.has_loads {
            if let Some(g) = self.gpu.as_mut() {
                g.download_u(1, &mut self.u)?;
            }
            let model = &mut *self.model;
            model
                .loads
                .apply(&self.u, self.time.load(step), &mut model.f_ext);
        }
        let at_end = (self.dynamic && step == self.time.total_steps)
            || self.relax.converged
            || (!self.dynamic && step >= self.time.total_steps);
        let record = self.rec.row_due(step) || at_end;
        let frame = (self.rec.frame_due(step) || std::mem::take(&mut self.stage_frame))
            && !(self.restarted && step == 0 && sink.is_some());
        if let (Some(g), true) = (self.gpu.as_mut(), record || frame) {
            let (min_j, p_min) = g.min_j()?;
            g.download_u(1, &mut self.u)?;
            g.download_u(0, &mut self.u_prev)?;
            if record {
                g.gather(&mut self.f)?;
            }
            self.j_pending = false;
            self.inverted(min_j, p_min)?;
        }
        let model = &mut *self.model;
        if record {
            if self.gpu.is_none() {
                model.forces.gather(&mut self.f);
            }
            let se = model
                .forces
                .strain_energy(&model.points, &model.slots, &self.u);
            let ke = kinetic(&model.mass, &self.u, &self.u_prev, self.time.dt_prev);
            if step == 0 {
                self.ledger.initial_kinetic = ke;
            }
            let external_work = self.ledger.external_work;
            if self.dynamic
                && step > 0
                && ke > 10.0 * (external_work.abs() + se + self.ledger.initial_kinetic) + 1e-12
            {
                let (dt, crit) = (self.time.dt, self.crit_now);
                let msg = format!(
                    "kinetic energy {sci_ke:.4e} J exceeds ten times the work done on the body ({sci_external_work:.4e} J) at step {step}, t = {t:.6} s: \
                     the integration is unstable with dt = {sci_dt:.4e} s ({:.3} x the critical estimate {sci_crit:.4e} s); reduce solver.dt_factor{}",
                    dt / crit,
                    self.hints.estimate
                , sci_ke = crate::error::Sci(ke), sci_external_work = crate::error::Sci(external_work), sci_dt = crate::error::Sci(dt), sci_crit = crate::error::Sci(crit));
                return Err(self.unstable(msg));
            }
            let largest = self.f.iter().map(|v| v.amax()).fold(0.0, f64::max);
            self.peak_force = self.peak_force.max(largest);
            let reactions = model.reaction_rows(&self.f);
            self.rec.history.push(HistoryRow {
                step,
                time: t,
                reactions,
                external_work,
                strain_energy: se,
                kinetic_energy: ke,
            });
        }
        if frame {
            if let Some(sink) = sink.as_mut() {
                let t0 = Instant::now();
                sink(model, t, &self.u)?;
                *self.sink_seconds += t0.elapsed().as_secs_f64();
            } else {
                self.rec.keep(t, &self.u);
            }
        }
        Ok((at_end, record))
    }

    /// One central-difference step to u(n+1): the update, the prescribed values, the
    /// corrections (essential boundaries, contact), the work and damping ledgers, the
    /// divergence test and relaxation's convergence estimate. `gathered`: [`Pass::record`]
    /// has already gathered the nodal forces at this step.
    fn advance(&mut self, gathered: bool) -> Result<()> {
        let step = self.step;
        let has_loads = self.has_loads;
        let has_late = !self.late.is_empty();
        let mut coefficients = self.time.coefficients(self.s.damping, self.relax.r);
        if self.dynamic && step == 0 {
            // The start: u(1) = u(0) + dt v(0) + dt^2/2 a(0), half the acceleration term of
            // the later steps (u(-1) = u(0) - dt v(0)). A load present from t = 0 otherwise
            // starts with v(1/2) = v(0) + dt a(0): free fall then ran dt/t ahead (0.43 % after
            // 234 steps, issue 41).
            coefficients.0 *= 0.5;
        }
        let a = coefficients.0;
        let next_load = self.time.load(step + 1);
        let (mut max_du, mut max_u);
        if let Some(g) = self.gpu.as_mut() {
            // The update and the prescribed values on the device.
            let f_ext = has_loads.then_some(self.model.f_ext.as_slice());
            let time = &self.time;
            let terms = (!self.assisted).then_some((
                match (time.dynamic, time.dt == time.dt_prev) {
                    (false, _) => 0,
                    (true, true) => 1,
                    (true, false) => 2,
                },
                time.dt,
                time.dt_prev,
            ));
            let sc = g.update(coefficients, gathered, next_load, f_ext, terms)?;
            if std::mem::take(&mut self.j_pending) {
                self.inverted(sc.min_j, sc.p_min)?;
            }
            (max_du, max_u) = (sc.max_du, sc.max_u);
            let Some(g) = self.gpu.as_mut() else {
                unreachable!("the device went away");
            };
            if !self.assisted {
                // The prescribed DOFs' work terms and u(n+1) came with the step's scalars.
                self.ledger.add_work_terms(g.dof_terms());
                return self.conclude(max_du, max_u);
            }
            // Corrections, loads or damping: the host does the rest of the step as on the
            // CPU, on copies of the state (of the window's nodes where the corrections name
            // theirs).
            if self.windowed {
                g.download_window(&mut self.u_next, &mut self.u, &mut self.u_prev, &mut self.f)?;
            } else {
                g.download_u(0, &mut self.u_prev)?;
                g.download_u(1, &mut self.u)?;
                g.download_u(2, &mut self.u_next)?;
                g.download_f(&mut self.f)?;
            }
            if self.damped {
                self.damping_sums();
            }
        } else {
            let model = &*self.model;
            let predictor = Predictor {
                mass: &model.mass,
                forces: &model.forces,
                f_ext: has_loads.then_some(model.f_ext.as_slice()),
                mask: &self.cons.mask,
                is_late: &self.is_late,
                coefficients,
                gathered,
                damped: self.damped,
                late_pending: self.ledger.late_pending(),
                damping: self.ledger.slots(),
            };
            (max_du, max_u) =
                predictor.update((&self.u, &self.u_prev), &mut self.u_next, &mut self.f);
            self.cons.prescribe(&mut self.u_next, next_load);
        }
        let t_host = Instant::now();
        let model = &mut *self.model;
        if let Some(corr) = model.corrector.as_mut() {
            corr.correct(&mut self.u_next, next_load, a);
            self.ledger.external_work += corr.work(&self.u_next, &self.u_prev);
        }
        if let Some(ct) = model.contact.as_mut() {
            ct.correct(&mut self.u_next, next_load, a, &model.mass, &self.cons.mask);
            self.ledger.external_work += ct.work(&self.u_next, &self.u_prev);
            if !self.dynamic && next_load >= 1.0 {
                let step = self.step;
                let (err, tol) = (self.relax.err_est, self.s.tolerance);
                if let Some(note) = self.settle.observe(step, ct.points_in_contact(), err, tol) {
                    if self.s.progress || self.s.progress_lines.is_some() {
                        eprintln!("warning: {note}");
                    }
                    self.settle.notes.push(note);
                }
            }
        }
        if let Some(c) = model.contact.as_ref().and_then(|ct| ct.conflict()) {
            return Err(contact_conflict(model, c, self.step + 1, next_load));
        }
        // The predictor's change includes the part the correction takes back (it never
        // vanishes next to a constrained boundary), so measure the corrected change.
        for &i in &self.late {
            let (a, b) = (self.u_next[i as usize], self.u[i as usize]);
            let d = a - b;
            max_du = nan_max(max_du, nan_max(d.x.abs(), nan_max(d.y.abs(), d.z.abs())));
            max_u = nan_max(max_u, nan_max(a.x.abs(), nan_max(a.y.abs(), a.z.abs())));
        }
        if self.damped {
            self.ledger
                .add_damping(self.s.damping, &self.time, has_late);
        }
        self.ledger.add_step_work(
            (&self.cons, &model.mass),
            &self.f,
            has_loads.then_some(model.f_ext.as_slice()),
            [&self.u_next, &self.u, &self.u_prev],
            &self.time,
        );
        for &(node, comp) in self.cons.dofs.iter() {
            max_u = nan_max(max_u, self.u_next[node as usize][comp as usize].abs());
        }
        if let Some(g) = self.gpu.as_mut() {
            g.note(
                "host: corrections and ledger",
                t_host.elapsed().as_secs_f64(),
            );
        }
        if let (Some(g), true) = (
            self.gpu.as_mut(),
            model.corrector.is_some() || model.contact.is_some(),
        ) {
            if self.windowed {
                g.upload_window(&self.u_next)?;
            } else {
                g.upload_next(&self.u_next)?;
            }
        }
        self.conclude(max_du, max_u)
    }

    /// The relaxation has converged at the stage held at `step`: keeps its state and
    /// reactions, and lets the load come on again towards the next stage (or the full load)
    /// with a fresh relaxation rate.
    fn stage_converged(&mut self, step: usize) -> Result<()> {
        if let Some(g) = self.gpu.as_mut() {
            g.download_u(1, &mut self.u)?;
            g.download_f(&mut self.f)?;
        }
        let reactions = self.model.reaction_rows(&self.f);
        self.stages.push(Stage {
            load: self.time.cap,
            step,
            reactions,
            u: self.u.clone(),
        });
        self.next_stage += 1;
        let next = self.s.stages.get(self.next_stage).copied().unwrap_or(1.0);
        self.time.resume(step + 1, next);
        let records = std::mem::take(&mut self.relax.records);
        let n = if self.dynamic { 0 } else { self.u.len() };
        self.relax = Relaxation::new(
            n,
            self.load_steps,
            self.s.estimate_interval,
            self.s.tolerance,
        );
        self.relax.records = records;
        self.stage_frame = true;
        Ok(())
    }

    /// The damping ledger's block sums of a damped device run, as the CPU update makes them
    /// (predict.rs; runs with late nodes keep to the CPU).
    #[allow(clippy::needless_range_loop)] // i indexes five arrays
    fn damping_sums(&mut self) {
        let slots = self.ledger.slots();
        let n = self.u.len();
        let mass = &self.model.mass;
        for blk in 0..n.div_ceil(NODE_BLOCK) {
            let mut damp = 0.0f64;
            for i in blk * NODE_BLOCK..n.min((blk + 1) * NODE_BLOCK) {
                if !self.is_late[i] {
                    damp +=
                        mass[i] * free_dist2(self.cons.mask[i], &self.u_next[i], &self.u_prev[i]);
                }
            }
            // SAFETY: blk is below the ledger's block count (n / NODE_BLOCK rounded up, as
            // given to Ledger::new), and this thread alone writes the slots.
            unsafe { slots.write(blk, damp, 0.0) };
        }
    }

    /// The end of a step: the divergence test on the largest change `max_du` and
    /// displacement `max_u` (m), relaxation's estimate, the swap to the next step.
    fn conclude(&mut self, mut max_du: f64, mut max_u: f64) -> Result<()> {
        let step = self.step;
        let (t, dt) = (self.time.time(step), self.time.dt);
        let max_rate = self.c * dt;
        let model = &*self.model;
        let size = self.size;
        if max_u.is_finite() && max_du.is_finite() && (max_u > 10.0 * size || max_du > max_rate) {
            // A body in fast rigid motion (a free body faster than its own waves, or carried
            // far) is not diverging: judge the step's change without its rigid part, and the
            // size by the deformed body's extent. Only here, so normal steps pay nothing.
            if let Some(g) = self.gpu.as_mut() {
                g.download_u(1, &mut self.u)?;
                g.download_u(2, &mut self.u_next)?;
            }
            let (change, extent) =
                deformation_change(&model.mass, &model.nodes, &self.u, &self.u_next);
            max_du = change;
            if change <= max_rate && extent <= 10.0 * size {
                max_u = 0.0;
            }
        }
        if !max_u.is_finite() || !max_du.is_finite() || max_u > 10.0 * size || max_du > max_rate {
            let crit = self.crit_now;
            let msg = format!(
                "the solution diverged at step {step}, t = {t:.6} s (largest displacement {sci_max_u:.3e} m, largest change in one step {sci_max_du:.3e} m): \
                 dt = {sci_dt:.4e} s is {:.3} x the critical estimate {sci_crit:.4e} s ({}); reduce solver.dt_factor (default 0.9; \
                 the estimate holds for the body as it was when made, and large compression lowers the critical step){}",
                dt / crit,
                estimated_at(self.updates.estimates, self.schedule.last),
                self.hints.estimate
            , sci_max_u = crate::error::Sci(max_u), sci_max_du = crate::error::Sci(max_du), sci_dt = crate::error::Sci(dt), sci_crit = crate::error::Sci(crit));
            return Err(self.unstable(msg));
        }

        self.schedule.travel += max_du;
        if !self.dynamic && self.time.load(step + 1) >= self.time.target() {
            if let (Some(g), true) = (self.gpu.as_mut(), self.relax.wants_state(step)) {
                g.download_u(1, &mut self.u)?;
                g.download_f(&mut self.f)?;
            }
            self.relax.observe(
                step,
                (&self.u, &self.f),
                (&model.mass, &self.cons.mask),
                max_du,
                dt,
            );
            if self.relax.converged && self.time.cap < 1.0 {
                self.stage_converged(step)?;
            }
        }

        std::mem::swap(&mut self.u_prev, &mut self.u);
        std::mem::swap(&mut self.u, &mut self.u_next);
        if let Some(g) = self.gpu.as_mut() {
            g.rotate();
        }
        self.time.dt_prev = dt;
        self.step += 1;
        if self.step.is_multiple_of(PROGRESS_STEPS) {
            let report = Report {
                step: self.step,
                total_steps: self.time.total_steps,
                t: self.time.time(self.step),
                load: self.time.load(self.step),
                err_est: self.relax.err_est,
                tolerance: self.s.tolerance,
                r: self.relax.r,
            };
            self.progress.update(&report, self.start);
        }
        Ok(())
    }

    /// Closes the ledgers, hands relaxation's final state to the sink (or keeps it) and
    /// collects the output.
    fn finish(mut self, mut sink: Option<&mut FrameSink<'_, M>>) -> Result<RunOutput> {
        self.progress.finish();
        if let Some(g) = self.gpu.as_mut() {
            g.download_u(0, &mut self.u_prev)?;
            g.download_u(1, &mut self.u)?;
            g.download_u(2, &mut self.u_next)?;
            g.download_f(&mut self.f)?;
        }
        // The last update's late share: u = u(N), u_next = u(N-2) after the final swap.
        self.ledger.finish_damping(
            &self.late,
            (&self.model.mass, &self.cons.mask),
            &self.u,
            &self.u_next,
        );
        let solve_seconds = self.start.elapsed().as_secs_f64() - *self.sink_seconds;
        let step = self.step;
        let time = &self.time;
        if !self.dynamic {
            let t_end = step as f64 * time.dt;
            if let Some(sink) = sink.as_mut() {
                sink(self.model, t_end, &self.u)?;
            } else {
                self.rec.keep_last(t_end, &self.u);
            }
        }
        let (strain_energy, kinetic_energy) = self
            .rec
            .history
            .last()
            .map(|h| (h.strain_energy, h.kinetic_energy))
            .unwrap_or((0.0, 0.0));
        let model = &*self.model;
        let (linear_end, angular_end) = momentum(
            &model.mass,
            &model.nodes,
            &self.u,
            &self.u_prev,
            time.dt_prev,
        );
        let (linear_start, angular_start) = self.momentum_start;
        let ledger = &self.ledger;
        Ok(RunOutput {
            device: "cpu".into(),
            device_setup_seconds: 0.0,
            momentum: Momentum {
                linear_start,
                linear_end,
                angular_start,
                angular_end,
            },
            u: self.u,
            u_prev: self.u_prev,
            f_int: self.f,
            dt: time.dt,
            dt_critical: self.dt_crit,
            critical: self.critical,
            steps: step,
            load_steps: (!self.dynamic).then_some(self.load_steps),
            simulated_time: time.time(step),
            converged: self.dynamic || self.relax.converged,
            history: self.rec.history,
            relaxation: self.relax.records,
            frames: self.rec.frames,
            external_work: ledger.external_work,
            peak_external_work: ledger.peak_external_work,
            initial_kinetic: ledger.initial_kinetic,
            damping_dissipation: ledger.damping_dissipation,
            strain_energy,
            kinetic_energy,
            solve_seconds,
            restarts: Vec::new(),
            notes: std::mem::take(&mut self.settle.notes),
            failed_steps: 0,
            step_updates: self.updates,
            stages: self.stages,
            peak_nodal_force: self.peak_force,
            force_evaluations: 0,
            statics: None,
        })
    }
}

/// Where the critical step in an instability message was estimated: the reference state, or
/// the deformed state at a step ([`super::Settings::step_update`]).
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

/// Steps at the full load after which a relaxation with contact that has not converged, and
/// whose points in contact kept changing, is said not to settle.
const SETTLE_WINDOW: usize = 10_000;

/// Watches a relaxation with contact at its full load: where the points in contact change in
/// more than 1 % of the steps of a [`SETTLE_WINDOW`] and the run has not converged, the contact
/// chatters (points leaving and re-entering contact) and the relaxation may settle only very
/// slowly or not at all below such a tolerance (issue 56: skull contact at 1e-6 m ran 135,000
/// steps, 90 s, without a word). Said once, as it happens and in the summary.
#[derive(Default)]
struct SettleWatch {
    /// Points in contact with each body after the previous step.
    last: Vec<usize>,
    /// Steps of the current window whose points in contact changed, and where it began.
    changes: usize,
    start: Option<usize>,
    /// The step the full load was first seen at.
    first: Option<usize>,
    said: bool,
    notes: Vec<String>,
}

impl SettleWatch {
    /// Takes step `step`'s points in contact with each body; the note, once, where the
    /// contact chatters and the relaxation has not settled.
    fn observe(
        &mut self,
        step: usize,
        now: &[usize],
        err_est: f64,
        tolerance: f64,
    ) -> Option<String> {
        // Copied into the kept buffer: no allocation in the time loop after the first step.
        if self.first.is_none() || self.last.as_slice() != now {
            if self.first.is_some() {
                self.changes += 1;
            }
            self.last.clear();
            self.last.extend_from_slice(now);
        }
        let first = *self.first.get_or_insert(step);
        let start = *self.start.get_or_insert(step);
        if self.said || step - start < SETTLE_WINDOW {
            return None;
        }
        let changes = std::mem::take(&mut self.changes);
        self.start = Some(step);
        if changes * 100 <= SETTLE_WINDOW {
            return None;
        }
        self.said = true;
        Some(format!(
            "the relaxation has not settled {} steps after the full load (error estimate {err_est:.3e} m, \
             solver.tolerance {tolerance:.3e} m): the points in contact changed in {changes} of the last \
             {SETTLE_WINDOW} steps (points leaving and re-entering contact), which can keep it from \
             converging below the chatter; if it runs long, loosen solver.tolerance (e.g. to \
             {:.1e} m) or set solver.max_steps",
            step - first,
            (10.0 * tolerance).max(err_est)
        ))
    }
}

#[cfg(test)]
mod settle_tests {
    use super::*;

    /// A step is said to collapse below a tenth of its first value or after 30 reductions;
    /// the stiffening of the cube compressed by 80 % (18 reductions to 0.23x) is not.
    #[test]
    fn a_collapse_is_a_tenth_or_many_reductions() {
        let u = |reductions, ratio: f64| StepUpdates {
            reductions,
            dt_initial: 1.0,
            dt_min: ratio,
            ..Default::default()
        };
        assert!(!collapsing(&u(18, 0.23)));
        assert!(collapsing(&u(3, 0.09)));
        assert!(collapsing(&u(30, 0.5)));
    }

    #[test]
    fn a_chattering_contact_that_does_not_settle_is_said_once() {
        // MNI skull contact at 1e-6 m: 246 changes in 10,000 steps (2.5 %) after the full load.
        let mut w = SettleWatch::default();
        let mut said = Vec::new();
        for step in 500..40_000 {
            let now = [4430 + usize::from(step % 40 == 0)];
            said.extend(w.observe(step, &now, 3.2e-5, 1e-6).map(|n| (step, n)));
        }
        assert_eq!(said.len(), 1, "{said:?}");
        assert_eq!(said[0].0, 500 + SETTLE_WINDOW);
        assert!(
            said[0].1.contains("changed in 500 of the last 10000 steps"),
            "{}",
            said[0].1
        );
        // A contact that holds still, or changes rarely, is not said to chatter.
        let mut w = SettleWatch::default();
        for step in 0..40_000 {
            let now = [7 + usize::from(step % 500 == 0)];
            assert_eq!(w.observe(step, &now, 3.2e-5, 1e-6), None);
        }
    }
}

/// Reductions of the relaxation's step after which it is said to collapse (the cube
/// compressed by 60 / 70 % takes 12 / 16 reductions to 0.45 / 0.34x, a stiffening, not a
/// collapse).
const COLLAPSE_REDUCTIONS: usize = 30;
/// A relaxation step below this fraction of its first value is said to collapse.
const COLLAPSE_RATIO: f64 = 0.1;

/// The step has been shortened many times or far below its first value: a relaxation that
/// will take many times the steps it was planned for (issue 57: a graded rim, 55 reductions to
/// 0.088x, five minutes without a word).
fn collapsing(u: &StepUpdates) -> bool {
    u.reductions >= COLLAPSE_REDUCTIONS || u.dt_min < COLLAPSE_RATIO * u.dt_initial
}

/// The warning for a collapsing relaxation step, naming the elements (points) that set it:
/// those whose deformed shape-function gradients have grown most (the step bound of a point
/// falls as 1 / sqrt(sum_a |F^-T dphi_a|^2)).
fn collapse_note<M: Material>(
    model: &Model<M>,
    u: &[Vector3<f64>],
    updates: &StepUpdates,
    step: usize,
) -> String {
    let worst = super::super::timestep::stiffened_points(model, u, 3);
    let list: Vec<String> = worst
        .iter()
        .map(|w| format!("{} (J {:.3}, its bound {:.2}x)", w.id, w.j, w.ratio))
        .collect();
    format!(
        "relaxation: the step collapsed to {:.3}x its first value ({} reductions by step {step}): \
         the steps from here take that much longer to settle the body. The points (elements) that set it: {}. Refine or \
         smooth the mesh there (a sharply driven rim, a sliver), load more slowly, or use \
         solver.mode = \"static\"",
        updates.dt_min / updates.dt_initial,
        updates.reductions,
        list.join(", ")
    )
}
