//! The linear solves of a Newton iteration, K_ff du = r: a new factorization, the kept
//! factor's modified-Newton step, and conjugate gradients on the current tangent
//! preconditioned by the kept factor, refactored only where CG would cost more.

use std::time::Instant;

use super::factor::Kind;
use super::{Newton, Variant, CG_LIMIT};
use crate::material::Material;
use crate::Result;

/// How many times more multiply-adds per second a factorization does than a CG iteration.
const FACTOR_EFFICIENCY: f64 = 9.0;

impl<M: Material> Newton<'_, M> {
    pub(super) fn refactor(&mut self, double: bool) -> Result<Kind> {
        let k = self.c.factor.factor(&self.c.tangent, double)?;
        if k == Kind::Modified {
            log::debug!(
                "    tangent not positive definite: {} pivots made positive",
                self.c.factor.changed_pivots
            );
        }
        self.fresh = true;
        self.factor_stale = false;
        Ok(k)
    }

    /// K_ff x = b to the relative residual `eta` with a factor of the current tangent just
    /// made: a single-precision factor's solve refined by conjugate gradients, and where they
    /// do not reach `eta` (a condition number near 1e7, where single precision's rounding
    /// is felt), the tangent factored again in double precision and solved directly.
    pub(super) fn fresh_solve(&mut self, b: &mut [f64], eta: f64) -> Result<()> {
        if self.c.factor.is_single() {
            if self.pcg(b, eta, true) {
                return Ok(());
            }
            self.refactor(true)?;
        }
        self.c.factor.solve(b);
        Ok(())
    }

    /// K_ff x = b for the free DOFs (b in, x out), by the variant's rule; the tangent is
    /// assembled at the current u by the caller where the variant needs it.
    pub(super) fn linear_solve(&mut self, b: &mut [f64], eta: f64) -> Result<()> {
        let t0 = Instant::now();
        let variant = self.s.static_variant;
        let have = self.c.factor.kind().is_some();
        let direct = match variant {
            Variant::Newton => true,
            Variant::Modified => !have || self.factor_stale,
            Variant::NewtonKrylov => {
                !have || self.factor_stale || self.c.factor.kind() == Some(Kind::Modified)
            }
        };
        if direct {
            self.refactor(false)?;
            self.fresh_solve(b, eta)?;
        } else if variant == Variant::Modified {
            self.c.factor.solve(b);
        } else if !self.pcg(b, eta, false) {
            self.refactor(false)?;
            self.fresh_solve(b, eta)?;
        }
        self.report.solve_seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// b = K_old^-1 b with the kept factor as it is (a modified-Newton step).
    pub(super) fn kept_solve(&mut self, b: &mut [f64]) {
        let t0 = Instant::now();
        self.c.factor.solve(b);
        self.report.kept_solves += 1;
        self.report.solve_seconds += t0.elapsed().as_secs_f64();
    }

    /// Conjugate gradients on the current tangent, preconditioned by the kept factor; b is
    /// replaced by the solution. False (b unchanged) when CG does not reach the relative
    /// residual `eta` (the forcing term, at most [`ETA_MAX`](super::ETA_MAX)) within its
    /// limit of iterations (at most [`CG_LIMIT`]; `fresh`: the factor is of this tangent, and
    /// failing costs a factorization in double precision, so the limit is CG_LIMIT) or meets a
    /// direction of non-positive curvature.
    pub(super) fn pcg(&mut self, b: &mut [f64], eta: f64, fresh: bool) -> bool {
        let n = b.len();
        let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
        let bnorm = dot(b, b).sqrt();
        if bnorm == 0.0 {
            return true;
        }
        let mut x = vec![0.0; n];
        let mut r = b.to_vec();
        let mut z = r.clone();
        self.c.factor.solve(&mut z);
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let mut q = vec![0.0; n];
        // A factorization pays once CG would take longer than it. Their costs are counted,
        // not timed, so that the path does not depend on the machine's load: a factorization's
        // multiply-adds against a CG iteration's (two triangular solves and a product with
        // the tangent), a factorization's dense kernels doing FACTOR_EFFICIENCY times more
        // per second (measured 7.8-9.6 on tet4-anp, tet10 and Ogden cases, 2 threads).
        let per_cg =
            4.0 * self.c.factor.factor_nonzeros() as f64 + 18.0 * self.c.tangent.blocks() as f64;
        let limit = if fresh {
            CG_LIMIT
        } else {
            ((self.c.factor.flops / FACTOR_EFFICIENCY / per_cg) as usize).clamp(4, CG_LIMIT)
        };
        let mut done = false;
        for _ in 0..limit {
            self.c.dofs.scatter(&p, &mut self.t0);
            self.c.tangent.multiply(&self.t0, &mut self.t1);
            self.c.dofs.gather(&self.t1, &mut q);
            self.report.linear_iterations += 1;
            self.force_evaluations += 1;
            let pq = dot(&p, &q);
            if !(pq > 0.0) {
                break;
            }
            let alpha = rz / pq;
            for i in 0..n {
                x[i] += alpha * p[i];
                r[i] -= alpha * q[i];
            }
            if dot(&r, &r).sqrt() <= eta * bnorm {
                b.copy_from_slice(&x);
                done = true;
                break;
            }
            z.copy_from_slice(&r);
            self.c.factor.solve(&mut z);
            let rz_new = dot(&r, &z);
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..n {
                p[i] = z[i] + beta * p[i];
            }
        }
        if !done {
            self.cg_partial = x;
        }
        done
    }
}
