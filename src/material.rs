//! Hyperelastic materials behind a small trait, so models can be added without touching kernels.

use nalgebra::Matrix3;

/// A hyperelastic material in the total-Lagrangian setting.
///
/// Kernels are generic over this trait (monomorphised), so a call costs nothing extra.
pub trait Material: Send + Sync + Clone {
    /// Strain energy density W(F) per unit reference volume, J/m^3.
    fn strain_energy(&self, f: &Matrix3<f64>) -> f64;
    /// Second Piola-Kirchhoff stress S = 2 dW/dC, Pa, from the deformation gradient F
    /// (`j` = det F, passed because kernels already have it).
    fn pk2_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64>;
    /// First Piola-Kirchhoff stress P = F S, Pa (what the force kernel needs: f_a = V P dphi_a).
    #[inline]
    fn first_pk_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
        f * self.pk2_stress(f, j)
    }
    /// [`first_pk_stress`](Self::first_pk_stress) at L points at once, lanes last:
    /// `f[3 r + c][l]` is F_rc of lane l, `j[l]` its det F; returns P in the same layout, Pa.
    /// Kernels evaluate blocks of points through it so that the compiler can keep the lanes
    /// in SIMD registers (and overlap the points' dependent chains); the default evaluates
    /// lane by lane. Every lane must get bitwise its `first_pk_stress`: kernels also batch
    /// points of any support size (MLS, transition) through it, and results must not depend
    /// on how points are grouped.
    #[inline(always)]
    fn first_pk_stress_lanes<const L: usize>(
        &self,
        f: &[[f64; L]; 9],
        j: &[f64; L],
    ) -> [[f64; L]; 9] {
        let mut out = [[0.0; L]; 9];
        for l in 0..L {
            let fl = Matrix3::from_fn(|r, c| f[3 * r + c][l]);
            let p = self.first_pk_stress(&fl, j[l]);
            for (i, o) in out.iter_mut().enumerate() {
                o[l] = p[(i / 3, i % 3)];
            }
        }
        out
    }
    /// The volumetric part of W = W_iso(J^(-2/3) C) + U(J): (U(J), J/m^3; U'(J), the pressure
    /// p = dU/dJ, Pa). The average-nodal-pressure tetrahedron swaps the element's own pressure
    /// for the mean of nodal ones through it.
    fn volumetric(&self, j: f64) -> (f64, f64);
    /// U''(J), Pa: the bulk stiffness of the volumetric part at J (the static solve's tangent,
    /// [`crate::solver::statics`]). The default differentiates [`Self::volumetric`] by central
    /// differences.
    fn volumetric_stiffness(&self, j: f64) -> f64 {
        let h = 1e-6 * j.abs().max(1.0);
        (self.volumetric(j + h).1 - self.volumetric(j - h).1) / (2.0 * h)
    }
    /// The tangent of the isochoric stress, A = dP_iso/dF (Pa), with
    /// P_iso = P - U'(J) cof(F) the first Piola-Kirchhoff stress of W_iso: row 3 i + J,
    /// column 3 k + L holds dP_iJ / dF_kL. The static solve assembles its stiffness from it
    /// (the volumetric part apart, [`Self::volumetric_stiffness`]). The default differentiates
    /// the stress by central differences (relative error about 1e-9); models override it with
    /// the exact form.
    fn isochoric_tangent(&self, f: &Matrix3<f64>) -> nalgebra::SMatrix<f64, 9, 9> {
        let p_iso = |g: &Matrix3<f64>| {
            let j = g.determinant();
            self.first_pk_stress(g, j) - crate::geometry::cofactor(g) * self.volumetric(j).1
        };
        let h = 1e-6 * f.amax().max(1.0);
        let mut a = nalgebra::SMatrix::<f64, 9, 9>::zeros();
        for k in 0..3 {
            for l in 0..3 {
                let mut fp = *f;
                fp[(k, l)] += h;
                let mut fm = *f;
                fm[(k, l)] -= h;
                let d = (p_iso(&fp) - p_iso(&fm)) / (2.0 * h);
                for i in 0..3 {
                    for jj in 0..3 {
                        a[(3 * i + jj, 3 * k + l)] = d[(i, jj)];
                    }
                }
            }
        }
        a
    }
    /// Dilatational (P-) wave speed in the reference configuration, m/s. Sets the stable step.
    fn wave_speed(&self) -> f64;
    /// Mass density, kg/m^3.
    fn density(&self) -> f64;
    /// Small-strain Lame moduli (lambda, mu), Pa, e.g. for hourglass stiffness.
    fn lame(&self) -> (f64, f64);
    /// The concrete model behind an enum of models ([`Solid`]), so that kernels can run code
    /// specialized for it: a match on the model inside the stress of every point block cost
    /// the neo-Hookean blocks 8-18 % (tet4-anp cylinder), dispatching once per block nothing.
    #[inline(always)]
    fn concrete(&self) -> Concrete<'_, Self> {
        Concrete::Itself(self)
    }
    /// (mu, kappa) in Pa where this is the neo-Hookean solid: the one model the GPU time loop
    /// evaluates ([`crate::solver::gpu`]).
    fn neo_hookean(&self) -> Option<(f64, f64)> {
        match self.concrete() {
            Concrete::NeoHookean(m) => Some((m.mu, m.kappa)),
            _ => None,
        }
    }
}

