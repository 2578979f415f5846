//! One pass of the time loop from the unloaded state at a fixed dt_factor (the caller,
//! [`super::run`], restarts relaxation with a shorter step after an instability).

use std::time::Instant;

use nalgebra::Vector3;

use super::energy::{kinetic, momentum, Ledger};
use super::predict::{nan_max, Predictor};
use super::record::{Progress, Recorder, Report, PROGRESS_STEPS};
use super::relaxation::Relaxation;
use super::schedule::{
    UpdateSchedule, UPDATE_ALLOWANCE, UPDATE_HYSTERESIS, UPDATE_MIN_RATIO, UPDATE_TOLERANCE,
};
use super::timeline::Timeline;
use super::{
    auto_load_steps, check_contact_start, fastest_wave, Critical, FrameSink, HistoryRow, Mode,
    Momentum, RunOutput, Settings, StepUpdates, DEFORMATION_ALLOWANCE, LANCZOS_ITERATIONS,
};
use crate::material::Material;
use crate::solver::forces::NODE_BLOCK;
use crate::solver::Model;
use crate::{Error, Result};

/// The run's wall clock, the time spent in the frame sink (which solve_seconds leaves out),
/// and where an instability stopped the attempt (steps taken, load fraction reached).
pub(super) struct Clock<'a> {
    pub(super) start: Instant,
    pub(super) sink_seconds: &'a mut f64,
    pub(super) reached: &'a mut (usize, f64),
}

