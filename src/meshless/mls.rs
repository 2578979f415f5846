//! Moving Least Squares shape functions and their first derivatives: linear MLS (m = 4) and the
//! Modified MLS with quadratic basis (MMLS, m = 10; thesis ch. 2.3 and 3.3, Horton 2010 sect. 2.4).
//!
//! The basis is shifted to the evaluation point and scaled by the support length, so the
//! moment matrix is built from numbers of order one whatever the model's position and size
//! (thesis sect. 2.4.4: the MMLS shape functions are invariant to translation, eq. 2.38, and to
//! scaling when mu scales with the fourth power of the length, eq. 2.51 - which expressing mu in
//! support-scaled coordinates does automatically). The conditioning check then means the same
//! thing for a brain in metres at the scanner origin as for a unit cube.

use nalgebra::{Cholesky, Matrix4, SMatrix, SVector, Vector3, Vector4};

/// Number of terms of the linear basis [1, x, y, z].
const M_LINEAR: usize = 4;
/// Number of terms of the quadratic basis [1, x, y, z, xx, yy, zz, xy, yz, zx].
const M_QUADRATIC: usize = 10;

/// Polynomial basis of the MLS approximation (thesis eq. 3.11, 3D form of eq. 2.2-2.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Basis {
    /// Classical linear MLS, m = 4: [1, x, y, z].
    #[default]
    Linear,
    /// Modified MLS with quadratic basis, m = 10: [1, x, y, z, xx, yy, zz, xy, yz, zx], the six
    /// second-order coefficients penalised by `mu` (thesis eq. 3.13-3.16).
    Quadratic,
}

/// Parameters of the shape-function construction.
#[derive(Debug, Clone, Copy)]
pub struct MlsSettings {
    /// Polynomial basis.
    pub basis: Basis,
    /// MMLS weight (dimensionless) on each of the six second-order coefficients, i.e. the
    /// diagonal of H in thesis eq. 3.16 (eq. 2.16 in 2D), with coordinates scaled by the support
    /// length h (the largest influence radius of the weighted nodes). Default 1e-7. Ignored for
    /// `Basis::Linear`; 0 gives classical quadratic MLS.
    pub mu: f64,
    /// Smallest accepted reciprocal condition number lambda_min / lambda_max of the scaled
    /// (modified) moment matrix, thesis eq. 2.19 / 3.15. Default 1e-10.
    pub min_rcond: f64,
}

impl Default for MlsSettings {
    fn default() -> Self {
        MlsSettings {
            basis: Basis::Linear,
            mu: 1e-7,
            min_rcond: 1e-10,
        }
    }
}

/// Quartic spline weight (Horton 2010 eq. 7): w(s) = 1 - 6 s^2 + 8 s^3 - 3 s^4 for 0 <= s < 1,
/// 0 for s >= 1 (and for NaN). Returns (w, dw/ds); s is the distance divided by the influence
/// radius (dimensionless). Even in s, so a negative s gives w(|s|) and the matching slope.
pub fn quartic(s: f64) -> (f64, f64) {
    let a = s.abs();
    if !(a < 1.0) {
        return (0.0, 0.0);
    }
    let t = 1.0 - a;
    // Factored forms (1-s)^3 (1+3s) and -12 s (1-s)^2: exactly 0 at s = 1 and strictly
    // positive below, so "w > 0" is the same test as "s < 1", without cancellation at the edge.
    (t * t * t * (1.0 + 3.0 * a), -12.0 * s * t * t)
}

/// Why shape functions could not be built at a point.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MlsError {
    /// Fewer nodes with nonzero weight than the basis needs: m for linear MLS and classical
    /// quadratic MLS (mu = 0), 4 for MMLS, whose penalty fixes the second-order part
    /// (thesis Lemma 1, sect. 2.4.1).
    #[error(
        "only {nodes} support nodes carry weight at this point, the basis needs at least {needed}"
    )]
    TooFewNodes { nodes: usize, needed: usize },
    /// The scaled moment matrix is (nearly) singular: lambda_min / lambda_max = `rcond` is below
    /// `MlsSettings::min_rcond` or not finite. Typically (nearly) coplanar support nodes for the
    /// linear basis, or a degenerate layout (e.g. two parallel planes) for classical quadratic MLS.
    #[error("moment matrix is ill-conditioned (lambda_min / lambda_max = {rcond:.3e})")]
    IllConditioned { rcond: f64 },
    /// `radii` must hold one radius per node, or a single radius shared by all nodes.
    #[error("{radii} influence radii given for {nodes} support nodes (need one per node, or one for all)")]
    RadiiMismatch { nodes: usize, radii: usize },
}

/// MLS / MMLS shape functions phi_j (dimensionless) and their derivatives dphi_j/dX (1/m) at the
/// point `x` (m) for the support nodes `nodes` (m).
///
/// Node j is weighted by w_j = `quartic(|x - x_j| / radii[j])` (radii in m: each node's
/// influence radius, or a single entry shared by all nodes). With the basis p shifted to `x` and
/// scaled by h = the largest radius among the weighted nodes,
/// phi_j = p(x)^T A^-1 p(x_j) w_j, A = P^T W P + H (thesis eq. 2.21 / 3.15; H of eq. 3.16 with
/// `s.mu` on its six second-order entries, H = 0 for the linear basis). The derivatives
/// differentiate that expression including dA/dX (the full EFG derivative, not the diffuse
/// one). The linear consistency conditions sum phi_j = 1, sum phi_j x_j = x (thesis eq.
/// 2.36-2.37) and their derivatives sum dphi_j = 0, sum x_j (outer) dphi_j = I hold to
/// round-off even when A is conditioned like 1/mu.
///
/// `phi` and `dphi` are cleared and then hold one entry per node in the order of `nodes`;
/// nodes outside their influence radius get phi = 0 and dphi = 0. Errors: fewer weighted nodes
/// than the basis needs, lambda_min / lambda_max of A below `s.min_rcond`, or a `radii` length
/// other than 1 or `nodes.len()`; on error the contents of `phi` and `dphi` are unspecified.
pub fn shape_functions(
    x: &Vector3<f64>,
    nodes: &[Vector3<f64>],
    radii: &[f64],
    s: &MlsSettings,
    phi: &mut Vec<f64>,
    dphi: &mut Vec<Vector3<f64>>,
) -> Result<(), MlsError> {
    match s.basis {
        Basis::Linear => evaluate::<M_LINEAR, true>(x, nodes, radii, 0.0, s.min_rcond, phi, dphi),
        Basis::Quadratic => {
            evaluate::<M_QUADRATIC, true>(x, nodes, radii, s.mu, s.min_rcond, phi, dphi)
        }
    }
}

