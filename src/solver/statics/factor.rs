//! The reduced stiffness K_ff (free DOFs) as a sparse symmetric matrix, its fill-reducing
//! order and symbolic Cholesky factorization built once per model, and numeric factorizations
//! (faer's supernodal LL^T, LDL^T where the matrix is not positive definite) kept for reuse.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LdltRef, LltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::Vector3;

use super::tangent::Tangent;
use super::trisolve::{Scalar, TreeSolve, TASKS};
use crate::{Error, InputKind, Result};

/// Free-DOF numbering: the free components of every node, node by node.
#[derive(Debug, Clone)]
pub struct Dofs {
    /// Per node and component: its free-DOF number, or u32::MAX where prescribed.
    pub index: Vec<[u32; 3]>,
    /// Number of free DOFs.
    pub len: usize,
}

impl Dofs {
    /// From the per-node mask of prescribed components.
    pub fn new(mask: &[[bool; 3]]) -> Self {
        let mut len = 0u32;
        let index = mask
            .iter()
            .map(|m| {
                std::array::from_fn(|c| {
                    if m[c] {
                        u32::MAX
                    } else {
                        len += 1;
                        len - 1
                    }
                })
            })
            .collect();
        Dofs {
            index,
            len: len as usize,
        }
    }

    /// The free entries of a nodal vector, in DOF order.
    pub fn gather(&self, v: &[Vector3<f64>], out: &mut [f64]) {
        for (i, ix) in self.index.iter().enumerate() {
            for c in 0..3 {
                if ix[c] != u32::MAX {
                    out[ix[c] as usize] = v[i][c];
                }
            }
        }
    }

    /// A nodal vector with the free entries of `x` and zero on prescribed components.
    pub fn scatter(&self, x: &[f64], out: &mut [Vector3<f64>]) {
        for (i, ix) in self.index.iter().enumerate() {
            for c in 0..3 {
                out[i][c] = if ix[c] != u32::MAX {
                    x[ix[c] as usize]
                } else {
                    0.0
                };
            }
        }
    }
}

/// Which factorization a [`Factor`] holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// LL^T: the matrix was positive definite.
    Llt,
    /// LDL^T with every pivot positive: K_ff is positive definite (single precision did not
    /// find it so).
    Ldlt,
    /// L |D| L^T of an LDL^T with a pivot not positive: K_ff is not positive definite (a
    /// tangent past a limit point, or buckling, or far from equilibrium); its solves give
    /// directions of descent ([`Factor::make_definite`]), not K^-1.
    Modified,
    /// LDL^T of the augmented matrix [K_b G; G^T -D^-1] of a tangent with split
    /// average-nodal-pressure units (K = K_b + G D G^T, one extra unknown per pressure node):
    /// quasi-definite where K_b is positive definite, so that any symmetric order factors
    /// (Vanderbei 1995); its solves are K^-1 on the displacement part.
    Augmented,
}

/// K_ff in compressed columns (upper triangle), its symbolic Cholesky factorization and the
/// latest numeric factor.
pub struct Factor {
    /// Unknowns of the factored matrix: the free DOFs, then one per split unit.
    n: usize,
    /// Free DOFs (the first `dofs` unknowns).
    dofs: usize,
    /// Per split unit: where its column's entries go in `values`, three per node of the unit
    /// (u32::MAX for a prescribed component), then its diagonal.
    unit_scatter: Vec<u32>,
    unit_scatter_offsets: Vec<usize>,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    /// Per block entry of the tangent and its 9 components (row-major): where it goes in
    /// `values`, or u32::MAX (a prescribed DOF or the lower triangle).
    scatter: Vec<[u32; 9]>,
    symbolic: SymbolicCholesky<usize>,
    /// The supernodal factor's solves split over the threads by its elimination tree (None:
    /// simplicial, or a tree that does not split).
    tree: Option<TreeSolve>,
    /// The factor's values in double precision (LDL^T, or a factorization that single
    /// precision could not take); allocated at its first use.
    l_values: Vec<f64>,
    /// The factor's values in single precision (LL^T of a positive definite K_ff, LDL^T of
    /// the augmented matrix), same
    /// structure; allocated at its first use.
    l_single: Vec<f32>,
    /// Pivots of the last double-precision LDL^T changed to make it positive definite
    /// ([`Kind::Modified`]): the tangent's eigenvalues not positive, by Sylvester's law of
    /// inertia (and any positive one under MODIFIED_FLOOR of the largest pivot).
    pub changed_pivots: usize,
    /// Whether the last factor is the single-precision one.
    single: bool,
    kind: Option<Kind>,
    /// The fill-reducing order kept: "amd", "nested dissection" (geometric) or "metis".
    pub ordering: &'static str,
    /// Multiply-adds of a numeric factorization, sum over the factor's columns of their
    /// nonzeros squared (from the symbolic structure).
    pub flops: f64,
    /// Numeric factorizations made, of them those in single precision, and those of a
    /// tangent not positive definite made so ([`Kind::Modified`]).
    pub factorizations: usize,
    pub single_factorizations: usize,
    pub modified_factorizations: usize,
    /// The most bytes held ([`Self::bytes`]) after any factorization.
    pub peak_bytes: usize,
    /// Wall seconds spent in the symbolic analysis and the numeric factorizations.
    pub symbolic_seconds: f64,
    pub factor_seconds: f64,
}