/// Notes where an instability stopped the attempt (steps taken, load fraction reached: the
/// restarts compare them) and makes its error.
fn unstable(reached: &mut (usize, f64), time: &Timeline, step: usize, msg: String) -> Error {
    *reached = (step, time.load(step));
    Error::Unstable(msg)
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
    let mut time = Timeline::new(s, dt_factor * dt_crit, dt_factor)?;
    let dt = time.dt;
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
    time.load_steps = load_steps;

    let has_loads = !model.loads.is_empty();
    if has_loads && model.f_ext.len() != n {
        model.f_ext = vec![Vector3::zeros(); n];
    }
    let zero = vec![Vector3::zeros(); n];
    let mut u = zero.clone();
    let mut u_prev = zero.clone();
    let mut u_next = zero.clone();
    let mut f = zero;
    let cons = model.constraints.clone();
    let cons = &cons;
    let prescribe = |target: &mut [Vector3<f64>], tau: f64| {
        for (k, &(node, comp)) in cons.dofs.iter().enumerate() {
            target[node as usize][comp as usize] = cons.amplitude[k] * cons.curve[k].value(tau);
        }
    };
    prescribe(&mut u, time.load(0));
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
    let mut rec = Recorder::plan(
        s,
        (n, model.boundaries.len()),
        (time.total_steps, dt),
        model.solver_bytes(),
        sink.is_some(),
    )?;
    let mut progress = Progress::new(s, time.total_steps);
    let damped = dynamic && s.damping > 0.0;
    let mut ledger = Ledger::new(if damped { n.div_ceil(NODE_BLOCK) } else { 0 });
    let mut relax = Relaxation::new(
        if dynamic { 0 } else { n },
        load_steps,
        s.estimate_interval,
        s.tolerance,
    );
    let mut step = 0usize;
    let mut crit_now = dt_crit;
    let mut updates = StepUpdates {
        dt_initial: dt,
        dt_min: dt,
        ..Default::default()
    };
    // Relaxation updates its step only after a restart: runs that converge at the first
    // attempt keep their fixed step (and their results).
    let mut lanczos = (s.step_update && (dynamic || restarted))
        .then(|| super::super::spectrum::Lanczos::new(model, LANCZOS_ITERATIONS));
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
        if let Some((lz, by_travel)) = lanczos
            .as_mut()
            .zip(due)
            .filter(|_| step < time.total_steps)
        {
            let t_now = time.time(step);
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
                if target < time.dt * (1.0 - UPDATE_HYSTERESIS) {
                    if target < UPDATE_MIN_RATIO * updates.dt_initial {
                        return Err(unstable(reached, &time, step, format!(
                            "the critical step fell to {crit:.4e} s at step {step}, t = {t_now:.6} s, below {:.0} % of \
                             the initial step {:.4e} s: a point is collapsing under the load (the largest frequency \
                             has risen {:.0}x). Refine where the body is compressed most, use a slower load, or \
                             check the boundary conditions",
                            100.0 * UPDATE_MIN_RATIO, updates.dt_initial,
                            (dt_crit / DEFORMATION_ALLOWANCE / e.critical_step()).max(1.0)
                        )));
                    }
                    let old_dt = time.dt;
                    if let Err(k) = time.shorten(step, target, s) {
                        return Err(unstable(reached, &time, step, format!(
                            "the critical step fell to {crit:.4e} s at step {step}, t = {t_now:.6} s, and the rest of \
                             the run would need {k:.3e} more steps: use a slower load or a coarser mesh where \
                             the body is compressed most, or set solver.max_steps to run it anyway"
                        )));
                    }
                    if dynamic {
                        rec.redivide(step, t_now, (old_dt, time.dt), time.total_steps - step);
                        progress.set_length(time.total_steps);
                    } else {
                        relax.shorten(time.dt);
                    }
                    updates.reductions += 1;
                    updates.last_reduction_time = t_now;
                    updates.dt_min = updates.dt_min.min(time.dt);
                }
            }
        }
        let t = time.time(step);
        let dt = time.dt;
        let max_rate = c * dt;
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
            return Err(unstable(reached, &time, step, format!(
                "integration point {id} near ({:.4e}, {:.4e}, {:.4e}) m inverted (J = {min_j:.4}) at step {step}, t = {t:.6} s \
                 (dt = {dt:.4e} s, {:.3} x the critical estimate {dt_crit:.4e} s; one-point FE meshes number points as their elements). \
                 The load is too large or fast for this discretization, or the step too large: reduce solver.dt_factor \
                 (large compression shortens the elements below the estimate, {}){hint}, refine, or use a slower load{damping_hint}",
                near.x, near.y, near.z,
                dt / crit_now, estimated_at(updates.estimates, schedule.last), dt_crit = crit_now
            )));
        }
        if has_loads {
            model.loads.apply(&u, time.load(step), &mut model.f_ext);
        }
        let at_end = (dynamic && step == time.total_steps)
            || relax.converged
            || (!dynamic && step >= time.total_steps);
        let record = rec.row_due(step) || at_end;
        if record {
            model.forces.gather(&mut f);
            let se = model.forces.strain_energy(&model.points, &model.slots, &u);
            let ke = kinetic(&model.mass, &u, &u_prev, time.dt_prev);
            if step == 0 {
                ledger.initial_kinetic = ke;
            }
            let external_work = ledger.external_work;
            if dynamic
                && step > 0
                && ke > 10.0 * (external_work.abs() + se + ledger.initial_kinetic) + 1e-12
            {
                return Err(unstable(reached, &time, step, format!(
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
            rec.history.push(HistoryRow {
                step,
                time: t,
                reactions,
                external_work,
                strain_energy: se,
                kinetic_energy: ke,
            });
        }
        if rec.frame_due(step) && !(restarted && step == 0 && sink.is_some()) {
            if let Some(sink) = sink.as_mut() {
                let t0 = Instant::now();
                sink(model, t, &u)?;
                *sink_seconds += t0.elapsed().as_secs_f64();
            } else {
                rec.keep(t, &u);
            }
        }
        if at_end {
            break;
        }

        let coefficients = time.coefficients(s.damping, relax.r);
        let a = coefficients.0;
        let predictor = Predictor {
            mass: &model.mass,
            forces: &model.forces,
            f_ext: has_loads.then_some(model.f_ext.as_slice()),
            mask: &cons.mask,
            is_late,
            coefficients,
            gathered: record,
            damped,
            late_pending: ledger.late_pending(),
            damping: ledger.slots(),
        };
        let (mut max_du, mut max_u) = predictor.update((&u, &u_prev), &mut u_next, &mut f);
        let next_load = time.load(step + 1);
        prescribe(&mut u_next, next_load);
        if let Some(corr) = model.corrector.as_mut() {
            corr.correct(&mut u_next, next_load, a);
            ledger.external_work += corr.work(&u_next, &u_prev);
        }
        if let Some(ct) = model.contact.as_mut() {
            ct.correct(&mut u_next, next_load, a, &model.mass, &cons.mask);
            ledger.external_work += ct.work(&u_next, &u_prev);
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
            ledger.add_damping(s.damping, &time, !late.is_empty());
        }
        ledger.add_step_work(
            (cons, &model.mass),
            &f,
            has_loads.then_some(model.f_ext.as_slice()),
            [&u_next, &u, &u_prev],
            &time,
        );
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
            return Err(unstable(reached, &time, step, format!(
                "the solution diverged at step {step}, t = {t:.6} s (largest displacement {max_u:.3e} m, largest change in one step {max_du:.3e} m): \
                 dt = {dt:.4e} s is {:.3} x the critical estimate {dt_crit:.4e} s ({}); reduce solver.dt_factor (default 0.9; \
                 the estimate holds for the body as it was when made, and large compression lowers the critical step){hint}",
                dt / crit_now, estimated_at(updates.estimates, schedule.last), dt_crit = crit_now
            )));
        }

        schedule.travel += max_du;
        if !dynamic && time.load(step + 1) >= 1.0 {
            relax.observe(step, (&u, &f), (&model.mass, &cons.mask), max_du, dt);
        }

        std::mem::swap(&mut u_prev, &mut u);
        std::mem::swap(&mut u, &mut u_next);
        time.dt_prev = dt;
        step += 1;
        if step.is_multiple_of(PROGRESS_STEPS) {
            let report = Report {
                step,
                total_steps: time.total_steps,
                t: time.time(step),
                load: time.load(step),
                err_est: relax.err_est,
                tolerance: s.tolerance,
                r: relax.r,
            };
            progress.update(&report, start);
        }
    }
    progress.finish();
    // The last update's late share: u = u(N), u_next = u(N-2) after the final swap.
    ledger.finish_damping(&late, (&model.mass, &cons.mask), &u, &u_next);
    let solve_seconds = start.elapsed().as_secs_f64() - *sink_seconds;
    if !dynamic {
        let t_end = step as f64 * time.dt;
        if let Some(sink) = sink.as_mut() {
            sink(model, t_end, &u)?;
        } else {
            rec.keep_last(t_end, &u);
        }
    }
    let (strain_energy, kinetic_energy) = rec
        .history
        .last()
        .map(|h| (h.strain_energy, h.kinetic_energy))
        .unwrap_or((0.0, 0.0));
    let (linear_end, angular_end) = momentum(&model.mass, &model.nodes, &u, &u_prev, time.dt_prev);
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
        dt: time.dt,
        dt_critical: dt_crit,
        critical,
        steps: step,
        load_steps: (!dynamic).then_some(load_steps),
        simulated_time: time.time(step),
        converged: dynamic || relax.converged,
        history: rec.history,
        relaxation: relax.records,
        frames: rec.frames,
        external_work: ledger.external_work,
        peak_external_work: ledger.peak_external_work,
        initial_kinetic: ledger.initial_kinetic,
        damping_dissipation: ledger.damping_dissipation,
        strain_energy,
        kinetic_energy,
        solve_seconds,
        restarts: Vec::new(),
        failed_steps: 0,
        step_updates: updates,
    })
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