/// A material as its concrete model ([`Material::concrete`]).
pub enum Concrete<'a, M> {
    NeoHookean(&'a NeoHookean),
    Ogden(&'a Ogden),
    /// A material that is its own concrete model.
    Itself(&'a M),
}

/// Compressible neo-Hookean solid in the form ABAQUS uses (docs/reference.md;
/// `mtled-fe-coupled-ebc-cylinder.txt` eq. 7):
/// W = mu/2 (J^(-2/3) tr C - 3) + kappa/2 (J - 1)^2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeoHookean {
    /// Shear modulus mu, Pa.
    pub mu: f64,
    /// Bulk modulus kappa, Pa.
    pub kappa: f64,
    /// Density rho, kg/m^3.
    pub density: f64,
}

impl NeoHookean {
    /// From Young's modulus E (Pa) and Poisson's ratio nu: mu = E / (2 (1 + nu)),
    /// kappa = E / (3 (1 - 2 nu)).
    pub fn from_young_poisson(e: f64, nu: f64, density: f64) -> Self {
        NeoHookean {
            mu: e / (2.0 * (1.0 + nu)),
            kappa: e / (3.0 * (1.0 - 2.0 * nu)),
            density,
        }
    }

    /// Cauchy stress sigma = J^-1 F S F^T, Pa.
    pub fn cauchy(&self, f: &Matrix3<f64>) -> Matrix3<f64> {
        let j = f.determinant();
        f * self.pk2_stress(f, j) * f.transpose() / j
    }
}

/// Dilatational wave speed sqrt((kappa + 4 mu / 3) / rho), m/s, of a solid with small-strain
/// shear and bulk moduli mu, kappa (Pa) and density rho (kg/m^3).
fn p_wave_speed(mu: f64, kappa: f64, rho: f64) -> f64 {
    ((kappa + 4.0 * mu / 3.0) / rho).sqrt()
}

/// Lame moduli (lambda, mu) = (kappa - 2 mu / 3, mu), Pa.
fn lame_from(mu: f64, kappa: f64) -> (f64, f64) {
    (kappa - 2.0 * mu / 3.0, mu)
}

/// x^(-1/3) for x > 0, to within 2 ulp, without the library cube root (a software routine that
/// took 20 % of a meshless step). Exponent-bit guess (Moroz et al. 2021) refined by four Newton
/// steps y <- y (4 - x y^3) / 3, which converge quadratically from its 3 % error. Other x (0,
/// negative, NaN, inf, subnormal) go to the library routine.
#[inline(always)]
pub fn inv_cbrt(x: f64) -> f64 {
    inv_cbrt_lanes([x])[0]
}

/// [`inv_cbrt`] of L values at once: the Newton steps run lane-parallel (SIMD), the rare
/// values outside its range are patched afterwards. Each lane gets exactly `inv_cbrt`'s value.
#[inline(always)]
pub fn inv_cbrt_lanes<const L: usize>(x: [f64; L]) -> [f64; L] {
    let mut y: [f64; L] = std::array::from_fn(|l| {
        f64::from_bits(0x553e_f0ff_289d_d796u64.wrapping_sub(x[l].to_bits() / 3))
    });
    // y (4 - x y^3) / 3 = (4/3) y - (x/3) (y^2)^2: four dependent multiplies per step instead
    // of six (the chain's latency, not its operation count, is what a point waits for).
    let x3: [f64; L] = std::array::from_fn(|l| x[l] * (1.0 / 3.0));
    for _ in 0..4 {
        for l in 0..L {
            let y2 = y[l] * y[l];
            y[l] = (4.0 / 3.0) * y[l] - x3[l] * (y2 * y2);
        }
    }
    for l in 0..L {
        if !(f64::MIN_POSITIVE..1e300).contains(&x[l]) {
            y[l] = x[l].cbrt().recip();
        }
    }
    y
}

/// Homogeneous uniaxial stretch of the neo-Hookean solid with free lateral faces:
/// F = diag(a, a, stretch) with a such that the lateral Cauchy stress vanishes
/// (docs/reference.md "Cube"). From sigma = mu J^(-5/3) dev(B) + kappa (J - 1) I with J = a^2 stretch:
/// sigma_xx = mu J^(-5/3) (a^2 - stretch^2) / 3 + kappa (J - 1) = 0, solved by bisection
/// (sigma_xx rises monotonically with a). Returns (a, J, sigma_zz in Pa).
pub fn uniaxial_stretch(m: &NeoHookean, stretch: f64) -> (f64, f64, f64) {
    let sxx = |a: f64| {
        let j = a * a * stretch;
        m.mu * j.powf(-5.0 / 3.0) * (a * a - stretch * stretch) / 3.0 + m.kappa * (j - 1.0)
    };
    // Bracket: at a with J = 1 the lateral stress has the sign of a^2 - stretch^2, at the
    // isochoric a = stretch^(-1/2) it vanishes in the volumetric part; widen until it changes
    // sign.
    let (mut lo, mut hi) = (1e-3, 1.0 / stretch.sqrt());
    while sxx(hi) < 0.0 && hi < 1e6 {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if sxx(mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let a = 0.5 * (lo + hi);
    let j = a * a * stretch;
    let szz =
        m.mu * j.powf(-5.0 / 3.0) * 2.0 * (stretch * stretch - a * a) / 3.0 + m.kappa * (j - 1.0);
    (a, j, szz)
}

impl Material for NeoHookean {
    fn neo_hookean(&self) -> Option<(f64, f64)> {
        Some((self.mu, self.kappa))
    }

    fn strain_energy(&self, f: &Matrix3<f64>) -> f64 {
        let j = f.determinant();
        let tr_c = f.norm_squared();
        let r = inv_cbrt(j);
        0.5 * self.mu * (r * r * tr_c - 3.0) + 0.5 * self.kappa * (j - 1.0).powi(2)
    }

    /// S = mu J^(-2/3) (I - tr(C)/3 C^-1) + kappa J (J - 1) C^-1 (docs/reference.md; not Horton 2010
    /// eq. 42, which is not stress-free at C = I).
    #[inline]
    fn pk2_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
        let c = f.transpose() * f;
        let tr_c = c.trace();
        // C^-1 = adj(C) / det C with det C = J^2; C is symmetric so adj is too.
        let inv_j2 = 1.0 / (j * j);
        let ci = Matrix3::new(
            c[(1, 1)] * c[(2, 2)] - c[(1, 2)] * c[(2, 1)],
            c[(0, 2)] * c[(2, 1)] - c[(0, 1)] * c[(2, 2)],
            c[(0, 1)] * c[(1, 2)] - c[(0, 2)] * c[(1, 1)],
            c[(1, 2)] * c[(2, 0)] - c[(1, 0)] * c[(2, 2)],
            c[(0, 0)] * c[(2, 2)] - c[(0, 2)] * c[(2, 0)],
            c[(0, 2)] * c[(1, 0)] - c[(0, 0)] * c[(1, 2)],
            c[(1, 0)] * c[(2, 1)] - c[(1, 1)] * c[(2, 0)],
            c[(0, 1)] * c[(2, 0)] - c[(0, 0)] * c[(2, 1)],
            c[(0, 0)] * c[(1, 1)] - c[(0, 1)] * c[(1, 0)],
        ) * inv_j2;
        let r = inv_cbrt(j);
        let mu_j = self.mu * (r * r);
        let a = -mu_j * tr_c / 3.0 + self.kappa * j * (j - 1.0);
        let mut s = ci * a;
        s[(0, 0)] += mu_j;
        s[(1, 1)] += mu_j;
        s[(2, 2)] += mu_j;
        s
    }

    /// P = F S = mu J^(-2/3) (F - tr(C)/3 F^-T) + kappa J (J - 1) F^-T, with F^-T = cof(F) / J:
    /// F C^-1 = F^-T, so neither C, C^-1 nor the product F S is formed (about half the
    /// operations of `f * pk2_stress`). The lane form with one lane, so that a point gets
    /// bitwise the same stress alone or in a block.
    #[inline(always)]
    fn first_pk_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
        let p = self.first_pk_stress_lanes(&lanes_of(f), &[j]);
        Matrix3::from_fn(|r, c| p[3 * r + c][0])
    }

    /// P at L points at once, the formula of [`first_pk_stress`](Material::first_pk_stress)
    /// above.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // index loops over lanes are what vectorizes
    fn first_pk_stress_lanes<const L: usize>(
        &self,
        f: &[[f64; L]; 9],
        j: &[f64; L],
    ) -> [[f64; L]; 9] {
        // Row-major F: f[3 r + c]; cof(F)_rc = (-1)^(r+c) minor_rc.
        let m = |i: usize, l: usize| f[i][l];
        let mut cof = [[0.0; L]; 9];
        for l in 0..L {
            cof[0][l] = m(4, l) * m(8, l) - m(5, l) * m(7, l);
            cof[1][l] = m(5, l) * m(6, l) - m(3, l) * m(8, l);
            cof[2][l] = m(3, l) * m(7, l) - m(4, l) * m(6, l);
            cof[3][l] = m(2, l) * m(7, l) - m(1, l) * m(8, l);
            cof[4][l] = m(0, l) * m(8, l) - m(2, l) * m(6, l);
            cof[5][l] = m(1, l) * m(6, l) - m(0, l) * m(7, l);
            cof[6][l] = m(1, l) * m(5, l) - m(2, l) * m(4, l);
            cof[7][l] = m(2, l) * m(3, l) - m(0, l) * m(5, l);
            cof[8][l] = m(0, l) * m(4, l) - m(1, l) * m(3, l);
        }
        let r = inv_cbrt_lanes(*j);
        let mut mu_j = [0.0; L];
        let mut b = [0.0; L];
        for l in 0..L {
            mu_j[l] = self.mu * (r[l] * r[l]);
            let mut tr_c = 0.0;
            for fi in f.iter() {
                tr_c += fi[l] * fi[l];
            }
            b[l] = (self.kappa * j[l] * (j[l] - 1.0) - mu_j[l] * tr_c * (1.0 / 3.0)) / j[l];
        }
        let mut out = [[0.0; L]; 9];
        for i in 0..9 {
            for l in 0..L {
                out[i][l] = f[i][l] * mu_j[l] + cof[i][l] * b[l];
            }
        }
        out
    }

    /// U = kappa / 2 (J - 1)^2.
    #[inline(always)]
    fn volumetric(&self, j: f64) -> (f64, f64) {
        (
            0.5 * self.kappa * (j - 1.0) * (j - 1.0),
            self.kappa * (j - 1.0),
        )
    }

    fn volumetric_stiffness(&self, _j: f64) -> f64 {
        self.kappa
    }

    /// P_iso = a (F - I_1/3 F^-T) with a = mu J^(-2/3), I_1 = F : F, differentiated exactly:
    /// dP_iJ/dF_kL = -2/3 a F^-1_Lk (F_iJ - I_1/3 F^-1_Ji)
    ///               + a (d_ik d_JL - 2/3 F_kL F^-1_Ji + I_1/3 F^-1_Jk F^-1_Li).
    fn isochoric_tangent(&self, f: &Matrix3<f64>) -> nalgebra::SMatrix<f64, 9, 9> {
        let j = f.determinant();
        let finv = crate::geometry::cofactor(f).transpose() / j;
        let r = inv_cbrt(j);
        let a = self.mu * r * r;
        let i1 = f.norm_squared();
        let mut t = nalgebra::SMatrix::<f64, 9, 9>::zeros();
        for i in 0..3 {
            for jj in 0..3 {
                let dev = f[(i, jj)] - i1 / 3.0 * finv[(jj, i)];
                for k in 0..3 {
                    for l in 0..3 {
                        let d = if i == k && jj == l { 1.0 } else { 0.0 };
                        t[(3 * i + jj, 3 * k + l)] = -2.0 / 3.0 * a * finv[(l, k)] * dev
                            + a * (d - 2.0 / 3.0 * f[(k, l)] * finv[(jj, i)]
                                + i1 / 3.0 * finv[(jj, k)] * finv[(l, i)]);
                    }
                }
            }
        }
        t
    }

    fn wave_speed(&self) -> f64 {
        p_wave_speed(self.mu, self.kappa, self.density)
    }

    fn density(&self) -> f64 {
        self.density
    }

    fn lame(&self) -> (f64, f64) {
        lame_from(self.mu, self.kappa)
    }
}

/// One-term Ogden solid with the volumetric term of the neo-Hookean form, as used for brain
/// tissue (Miller and Chinzei 2002, J. Biomech. 35: mu = 842 Pa, alpha = -4.7; NiftySim's
/// Ogden material):
/// W = (2 mu / alpha^2) (lbar_1^alpha + lbar_2^alpha + lbar_3^alpha - 3) + kappa/2 (J - 1)^2,
/// with lbar_i = J^(-1/3) lambda_i the isochoric principal stretches. mu is the small-strain
/// shear modulus for any alpha; alpha = 2 is the neo-Hookean solid of [`NeoHookean`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ogden {
    /// Shear modulus mu, Pa.
    pub mu: f64,
    /// Exponent alpha (non-zero).
    pub alpha: f64,
    /// Bulk modulus kappa, Pa.
    pub kappa: f64,
    /// Density rho, kg/m^3.
    pub density: f64,
}