/// The shape functions phi_j of [`shape_functions`] without derivatives (cheaper): probes,
/// output interpolation and boundary integrals. Thesis eq. 2.21 / 3.15.
pub fn shape_values(
    x: &Vector3<f64>,
    nodes: &[Vector3<f64>],
    radii: &[f64],
    s: &MlsSettings,
    phi: &mut Vec<f64>,
) -> Result<(), MlsError> {
    // Never pushed to, so it never allocates.
    let mut unused = Vec::new();
    match s.basis {
        Basis::Linear => {
            evaluate::<M_LINEAR, false>(x, nodes, radii, 0.0, s.min_rcond, phi, &mut unused)
        }
        Basis::Quadratic => {
            evaluate::<M_QUADRATIC, false>(x, nodes, radii, s.mu, s.min_rcond, phi, &mut unused)
        }
    }
}

/// Smallest and largest eigenvalue of a symmetric matrix given by its lower triangle.
///
/// A trait on the two concrete sizes because nalgebra's eigenvalue routine needs dimension
/// arithmetic (D - 1) that const generics cannot express without where-clauses that hide
/// nalgebra's other impls.
trait EigenRange {
    fn eigen_range(&self) -> (f64, f64);
}

macro_rules! eigen_range_impl {
    ($m:expr) => {
        impl EigenRange for SMatrix<f64, $m, $m> {
            #[inline]
            fn eigen_range(&self) -> (f64, f64) {
                let e = self.symmetric_eigenvalues();
                (e.min(), e.max())
            }
        }
    };
}
eigen_range_impl!(4);
eigen_range_impl!(10);

/// Basis vector at the scaled offset y = (x_j - x) / h. Terms 4.. exist only for M = 10.
#[inline(always)]
fn basis<const M: usize>(y: &Vector3<f64>) -> SVector<f64, M> {
    let mut p = SVector::<f64, M>::zeros();
    let v = p.as_mut_slice();
    if let Some(lin) = v.get_mut(0..4) {
        lin.copy_from_slice(&[1.0, y.x, y.y, y.z]);
    }
    if let Some(quad) = v.get_mut(4..10) {
        quad.copy_from_slice(&[
            y.x * y.x,
            y.y * y.y,
            y.z * y.z,
            y.x * y.y,
            y.y * y.z,
            y.z * y.x,
        ]);
    }
    p
}

