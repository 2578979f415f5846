//! Linear constraints in the static solve (EBCIEM and SEBCIEM rows, measured displacements
//! on meshless nodes): their targets at a load fraction, penalties and multipliers (an
//! augmented Lagrangian; where the rows spread, the multipliers' update solved by GMRES
//! through the kept factor), their stiffness and reactions.

use std::time::Instant;

use nalgebra::{Matrix3, Vector3};

use super::{krylov, Newton};
use crate::material::Material;

/// The share of `solver.tolerance` (m) below which the linear constraints count as met.
pub(super) const CONSTRAINT_SHARE: f64 = 1e-2;

impl<M: Material> Newton<'_, M> {
    /// Sets the constraints' targets at load fraction `tau`.
    pub(super) fn set_targets(&mut self, tau: f64) {
        if self.rows.is_empty() {
            return;
        }
        if let Some(now) = self
            .model
            .corrector
            .as_ref()
            .and_then(|c| c.linear_constraints(tau))
        {
            for (r, n) in self.rows.iter_mut().zip(now) {
                r.target = n.target;
            }
        }
    }

    /// Largest constraint violation, m.
    pub(super) fn worst_violation(&self) -> f64 {
        self.rows
            .iter()
            .map(|lc| violation(lc, &self.u).abs())
            .fold(0.0, f64::max)
    }

    /// The penalties, once, from the first tangent: BETA x the stiffness of the row's nodes
    /// along its axis (weighted by the row), so one multiplier update leaves about 1 / BETA of
    /// the violation.
    pub(super) fn set_penalties(&mut self) {
        const BETA: f64 = 1e3;
        if self.penalty.len() == self.rows.len() {
            return;
        }
        self.penalty = self
            .rows
            .iter()
            .map(|lc| {
                let (mut k, mut w2) = (0.0, 0.0);
                for &(j, w) in &lc.row {
                    k += w * w * self.c.tangent.diagonal(j as usize)[(lc.axis, lc.axis)];
                    w2 += w * w;
                }
                BETA * (k / w2.max(f64::MIN_POSITIVE)).abs()
            })
            .collect();
    }

    /// The constraints' multiplier update once Newton has converged at the current ones.
    /// With the forces spread by the rows (SEBCIEM) the augmented Lagrangian's
    /// lambda += k c, which leaves about 1 / BETA of the violation. With EBCIEM's spread V
    /// that update does not contract (V is not Phi^T, nor of its scale): the change that
    /// removes the violation c to first order, Phi K^-1 V dlambda = c with the kept factor of
    /// K (its penalty stiffness included), solved by GMRES, each product a pair of triangular
    /// solves; an inexact factor only costs another Newton pass and update.
    pub(super) fn update_multipliers(&mut self) {
        if self.rows.iter().all(|lc| lc.spread.is_none()) || self.c.factor.kind().is_none() {
            for i in 0..self.rows.len() {
                self.lambda[i] += self.penalty[i] * violation(&self.rows[i], &self.u);
            }
            return;
        }
        let t0 = Instant::now();
        let c: Vec<f64> = self.rows.iter().map(|lc| violation(lc, &self.u)).collect();
        // Right preconditioner: the inverse diagonal of Phi K^-1 V with K^-1 taken as the
        // penalty's 1 / k (exact where the penalty dominates the row's stiffness).
        let d: Vec<f64> = self
            .rows
            .iter()
            .zip(&self.penalty)
            .map(|(lc, &k)| {
                let v = lc.spread.as_deref().unwrap_or(&lc.row);
                let pv: f64 = lc
                    .row
                    .iter()
                    .map(|&(j, w)| w * v.iter().find(|e| e.0 == j).map_or(0.0, |e| e.1))
                    .sum();
                if pv > 0.0 && k > 0.0 {
                    k / pv
                } else {
                    1.0
                }
            })
            .collect();
        let (rows, dofs, factor) = (&self.rows, &self.c.dofs, &self.c.factor);
        let n = self.u.len();
        let mut nodal = vec![Vector3::zeros(); n];
        let mut free = vec![0.0; dofs.len];
        let apply = |x: &[f64], out: &mut [f64]| {
            nodal.iter_mut().for_each(|v| *v = Vector3::zeros());
            for (lc, &xi) in rows.iter().zip(x) {
                for &(j, w) in lc.spread.as_deref().unwrap_or(&lc.row) {
                    nodal[j as usize][lc.axis] += w * xi;
                }
            }
            dofs.gather(&nodal, &mut free);
            factor.solve(&mut free);
            dofs.scatter(&free, &mut nodal);
            for (lc, o) in rows.iter().zip(out.iter_mut()) {
                *o = lc
                    .row
                    .iter()
                    .map(|&(j, w)| w * nodal[j as usize][lc.axis])
                    .sum();
            }
        };
        let (dl, outcome) = krylov::gmres(apply, &d, &c, 1e-6, 50, 500);
        for (l, x) in self.lambda.iter_mut().zip(dl) {
            *l += x;
        }
        self.report.multiplier_iterations += outcome.iterations;
        self.report.solve_seconds += t0.elapsed().as_secs_f64();
        log::debug!(
            "    EBCIEM multipliers: {} GMRES products, relative residual {:.2e}",
            outcome.iterations,
            outcome.relative_residual
        );
    }

    /// Adds the penalties' stiffness k w w^T to the assembled tangent.
    pub(super) fn add_constraint_stiffness(&mut self) {
        for (i, lc) in self.rows.iter().enumerate() {
            let k = self.penalty[i];
            for &(a, wa) in &lc.row {
                for &(b, wb) in &lc.row {
                    let mut m = Matrix3::zeros();
                    m[(lc.axis, lc.axis)] = k * wa * wb;
                    self.c.tangent.add(a as usize, b as usize, &m);
                }
            }
        }
    }

    /// The force each boundary's constraints apply to the body, N (negative of their share of
    /// the residual's constraint forces), handed to the corrector as its reactions.
    pub(super) fn constraint_reactions(&mut self) {
        if self.rows.is_empty() {
            return;
        }
        let nb = self.model.boundaries.len();
        let mut r = vec![Vector3::zeros(); nb];
        for (i, lc) in self.rows.iter().enumerate() {
            let pen = self.penalty.get(i).copied().unwrap_or(0.0) * violation(lc, &self.u);
            let sum = |v: &[(u32, f64)]| v.iter().map(|&(_, w)| w).sum::<f64>();
            let f =
                self.lambda[i] * sum(lc.spread.as_deref().unwrap_or(&lc.row)) + pen * sum(&lc.row);
            if let Some(rb) = r.get_mut(lc.boundary) {
                rb[lc.axis] -= f;
            }
        }
        if let Some(c) = self.model.corrector.as_mut() {
            c.set_reactions(&r);
        }
    }
}

/// The constraint's violation, row . u_axis - target, m.
pub(super) fn violation(lc: &crate::solver::LinearConstraint, u: &[Vector3<f64>]) -> f64 {
    lc.row
        .iter()
        .map(|&(j, w)| w * u[j as usize][lc.axis])
        .sum::<f64>()
        - lc.target
}
