//! Sparse LU of the essential-boundary matrix `A = Phi M^-1 V`, factored once by faer and
//! stored by rows for the solve repeated every time step.
//!
//! faer factors (a fill-reducing column order, then left-looking LU with partial pivoting,
//! `P A Q = L U`); the factors are then regrouped by rows so that each unknown of a triangular
//! solve is one gathered dot product, and up to [`LANES`] right-hand sides (the x, y and z
//! corrections of SEBCIEM) ride along in the lanes of one `[f64; LANES]` per row. For the
//! 418 constrained nodes of the meshless cylinder this solve of three columns took 12 us
//! against 23 us for faer's general one (2,000 solves timed, one thread).

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::perm::PermRef;
use faer::sparse::linalg::lu::simplicial::{
    factorize_simplicial_numeric_lu, factorize_simplicial_numeric_lu_scratch, SimplicialLu,
};
use faer::sparse::linalg::LuError;
use faer::sparse::linalg::{amd, colamd};
use faer::sparse::SparseColMatRef;

/// Largest system [`SparseLu::factor`] also factors after an AMD ordering: up to here both
/// factorizations take milliseconds.
pub const AMD_TRIAL_MAX: usize = 1024;

/// Right-hand sides one [`SparseLu::solve`] carries at once.
pub const LANES: usize = 4;

/// Why a factorization failed.
#[derive(Debug)]
pub enum FactorError {
    /// No memory for faer's workspace.
    OutOfMemory,
    /// No non-zero pivot candidate at this elimination step: the matrix is structurally singular.
    StructurallySingular(usize),
    /// Anything else faer reported.
    Other(String),
}

/// Fill-reducing column orderings [`SparseLu::factor`] tries.
#[derive(Debug, Clone, Copy)]
enum Ordering {
    Colamd,
    Amd,
}

/// A sparse matrix by rows: the entries of row i are `ptr[i]..ptr[i + 1]`, columns ascending.
#[derive(Debug, Default, Clone)]
struct Rows {
    ptr: Vec<u32>,
    idx: Vec<u32>,
    val: Vec<f64>,
}

impl Rows {
    /// The entries of a column-major n x n matrix that pass `keep(row, col)`, regrouped by row.
    fn from_columns(
        n: usize,
        col_ptr: &[usize],
        row_idx: &[usize],
        val: &[f64],
        keep: impl Fn(usize, usize) -> bool,
    ) -> Self {
        let mut ptr = vec![0u32; n + 1];
        for j in 0..n {
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                if keep(i, j) {
                    ptr[i + 1] += 1;
                }
            }
        }
        for i in 0..n {
            ptr[i + 1] += ptr[i];
        }
        let nnz = ptr[n] as usize;
        let mut fill: Vec<usize> = ptr[..n].iter().map(|&p| p as usize).collect();
        let mut idx = vec![0u32; nnz];
        let mut vals = vec![0.0; nnz];
        for j in 0..n {
            for p in col_ptr[j]..col_ptr[j + 1] {
                let i = row_idx[p];
                if keep(i, j) {
                    idx[fill[i]] = j as u32;
                    vals[fill[i]] = val[p];
                    fill[i] += 1;
                }
            }
        }
        Rows {
            ptr,
            idx,
            val: vals,
        }
    }

    #[inline(always)]
    fn range(&self, i: usize) -> std::ops::Range<usize> {
        self.ptr[i] as usize..self.ptr[i + 1] as usize
    }

    /// Row i times `x` (n rows of lanes), lane by lane. Four partial sums over the entries
    /// p = 0, 1, 2, 3 mod 4, added as (s0 + s1) + (s2 + s3): one chain of adds ran at the
    /// add latency, about four cycles an entry.
    #[inline(always)]
    fn row_times(&self, i: usize, x: &[[f64; LANES]]) -> [f64; LANES] {
        let r = self.range(i);
        let idx = &self.idx[r.clone()];
        let val = &self.val[r];
        let mut s = [[0.0; LANES]; 4];
        let mut ic = idx.chunks_exact(4);
        let mut vc = val.chunks_exact(4);
        for (is, vs) in (&mut ic).zip(&mut vc) {
            for q in 0..4 {
                // SAFETY: every column index is below n (checked in `SparseLu::factor`) and x
                // holds n rows (asserted by the callers).
                let xr = unsafe { x.get_unchecked(is[q] as usize) };
                add_scaled(&mut s[q], vs[q], xr);
            }
        }
        for (q, (&j, &v)) in ic.remainder().iter().zip(vc.remainder()).enumerate() {
            // SAFETY: as above.
            let xr = unsafe { x.get_unchecked(j as usize) };
            add_scaled(&mut s[q], v, xr);
        }
        let a = add(&s[0], &s[1]);
        let b = add(&s[2], &s[3]);
        add(&a, &b)
    }
}

