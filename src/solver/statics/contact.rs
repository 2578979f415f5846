//! Rigid contact in the static solve: each surface point's penalty and multiplier (an
//! augmented Lagrangian, lambda = max(0, lambda + k d)), the contact stiffness added to the
//! tangent, the push directions kept between load steps, the multipliers a warm start
//! estimates from its residual, and the refusal of a point the boundary conditions hold
//! against the push (docs/methods.md, "Static solve").

use nalgebra::Vector3;

use super::{Newton, STATIC_HELD_SHARE};
use crate::material::Material;
use crate::Error;

/// A contact point's penalty over the mean diagonal stiffness of its nodes. Stiffer
/// penalties need fewer multiplier updates, but the Newton directions overshoot where
/// points come into contact and the active set cycles. A sphere pressed 20 mm into the cube
/// (`tests/contact.rs`): at 1e3, hex8, tet4 and tet4-anp all stall; at 10, hex8 stalls; at 3,
/// all three converge to relaxation's force (286-421 force evaluations). brain-contact
/// (coupled): 34 % of the load in 150 s at 1e3, all of it in 356 s at 10, 12.7 % in 197 s at 3.
const CONTACT_BETA: f64 = 3.0;
/// A warm start's contact point within this share of the mean node spacing of its rigid
/// surface counts as touching it ([`Newton::warm_contact_multipliers`]).
const WARM_CONTACT_SHARE: f64 = 1e-3;

