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

/// How a CG run with the kept factor may end before its limit of iterations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Cg {
    /// The factor is of this tangent: CG refines its solve up to the limit.
    Fresh,
    /// The kept factor of an earlier tangent: CG is abandoned at [`CG_CHECK`] iterations
    /// where its rate so far would take more than [`CG_ABANDON`] x the limit to converge.
    Kept,
    /// As `Kept`, but run to the limit: its last iterate is used where it does not converge.
    Probe,
}

/// The iteration at which a CG run with the kept factor is judged ([`Cg::Kept`]).
const CG_CHECK: usize = 6;
/// A CG run with the kept factor is abandoned where the iterations to the forcing term,
/// extrapolated from its mean rate over its first [`CG_CHECK`] (k ln(eta) / ln(|r_k| /
/// |b|)), exceed this many times its limit: the limit is what a factorization costs in CG
/// iterations, and a run bound to reach it wastes them all before the factorization it ends
/// in. The five runs that failed on the benchmark's c4 (tet10, 73,092 DOFs, limit 24) stood
/// at 0.45-0.75 of |b| after 6 iterations, extrapolated to 33-111 iterations (three beyond
/// 48); those that converged, to 6-15. cylinder-mixed's slowest success extrapolated to 1.29
/// x its limit (it converged at 39 of 40), brain-indentation's to 1.05 x. With it, c4's CG
/// iterations fell from 330 to 276 and its run from 20.0 to 17.8 s on 2 cores, every Newton
/// iterate the same: an abandoned run's factorization and fresh solve do not depend on it.
/// Not on the first iteration of a load step ([`Cg::Probe`]), whose last iterate is used.
const CG_ABANDON: f64 = 2.0;

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
            if self.pcg(b, eta, Cg::Fresh) {
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
        } else if !self.pcg(b, eta, Cg::Kept) {
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
    /// limit of iterations (at most [`CG_LIMIT`]; with a [`Cg::Fresh`] factor, failing costs
    /// a factorization in double precision, so the limit is CG_LIMIT), is abandoned as
    /// bound to miss it ([`CG_ABANDON`]), or meets a direction of non-positive curvature.
    pub(super) fn pcg(&mut self, b: &mut [f64], eta: f64, run: Cg) -> bool {
        let fresh = run == Cg::Fresh;
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
        for k in 1..=limit {
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
            let rnorm = dot(&r, &r).sqrt();
            if rnorm <= eta * bnorm {
                b.copy_from_slice(&x);
                done = true;
                break;
            }
            if run == Cg::Kept && k == CG_CHECK && k < limit {
                let rate = (rnorm / bnorm).ln() / k as f64;
                let needed = if rate < 0.0 {
                    eta.ln() / rate
                } else {
                    f64::INFINITY
                };
                if needed > CG_ABANDON * limit as f64 {
                    log::debug!(
                        "    CG abandoned at {k} of {limit} iterations: {:.2e} of the right-hand \
                         side, {needed:.0} iterations to {eta:.1e} at that rate",
                        rnorm / bnorm
                    );
                    break;
                }
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

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use nalgebra::Vector3;

    use super::super::factor::tests::box_at;
    use super::super::factor::Factor;
    use super::super::tangent::Tangent;
    use super::super::{Cache, Newton};
    use super::{Cg, CG_CHECK};
    use crate::solver::integrate::{Mode, Settings};

    /// CG preconditioned by the factor of a tet4-anp box of Poisson's ratio 0.3 (unloaded,
    /// 10,530 DOFs) on the tangent of the same box at 0.499: the run is abandoned at CG_CHECK
    /// iterations, and the same run taken to its limit (23) misses the forcing term too; on
    /// the tangent at 0.45, which converges after the check (in 9), both give the same bits.
    #[test]
    fn cg_with_a_stale_factor_is_abandoned_only_where_it_would_fail() {
        let cells = [14, 12, 18];
        let at_rest = |_: &Vector3<f64>| Vector3::zeros();
        let (base, u, dofs, b) = box_at(0.3, cells, at_rest);
        let mut tangent = Tangent::new(&base, &[], false);
        tangent.assemble(&base, &u);
        let mut factor = Factor::new(&tangent, &dofs, &base.nodes).unwrap();
        factor.factor(&tangent, false).unwrap();
        let mut cache = Cache {
            tangent,
            factor,
            dofs,
        };
        let s = Settings {
            mode: Mode::Static,
            ..Settings::default()
        };
        let mut run = |nu: f64, how: Cg| {
            let (mut model, ..) = box_at(nu, cells, at_rest);
            let mut st = Newton::new(&mut model, &s, &mut cache, Instant::now());
            st.assemble();
            let mut x = b.clone();
            let ok = st.pcg(&mut x, 1e-4, how);
            (ok, st.report.linear_iterations, x)
        };
        let (kept, kept_its, _) = run(0.499, Cg::Kept);
        let (probe, probe_its, _) = run(0.499, Cg::Probe);
        eprintln!("far: abandoned at {kept_its}, the run to the limit missed at {probe_its}");
        assert!(
            probe_its > 2 * CG_CHECK,
            "a limit of {probe_its} iterations"
        );
        assert!(!kept && kept_its == CG_CHECK, "{kept} after {kept_its}");
        assert!(!probe, "the run to the limit ({probe_its}) converged");
        let (kept, kept_its, xk) = run(0.45, Cg::Kept);
        let (probe, probe_its, xp) = run(0.45, Cg::Probe);
        eprintln!("near: both converged in {kept_its}");
        assert!(
            kept && probe && kept_its == probe_its,
            "{kept_its} {probe_its}"
        );
        assert!(
            kept_its > CG_CHECK,
            "converged in {kept_its}, before the check"
        );
        assert!(xk.iter().zip(&xp).all(|(a, c)| a.to_bits() == c.to_bits()));
    }
}