impl Factor {
    /// The pattern of K_ff from the tangent's block pattern and the free DOFs, with its
    /// fill-reducing order (AMD) and symbolic factorization. Errors when faer cannot allocate.
    pub fn new(k: &Tangent, dofs: &Dofs, coords: &[Vector3<f64>]) -> Result<Self> {
        let t0 = std::time::Instant::now();
        let units = k.pressure_units();
        let n = dofs.len + units.len();
        let nodes = dofs.index.len();
        // Column (a, i) holds the rows (b, k) <= (a, i) of block row a (K is symmetric, so
        // block row a is block column a transposed).
        let mut col_ptr = vec![0usize; n + 1];
        for a in 0..nodes {
            for i in 0..3 {
                let ca = dofs.index[a][i];
                if ca == u32::MAX {
                    continue;
                }
                let mut count = 0;
                for e in k.offsets[a]..k.offsets[a + 1] {
                    let b = k.cols[e] as usize;
                    for kk in 0..3 {
                        let rb = dofs.index[b][kk];
                        if rb != u32::MAX && rb <= ca {
                            count += 1;
                        }
                    }
                }
                col_ptr[ca as usize + 1] = count;
            }
        }
        // Unit columns: the free DOFs of its nodes (all numbered before it), then its diagonal.
        let free_of = |j: u32| {
            dofs.index[j as usize]
                .iter()
                .filter(|&&d| d != u32::MAX)
                .count()
        };
        for (i, u) in units.clone().enumerate() {
            let (un, _, _) = k.unit(u);
            col_ptr[dofs.len + i + 1] = un.iter().map(|&j| free_of(j)).sum::<usize>() + 1;
        }
        for j in 0..n {
            col_ptr[j + 1] += col_ptr[j];
        }
        let nnz = col_ptr[n];
        let mut row_idx = vec![0usize; nnz];
        let mut scatter = vec![[u32::MAX; 9]; k.cols.len()];
        let mut fill = col_ptr.clone();
        for a in 0..nodes {
            for i in 0..3 {
                let ca = dofs.index[a][i];
                if ca == u32::MAX {
                    continue;
                }
                for e in k.offsets[a]..k.offsets[a + 1] {
                    let b = k.cols[e] as usize;
                    for kk in 0..3 {
                        let rb = dofs.index[b][kk];
                        if rb != u32::MAX && rb <= ca {
                            let at = fill[ca as usize];
                            row_idx[at] = rb as usize;
                            // Block (a, b) entry (i, kk) is K[(a, i), (b, kk)] = K[(b, kk), (a, i)].
                            scatter[e][3 * i + kk] = at as u32;
                            fill[ca as usize] += 1;
                        }
                    }
                }
            }
        }
        let mut unit_scatter = Vec::new();
        let mut unit_scatter_offsets = vec![0usize];
        for (i, u) in units.clone().enumerate() {
            let col = dofs.len + i;
            let (un, _, _) = k.unit(u);
            let mut at = col_ptr[col];
            for &j in un {
                for &d in &dofs.index[j as usize] {
                    if d != u32::MAX {
                        row_idx[at] = d as usize;
                        unit_scatter.push(at as u32);
                        at += 1;
                    } else {
                        unit_scatter.push(u32::MAX);
                    }
                }
            }
            row_idx[at] = col;
            unit_scatter.push(at as u32);
            unit_scatter_offsets.push(unit_scatter.len());
        }
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        // Both orders' symbolic analyses take a fraction of a factorization; the one with the
        // smaller factor is kept (nested dissection: 8.4 against 11.3 million nonzeros on the
        // hex8 cylinder; AMD: 4.6 against 5.9 on brain-shift's tet4-anp).
        let symbolic_with = |how: SymmetricOrdering<'_, usize>| {
            factorize_symbolic_cholesky(
                pattern,
                Side::Upper,
                how,
                CholeskySymbolicParams::default(),
            )
            .map_err(|e| {
                Error::input(
                    InputKind::Value,
                    format!("the static solve's symbolic factorization: {e:?}"),
                )
            })
        };
        // The three analyses are independent: on the threads at once (each result is the
        // same on any count; c3's took 0.07, 0.10 and 0.20 s one after another).
        let custom = |(fwd, inv): (Vec<usize>, Vec<usize>)| {
            symbolic_with(SymmetricOrdering::Custom(faer::perm::PermRef::new_checked(
                &fwd, &inv, n,
            )))
        };
        let (nd, (amd, metis)) = rayon::join(
            || custom(dof_order(k, dofs, coords)),
            || {
                rayon::join(
                    || symbolic_with(SymmetricOrdering::Amd),
                    || {
                        metis_node_order(k, dofs.index.len())
                            .map(|order| custom(expand_to_dofs(&order, k, dofs)))
                    },
                )
            },
        );
        // The smallest factor of the three orders; the first of equals.
        let (mut symbolic, mut ordering) = (nd?, "nested dissection");
        let amd = amd?;
        if amd.len_val() < symbolic.len_val() {
            (symbolic, ordering) = (amd, "amd");
        }
        if let Some(metis) = metis.transpose()? {
            if metis.len_val() < symbolic.len_val() {
                (symbolic, ordering) = (metis, "metis");
            }
        }
        let flops = factor_flops(&symbolic);
        let tree = match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(sn) => TreeSolve::new(sn),
            SymbolicCholeskyRaw::Simplicial(_) => None,
        };
        Ok(Factor {
            n,
            dofs: dofs.len,
            unit_scatter,
            unit_scatter_offsets,
            values: vec![0.0; nnz],
            col_ptr,
            row_idx,
            scatter,
            symbolic,
            tree,
            l_values: Vec::new(),
            l_single: Vec::new(),
            changed_pivots: 0,
            single: false,
            kind: None,
            ordering,
            flops,
            factorizations: 0,
            single_factorizations: 0,
            modified_factorizations: 0,
            peak_bytes: 0,
            symbolic_seconds: t0.elapsed().as_secs_f64(),
            factor_seconds: 0.0,
        })
    }

    /// Nonzeros of the factor L.
    pub fn factor_nonzeros(&self) -> usize {
        self.symbolic.len_val()
    }

    /// Nonzeros of the upper triangle of K_ff.
    pub fn matrix_nonzeros(&self) -> usize {
        self.row_idx.len()
    }

    /// Bytes of the matrix, its scatter map and the factor.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        self.col_ptr.len() * size_of::<usize>()
            + self.row_idx.len() * (size_of::<usize>() + size_of::<f64>())
            + self.scatter.len() * size_of::<[u32; 9]>()
            + self.l_values.len() * size_of::<f64>()
            + self.l_single.len() * size_of::<f32>()
            + self.tree.as_ref().map_or(0, TreeSolve::bytes)
    }

    /// Whether the last factor is in single precision (a preconditioner whose solves are
    /// accurate to about 1e-7 times the condition number, not a direct solve).
    pub fn is_single(&self) -> bool {
        self.single && self.kind.is_some()
    }

    /// Bytes a factorization of `k` over `dofs` would hold, estimated before building it:
    /// the factor's nonzeros from the symbolic analysis are only known after it, so this
    /// counts the matrix, a factor of `fill` times its nonzeros and the tree-split solves'
    /// buffers.
    pub fn estimate_bytes(k: &Tangent, dofs: &Dofs, fill: f64) -> usize {
        let frac = dofs.len as f64 / (3 * dofs.index.len()).max(1) as f64;
        let nnz = k.blocks() as f64 * 4.5 * frac * frac;
        (nnz * (16.0 + 36.0 / 4.5 + 8.0 * fill)) as usize + TASKS * dofs.len * 8
    }

    /// Takes the values of the assembled tangent `k` and factors them: LL^T (the augmented
    /// matrix: LDL^T) in single precision unless `double` (mixed precision: the solves that
    /// use it are refined by conjugate gradients on the double-precision tangent, Higham 2002
    /// ch. 12); otherwise, or where single precision does not find the matrix positive
    /// definite (or its factor is not finite), LDL^T in double: exact where every pivot is
    /// positive ([`Kind::Ldlt`]), made positive definite where one is not ([`Kind::Modified`]).
    /// Errors when it is singular.
    pub fn factor(&mut self, k: &Tangent, double: bool) -> Result<Kind> {
        let t0 = std::time::Instant::now();
        self.take_values(k);
        if !double {
            if let Some(kind) = self.factor_single()? {
                self.factor_seconds += t0.elapsed().as_secs_f64();
                return Ok(kind);
            }
        }
        let augmented = self.n > self.dofs;
        let a = SparseColMatRef::new(pattern(self.n, &self.col_ptr, &self.row_idx), &self.values);
        let par = Par::Seq;
        let mut mem = self.workspace()?;
        let stack = MemStack::new(&mut mem);
        self.single = false;
        self.l_single = Vec::new();
        if self.l_values.is_empty() {
            let len = self.symbolic.len_val();
            self.l_values = try_zeros(len).ok_or_else(|| no_memory(len, 8))?;
        }
        // LDL^T straight away: the augmented matrix is indefinite by construction, and K_ff
        // where single precision found it not positive definite most often is (brain-indentation:
        // double-precision LL^T failed after it at every such tangent), which LDL^T's pivots
        // tell without another factorization.
        self.symbolic
            .factorize_numeric_ldlt(
                &mut self.l_values,
                a,
                Side::Upper,
                LdltRegularization::default(),
                par,
                stack,
                Default::default(),
            )
            .map_err(|e| Error::Unstable(format!("the tangent stiffness is singular ({e:?})")))?;
        self.changed_pivots = 0;
        let kind = if augmented {
            Kind::Augmented
        } else {
            self.changed_pivots = self.make_definite();
            if self.changed_pivots == 0 {
                Kind::Ldlt
            } else {
                self.modified_factorizations += 1;
                Kind::Modified
            }
        };
        if self.l_values.iter().any(|v| !v.is_finite()) {
            self.kind = None;
            return Err(Error::Unstable(
                "the tangent stiffness is singular: its factorization is not finite".into(),
            ));
        }
        self.kind = Some(kind);
        self.peak_bytes = self.peak_bytes.max(self.bytes());
        self.factorizations += 1;
        self.factor_seconds += t0.elapsed().as_secs_f64();
        Ok(kind)
    }

    /// K_ff's values (and the augmented matrix's) from the assembled tangent.
    fn take_values(&mut self, k: &Tangent) {
        self.values.iter_mut().for_each(|v| *v = 0.0);
        for (e, s) in self.scatter.iter().enumerate() {
            let b = &k.values[e];
            for (c, &at) in s.iter().enumerate() {
                if at != u32::MAX {
                    self.values[at as usize] = b[(c / 3, c % 3)];
                }
            }
        }
        for (i, u) in k.pressure_units().enumerate() {
            let (_, g, d) = k.unit(u);
            let at =
                &self.unit_scatter[self.unit_scatter_offsets[i]..self.unit_scatter_offsets[i + 1]];
            for (m, gm) in g.iter().enumerate() {
                for c in 0..3 {
                    if at[3 * m + c] != u32::MAX {
                        self.values[at[3 * m + c] as usize] = gm[c];
                    }
                }
            }
            // -1 / D; a unit without volumetric stiffness is decoupled (-1 / D huge).
            self.values[at[3 * g.len()] as usize] = if d > 0.0 { -1.0 / d } else { -1e150 };
        }
    }

    /// The factorization's workspace, for either precision and either kind.
    fn workspace(&self) -> Result<MemBuffer> {
        // Sequential: faer's parallel matrix-vector product (a supernode one column wide
        // over at least 65,536 entries) sums one partial per thread, so a parallel factor of a
        // large model could differ in the last bits between thread counts. On this 2-core
        // machine the 12 factorizations of the indentation benchmark took 3.05 s sequential
        // and 3.04 s on both threads.
        let par = Par::Seq;
        let req = self
            .symbolic
            .factorize_numeric_llt_scratch::<f64>(par, Default::default())
            .or(self
                .symbolic
                .factorize_numeric_ldlt_scratch::<f64>(par, Default::default()));
        MemBuffer::try_new(req).map_err(|_| {
            Error::input(
                InputKind::Limit,
                "no memory for the static solve's factorization workspace",
            )
        })
    }

    /// The values taken factored in single precision: LL^T, the augmented matrix LDL^T.
    /// None where that fails (not positive definite, or a factor not finite).
    fn factor_single(&mut self) -> Result<Option<Kind>> {
        let augmented = self.n > self.dofs;
        let par = Par::Seq;
        let mut mem = self.workspace()?;
        let stack = MemStack::new(&mut mem);
        // Single precision first: on the indentation benchmark's c3 (tet10, 30,039 DOFs) its
        // factorization took 0.18 s against 0.26 s, a pair of triangular solves 8 ms against
        // 20 ms (they stream the factor from memory), and half the factor's memory; the
        // augmented matrix of the coupled brain-contact (22,923 DOFs): 6 factorizations in
        // 11.4 s against 23.6 s, the static solve 44.6 s against 85.4 s.
        if self.l_single.is_empty() {
            let len = self.symbolic.len_val();
            let mut v = Vec::new();
            v.try_reserve_exact(len).map_err(|_| no_memory(len, 4))?;
            v.resize(len, 0.0f32);
            self.l_single = v;
        }
        // -1 / D of a unit without volumetric stiffness (-1e150) is beyond single
        // precision: the most negative finite value keeps it decoupled.
        let single: Vec<f32> = self
            .values
            .iter()
            .map(|&v| (v as f32).max(f32::MIN))
            .collect();
        let a = SparseColMatRef::new(pattern(self.n, &self.col_ptr, &self.row_idx), &single[..]);
        let ok = if augmented {
            self.symbolic
                .factorize_numeric_ldlt(
                    &mut self.l_single,
                    a,
                    Side::Upper,
                    LdltRegularization::default(),
                    par,
                    stack,
                    Default::default(),
                )
                .is_ok()
        } else {
            self.symbolic
                .factorize_numeric_llt(
                    &mut self.l_single,
                    a,
                    Side::Upper,
                    LltRegularization::default(),
                    par,
                    stack,
                    Default::default(),
                )
                .is_ok()
        };
        if !(ok && self.l_single.iter().all(|v| v.is_finite())) {
            return Ok(None);
        }
        // One factor held at a time: the other precision's is given back.
        self.l_values = Vec::new();
        let kind = if augmented {
            Kind::Augmented
        } else {
            Kind::Llt
        };
        self.kind = Some(kind);
        self.single = true;
        self.factorizations += 1;
        self.single_factorizations += 1;
        self.peak_bytes = self.peak_bytes.max(self.bytes());
        Ok(Some(kind))
    }

    /// LDL^T of an indefinite K made the factor of a positive definite L |D| L^T: every
    /// pivot replaced by its absolute value, at least MODIFIED_FLOOR of the largest (a
    /// modified symmetric indefinite factorization, Nocedal and Wright 2006 sect. 3.4, with
    /// D diagonal: faer's LDL^T does not pivot). Its solves give directions of descent of
    /// the energy, (L |D| L^T)^-1 r, where LDL^T's K^-1 r could climb it. Returns how many
    /// pivots it changed: the tangent's eigenvalues not positive (Sylvester's law of
    /// inertia), and positive ones under the floor.
    fn make_definite(&mut self) -> usize {
        let at: Vec<usize> = match self.symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(sn) => {
                let (begin, end) = (sn.supernode_begin(), sn.supernode_end());
                let (rows, vals) = (sn.col_ptr_for_row_idx(), sn.col_ptr_for_val());
                (0..sn.n_supernodes())
                    .flat_map(|k| {
                        let w = end[k] - begin[k];
                        let height = w + rows[k + 1] - rows[k];
                        (0..w).map(move |j| vals[k] + j * height + j)
                    })
                    .collect()
            }
            SymbolicCholeskyRaw::Simplicial(sm) => sm.col_ptr()[..self.n].to_vec(),
        };
        let largest = at
            .iter()
            .fold(0.0f64, |m, &i| m.max(self.l_values[i].abs()));
        let mut negative = 0;
        for i in at {
            let d = &mut self.l_values[i];
            negative += usize::from(*d < 0.0);
            *d = d.abs().max(MODIFIED_FLOOR * largest);
        }
        negative
    }

    /// Solves K_ff x = b in place with the last factor (b: one value per free DOF; an
    /// augmented factor solves with zero on its extra unknowns and keeps the DOF part).
    pub fn solve(&self, b: &mut [f64]) {
        if self.tree_solve(b) {
            return;
        }
        let par = Par::Seq;
        if self.is_single() {
            let req = self.symbolic.solve_in_place_scratch::<f32>(1, par);
            let mut mem = MemBuffer::new(req);
            let stack = MemStack::new(&mut mem);
            // An augmented factor solves with zero on its extra unknowns.
            let mut x = vec![0f32; self.n];
            for (xi, bi) in x.iter_mut().zip(&b[..self.dofs]) {
                *xi = *bi as f32;
            }
            let rhs = MatMut::from_column_major_slice_mut(&mut x, self.n, 1);
            if self.kind == Some(Kind::Augmented) {
                LdltRef::new(&self.symbolic, &self.l_single).solve_in_place_with_conj(
                    Conj::No,
                    rhs,
                    par,
                    stack,
                );
            } else {
                LltRef::new(&self.symbolic, &self.l_single).solve_in_place_with_conj(
                    Conj::No,
                    rhs,
                    par,
                    stack,
                );
            }
            for (bi, xi) in b[..self.dofs].iter_mut().zip(&x) {
                *bi = *xi as f64;
            }
            return;
        }
        let req = self.symbolic.solve_in_place_scratch::<f64>(1, par);
        let mut mem = MemBuffer::new(req);
        let stack = MemStack::new(&mut mem);
        let mut extended = Vec::new();
        let x: &mut [f64] = if self.n > self.dofs {
            extended.resize(self.n, 0.0);
            extended[..self.dofs].copy_from_slice(&b[..self.dofs]);
            &mut extended
        } else {
            &mut *b
        };
        let rhs = MatMut::from_column_major_slice_mut(x, self.n, 1);
        match self.kind {
            Some(Kind::Llt) => LltRef::new(&self.symbolic, &self.l_values)
                .solve_in_place_with_conj(Conj::No, rhs, par, stack),
            Some(Kind::Ldlt | Kind::Modified | Kind::Augmented) => LdltRef::new(
                &self.symbolic,
                &self.l_values,
            )
            .solve_in_place_with_conj(Conj::No, rhs, par, stack),
            None => {}
        }
        if self.n > self.dofs {
            b[..self.dofs].copy_from_slice(&extended[..self.dofs]);
        }
    }

    /// [`Self::solve`] by the tree-split solves ([`TreeSolve`]); false (b untouched) where
    /// the factor has none.
    fn tree_solve(&self, b: &mut [f64]) -> bool {
        let (Some(tree), SymbolicCholeskyRaw::Supernodal(sn), Some(kind)) =
            (&self.tree, self.symbolic.raw(), self.kind)
        else {
            return false;
        };
        // LL^T (either precision) has L's own diagonal; LDL^T a unit L and D.
        let unit = kind != Kind::Llt;
        if self.single {
            permuted_solve(&self.symbolic, b, self.dofs, self.n, |x: &mut [f32]| {
                tree.solve(sn, &self.l_single, x, unit)
            });
        } else {
            permuted_solve(&self.symbolic, b, self.dofs, self.n, |x: &mut [f64]| {
                tree.solve(sn, &self.l_values, x, unit)
            });
        }
        true
    }

    /// The kind of the last factorization (None before the first).
    pub fn kind(&self) -> Option<Kind> {
        self.kind
    }
}

