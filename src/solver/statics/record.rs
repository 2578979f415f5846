//! What the static solve reports as it goes and at its end: the residual history, the
//! history rows and frames at each equilibrium, the load stages, progress lines, the work
//! of the loads along the path (Simpson on parabolas through the equilibria) and the
//! [`RunOutput`].

use std::time::Instant;

use nalgebra::Vector3;

use super::super::integrate::{FrameSink, HistoryRow, Momentum, RunOutput, Stage, StepUpdates};
use super::{Newton, ResidualRow};
use crate::material::Material;
use crate::Result;

impl<M: Material> Newton<'_, M> {
    pub(super) fn push_residual(
        &mut self,
        load: f64,
        iteration: usize,
        r: f64,
        scale: f64,
        update: f64,
    ) {
        let scale = scale.max(self.peak_force).max(f64::MIN_POSITIVE);
        {
            log::debug!(
                "  load {load:.4} it {iteration}: residual {:.3e} update {update:.3e} m, {} points pushing, factorizations {} ({:.2} s, L nnz {}), cg {}, evals {}, assembly {:.2} s, solves {:.2} s, {:.2} s",
                r / scale,
                self.t_state.iter().filter(|s| s.2 > 0.0).count(),
                self.c.factor.factorizations,
                self.c.factor.factor_seconds,
                self.c.factor.factor_nonzeros(),
                self.report.linear_iterations,
                self.force_evaluations,
                self.report.assembly_seconds,
                self.report.solve_seconds,
                self.start.elapsed().as_secs_f64()
            );
        }
        self.report.residual_history.push(ResidualRow {
            load,
            iteration,
            residual: r / scale,
            update,
        });
    }

    /// A history row at load fraction `tau` (after its forces were evaluated at u). The work
    /// of every force on the body (loads and reactions) is the integral of F_int . du along
    /// the equilibrium path, by trapezoids between load steps.
    pub(super) fn record_row(&mut self, tau: f64) {
        let m = &mut *self.model;
        let se = m.forces.strain_energy(&m.points, &m.slots, &self.u);
        // The work done on the body equals its internal forces' at equilibrium, whatever
        // applies them (loads, prescribed values, constraints, contact).
        let f_int = if self.f_int.is_empty() {
            &self.f
        } else {
            &self.f_int
        };
        // The work of F_int along the path through the rows, parametrised by its chord
        // length: F_int and u interpolated by the parabola through the last three rows, their
        // product integrated exactly over the newest interval; the first interval by a
        // trapezoid until a third row comes, then by the parabola too (the earlier rows'
        // work corrected). The trapezoids over the brain's two load steps under the punch
        // gave 1.0 % more work than strain energy.
        let chord = self.work_state.last().map_or(0.0, |(t, u0, _)| {
            t + u0
                .iter()
                .zip(&self.u)
                .map(|(a, b)| (b - a).norm_squared())
                .sum::<f64>()
                .sqrt()
        });
        if self.work_state.len() == 3 {
            self.work_state.remove(0);
        }
        self.work_state.push((chord, self.u.clone(), f_int.clone()));
        let ws = &self.work_state;
        match ws.len() {
            2 if ws[1].0 > ws[0].0 => {
                let w: f64 = (0..self.u.len())
                    .map(|i| 0.5 * (ws[0].2[i] + ws[1].2[i]).dot(&(ws[1].1[i] - ws[0].1[i])))
                    .sum();
                self.first_trapezoid = Some(w);
                self.external_work += w;
            }
            3 if ws[2].0 > ws[1].0 && ws[1].0 > ws[0].0 => {
                self.external_work += work_on_parabola(ws, 1);
                if let Some(trap) = self.first_trapezoid.take() {
                    let fix = work_on_parabola(ws, 0) - trap;
                    self.external_work += fix;
                    // The rows from the end of the first interval on.
                    let n = self.history.len();
                    for h in &mut self.history[n - 1..] {
                        h.external_work += fix;
                    }
                }
            }
            _ => {}
        }
        if !m.f_ext.is_empty() {
            m.f_ext.clone_from(&self.fe);
        }
        let reactions = m.reaction_rows(&self.f);
        self.peak_force = self
            .peak_force
            .max(self.f.iter().map(|v| v.amax()).fold(0.0, f64::max));
        self.peak_work = self.peak_work.max(self.external_work.abs());
        self.history.push(HistoryRow {
            step: self.report.newton_iterations,
            time: tau,
            reactions,
            external_work: self.external_work,
            strain_energy: se,
            kinetic_energy: 0.0,
        });
    }

    /// Keeps the state at load stage `load`.
    pub(super) fn stage(&mut self, load: f64) -> Result<()> {
        let reactions = self.model.reaction_rows(&self.f);
        self.stages.push(Stage {
            load,
            step: self.report.newton_iterations,
            reactions,
            u: self.u.clone(),
        });
        Ok(())
    }

    pub(super) fn frame(&mut self, t: f64, sink: &mut Option<&mut FrameSink<'_, M>>) -> Result<()> {
        if let Some(sink) = sink.as_mut() {
            let t0 = Instant::now();
            sink(self.model, t, &self.u)?;
            self.sink_seconds += t0.elapsed().as_secs_f64();
        } else {
            self.frames.push((t, self.u.clone()));
        }
        Ok(())
    }

    pub(super) fn progress(&mut self, tau: f64) {
        let every = match (self.s.progress_lines, self.s.progress) {
            (Some(e), _) => e,
            (None, true) => 0.0,
            _ => return,
        };
        if self.last_progress.elapsed().as_secs_f64() >= every || tau >= 1.0 {
            self.last_progress = Instant::now();
            let r = self
                .report
                .residual_history
                .last()
                .map_or(0.0, |h| h.residual);
            eprintln!(
                "static: {:.1} % of the load, {} load steps, {} Newton iterations, {} factorizations, \
                 residual {r:.2e}, {:.1} s",
                100.0 * tau,
                self.report.load_steps,
                self.report.newton_iterations,
                self.c.factor.factorizations,
                self.start.elapsed().as_secs_f64()
            );
        }
    }

    /// A path of one interval (one load step) has no third state for the parabola of
    /// [`Self::record_row`]: its work by Simpson's rule on the straight segment instead (F_int
    /// is the gradient of the strain energy, so any path between the two gives the same), the
    /// forces at its midpoint evaluated, then those at u again for what reads them after.
    /// The exact cube's one load step: the trapezoid gave 9 % more work than strain energy.
    pub(super) fn simpson_work(&mut self) {
        let (Some(trap), 2) = (self.first_trapezoid, self.work_state.len()) else {
            return;
        };
        let ws = &self.work_state;
        let mid: Vec<Vector3<f64>> = ws[0]
            .1
            .iter()
            .zip(&ws[1].1)
            .map(|(a, b)| 0.5 * (a + b))
            .collect();
        let m = &mut *self.model;
        let mut f_mid = vec![Vector3::zeros(); mid.len()];
        m.forces.compute(&m.points, &m.slots, &mid, &mut f_mid);
        let valid = m.forces.min_j().0 > 0.0;
        let mut at_u = vec![Vector3::zeros(); mid.len()];
        m.forces.compute(&m.points, &m.slots, &self.u, &mut at_u);
        self.force_evaluations += 2;
        if !valid {
            return;
        }
        let w: f64 = (0..mid.len())
            .map(|i| {
                (ws[0].2[i] + 4.0 * f_mid[i] + ws[1].2[i]).dot(&(ws[1].1[i] - ws[0].1[i])) / 6.0
            })
            .sum();
        let fix = w - trap;
        self.first_trapezoid = None;
        self.external_work += fix;
        if let Some(h) = self.history.last_mut() {
            h.external_work += fix;
        }
    }

    /// The run's output.
    pub(super) fn finish(&mut self) -> RunOutput {
        self.constraint_reactions();
        self.contact_state();
        self.simpson_work();
        let m = &mut *self.model;
        if !m.f_ext.is_empty() {
            m.f_ext.clone_from(&self.fe);
        }
        self.report.factorizations = self.c.factor.factorizations;
        self.report.single_factorizations = self.c.factor.single_factorizations;
        self.report.modified_factorizations = self.c.factor.modified_factorizations;
        self.report.factor_bytes = self.c.peak_bytes(self.model.points.len());
        self.report.factor_seconds = self.c.factor.factor_seconds;
        let strain_energy = self.history.last().map_or(0.0, |h| h.strain_energy);
        RunOutput {
            device: "cpu".into(),
            device_setup_seconds: 0.0,
            u: self.u.clone(),
            u_prev: self.u.clone(),
            f_int: self.f.clone(),
            dt: 0.0,
            dt_critical: 0.0,
            critical: super::super::integrate::Critical::Node(0),
            steps: self.report.newton_iterations,
            load_steps: Some(self.report.load_steps),
            simulated_time: self.tau_of(self.report.load_reached),
            converged: self.converged,
            history: std::mem::take(&mut self.history),
            relaxation: Vec::new(),
            frames: std::mem::take(&mut self.frames),
            external_work: self.external_work,
            peak_external_work: self.peak_work,
            initial_kinetic: 0.0,
            damping_dissipation: 0.0,
            momentum: Momentum::default(),
            strain_energy,
            kinetic_energy: 0.0,
            solve_seconds: self.start.elapsed().as_secs_f64() - self.sink_seconds,
            restarts: Vec::new(),
            notes: std::mem::take(&mut self.notes),
            failed_steps: 0,
            step_updates: StepUpdates::default(),
            stages: std::mem::take(&mut self.stages),
            peak_nodal_force: self.peak_force,
            force_evaluations: self.force_evaluations,
            statics: Some(std::mem::take(&mut self.report)),
        }
    }
}

