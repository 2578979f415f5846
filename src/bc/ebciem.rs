//! Essential boundary conditions on meshless nodes (thesis chapter 4): SEBCIEM and EBCIEM.
//!
//! Meshless shape functions are not interpolating: prescribing the nodal parameters of the
//! constrained nodes does not make the interpolated displacement equal the prescribed value
//! there. Both methods instead correct the explicit predictor every step, per displacement
//! component (thesis eq. 4.21-4.24):
//!
//! `u = u_pred + M^-1 V [Phi M^-1 V]^-1 (u_bar - Phi u_pred)`
//!
//! with `Phi_kj = phi_j(x_k)` (shape functions of all N nodes at the ne constrained nodes),
//! `M` the diagonal lumped mass matrix, and `V` the boundary-force interpolation matrix:
//! `V = Phi^T` for SEBCIEM (eq. 4.30, forces lumped at the constrained nodes) or the
//! boundary integral of eq. 4.12 for EBCIEM (see [`ebciem_columns`]).
//!
//! The ne x ne matrix `A = Phi M^-1 V` is constant in a Total Lagrangian run, so it is factored
//! once (sparse LU with partial pivoting; it is nonsymmetric for EBCIEM) and each step costs two
//! sparse products and one pair of triangular solves. `M^-1 V A^-1` is never formed: it would be
//! dense N x ne.

use faer::sparse::{SparseColMat, Triplet};
use nalgebra::Vector3;

use super::sparse_lu::{FactorError, SparseLu, LANES};

use crate::{Error, InputKind, Result};

// `ComponentCorrection::correct_component` addresses node j's component c as f64 number 3 j + c.
const _: () = assert!(std::mem::size_of::<Vector3<f64>>() == 3 * std::mem::size_of::<f64>());

use crate::quadrature::SparseRow;

/// Estimated 1-norm condition numbers of `A = Phi M^-1 V` above this are treated as singular:
/// the correction would amplify the rounding of the residual `u_bar - Phi u_pred` by as much,
/// which leaves fewer than ~4 significant digits in the imposed values.
const MAX_CONDITION: f64 = 1e12;

const AXIS: [&str; 3] = ["x", "y", "z"];

/// Sorts by node id and sums duplicate entries, so equal inputs give bitwise equal outputs
/// whatever order the entries came in (the stable sort keeps the summation order of duplicates
/// the input order, which is itself deterministic).
fn canonical(mut v: SparseRow) -> SparseRow {
    v.sort_by_key(|&(j, _)| j);
    let mut out: SparseRow = Vec::with_capacity(v.len());
    for (j, x) in v {
        match out.last_mut() {
            Some(last) if last.0 == j => last.1 += x,
            _ => out.push((j, x)),
        }
    }
    out
}

/// Compressed storage of ne sparse vectors over the N nodes (rows of Phi or columns of V).
#[derive(Debug, Clone, PartialEq)]
struct Compressed {
    ptr: Vec<usize>,
    idx: Vec<u32>,
    val: Vec<f64>,
}

impl Compressed {
    fn from_vecs(vecs: Vec<SparseRow>) -> Self {
        let mut ptr = Vec::with_capacity(vecs.len() + 1);
        ptr.push(0);
        let nnz: usize = vecs.iter().map(Vec::len).sum();
        let mut idx = Vec::with_capacity(nnz);
        let mut val = Vec::with_capacity(nnz);
        for v in vecs {
            for (j, x) in canonical(v) {
                idx.push(j);
                val.push(x);
            }
            ptr.push(idx.len());
        }
        Compressed { ptr, idx, val }
    }

    #[inline]
    fn range(&self, k: usize) -> std::ops::Range<usize> {
        self.ptr[k]..self.ptr[k + 1]
    }
}

/// Components one solve can serve together ([`ComponentCorrection::solve_shared`]): x, y, z.
pub const MAX_SHARED: usize = 3;
const _: () = assert!(MAX_SHARED <= LANES);

/// The essential-boundary correction of one displacement component (thesis eq. 4.21-4.24),
/// with `A = Phi M^-1 V` factored once at construction.
///
/// Works for SEBCIEM (`V = Phi^T`, eq. 4.30; see [`ComponentCorrection::sebciem`]) and EBCIEM
/// (`V` from the boundary integral of eq. 4.12; see [`ebciem_columns`]).
#[derive(Clone)]
pub struct ComponentCorrection {
    component: usize,
    nodes: Vec<usize>,
    num_nodes: usize,
    /// Rows of Phi (one per constrained node), canonical.
    phi: Compressed,
    /// Columns of V (one per constrained node), canonical.
    v: Compressed,
    /// `V_jk / m_j` in the layout of `v`, so the per-step update needs no division.
    minv_v: Vec<f64>,
    /// Column sums `s_k = sum_j V_jk` (dimensionless for SEBCIEM, m^2 for EBCIEM).
    col_sum: Vec<f64>,
    /// `None` when no node is constrained in this component.
    factor: Option<SparseLu>,
    /// Solve scratch (ne rows), allocated once so `correct` does not allocate.
    work: Vec<[f64; LANES]>,
    /// Multipliers `y = A^-1 (u_bar - Phi u_pred)` of the last `correct` (zero before).
    y: Vec<f64>,
    /// Estimated 1-norm condition number of A (0 when ne = 0).
    cond: f64,
}

impl std::fmt::Debug for ComponentCorrection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ComponentCorrection")
            .field("component", &self.component)
            .field("constrained_nodes", &self.nodes.len())
            .field("num_nodes", &self.num_nodes)
            .field("phi_nnz", &self.phi.idx.len())
            .field("v_nnz", &self.v.idx.len())
            .finish_non_exhaustive()
    }
}