/// b's first `dofs` entries into the factor's order (zero on the rest of its `n`
/// unknowns), solved by `solve`, and back.
fn permuted_solve<T: Scalar>(
    symbolic: &SymbolicCholesky<usize>,
    b: &mut [f64],
    dofs: usize,
    n: usize,
    solve: impl FnOnce(&mut [T]),
) {
    let mut x = vec![T::from_f64(0.0); n];
    match symbolic.perm() {
        Some(perm) => {
            let (fwd, inv) = perm.arrays();
            for (xi, &f) in x.iter_mut().zip(fwd) {
                if f < dofs {
                    *xi = T::from_f64(b[f]);
                }
            }
            solve(&mut x);
            for (bi, &k) in b[..dofs].iter_mut().zip(inv) {
                *bi = x[k].to_f64();
            }
        }
        None => {
            for (xi, bi) in x.iter_mut().zip(&b[..dofs]) {
                *xi = T::from_f64(*bi);
            }
            solve(&mut x);
            for (bi, xi) in b[..dofs].iter_mut().zip(&x) {
                *bi = xi.to_f64();
            }
        }
    }
}

/// The smallest pivot of a modified factor, over its largest ([`Factor::make_definite`]).
const MODIFIED_FLOOR: f64 = 1e-8;

/// Sum over the columns of L of their nonzeros squared: the multiply-adds of a factorization.
fn factor_flops(s: &SymbolicCholesky<usize>) -> f64 {
    use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
    match s.raw() {
        SymbolicCholeskyRaw::Supernodal(sn) => {
            let (begin, end, ptr) = (
                sn.supernode_begin(),
                sn.supernode_end(),
                sn.col_ptr_for_row_idx(),
            );
            (0..sn.n_supernodes())
                .map(|k| {
                    let w = end[k] - begin[k];
                    let below = ptr[k + 1] - ptr[k];
                    (0..w)
                        .map(|c| ((w - c + below) as f64).powi(2))
                        .sum::<f64>()
                })
                .sum()
        }
        SymbolicCholeskyRaw::Simplicial(sm) => sm
            .col_ptr()
            .windows(2)
            .map(|w| ((w[1] - w[0]) as f64).powi(2))
            .sum(),
    }
}