/// `P A Q = L U` with L unit lower and U upper triangular, by rows.
#[derive(Debug, Default, Clone)]
pub struct SparseLu {
    n: usize,
    /// Row p of `P A` is row `row_perm[p]` of A.
    row_perm: Vec<u32>,
    /// Column j of `A Q` is column `col_perm[j]` of A.
    col_perm: Vec<u32>,
    /// L below its unit diagonal.
    lower: Rows,
    /// U above its diagonal.
    upper: Rows,
    /// `1 / U_ii` (infinite for a zero pivot, which the caller's condition estimate rejects).
    inv_diag: Vec<f64>,
    /// Whether [`SparseLu::solve`] may run its AVX2 build.
    avx2: bool,
}

impl SparseLu {
    /// Factors the square matrix `a` with faer's simplicial LU with partial pivoting after a
    /// COLAMD column ordering and, for up to [`AMD_TRIAL_MAX`] unknowns, also after an AMD
    /// ordering (pattern of `A + A^T`), keeping the factors with fewer entries (the solve
    /// costs one multiply-add per entry and right-hand side). AMD suits the cylinder's
    /// symmetric SEBCIEM matrix (19,216 entries off the diagonals against COLAMD's 21,665);
    /// on the brain's 2,186 constrained nodes it filled twice as much as COLAMD (1,652,247
    /// entries against 813,467) and took 0.61 s against 0.16 s. A numerically zero pivot is
    /// not an error here: it shows as a non-finite solution.
    pub fn factor(a: SparseColMatRef<'_, usize, f64>) -> Result<Self, FactorError> {
        let by_colamd = Self::factor_ordered(a, Ordering::Colamd)?;
        if a.nrows() > AMD_TRIAL_MAX {
            return Ok(by_colamd);
        }
        let by_amd = Self::factor_ordered(a, Ordering::Amd)?;
        Ok(if by_amd.nnz() < by_colamd.nnz() {
            by_amd
        } else {
            by_colamd
        })
    }