impl ComponentCorrection {
    /// Builds and factors the correction of displacement component `component` (0 = x, 1 = y,
    /// 2 = z).
    ///
    /// - `nodes`: the ne constrained node ids; they order the rows of Phi and the columns of V.
    /// - `phi_rows[k]`: `phi_j(x_k)` for the support nodes j of constrained node `nodes[k]`
    ///   (dimensionless; the rows of Phi, eq. 4.19).
    /// - `v_cols[k]`: column k of V (dimensionless for SEBCIEM, eq. 4.30; m^2 for EBCIEM,
    ///   eq. 4.12).
    /// - `mass`: lumped masses of all N nodes, kg.
    ///
    /// Duplicate entries within a row or column are summed.
    ///
    /// # Errors
    /// [`Error::Input`] when the component is not 0-2, the sizes disagree, a node index is out
    /// of range, a constrained node is listed twice, a value is not finite, a mass is not
    /// positive, a row of Phi or column of V is empty, or `A = Phi M^-1 V` (eq. 4.24) is
    /// singular or numerically singular.
    pub fn new(
        component: usize,
        nodes: Vec<usize>,
        phi_rows: Vec<SparseRow>,
        v_cols: Vec<SparseRow>,
        mass: &[f64],
    ) -> Result<Self> {
        if component > 2 {
            return Err(Error::input(InputKind::Discretization, format!(
                "essential boundary correction: component {component} does not exist; use 0 (x), 1 (y) or 2 (z)"
            )));
        }
        let axis = AXIS[component];
        let ne = nodes.len();
        let n = mass.len();
        if phi_rows.len() != ne || v_cols.len() != ne {
            return Err(Error::input(InputKind::Discretization, format!(
                "essential boundary correction ({axis}): {ne} constrained nodes but {} shape-function rows and {} boundary-force columns; \
                 give one row and one column per constrained node",
                phi_rows.len(),
                v_cols.len()
            )));
        }
        if let Some((j, &m)) = mass
            .iter()
            .enumerate()
            .find(|(_, &m)| !(m > 0.0 && m.is_finite()))
        {
            return Err(Error::input(InputKind::Discretization, format!(
                "essential boundary correction ({axis}): node {j} has lumped mass {m} kg; every node needs a positive finite mass \
                 (check that the node lies inside a quadrature cell and that the density is positive)"
            )).node(j));
        }
        // Repeated ids would make two identical rows of A; say so directly rather than
        // reporting a singular matrix.
        let mut seen = vec![false; n];
        for &node in &nodes {
            if node >= n {
                return Err(Error::input(InputKind::Discretization, format!(
                    "essential boundary correction ({axis}): constrained node {node} is out of range (the model has {n} nodes)"
                )).node(node));
            }
            if std::mem::replace(&mut seen[node], true) {
                return Err(Error::input(InputKind::Discretization, format!(
                    "essential boundary correction ({axis}): node {node} is listed twice among the constrained nodes; \
                     list each constrained node once"
                )).node(node));
            }
        }
        for (what, vecs) in [
            ("shape-function row", &phi_rows),
            ("boundary-force column", &v_cols),
        ] {
            for (k, vec) in vecs.iter().enumerate() {
                if vec.is_empty() {
                    return Err(Error::input(InputKind::Discretization, format!(
                        "essential boundary correction ({axis}): the {what} of constrained node {} is empty; \
                         the node must lie in the support of some nodes (and, for EBCIEM, on a boundary triangle)",
                        nodes[k]
                    )).node(nodes[k]));
                }
                if let Some(&(j, x)) = vec
                    .iter()
                    .find(|&&(j, x)| j as usize >= n || !x.is_finite())
                {
                    return Err(Error::input(InputKind::Discretization, format!(
                        "essential boundary correction ({axis}): the {what} of constrained node {} has entry ({j}, {x}); \
                         node ids must be below {n} and values finite",
                        nodes[k]
                    )).node(nodes[k]));
                }
            }
        }

        let phi = Compressed::from_vecs(phi_rows);
        let v = Compressed::from_vecs(v_cols);
        let minv_v: Vec<f64> = v
            .idx
            .iter()
            .zip(&v.val)
            .map(|(&j, &x)| x / mass[j as usize])
            .collect();
        let col_sum: Vec<f64> = (0..ne).map(|k| v.val[v.range(k)].iter().sum()).collect();

        let mut this = ComponentCorrection {
            component,
            nodes,
            num_nodes: n,
            phi,
            v,
            minv_v,
            col_sum,
            factor: None,
            work: Vec::new(),
            y: vec![0.0; ne],
            cond: 0.0,
        };
        if ne > 0 {
            this.factorize()?;
        }
        Ok(this)
    }

    /// SEBCIEM (thesis section 4.3.1): the boundary force is lumped at the constrained nodes,
    /// so `V = Phi^T` (eq. 4.30). Arguments and errors as [`ComponentCorrection::new`].
    pub fn sebciem(
        component: usize,
        nodes: Vec<usize>,
        phi_rows: Vec<SparseRow>,
        mass: &[f64],
    ) -> Result<Self> {
        let v_cols = phi_rows.clone();
        Self::new(component, nodes, phi_rows, v_cols, mass)
    }

    /// Assembles `A = Phi M^-1 V`, factors it, and rejects it when (numerically) singular.
    fn factorize(&mut self) -> Result<()> {
        let ne = self.nodes.len();
        let n = self.num_nodes;
        let axis = AXIS[self.component];
        let singular = |detail: String| {
            Error::input(InputKind::Discretization, format!(
                "essential boundary correction ({axis}): the {ne} x {ne} matrix Phi M^-1 V (thesis eq. 4.24) for the {ne} constrained nodes \
                 is singular ({detail}); likely causes: constrained nodes closer together than the shape-function support spacing \
                 (their shape-function rows are nearly identical), or two constrained nodes at the same position; \
                 thin out the constrained nodes or refine the node spacing there"
            ))
        };

        // Phi^T by counting sort: column l of A needs, for each node j of V's column l, the
        // constrained rows k whose support contains j.
        let mut t_ptr = vec![0usize; n + 1];
        for &j in &self.phi.idx {
            t_ptr[j as usize + 1] += 1;
        }
        for j in 0..n {
            t_ptr[j + 1] += t_ptr[j];
        }
        let mut fill = t_ptr.clone();
        let mut t_row = vec![0usize; self.phi.idx.len()];
        let mut t_val = vec![0.0; self.phi.idx.len()];
        for k in 0..ne {
            for p in self.phi.range(k) {
                let j = self.phi.idx[p] as usize;
                t_row[fill[j]] = k;
                t_val[fill[j]] = self.phi.val[p];
                fill[j] += 1;
            }
        }

        let mut acc = vec![0.0; ne];
        let mut marked = vec![false; ne];
        let mut touched: Vec<usize> = Vec::new();
        let mut triplets: Vec<Triplet<usize, usize, f64>> = Vec::new();
        let mut a_norm = 0.0f64;
        for l in 0..ne {
            for p in self.v.range(l) {
                let j = self.v.idx[p] as usize;
                let w = self.minv_v[p];
                for q in t_ptr[j]..t_ptr[j + 1] {
                    let k = t_row[q];
                    if !marked[k] {
                        marked[k] = true;
                        touched.push(k);
                    }
                    acc[k] += t_val[q] * w;
                }
            }
            touched.sort_unstable();
            let mut col_norm = 0.0;
            for &k in &touched {
                triplets.push(Triplet::new(k, l, acc[k]));
                col_norm += acc[k].abs();
                acc[k] = 0.0;
                marked[k] = false;
            }
            a_norm = a_norm.max(col_norm);
            touched.clear();
        }

        let a =
            SparseColMat::<usize, f64>::try_new_from_triplets(ne, ne, &triplets).map_err(|e| {
                Error::input(
                    InputKind::Discretization,
                    format!("essential boundary correction: cannot assemble Phi M^-1 V: {e:?}"),
                )
            })?;
        let factor = SparseLu::factor(a.as_ref()).map_err(|e| match e {
            FactorError::StructurallySingular(index) => singular(format!(
                "structurally: no pivot at elimination step {index}"
            )),
            FactorError::OutOfMemory => Error::input(
                InputKind::Limit,
                format!(
                    "essential boundary correction: out of memory factoring a {ne} x {ne} matrix"
                ),
            ),
            FactorError::Other(e) => Error::input(
                InputKind::Discretization,
                format!(
                    "essential boundary correction: LU factorization of Phi M^-1 V failed: {e}"
                ),
            ),
        })?;
        self.factor = Some(factor);
        self.work = vec![[0.0; LANES]; ne];

        // faer does not report numerically zero pivots (it divides by them), so estimate the
        // condition number and reject what cannot be trusted.
        let inv_norm = self.estimate_inverse_norm1();
        let cond = a_norm * inv_norm;
        if !(cond.is_finite() && cond <= MAX_CONDITION) {
            return Err(singular(format!(
                "estimated 1-norm condition number {sci_cond:.3e}",
                sci_cond = crate::error::Sci(cond)
            )));
        }
        self.cond = cond;
        Ok(())
    }

