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
    /// The kept factor of an earlier tangent: CG is abandoned half way to its limit where
    /// its rate would take it past [`CG_ABANDON`] x the limit ([`cg_check`]).
    Kept,
    /// As `Kept`, but run to the limit: its last iterate is used where it does not converge.
    Probe,
}

/// The earliest iteration at which a CG run with the kept factor is judged ([`Cg::Kept`]).
const CG_CHECK: usize = 6;

/// The iteration at which a CG run with the kept factor and a limit of `limit` iterations
/// is judged: half way, not before [`CG_CHECK`]. Judged at 6 iterations from the start
/// (2026-12-01, twenty-third session), the MNI brain's Newton iterations from the unloaded
/// state lost five runs that converged at 17-23 of 28: with a factor that lacks the stiffness
/// of points that came into contact since, the residual stood at 0.85-0.97 of the right-hand
/// side after 6 iterations, or rose to 2-2.5x it first and fell after (CG resolving the few
/// eigenvalues the factor misses). The refactorizations instead changed its path, and the
/// solve stopped at 99.8 % of the load and fell back to relaxation (59.6 s against 44.3 s,
/// converged, without the rule).
fn cg_check(limit: usize) -> usize {
    (limit / 2).max(CG_CHECK)
}

/// A CG run with the kept factor is abandoned at [`cg_check`] where the iterations to the
/// forcing term, extrapolated at its rate since its largest residual so far
/// ([`bound_to_miss`]), exceed this many times its limit: the limit is what a factorization
/// costs in CG iterations, and a run bound to reach it wastes them all before the
/// factorization it ends in. The five runs that failed on the benchmark's c4 (tet10, 73,092
/// DOFs, limit 24) stood at 0.18-0.48 of |b| after 12 iterations and extrapolated to 31-72
/// iterations (three abandoned); the MNI brain's runs that converged extrapolated to 16-19.
/// Not on the first iteration of a load step ([`Cg::Probe`]), whose last iterate is used.
const CG_ABANDON: f64 = 1.5;