    fn factor_ordered(
        a: SparseColMatRef<'_, usize, f64>,
        ordering: Ordering,
    ) -> Result<Self, FactorError> {
        let n = a.nrows();
        assert!(
            a.ncols() == n,
            "SparseLu::factor: {n} x {} matrix",
            a.ncols()
        );
        if n >= u32::MAX as usize {
            return Err(FactorError::Other(format!("{n} unknowns are too many")));
        }
        let nnz = a.symbolic().compute_nnz();
        let req = StackReq::any_of(&[
            colamd::order_scratch::<usize>(n, n, nnz),
            // `amd::order` wants the entries of one triangle; all of them bound it.
            amd::order_scratch::<usize>(n, nnz),
            factorize_simplicial_numeric_lu_scratch::<usize, f64>(n, n),
        ]);
        let mut mem = MemBuffer::try_new(req).map_err(|_| FactorError::OutOfMemory)?;
        let mut col_fwd = vec![0usize; n];
        let mut col_inv = vec![0usize; n];
        let stack = MemStack::new(&mut mem);
        match ordering {
            Ordering::Colamd => colamd::order(
                &mut col_fwd,
                &mut col_inv,
                a.symbolic(),
                Default::default(),
                stack,
            )
            .map(|_| ()),
            Ordering::Amd => amd::order(
                &mut col_fwd,
                &mut col_inv,
                a.symbolic(),
                Default::default(),
                stack,
            )
            .map(|_| ()),
        }
        .map_err(|e| FactorError::Other(format!("{e:?}")))?;
        let mut row_fwd = vec![0usize; n];
        let mut row_inv = vec![0usize; n];
        let mut lu = SimplicialLu::<usize, f64>::new();
        factorize_simplicial_numeric_lu(
            &mut row_fwd,
            &mut row_inv,
            &mut lu,
            a,
            PermRef::new_checked(&col_fwd, &col_inv, n),
            MemStack::new(&mut mem),
        )
        .map_err(|e| match e {
            LuError::SymbolicSingular { index } => FactorError::StructurallySingular(index),
            e => FactorError::Other(format!("{e:?}")),
        })?;

        let l = lu.l_factor_unsorted();
        let lower = Rows::from_columns(n, l.col_ptr(), l.row_idx(), l.val(), |i, j| i > j);
        let u = lu.u_factor_unsorted();
        let upper = Rows::from_columns(n, u.col_ptr(), u.row_idx(), u.val(), |i, j| i < j);
        // `Rows::row_times` reads x[j] unchecked for every stored column j.
        if lower.idx.iter().chain(&upper.idx).any(|&j| j as usize >= n) {
            return Err(FactorError::Other(
                "factor column index out of range".into(),
            ));
        }
        let mut inv_diag = vec![f64::INFINITY; n];
        for (j, d) in inv_diag.iter_mut().enumerate() {
            for p in u.col_ptr()[j]..u.col_ptr()[j + 1] {
                if u.row_idx()[p] == j {
                    *d = 1.0 / u.val()[p];
                }
            }
        }
        Ok(SparseLu {
            n,
            row_perm: row_fwd.iter().map(|&i| i as u32).collect(),
            col_perm: col_fwd.iter().map(|&j| j as u32).collect(),
            lower,
            upper,
            inv_diag,
            avx2: crate::simd_available(),
        })
    }

    /// Number of unknowns.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Stored entries of L and U, diagonals included.
    pub fn nnz(&self) -> usize {
        self.lower.idx.len() + self.upper.idx.len() + 2 * self.n
    }

