//! Global estimate of the largest frequency of the discretization (Lanczos on the reference
//! stiffness), for a stable step that is not 1.5-2.5x conservative as the per-point and nodal
//! bounds are where supports are large (ABAQUS/Explicit's "global estimator" is the same idea).
//!
//! The operator is A = M^-1/2 K_0 M^-1/2 on the free DOFs (a principal submatrix of the full
//! one, so by Cauchy interlacing its largest eigenvalue is at most the full one's), with K_0
//! the tangent at the reference configuration applied without assembly: K_0 z is the internal
//! force of the small displacement eps z divided by eps (F_int(0) = 0, so the forward
//! difference errs by O(eps |grad z|), about 1e-8 relative here). Lanczos without
//! reorthogonalization: loss of orthogonality only duplicates converged Ritz values and does
//! not move the largest one.

use nalgebra::{DMatrix, Vector3};

use super::Model;
use crate::material::Material;

/// What the Lanczos run found.
#[derive(Debug, Clone, Copy)]
pub struct Estimate {
    /// Largest Ritz value plus its residual bound, 1/s^2: an eigenvalue of A lies within the
    /// residual of the Ritz value, so this is the estimate of lambda_max(M^-1 K_0) rounded up.
    pub lambda_max: f64,
    /// The largest Ritz value alone, 1/s^2.
    pub ritz: f64,
    /// Lanczos iterations (force evaluations).
    pub iterations: usize,
}

impl Estimate {
    /// Central-difference critical step 2 / omega_max, s.
    pub fn critical_step(&self) -> f64 {
        2.0 / self.lambda_max.sqrt()
    }
}

/// Largest eigenvalue of the symmetric tridiagonal matrix (alpha, beta) and the last component
/// of its eigenvector (the Ritz residual is |beta_k s_k|).
fn top_ritz(alpha: &[f64], beta: &[f64]) -> (f64, f64) {
    let k = alpha.len();
    let mut t = DMatrix::<f64>::zeros(k, k);
    for i in 0..k {
        t[(i, i)] = alpha[i];
        if i + 1 < k {
            t[(i, i + 1)] = beta[i];
            t[(i + 1, i)] = beta[i];
        }
    }
    let e = t.symmetric_eigen();
    let (mut best, mut idx) = (f64::NEG_INFINITY, 0);
    for (i, &v) in e.eigenvalues.iter().enumerate() {
        if v > best {
            best = v;
            idx = i;
        }
    }
    (best, e.eigenvectors[(k - 1, idx)])
}

/// Dot product over nodes in node order (deterministic for any thread count).
fn dot(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

/// Estimates lambda_max(M^-1 K_0) of `model` on its free DOFs (those not in
/// `model.constraints.mask`; boundaries imposed by a corrector count as free, which can only
/// raise the estimate). Runs at most `max_iterations` Lanczos steps, stopping when the Ritz
/// residual falls below `tolerance` x the Ritz value. The start vector is a fixed
/// pseudo-random field, so the estimate is the same on every run and thread count.
/// Returns None when the model has no free DOF or the operator is not positive.
pub fn largest_eigenvalue<M: Material>(
    model: &mut Model<M>,
    max_iterations: usize,
    tolerance: f64,
) -> Option<Estimate> {
    let n = model.nodes.len();
    let mask = model.constraints.mask.clone();
    let free = |i: usize, k: usize| !mask.get(i).is_some_and(|m| m[k]);
    let inv_sqrt_m: Vec<f64> = model.mass.iter().map(|&m| 1.0 / m.sqrt()).collect();
    // Displacement scale: the forward difference sees strains of about 1e-8.
    let (lo, hi) = model.nodes.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(l, h), p| (l.inf(p), h.sup(p)),
    );
    let size = (hi - lo).norm();
    if !(size > 0.0) {
        return None;
    }
    // xorshift64*: a fixed start vector.
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut rand = || {
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let mut v: Vec<Vector3<f64>> = (0..n)
        .map(|i| Vector3::from_fn(|k, _| if free(i, k) { rand() } else { 0.0 }))
        .collect();
    let norm = dot(&v, &v).sqrt();
    if !(norm > 0.0) {
        return None;
    }
    v.iter_mut().for_each(|x| *x /= norm);
    let mut v_prev = vec![Vector3::zeros(); n];
    let mut u = vec![Vector3::zeros(); n];
    let mut f = vec![Vector3::zeros(); n];
    let (mut alpha, mut beta) = (Vec::new(), Vec::new());
    let mut best = None;
    for it in 1..=max_iterations.max(1) {
        // w = M^-1/2 K M^-1/2 v on the free DOFs.
        let zmax = v
            .iter()
            .zip(&inv_sqrt_m)
            .map(|(x, s)| x.amax() * s)
            .fold(0.0, f64::max);
        let eps = 1e-8 * size / zmax;
        for i in 0..n {
            u[i] = v[i] * (eps * inv_sqrt_m[i]);
        }
        model
            .forces
            .compute(&model.points, &model.slots, &u, &mut f);
        let mut w: Vec<Vector3<f64>> = (0..n)
            .map(|i| {
                let y = f[i] * (inv_sqrt_m[i] / eps);
                Vector3::from_fn(|k, _| if free(i, k) { y[k] } else { 0.0 })
            })
            .collect();
        let a = dot(&v, &w);
        let b_prev = beta.last().copied().unwrap_or(0.0);
        for i in 0..n {
            w[i] -= v[i] * a + v_prev[i] * b_prev;
        }
        let b = dot(&w, &w).sqrt();
        alpha.push(a);
        let (theta, s_last) = top_ritz(&alpha, &beta);
        let residual = (b * s_last).abs();
        if !(theta > 0.0 && theta.is_finite()) {
            return None;
        }
        let e = Estimate {
            lambda_max: theta + residual,
            ritz: theta,
            iterations: it,
        };
        best = Some(e);
        if residual <= tolerance * theta || !(b > 1e-14 * theta.sqrt()) {
            break;
        }
        beta.push(b);
        std::mem::swap(&mut v_prev, &mut v);
        for i in 0..n {
            v[i] = w[i] / b;
        }
    }
    best
}
