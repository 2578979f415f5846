//! Stable time step from the discretization itself (Joldes et al.; thesis eq. 4.1-4.2).

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