/// The iterations a CG run would take to bring its residual to `eta` |b|, extrapolated from
/// `history` (|r_j| / |b| for j = 1..k) at its rate since its largest residual (|b| itself
/// where none was larger), where they exceed [`CG_ABANDON`] x `limit`; None where the run
/// is to go on. The rate is taken from the largest residual, not from |b|, so that a run
/// whose residual first rose (the MNI brain's rose to 2-2.5 |b| in 3-4 iterations) is
/// judged by how it falls.
fn bound_to_miss(history: &[f64], limit: usize, eta: f64) -> Option<f64> {
    let k = history.len();
    let last = *history.last()?;
    let (top_at, top) =
        history.iter().enumerate().fold(
            (0, 1.0),
            |(ja, a), (j, &x)| if x > a { (j + 1, x) } else { (ja, a) },
        );
    let rate = if k > top_at {
        (last / top).ln() / (k - top_at) as f64
    } else {
        0.0
    };
    let needed = if rate < 0.0 {
        k as f64 + (eta / last).ln() / rate
    } else {
        f64::INFINITY
    };
    (needed > CG_ABANDON * limit as f64).then_some(needed)
}

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
        let check = cg_check(limit);
        let mut history = Vec::with_capacity(limit);
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
            history.push(rnorm / bnorm);
            if run == Cg::Kept && k == check && k < limit {
                if let Some(needed) = bound_to_miss(&history, limit, eta) {
                    log::debug!(
                        "    CG abandoned at {k} of {limit} iterations: {:.2e} of the right-hand \
                         side, {needed:.0} iterations to {eta:.1e} at its rate since its largest",
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
    use super::{bound_to_miss, cg_check, Cg, CG_CHECK};
    use crate::solver::integrate::{Mode, Settings};

    /// CG preconditioned by the factor of a tet4-anp box of Poisson's ratio 0.3 (unloaded,
    /// 10,530 DOFs): on the tangent of the same box at 0.499 the run is abandoned at its
    /// check, half way to its limit (23), and the same run taken to the limit misses the
    /// forcing term too; on the tangent at 0.485, which converges after the check (in 18),
    /// both give the same bits.
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
        assert!(
            !kept && kept_its == cg_check(probe_its),
            "{kept} after {kept_its}"
        );
        assert!(!probe, "the run to the limit ({probe_its}) converged");
        let (kept, kept_its, xk) = run(0.485, Cg::Kept);
        let (probe, probe_its, xp) = run(0.485, Cg::Probe);
        eprintln!("near: both converged in {kept_its}");
        assert!(
            kept && probe && kept_its == probe_its,
            "{kept} {kept_its} {probe} {probe_its}"
        );
        assert!(
            kept_its > cg_check(probe_its),
            "converged in {kept_its}, before the check"
        );
        assert!(xk.iter().zip(&xp).all(|(a, c)| a.to_bits() == c.to_bits()));
    }

    /// Residual histories (|r_j| / |b|, to the two digits logged) of CG runs with a kept
    /// factor, 2026-12-01, judged at their checks. The MNI brain's Newton iterations from the
    /// unloaded state (limit 28, judged at 14): five runs that converged at 17-23 go on,
    /// though judged at 6 iterations by the mean rate from |b| (the rule before) each was
    /// abandoned, extrapolated to 85-490. The benchmark's c4 (limit 24, judged at 12): the
    /// three of its five failures that stood furthest from their forcing terms are
    /// abandoned.
    #[test]
    fn runs_that_rise_before_they_fall_are_not_abandoned() {
        #[rustfmt::skip]
        let converged: [(f64, [f64; 14]); 5] = [
            (0.077, [0.94, 2.01, 2.54, 1.83, 1.3, 0.85, 0.69, 0.49, 0.43, 0.3, 0.27, 0.22, 0.19, 0.17]),
            (0.083, [0.82, 1.22, 1.88, 2.01, 1.49, 0.97, 0.81, 0.63, 0.56, 0.44, 0.36, 0.32, 0.27, 0.25]),
            (0.1, [0.85, 1.1, 1.69, 1.92, 1.49, 0.86, 0.7, 0.62, 0.56, 0.48, 0.4, 0.36, 0.31, 0.28]),
            (0.1, [0.91, 1.1, 1.08, 1.15, 1.1, 0.85, 0.69, 0.53, 0.42, 0.33, 0.26, 0.22, 0.18, 0.15]),
            (0.1, [0.68, 0.92, 1.35, 1.85, 1.33, 0.93, 0.68, 0.55, 0.43, 0.39, 0.28, 0.25, 0.19, 0.17]),
        ];
        for (eta, h) in &converged {
            assert_eq!(cg_check(28), h.len());
            assert_eq!(bound_to_miss(h, 28, *eta), None, "{h:?}");
            // The rule before: the mean rate over the first 6 from |b|, against twice the limit.
            let before = 6.0 * eta.ln() / h[5].ln();
            assert!(before > 2.0 * 28.0, "{before}");
        }
        #[rustfmt::skip]
        let failed: [(f64, [f64; 12]); 3] = [
            (0.012, [0.8, 0.65, 0.63, 0.71, 0.73, 0.75, 0.71, 0.67, 0.61, 0.57, 0.53, 0.48]),
            (0.014, [0.84, 0.7, 0.77, 0.73, 0.65, 0.48, 0.45, 0.47, 0.52, 0.49, 0.44, 0.37]),
            (0.0013, [0.86, 0.75, 0.76, 0.59, 0.5, 0.45, 0.41, 0.37, 0.34, 0.27, 0.2, 0.19]),
        ];
        for (eta, h) in &failed {
            assert_eq!(cg_check(24), h.len());
            assert!(bound_to_miss(h, 24, *eta).is_some(), "{h:?}");
        }
    }
}
