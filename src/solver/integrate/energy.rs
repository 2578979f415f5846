//! The energy the time loop accounts for step by step: the work of the boundaries, loads and
//! corrections on the body, and the work done against mass-proportional damping. With the
//! strain and kinetic energies they close the balance the summary checks.

use nalgebra::Vector3;

use super::super::SharedMut;
use super::timeline::Timeline;
use crate::bc::Constraints;

/// |a - b|^2 over the free components (`mask` false), m^2: the damping's work per unit
/// c m / (2 (h + h_prev)) with a = u(n+1), b = u(n-1).
#[inline(always)]
pub(super) fn free_dist2(mask: [bool; 3], a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (0..3)
        .filter(|&k| !mask[k])
        .map(|k| (a[k] - b[k]).powi(2))
        .sum()
}

/// Kinetic energy with the backward-difference velocity (u(n) - u(n-1)) / dt, J. Fixed-order sum.
pub(super) fn kinetic(mass: &[f64], u: &[Vector3<f64>], u_prev: &[Vector3<f64>], dt: f64) -> f64 {
    mass.iter()
        .zip(u.iter().zip(u_prev))
        .map(|(m, (a, b))| 0.5 * m * ((a - b) / dt).norm_squared())
        .sum()
}

/// (linear, angular about the origin) momentum with positions X + u and velocities
/// (u - u_prev) / dt.
pub(super) fn momentum(
    mass: &[f64],
    x: &[Vector3<f64>],
    u: &[Vector3<f64>],
    u_prev: &[Vector3<f64>],
    dt: f64,
) -> ([f64; 3], [f64; 3]) {
    let (mut p, mut l) = (Vector3::zeros(), Vector3::zeros());
    for i in 0..mass.len() {
        let v = (u[i] - u_prev[i]) / dt;
        p += v * mass[i];
        l += (x[i] + u[i]).cross(&v) * mass[i];
    }
    (p.into(), l.into())
}

/// Work and dissipation summed over the steps, J.
pub(super) struct Ledger {
    pub(super) external_work: f64,
    /// The largest |external work| reached.
    pub(super) peak_external_work: f64,
    pub(super) damping_dissipation: f64,
    pub(super) initial_kinetic: f64,
    /// Per node block, sum of m |u(n+1) - u(n-1)|^2 over free DOFs, written by the parallel
    /// update and summed in block order after it (a sum across threads would depend on their
    /// count). The late nodes (moved by corrections after the update) are final only after
    /// their correction: their share of a step is summed in the next step's parallel update,
    /// where u_next still holds u(n-1) until it is overwritten (a serial pass after the
    /// correction cost the two-thread meshless cylinder 10 %: the second worker falls asleep).
    blocks: Vec<f64>,
    late_blocks: Vec<f64>,
    /// c / (2 (h + h_prev)) of the step whose late share is pending.
    late_factor: Option<f64>,
}

/// Where the parallel update writes each node block's damping sums (one slot per block).
#[derive(Clone, Copy)]
pub(super) struct DampingSlots {
    blocks: SharedMut<f64>,
    late: SharedMut<f64>,
}

impl DampingSlots {
    /// Writes block `blk`'s sums: this step's other nodes, and the last step's late nodes.
    ///
    /// # Safety
    /// `blk` is below the block count given to [`Ledger::new`], the ledger outlives the
    /// slots, and no other thread writes block `blk`.
    #[inline(always)]
    pub(super) unsafe fn write(self, blk: usize, damp: f64, late: f64) {
        unsafe {
            *self.blocks.get().add(blk) = damp;
            *self.late.get().add(blk) = late;
        }
    }
}

impl Ledger {
    /// `blocks`: node blocks of a damped run (0 without damping).
    pub(super) fn new(blocks: usize) -> Self {
        Ledger {
            external_work: 0.0,
            peak_external_work: 0.0,
            damping_dissipation: 0.0,
            initial_kinetic: 0.0,
            blocks: vec![0.0; blocks],
            late_blocks: vec![0.0; blocks],
            late_factor: None,
        }
    }

    /// The last step's late share is still to be summed (by this step's update).
    pub(super) fn late_pending(&self) -> bool {
        self.late_factor.is_some()
    }