/// The one implementation behind both public functions, monomorphised per basis size M and
/// per DERIV (with or without derivatives), all on the stack.
///
/// During the node passes `phi[j]` holds w_j and `dphi[j]` holds dw_j/dX until the final pass
/// overwrites them, which keeps the routine free of scratch allocations.
fn evaluate<const M: usize, const DERIV: bool>(
    x: &Vector3<f64>,
    nodes: &[Vector3<f64>],
    radii: &[f64],
    mu: f64,
    min_rcond: f64,
    phi: &mut Vec<f64>,
    dphi: &mut Vec<Vector3<f64>>,
) -> Result<(), MlsError>
where
    SMatrix<f64, M, M>: EigenRange,
{
    let n = nodes.len();
    if radii.len() != n && radii.len() != 1 {
        return Err(MlsError::RadiiMismatch {
            nodes: n,
            radii: radii.len(),
        });
    }
    let radius = |j: usize| if radii.len() == 1 { radii[0] } else { radii[j] };

    // Pass 1: weights, their gradients, and the support length h.
    phi.clear();
    dphi.clear();
    let mut weighted = 0usize;
    let mut h = 0.0f64;
    for (j, xj) in nodes.iter().enumerate() {
        let r = radius(j);
        let d = xj - x;
        let dist = d.norm();
        // A radius that is not a positive finite number gives the node no weight rather than
        // NaN / inf entries in the moment matrix.
        let (w, _) = if r > 0.0 && r.is_finite() {
            quartic(dist / r)
        } else {
            (0.0, 0.0)
        };
        phi.push(w);
        if DERIV {
            // dw/dX = w'(s) ds/dX with ds/dX = (X - x_j) / (|X - x_j| r) and
            // w'(s) = -12 s (1 - s)^2; s / |X - x_j| = 1 / r removes the 0/0 at the node itself.
            let g = if w > 0.0 {
                let t = 1.0 - dist / r;
                d * (12.0 * t * t / (r * r))
            } else {
                Vector3::zeros()
            };
            dphi.push(g);
        }
        if w > 0.0 {
            weighted += 1;
            h = h.max(r);
        }
    }
    // Classical quadratic MLS must determine all ten coefficients from the data; MMLS only the
    // linear part, the penalty fixes the rest (thesis Lemma 1).
    let needed = if M == M_QUADRATIC && mu > 0.0 {
        M_LINEAR
    } else {
        M
    };
    if weighted < needed {
        return Err(MlsError::TooFewNodes {
            nodes: weighted,
            needed,
        });
    }
    let inv_h = 1.0 / h;

    // Pass 2: modified moment matrix A = sum_j w_j p_j p_j^T + H (thesis eq. 2.19 / 3.15,
    // H of eq. 3.16), lower triangle only: that is all the eigenvalue and Cholesky routines read.
    let mut a = SMatrix::<f64, M, M>::zeros();
    for (xj, &w) in nodes.iter().zip(phi.iter()) {
        if w > 0.0 {
            let p = basis::<M>(&((xj - x) * inv_h));
            for c in 0..M {
                let wc = w * p[c];
                for r in c..M {
                    a[(r, c)] += wc * p[r];
                }
            }
        }
    }
    for k in M_LINEAR..M {
        a[(k, k)] += mu;
    }

    let chol = factor_checked(a, min_rcond)?;

    // p(x) = e_1 in shifted coordinates, so gamma = A^-1 e_1 and phi_j = w_j gamma . p_j.
    let mut e1 = SVector::<f64, M>::zeros();
    e1[0] = 1.0;
    let gamma = chol.solve(&e1);
    // The leading 4x4 block of the Cholesky factor of A is the factor of the linear block A11
    // (H is zero there); by eigenvalue interlacing A11 is at least as well conditioned as A.
    let l11: Matrix4<f64> = chol.l_dirty().fixed_view::<4, 4>(0, 0).into_owned();
    let node_p = |xj: &Vector3<f64>| basis::<M>(&((xj - x) * inv_h));
    let lin = |p: &SVector<f64, M>| -> Vector4<f64> { p.fixed_rows::<4>(0).into_owned() };

    // Why a consistency correction: on supports where the unmodified moment matrix is (nearly)
    // singular (nodes on two planes, few nodes) A has condition ~ 1/mu and gamma a component of
    // size ~ 1/mu that p_j . gamma cancels, so phi carries round-off ~ eps/mu and the linear
    // consistency sum_j phi_j p_lin(x_j) = p_lin(x) (thesis eq. 2.36-2.37, the patch test)
    // would hold only to ~1e-10. The residual of those four conditions, measured on the
    // computed O(1) values, is removed with one solve on the linear block A11 (for MMLS far
    // better conditioned than A; for linear MLS this is one step of iterative refinement):
    // phi_j += w_j p_lin(x_j) . A11^-1 rho. The change is of the size of the round-off itself.
    // Columns of `rho`: value, d/dX, d/dY, d/dZ (targets e_1 and e_{k+1} / h).
    let mut rho = Matrix4::<f64>::zeros();
    rho[(0, 0)] = 1.0;
    for k in 0..3 {
        rho[(k + 1, k + 1)] = inv_h;
    }

    if !DERIV {
        for (xj, &w) in nodes.iter().zip(phi.iter()) {
            if w > 0.0 {
                let p = node_p(xj);
                rho.column_mut(0).axpy(-w * gamma.dot(&p), &lin(&p), 1.0);
            }
        }
        let c = solve_l11(&l11, &rho.column(0).into_owned());
        for (xj, f) in nodes.iter().zip(phi.iter_mut()) {
            let w = *f;
            *f = if w > 0.0 {
                let p = node_p(xj);
                w * (gamma.dot(&p) + lin(&p).dot(&c))
            } else {
                0.0
            };
        }
        return Ok(());
    }

    // Derivatives with the basis origin and scale frozen at x (allowed by the translation
    // invariance, thesis Lemma 4 eq. 2.38): phi_j(X) = p(X)^T A(X)^-1 p_j w_j(X), hence
    //   dgamma_k = A^-1 (dp/dX_k - dA/dX_k gamma),  dA/dX_k = sum_j dw_j/dX_k p_j p_j^T,
    //   dphi_j,k = dgamma_k . p_j w_j + gamma . p_j dw_j/dX_k,
    // where dp/dX_k at the origin is e_{k+1} / h (second-order terms have zero slope there).
    // dA_k gamma is accumulated as sum_j dw_jk (p_j . gamma) p_j: O(n m), never forming dA_k.
    let mut rhs = SMatrix::<f64, M, 3>::zeros();
    for k in 0..3 {
        rhs[(k + 1, k)] = inv_h;
    }
    for ((xj, &w), dw) in nodes.iter().zip(phi.iter()).zip(dphi.iter()) {
        if w > 0.0 {
            let p = node_p(xj);
            let g = gamma.dot(&p);
            for k in 0..3 {
                rhs.column_mut(k).axpy(-g * dw[k], &p, 1.0);
            }
            rho.column_mut(0).axpy(-w * g, &lin(&p), 1.0);
        }
    }
    let dgamma = chol.solve(&rhs);
    let dphi_raw =
        |p: &SVector<f64, M>, w: f64, g: f64, dw: &Vector3<f64>| dgamma.tr_mul(p) * w + dw * g;
    for ((xj, &w), dw) in nodes.iter().zip(phi.iter()).zip(dphi.iter()) {
        if w > 0.0 {
            let p = node_p(xj);
            let d = dphi_raw(&p, w, gamma.dot(&p), dw);
            let pl = lin(&p);
            for k in 0..3 {
                rho.column_mut(k + 1).axpy(-d[k], &pl, 1.0);
            }
        }
    }
    let c = solve_l11(&l11, &rho);

    for ((xj, f), df) in nodes.iter().zip(phi.iter_mut()).zip(dphi.iter_mut()) {
        let w = *f;
        if w > 0.0 {
            let p = node_p(xj);
            let g = gamma.dot(&p);
            let cp = c.tr_mul(&lin(&p));
            *f = w * (g + cp[0]);
            *df = dphi_raw(&p, w, g, df) + Vector3::new(cp[1], cp[2], cp[3]) * w;
        } else {
            *f = 0.0;
            *df = Vector3::zeros();
        }
    }
    Ok(())
}