impl Ogden {
    /// Principal stretches squared (eigenvalues of C = F^T F) and the principal directions.
    fn principal(f: &Matrix3<f64>) -> (nalgebra::Vector3<f64>, Matrix3<f64>) {
        let c = right_cauchy_green_lanes(&lanes_of(f));
        symmetric_eigen3(Matrix3::from_fn(|r, k| c[r][k][0]))
    }

    /// Second Piola-Kirchhoff stress S = sum_i tau_i / lambda_i^2 N_i (x) N_i at L points
    /// (lanes last, as [`Material::first_pk_stress_lanes`]; `s[r][c][l]`), Pa.
    /// The eigen-decompositions of the L points run side by side (SIMD square roots and
    /// divisions), each lane's rotations masked once it has converged, so a lane's result does
    /// not depend on its neighbours: the scalar path is this one with L = 1.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // index loops over lanes are what vectorizes
    fn pk2_lanes<const L: usize>(&self, f: &[[f64; L]; 9], j: &[f64; L]) -> [[[f64; L]; 3]; 3] {
        let (l2, v) = symmetric_eigen3_lanes(right_cauchy_green_lanes(f));
        // g_i = tau_i / lambda_i^2, lane by lane (the powers do not vectorize).
        let mut g = [[0.0; L]; 3];
        for l in 0..L {
            let tau = self.kirchhoff(&nalgebra::Vector3::new(l2[0][l], l2[1][l], l2[2][l]), j[l]);
            for i in 0..3 {
                g[i][l] = tau[i] / l2[i][l];
            }
        }
        let mut s = [[[0.0; L]; 3]; 3];
        for r in 0..3 {
            for c in 0..3 {
                for i in 0..3 {
                    for l in 0..L {
                        s[r][c][l] += v[r][i][l] * v[c][i][l] * g[i][l];
                    }
                }
            }
        }
        s
    }

    /// P = F S at L points from [`Self::pk2_lanes`], Pa.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)]
    fn first_pk_lanes<const L: usize>(&self, f: &[[f64; L]; 9], j: &[f64; L]) -> [[f64; L]; 9] {
        let s = self.pk2_lanes(f, j);
        let mut p = [[0.0; L]; 9];
        for r in 0..3 {
            for c in 0..3 {
                for k in 0..3 {
                    for l in 0..L {
                        p[3 * r + c][l] += f[3 * r + k][l] * s[k][c][l];
                    }
                }
            }
        }
        p
    }