    pub(super) fn slots(&mut self) -> DampingSlots {
        DampingSlots {
            blocks: SharedMut(self.blocks.as_mut_ptr()),
            late: SharedMut(self.late_blocks.as_mut_ptr()),
        }
    }

    /// Adds the damping's work c m v(n) . (u(n+1) - u(n-1)) / 2 with v(n) = (u(n+1) - u(n-1))
    /// / (h + h_prev) from the update's block sums: this step's other nodes and the last
    /// step's late nodes. `late`: this step has late nodes, summed by the next update.
    pub(super) fn add_damping(&mut self, damping: f64, time: &Timeline, late: bool) {
        if let Some(fl) = self.late_factor {
            self.damping_dissipation += fl * self.late_blocks.iter().sum::<f64>();
        }
        let factor = damping / (2.0 * (time.dt + time.dt_prev));
        self.damping_dissipation += factor * self.blocks.iter().sum::<f64>();
        self.late_factor = late.then_some(factor);
    }

    /// The last step's late share at the end of the run: `u` = u(N), `u_old` = u(N-2).
    pub(super) fn finish_damping(
        &mut self,
        late: &[u32],
        (mass, mask): (&[f64], &[[bool; 3]]),
        u: &[Vector3<f64>],
        u_old: &[Vector3<f64>],
    ) {
        if let Some(fl) = self.late_factor {
            let m_d2: f64 = late
                .iter()
                .map(|&i| i as usize)
                .map(|i| mass[i] * free_dist2(mask[i], &u[i], &u_old[i]))
                .sum();
            self.damping_dissipation += fl * m_d2;
        }
    }

    /// Adds the work of the boundary forces, sum (F_int + M a) . (u(n+1) - u(n-1)) / 2 over the
    /// constrained DOFs, and of the loads `f_ext` (N) on the DOFs the integrator moves; `u` =
    /// [u(n+1), u(n), u(n-1)] (m), `f` the internal forces (N). Then the peak.
    /// [`Self::add_step_work`] without loads from the prescribed DOFs' work terms, in DOF
    /// order (the device loop's, computed as [`dof_work`] does).
    pub(super) fn add_work_terms(&mut self, terms: &[f64]) {
        for &t in terms {
            self.external_work += t;
        }
        self.peak_external_work = self.peak_external_work.max(self.external_work.abs());
    }

    pub(super) fn add_step_work(
        &mut self,
        (cons, mass): (&Constraints, &[f64]),
        f: &[Vector3<f64>],
        f_ext: Option<&[Vector3<f64>]>,
        [u_next, u, u_prev]: [&[Vector3<f64>]; 3],
        time: &Timeline,
    ) {
        for &(node, comp) in cons.dofs.iter() {
            let (i, k) = (node as usize, comp as usize);
            self.external_work += dof_work(
                mass[i],
                [f[i][k], u_next[i][k], u[i][k], u_prev[i][k]],
                time,
            );
        }
        if let Some(f_ext) = f_ext {
            for (i, fe) in f_ext.iter().enumerate() {
                for k in 0..3 {
                    if !cons.mask[i][k] {
                        self.external_work += fe[k] * 0.5 * (u_next[i][k] - u_prev[i][k]);
                    }
                }
            }
        }
        self.peak_external_work = self.peak_external_work.max(self.external_work.abs());
    }
}

/// The work of a prescribed DOF of nodal mass `m` (kg) over one step, J: its internal force
/// plus inertia (N) times the central-difference increment (u(n+1) - u(n-1)) / 2, from
/// (f, u(n+1), u(n), u(n-1)).
fn dof_work(m: f64, [f, un, u, up]: [f64; 4], time: &Timeline) -> f64 {
    let (dt, dt_prev) = (time.dt, time.dt_prev);
    let inertia = if time.dynamic && dt == dt_prev {
        m * (un - 2.0 * u + up) / (dt * dt)
    } else if time.dynamic {
        let (vn, vp) = ((un - u) / dt, (u - up) / dt_prev);
        m * (vn - vp) / (0.5 * (dt + dt_prev))
    } else {
        0.0
    };
    (f + inertia) * 0.5 * (un - up)
}