/// The pattern of the upper triangle of an n x n matrix in compressed columns.
fn pattern<'a>(
    n: usize,
    col_ptr: &'a [usize],
    row_idx: &'a [usize],
) -> SymbolicSparseColMatRef<'a, usize> {
    SymbolicSparseColMatRef::new_checked(n, n, col_ptr, None, row_idx)
}

/// The error where a factor of `len` nonzeros of `bytes` each cannot be allocated.
fn no_memory(len: usize, bytes: usize) -> Error {
    Error::input(
        InputKind::Limit,
        format!(
            "the static solve's factor needs {:.2} GB ({len} nonzeros) and cannot be allocated; \
             use solver.mode = \"relaxation\", which needs no factor",
            (len * bytes) as f64 * 1e-9
        ),
    )
}

/// A zeroed vector of `n` values, or None when it cannot be allocated.
fn try_zeros(n: usize) -> Option<Vec<f64>> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).ok()?;
    v.resize(n, 0.0);
    Some(v)
}

/// Nodes per leaf of the nested dissection: a leaf's DOFs are eliminated as one dense block.
const LEAF: usize = 24;

/// A fill-reducing order of the free DOFs: geometric nested dissection of the node graph
/// (George 1973): the nodes are split at the median of the longest axis of their box, the
/// nodes of the smaller side that a point or unit joins to the other side are the separator,
/// numbered after both halves, recursively down to leaves of [`LEAF`] nodes; each node's free
/// DOFs follow each other. Returns (new -> old, old -> new).
fn dof_order(k: &Tangent, dofs: &Dofs, nodes: &[Vector3<f64>]) -> (Vec<usize>, Vec<usize>) {
    expand_to_dofs(&geometric_node_order(k, nodes), k, dofs)
}