    /// Estimates `||A^-1||_1` with Hager's method as refined by Higham (1988, Algorithm 4.1):
    /// a few solves with A and A^T instead of the inverse. Returns infinity when a solve
    /// produces non-finite values (an exactly zero pivot).
    fn estimate_inverse_norm1(&mut self) -> f64 {
        let ne = self.nodes.len();
        let Some(factor) = self.factor.as_ref() else {
            return 0.0;
        };
        let work = &mut self.work;
        let mut scratch = vec![0.0; ne];
        let norm1 = |x: &[f64]| x.iter().map(|v| v.abs()).sum::<f64>();
        let mut x = vec![1.0 / ne as f64; ne];
        let mut z = vec![0.0; ne];
        let mut est = 0.0f64;
        let mut last_unit = 0usize;
        for iter in 0..5 {
            factor.solve(&mut x, 1, work);
            let new_est = norm1(&x);
            if !new_est.is_finite() {
                return f64::INFINITY;
            }
            if iter > 0 && new_est <= est {
                break;
            }
            est = new_est;
            for (zi, &xi) in z.iter_mut().zip(&x) {
                *zi = if xi >= 0.0 { 1.0 } else { -1.0 };
            }
            factor.solve_transpose(&mut z, &mut scratch);
            // Stop when no unit vector promises a larger estimate: z^T x for the current unit
            // vector x = e_j is z_j.
            let (jmax, zmax) = z
                .iter()
                .enumerate()
                .fold((0usize, -1.0f64), |(bj, bv), (j, &v)| {
                    if v.abs() > bv {
                        (j, v.abs())
                    } else {
                        (bj, bv)
                    }
                });
            if !zmax.is_finite() {
                return f64::INFINITY;
            }
            if iter > 0 && zmax <= z[last_unit] {
                break;
            }
            last_unit = jmax;
            x.fill(0.0);
            x[jmax] = 1.0;
        }
        // Alternating test vector catches matrices where the power-like iteration stalls.
        let denom = if ne > 1 { (ne - 1) as f64 } else { 1.0 };
        for (i, xi) in x.iter_mut().enumerate() {
            let s = if i % 2 == 0 { 1.0 } else { -1.0 };
            *xi = s * (1.0 + i as f64 / denom);
        }
        factor.solve(&mut x, 1, work);
        let alt = 2.0 * norm1(&x) / (3.0 * ne as f64);
        if !alt.is_finite() {
            return f64::INFINITY;
        }
        est.max(alt)
    }

    /// The displacement component this correction constrains (0 = x, 1 = y, 2 = z).
    pub fn component(&self) -> usize {
        self.component
    }

    /// Row `k` of Phi: (node, phi_j(x_k)) of constrained node `k`'s support.
    pub fn phi_row(&self, k: usize) -> Vec<(u32, f64)> {
        let r = self.phi.range(k);
        self.phi.idx[r.clone()]
            .iter()
            .copied()
            .zip(self.phi.val[r].iter().copied())
            .collect()
    }

    /// Column `k` of V: (node, V_jk) carrying constrained node `k`'s boundary force
    /// (dimensionless for SEBCIEM, m^2 for EBCIEM, eq. 4.12).
    pub fn v_column(&self, k: usize) -> Vec<(u32, f64)> {
        let r = self.v.range(k);
        self.v.idx[r.clone()]
            .iter()
            .copied()
            .zip(self.v.val[r].iter().copied())
            .collect()
    }

    /// Whether V is Phi^T (SEBCIEM, eq. 4.30): the constraint forces are spread by the shape
    /// functions themselves.
    pub fn is_lumped(&self) -> bool {
        self.phi == self.v
    }

    /// The constrained node ids, in the order of the rows of Phi and the columns of V.
    pub fn nodes(&self) -> &[usize] {
        &self.nodes
    }

    /// Estimated 1-norm condition number of `A = Phi M^-1 V` (eq. 4.24), for diagnostics; 0
    /// when no node is constrained. Construction fails above 1e12.
    pub fn condition_estimate(&self) -> f64 {
        self.cond
    }

