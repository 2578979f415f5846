//! Adaptive dynamic relaxation (Joldes, Wittek & Miller 2011): the convergence rate r of the
//! update u(n+1) = A M^-1 (F_ext - F_int) + (1 + r^2) u(n) - r^2 u(n-1), set from estimates of
//! the lowest frequency, and the stopping test on the estimated distance to the solution.

use nalgebra::Vector3;

use super::RelaxationRecord;

/// Steps the error estimate must stay below the tolerance before the run stops.
const CONVERGED_STEPS: usize = 100;

/// Dynamic-relaxation rate from the lowest frequency: k = 2 / (w_min dt), r = (k - 1) / (k + 1).
fn rate_from_omega(omega: f64, dt: f64) -> f64 {
    let k = 2.0 / (omega * dt);
    ((k - 1.0) / (k + 1.0)).clamp(0.0, 0.99999)
}

/// The rate in use, the frequency estimates behind it and the convergence test.
pub(super) struct Relaxation {
    /// The convergence rate in use.
    pub(super) r: f64,
    /// The last estimate of the lowest frequency, rad/s: a new one is accepted when it agrees
    /// with it to 5 %.
    omega_prev: Option<f64>,
    /// The lowest frequency behind the rate in use (rad/s), to set the rate again for a
    /// shorter step.
    omega_in_use: Option<f64>,
    /// The step of the saved reference state (None until the load is fully applied).
    ref_step: Option<usize>,
    /// Displacements (m) and internal forces (N) at the reference state: the frequency comes
    /// from their changes since.
    u_ref: Vec<Vector3<f64>>,
    f_ref: Vec<Vector3<f64>>,
    /// Steps between frequency estimates.
    interval: usize,
    /// Stop when the error estimate stays below this for [`CONVERGED_STEPS`] steps, m.
    tolerance: f64,
    /// Consecutive steps with the error estimate below the tolerance.
    below: usize,
    /// Estimated distance to the converged solution, m.
    pub(super) err_est: f64,
    /// The error estimate stayed below the tolerance long enough.
    pub(super) converged: bool,
    pub(super) records: Vec<RelaxationRecord>,
}

impl Relaxation {
    /// For `n` nodes (0 in a dynamic run, which uses none of it) and a load applied over
    /// `load_steps` steps: until the load is fully applied the rate follows the loading,
    /// r = 1 - 10 / load_steps (in 0.5..0.999).
    pub(super) fn new(n: usize, load_steps: usize, interval: usize, tolerance: f64) -> Self {
        Relaxation {
            r: (1.0 - 10.0 / load_steps.max(20) as f64).clamp(0.5, 0.999),
            omega_prev: None,
            omega_in_use: None,
            ref_step: None,
            u_ref: vec![Vector3::zeros(); n],
            f_ref: vec![Vector3::zeros(); n],
            interval: interval.max(1),
            tolerance,
            below: 0,
            err_est: f64::INFINITY,
            converged: false,
            records: Vec::new(),
        }
    }

    /// A warm start: the rate from the lowest frequency `omega` (rad/s) a previous relaxation
    /// of the model settled on, kept by the first observation (which otherwise sets it from
    /// the Rayleigh quotient of the loaded shape).
    pub(super) fn start_at(&mut self, omega: f64, dt: f64) {
        if omega > 0.0 && omega.is_finite() {
            self.r = rate_from_omega(omega, dt);
            self.omega_in_use = Some(omega);
        }
    }

    /// The rate for a step shortened to `dt` (s), from the frequency in use.
    pub(super) fn shorten(&mut self, dt: f64) {
        if let Some(w) = self.omega_in_use {
            self.r = rate_from_omega(w, dt);
        }
    }

    /// Whether [`Self::observe`] at `step` reads the displacements and forces.
    pub(super) fn wants_state(&self, step: usize) -> bool {
        self.ref_step.is_none_or(|r| step >= r + self.interval)
    }

    /// A step under the full load with displacements `u` (m), internal forces `f` (N), its
    /// largest change `max_du` (m) and length `dt` (s). The first sets the rate from the
    /// Rayleigh quotient of the loaded shape over all DOFs; every `interval` steps after,
    /// omega_min^2 = du.dF / du.M.du over the free DOFs (`mask` false) against the saved
    /// state, accepted when two in a row agree to 5 %. The error estimate is
    /// max_du r' / (1 - r') with r' = r + 0.2 (1 - r).
    pub(super) fn observe(
        &mut self,
        step: usize,
        (u, f): (&[Vector3<f64>], &[Vector3<f64>]),
        (mass, mask): (&[f64], &[[bool; 3]]),
        max_du: f64,
        dt: f64,
    ) {
        if self.ref_step.is_none() {
            let num: f64 = u.iter().zip(f).map(|(x, y)| x.dot(y)).sum();
            let den: f64 = u.iter().zip(mass).map(|(x, m)| m * x.norm_squared()).sum();
            if num > 0.0 && den > 0.0 && self.omega_in_use.is_none() {
                self.r = rate_from_omega((num / den).sqrt(), dt);
                self.omega_in_use = Some((num / den).sqrt());
            }
            self.save(step, u, f);
        } else if self.ref_step.is_some_and(|r| step >= r + self.interval) {
            let (mut num, mut den) = (0.0, 0.0);
            for i in 0..u.len() {
                for k in 0..3 {
                    if !mask[i][k] {
                        let du = u[i][k] - self.u_ref[i][k];
                        num += du * (f[i][k] - self.f_ref[i][k]);
                        den += mass[i] * du * du;
                    }
                }
            }
            if num > 0.0 && den > 0.0 {
                let omega = (num / den).sqrt();
                let accepted = self
                    .omega_prev
                    .is_some_and(|w| (omega - w).abs() <= 0.05 * omega);
                if accepted {
                    self.r = rate_from_omega(omega, dt);
                    self.omega_in_use = Some(omega);
                }
                self.omega_prev = Some(omega);
                let rp = self.r + 0.2 * (1.0 - self.r);
                self.records.push(RelaxationRecord {
                    step,
                    omega_min: omega,
                    r: self.r,
                    accepted,
                    error_estimate: max_du * rp / (1.0 - rp),
                });
            }
            self.save(step, u, f);
        }
        let rp = self.r + 0.2 * (1.0 - self.r);
        self.err_est = max_du * rp / (1.0 - rp);
        if self.err_est < self.tolerance {
            self.below += 1;
            if self.below >= CONVERGED_STEPS {
                self.converged = true;
            }
        } else {
            self.below = 0;
        }
    }

    fn save(&mut self, step: usize, u: &[Vector3<f64>], f: &[Vector3<f64>]) {
        self.u_ref.copy_from_slice(u);
        self.f_ref.copy_from_slice(f);
        self.ref_step = Some(step);
    }
}