    /// Principal Kirchhoff stresses tau_i (Pa) from the squared stretches `l2` and J:
    /// tau_i = (2 mu / alpha) (lbar_i^alpha - (1/3) sum_j lbar_j^alpha) + kappa J (J - 1).
    fn kirchhoff(&self, l2: &nalgebra::Vector3<f64>, j: f64) -> nalgebra::Vector3<f64> {
        let jm = j.powf(-self.alpha / 3.0);
        let la = l2.map(|v| v.powf(0.5 * self.alpha) * jm);
        let mean = (la.x + la.y + la.z) / 3.0;
        let p = self.kappa * j * (j - 1.0);
        la.map(|v| 2.0 * self.mu / self.alpha * (v - mean) + p)
    }

    /// Homogeneous uniaxial stretch with free lateral faces, F = diag(a, a, stretch), from the
    /// closed-form principal stresses (independent of the eigen-decomposition the kernel
    /// uses): tau_1 = (2 mu / (3 alpha)) (lbar_1^alpha - lbar_3^alpha) + kappa J (J - 1) = 0
    /// solved for a by bisection. Returns (a, J, sigma_zz in Pa).
    pub fn uniaxial(&self, stretch: f64) -> (f64, f64, f64) {
        let parts = |a: f64| {
            let j = a * a * stretch;
            let c = j.powf(-1.0 / 3.0);
            let (l1, l3) = ((a * c).powf(self.alpha), (stretch * c).powf(self.alpha));
            (j, l1, l3, self.kappa * j * (j - 1.0))
        };
        let t1 = |a: f64| {
            let (_, l1, l3, p) = parts(a);
            2.0 * self.mu / (3.0 * self.alpha) * (l1 - l3) + p
        };
        let a = bisect_increasing(t1, 1.0 / stretch.sqrt());
        let (j, l1, l3, p) = parts(a);
        (
            a,
            j,
            (4.0 * self.mu / (3.0 * self.alpha) * (l3 - l1) + p) / j,
        )
    }
}

/// F (row-major, 3 r + c) of one point as lanes of width 1.
fn lanes_of(f: &Matrix3<f64>) -> [[f64; 1]; 9] {
    std::array::from_fn(|i| [f[(i / 3, i % 3)]])
}

/// C = F^T F at L points: `f[3 r + c][l]` is F_rc of lane l; C_ab = sum_r F_ra F_rb.
#[inline(always)]
fn right_cauchy_green_lanes<const L: usize>(f: &[[f64; L]; 9]) -> [[[f64; L]; 3]; 3] {
    let mut c = [[[0.0; L]; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            for l in 0..L {
                c[a][b][l] =
                    f[a][l] * f[b][l] + f[3 + a][l] * f[3 + b][l] + f[6 + a][l] * f[6 + b][l];
            }
        }
    }
    c
}

/// Eigenvalues and orthonormal eigenvectors (columns) of a symmetric 3 x 3 matrix by cyclic
/// Jacobi rotations (Golub and Van Loan, Matrix Computations, sect. 8.5): each rotation zeroes
/// one off-diagonal entry, and the sweeps converge quadratically, so a strained C needs three or
/// four and a nearly undeformed one one or two. Stops when the off-diagonal part is below 1e-30
/// of the matrix's squared norm (or after 16 sweeps). Several times faster for one 3 x 3 than
/// the general tridiagonal QR, and exact for coincident eigenvalues (any basis of their space
/// is a valid set of eigenvectors).
pub fn symmetric_eigen3(a: Matrix3<f64>) -> (nalgebra::Vector3<f64>, Matrix3<f64>) {
    let (l, v) = symmetric_eigen3_lanes::<1>(std::array::from_fn(|r| {
        std::array::from_fn(|c| [a[(r, c)]])
    }));
    (
        nalgebra::Vector3::from_fn(|i, _| l[i][0]),
        Matrix3::from_fn(|r, c| v[r][c][0]),
    )
}

/// [`symmetric_eigen3`] of L matrices at once, `a[r][c][l]` the entry (r, c) of lane l:
/// returns the eigenvalues `[i][l]` and eigenvectors `[r][i][l]` (component r of vector i).
/// Every lane takes exactly the rotations it would take alone (a converged lane is masked
/// out), so results are bitwise those of L = 1.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // index loops over lanes are what vectorizes
pub fn symmetric_eigen3_lanes<const L: usize>(
    mut a: [[[f64; L]; 3]; 3],
) -> ([[f64; L]; 3], [[[f64; L]; 3]; 3]) {
    let mut v = [[[0.0; L]; 3]; 3];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = [1.0; L];
    }
    let mut scale = [0.0; L];
    for row in &a {
        for e in row {
            for l in 0..L {
                scale[l] += e[l] * e[l];
            }
        }
    }
    let mut active = [true; L];
    for _ in 0..16 {
        let mut any = false;
        for l in 0..L {
            let off = a[0][1][l] * a[0][1][l] + a[0][2][l] * a[0][2][l] + a[1][2][l] * a[1][2][l];
            // Written so that a NaN stops the lane.
            active[l] = active[l] && off > 1e-30 * scale[l];
            any |= active[l];
        }
        if !any {
            break;
        }
        jacobi_rotation(&mut a, &mut v, &active, 0, 1);
        jacobi_rotation(&mut a, &mut v, &active, 0, 2);
        jacobi_rotation(&mut a, &mut v, &active, 1, 2);
    }
    (std::array::from_fn(|i| a[i][i]), v)
}

/// One Jacobi rotation in the (p, q) plane that zeroes a_pq, applied to the lanes that are
/// `active` and have a_pq != 0 (the others keep their values).
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn jacobi_rotation<const L: usize>(
    a: &mut [[[f64; L]; 3]; 3],
    v: &mut [[[f64; L]; 3]; 3],
    active: &[bool; L],
    p: usize,
    q: usize,
) {
    let r = 3 - p - q;
    for l in 0..L {
        let apq = a[p][q][l];
        let go = active[l] && apq != 0.0;
        // t = tan of the rotation angle, the smaller root of t^2 + 2 theta t - 1 = 0.
        let theta = (a[q][q][l] - a[p][p][l]) / (2.0 * apq);
        let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
        let c = 1.0 / (t * t + 1.0).sqrt();
        let s = t * c;
        let pick = |new: f64, old: f64| if go { new } else { old };
        let (arp, arq) = (a[r][p][l], a[r][q][l]);
        a[p][p][l] = pick(a[p][p][l] - t * apq, a[p][p][l]);
        a[q][q][l] = pick(a[q][q][l] + t * apq, a[q][q][l]);
        a[p][q][l] = pick(0.0, apq);
        a[q][p][l] = a[p][q][l];
        a[r][p][l] = pick(c * arp - s * arq, arp);
        a[p][r][l] = a[r][p][l];
        a[r][q][l] = pick(s * arp + c * arq, arq);
        a[q][r][l] = a[r][q][l];
        for k in 0..3 {
            let (vkp, vkq) = (v[k][p][l], v[k][q][l]);
            v[k][p][l] = pick(c * vkp - s * vkq, vkp);
            v[k][q][l] = pick(s * vkp + c * vkq, vkq);
        }
    }
}