    /// The nodes the constraint force acts on (the row indices of V), unsorted, with repeats.
    pub fn forced_nodes(&self) -> impl Iterator<Item = usize> + '_ {
        self.v.idx.iter().map(|&j| j as usize)
    }

    /// Number of nodes N of the model the correction was built for.
    pub fn num_nodes(&self) -> usize {
        self.num_nodes
    }

    /// Column sums `s_k = sum_j V_jk`: the total nodal force that a unit multiplier of column k
    /// applies (dimensionless for SEBCIEM, where they equal 1 for partition-of-unity shape
    /// functions; m^2 for EBCIEM, where they are the boundary area attributed to node k).
    pub fn column_sums(&self) -> &[f64] {
        &self.col_sum
    }

    /// The multipliers `y = [Phi M^-1 V]^-1 (u_bar - Phi u_pred)` of the last
    /// [`correct`](Self::correct) (kg m for SEBCIEM, kg/m for EBCIEM, so that `M^-1 V y` is a
    /// displacement and `V y / alpha` a force); zero before the first call. `T_e = y / alpha` is
    /// the boundary force of eq. 4.11.
    pub fn multipliers(&self) -> &[f64] {
        &self.y
    }

    /// Applies the correction of thesis eq. 4.21-4.23 in place: `u` holds the predicted
    /// displacements of all N nodes (m; only component [`component`](Self::component) is read
    /// and changed), `target[k]` the prescribed value at `nodes()[k]` (m). Afterwards
    /// `sum_j phi_j(x_k) u_j = target[k]` to rounding. Stores the multipliers for
    /// [`constraint_force`](Self::constraint_force). Does not allocate.
    ///
    /// # Panics
    /// If `u.len()` is not N or `target.len()` is not ne (a caller bug, not an input error).
    pub fn correct(&mut self, u: &mut [Vector3<f64>], target: &[f64]) {
        let ne = self.nodes.len();
        assert!(
            u.len() == self.num_nodes && target.len() == ne,
            "ComponentCorrection::correct: got {} displacements and {} targets, expected {} and {ne}",
            u.len(),
            target.len(),
            self.num_nodes
        );
        // SAFETY: u holds num_nodes vectors (checked) and is borrowed mutably for the call.
        unsafe { self.correct_component(u.as_mut_ptr() as *mut f64, target) }
    }

    /// [`correct`](Self::correct) on raw storage: `u` points at N contiguous `Vector3<f64>`
    /// (3 f64 each), of which only component [`component`](Self::component) is read and
    /// written, so the corrections of different components can run at the same time.
    ///
    /// # Safety
    /// `u` must point at N = [`num_nodes`](Self::num_nodes) vectors, and no other thread may
    /// access this component of them during the call. `target.len()` must be ne.
    pub unsafe fn correct_component(&mut self, u: *mut f64, target: &[f64]) {
        let Some(factor) = self.factor.as_ref() else {
            return;
        };
        let mut y = std::mem::take(&mut self.y);
        self.residual(u, target, &mut y);
        factor.solve(&mut y, 1, &mut self.work);
        self.y = y;
        self.apply(u);
    }

    /// This correction for displacement component `component` (0 = x, 1 = y, 2 = z) instead:
    /// the same constrained nodes, Phi, V and factors, without factoring A again (the brain's
    /// 2,186 constrained nodes took 0.16 s per factorization).
    ///
    /// # Panics
    /// If `component` is not 0-2 (a caller bug).
    pub fn for_component(&self, component: usize) -> Self {
        assert!(
            component <= 2,
            "ComponentCorrection::for_component({component})"
        );
        let mut c = self.clone();
        c.component = component;
        c.y.fill(0.0);
        c
    }

    /// Whether `other` has the same system `A = Phi M^-1 V`: the same constrained nodes, Phi
    /// and V (with SEBCIEM, every component constrained on the same nodes), so one factor
    /// serves both ([`Self::solve_shared`]).
    pub fn same_system(&self, other: &Self) -> bool {
        self.nodes == other.nodes
            && self.phi == other.phi
            && self.v == other.v
            && self.minv_v == other.minv_v
    }

    /// [`Self::correct_component`] of up to [`MAX_SHARED`] components with the same system
    /// ([`Self::same_system`]): the residuals of all of them in one pass over Phi, one solve
    /// of as many columns with the first one's factor (the columns ride in the lanes of one
    /// substitution), then the updates in one pass over V. Each value is computed with the
    /// operations, in the order, of the separate corrections, so the results are bitwise
    /// theirs. `rhs` is scratch of ne x (number of components). The update also adds each
    /// component's constraint forces `(V y)_j / alpha` (N) into `nodal` (N vectors, as `u`),
    /// with the arithmetic of [`Self::add_nodal_forces`]. All on the calling thread: one task
    /// per component ran slower on two threads (they wrote the x, y and z of the same nodes,
    /// one cache line, from both cores), and the time loop keeps its second thread spinning
    /// meanwhile.
    ///
    /// # Safety
    /// As [`Self::correct_component`] for each of `comps`, which constrain distinct components
    /// and share the first one's system (the caller checks [`Self::same_system`] once);
    /// `nodal` must point at N vectors that no other thread accesses during the call.
    ///
    /// # Panics
    /// If there are more than MAX_SHARED components, or `targets` or `rhs` do not fit.
    pub unsafe fn solve_shared(
        comps: &mut [&mut ComponentCorrection],
        u: *mut f64,
        targets: &[&[f64]],
        rhs: &mut [f64],
        nodal: *mut f64,
        alpha: f64,
    ) {
        let k = comps.len();
        assert!(k <= MAX_SHARED && targets.len() == k);
        let Some(ne) = comps.first().map(|c| c.nodes.len()) else {
            return;
        };
        assert!(targets.iter().all(|t| t.len() == ne));
        let rhs = &mut rhs[..ne * k];
        let mut axes = [0usize; MAX_SHARED];
        for (a, c) in axes.iter_mut().zip(comps.iter()) {
            *a = c.component;
        }
        let axes = &axes[..k];
        let lead = &mut *comps[0];
        for row in 0..ne {
            let r = lead.phi.range(row);
            let mut interp = [-0.0; MAX_SHARED];
            for (&j, &p) in lead.phi.idx[r.clone()].iter().zip(&lead.phi.val[r]) {
                let uj = u.add(3 * j as usize);
                for (s, &c) in interp.iter_mut().zip(axes) {
                    *s += p * *uj.add(c);
                }
            }
            for (ci, t) in targets.iter().enumerate() {
                rhs[ci * ne + row] = t[row] - interp[ci];
            }
        }
        let Some(factor) = lead.factor.as_ref() else {
            return;
        };
        factor.solve(rhs, k, &mut lead.work);
        for (c, r) in comps.iter_mut().zip(rhs.chunks_exact(ne)) {
            c.y.copy_from_slice(r);
        }
        let lead = &*comps[0];
        for row in 0..ne {
            let mut y = [0.0; MAX_SHARED];
            let mut f = [0.0; MAX_SHARED];
            for ci in 0..k {
                y[ci] = rhs[ci * ne + row];
                f[ci] = y[ci] / alpha;
            }
            for p in lead.v.range(row) {
                let j = 3 * lead.v.idx[p] as usize;
                let (m, v) = (lead.minv_v[p], lead.v.val[p]);
                for (ci, &c) in axes.iter().enumerate() {
                    *u.add(j + c) += m * y[ci];
                    *nodal.add(j + c) += v * f[ci];
                }
            }
        }
    }

    /// `out[k] = target[k] - sum_j Phi_kj u_j` for this component (m).
    ///
    /// # Safety
    /// As [`Self::correct_component`] (read only).
    unsafe fn residual(&self, u: *const f64, target: &[f64], out: &mut [f64]) {
        let c = self.component;
        for (k, (o, &t)) in out.iter_mut().zip(target).enumerate() {
            let r = self.phi.range(k);
            // From -0.0, like `Iterator::sum`, and in the order of `solve_shared`.
            let interp = self.phi.idx[r.clone()]
                .iter()
                .zip(&self.phi.val[r])
                .fold(-0.0, |s, (&j, &p)| s + p * *u.add(3 * j as usize + c));
            *o = t - interp;
        }
    }

    /// The nodes whose displacement a correction reads (the supports of the constrained
    /// nodes, Phi's columns) or writes (V's rows), with repeats.
    pub fn touched_nodes(&self) -> impl Iterator<Item = u32> + '_ {
        self.phi.idx.iter().chain(&self.v.idx).copied()
    }

    /// `u += M^-1 V y` for this component with the stored multipliers (m).
    ///
    /// # Safety
    /// As [`Self::correct_component`].
    unsafe fn apply(&self, u: *mut f64) {
        let c = self.component;
        for (k, &yk) in self.y.iter().enumerate() {
            for p in self.v.range(k) {
                *u.add(3 * self.v.idx[p] as usize + c) += self.minv_v[p] * yk;
            }
        }
    }

    /// After [`correct`](Self::correct): the force (N) this component's constraint applied to
    /// the body, summed over all nodes, from the columns `columns` (indices into
    /// [`nodes`](Self::nodes)), i.e. `sum_{k in columns} s_k y_k / alpha`. `alpha` is the force
    /// coefficient of the integrator (s^2 per unit of M^-1 F: `u_next = alpha M^-1 F + ...`,
    /// thesis eq. 4.17). Equals `sum_j m_j (u_j - u_pred_j) / alpha` over those columns'
    /// contributions.
    ///
    /// # Panics
    /// If a column index is not below ne (a caller bug).
    pub fn constraint_force(&self, columns: &[usize], alpha: f64) -> f64 {
        columns
            .iter()
            .map(|&k| self.col_sum[k] * self.y[k])
            .sum::<f64>()
            / alpha
    }

    /// After [`correct`](Self::correct): adds the constraint force on every node, `(V y)_j /
    /// alpha` (N; thesis eq. 4.11 with `T_e = y / alpha`), into `out[j][component]`, e.g. for
    /// external-work accounting.
    ///
    /// # Panics
    /// If `out.len()` is not N (a caller bug).
    pub fn add_nodal_forces(&self, out: &mut [Vector3<f64>], alpha: f64) {
        assert!(
            out.len() == self.num_nodes,
            "ComponentCorrection::add_nodal_forces: got {} nodes, expected {}",
            out.len(),
            self.num_nodes
        );
        let c = self.component;
        for (k, &yk) in self.y.iter().enumerate() {
            let f = yk / alpha;
            for p in self.v.range(k) {
                out[self.v.idx[p] as usize][c] += self.v.val[p] * f;
            }
        }
    }

    /// Interpolated values `sum_j Phi_kj u_j` (m) of this component at each constrained node, in
    /// the order of [`nodes`](Self::nodes), written to `out` (cleared first); for checking the
    /// imposition (eq. 4.19).
    ///
    /// # Panics
    /// If `u.len()` is not N (a caller bug).
    pub fn interpolate(&self, u: &[Vector3<f64>], out: &mut Vec<f64>) {
        assert!(
            u.len() == self.num_nodes,
            "ComponentCorrection::interpolate: got {} nodes, expected {}",
            u.len(),
            self.num_nodes
        );
        let c = self.component;
        out.clear();
        out.extend((0..self.nodes.len()).map(|k| {
            let r = self.phi.range(k);
            self.phi.idx[r.clone()]
                .iter()
                .zip(&self.phi.val[r])
                .map(|(&j, &p)| p * u[j as usize][c])
                .sum::<f64>()
        }));
    }
}