/// Cholesky factor of the moment matrix `a` (lower triangle read), or IllConditioned when
/// lambda_min / lambda_max < `min_rcond` (or not finite, or `a` not positive definite).
///
/// The 10x10 eigenvalues cost more than everything else in an evaluation, so they are computed
/// only when a cheap bound cannot decide: lambda_max <= tr A and lambda_min >= 1 / tr A^-1 with
/// tr A^-1 = |L^-1|_F^2, so 1 / (tr A tr A^-1) <= lambda_min / lambda_max (within a factor m^2
/// of it). Accepting on the bound therefore gives the eigenvalue test's answer, up to the
/// round-off both carry right at the threshold.
fn factor_checked<const M: usize>(
    a: SMatrix<f64, M, M>,
    min_rcond: f64,
) -> Result<Cholesky<f64, nalgebra::Const<M>>, MlsError>
where
    SMatrix<f64, M, M>: EigenRange,
{
    // The eigenvalue iteration has no bound on its iterations and is not meant for NaN / inf.
    if !a.iter().all(|v| v.is_finite()) {
        return Err(MlsError::IllConditioned { rcond: f64::NAN });
    }
    let chol = Cholesky::new(a);
    if let Some(c) = &chol {
        if 1.0 / (a.trace() * inverse_lower_norm_squared(c.l_dirty())) >= min_rcond {
            return chol.ok_or(MlsError::IllConditioned { rcond: f64::NAN });
        }
    }
    let (lmin, lmax) = a.eigen_range();
    let rcond = lmin / lmax;
    // Written so that NaN (lmax = 0) and negative eigenvalues (mu < 0) are rejected too.
    match chol {
        Some(c) if rcond >= min_rcond && rcond.is_finite() => Ok(c),
        _ => Err(MlsError::IllConditioned { rcond }),
    }
}

/// |L^-1|_F^2 (= trace A^-1 for A = L L^T) of a lower-triangular `l` with positive diagonal;
/// only the lower triangle is read.
fn inverse_lower_norm_squared<const M: usize>(l: &SMatrix<f64, M, M>) -> f64 {
    let mut sum = 0.0;
    let mut col = [0.0f64; M];
    for c in 0..M {
        // Column c of L^-1 by forward substitution; entries above c are zero.
        for i in c..M {
            let mut v = if i == c { 1.0 } else { 0.0 };
            for k in c..i {
                v -= l[(i, k)] * col[k];
            }
            col[i] = v / l[(i, i)];
            sum += col[i] * col[i];
        }
    }
    sum
}