/// The nodes in geometric nested-dissection order ([`dof_order`]).
fn geometric_node_order(k: &Tangent, nodes: &[Vector3<f64>]) -> Vec<u32> {
    let n = nodes.len();
    let mut order: Vec<u32> = Vec::with_capacity(n);
    let mut part = vec![u32::MAX; n];
    let mut next_label = 0u32;
    let mut stack: Vec<Vec<u32>> = vec![(0..n as u32).collect()];
    // Separators are numbered after what they separate: collect (segment, separator) in a
    // post-order by an explicit stack of work items.
    enum Work {
        Split(Vec<u32>),
        Emit(Vec<u32>),
    }
    let mut work = vec![Work::Split(stack.pop().unwrap_or_default())];
    while let Some(w) = work.pop() {
        let ids = match w {
            Work::Emit(v) => {
                order.extend(v);
                continue;
            }
            Work::Split(v) => v,
        };
        if ids.len() <= LEAF {
            order.extend(ids);
            continue;
        }
        let (mut lo, mut hi) = (Vector3::repeat(f64::MAX), Vector3::repeat(f64::MIN));
        for &i in &ids {
            lo = lo.inf(&nodes[i as usize]);
            hi = hi.sup(&nodes[i as usize]);
        }
        let axis = (hi - lo).imax();
        let mut ids = ids;
        let mid = ids.len() / 2;
        ids.select_nth_unstable_by(mid, |&a, &b| {
            nodes[a as usize][axis].total_cmp(&nodes[b as usize][axis])
        });
        let (left, right) = ids.split_at(mid);
        let (la, lb) = (next_label, next_label + 1);
        next_label += 2;
        for &i in left {
            part[i as usize] = la;
        }
        for &i in right {
            part[i as usize] = lb;
        }
        let touches = |i: u32, other: u32| {
            let i = i as usize;
            k.cols[k.offsets[i]..k.offsets[i + 1]]
                .iter()
                .any(|&j| part[j as usize] == other)
        };
        let sep_left: Vec<u32> = left.iter().copied().filter(|&i| touches(i, lb)).collect();
        let sep_right: Vec<u32> = right.iter().copied().filter(|&i| touches(i, la)).collect();
        let (sep, a, b): (Vec<u32>, Vec<u32>, Vec<u32>) = if sep_left.len() <= sep_right.len() {
            let rest = left
                .iter()
                .copied()
                .filter(|i| !sep_left.contains(i))
                .collect();
            (sep_left, rest, right.to_vec())
        } else {
            let rest = right
                .iter()
                .copied()
                .filter(|i| !sep_right.contains(i))
                .collect();
            (sep_right, left.to_vec(), rest)
        };
        work.push(Work::Emit(sep));
        work.push(Work::Split(b));
        work.push(Work::Split(a));
    }
    order
}