/// The work of F along the path through three states (t_k, u_k, F_k) (t the chord length)
/// over the interval [t_m, t_m+1]: the integral of F(t) . u'(t) with F and u the parabolas
/// through the three, exact by two Gauss points (the integrand is a cubic).
pub(super) fn work_on_parabola(
    ws: &[(f64, Vec<Vector3<f64>>, Vec<Vector3<f64>>)],
    m: usize,
) -> f64 {
    let t = [ws[0].0, ws[1].0, ws[2].0];
    let basis = |x: f64| -> ([f64; 3], [f64; 3]) {
        let mut l = [0.0; 3];
        let mut dl = [0.0; 3];
        for k in 0..3 {
            let (i, j) = ((k + 1) % 3, (k + 2) % 3);
            let den = (t[k] - t[i]) * (t[k] - t[j]);
            l[k] = (x - t[i]) * (x - t[j]) / den;
            dl[k] = (2.0 * x - t[i] - t[j]) / den;
        }
        (l, dl)
    };
    let (a, b) = (t[m], t[m + 1]);
    let g = 0.5 / 3f64.sqrt();
    let mut weights = [[0.0; 3]; 3];
    for x in [0.5 - g, 0.5 + g] {
        let (l, dl) = basis(a + x * (b - a));
        for j in 0..3 {
            for k in 0..3 {
                weights[j][k] += 0.5 * (b - a) * l[j] * dl[k];
            }
        }
    }
    let mut w = 0.0;
    for j in 0..3 {
        for k in 0..3 {
            if weights[j][k] != 0.0 {
                w += weights[j][k]
                    * ws[j]
                        .2
                        .iter()
                        .zip(&ws[k].1)
                        .map(|(f, u)| f.dot(u))
                        .sum::<f64>();
            }
        }
    }
    w
}