/// The root of `g`, increasing in a, bracketed from (1e-3, start) by doubling the upper end.
fn bisect_increasing(g: impl Fn(f64) -> f64, start: f64) -> f64 {
    let (mut lo, mut hi) = (1e-3, start);
    while g(hi) < 0.0 && hi < 1e6 {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if g(mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

impl Material for Ogden {
    fn strain_energy(&self, f: &Matrix3<f64>) -> f64 {
        let (l2, _) = Self::principal(f);
        let j = f.determinant();
        let jm = j.powf(-self.alpha / 3.0);
        let sum: f64 = l2.iter().map(|v| v.powf(0.5 * self.alpha) * jm).sum();
        2.0 * self.mu / (self.alpha * self.alpha) * (sum - 3.0)
            + 0.5 * self.kappa * (j - 1.0).powi(2)
    }

    /// S = sum_i tau_i / lambda_i^2 N_i (x) N_i (principal directions N_i of C).
    fn pk2_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
        let s = self.pk2_lanes::<1>(&lanes_of(f), &[j]);
        Matrix3::from_fn(|r, c| s[r][c][0])
    }

    #[inline(never)]
    fn first_pk_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
        let p = self.first_pk_lanes::<1>(&lanes_of(f), &[j]);
        Matrix3::from_fn(|r, c| p[3 * r + c][0])
    }

    /// Inlined so that the AVX2 kernels evaluate four lanes per instruction.
    #[inline(always)]
    fn first_pk_stress_lanes<const L: usize>(
        &self,
        f: &[[f64; L]; 9],
        j: &[f64; L],
    ) -> [[f64; L]; 9] {
        self.first_pk_lanes(f, j)
    }

    /// U = kappa / 2 (J - 1)^2.
    #[inline(always)]
    fn volumetric(&self, j: f64) -> (f64, f64) {
        (
            0.5 * self.kappa * (j - 1.0) * (j - 1.0),
            self.kappa * (j - 1.0),
        )
    }

    fn volumetric_stiffness(&self, _j: f64) -> f64 {
        self.kappa
    }

    /// dP_iso/dF (9 x 9, row 3 i + J, column 3 k + L), Pa, in closed form from the principal
    /// stretches (Holzapfel, Nonlinear Solid Mechanics, 2000, eqs. 6.196 and 6.200; Simo and
    /// Taylor 1991): with S_a = tau_a / lambda_a^2 the principal isochoric stresses
    /// ([`Ogden::kirchhoff`] less its volumetric part),
    /// C = 2 dS/dC = sum_ab G_ab N_a N_a N_b N_b + sum_(a != b) H_ab (N_a N_b N_a N_b + N_a N_b N_b N_a),
    /// G_ab = (1 / lambda_b) dS_a/dlambda_b, H_ab = (S_b - S_a) / (lambda_b^2 - lambda_a^2)
    /// and, for equal stretches, its limit (G_bb - G_ab) / 2 (taken as (G_aa + G_bb - G_ab -
    /// G_ba) / 4, the same at the limit and symmetric); then
    /// A_iJkL = delta_ik S_JL + F_iM F_kN C_MJNL. One eigen-decomposition instead of the 18
    /// stress evaluations of the central differences.
    fn isochoric_tangent(&self, f: &Matrix3<f64>) -> nalgebra::SMatrix<f64, 9, 9> {
        let (l2, n) = Self::principal(f);
        let j = f.determinant();
        let jm = j.powf(-self.alpha / 3.0);
        let b = l2.map(|v| v.powf(0.5 * self.alpha) * jm);
        let mean = (b.x + b.y + b.z) / 3.0;
        let two_mu = 2.0 * self.mu;
        let s = nalgebra::Vector3::from_fn(|a, _| two_mu / self.alpha * (b[a] - mean) / l2[a]);
        // G_ab = D_ab / (l2_a l2_b) - 2 delta_ab S_a / l2_a, D_ab = lambda_b dtau_a/dlambda_b.
        let g = Matrix3::from_fn(|a, c| {
            let delta = if a == c { 1.0 } else { 0.0 };
            let d = two_mu * (b[a] * (delta - 1.0 / 3.0) - (b[c] - mean) / 3.0);
            d / (l2[a] * l2[c]) - 2.0 * delta * s[a] / l2[a]
        });
        let scale = l2.amax();
        let h = |a: usize, c: usize| {
            let gap = l2[c] - l2[a];
            if gap.abs() > 1e-6 * scale {
                (s[c] - s[a]) / gap
            } else {
                // Symmetric in a and c, as the quotient is.
                0.25 * (g[(a, a)] + g[(c, c)] - g[(a, c)] - g[(c, a)])
            }
        };
        // F N_a (x) N_c as a 9-vector (index 3 i + J).
        let fn_ = [0, 1, 2].map(|a| f * n.column(a));
        let w = |a: usize, c: usize| {
            nalgebra::SVector::<f64, 9>::from_fn(|r, _| fn_[a][r / 3] * n[(r % 3, c)])
        };
        let ws: [[nalgebra::SVector<f64, 9>; 3]; 3] =
            std::array::from_fn(|a| std::array::from_fn(|c| w(a, c)));
        let mut t = nalgebra::SMatrix::<f64, 9, 9>::zeros();
        for a in 0..3 {
            for c in 0..3 {
                t += g[(a, c)] * ws[a][a] * ws[c][c].transpose();
                if a != c {
                    t += h(a, c) * ws[a][c] * (ws[a][c] + ws[c][a]).transpose();
                }
            }
        }
        // delta_ik S_JL, with S = sum_a S_a N_a N_a.
        let s_full = n * Matrix3::from_diagonal(&s) * n.transpose();
        for i in 0..3 {
            for jj in 0..3 {
                for l in 0..3 {
                    t[(3 * i + jj, 3 * i + l)] += s_full[(jj, l)];
                }
            }
        }
        t
    }

    fn wave_speed(&self) -> f64 {
        p_wave_speed(self.mu, self.kappa, self.density)
    }

    fn density(&self) -> f64 {
        self.density
    }

    fn lame(&self) -> (f64, f64) {
        lame_from(self.mu, self.kappa)
    }
}

/// The materials a scene can use, dispatched per lane block: the kernel stays monomorphic and
/// each block evaluates one variant's (vectorized) stress.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Solid {
    NeoHookean(NeoHookean),
    Ogden(Ogden),
}

impl Solid {
    /// Bulk modulus kappa, Pa.
    pub fn kappa(&self) -> f64 {
        match self {
            Solid::NeoHookean(m) => m.kappa,
            Solid::Ogden(m) => m.kappa,
        }
    }
}

impl From<NeoHookean> for Solid {
    fn from(m: NeoHookean) -> Self {
        Solid::NeoHookean(m)
    }
}

impl Material for Solid {
    #[inline]
    fn strain_energy(&self, f: &Matrix3<f64>) -> f64 {
        match self {
            Solid::NeoHookean(m) => m.strain_energy(f),
            Solid::Ogden(m) => m.strain_energy(f),
        }
    }