/// One METIS call at a time in the process: METIS draws its random numbers from one state for
/// the whole process (GKlib's generator, reseeded at every call), so orders computed at the
/// same time on several threads interleaved their draws and differed from run to run: 39 of
/// 40 in `the_metis_order_is_the_same_while_other_threads_order`, and brain-shift's static
/// answer on 1 and 3 threads in CI, where other tests of the binary ordered at the same time.
static METIS_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The nodes in METIS's multilevel nested-dissection order of the tangent's node graph
/// (METIS_NodeND; Karypis and Kumar 1998, SIAM J. Sci. Comput. 20(1)): separators found by
/// graph coarsening and refinement rather than by coordinates. Deterministic (METIS's fixed
/// seed, one call at a time: [`METIS_LOCK`]). None where METIS refuses the graph.
fn metis_node_order(k: &Tangent, n: usize) -> Option<Vec<u32>> {
    use metis_sys::idx_t;
    let mut xadj: Vec<idx_t> = Vec::with_capacity(n + 1);
    let mut adjncy: Vec<idx_t> = Vec::with_capacity(k.cols.len());
    xadj.push(0);
    for i in 0..n {
        for &j in &k.cols[k.offsets[i]..k.offsets[i + 1]] {
            if j as usize != i {
                adjncy.push(idx_t::try_from(j).ok()?);
            }
        }
        xadj.push(idx_t::try_from(adjncy.len()).ok()?);
    }
    let mut nvtxs = idx_t::try_from(n).ok()?;
    if nvtxs == 0 {
        return Some(Vec::new());
    }
    let mut options = [0 as idx_t; metis_sys::METIS_NOPTIONS as usize];
    let (mut perm, mut iperm) = (vec![0 as idx_t; n], vec![0 as idx_t; n]);
    // SAFETY: the arrays are METIS's CSR graph of nvtxs vertices (xadj nvtxs + 1 offsets into
    // adjncy, every entry a vertex below nvtxs), options holds METIS_NOPTIONS entries, perm
    // and iperm nvtxs each; a null vwgt means unit weights. METIS keeps no pointer.
    // A panic elsewhere while holding the lock leaves METIS's state as a call left it, which
    // the next call reseeds: the poisoned lock is taken all the same.
    let _one_at_a_time = METIS_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let ok = unsafe {
        metis_sys::METIS_SetDefaultOptions(options.as_mut_ptr());
        metis_sys::METIS_NodeND(
            &mut nvtxs,
            xadj.as_mut_ptr(),
            adjncy.as_mut_ptr(),
            std::ptr::null_mut(),
            options.as_mut_ptr(),
            perm.as_mut_ptr(),
            iperm.as_mut_ptr(),
        )
    } == metis_sys::rstatus_et_METIS_OK;
    // perm[new] = old.
    ok.then(|| perm.iter().map(|&p| p as u32).collect())
}

