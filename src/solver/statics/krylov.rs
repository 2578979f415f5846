//! Restarted GMRES (Saad and Schultz 1986; Saad, *Iterative Methods for Sparse Linear
//! Systems*, 2nd ed., algorithm 6.9 with Givens rotations) for the small nonsymmetric systems
//! of the static solve: EBCIEM's multiplier update, whose operator Phi K^-1 V is nonsymmetric
//! because V (the boundary-force columns) is not Phi^T.

/// What [`gmres`] reached.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// Products with the operator.
    pub iterations: usize,
    /// Final |b - A x| / |b|.
    pub relative_residual: f64,
}

/// Solves `A x = b` from x = 0 by GMRES(`restart`), right-preconditioned by the diagonal `d`
/// (A D y = b, x = D y), until |b - A x| <= `tolerance` |b| or `max_iterations` products.
/// `apply(v, out)` writes A v to `out`. Deterministic: every sum runs in index order.
pub fn gmres(
    mut apply: impl FnMut(&[f64], &mut [f64]),
    d: &[f64],
    b: &[f64],
    tolerance: f64,
    restart: usize,
    max_iterations: usize,
) -> (Vec<f64>, Outcome) {
    let n = b.len();
    let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
    let norm = |x: &[f64]| dot(x, x).sqrt();
    let mut x = vec![0.0; n];
    let bnorm = norm(b);
    let mut out = Outcome {
        iterations: 0,
        relative_residual: 0.0,
    };
    if bnorm == 0.0 || n == 0 {
        return (x, out);
    }
    let m = restart.clamp(1, n);
    let mut r = b.to_vec();
    let mut w = vec![0.0; n];
    let mut z = vec![0.0; n];
    loop {
        let beta = norm(&r);
        out.relative_residual = beta / bnorm;
        if out.relative_residual <= tolerance || out.iterations >= max_iterations {
            return (x, out);
        }
        let mut basis: Vec<Vec<f64>> = vec![r.iter().map(|v| v / beta).collect()];
        // Hessenberg columns after the rotations, and the rotations (c, s).
        let mut h: Vec<Vec<f64>> = Vec::with_capacity(m);
        let mut rot: Vec<(f64, f64)> = Vec::with_capacity(m);
        let mut g = vec![beta];
        for j in 0..m {
            for i in 0..n {
                z[i] = d[i] * basis[j][i];
            }
            apply(&z, &mut w);
            out.iterations += 1;
            // Modified Gram-Schmidt.
            let mut col = vec![0.0; j + 2];
            for (i, v) in basis.iter().enumerate() {
                let hij = dot(&w, v);
                col[i] = hij;
                for k in 0..n {
                    w[k] -= hij * v[k];
                }
            }
            let hn = norm(&w);
            col[j + 1] = hn;
            for (i, &(c, s)) in rot.iter().enumerate() {
                let (a, b) = (col[i], col[i + 1]);
                col[i] = c * a + s * b;
                col[i + 1] = -s * a + c * b;
            }
            let rho = col[j].hypot(col[j + 1]);
            let (c, s) = if rho == 0.0 {
                (1.0, 0.0)
            } else {
                (col[j] / rho, col[j + 1] / rho)
            };
            col[j] = rho;
            col[j + 1] = 0.0;
            rot.push((c, s));
            g.push(-s * g[j]);
            g[j] *= c;
            h.push(col);
            let done = g[j + 1].abs() <= tolerance * bnorm
                || out.iterations >= max_iterations
                || hn == 0.0;
            if !done {
                basis.push(w.iter().map(|v| v / hn).collect());
            }
            if done || j + 1 == m {
                // y from the triangular system, x += D V y.
                let k = j + 1;
                let mut y = vec![0.0; k];
                for i in (0..k).rev() {
                    let mut s = g[i];
                    for l in i + 1..k {
                        s -= h[l][i] * y[l];
                    }
                    y[i] = if h[i][i] == 0.0 { 0.0 } else { s / h[i][i] };
                }
                for (l, yl) in y.iter().enumerate() {
                    for i in 0..n {
                        x[i] += d[i] * basis[l][i] * yl;
                    }
                }
                break;
            }
        }
        // The true residual for the restart and the test.
        apply(&x, &mut w);
        out.iterations += 1;
        for i in 0..n {
            r[i] = b[i] - w[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A nonsymmetric, diagonally dominant system with a known solution is solved to the
    /// tolerance, with and without restarts.
    #[test]
    fn gmres_solves_a_nonsymmetric_system() {
        let n = 40;
        let a = |i: usize, j: usize| -> f64 {
            if i == j {
                4.0 + i as f64 * 0.1
            } else if j == i + 1 {
                1.3
            } else if i == j + 1 {
                -0.7
            } else if j == (i * 7 + 3) % n {
                0.2
            } else {
                0.0
            }
        };
        let exact: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let b: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| a(i, j) * exact[j]).sum())
            .collect();
        let apply = |v: &[f64], out: &mut [f64]| {
            for i in 0..n {
                out[i] = (0..n).map(|j| a(i, j) * v[j]).sum();
            }
        };
        let d: Vec<f64> = (0..n).map(|i| 1.0 / a(i, i)).collect();
        for restart in [5, 40] {
            let (x, o) = gmres(apply, &d, &b, 1e-12, restart, 500);
            assert!(o.relative_residual <= 1e-12, "{o:?}");
            let err = x
                .iter()
                .zip(&exact)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-10, "restart {restart}: error {err}, {o:?}");
        }
    }
}
