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
//!
//! [`Lanczos::estimate`] also runs about a deformed state u (dynamic runs' step updates): K(u) z
//! is then (F_int(u + eps z) - F_int(u)) / eps, the tangent there, material and geometric
//! stiffness together.

use nalgebra::Vector3;

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
/// of its unit eigenvector (the Ritz residual is |beta_k s_k|), without allocating: bisection
/// on the Sturm count for the eigenvalue, then inverse iteration with a tridiagonal LU with
/// partial pivoting (as LAPACK's dgttrf) for the eigenvector. `work` holds at least
/// 6 x alpha.len() values.
fn top_ritz(alpha: &[f64], beta: &[f64], work: &mut [f64]) -> (f64, f64) {
    let k = alpha.len();
    if k == 0 {
        return (f64::NAN, 0.0);
    }
    let b = |i: usize| if i + 1 < k { beta[i] } else { 0.0 };
    // Gershgorin interval.
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (i, &a) in alpha.iter().enumerate() {
        let r = b(i).abs() + if i > 0 { b(i - 1).abs() } else { 0.0 };
        lo = lo.min(a - r);
        hi = hi.max(a + r);
    }
    let scale = lo.abs().max(hi.abs()).max(f64::MIN_POSITIVE);
    let tiny = f64::EPSILON * scale;
    // Eigenvalues below x: the negative pivots of T - x I = L D L^T (Sylvester).
    let below = |x: f64| {
        let (mut d, mut n) = (1.0f64, 0usize);
        for (i, &a) in alpha.iter().enumerate() {
            let off = if i > 0 { b(i - 1) * b(i - 1) / d } else { 0.0 };
            d = a - x - off;
            if d == 0.0 {
                d = -tiny;
            }
            if d < 0.0 {
                n += 1;
            }
        }
        n
    };
    // Ends when no double lies strictly between the bounds, at the latest.
    loop {
        let mid = 0.5 * (lo + hi);
        if !(mid > lo && mid < hi) || hi - lo <= 2.0 * tiny {
            break;
        }
        if below(mid) == k {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let theta = hi;
    // Inverse iteration on T - theta I. Row i of U holds d[i], e[i], g[i] at columns i, i+1,
    // i+2; l[i] is the multiplier that eliminates row i+1's sub-diagonal, sw[i] = 1 where rows
    // i and i+1 were swapped for it.
    let (d, rest) = work.split_at_mut(k);
    let (e, rest) = rest.split_at_mut(k);
    let (g, rest) = rest.split_at_mut(k);
    let (l, rest) = rest.split_at_mut(k);
    let (sw, rest) = rest.split_at_mut(k);
    let x = &mut rest[..k];
    for i in 0..k {
        d[i] = alpha[i] - theta;
        e[i] = b(i);
        g[i] = 0.0;
        l[i] = 0.0;
        sw[i] = 0.0;
        x[i] = 1.0;
    }
    for i in 0..k - 1 {
        // Row i+1 is (b(i), d[i+1], e[i+1]) at columns i, i+1, i+2.
        let sub = b(i);
        if sub.abs() > d[i].abs() {
            let (di, ei) = (d[i], e[i]);
            d[i] = sub;
            e[i] = d[i + 1];
            g[i] = e[i + 1];
            let m = di / sub;
            l[i] = m;
            sw[i] = 1.0;
            d[i + 1] = ei - m * e[i];
            e[i + 1] = -m * g[i];
        } else {
            if d[i] == 0.0 {
                d[i] = tiny;
            }
            let m = sub / d[i];
            l[i] = m;
            d[i + 1] -= m * e[i];
        }
    }
    if d[k - 1] == 0.0 {
        d[k - 1] = tiny;
    }
    for _ in 0..3 {
        for i in 0..k - 1 {
            if sw[i] != 0.0 {
                x.swap(i, i + 1);
            }
            x[i + 1] -= l[i] * x[i];
        }
        for i in (0..k).rev() {
            let mut v = x[i];
            if i + 1 < k {
                v -= e[i] * x[i + 1];
            }
            if i + 2 < k {
                v -= g[i] * x[i + 2];
            }
            x[i] = v / d[i];
        }
        let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return (theta, 0.0);
        }
        x.iter_mut().for_each(|v| *v /= norm);
    }
    (theta, x[k - 1])
}

/// Dot product over nodes in node order (deterministic for any thread count).
fn dot(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

/// Estimates lambda_max(M^-1 K_0) of `model` on its free DOFs; see [`Lanczos::estimate`].
pub fn largest_eigenvalue<M: Material>(
    model: &mut Model<M>,
    max_iterations: usize,
    tolerance: f64,
) -> Option<Estimate> {
    Lanczos::new(model, max_iterations).estimate(model, None, tolerance)
}

/// The estimate's vectors, allocated once, so that the time loop can estimate again at the
/// deformed state without allocating (`tests/allocation.rs`).
pub struct Lanczos {
    max_iterations: usize,
    v: Vec<Vector3<f64>>,
    v_prev: Vec<Vector3<f64>>,
    w: Vec<Vector3<f64>>,
    u: Vec<Vector3<f64>>,
    f: Vec<Vector3<f64>>,
    f0: Vec<Vector3<f64>>,
    inv_sqrt_m: Vec<f64>,
    alpha: Vec<f64>,
    beta: Vec<f64>,
    work: Vec<f64>,
}

impl Lanczos {
    /// Workspace for `model` and at most `max_iterations` Lanczos steps.
    pub fn new<M: Material>(model: &Model<M>, max_iterations: usize) -> Self {
        let n = model.nodes.len();
        let k = max_iterations.max(1);
        let z = vec![Vector3::zeros(); n];
        Lanczos {
            max_iterations: k,
            v: z.clone(),
            v_prev: z.clone(),
            w: z.clone(),
            u: z.clone(),
            f: z.clone(),
            f0: z,
            inv_sqrt_m: model.mass.iter().map(|&m| 1.0 / m.sqrt()).collect(),
            alpha: Vec::with_capacity(k),
            beta: Vec::with_capacity(k),
            work: vec![0.0; 6 * k],
        }
    }

    /// Estimates lambda_max(M^-1 K) of `model` on its free DOFs (those not in
    /// `model.constraints.mask`; boundaries imposed by a corrector count as free, which can
    /// only raise the estimate), with K the tangent stiffness at the displacements `base`
    /// (m; None: the reference state, where the internal force vanishes). K z is the forward
    /// difference (F_int(base + eps z) - F_int(base)) / eps at strains of about 1e-8. Runs at
    /// most `max_iterations` Lanczos steps, stopping when the Ritz residual falls below
    /// `tolerance` x the Ritz value. The start vector is a fixed pseudo-random field, so the
    /// estimate is the same on every run and thread count. Returns None when the model has no
    /// free DOF or the operator is not positive. Allocates nothing. Leaves the model's point
    /// stage holding the last perturbed state.
    pub fn estimate<M: Material>(
        &mut self,
        model: &mut Model<M>,
        base: Option<&[Vector3<f64>]>,
        tolerance: f64,
    ) -> Option<Estimate> {
        let Model {
            nodes,
            points,
            slots,
            constraints,
            forces,
            ..
        } = model;
        let n = nodes.len();
        let mask = &constraints.mask;
        let free = |i: usize, k: usize| !mask.get(i).is_some_and(|m| m[k]);
        let Lanczos {
            max_iterations,
            v,
            v_prev,
            w,
            u,
            f,
            f0,
            inv_sqrt_m,
            alpha,
            beta,
            work,
        } = self;
        alpha.clear();
        beta.clear();
        // Displacement scale: the forward difference sees strains of about 1e-8.
        let (lo, hi) = nodes.iter().fold(
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
        if let Some(b) = base {
            forces.compute(points, slots, b, f0);
        }
        // xorshift64*: a fixed start vector.
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut rand = || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for (i, x) in v.iter_mut().enumerate() {
            *x = Vector3::from_fn(|k, _| if free(i, k) { rand() } else { 0.0 });
        }
        let norm = dot(v, v).sqrt();
        if !(norm > 0.0) {
            return None;
        }
        v.iter_mut().for_each(|x| *x /= norm);
        v_prev.iter_mut().for_each(|x| *x = Vector3::zeros());
        let mut best = None;
        for it in 1..=*max_iterations {
            // w = M^-1/2 K M^-1/2 v on the free DOFs.
            let zmax = v
                .iter()
                .zip(inv_sqrt_m.iter())
                .map(|(x, s)| x.amax() * s)
                .fold(0.0, f64::max);
            let eps = 1e-8 * size / zmax;
            for i in 0..n {
                u[i] = v[i] * (eps * inv_sqrt_m[i]);
                if let Some(b) = base {
                    u[i] += b[i];
                }
            }
            forces.compute(points, slots, u, f);
            for i in 0..n {
                let df = if base.is_some() { f[i] - f0[i] } else { f[i] };
                let y = df * (inv_sqrt_m[i] / eps);
                w[i] = Vector3::from_fn(|k, _| if free(i, k) { y[k] } else { 0.0 });
            }
            let a = dot(v, w);
            let b_prev = beta.last().copied().unwrap_or(0.0);
            for i in 0..n {
                w[i] -= v[i] * a + v_prev[i] * b_prev;
            }
            let b = dot(w, w).sqrt();
            alpha.push(a);
            beta.push(b);
            let (theta, s_last) = top_ritz(alpha, beta, work);
            let residual = (b * s_last).abs();
            if !(theta > 0.0 && theta.is_finite()) {
                return None;
            }
            best = Some(Estimate {
                lambda_max: theta + residual,
                ritz: theta,
                iterations: it,
            });
            if residual <= tolerance * theta || !(b > 1e-14 * theta.sqrt()) {
                break;
            }
            std::mem::swap(v_prev, v);
            for i in 0..n {
                v[i] = w[i] / b;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// The allocation-free tridiagonal solver against nalgebra's dense symmetric eigensolver.
    #[test]
    fn top_ritz_matches_a_dense_eigensolver() {
        let mut state: u64 = 7;
        let mut rand = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for k in [1usize, 2, 3, 5, 17, 60, 200] {
            for trial in 0..4 {
                let alpha: Vec<f64> = (0..k).map(|_| 1e6 * (rand() - 0.3)).collect();
                // Some tiny couplings (nearly split matrices) in the later trials.
                let beta: Vec<f64> = (0..k)
                    .map(|i| 1e6 * rand() * if trial >= 2 && i % 5 == 0 { 1e-9 } else { 1.0 })
                    .collect();
                let mut t = DMatrix::<f64>::zeros(k, k);
                for i in 0..k {
                    t[(i, i)] = alpha[i];
                    if i + 1 < k {
                        t[(i, i + 1)] = beta[i];
                        t[(i + 1, i)] = beta[i];
                    }
                }
                let e = t.symmetric_eigen();
                let (mut top, mut idx) = (f64::NEG_INFINITY, 0);
                for (i, &v) in e.eigenvalues.iter().enumerate() {
                    if v > top {
                        top = v;
                        idx = i;
                    }
                }
                let mut work = vec![0.0; 6 * k];
                let (theta, s) = top_ritz(&alpha, &beta, &mut work);
                let s_ref = e.eigenvectors[(k - 1, idx)];
                assert!(
                    (theta - top).abs() <= 1e-12 * top.abs().max(1.0),
                    "k = {k}: {theta} vs {top}"
                );
                assert!(
                    (s.abs() - s_ref.abs()).abs() <= 1e-8,
                    "k = {k}, trial {trial}: last component {s} vs {s_ref}"
                );
            }
        }
    }
}