impl<M: Material> Newton<'_, M> {
    /// The contact penalties, once, from the first tangent: [`CONTACT_BETA`] x the mean diagonal
    /// stiffness of the point's nodes.
    pub(super) fn set_contact_penalties(&mut self) {
        if self.t_penalty.len() == self.touch.len() {
            return;
        }
        let Some(ct) = self.model.contact.as_ref() else {
            return;
        };
        self.t_penalty = self
            .touch
            .iter()
            .map(|&(b, i)| {
                let row = &ct.points_of(b as usize)[i as usize].row;
                let (mut k, mut w2) = (0.0, 0.0);
                for &(j, w) in row {
                    k += w * w * self.c.tangent.diagonal(j as usize).trace() / 3.0;
                    w2 += w * w;
                }
                CONTACT_BETA * (k / w2.max(f64::MIN_POSITIVE)).abs()
            })
            .collect();
    }

    /// The active points' stiffness w_a w_b (k n n^T - g sym(dn/dx)): the penalty along the
    /// normal, and the normal's turning under the point's force g ([`Contact::normal_gradient`],
    /// symmetrized as the factorization needs). Without the turning, a node of the 25 mm cube
    /// pressed by a 20 mm ball 24 mm down, sliding around it under 0.9 N (its turning 45 N/m
    /// against about 75 N/m of tissue), crept by 4e-5 m per Newton iteration and the solve stopped
    /// at 91 % of the load.
    ///
    /// [`Contact::normal_gradient`]: crate::bc::contact::Contact::normal_gradient
    pub(super) fn add_contact_stiffness(&mut self) {
        let Some(ct) = self.model.contact.as_ref() else {
            return;
        };
        for (k, &(b, i)) in self.touch.iter().enumerate() {
            let (_, n, g) = self.t_state[k];
            if !(g > 0.0) {
                continue;
            }
            let p = &ct.points_of(b as usize)[i as usize];
            let turn = ct.normal_gradient(
                b as usize,
                p,
                &self.u,
                self.tau_now,
                self.t_hint.get(k).copied().flatten(),
            );
            let nn = n * n.transpose() * self.t_penalty[k] - (turn + turn.transpose()) * (0.5 * g);
            let row = &p.row;
            for &(a, wa) in row {
                for &(c, wc) in row {
                    self.c
                        .tangent
                        .add(a as usize, c as usize, &(nn * (wa * wc)));
                }
            }
        }
    }

    /// A point pressed deeper than the contact's tolerance that the boundary conditions
    /// hold against the push: no multiplier can move it, so the rigid body would pass through
    /// the tissue. The error relaxation gives, naming the contact, the point and the boundary.
    pub(super) fn contact_conflict(&self, tau: f64) -> Option<Error> {
        let ct = self.model.contact.as_ref()?;
        let mask = &self.model.constraints.mask;
        let tol = ct.tolerance();
        let k = (0..self.touch.len()).find(|&k| {
            let (depth, n, _) = self.t_state[k];
            let (b, i) = self.touch[k];
            depth > tol
                && ct.points_of(b as usize)[i as usize].held_along(&n, mask, STATIC_HELD_SHARE)
        })?;
        let (b, i) = (self.touch[k].0 as usize, self.touch[k].1 as usize);
        let p = &ct.points_of(b)[i];
        let (depth, n, _) = self.t_state[k];
        let c = crate::bc::contact::Conflict {
            body: b,
            x: p.x,
            depth,
            node: p.main_node(),
            normal: n,
        };
        Some(crate::solver::integrate::contact_conflict(
            self.model,
            &c,
            self.report.load_steps + 1,
            tau,
        ))
    }

    /// The longest load step (a load fraction) over which no rigid surface read from a file
    /// travels more than half the body's mean node spacing ([`Self::mean_spacing`]); 1
    /// without one. Such a surface has a far side: put at its final
    /// place in one step it can end nearer that side than the one it should press. A plate
    /// 30 mm thick driven 20 mm onto the meshless cube met the cube's top 10 mm from its upper
    /// face and pushed it up through the plate (+1.85 N against -7.63 N). Analytic tools are
    /// measured from the side they press (a plane has none other) and keep the full step.
    pub(super) fn contact_step_limit(&self) -> f64 {
        let Some(ct) = self.model.contact.as_ref() else {
            return 1.0;
        };
        const SAMPLES: usize = 64;
        let mut speed = 0.0f64;
        for b in (0..ct.len()).filter(|&b| ct.is_surface(b)) {
            for k in 1..=SAMPLES {
                let (t0, t1) = (
                    self.tau_of((k - 1) as f64 / SAMPLES as f64),
                    self.tau_of(k as f64 / SAMPLES as f64),
                );
                let step = (ct.body_displacement(b, t1) - ct.body_displacement(b, t0)).norm();
                speed = speed.max(step * SAMPLES as f64);
            }
        }
        let spacing = self.mean_spacing();
        if !(speed > 0.0 && spacing > 0.0) {
            return 1.0;
        }
        (0.5 * spacing / speed).min(1.0)
    }

    /// A point deeper than `tol` (m) in a rigid body, or one pushing while off its surface
    /// by more than `tol`: the multipliers are not settled. The second holds where rounds
    /// end before convergence ([`ROUND_CONTRACTION`](super::ROUND_CONTRACTION)): the plate
    /// moved from 10 to 20 mm on the cube, warm, settled at -7.633685 N against the exact
    /// -7.632692 N with a point pushing off the plate; -7.632693 N with it.
    pub(super) fn contact_unsettled(&self, tol: f64) -> bool {
        self.worst_penetration() > tol || self.t_state.iter().any(|&(d, _, g)| g > 0.0 && d < -tol)
    }

    /// Deepest penetration of a candidate point, m (0 without contact).
    pub(super) fn worst_penetration(&self) -> f64 {
        self.t_state.iter().map(|&(d, _, _)| d).fold(0.0, f64::max)
    }

    /// A force the tissue carries, N: the largest shear modulus times the squared mean node
    /// spacing ([`Self::mean_spacing`]).
    pub(super) fn force_scale(&self) -> f64 {
        let mu = self
            .model
            .forces
            .materials
            .iter()
            .map(|x| x.lame().1)
            .fold(0.0, f64::max);
        let h = self.mean_spacing();
        mu * h * h
    }

    /// The body's mean node spacing, m: the cube root of its bounding box's volume per node.
    pub(super) fn mean_spacing(&self) -> f64 {
        let nodes = &self.model.nodes;
        let (lo, hi) = nodes.iter().fold(
            (
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            ),
            |(lo, hi), x| (lo.inf(x), hi.sup(x)),
        );
        let e = hi - lo;
        (e.x * e.y * e.z / nodes.len().max(1) as f64).cbrt()
    }

    /// The contact multipliers of a warm start's state, estimated from its residual: a
    /// point on the rigid surface (within [`WARM_CONTACT_SHARE`] of the body's mean node
    /// spacing) takes the push along its normal that its nodes are short of, by least squares
    /// over its weights. A state relaxed against a surface holds its points on it, where the
    /// penalty alone pushes nothing: without multipliers its first tangent had no contact,
    /// and the MNI brain fell through the skull in the linear predictor (min J -1,812).
    pub(super) fn warm_contact_multipliers(&mut self) {
        let Some(ct) = self.model.contact.as_ref() else {
            return;
        };
        let near = WARM_CONTACT_SHARE * self.mean_spacing();
        let mut any = false;
        for (k, &(b, i)) in self.touch.iter().enumerate() {
            let (depth, n, _) = self.t_state[k];
            if !(depth > -near) {
                continue;
            }
            let row = &ct.points_of(b as usize)[i as usize].row;
            let (mut push, mut w2) = (0.0, 0.0);
            for &(j, w) in row {
                let j = j as usize;
                let mut r = self.fe[j] - self.f[j];
                for c in 0..3 {
                    if self.model.constraints.mask[j][c] {
                        r[c] = 0.0;
                    }
                }
                push -= w * n.dot(&r);
                w2 += w * w;
            }
            if push > 0.0 && w2 > 0.0 {
                self.t_lambda[k] = push / w2;
                any = true;
            }
        }
        if any {
            self.forces(self.tau_now);
        }
    }

    /// Hands the contact's end state (forces per body, points in contact) to the model.
    pub(super) fn contact_state(&mut self) {
        let worst = self.worst_penetration();
        let scale = self.force_scale();
        let Some(ct) = self.model.contact.as_mut() else {
            return;
        };
        let mut forces = vec![Vector3::zeros(); ct.len()];
        let mut count = vec![0usize; ct.len()];
        // A point counts as in contact where its force is more than rounding against the
        // forces the tissue carries (its shear modulus times the mean node spacing squared): a
        // ball driven through the cube in one step ended with 1e-14 N on a point it grazed,
        // which hid that it pressed nothing.
        let floor = 1e-9 * scale;
        for (k, &(b, _)) in self.touch.iter().enumerate() {
            let (_, n, g) = self.t_state[k];
            if g > 0.0 {
                forces[b as usize] += n * g;
            }
            if g > floor {
                count[b as usize] += 1;
            }
        }
        ct.set_static_state(forces, count, worst);
    }

    /// Every contact point keeps, for the next load step, the push direction it has at this
    /// equilibrium: a point pressing keeps the face it presses, and one not yet touching the
    /// face it is nearest to, which it will enter through (a flat punch's end, for a point
    /// beneath it). Measured afresh after a long step, a point carried under the end deeper
    /// than its distance to the side wall was pushed out sideways: the brain under the punch
    /// took two load steps and settled at 42.2 mN against relaxation's 58.87 mN.
    pub(super) fn keep_faces(&mut self) {
        for (h, st) in self.t_hint.iter_mut().zip(&self.t_state) {
            *h = Some(st.1);
        }
    }
}