    /// Solves `A X = R` in place for the `k` columns of `rhs` (column-major, n x k,
    /// 1 <= k <= [`LANES`]); `work` is scratch of at least n rows. Does not allocate. The
    /// AVX2 build of the loops gives bitwise the same values (no fused multiply-add).
    ///
    /// # Panics
    /// If k or the slice lengths do not fit (a caller bug).
    pub fn solve(&self, rhs: &mut [f64], k: usize, work: &mut [[f64; LANES]]) {
        let n = self.n;
        assert!(
            (1..=LANES).contains(&k) && rhs.len() == n * k && work.len() >= n,
            "SparseLu::solve: {} values in {k} columns and {} scratch rows for {n} unknowns",
            rhs.len(),
            work.len()
        );
        let work = &mut work[..n];
        for (w, &r) in work.iter_mut().zip(&self.row_perm) {
            let mut lanes = [0.0; LANES];
            for (c, l) in lanes.iter_mut().enumerate().take(k) {
                *l = rhs[c * n + r as usize];
            }
            *w = lanes;
        }
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` was set only where the CPU has AVX2 (`simd_available`).
            unsafe { self.substitute_avx2(work) };
        } else {
            self.substitute(work);
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.substitute(work);
        for (w, &col) in work.iter().zip(&self.col_perm) {
            for (c, &l) in w.iter().enumerate().take(k) {
                rhs[c * n + col as usize] = l;
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn substitute_avx2(&self, work: &mut [[f64; LANES]]) {
        self.substitute(work);
    }

    /// Forward then backward substitution on the permuted right-hand sides in `work` (n rows).
    /// Row i of L and of U reaches only columns below and above i respectively, so every row
    /// gathered is final when it is read.
    #[inline(always)]
    fn substitute(&self, work: &mut [[f64; LANES]]) {
        let n = self.n;
        assert!(work.len() == n);
        for i in 0..n {
            let s = self.lower.row_times(i, work);
            work[i] = sub(&work[i], &s);
        }
        for i in (0..n).rev() {
            let s = self.upper.row_times(i, work);
            let d = self.inv_diag[i];
            work[i] = sub(&work[i], &s).map(|v| v * d);
        }
    }

    /// Solves `A^T x = b` in place for one column (`rhs`, n values); `work` is scratch of at
    /// least n values. Used by the condition estimate only.
    ///
    /// # Panics
    /// If the slice lengths do not fit (a caller bug).
    pub fn solve_transpose(&self, rhs: &mut [f64], work: &mut [f64]) {
        let n = self.n;
        assert!(
            rhs.len() == n && work.len() >= n,
            "SparseLu::solve_transpose: {} values and {} scratch for {n} unknowns",
            rhs.len(),
            work.len()
        );
        // A^T = Q U^T L^T P: the rows of U and L are the columns of U^T and L^T.
        let work = &mut work[..n];
        for (w, &col) in work.iter_mut().zip(&self.col_perm) {
            *w = rhs[col as usize];
        }
        for i in 0..n {
            let wi = work[i] * self.inv_diag[i];
            work[i] = wi;
            for p in self.upper.range(i) {
                work[self.upper.idx[p] as usize] -= self.upper.val[p] * wi;
            }
        }
        for i in (0..n).rev() {
            let vi = work[i];
            for p in self.lower.range(i) {
                work[self.lower.idx[p] as usize] -= self.lower.val[p] * vi;
            }
        }
        for (&w, &r) in work.iter().zip(&self.row_perm) {
            rhs[r as usize] = w;
        }
    }
}

/// `acc += v * x`, lane by lane.
#[inline(always)]
fn add_scaled(acc: &mut [f64; LANES], v: f64, x: &[f64; LANES]) {
    for c in 0..LANES {
        acc[c] += v * x[c];
    }
}

#[inline(always)]
fn add(a: &[f64; LANES], b: &[f64; LANES]) -> [f64; LANES] {
    std::array::from_fn(|c| a[c] + b[c])
}

#[inline(always)]
fn sub(a: &[f64; LANES], b: &[f64; LANES]) -> [f64; LANES] {
    std::array::from_fn(|c| a[c] - b[c])
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::{SparseColMat, Triplet};

    /// A random sparse n x n matrix with a dominant but permuted band, dense as `dense`.
    #[allow(clippy::needless_range_loop)] // i and j index the rows and columns together
    fn matrix(n: usize, seed: u64, symmetric: bool) -> Vec<Vec<f64>> {
        let mut s = seed;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut a = vec![vec![0.0; n]; n];
        for i in 0..n {
            // The large entry off the diagonal forces row pivoting.
            a[i][(i + 3) % n] = 4.0 + rnd();
            for _ in 0..3 {
                let j = (rnd() * n as f64) as usize % n;
                a[i][j] += rnd() - 0.5;
            }
        }
        if symmetric {
            for i in 0..n {
                for j in 0..i {
                    let v = a[i][j] + a[j][i];
                    a[i][j] = v;
                    a[j][i] = v;
                }
                a[i][i] += 10.0;
            }
        }
        a
    }

    fn sparse(a: &[Vec<f64>]) -> SparseColMat<usize, f64> {
        let n = a.len();
        let mut t = Vec::new();
        for (i, row) in a.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    t.push(Triplet::new(i, j, v));
                }
            }
        }
        SparseColMat::try_new_from_triplets(n, n, &t).unwrap()
    }

    fn mul(a: &[Vec<f64>], x: &[f64], transpose: bool) -> Vec<f64> {
        let n = a.len();
        (0..n)
            .map(|i| {
                (0..n)
                    .map(|j| if transpose { a[j][i] } else { a[i][j] } * x[j])
                    .sum()
            })
            .collect()
    }

    #[test]
    fn solves_reproduce_the_right_hand_sides() {
        for (n, seed, symmetric) in [(1, 1, false), (7, 2, false), (60, 3, false), (45, 4, true)] {
            let a = matrix(n, seed, symmetric);
            let lu = SparseLu::factor(sparse(&a).as_ref()).unwrap();
            assert_eq!(lu.dim(), n);
            for k in 1..=LANES {
                let xs: Vec<Vec<f64>> = (0..k)
                    .map(|c| {
                        (0..n)
                            .map(|i| ((i * 7 + c * 3) % 11) as f64 - 5.0)
                            .collect()
                    })
                    .collect();
                let mut rhs: Vec<f64> = xs.iter().flat_map(|x| mul(&a, x, false)).collect();
                let mut work = vec![[f64::NAN; LANES]; n + 2];
                lu.solve(&mut rhs, k, &mut work);
                for (c, x) in xs.iter().enumerate() {
                    for i in 0..n {
                        let got = rhs[c * n + i];
                        assert!(
                            (got - x[i]).abs() < 1e-11,
                            "n {n} k {k} column {c} row {i}: {got} vs {}",
                            x[i]
                        );
                    }
                }
            }
            let x: Vec<f64> = (0..n).map(|i| (i % 5) as f64 - 1.5).collect();
            let mut b = mul(&a, &x, true);
            let mut work = vec![f64::NAN; n];
            lu.solve_transpose(&mut b, &mut work);
            for i in 0..n {
                assert!(
                    (b[i] - x[i]).abs() < 1e-11,
                    "transpose, n {n} row {i}: {} vs {}",
                    b[i],
                    x[i]
                );
            }
        }
    }

    #[test]
    fn avx2_and_portable_builds_give_bitwise_equal_solutions() {
        let a = matrix(80, 5, false);
        let mut lu = SparseLu::factor(sparse(&a).as_ref()).unwrap();
        let rhs: Vec<f64> = (0..3 * 80).map(|i| ((i * 13) % 17) as f64 - 8.0).collect();
        let mut work = vec![[0.0; LANES]; 80];
        let mut solve = |lu: &SparseLu| {
            let mut x = rhs.clone();
            lu.solve(&mut x, 3, &mut work);
            x
        };
        let with = solve(&lu);
        lu.avx2 = false;
        let without = solve(&lu);
        assert_eq!(with, without);
    }

    #[test]
    fn structurally_singular_matrix_is_an_error() {
        let a = vec![
            vec![1.0, 2.0, 0.0],
            vec![3.0, 4.0, 0.0],
            vec![0.0, 5.0, 0.0],
        ];
        assert!(matches!(
            SparseLu::factor(sparse(&a).as_ref()),
            Err(FactorError::StructurallySingular(_))
        ));
    }

    #[test]
    fn numerically_zero_pivot_gives_non_finite_solutions() {
        let a = vec![vec![1.0, 2.0], vec![2.0, 4.0]];
        let lu = SparseLu::factor(sparse(&a).as_ref()).unwrap();
        let mut b = vec![1.0, 1.0];
        lu.solve(&mut b, 1, &mut [[0.0; LANES]; 2]);
        assert!(b.iter().any(|v| !v.is_finite()));
    }
}