/// Solves A11 X = B given the lower Cholesky factor `l` of A11 (positive diagonal, as any
/// successful Cholesky factor has).
fn solve_l11<const C: usize>(l: &Matrix4<f64>, b: &SMatrix<f64, 4, C>) -> SMatrix<f64, 4, C> {
    let mut x = *b;
    for c in 0..C {
        for i in 0..4 {
            let mut v = x[(i, c)];
            for k in 0..i {
                v -= l[(i, k)] * x[(k, c)];
            }
            x[(i, c)] = v / l[(i, i)];
        }
        for i in (0..4).rev() {
            let mut v = x[(i, c)];
            for k in i + 1..4 {
                v -= l[(k, i)] * x[(k, c)];
            }
            x[(i, c)] = v / l[(i, i)];
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tiny LCG so the clouds are irregular but reproducible.
    struct Lcg(u64);
    impl Lcg {
        fn uniform(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        fn vec(&mut self, lo: f64, hi: f64) -> Vector3<f64> {
            Vector3::new(
                lo + (hi - lo) * self.uniform(),
                lo + (hi - lo) * self.uniform(),
                lo + (hi - lo) * self.uniform(),
            )
        }
    }

    /// 5x5x5 grid of spacing 0.25 m, each node jittered by up to +-0.1 m per axis.
    fn cloud(seed: u64) -> Vec<Vector3<f64>> {
        let mut g = Lcg(seed);
        let mut v = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                for k in 0..5 {
                    let base = Vector3::new(i as f64, j as f64, k as f64) * 0.25;
                    v.push(base + g.vec(-0.1, 0.1));
                }
            }
        }
        v
    }

    /// Per-node radii 0.36..0.48 m.
    fn node_radii(n: usize, seed: u64) -> Vec<f64> {
        let mut g = Lcg(seed);
        (0..n).map(|_| 0.36 + 0.12 * g.uniform()).collect()
    }

    fn eval_points(seed: u64, n: usize) -> Vec<Vector3<f64>> {
        let mut g = Lcg(seed);
        (0..n).map(|_| g.vec(0.3, 0.7)).collect()
    }

    fn in_support(x: &Vector3<f64>, nodes: &[Vector3<f64>], radii: &[f64]) -> usize {
        nodes
            .iter()
            .enumerate()
            .filter(|(j, xj)| (*xj - x).norm() < radii[if radii.len() == 1 { 0 } else { *j }])
            .count()
    }

    fn settings(basis: Basis, mu: f64) -> MlsSettings {
        MlsSettings {
            basis,
            mu,
            ..MlsSettings::default()
        }
    }

    /// Max over the point of |sum phi - 1|, |sum dphi|, |sum phi x_j - x| and
    /// |sum x_j (outer) dphi_j - I|.
    fn consistency_errors(
        x: &Vector3<f64>,
        nodes: &[Vector3<f64>],
        phi: &[f64],
        dphi: &[Vector3<f64>],
    ) -> (f64, f64, f64, f64) {
        let sum_phi: f64 = phi.iter().sum();
        let sum_dphi: Vector3<f64> = dphi.iter().sum();
        let mut rx = Vector3::zeros();
        let mut rg = nalgebra::Matrix3::<f64>::zeros();
        for j in 0..nodes.len() {
            rx += nodes[j] * phi[j];
            rg += nodes[j] * dphi[j].transpose();
        }
        (
            (sum_phi - 1.0).abs(),
            sum_dphi.amax(),
            (rx - x).amax(),
            (rg - nalgebra::Matrix3::identity()).amax(),
        )
    }

    #[test]
    fn quartic_weight() {
        assert_eq!(quartic(0.0), (1.0, 0.0));
        assert_eq!(quartic(1.0), (0.0, 0.0));
        assert_eq!(quartic(1.5), (0.0, 0.0));
        assert_eq!(quartic(f64::NAN), (0.0, 0.0));
        assert_eq!(quartic(-1.5), (0.0, 0.0));
        assert_eq!(quartic(-0.3), (quartic(0.3).0, -quartic(0.3).1));
        for &s in &[0.1, 0.37, 0.5, 0.93] {
            let (w, dw) = quartic(s);
            let poly = 1.0 - 6.0 * s * s + 8.0 * s.powi(3) - 3.0 * s.powi(4);
            assert!((w - poly).abs() < 1e-15);
            let fd = (quartic(s + 1e-6).0 - quartic(s - 1e-6).0) / 2e-6;
            assert!((dw - fd).abs() < 1e-8, "{dw} vs {fd}");
        }
    }

    /// Test 1: partition of unity and linear reproduction, values and derivatives, both bases,
    /// per-node radii and one common radius.
    #[test]
    fn consistency_on_irregular_cloud() {
        let nodes = cloud(7);
        let per_node = node_radii(nodes.len(), 11);
        let common = vec![0.42];
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        for (name, radii) in [("per-node", &per_node), ("common", &common)] {
            for basis in [Basis::Linear, Basis::Quadratic] {
                let s = settings(basis, 1e-7);
                let mut worst = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
                let (mut nmin, mut nmax) = (usize::MAX, 0);
                for x in eval_points(3, 50) {
                    let count = in_support(&x, &nodes, radii);
                    nmin = nmin.min(count);
                    nmax = nmax.max(count);
                    shape_functions(&x, &nodes, radii, &s, &mut phi, &mut dphi).unwrap();
                    assert_eq!(phi.len(), nodes.len());
                    assert_eq!(dphi.len(), nodes.len());
                    let e = consistency_errors(&x, &nodes, &phi, &dphi);
                    worst = (
                        worst.0.max(e.0),
                        worst.1.max(e.1),
                        worst.2.max(e.2),
                        worst.3.max(e.3),
                    );
                    // Nodes outside their radius stay in place with exact zeros.
                    for j in 0..nodes.len() {
                        let r = radii[if radii.len() == 1 { 0 } else { j }];
                        if (nodes[j] - x).norm() >= r {
                            assert_eq!(phi[j], 0.0);
                            assert_eq!(dphi[j], Vector3::zeros());
                        }
                    }
                    // The values-only path gives the same numbers.
                    let mut phi2 = Vec::new();
                    shape_values(&x, &nodes, radii, &s, &mut phi2).unwrap();
                    for j in 0..nodes.len() {
                        assert!((phi2[j] - phi[j]).abs() < 1e-14);
                    }
                }
                println!(
                    "consistency {name:8} {basis:?}: support {nmin}..{nmax} nodes, |sum phi - 1| {:.1e}, |sum dphi| {:.1e} 1/m, \
                     |sum phi x - x| {:.1e} m, |sum x dphi - I| {:.1e}",
                    worst.0, worst.1, worst.2, worst.3
                );
                assert!((12..=40).contains(&nmin) && (12..=40).contains(&nmax));
                assert!(worst.0 < 1e-12 && worst.1 < 1e-12, "{worst:?}");
                assert!(worst.2 < 1e-10 && worst.3 < 1e-10, "{worst:?}");
            }
        }
    }

    fn quad_field(x: &Vector3<f64>) -> (f64, Vector3<f64>) {
        let (a, b, c) = (x.x, x.y, x.z);
        let f = 0.3 + 1.2 * a - 0.7 * b + 0.4 * c + 0.9 * a * a - 0.5 * b * b
            + 0.6 * c * c
            + 0.8 * a * b
            - 0.3 * b * c
            + 0.45 * c * a;
        let g = Vector3::new(
            1.2 + 1.8 * a + 0.8 * b + 0.45 * c,
            -0.7 - 1.0 * b + 0.8 * a - 0.3 * c,
            0.4 + 1.2 * c - 0.3 * b + 0.45 * a,
        );
        (f, g)
    }

    /// Worst relative errors (value, gradient) in reproducing `quad_field` over the points.
    fn quadratic_reproduction(mu: f64) -> (f64, f64) {
        let nodes = cloud(7);
        let radii = node_radii(nodes.len(), 11);
        let s = settings(Basis::Quadratic, mu);
        let fvals: Vec<(f64, Vector3<f64>)> = nodes.iter().map(quad_field).collect();
        let fscale = fvals.iter().map(|v| v.0.abs()).fold(0.0, f64::max);
        let gscale = fvals.iter().map(|v| v.1.norm()).fold(0.0, f64::max);
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        let (mut ef, mut eg) = (0.0f64, 0.0f64);
        for x in eval_points(5, 50) {
            shape_functions(&x, &nodes, &radii, &s, &mut phi, &mut dphi).unwrap();
            let (f, g) = quad_field(&x);
            let fh: f64 = (0..nodes.len()).map(|j| phi[j] * fvals[j].0).sum();
            let gh: Vector3<f64> = (0..nodes.len()).map(|j| dphi[j] * fvals[j].0).sum();
            ef = ef.max((fh - f).abs() / fscale);
            eg = eg.max((gh - g).norm() / gscale);
        }
        (ef, eg)
    }

    /// Test 2: MMLS reproduces a quadratic field up to a bias set by mu.
    #[test]
    fn mmls_quadratic_reproduction_depends_on_mu() {
        let mus = [0.0, 1e-9, 1e-7, 1e-5, 1e-3];
        let errs: Vec<(f64, f64)> = mus.iter().map(|&mu| quadratic_reproduction(mu)).collect();
        for (mu, (ef, eg)) in mus.iter().zip(&errs) {
            println!("quadratic reproduction mu = {mu:.0e}: relative error value {ef:.2e}, gradient {eg:.2e}");
        }
        // Classical quadratic MLS (mu = 0) reproduces quadratics to round-off.
        assert!(errs[0].0 < 1e-12 && errs[0].1 < 1e-12, "{:?}", errs[0]);
        // The default mu = 1e-7 biases them slightly: the quadratic Schur complement of the
        // scaled moment matrix has eigenvalues down to ~3e-4 on this cloud, and the bias is
        // ~ mu / that, larger in the gradient (measured 5e-7 value, 2e-5 gradient).
        assert!(errs[2].0 < 1e-5 && errs[2].1 < 1e-4, "{:?}", errs[2]);
        // The bias grows with mu.
        for k in 1..mus.len() {
            assert!(
                errs[k].0 > errs[k - 1].0 && errs[k].1 > errs[k - 1].1,
                "{:?}",
                errs
            );
        }
        assert!(errs[4].0 > 100.0 * errs[2].0 && errs[4].1 > 100.0 * errs[2].1);
    }

    /// Two parallel planes z = 0 and z = 1 m, 4x4 grid of spacing 1 m on each.
    fn two_planes() -> Vec<Vector3<f64>> {
        let mut v = Vec::new();
        for k in 0..2 {
            for i in 0..4 {
                for j in 0..4 {
                    v.push(Vector3::new(i as f64, j as f64, k as f64));
                }
            }
        }
        v
    }

    /// Test 3: classical quadratic MLS is singular on two planes (z^2 = z on the nodes); MMLS is not.
    #[test]
    fn mmls_handles_two_parallel_planes() {
        let nodes = two_planes();
        let radii = [3.5];
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        let points = [
            Vector3::new(1.3, 1.6, 0.5),
            Vector3::new(1.5, 1.5, 0.0),
            Vector3::new(0.7, 2.2, 0.8),
            Vector3::new(2.1, 1.1, 0.25),
        ];
        let mut worst = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for x in &points {
            let r = shape_functions(
                x,
                &nodes,
                &radii,
                &settings(Basis::Quadratic, 0.0),
                &mut phi,
                &mut dphi,
            );
            match r {
                Err(MlsError::IllConditioned { rcond }) => {
                    println!("two planes, mu = 0: rcond {rcond:.1e}")
                }
                other => panic!("classical quadratic MLS on two planes: {other:?}"),
            }
            shape_functions(
                x,
                &nodes,
                &radii,
                &settings(Basis::Quadratic, 1e-7),
                &mut phi,
                &mut dphi,
            )
            .unwrap();
            let e = consistency_errors(x, &nodes, &phi, &dphi);
            worst = (
                worst.0.max(e.0),
                worst.1.max(e.1),
                worst.2.max(e.2),
                worst.3.max(e.3),
            );
        }
        println!(
            "two planes, mu = 1e-7: |sum phi - 1| {:.1e}, |sum dphi| {:.1e}, |sum phi x - x| {:.1e}, |sum x dphi - I| {:.1e}",
            worst.0, worst.1, worst.2, worst.3
        );
        assert!(
            worst.0 < 1e-10 && worst.1 < 1e-10 && worst.2 < 1e-10 && worst.3 < 1e-10,
            "{worst:?}"
        );
    }

    /// Test 4: a coplanar support cannot determine the linear coefficient normal to the plane.
    #[test]
    fn coplanar_support_is_ill_conditioned() {
        let nodes: Vec<Vector3<f64>> = two_planes().into_iter().take(16).collect();
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        for x in [Vector3::new(1.3, 1.6, 0.0), Vector3::new(1.3, 1.6, 0.4)] {
            for s in [
                settings(Basis::Linear, 0.0),
                settings(Basis::Quadratic, 1e-7),
            ] {
                let r = shape_functions(&x, &nodes, &[3.5], &s, &mut phi, &mut dphi);
                match r {
                    Err(MlsError::IllConditioned { rcond }) => {
                        println!("coplanar {:?} at z = {}: rcond {rcond:.1e}", s.basis, x.z)
                    }
                    other => panic!("coplanar support, {:?}: {other:?}", s.basis),
                }
                assert!(matches!(
                    shape_values(&x, &nodes, &[3.5], &s, &mut phi),
                    Err(MlsError::IllConditioned { .. })
                ));
            }
        }
    }

    /// A nearly coplanar support (out-of-plane jitter 1e-4 of the spacing) passes the rcond
    /// check with rcond ~1e-9, where the moment solve alone leaves the linear consistency at
    /// ~eps / rcond; the consistency correction keeps it at round-off.
    #[test]
    fn nearly_coplanar_support_stays_consistent() {
        let mut g = Lcg(5);
        let nodes: Vec<Vector3<f64>> = two_planes()
            .into_iter()
            .take(16)
            .map(|p| p + Vector3::new(0.0, 0.0, 2e-4 * (g.uniform() - 0.5)))
            .collect();
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        for x in [Vector3::new(1.3, 1.6, 0.0), Vector3::new(1.3, 1.6, 0.3)] {
            let s = MlsSettings::default();
            shape_functions(&x, &nodes, &[3.5], &s, &mut phi, &mut dphi).unwrap();
            let e = consistency_errors(&x, &nodes, &phi, &dphi);
            println!(
                "nearly coplanar, linear, z = {}: |sum phi - 1| {:.1e}, |sum dphi| {:.1e}, |sum phi x - x| {:.1e}, |sum x dphi - I| {:.1e}",
                x.z, e.0, e.1, e.2, e.3
            );
            assert!(
                e.0 < 1e-12 && e.1 < 1e-12 && e.2 < 1e-12 && e.3 < 1e-12,
                "{e:?}"
            );
            // Ten times less jitter is rejected.
            let flatter: Vec<Vector3<f64>> = nodes
                .iter()
                .map(|p| Vector3::new(p.x, p.y, p.z * 0.1))
                .collect();
            match shape_functions(&x, &flatter, &[3.5], &s, &mut phi, &mut dphi) {
                Err(MlsError::IllConditioned { rcond }) => {
                    println!("  ten times flatter: rcond {rcond:.1e}")
                }
                other => panic!("{other:?}"),
            }
        }
    }

    /// The trace bound that skips the eigenvalues never changes the accept / reject decision:
    /// random SPD matrices with prescribed spectra around the threshold.
    fn conditioning_decisions<const M: usize>(seed: u64)
    where
        SMatrix<f64, M, M>: EigenRange,
    {
        let mut g = Lcg(seed);
        let min_rcond = 1e-10;
        let mut counts = [0usize; 2];
        for _ in 0..400 {
            // A product of random Householder reflections: a generic orthogonal matrix.
            let mut q = SMatrix::<f64, M, M>::identity();
            for _ in 0..4 {
                let v = SVector::<f64, M>::from_fn(|_, _| g.uniform() - 0.5).normalize();
                q *= SMatrix::<f64, M, M>::identity() - v * v.transpose() * 2.0;
            }
            let lmax = 1.0 + 4.0 * g.uniform();
            // Target rcond log-uniform over 1e-13..1e-7, other eigenvalues in between.
            let rcond = 10f64.powf(-13.0 + 6.0 * g.uniform());
            if (rcond / min_rcond).ln().abs() < 1e-4 {
                continue;
            }
            let mut lam = SVector::<f64, M>::from_fn(|_, _| lmax * rcond.powf(g.uniform()));
            lam[0] = lmax;
            lam[M - 1] = lmax * rcond;
            let a = q * SMatrix::<f64, M, M>::from_diagonal(&lam) * q.transpose();
            let ok = factor_checked(a, min_rcond).is_ok();
            assert_eq!(ok, rcond >= min_rcond, "rcond {rcond:e}");
            counts[ok as usize] += 1;
        }
        println!(
            "conditioning check m = {M}: {} accepted, {} rejected, all as the spectrum says",
            counts[1], counts[0]
        );
        assert!(counts[0] > 50 && counts[1] > 50);
    }

    #[test]
    fn conditioning_bound_agrees_with_eigenvalues() {
        conditioning_decisions::<4>(17);
        conditioning_decisions::<10>(19);
        // Not positive definite, or not finite: rejected, not a panic.
        let mut a = SMatrix::<f64, 10, 10>::identity();
        a[(3, 3)] = -1.0;
        assert!(matches!(
            factor_checked(a, 1e-10),
            Err(MlsError::IllConditioned { .. })
        ));
        a[(3, 3)] = f64::NAN;
        assert!(matches!(
            factor_checked(a, 1e-10),
            Err(MlsError::IllConditioned { .. })
        ));
        assert!(matches!(
            factor_checked(SMatrix::<f64, 4, 4>::zeros(), 1e-10),
            Err(MlsError::IllConditioned { .. })
        ));
    }

    /// Test 5: too few weighted nodes, and mismatched radii.
    #[test]
    fn too_few_nodes() {
        let x = Vector3::new(0.0, 0.0, 0.0);
        // Three nodes inside radius 1, five well outside.
        let mut nodes = vec![
            Vector3::new(0.3, 0.0, 0.1),
            Vector3::new(0.0, 0.4, 0.0),
            Vector3::new(0.1, 0.1, -0.5),
        ];
        for k in 0..5 {
            nodes.push(Vector3::new(2.0 + k as f64, 1.0, 0.0));
        }
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        let three = MlsError::TooFewNodes {
            nodes: 3,
            needed: 4,
        };
        for s in [
            settings(Basis::Linear, 0.0),
            settings(Basis::Quadratic, 1e-7),
        ] {
            assert_eq!(
                shape_functions(&x, &nodes, &[1.0], &s, &mut phi, &mut dphi),
                Err(three.clone())
            );
            assert_eq!(
                shape_values(&x, &nodes, &[1.0], &s, &mut phi),
                Err(three.clone())
            );
        }
        // Classical quadratic MLS needs all ten coefficients from the data.
        let mut g = Lcg(1);
        let six: Vec<Vector3<f64>> = (0..6).map(|_| g.vec(-0.5, 0.5)).collect();
        assert_eq!(
            shape_functions(
                &x,
                &six,
                &[1.0],
                &settings(Basis::Quadratic, 0.0),
                &mut phi,
                &mut dphi
            ),
            Err(MlsError::TooFewNodes {
                nodes: 6,
                needed: 10
            })
        );
        // ...while MMLS builds shape functions from the same six.
        shape_functions(
            &x,
            &six,
            &[1.0],
            &settings(Basis::Quadratic, 1e-7),
            &mut phi,
            &mut dphi,
        )
        .unwrap();
        assert!((phi.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // Degenerate inputs are errors, not panics.
        assert_eq!(
            shape_functions(&x, &[], &[], &MlsSettings::default(), &mut phi, &mut dphi),
            Err(MlsError::TooFewNodes {
                nodes: 0,
                needed: 4
            })
        );
        assert_eq!(
            shape_values(
                &Vector3::repeat(f64::NAN),
                &six,
                &[1.0],
                &MlsSettings::default(),
                &mut phi
            ),
            Err(MlsError::TooFewNodes {
                nodes: 0,
                needed: 4
            })
        );
        assert_eq!(
            shape_values(&x, &six, &[1.0, 1.0], &MlsSettings::default(), &mut phi),
            Err(MlsError::RadiiMismatch { nodes: 6, radii: 2 })
        );
    }

    /// Test 6: analytic derivatives against central differences of the values.
    #[test]
    fn derivatives_match_finite_differences() {
        let nodes = cloud(7);
        let radii = node_radii(nodes.len(), 11);
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        let (mut pp, mut pm) = (Vec::new(), Vec::new());
        for basis in [Basis::Linear, Basis::Quadratic] {
            let s = settings(basis, 1e-7);
            let mut worst = 0.0f64;
            let mut tested = 0;
            for x in eval_points(9, 30) {
                // Skip points where a node sits within a few steps of its support edge: there the
                // central difference would straddle the support change.
                let step = 1e-6 * 0.42;
                let near_edge =
                    (0..nodes.len()).any(|j| ((nodes[j] - x).norm() / radii[j] - 1.0).abs() < 1e-4);
                if near_edge {
                    continue;
                }
                tested += 1;
                shape_functions(&x, &nodes, &radii, &s, &mut phi, &mut dphi).unwrap();
                let scale = dphi.iter().map(|g| g.amax()).fold(0.0, f64::max);
                for k in 0..3 {
                    let mut e = Vector3::zeros();
                    e[k] = step;
                    shape_values(&(x + e), &nodes, &radii, &s, &mut pp).unwrap();
                    shape_values(&(x - e), &nodes, &radii, &s, &mut pm).unwrap();
                    for j in 0..nodes.len() {
                        let fd = (pp[j] - pm[j]) / (2.0 * step);
                        worst = worst.max((fd - dphi[j][k]).abs() / scale);
                    }
                }
            }
            println!("derivatives vs central differences {basis:?}: {tested} points, max relative error {worst:.1e}");
            assert!(tested >= 10);
            assert!(worst < 1e-6, "{worst:e}");
        }
    }

    /// Test 7: translating everything by 1000 m, or scaling it to millimetres, leaves phi
    /// unchanged (thesis eq. 2.38 and 2.52) and scales dphi by the inverse length.
    #[test]
    fn translation_and_scale_invariance() {
        let nodes = cloud(7);
        let radii = node_radii(nodes.len(), 11);
        let off = Vector3::new(1000.0, -1000.0, 1000.0);
        let shifted: Vec<Vector3<f64>> = nodes.iter().map(|p| p + off).collect();
        let sc = 1e-3;
        let scaled: Vec<Vector3<f64>> = nodes.iter().map(|p| p * sc).collect();
        let scaled_radii: Vec<f64> = radii.iter().map(|r| r * sc).collect();
        let (mut phi, mut dphi) = (Vec::new(), Vec::new());
        let (mut phi2, mut dphi2) = (Vec::new(), Vec::new());
        for basis in [Basis::Linear, Basis::Quadratic] {
            let s = settings(basis, 1e-7);
            let (mut et, mut etd, mut es, mut esd) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for x in eval_points(13, 20) {
                shape_functions(&x, &nodes, &radii, &s, &mut phi, &mut dphi).unwrap();
                let dscale = dphi.iter().map(|g| g.amax()).fold(0.0, f64::max);
                shape_functions(&(x + off), &shifted, &radii, &s, &mut phi2, &mut dphi2).unwrap();
                for j in 0..nodes.len() {
                    et = et.max((phi2[j] - phi[j]).abs());
                    etd = etd.max((dphi2[j] - dphi[j]).amax() / dscale);
                }
                shape_functions(&(x * sc), &scaled, &scaled_radii, &s, &mut phi2, &mut dphi2)
                    .unwrap();
                for j in 0..nodes.len() {
                    es = es.max((phi2[j] - phi[j]).abs());
                    esd = esd.max((dphi2[j] * sc - dphi[j]).amax() / dscale);
                }
            }
            println!(
                "invariance {basis:?}: +1000 m shift max |d phi| {et:.1e}, relative |d dphi| {etd:.1e}; \
                 x1e-3 scale max |d phi| {es:.1e}, relative |d dphi| {esd:.1e}"
            );
            assert!(et < 1e-9 && etd < 1e-8, "{et:e} {etd:e}");
            assert!(es < 1e-12 && esd < 1e-12, "{es:e} {esd:e}");
        }
    }

    /// Time per call; run with `cargo test --release --lib meshless::mls -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing() {
        use std::hint::black_box;
        use std::time::Instant;
        let mut g = Lcg(42);
        for (basis, n, iters) in [
            (Basis::Linear, 16usize, 100_000usize),
            (Basis::Quadratic, 30, 30_000),
        ] {
            let nodes: Vec<Vector3<f64>> = (0..n).map(|_| g.vec(-1.0, 1.0)).collect();
            let radii: Vec<f64> = (0..n).map(|_| 1.8 + 0.4 * g.uniform()).collect();
            let s = settings(basis, 1e-7);
            let x = Vector3::new(0.05, -0.02, 0.03);
            let (mut phi, mut dphi) = (Vec::with_capacity(n), Vec::with_capacity(n));
            shape_functions(&x, &nodes, &radii, &s, &mut phi, &mut dphi).unwrap();
            assert_eq!(phi.iter().filter(|p| **p != 0.0).count(), n);
            // The machine is shared: the best of a few repetitions is the least disturbed.
            let (mut with, mut without) = (f64::INFINITY, f64::INFINITY);
            for _ in 0..7 {
                let t = Instant::now();
                for _ in 0..iters {
                    shape_functions(
                        black_box(&x),
                        black_box(&nodes),
                        &radii,
                        &s,
                        &mut phi,
                        &mut dphi,
                    )
                    .unwrap();
                    black_box(&dphi);
                }
                with = with.min(t.elapsed().as_secs_f64() / iters as f64);
                let t = Instant::now();
                for _ in 0..iters {
                    shape_values(black_box(&x), black_box(&nodes), &radii, &s, &mut phi).unwrap();
                    black_box(&phi);
                }
                without = without.min(t.elapsed().as_secs_f64() / iters as f64);
            }
            println!(
                "timing {basis:?}, {n} nodes: shape_functions {:.2} us/call, shape_values {:.2} us/call",
                with * 1e6,
                without * 1e6
            );
        }
    }
}
