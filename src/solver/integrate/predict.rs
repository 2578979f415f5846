//! The explicit predictor: every free DOF's next displacement,
//! u(n+1) = -A M^-1 (F_int - F_ext) + B u(n) + C u(n-1), in parallel over node blocks.

use nalgebra::Vector3;

use super::energy::{free_dist2, DampingSlots};
use crate::material::Material;
use crate::solver::forces::NODE_BLOCK;
use crate::solver::{Forces, SharedMut};

/// What one step's update reads besides the displacements.
pub(super) struct Predictor<'a, M: Material> {
    /// Lumped masses, kg.
    pub(super) mass: &'a [f64],
    /// The point stage of this step (nodal forces gathered per block here unless `gathered`).
    pub(super) forces: &'a Forces<M>,
    /// External loads, N (None without loads).
    pub(super) f_ext: Option<&'a [Vector3<f64>]>,
    /// Constrained components, left as they are.
    pub(super) mask: &'a [[bool; 3]],
    /// Nodes that corrections or prescribed values move after the update: their change is
    /// measured after those, and their damping share in the next step's update.
    pub(super) is_late: &'a [bool],
    /// (A, B, C) of the update.
    pub(super) coefficients: (f64, f64, f64),
    /// The nodal forces are already in `f` (a step that records them).
    pub(super) gathered: bool,
    /// Damped dynamics: each block's damping sums go to `damping`.
    pub(super) damped: bool,
    /// The last step's late nodes still owe their damping share.
    pub(super) late_pending: bool,
    pub(super) damping: DampingSlots,
}

impl<M: Material> Predictor<'_, M> {
    /// Writes `u_next` on the free components from `u` = u(n), `u_prev` = u(n-1) (m) and the
    /// internal forces `f` (N; gathered here per block unless [`Self::gathered`]). Returns the
    /// largest change in one step and the largest displacement (m) over the nodes that are
    /// not late, NaN where any is. Blocks run from both ends as the point stage
    /// (`two_ended`); max is order-independent, so the result does not depend on the
    /// thread count.
    pub(super) fn update(
        &self,
        (u, u_prev): (&[Vector3<f64>], &[Vector3<f64>]),
        u_next: &mut [Vector3<f64>],
        f: &mut [Vector3<f64>],
    ) -> (f64, f64) {
        let n = u.len();
        assert!(u_prev.len() == n && u_next.len() == n && f.len() == n);
        let (a, b, cc) = self.coefficients;
        let (mass, mask_all, is_late) = (self.mass, self.mask, self.is_late);
        let un_all = SharedMut(u_next.as_mut_ptr());
        let f_all = SharedMut(f.as_mut_ptr());
        crate::solver::two_ended::for_each_item(
            n.div_ceil(NODE_BLOCK),
            (0.0f64, 0.0f64),
            |blk| {
                let n0 = blk * NODE_BLOCK;
                let len = NODE_BLOCK.min(n - n0);
                // SAFETY: u_next and f hold n vectors (asserted) and are borrowed mutably for
                // the loop; block blk is nodes n0..n0 + len, which no other item touches.
                let (un_b, f_b) = unsafe {
                    (
                        std::slice::from_raw_parts_mut(un_all.get().add(n0), len),
                        std::slice::from_raw_parts_mut(f_all.get().add(n0), len),
                    )
                };
                if !self.gathered {
                    self.forces.node_forces(n0, f_b);
                }
                let mut acc = (0.0f64, 0.0f64);
                let (mut damp, mut damp_late) = (0.0f64, 0.0f64);
                for (j, (un, fi)) in un_b.iter_mut().zip(f_b.iter()).enumerate() {
                    let i = n0 + j;
                    if self.late_pending && is_late[i] {
                        // The last step's share: u = u(n), un = u(n-2) before the write.
                        damp_late += mass[i] * free_dist2(mask_all[i], &u[i], un);
                    }
                    // The net force F_int - F_ext (bitwise F_int without loads).
                    let fi = match self.f_ext {
                        Some(e) => fi - e[i],
                        None => *fi,
                    };
                    let inv_m = a / mass[i];
                    let mask = mask_all[i];
                    let mut mdu = 0.0f64;
                    for k in 0..3 {
                        if !mask[k] {
                            let v = -inv_m * fi[k] + b * u[i][k] + cc * u_prev[i][k];
                            un[k] = v;
                            mdu = nan_max(mdu, (v - u[i][k]).abs());
                        }
                    }
                    if !is_late[i] {
                        acc = (
                            nan_max(acc.0, mdu),
                            nan_max(acc.1, nan_max(un.x.abs(), nan_max(un.y.abs(), un.z.abs()))),
                        );
                        if self.damped {
                            damp += mass[i] * free_dist2(mask, un, &u_prev[i]);
                        }
                    }
                }
                if self.damped {
                    // SAFETY: a damped run's ledger holds one slot per block and outlives
                    // the loop; only block blk writes slot blk.
                    unsafe { self.damping.write(blk, damp, damp_late) };
                }
                acc
            },
            |x, y| (nan_max(x.0, y.0), nan_max(x.1, y.1)),
        )
    }
}

/// max that propagates NaN (f64::max drops it), so divergence cannot hide.
#[inline]
pub(super) fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}