    #[inline]
    fn pk2_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
        match self {
            Solid::NeoHookean(m) => m.pk2_stress(f, j),
            Solid::Ogden(m) => m.pk2_stress(f, j),
        }
    }

    #[inline(always)]
    fn first_pk_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
        match self {
            Solid::NeoHookean(m) => m.first_pk_stress(f, j),
            Solid::Ogden(m) => m.first_pk_stress(f, j),
        }
    }

    #[inline(always)]
    fn first_pk_stress_lanes<const L: usize>(
        &self,
        f: &[[f64; L]; 9],
        j: &[f64; L],
    ) -> [[f64; L]; 9] {
        match self {
            Solid::NeoHookean(m) => m.first_pk_stress_lanes(f, j),
            Solid::Ogden(m) => m.first_pk_stress_lanes(f, j),
        }
    }

    #[inline]
    fn volumetric(&self, j: f64) -> (f64, f64) {
        match self {
            Solid::NeoHookean(m) => m.volumetric(j),
            Solid::Ogden(m) => m.volumetric(j),
        }
    }

    fn volumetric_stiffness(&self, j: f64) -> f64 {
        match self {
            Solid::NeoHookean(m) => m.volumetric_stiffness(j),
            Solid::Ogden(m) => m.volumetric_stiffness(j),
        }
    }

    fn isochoric_tangent(&self, f: &Matrix3<f64>) -> nalgebra::SMatrix<f64, 9, 9> {
        match self {
            Solid::NeoHookean(m) => m.isochoric_tangent(f),
            Solid::Ogden(m) => m.isochoric_tangent(f),
        }
    }

    fn wave_speed(&self) -> f64 {
        match self {
            Solid::NeoHookean(m) => m.wave_speed(),
            Solid::Ogden(m) => m.wave_speed(),
        }
    }

    fn density(&self) -> f64 {
        match self {
            Solid::NeoHookean(m) => m.density(),
            Solid::Ogden(m) => m.density(),
        }
    }

    fn lame(&self) -> (f64, f64) {
        match self {
            Solid::NeoHookean(m) => m.lame(),
            Solid::Ogden(m) => m.lame(),
        }
    }

    #[inline(always)]
    fn concrete(&self) -> Concrete<'_, Self> {
        match self {
            Solid::NeoHookean(m) => Concrete::NeoHookean(m),
            Solid::Ogden(m) => Concrete::Ogden(m),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mat() -> NeoHookean {
        NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0)
    }

    /// Deterministic pseudo-random numbers (no extra crate for tests).
    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64) / ((1u64 << 53) as f64)
    }

    fn random_f(state: &mut u64) -> Matrix3<f64> {
        loop {
            let f = Matrix3::identity() + Matrix3::from_fn(|_, _| 0.6 * (lcg(state) - 0.5));
            if f.determinant() > 0.2 {
                return f;
            }
        }
    }

    /// A material as `M` but for its tangent, which it takes from the trait's default: central
    /// differences of its stress.
    #[derive(Clone)]
    struct ByDifferences<M>(M);

    impl<M: Material> Material for ByDifferences<M> {
        fn strain_energy(&self, f: &Matrix3<f64>) -> f64 {
            self.0.strain_energy(f)
        }
        fn pk2_stress(&self, f: &Matrix3<f64>, j: f64) -> Matrix3<f64> {
            self.0.pk2_stress(f, j)
        }
        fn volumetric(&self, j: f64) -> (f64, f64) {
            self.0.volumetric(j)
        }
        fn wave_speed(&self) -> f64 {
            self.0.wave_speed()
        }
        fn density(&self) -> f64 {
            self.0.density()
        }
        fn lame(&self) -> (f64, f64) {
            self.0.lame()
        }
    }

    /// The exact neo-Hookean isochoric tangent equals central differences of its stress (the
    /// trait's default), and the one-term Ogden solid at alpha = 2, which is the same solid,
    /// gives the same tangent through its own (eigenvalue) stress.
    #[test]
    fn isochoric_tangent_is_the_derivative_of_the_isochoric_stress() {
        let m = mat();
        let og = Ogden {
            mu: m.mu,
            alpha: 2.0,
            kappa: m.kappa,
            density: 1000.0,
        };
        let mut state = 7u64;
        for _ in 0..20 {
            let f = random_f(&mut state);
            let exact = m.isochoric_tangent(&f);
            let fd = ByDifferences(m).isochoric_tangent(&f);
            let scale = exact.amax();
            assert!((exact - fd).amax() < 1e-7 * scale, "{exact} {fd}");
            assert!((og.isochoric_tangent(&f) - exact).amax() < 1e-6 * scale);
            // A hyperelastic tangent has the major symmetry dP_iJ/dF_kL = dP_kL/dF_iJ.
            assert!((exact - exact.transpose()).amax() < 1e-12 * scale);
            let h = 1e-6;
            let u = |j: f64| ByDifferences(m).volumetric_stiffness(j);
            assert!(
                (u(f.determinant()) - m.volumetric_stiffness(f.determinant())).abs() < h * m.kappa
            );
        }
    }

    #[test]
    fn reference_constants_match_reference_md() {
        let m = mat();
        assert!((m.mu - 1006.711).abs() < 1e-3);
        assert!((m.kappa - 50000.0).abs() < 1e-9);
        assert!((m.lame().0 - 49328.86).abs() < 1e-2);
        assert!((m.wave_speed() - 7.16535).abs() < 1e-5);
    }

    #[test]
    fn inv_cbrt_matches_the_library_cube_root() {
        let mut st = 3u64;
        for k in 0..200_000 {
            // Log-uniform over [1e-12, 1e12], plus the neighbourhood of 1 where J lives.
            let x = if k % 2 == 0 {
                10f64.powf(24.0 * lcg(&mut st) - 12.0)
            } else {
                1.0 + 0.5 * (lcg(&mut st) - 0.5)
            };
            let (a, b) = (inv_cbrt(x), x.cbrt().recip());
            assert!(
                (a - b).abs() <= 4.0 * f64::EPSILON * b,
                "x = {x:e}: {a:e} vs {b:e}"
            );
        }
        assert!(
            inv_cbrt(-8.0) == -0.5 && inv_cbrt(0.0).is_infinite() && inv_cbrt(f64::NAN).is_nan()
        );
    }

    #[test]
    fn first_pk_equals_f_times_pk2() {
        let m = mat();
        let mut st = 11u64;
        for _ in 0..1000 {
            let f = random_f(&mut st);
            let j = f.determinant();
            let (a, b) = (m.first_pk_stress(&f, j), f * m.pk2_stress(&f, j));
            assert!(
                (a - b).norm() <= 1e-12 * b.norm().max(m.kappa),
                "{a} vs {b}"
            );
        }
    }

    #[test]
    fn stress_free_at_identity() {
        let s = mat().pk2_stress(&Matrix3::identity(), 1.0);
        assert!(s.norm() < 1e-12, "S(I) = {s}");
    }

    #[test]
    fn pk2_is_twice_the_derivative_of_energy_in_c() {
        // dW = S : dF^T F (symmetrised) => compare S : (dC/2) with W(F + dF) - W(F - dF).
        // Using dF = eps E_ij F-free perturbation: dW/dF = F S, check P = F S by central differences.
        let m = mat();
        let mut st = 7u64;
        for _ in 0..50 {
            let f = random_f(&mut st);
            let p = f * m.pk2_stress(&f, f.determinant());
            let scale = p.abs().max().max(m.mu);
            for i in 0..3 {
                for j in 0..3 {
                    let h = 1e-6;
                    let mut fp = f;
                    fp[(i, j)] += h;
                    let mut fm = f;
                    fm[(i, j)] -= h;
                    let fd = (m.strain_energy(&fp) - m.strain_energy(&fm)) / (2.0 * h);
                    assert!(
                        (fd - p[(i, j)]).abs() <= 1e-6 * scale,
                        "P[{i}{j}] = {} vs finite difference {fd}",
                        p[(i, j)]
                    );
                }
            }
        }
    }

    /// W as a function of C alone (J = sqrt(det C)), to differentiate in C.
    fn energy_of_c(m: &NeoHookean, c: &Matrix3<f64>) -> f64 {
        let j = c.determinant().sqrt();
        0.5 * m.mu * (j.powf(-2.0 / 3.0) * c.trace() - 3.0) + 0.5 * m.kappa * (j - 1.0).powi(2)
    }

    #[test]
    fn pk2_matches_finite_difference_2_dw_dc() {
        // S_ij = 2 dW/dC_ij. The symmetric perturbation h (E_ij + E_ji) changes W by
        // 2 h dW/dC_ij (both entries, i != j) or 2 h dW/dC_ii (one entry moved by 2h), i.e. by S_ij h.
        let m = mat();
        let mut st = 3u64;
        for _ in 0..50 {
            let f = random_f(&mut st);
            let c = f.transpose() * f;
            let s = m.pk2_stress(&f, f.determinant());
            let scale = s.abs().max().max(m.mu);
            let h = 1e-6;
            for i in 0..3 {
                for j in 0..3 {
                    let mut e = Matrix3::zeros();
                    e[(i, j)] += h;
                    e[(j, i)] += h;
                    let dw = (energy_of_c(&m, &(c + e)) - energy_of_c(&m, &(c - e))) / (2.0 * h);
                    assert!(
                        (dw - s[(i, j)]).abs() <= 1e-6 * scale,
                        "S[{i}{j}]: {} vs finite difference {dw}",
                        s[(i, j)]
                    );
                }
            }
        }
    }

    #[test]
    fn objectivity_rotated_f_gives_same_s() {
        let m = mat();
        let mut st = 11u64;
        for _ in 0..20 {
            let f = random_f(&mut st);
            let axis = nalgebra::Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st) + 0.1);
            let r = nalgebra::Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(axis),
                6.0 * lcg(&mut st),
            );
            let s1 = m.pk2_stress(&f, f.determinant());
            let rf = r.matrix() * f;
            let s2 = m.pk2_stress(&rf, rf.determinant());
            assert!((s1 - s2).norm() <= 1e-10 * s1.norm().max(1.0));
        }
    }

    #[test]
    fn uniaxial_cube_root_matches_reference() {
        // Exact cube (docs/reference.md): F = diag(a, a, 0.8), lateral Cauchy stress zero at a = 1.11574668.
        let m = mat();
        let f = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.11574668, 1.11574668, 0.8));
        let sig = m.cauchy(&f);
        assert!(sig[(0, 0)].abs() < 1e-3, "lateral stress {}", sig[(0, 0)]);
        assert!(
            (sig[(2, 2)] + 613.1215).abs() < 1e-3,
            "axial {}",
            sig[(2, 2)]
        );
    }

    #[test]
    fn uniaxial_stretch_matches_the_reference_cube_and_the_kernel() {
        // docs/reference.md: E = 3000 Pa, nu = 0.49, 20 % compression.
        let m = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        let (a, j, szz) = uniaxial_stretch(&m, 0.8);
        assert!((a - 1.11574668).abs() < 5e-9, "{a}");
        assert!((j - 0.99591252).abs() < 5e-9, "{j}");
        assert!((szz + 613.1215).abs() < 5e-5, "{szz}");
        // The kernel's stress at that F is uniaxial, for other nu and stretches too.
        for nu in [0.3, 0.45, 0.4999] {
            for stretch in [0.2, 0.8, 1.3] {
                let m = NeoHookean::from_young_poisson(3000.0, nu, 1000.0);
                let (a, _, szz) = uniaxial_stretch(&m, stretch);
                let s = m.cauchy(&Matrix3::from_diagonal(&nalgebra::Vector3::new(
                    a, a, stretch,
                )));
                let scale = szz.abs();
                assert!(
                    s[(0, 0)].abs() < 1e-9 * scale && s[(1, 1)].abs() < 1e-9 * scale,
                    "{s}"
                );
                assert!((s[(2, 2)] - szz).abs() < 1e-9 * scale, "{s} vs {szz}");
            }
        }
    }

    /// The closed-form Ogden tangent equals central differences of the Ogden stress (the
    /// trait's default) for brain tissue (alpha = -4.7) and alpha = 7, at random deformations
    /// and where stretches coincide or nearly do (F = I, uniaxial stretch, a split of 1e-9 and
    /// of 1e-5), where its spin terms take their limit.
    #[test]
    fn ogden_tangent_matches_the_differences_of_its_stress() {
        let rot = nalgebra::Rotation3::from_euler_angles(0.3, -0.7, 1.1).into_inner();
        let mut cases: Vec<Matrix3<f64>> = vec![
            Matrix3::identity(),
            Matrix3::from_diagonal(&nalgebra::Vector3::new(1.1, 1.1, 0.8)),
            rot * Matrix3::from_diagonal(&nalgebra::Vector3::new(0.9, 0.9 + 1e-9, 1.3)),
            rot * Matrix3::from_diagonal(&nalgebra::Vector3::new(0.9, 0.9 + 1e-5, 1.3)),
            rot * Matrix3::from_diagonal(&nalgebra::Vector3::new(0.5, 0.5, 0.5)),
        ];
        let mut state = 11u64;
        cases.extend((0..20).map(|_| random_f(&mut state)));
        for alpha in [-4.7, 7.0] {
            let og = Ogden { alpha, ..brain() };
            for f in &cases {
                let exact = og.isochoric_tangent(f);
                let fd = ByDifferences(og).isochoric_tangent(f);
                let scale = fd.amax();
                assert!(
                    (exact - fd).amax() < 1e-6 * scale,
                    "alpha {alpha}, F {f}: {exact} against {fd}"
                );
                assert!((exact - exact.transpose()).amax() < 1e-10 * scale);
            }
        }
    }

    /// Brain tissue (Miller and Chinzei 2002) with a near-incompressible bulk modulus.
    fn brain() -> Ogden {
        Ogden {
            mu: 842.0,
            alpha: -4.7,
            kappa: 842.0 * 100.0,
            density: 1000.0,
        }
    }

    /// P = dW/dF by central differences of the Ogden energy, and S symmetric, stress free at
    /// F = I, objective.
    #[test]
    fn ogden_stress_is_the_derivative_of_its_energy() {
        for m in [
            brain(),
            Ogden {
                alpha: 3.0,
                ..brain()
            },
        ] {
            assert!(m.pk2_stress(&Matrix3::identity(), 1.0).norm() < 1e-9);
            let mut st = 5u64;
            for _ in 0..40 {
                let f = random_f(&mut st);
                let p = m.first_pk_stress(&f, f.determinant());
                let scale = p.abs().max().max(m.mu);
                for i in 0..3 {
                    for j in 0..3 {
                        let h = 1e-6;
                        let (mut fp, mut fm) = (f, f);
                        fp[(i, j)] += h;
                        fm[(i, j)] -= h;
                        let fd = (m.strain_energy(&fp) - m.strain_energy(&fm)) / (2.0 * h);
                        assert!(
                            (fd - p[(i, j)]).abs() <= 2e-6 * scale,
                            "alpha {}: P[{i}{j}] = {} vs {fd}",
                            m.alpha,
                            p[(i, j)]
                        );
                    }
                }
                let s = m.pk2_stress(&f, f.determinant());
                assert!((s - s.transpose()).norm() <= 1e-10 * s.norm().max(1.0));
                let r = nalgebra::Rotation3::from_euler_angles(0.3, -1.1, 2.0);
                let rf = r.matrix() * f;
                assert!(
                    (m.pk2_stress(&rf, rf.determinant()) - s).norm() <= 1e-9 * s.norm().max(1.0)
                );
            }
        }
    }

    /// alpha = 2 is the neo-Hookean solid; the small-strain moduli are mu and kappa.
    #[test]
    fn ogden_with_alpha_2_is_neo_hookean() {
        let nh = mat();
        let og = Ogden {
            mu: nh.mu,
            alpha: 2.0,
            kappa: nh.kappa,
            density: nh.density,
        };
        let mut st = 9u64;
        for _ in 0..50 {
            let f = random_f(&mut st);
            let j = f.determinant();
            let (a, b) = (og.pk2_stress(&f, j), nh.pk2_stress(&f, j));
            assert!((a - b).norm() <= 1e-9 * b.norm().max(nh.mu), "{a} vs {b}");
            assert!((og.strain_energy(&f) - nh.strain_energy(&f)).abs() <= 1e-9 * nh.mu);
        }
        assert_eq!(og.lame(), nh.lame());
        assert_eq!(og.wave_speed(), nh.wave_speed());
    }

    /// The kernel's stress at the closed-form uniaxial solution is uniaxial with the
    /// closed-form axial stress, in tension and compression.
    #[test]
    fn ogden_uniaxial_closed_form_matches_the_stress() {
        for m in [
            brain(),
            Ogden {
                alpha: 2.5,
                ..brain()
            },
        ] {
            for stretch in [0.5, 0.8, 1.2, 1.5] {
                let (a, j, szz) = m.uniaxial(stretch);
                let f = Matrix3::from_diagonal(&nalgebra::Vector3::new(a, a, stretch));
                let sig = f * m.pk2_stress(&f, j) * f.transpose() / j;
                let scale = szz.abs();
                assert!(
                    sig[(0, 0)].abs() < 1e-8 * scale && sig[(1, 1)].abs() < 1e-8 * scale,
                    "{sig}"
                );
                assert!((sig[(2, 2)] - szz).abs() < 1e-8 * scale, "{sig} vs {szz}");
            }
            // Incompressible limit check: sigma = (2 mu / alpha) (l^alpha - l^(-alpha / 2)).
            let stiff = Ogden {
                kappa: 1e7 * m.mu,
                ..m
            };
            let (_, _, szz) = stiff.uniaxial(0.8);
            let want = 2.0 * m.mu / m.alpha * (0.8f64.powf(m.alpha) - 0.8f64.powf(-m.alpha / 2.0));
            assert!((szz - want).abs() < 1e-4 * want.abs(), "{szz} vs {want}");
        }
    }

    /// Four points evaluated side by side give each lane bitwise its scalar stress, whatever
    /// its neighbours (an undeformed lane, for Ogden converging at once while strained ones
    /// take several sweeps; one with coincident stretches), and P = F S: the contract of
    /// `first_pk_stress_lanes` for both materials.
    #[test]
    fn lanes_equal_the_scalar_stress_bitwise() {
        fn check<M: Material>(m: &M) {
            let mut st = 5u64;
            for block in 0..50 {
                let mut fs: Vec<Matrix3<f64>> = (0..4).map(|_| random_f(&mut st)).collect();
                fs[block % 4] = Matrix3::identity();
                fs[(block + 1) % 4] =
                    Matrix3::from_diagonal(&nalgebra::Vector3::new(1.1, 1.1, 0.8));
                let f: [[f64; 4]; 9] =
                    std::array::from_fn(|i| std::array::from_fn(|l| fs[l][(i / 3, i % 3)]));
                let j: [f64; 4] = std::array::from_fn(|l| fs[l].determinant());
                let p = m.first_pk_stress_lanes(&f, &j);
                for l in 0..4 {
                    let one = m.first_pk_stress(&fs[l], j[l]);
                    let via_s = fs[l] * m.pk2_stress(&fs[l], j[l]);
                    for i in 0..9 {
                        assert_eq!(p[i][l].to_bits(), one[(i / 3, i % 3)].to_bits(), "lane {l}");
                        assert!(
                            (one[(i / 3, i % 3)] - via_s[(i / 3, i % 3)]).abs()
                                <= 1e-12 * one.norm()
                        );
                    }
                }
            }
        }
        check(&brain());
        check(&mat());
        check(&Solid::Ogden(brain()));
    }

    /// The Jacobi eigen-decomposition reproduces random symmetric matrices (V diag V^T = A,
    /// V orthonormal), coincident eigenvalues included, and agrees with nalgebra's.
    #[test]
    fn symmetric_eigen3_decomposes_c() {
        let mut st = 17u64;
        let mut cases: Vec<Matrix3<f64>> = (0..500)
            .map(|_| {
                let f = random_f(&mut st);
                f.transpose() * f
            })
            .collect();
        cases.push(Matrix3::identity());
        cases.push(Matrix3::from_diagonal(&nalgebra::Vector3::new(
            2.0, 2.0, 0.5,
        )));
        let r = nalgebra::Rotation3::from_euler_angles(0.4, 1.1, -0.7);
        cases.push(
            r.matrix()
                * Matrix3::from_diagonal(&nalgebra::Vector3::new(3.0, 1.0, 1.0))
                * r.matrix().transpose(),
        );
        for a in cases {
            let (l, v) = symmetric_eigen3(a);
            let back = v * Matrix3::from_diagonal(&l) * v.transpose();
            assert!((back - a).norm() <= 1e-13 * a.norm(), "{a} -> {back}");
            assert!((v.transpose() * v - Matrix3::identity()).norm() <= 1e-14);
            let mut mine: Vec<f64> = l.iter().copied().collect();
            let mut theirs: Vec<f64> = nalgebra::SymmetricEigen::new(a)
                .eigenvalues
                .iter()
                .copied()
                .collect();
            mine.sort_by(f64::total_cmp);
            theirs.sort_by(f64::total_cmp);
            for (x, y) in mine.iter().zip(&theirs) {
                assert!((x - y).abs() <= 1e-13 * a.norm(), "{mine:?} vs {theirs:?}");
            }
        }
    }
}