/// (new -> old, old -> new) of the free DOFs and the split units' unknowns for nodes in
/// `order`: each node's free DOFs follow each other, then its units.
fn expand_to_dofs(order: &[u32], k: &Tangent, dofs: &Dofs) -> (Vec<usize>, Vec<usize>) {
    let n = dofs.index.len();
    // A split unit's unknown follows its node's DOFs: it joins only that node's neighbours,
    // which the dissection keeps on the node's side or in its separator.
    let units = k.pressure_units();
    let mut at_node: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (i, u) in units.clone().enumerate() {
        at_node[k.unit_key(u)].push((dofs.len + i) as u32);
    }
    let mut fwd = Vec::with_capacity(dofs.len + units.len());
    for &i in order {
        for c in 0..3 {
            let d = dofs.index[i as usize][c];
            if d != u32::MAX {
                fwd.push(d as usize);
            }
        }
        fwd.extend(at_node[i as usize].iter().map(|&x| x as usize));
    }
    let mut inv = vec![0usize; fwd.len()];
    for (new, &old) in fwd.iter().enumerate() {
        inv[old] = new;
    }
    (fwd, inv)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::fe::{element_points, ElementKind};
    use crate::geometry::shapes::box_tet;
    use crate::material::{NeoHookean, Solid};
    use crate::solver::Model;

    /// A tet4-anp box of Poisson's ratio `nu` (`cells` over 40 x 30 x 50 mm, its base held)
    /// at the displacement `at` of each node, its free DOFs and a right-hand side.
    pub(in crate::solver::statics) fn box_at(
        nu: f64,
        cells: [usize; 3],
        at: impl Fn(&Vector3<f64>) -> Vector3<f64>,
    ) -> (Model<Solid>, Vec<Vector3<f64>>, Dofs, Vec<f64>) {
        let mesh = box_tet(Vector3::zeros(), Vector3::new(0.04, 0.03, 0.05), cells).unwrap();
        let mat = Solid::NeoHookean(NeoHookean::from_young_poisson(3000.0, nu, 1000.0));
        let qp = element_points(&mesh, ElementKind::Tet4Anp, 0.05, 1e4).unwrap();
        let model = Model::new(mesh.nodes.clone(), qp, mat, Vec::new()).unwrap();
        let u = model.nodes.iter().map(at).collect();
        let mask: Vec<[bool; 3]> = model.nodes.iter().map(|x| [x.z == 0.0; 3]).collect();
        let dofs = Dofs::new(&mask);
        let b = (0..dofs.len)
            .map(|i| ((i * 37 % 11) as f64) - 5.0)
            .collect();
        (model, u, dofs, b)
    }

    /// K x - b on the free DOFs, through the tangent's own product.
    fn residual(k: &Tangent, dofs: &Dofs, x: &[f64], b: &[f64]) -> Vec<f64> {
        let n = dofs.index.len();
        let (mut xs, mut kx) = (vec![Vector3::zeros(); n], vec![Vector3::zeros(); n]);
        dofs.scatter(x, &mut xs);
        k.multiply(&xs, &mut kx);
        let mut r = vec![0.0; dofs.len];
        dofs.gather(&kx, &mut r);
        r.iter().zip(b).map(|(a, c)| a - c).collect()
    }

    /// The triangular solves split over the elimination tree ([`TreeSolve`]) give faer's
    /// sequential solves to rounding, for LL^T and LDL^T of K_ff and the augmented matrix in
    /// either precision, and bitwise the same answer on 1 and 3 threads (the split and each
    /// block of a large supernode's products are fixed by the structure alone).
    #[test]
    fn the_tree_split_solves_match_the_sequential_ones_on_any_thread_count() {
        use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
        let (model, u, dofs, b) =
            box_at(0.45, [12, 12, 14], |x| Vector3::new(0.02 * x.z, 0.0, 0.0));
        for split in [false, true] {
            let mut k = Tangent::new(&model, &[], split);
            k.assemble(&model, &u);
            let mut f = Factor::new(&k, &dofs, &model.nodes).unwrap();
            assert!(f.tree.is_some(), "the factor of {} unknowns splits", f.n);
            // A supernode large enough that its products are split into blocks too.
            let SymbolicCholeskyRaw::Supernodal(sn) = f.symbolic.raw() else {
                panic!("a simplicial factor of {} unknowns", f.n);
            };
            let largest = (0..sn.n_supernodes())
                .map(|s| {
                    (sn.supernode_end()[s] - sn.supernode_begin()[s])
                        * sn.supernode(s).pattern().len()
                })
                .max()
                .unwrap_or(0);
            assert!(
                largest >= super::super::trisolve::SPLIT_ENTRIES,
                "{largest}"
            );
            for double in [true, false] {
                let kind = f.factor(&k, double).unwrap();
                let tree = f.tree.take();
                let mut sequential = b.clone();
                f.solve(&mut sequential);
                f.tree = tree;
                let on = |threads: usize| {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    let mut x = b.clone();
                    pool.install(|| f.solve(&mut x));
                    x
                };
                let (one, three) = (on(1), on(3));
                assert!(
                    one.iter()
                        .zip(&three)
                        .all(|(a, c)| a.to_bits() == c.to_bits()),
                    "{kind:?}: 1 and 3 threads differ"
                );
                let scale = sequential.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                let diff = one
                    .iter()
                    .zip(&sequential)
                    .fold(0.0f64, |m, (a, c)| m.max((a - c).abs()));
                let tol = if double { 1e-12 } else { 1e-5 };
                eprintln!("{kind:?} double {double}: {:.2e}", diff / scale);
                assert!(diff <= tol * scale, "{kind:?}: {diff:e} of {scale:e}");
            }
        }
    }

    /// The single-precision factor (mixed precision), of the assembled K_ff (LL^T) and of the
    /// augmented matrix (LDL^T): half the bytes of the double one, its solve within the
    /// rounding of single precision times the condition number (a preconditioner that CG
    /// refines), where the double one's is within 1e-9; near incompressibility too.
    #[test]
    fn the_single_precision_factor_solves_to_its_rounding_in_half_the_memory() {
        for nu in [0.45, 0.4999] {
            // Simple shear: where the volume changes, nu = 0.4999's pressure makes the
            // tangent of this state, not an equilibrium, indefinite from 0.2 % compression.
            let (model, u, dofs, b) =
                box_at(nu, [8, 6, 10], |x| Vector3::new(0.02 * x.z, 0.0, 0.0));
            for split in [false, true] {
                let mut k = Tangent::new(&model, &[], split);
                k.assemble(&model, &u);
                let mut f = Factor::new(&k, &dofs, &model.nodes).unwrap();
                let mut errors = Vec::new();
                let mut bytes = Vec::new();
                for double in [true, false] {
                    // In double precision K_ff is factored LDL^T (its pivots tell whether it
                    // is positive definite), in single LL^T.
                    let kind = match (split, double) {
                        (true, _) => Kind::Augmented,
                        (false, true) => Kind::Ldlt,
                        (false, false) => Kind::Llt,
                    };
                    assert_eq!(f.factor(&k, double).unwrap(), kind);
                    assert_eq!(f.is_single(), !double);
                    bytes.push(f.l_values.len() * 8 + f.l_single.len() * 4);
                    let mut x = b.clone();
                    f.solve(&mut x);
                    let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
                    errors.push(norm(&residual(&k, &dofs, &x, &b)) / norm(&b));
                }
                println!(
                    "nu {nu} split {split}: relative residual double {:.2e}, single {:.2e}; \
                     bytes {bytes:?}",
                    errors[0], errors[1]
                );
                assert!(errors[0] < 1e-9, "nu {nu}: double {:e}", errors[0]);
                assert!(
                    errors[1] < 1e-2 && errors[1] > errors[0],
                    "nu {nu}: single {:e}",
                    errors[1]
                );
                assert_eq!(2 * bytes[1], bytes[0], "nu {nu}");
                assert_eq!((f.factorizations, f.single_factorizations), (2, 1));
            }
        }
    }

    /// The augmented factor of a tangent with split nodal-pressure units solves K x = b as
    /// the factor of the assembled two-ring matrix does, near incompressibility too, with a
    /// factor of fewer nonzeros. The state keeps the volume (J = 1), so that K_ff is positive
    /// definite and its factor exact: compressed 20 %, it is not even at nu = 0.45, and its
    /// factor is made positive definite (`an_indefinite_tangent_gets_...`).
    #[test]
    fn the_augmented_factor_solves_the_tangent_with_less_fill() {
        for nu in [0.45, 0.4999] {
            let (model, u, dofs, b) =
                box_at(nu, [8, 6, 10], |x| Vector3::new(0.1 * x.z, 0.05 * x.x, 0.0));
            let mut solved = Vec::new();
            let mut fill = Vec::new();
            for split in [false, true] {
                let mut k = Tangent::new(&model, &[], split);
                k.assemble(&model, &u);
                let mut f = Factor::new(&k, &dofs, &model.nodes).unwrap();
                let kind = f.factor(&k, true).unwrap();
                assert_eq!(kind == Kind::Augmented, split);
                let mut x = b.clone();
                f.solve(&mut x);
                let err = residual(&k, &dofs, &x, &b)
                    .iter()
                    .fold(0.0f64, |m, a| m.max(a.abs()));
                assert!(err < 1e-8 * 5.0, "nu {nu} split {split}: |Kx - b| {err:e}");
                solved.push(x);
                fill.push(f.factor_nonzeros());
            }
            let scale = solved[0].iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let d = solved[0]
                .iter()
                .zip(&solved[1])
                .fold(0.0f64, |m, (a, c)| m.max((a - c).abs()));
            println!(
                "nu {nu}: factor nonzeros {} two-ring, {} augmented; |dx| {d:e} of {scale:e}",
                fill[0], fill[1]
            );
            assert!(d < 1e-8 * scale, "nu {nu}: {d:e} of {scale:e}");
            assert!(fill[1] < fill[0]);
        }
    }

    /// The tangent of a box compressed 1 % at nu = 0.4999 (not an equilibrium: a pressure of
    /// about 50 kPa against a shear modulus of 1 kPa) is indefinite. Its factor is made
    /// positive definite, L |D| L^T: as many pivots changed as K_ff has negative eigenvalues
    /// (Sylvester's law of inertia, against a dense symmetric eigensolver), and every solve
    /// x = (L |D| L^T)^-1 b a direction of descent, b . x > 0. Uncompressed, the same box's
    /// LDL^T is K_ff's: no pivot changed, and the solve exact.
    #[test]
    fn an_indefinite_tangent_gets_a_positive_definite_factor_with_its_inertia() {
        for squeeze in [0.01, 0.0] {
            let (model, u, dofs, _) = box_at(0.4999, [3, 3, 4], |x| {
                Vector3::new(0.0, 0.0, -squeeze * x.z)
            });
            let mut k = Tangent::new(&model, &[], false);
            k.assemble(&model, &u);
            // K_ff dense, through the tangent's product with the unit vectors.
            let n = dofs.len;
            let mut dense = nalgebra::DMatrix::zeros(n, n);
            for j in 0..n {
                let mut e = vec![0.0; n];
                e[j] = 1.0;
                let col = residual(&k, &dofs, &e, &vec![0.0; n]);
                dense.column_mut(j).copy_from_slice(&col);
            }
            let eigen = nalgebra::SymmetricEigen::new(dense.clone());
            let negative = eigen.eigenvalues.iter().filter(|&&l| l < 0.0).count();
            let mut f = Factor::new(&k, &dofs, &model.nodes).unwrap();
            // Uncompressed, in double precision: LDL^T (single precision's LL^T is exact
            // only to its rounding).
            let kind = f.factor(&k, squeeze == 0.0).unwrap();
            println!(
                "squeeze {squeeze}: {kind:?}, {} pivots changed, {negative} negative \
                 eigenvalues of {n}",
                f.changed_pivots
            );
            let mut worst = f64::INFINITY;
            for s in 0..20 {
                let b: Vec<f64> = (0..n)
                    .map(|i| (((i + 7) * (s + 3) * 2654435761usize) % 1000) as f64 - 499.5)
                    .collect();
                let mut x = b.clone();
                f.solve(&mut x);
                let bx: f64 = b.iter().zip(&x).map(|(a, c)| a * c).sum();
                let bb: f64 = b.iter().map(|a| a * a).sum();
                worst = worst.min(bx / bb);
                if squeeze == 0.0 {
                    let err = residual(&k, &dofs, &x, &b)
                        .iter()
                        .fold(0.0f64, |m, a| m.max(a.abs()));
                    assert!(err < 1e-8 * 500.0, "|Kx - b| {err:e}");
                }
            }
            assert!(worst > 0.0, "squeeze {squeeze}: b . x / b . b = {worst:e}");
            if squeeze > 0.0 {
                assert!(negative > 0);
                assert_eq!((kind, f.changed_pivots), (Kind::Modified, negative));
            } else {
                assert_eq!((negative, kind, f.changed_pivots), (0, Kind::Ldlt, 0));
            }
        }
    }

    /// A tet4-anp box, 8 x 6 x 10 cells over 40 x 30 x 50 mm, nearly incompressible.
    fn anp_box() -> Model<Solid> {
        let mesh = box_tet(Vector3::zeros(), Vector3::new(0.04, 0.03, 0.05), [8, 6, 10]).unwrap();
        let mat = Solid::NeoHookean(NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0));
        let qp = element_points(&mesh, ElementKind::Tet4Anp, 0.05, 1e4).unwrap();
        Model::new(mesh.nodes, qp, mat, Vec::new()).unwrap()
    }

    /// METIS's order is a permutation of the nodes, the same on every call, and expands to
    /// every free DOF and split unit once; the factor keeps the order with the fewest nonzeros.
    #[test]
    fn the_metis_order_is_a_deterministic_permutation_of_every_unknown() {
        let model = anp_box();
        let n = model.nodes.len();
        let mask: Vec<[bool; 3]> = model.nodes.iter().map(|x| [x.z == 0.0; 3]).collect();
        let dofs = Dofs::new(&mask);
        let k = Tangent::new(&model, &[], true);
        let order = metis_node_order(&k, n).expect("METIS orders a mesh graph");
        assert_eq!(metis_node_order(&k, n), Some(order.clone()));
        let mut seen = vec![false; n];
        order.iter().for_each(|&i| seen[i as usize] = true);
        assert!(order.len() == n && seen.iter().all(|&s| s));
        let (fwd, inv) = expand_to_dofs(&order, &k, &dofs);
        let unknowns = dofs.len + k.pressure_units().len();
        assert_eq!(fwd.len(), unknowns);
        assert!(fwd.iter().enumerate().all(|(new, &old)| inv[old] == new));
        let f = Factor::new(&k, &dofs, &model.nodes).unwrap();
        println!(
            "factor: {} order, {} nonzeros",
            f.ordering,
            f.factor_nonzeros()
        );
        assert!(["amd", "nested dissection", "metis"].contains(&f.ordering));
    }

    /// METIS's order is the same when other threads order graphs at the same time (its random
    /// numbers are one state for the whole process; two static solves at once, as the tests
    /// of one binary or the runs of a sweep, drew from it in turn and got other orders).
    #[test]
    fn the_metis_order_is_the_same_while_other_threads_order() {
        let model = anp_box();
        let n = model.nodes.len();
        let k = Tangent::new(&model, &[], true);
        let alone = metis_node_order(&k, n).expect("METIS orders a mesh graph");
        let differ = std::thread::scope(|scope| {
            let runs: Vec<_> = (0..4)
                .map(|_| {
                    scope.spawn(|| {
                        (0..10)
                            .filter(|_| metis_node_order(&k, n).as_ref() != Some(&alone))
                            .count()
                    })
                })
                .collect();
            runs.into_iter().map(|r| r.join().unwrap()).sum::<usize>()
        });
        assert_eq!(differ, 0, "{differ} of 40 orders differed");
    }
}
