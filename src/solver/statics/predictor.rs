//! A load step's start: the prescribed values moved to the step's end, the free nodes placed
//! by extrapolating the load path (a parabola through the last three equilibria, or a line
//! through two), or where there is no path yet or it inverts an element, by the linear
//! predictor u_f += K_ff^-1 (r_f - K_fp du_p).

use nalgebra::Vector3;

use super::{Newton, Variant, CG_TOLERANCE, PREDICTOR_J, PREDICTOR_SHORTEST};
use crate::material::Material;
use crate::Result;

impl<M: Material> Newton<'_, M> {
    /// Whether the model's elements hold their nodes' volumes, not their points', near
    /// incompressible (average nodal pressure): their points' J is no measure of a step.
    fn nodal_pressure(&self) -> bool {
        !self.c.tangent.pressure_units().is_empty()
    }

    /// Places u at the load step's end `lam1` (the load's share) from its start `lam0`;
    /// `cheap`: the kept factor of an earlier state solves the linear predictor as it is.
    /// Returns the largest change of a nodal value it made (m), or None where the step is to
    /// be cut (the linear predictor inverts an element, or either predictor shrinks the
    /// smallest volume ratio below [`PREDICTOR_J`] of its value at the step's start).
    pub(super) fn predict(&mut self, lam0: f64, lam1: f64, cheap: bool) -> Result<Option<f64>> {
        let tau1 = self.tau_of(lam1);
        let n = self.u.len();
        // The prescribed values' change over the step.
        let mut target = self.u.clone();
        self.model.constraints.prescribe(&mut target, tau1);
        let mut delta = vec![Vector3::zeros(); n];
        let mut moved = false;
        for (i, m) in self.model.constraints.mask.iter().enumerate() {
            for k in 0..3 {
                if m[k] {
                    delta[i][k] = target[i][k] - self.u[i][k];
                    moved |= delta[i][k] != 0.0;
                }
            }
        }
        // The predictor: the load path extrapolated from its last converged states, by a
        // parabola through three (the driven rim's stiffening bends the path: on the
        // benchmark's c1, at the same steps, the residual after it fell from 0.39-0.55 of the
        // largest force with a line to 0.07-0.12, and c3 took 52 Newton iterations against
        // 71) or a line through two; where there are none or it inverts an element, the
        // linear one u_f += K_ff^-1 (r_f - K_fp du_p).
        let u0 = self.u.clone();
        let mut last_update = 0.0f64;
        let mut predicted = false;
        self.predictor_factorizations = self.c.factor.factorizations;
        if lam1 > lam0 && self.path.len() >= 2 {
            let w = lagrange_weights(self.path.iter().map(|p| p.0), lam1);
            for i in 0..n {
                for c in 0..3 {
                    self.u[i][c] = if self.model.constraints.mask[i][c] {
                        target[i][c]
                    } else {
                        self.path.iter().zip(&w).map(|(p, w)| w * p.1[i][c]).sum()
                    };
                }
                last_update = last_update.max((self.u[i] - u0[i]).amax());
            }
            let j = self.forces(tau1);
            // As the linear predictor's below: one that shrinks the smallest volume ratio
            // too far is cut at once. Newton's first iterations from it crawled (the
            // benchmark's second load step, 0.1 -> 0.2 of the load: a line search step of
            // 0.21, then a tangent not positive definite, factored in double precision at
            // 1.5 s on c4, before the cut came).
            let j_start = self.path_j;
            if j > 0.0 && !self.nodal_pressure() && j < PREDICTOR_J * j_start {
                log::debug!(
                    "    path predictor cut: min J {j:.4} against {j_start:.4} at the start"
                );
                return Ok(None);
            }
            if j > 0.0 {
                predicted = true;
            } else {
                self.u.clone_from(&u0);
            }
        }
        let mut rhs = vec![0.0; self.c.dofs.len];
        if !predicted {
            self.forces(tau1);
            let j_start = self.min_j.0;
            for i in 0..n {
                self.t0[i] = self.fe[i] - self.f[i];
            }
            // K_fp du_p from the tangent here, not from the last one assembled where that is
            // a rejected step's (after a cut: the predictor from it inverted cylinder-mixed's
            // elements at 1/16 of the load that its own tangent took whole).
            let need_tangent = (moved && self.tangent_stale)
                || (!cheap
                    && (self.s.static_variant != Variant::Modified
                        || self.c.factor.kind().is_none()));
            if need_tangent {
                self.assemble();
            }
            if moved {
                // r_f - K_fp du_p
                self.c.tangent.multiply(&delta, &mut self.t1);
                for i in 0..n {
                    self.t0[i] -= self.t1[i];
                }
            }
            self.c.dofs.gather(&self.t0, &mut rhs);
            if cheap {
                self.kept_solve(&mut rhs);
            } else {
                self.linear_solve(&mut rhs, CG_TOLERANCE)?;
            }
            // A factor the predictor made is of the start: kept for a retry even where the
            // predictor inverts an element below.
            self.predictor_factorizations = self.c.factor.factorizations;
            self.c.dofs.scatter(&rhs, &mut self.t0);
            for i in 0..n {
                self.u[i] += self.t0[i] + delta[i];
            }
            last_update = self
                .t0
                .iter()
                .chain(&delta)
                .map(|v| v.amax())
                .fold(0.0, f64::max);
            let mut j = self.forces(tau1);
            log::debug!("    linear predictor: min J {j:.4}");
            // With rigid contact, a predictor that inverts an element is shortened rather
            // than the load step: the residual a loosely converged sub-step carries swings a
            // body held by contact (its tangent free along the surface where points do not
            // press yet) by millimetres whatever the load step's length. The MNI brain's
            // predictors at 7.74 % of gravity reached J = -17.1 for every cut down to the
            // shortest load step; a quarter at a time, the Newton iterations then take it.
            let mut share = 1.0;
            while !(j > 0.0) && !self.touch.is_empty() && share > PREDICTOR_SHORTEST {
                share *= 0.25;
                for i in 0..n {
                    self.u[i] = u0[i] + self.t0[i] * share + delta[i];
                }
                j = self.forces(tau1);
                log::debug!("    linear predictor x {share:.2e}: min J {j:.4}");
            }
            if !(j > 0.0) {
                return Ok(None);
            }
            // A linear predictor that shrinks the smallest volume ratio below PREDICTOR_J of
            // its value at the step's start has taken the step too long for its tangent: cut
            // now, at the cost of a force evaluation (the retry's predictor reuses this factor
            // of the start), rather than after Newton iterations and factorizations of the
            // states it leads to. Not with average nodal pressure, whose nodes' volumes, not
            // its points', are held near incompressible.
            if lam1 > lam0 && !self.nodal_pressure() && j < PREDICTOR_J * j_start {
                log::debug!("    predictor cut: min J {j:.4} against {j_start:.4} at the start");
                return Ok(None);
            }
        }
        Ok(Some(last_update))
    }
}

/// The Lagrange interpolation weights of the points `at` evaluated at `t`: the polynomial
/// through the points, of degree one less than their number.
pub(super) fn lagrange_weights(at: impl Iterator<Item = f64>, t: f64) -> Vec<f64> {
    let xs: Vec<f64> = at.collect();
    (0..xs.len())
        .map(|i| {
            xs.iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, &xj)| (t - xj) / (xs[i] - xj))
                .product()
        })
        .collect()
}