/// The corrections of all constrained components together (each component has its own
/// constrained nodes and its own factored `A`, thesis eq. 4.24).
#[derive(Debug, Default)]
pub struct EssentialCorrection {
    pub components: Vec<ComponentCorrection>,
}

impl EssentialCorrection {
    /// Groups per-component corrections.
    ///
    /// # Errors
    /// [`Error::Input`] when two corrections constrain the same component or were built for
    /// models with different node counts.
    pub fn new(components: Vec<ComponentCorrection>) -> Result<Self> {
        for (i, a) in components.iter().enumerate() {
            for b in &components[..i] {
                if a.component == b.component {
                    return Err(Error::input(InputKind::Discretization, format!(
                        "essential boundary correction: component {} is given twice; merge its constrained nodes into one correction",
                        AXIS[a.component]
                    )));
                }
                if a.num_nodes != b.num_nodes {
                    return Err(Error::input(InputKind::Discretization, format!(
                        "essential boundary correction: components {} and {} were built for {} and {} nodes",
                        AXIS[b.component], AXIS[a.component], b.num_nodes, a.num_nodes
                    )));
                }
            }
        }
        Ok(EssentialCorrection { components })
    }

    /// Applies every component's correction (thesis eq. 4.22) to the predicted displacements
    /// `u` (m); `targets[i]` are the prescribed values (m) for `components[i]`, in the order of
    /// its nodes. Components are independent, so the order of application does not matter.
    ///
    /// # Panics
    /// If `targets.len()` differs from the number of components, or on a size mismatch of
    /// [`ComponentCorrection::correct`] (caller bugs).
    pub fn correct(&mut self, u: &mut [Vector3<f64>], targets: &[Vec<f64>]) {
        assert!(
            targets.len() == self.components.len(),
            "EssentialCorrection::correct: {} target vectors for {} components",
            targets.len(),
            self.components.len()
        );
        for (c, t) in self.components.iter_mut().zip(targets) {
            c.correct(u, t);
        }
    }

    /// After [`correct`](Self::correct): the total force (N) all constraints applied to the
    /// body, per component (`alpha` as in [`ComponentCorrection::constraint_force`]).
    pub fn total_force(&self, alpha: f64) -> Vector3<f64> {
        let mut f = Vector3::zeros();
        for c in &self.components {
            f[c.component] += c.col_sum.iter().zip(&c.y).map(|(s, y)| s * y).sum::<f64>() / alpha;
        }
        f
    }

    /// After [`correct`](Self::correct): adds every component's nodal constraint forces (N)
    /// into `out` (see [`ComponentCorrection::add_nodal_forces`]).
    pub fn add_nodal_forces(&self, out: &mut [Vector3<f64>], alpha: f64) {
        for c in &self.components {
            c.add_nodal_forces(out, alpha);
        }
    }

    /// Largest `|sum_j Phi_kj u_j - target_k|` (m) over all components and constrained nodes:
    /// how well `u` satisfies the essential conditions (eq. 4.19). Allocates; for checks.
    pub fn max_imposition_error(&self, u: &[Vector3<f64>], targets: &[Vec<f64>]) -> f64 {
        let mut buf = Vec::new();
        let mut worst = 0.0f64;
        for (c, t) in self.components.iter().zip(targets) {
            c.interpolate(u, &mut buf);
            for (a, b) in buf.iter().zip(t) {
                worst = worst.max((a - b).abs());
            }
        }
        worst
    }
}

