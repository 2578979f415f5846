//! Stable time step from the discretization itself: the per-point bound of Joldes et al.
//! (thesis eq. 4.1-4.2) and a nodal block-Gershgorin bound; the run takes the larger step,
//! since both bound the largest eigenvalue of the reference stiffness.

use crate::quadrature::QuadraturePoints;

/// Critical step, s: min over points I of 2 / (c sqrt(n_I sum_j |dphi_j/dX|^2)), with c the
/// dilatational wave speed (m/s) and the point's mass split evenly over its n_I nodes. Returns the
/// step and the point that sets it.
pub fn critical_time_step(qp: &QuadraturePoints, wave_speed: f64) -> (f64, usize) {
    let mut best = (f64::INFINITY, 0);
    for p in 0..qp.len() {
        let r = qp.slots(p);
        let n = r.len() as f64;
        let sum: f64 = qp.dphi[r].iter().map(|d| d.norm_squared()).sum();
        let dt = 2.0 / (wave_speed * (n * sum).sqrt());
        if dt < best.0 {
            best = (dt, p);
        }
    }
    best
}

/// Nodal (block Gershgorin) bound on the stable step, s: with lumped masses m_i (kg) and the
/// reference stiffness blocks |K_ij| <= sum_p w_p (lambda + 2 mu) |dphi_i| |dphi_j|,
/// lambda_max(M^-1 K) <= max_i (c^2 rho / m_i) sum_p w_p |dphi_i(p)| sum_j |dphi_j(p)|.
/// Returns the step 2 / sqrt(lambda_max) and the node that sets it.
pub fn nodal_time_step(
    qp: &QuadraturePoints,
    slots: &crate::quadrature::NodeSlots,
    mass: &[f64],
    wave_speed: f64,
    density: f64,
) -> (f64, usize) {
    let abs_sum: Vec<f64> = (0..qp.len())
        .map(|p| qp.dphi[qp.slots(p)].iter().map(|d| d.norm()).sum())
        .collect();
    let mut best = (f64::INFINITY, 0);
    for (i, &m) in mass.iter().enumerate() {
        let mut row = 0.0;
        for k in slots.range(i) {
            let p = slots.points[k] as usize;
            let s = slots.slots[k] as usize;
            row += qp.weights[p] * qp.dphi[s].norm() * abs_sum[p];
        }
        let lam = wave_speed * wave_speed * density / m * row;
        let dt = 2.0 / lam.sqrt();
        if dt < best.0 {
            best = (dt, i);
        }
    }
    best
}