/// Builds the columns of V for EBCIEM (thesis eq. 4.12):
/// `V_jk = sum_g phi_j(s_g) N_k(s_g) w_g`, integrating over the triangulated essential boundary
/// with the 3-point rule per triangle (barycentric points (2/3, 1/6, 1/6) and permutations,
/// weights area/3; exact for polynomials of degree 2) and `N_k` the linear hat function of
/// boundary vertex k.
///
/// - `nodes`: the constrained node ids (global); the returned columns follow this order.
/// - `positions`: reference positions of all N nodes, m.
/// - `tris`: boundary triangles as global node ids; every vertex must be in `nodes`.
/// - `shape_at(&x)`: the meshless shape functions `phi_j(x)` at a boundary point x (m) for the
///   nodes j of its support.
///
/// Columns are canonical (sorted by node id, duplicates summed) and have units of m^2;
/// degenerate (zero-area) triangles contribute nothing.
///
/// # Errors
/// [`Error::Input`] when a node id is out of range or repeated in `nodes`, a triangle vertex is
/// not a constrained node, a position is not finite, a constrained node belongs to no
/// triangle of positive area, `shape_at` fails, or it returns an out-of-range node or a
/// non-finite value.
pub fn ebciem_columns(
    nodes: &[usize],
    positions: &[Vector3<f64>],
    tris: &[[usize; 3]],
    shape_at: impl Fn(&Vector3<f64>) -> Result<SparseRow>,
) -> Result<Vec<SparseRow>> {
    let n = positions.len();
    // Global id -> column; a dense map keeps the lookup deterministic and O(1).
    let mut column = vec![usize::MAX; n];
    for (k, &node) in nodes.iter().enumerate() {
        if node >= n {
            return Err(Error::input(
                InputKind::Discretization,
                format!(
                "EBCIEM boundary: constrained node {node} is out of range (the model has {n} nodes)"
            ),
            )
            .node(node));
        }
        if column[node] != usize::MAX {
            return Err(Error::input(InputKind::Discretization, format!(
                "EBCIEM boundary: node {node} is listed twice among the constrained nodes; list each once"
            )).node(node));
        }
        column[node] = k;
    }
    const BARY: [[f64; 3]; 3] = [
        [2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0],
        [1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0],
        [1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0],
    ];
    let mut cols: Vec<SparseRow> = vec![Vec::new(); nodes.len()];
    for (t, tri) in tris.iter().enumerate() {
        let mut ks = [0usize; 3];
        for (slot, &v) in ks.iter_mut().zip(tri) {
            match column.get(v) {
                Some(&k) if k != usize::MAX => *slot = k,
                _ => {
                    return Err(Error::input(InputKind::Discretization, format!(
                        "EBCIEM boundary: vertex {v} of boundary triangle {t} is not a constrained node; \
                         the essential boundary triangulation must use only constrained nodes"
                    )).node(v))
                }
            }
        }
        let p = tri.map(|v| positions[v]);
        if p.iter().any(|x| !x.iter().all(|c| c.is_finite())) {
            return Err(Error::input(
                InputKind::Discretization,
                format!("EBCIEM boundary: boundary triangle {t} has a non-finite vertex position"),
            ));
        }
        let area = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
        if !(area > 0.0) {
            continue;
        }
        let w = area / 3.0;
        for lam in &BARY {
            let x = p[0] * lam[0] + p[1] * lam[1] + p[2] * lam[2];
            let phi = shape_at(&x)?;
            if let Some(&(j, val)) = phi
                .iter()
                .find(|&&(j, val)| j as usize >= n || !val.is_finite())
            {
                return Err(Error::input(InputKind::Discretization, format!(
                    "EBCIEM boundary: shape functions at a Gauss point of boundary triangle {t} contain entry ({j}, {val}); \
                     node ids must be below {n} and values finite"
                )));
            }
            for (&k, &nk) in ks.iter().zip(lam) {
                cols[k].extend(phi.iter().map(|&(j, val)| (j, val * nk * w)));
            }
        }
    }
    if let Some(k) = cols.iter().position(Vec::is_empty) {
        return Err(Error::input(InputKind::Discretization, format!(
            "EBCIEM boundary: constrained node {} belongs to no boundary triangle of positive area; \
             triangulate the whole essential boundary or use SEBCIEM",
            nodes[k]
        )).node(nodes[k]));
    }
    Ok(cols.into_iter().map(canonical).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random numbers (splitmix64), so the tests need no extra crates.
    struct Rng(u64);
    impl Rng {
        fn next_f64(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64
        }
        /// Uniform in [-1, 1).
        fn sym(&mut self) -> f64 {
            2.0 * self.next_f64() - 1.0
        }
    }

    const H: f64 = 0.01;

    /// 3 x 3 x 4 grid of spacing H (m); the z = 0 layer (nodes 0..9) is exact, the layers above
    /// are jittered so no symmetry hides a bug.
    fn box_nodes(rng: &mut Rng) -> Vec<Vector3<f64>> {
        let mut p = Vec::new();
        for k in 0..4 {
            for j in 0..3 {
                for i in 0..3 {
                    let mut x = Vector3::new(i as f64 * H, j as f64 * H, k as f64 * H);
                    if k > 0 {
                        x += Vector3::new(rng.sym(), rng.sym(), rng.sym()) * 0.15 * H;
                    }
                    p.push(x);
                }
            }
        }
        p
    }

    /// Smooth, non-interpolating partition of unity: normalised quartic weights
    /// (1 - (r/R)^2)^2 over the nodes within R = 1.6 H.
    fn shape(pos: &[Vector3<f64>], x: &Vector3<f64>) -> Result<SparseRow> {
        let r = 1.6 * H;
        let mut out: SparseRow = pos
            .iter()
            .enumerate()
            .filter_map(|(j, p)| {
                let q = (p - x).norm_squared() / (r * r);
                (q < 1.0).then_some((j as u32, (1.0 - q) * (1.0 - q)))
            })
            .collect();
        let sum: f64 = out.iter().map(|e| e.1).sum();
        if !(sum > 0.0) {
            return Err(Error::input(InputKind::Discretization, "no support"));
        }
        out.iter_mut().for_each(|e| e.1 /= sum);
        Ok(out)
    }

    fn masses(rng: &mut Rng, n: usize) -> Vec<f64> {
        (0..n).map(|_| 1e-3 * (1.0 + 0.5 * rng.sym())).collect()
    }

    fn random_u(rng: &mut Rng, n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|_| Vector3::new(rng.sym(), rng.sym(), rng.sym()) * 1e-3)
            .collect()
    }

    /// max |Phi u - target| / max |target|.
    fn rel_error(c: &ComponentCorrection, u: &[Vector3<f64>], target: &[f64]) -> f64 {
        let mut interp = Vec::new();
        c.interpolate(u, &mut interp);
        let scale = target.iter().fold(0.0f64, |m, t| m.max(t.abs()));
        interp
            .iter()
            .zip(target)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
            / scale
    }

    fn rows(pos: &[Vector3<f64>], nodes: &[usize]) -> Vec<SparseRow> {
        nodes
            .iter()
            .map(|&k| shape(pos, &pos[k]).unwrap())
            .collect()
    }

    /// The bottom face z = 0 of the box, 2 x 2 squares split into 8 triangles.
    fn bottom_tris() -> Vec<[usize; 3]> {
        let id = |i: usize, j: usize| j * 3 + i;
        let mut t = Vec::new();
        for j in 0..2 {
            for i in 0..2 {
                t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        t
    }

    #[test]
    fn sebciem_imposes_targets_and_nodal_baseline_does_not() {
        let mut rng = Rng(7);
        let pos = box_nodes(&mut rng);
        let n = pos.len();
        let mass = masses(&mut rng, n);
        let nodes = vec![0, 2, 4, 13, 22, 35];
        for comp in 0..3 {
            let mut c =
                ComponentCorrection::sebciem(comp, nodes.clone(), rows(&pos, &nodes), &mass)
                    .unwrap();
            let mut worst = 0.0f64;
            let mut worst_baseline = f64::INFINITY;
            for _ in 0..5 {
                let u_pred = random_u(&mut rng, n);
                let target: Vec<f64> = nodes.iter().map(|_| 2e-3 * rng.sym()).collect();
                let mut u = u_pred.clone();
                c.correct(&mut u, &target);
                worst = worst.max(rel_error(&c, &u, &target));
                // Other components are untouched.
                for (a, b) in u.iter().zip(&u_pred) {
                    for d in (0..3).filter(|&d| d != comp) {
                        assert_eq!(a[d].to_bits(), b[d].to_bits());
                    }
                }
                // Baseline: prescribe the nodal parameters directly.
                let mut ub = u_pred.clone();
                for (&k, &t) in nodes.iter().zip(&target) {
                    ub[k][comp] = t;
                }
                worst_baseline = worst_baseline.min(rel_error(&c, &ub, &target));
            }
            eprintln!("SEBCIEM: cond(A) ~ {:.3e}", c.condition_estimate());
            eprintln!(
                "SEBCIEM component {comp}: imposition error {worst:.3e} (relative), nodal baseline error {worst_baseline:.3e} (smallest over trials)"
            );
            assert!(worst < 1e-10, "{worst}");
            assert!(worst_baseline > 1e-3, "{worst_baseline}");
        }
    }

    #[test]
    fn ebciem_imposes_targets_on_a_triangulated_face() {
        let mut rng = Rng(11);
        let pos = box_nodes(&mut rng);
        let n = pos.len();
        let mass = masses(&mut rng, n);
        let nodes: Vec<usize> = (0..9).collect();
        let cols = ebciem_columns(&nodes, &pos, &bottom_tris(), |x| shape(&pos, x)).unwrap();
        // Partition of unity and a rule exact for linear hats: the column sums are the areas
        // attributed to each node and add up to the face area.
        let total: f64 = cols.iter().flatten().map(|e| e.1).sum();
        assert!((total - 4.0 * H * H).abs() < 1e-12 * 4.0 * H * H, "{total}");
        for col in &cols {
            assert!(col.windows(2).all(|w| w[0].0 < w[1].0), "canonical order");
        }
        let mut c =
            ComponentCorrection::new(2, nodes.clone(), rows(&pos, &nodes), cols, &mass).unwrap();
        let mut worst = 0.0f64;
        let mut worst_baseline = f64::INFINITY;
        for _ in 0..5 {
            let u_pred = random_u(&mut rng, n);
            let target: Vec<f64> = nodes.iter().map(|_| 2e-3 * rng.sym()).collect();
            let mut u = u_pred.clone();
            c.correct(&mut u, &target);
            worst = worst.max(rel_error(&c, &u, &target));
            let mut ub = u_pred.clone();
            for (&k, &t) in nodes.iter().zip(&target) {
                ub[k][2] = t;
            }
            worst_baseline = worst_baseline.min(rel_error(&c, &ub, &target));
        }
        eprintln!("EBCIEM: cond(A) ~ {:.3e}", c.condition_estimate());
        eprintln!(
            "EBCIEM: imposition error {worst:.3e} (relative), nodal baseline error {worst_baseline:.3e} (smallest over trials)"
        );
        assert!(worst < 1e-10, "{worst}");
        assert!(worst_baseline > 1e-3, "{worst_baseline}");

        // A uniform target (rigid translation of the face) is also imposed exactly.
        let mut u = vec![Vector3::zeros(); n];
        let target = vec![-1e-3; 9];
        c.correct(&mut u, &target);
        let e = rel_error(&c, &u, &target);
        eprintln!("EBCIEM uniform target: imposition error {e:.3e}");
        assert!(e < 1e-10);
    }

    #[test]
    fn constraint_force_matches_momentum_change() {
        let mut rng = Rng(23);
        let pos = box_nodes(&mut rng);
        let n = pos.len();
        let mass = masses(&mut rng, n);
        let alpha = 1e-8; // 2 dt^2 / (2 + c dt) for dt = 1e-4 s, c = 0
        let sebciem_nodes = vec![0, 2, 4, 13, 22, 35];
        let face: Vec<usize> = (0..9).collect();
        let cols = ebciem_columns(&face, &pos, &bottom_tris(), |x| shape(&pos, x)).unwrap();
        let cases = [
            ComponentCorrection::sebciem(
                0,
                sebciem_nodes.clone(),
                rows(&pos, &sebciem_nodes),
                &mass,
            )
            .unwrap(),
            ComponentCorrection::new(1, face.clone(), rows(&pos, &face), cols, &mass).unwrap(),
        ];
        for (case, mut c) in cases.into_iter().enumerate() {
            let comp = c.component();
            if case == 0 {
                let worst = c
                    .column_sums()
                    .iter()
                    .fold(0.0f64, |m, s| m.max((s - 1.0).abs()));
                eprintln!("SEBCIEM column sums: max |s_k - 1| = {worst:.3e}");
                assert!(worst < 1e-12);
            }
            let u_pred = random_u(&mut rng, n);
            let target: Vec<f64> = c.nodes().iter().map(|_| 2e-3 * rng.sym()).collect();
            let mut u = u_pred.clone();
            c.correct(&mut u, &target);
            let momentum: Vec<f64> = (0..n)
                .map(|j| mass[j] * (u[j][comp] - u_pred[j][comp]) / alpha)
                .collect();
            let total: f64 = momentum.iter().sum();
            let all: Vec<usize> = (0..c.nodes().len()).collect();
            let f = c.constraint_force(&all, alpha);
            let scale = momentum.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let mut nodal = vec![Vector3::zeros(); n];
            c.add_nodal_forces(&mut nodal, alpha);
            let nodal_err = (0..n).fold(0.0f64, |m, j| m.max((nodal[j][comp] - momentum[j]).abs()));
            eprintln!(
                "case {case}: sum M du/alpha = {total:.6e} N, constraint_force = {f:.6e} N, \
                 |difference|/max nodal = {:.3e}, nodal forces error {:.3e}",
                (total - f).abs() / scale,
                nodal_err / scale
            );
            assert!((total - f).abs() < 1e-10 * scale);
            assert!(nodal_err < 1e-10 * scale);
            // Groups of columns add up.
            let (g1, g2) = all.split_at(2);
            let parts = c.constraint_force(g1, alpha) + c.constraint_force(g2, alpha);
            assert!((parts - f).abs() < 1e-12 * scale);
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let mut rng = Rng(5);
        let mut pos = box_nodes(&mut rng);
        let n = pos.len();
        let mass = masses(&mut rng, n);
        let nodes = vec![0, 2, 4, 13, 22, 35];

        let err = ComponentCorrection::sebciem(0, nodes.clone(), rows(&pos, &nodes[..5]), &mass)
            .unwrap_err()
            .to_string();
        assert!(err.contains("6 constrained nodes but 5"), "{err}");

        let mut bad_mass = mass.clone();
        bad_mass[3] = 0.0;
        let err = ComponentCorrection::sebciem(0, nodes.clone(), rows(&pos, &nodes), &bad_mass)
            .unwrap_err()
            .to_string();
        assert!(err.contains("node 3"), "{err}");

        let mut r = rows(&pos, &nodes);
        r[1].push((n as u32, 0.5));
        assert!(ComponentCorrection::sebciem(0, nodes.clone(), r, &mass).is_err());
        let mut far = nodes.clone();
        far[0] = n;
        assert!(ComponentCorrection::sebciem(0, far, rows(&pos, &nodes), &mass).is_err());
        assert!(ComponentCorrection::sebciem(3, nodes.clone(), rows(&pos, &nodes), &mass).is_err());

        let twice = vec![0, 2, 2];
        let err = ComponentCorrection::sebciem(1, twice.clone(), rows(&pos, &twice), &mass)
            .unwrap_err()
            .to_string();
        assert!(err.contains("listed twice"), "{err}");

        // Two distinct nodes at the same position: identical rows of Phi, singular A.
        pos.push(pos[4]);
        let mut mass2 = mass.clone();
        mass2.push(1e-3);
        let same = vec![0, 4, 13, n];
        let err = ComponentCorrection::sebciem(2, same.clone(), rows(&pos, &same), &mass2)
            .unwrap_err()
            .to_string();
        eprintln!("singular: {err}");
        assert!(
            err.contains("singular") && err.contains("(z)") && err.contains("4 constrained"),
            "{err}"
        );

        // EBCIEM with a nearly coincident pair: numerically singular.
        pos[n] = pos[4] + Vector3::new(1e-14, 0.0, 0.0);
        let err = ComponentCorrection::sebciem(2, same.clone(), rows(&pos, &same), &mass2)
            .unwrap_err()
            .to_string();
        eprintln!("nearly singular: {err}");
        assert!(err.contains("singular"), "{err}");

        let face: Vec<usize> = (0..8).collect();
        let err = ebciem_columns(&face, &pos, &bottom_tris(), |x| shape(&pos, x))
            .unwrap_err()
            .to_string();
        assert!(err.contains("vertex 8"), "{err}");

        let e = EssentialCorrection::new(vec![
            ComponentCorrection::sebciem(0, vec![0], rows(&pos, &[0]), &mass2).unwrap(),
            ComponentCorrection::sebciem(0, vec![2], rows(&pos, &[2]), &mass2).unwrap(),
        ]);
        assert!(e.is_err());
    }

    #[test]
    fn one_shared_solve_matches_separate_corrections() {
        let mut rng = Rng(7);
        let pos = box_nodes(&mut rng);
        let n = pos.len();
        let mass = masses(&mut rng, n);
        let face: Vec<usize> = (0..9).collect();
        let build = |c: usize| {
            ComponentCorrection::sebciem(c, face.clone(), rows(&pos, &face), &mass).unwrap()
        };
        let (mut x, mut y, mut z) = (build(0), build(1), build(2));
        assert!(x.same_system(&y) && x.same_system(&z));
        let other =
            ComponentCorrection::sebciem(1, vec![0, 2, 4], rows(&pos, &[0, 2, 4]), &mass).unwrap();
        assert!(!x.same_system(&other));
        let cols = ebciem_columns(&face, &pos, &bottom_tris(), |x| shape(&pos, x)).unwrap();
        let ebc =
            ComponentCorrection::new(1, face.clone(), rows(&pos, &face), cols, &mass).unwrap();
        assert!(!x.same_system(&ebc), "EBCIEM's V differs from Phi^T");

        let u_pred = random_u(&mut rng, n);
        let targets: Vec<Vec<f64>> = (0..3)
            .map(|_| face.iter().map(|_| 1e-3 * rng.sym()).collect())
            .collect();
        let mut separate = u_pred.clone();
        for (c, t) in [&mut x, &mut y, &mut z].into_iter().zip(&targets) {
            c.correct(&mut separate, t);
        }
        let y_separate: Vec<Vec<f64>> = [&x, &y, &z]
            .iter()
            .map(|c| c.multipliers().to_vec())
            .collect();
        let mut shared = u_pred.clone();
        let mut rhs = vec![0.0; 3 * face.len()];
        let mut nodal = vec![Vector3::zeros(); n];
        let alpha = 2.5e-7;
        // SAFETY: `shared` and `nodal` hold n vectors, borrowed mutably; x, y, z share one system.
        unsafe {
            ComponentCorrection::solve_shared(
                &mut [&mut x, &mut y, &mut z],
                shared.as_mut_ptr() as *mut f64,
                &[&targets[0], &targets[1], &targets[2]],
                &mut rhs,
                nodal.as_mut_ptr() as *mut f64,
                alpha,
            )
        };
        // The fused update adds the same constraint forces as add_nodal_forces, bitwise.
        let mut want = vec![Vector3::zeros(); n];
        for c in [&x, &y, &z] {
            c.add_nodal_forces(&mut want, alpha);
        }
        assert!(want.iter().any(|f| f.norm() > 0.0));
        assert_eq!(nodal, want);
        // The lanes of one substitution do what separate solves do: bitwise the same.
        for (c, want) in [&x, &y, &z].iter().zip(&y_separate) {
            assert_eq!(c.multipliers(), &want[..]);
        }
        assert_eq!(shared, separate);
        // And the shared correction imposes the targets.
        let all = EssentialCorrection::new(vec![x, y, z]).unwrap();
        assert!(all.max_imposition_error(&shared, &targets) < 1e-12);
    }

    #[test]
    fn correct_is_deterministic_and_empty_is_a_no_op() {
        let mut rng = Rng(99);
        let pos = box_nodes(&mut rng);
        let n = pos.len();
        let mass = masses(&mut rng, n);
        let face: Vec<usize> = (0..9).collect();
        let cols = ebciem_columns(&face, &pos, &bottom_tris(), |x| shape(&pos, x)).unwrap();
        let mut all = EssentialCorrection::new(vec![
            ComponentCorrection::new(0, face.clone(), rows(&pos, &face), cols, &mass).unwrap(),
            ComponentCorrection::sebciem(2, face.clone(), rows(&pos, &face), &mass).unwrap(),
            ComponentCorrection::sebciem(1, vec![], vec![], &mass).unwrap(),
        ])
        .unwrap();
        let u_pred = random_u(&mut rng, n);
        let targets = vec![
            face.iter().map(|_| 1e-3 * rng.sym()).collect::<Vec<_>>(),
            face.iter().map(|_| 1e-3 * rng.sym()).collect(),
            vec![],
        ];
        let mut u1 = u_pred.clone();
        all.correct(&mut u1, &targets);
        let f1 = all.total_force(1e-8);
        let mut u2 = u_pred.clone();
        all.correct(&mut u2, &targets);
        let f2 = all.total_force(1e-8);
        for (a, b) in u1.iter().zip(&u2) {
            for d in 0..3 {
                assert_eq!(a[d].to_bits(), b[d].to_bits());
            }
        }
        for d in 0..3 {
            assert_eq!(f1[d].to_bits(), f2[d].to_bits());
        }
        for (a, b) in u1.iter().zip(&u_pred) {
            assert_eq!(a[1].to_bits(), b[1].to_bits());
        }
        let err = all.max_imposition_error(&u1, &targets);
        eprintln!("all components: max imposition error {err:.3e} m");
        assert!(err < 1e-13);
    }

    #[test]
    fn condition_estimate_matches_dense_inverse() {
        let mut rng = Rng(31);
        let pos = box_nodes(&mut rng);
        let n = pos.len();
        let mass = masses(&mut rng, n);
        let face: Vec<usize> = (0..9).collect();
        let sparse_nodes = vec![0, 2, 4, 13, 22, 35];
        let cols = ebciem_columns(&face, &pos, &bottom_tris(), |x| shape(&pos, x)).unwrap();
        let cases = [
            (face.clone(), cols),
            (sparse_nodes.clone(), rows(&pos, &sparse_nodes)),
            (face.clone(), rows(&pos, &face)),
        ];
        for (nodes, v) in cases {
            let phi = rows(&pos, &nodes);
            let ne = nodes.len();
            let mut a = nalgebra::DMatrix::<f64>::zeros(ne, ne);
            for k in 0..ne {
                for l in 0..ne {
                    for &(j, p) in &phi[k] {
                        for &(jj, q) in &v[l] {
                            if j == jj {
                                a[(k, l)] += p * q / mass[j as usize];
                            }
                        }
                    }
                }
            }
            let norm1 = |m: &nalgebra::DMatrix<f64>| {
                m.column_iter()
                    .map(|c| c.iter().map(|x| x.abs()).sum::<f64>())
                    .fold(0.0, f64::max)
            };
            let exact = norm1(&a) * norm1(&a.clone().try_inverse().unwrap());
            let c = ComponentCorrection::new(0, nodes, phi, v, &mass).unwrap();
            let est = c.condition_estimate();
            eprintln!("cond_1(A): estimate {est:.4e}, exact {exact:.4e}");
            assert!(est <= exact * (1.0 + 1e-10) && est >= exact / 3.0);
        }
    }
}
