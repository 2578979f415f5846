//! The triangular solves of a supernodal factor on the threads, split by the elimination
//! tree: disjoint subtrees are independent (a supernode's column block is written only by its
//! descendants), so they run at once, and the few separators above them, in sequence.
//!
//! The split is fixed by the symbolic structure alone ([`TASKS`] subtrees of about equal
//! work), never by the thread count, so the answer is bitwise the same for any number of
//! threads. The backward solve (L^T x = y) reads ancestors and writes a supernode's own rows:
//! the same operations as in sequence. In the forward solve (L y = b) a subtree's updates to
//! the rows above it go into a buffer of its own, added to those rows in subtree order.
//!
//! The two solves stream the factor from memory once each, and a conjugate-gradient
//! iteration preconditioned by it is two of them: on the indentation benchmark's c4 (tet10,
//! 73,092 DOFs, 45 million nonzeros) a pair of them took 35 ms in sequence, 9.6 s of the
//! static solve's 24 s.

use std::sync::Mutex;

use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_unit_lower_triangular_in_place,
    solve_unit_upper_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::traits::ComplexField;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

use crate::solver::SharedMut;

/// Subtrees the forward and backward solves split into: enough for rayon to balance them
/// over the threads, few enough that the separators left above them stay a small share.
pub const TASKS: usize = 16;

/// Off-diagonal entries of a supernode from which its products with x are split over the
/// threads, in blocks of ROW_CHUNK rows (forward) or COLUMN_CHUNK columns (backward): fixed
/// sizes, so the split is the same for any thread count.
pub const SPLIT_ENTRIES: usize = 1 << 16;
const ROW_CHUNK: usize = 256;
const COLUMN_CHUNK: usize = 32;

/// One subtree: its supernodes (ascending: children before parents) and its root, whose
/// off-diagonal rows are all the rows above the subtree its supernodes update.
#[derive(Debug, Clone)]
struct Task {
    supernodes: Vec<usize>,
    root: usize,
}

/// The split of a supernodal factor's elimination tree into independent subtrees and the
/// supernodes above them.
#[derive(Debug)]
pub struct TreeSolve {
    tasks: Vec<Task>,
    /// Supernodes in no task, ascending.
    top: Vec<usize>,
    /// Per column of the factor, the task its supernode is in (u32::MAX: the top).
    owner: Vec<u32>,
    /// Per task, its updates to the rows above it (one entry per row of the factor), zero
    /// between solves.
    buffers: Mutex<Vec<Vec<f64>>>,
}

/// A scalar the solves take: f32 (the single-precision factor) or f64.
pub trait Scalar: ComplexField + Copy + Send + Sync + 'static {
    fn to_f64(self) -> f64;
    fn from_f64(x: f64) -> Self;
}
impl Scalar for f32 {
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn from_f64(x: f64) -> Self {
        x as f32
    }
}
impl Scalar for f64 {
    fn to_f64(self) -> f64 {
        self
    }
    fn from_f64(x: f64) -> Self {
        x
    }
}

impl TreeSolve {
    /// The split of `sn`'s tree, or None where it has fewer than two subtrees (or a
    /// supernode's parent comes before it, which a supernodal factor's order never has).
    pub fn new(sn: &SymbolicSupernodalCholesky<usize>) -> Option<Self> {
        let ns = sn.n_supernodes();
        if ns < 2 {
            return None;
        }
        let begin = sn.supernode_begin();
        let end = sn.supernode_end();
        let n = sn.nrows();
        // The supernode of each column, each supernode's parent (the one holding its first
        // off-diagonal row).
        let mut of_col = vec![0usize; n];
        for s in 0..ns {
            of_col[begin[s]..end[s]].iter_mut().for_each(|x| *x = s);
        }
        let mut parent = vec![usize::MAX; ns];
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); ns];
        for (s, p) in parent.iter_mut().enumerate() {
            let pat = sn.supernode(s).pattern();
            if let Some(&r) = pat.iter().min() {
                *p = of_col[r];
                if *p <= s {
                    return None;
                }
                children[*p].push(s);
            }
        }
        // Each subtree's work (factor entries); children come before their parents.
        let vals = sn.col_ptr_for_val();
        let mut work = vec![0usize; ns];
        for s in 0..ns {
            work[s] += vals[s + 1] - vals[s];
            if parent[s] != usize::MAX {
                work[parent[s]] += work[s];
            }
        }
        let roots: Vec<usize> = (0..ns).filter(|&s| parent[s] == usize::MAX).collect();
        let total: usize = roots.iter().map(|&s| work[s]).sum();
        // From the roots down: the heaviest subtree is replaced by its children while it
        // holds more than a TASKS-th of the work (ties by index: a fixed split).
        let mut open = roots;
        loop {
            let Some((k, &s)) = open
                .iter()
                .enumerate()
                .max_by(|a, b| work[*a.1].cmp(&work[*b.1]).then(b.1.cmp(a.1)))
            else {
                break;
            };
            if work[s] * TASKS <= total || children[s].is_empty() {
                break;
            }
            open.swap_remove(k);
            open.extend_from_slice(&children[s]);
        }
        open.sort_unstable();
        if open.len() < 2 {
            return None;
        }
        // Each supernode's task: its nearest ancestor-or-self among the roots of `open`.
        let mut task_of = vec![u32::MAX; ns];
        for (t, &r) in open.iter().enumerate() {
            task_of[r] = t as u32;
        }
        for s in (0..ns).rev() {
            if task_of[s] == u32::MAX && parent[s] != usize::MAX {
                let p = parent[s];
                // A parent inside a task passes it down; the top's own supernodes do not.
                if task_of[p] != u32::MAX {
                    task_of[s] = task_of[p];
                }
            }
        }
        let mut tasks: Vec<Task> = open
            .iter()
            .map(|&r| Task {
                supernodes: Vec::new(),
                root: r,
            })
            .collect();
        let mut top = Vec::new();
        let mut owner = vec![u32::MAX; n];
        for s in 0..ns {
            match task_of[s] {
                u32::MAX => top.push(s),
                t => {
                    tasks[t as usize].supernodes.push(s);
                    owner[begin[s]..end[s]].iter_mut().for_each(|x| *x = t);
                }
            }
        }
        let buffers = tasks.iter().map(|_| vec![0.0; n]).collect();
        Some(TreeSolve {
            tasks,
            top,
            owner,
            buffers: Mutex::new(buffers),
        })
    }

    /// Bytes of the per-task buffers.
    pub fn bytes(&self) -> usize {
        self.buffers
            .lock()
            .map(|b| b.iter().map(|v| v.len() * 8).sum())
            .unwrap_or(0)
    }

    /// Solves L D L^T x = b in place (`x` in the factor's order): `unit` for LDL^T (unit L,
    /// D on the diagonal of the supernodes' diagonal blocks), otherwise LL^T.
    pub fn solve<T: Scalar>(
        &self,
        sn: &SymbolicSupernodalCholesky<usize>,
        values: &[T],
        x: &mut [T],
        unit: bool,
    ) {
        let l = Lower { sn, values, unit };
        let mut buffers = match self.buffers.lock() {
            Ok(b) => b,
            Err(e) => e.into_inner(),
        };
        let xp = SharedMut(x.as_mut_ptr());
        let len = x.len();
        // Forward: the subtrees at once, each into its own rows and buffer.
        let owner = &self.owner;
        self.tasks
            .par_iter()
            .zip(buffers.par_iter_mut())
            .enumerate()
            .for_each(|(k, (t, buf))| {
                // SAFETY: a task reads and writes only the rows of its own columns (its
                // supernodes' diagonal blocks, which only their descendants update); the
                // tasks' columns are disjoint.
                let x = unsafe { std::slice::from_raw_parts_mut(xp.get(), len) };
                let mut tmp = Vec::new();
                for &s in &t.supernodes {
                    l.forward(s, x, &mut tmp, |i, v| {
                        let own = owner[i] == k as u32;
                        if !own {
                            buf[i] += v.to_f64();
                        }
                        own
                    });
                }
            });
        for (t, buf) in self.tasks.iter().zip(buffers.iter_mut()) {
            for &i in sn.supernode(t.root).pattern() {
                let b = &mut buf[i];
                x[i] = T::from_f64(x[i].to_f64() - *b);
                *b = 0.0;
            }
        }
        let mut tmp = Vec::new();
        for &s in &self.top {
            l.forward(s, x, &mut tmp, |_, _| true);
        }
        if unit {
            l.scale_by_diagonal(x);
        }
        // Backward: the separators from the root down, then the subtrees at once.
        for &s in self.top.iter().rev() {
            l.backward(s, x, &mut tmp);
        }
        self.tasks.par_iter().for_each(|t| {
            // SAFETY: as above; rows above the task are only read.
            let x = unsafe { std::slice::from_raw_parts_mut(xp.get(), len) };
            let mut tmp = Vec::new();
            for &s in t.supernodes.iter().rev() {
                l.backward(s, x, &mut tmp);
            }
        });
    }
}

/// A supernodal factor's values with its structure: `unit` for LDL^T.
struct Lower<'a, T> {
    sn: &'a SymbolicSupernodalCholesky<usize>,
    values: &'a [T],
    unit: bool,
}

impl<T: Scalar> Lower<'_, T> {
    /// Supernode `s`'s diagonal block, its off-diagonal rows (values and row indices) and
    /// its first column.
    fn blocks(&self, s: usize) -> (MatRef<'_, T>, MatRef<'_, T>, &[usize], usize) {
        let sn = self.sn;
        let start = sn.supernode_begin()[s];
        let width = sn.supernode_end()[s] - start;
        let pattern = sn.supernode(s).pattern();
        let vals = sn.col_ptr_for_val();
        let ls = MatRef::from_column_major_slice(
            &self.values[vals[s]..vals[s + 1]],
            width + pattern.len(),
            width,
        );
        let (top, bot) = ls.split_at_row(width);
        (top, bot, pattern, start)
    }

    /// The forward step of supernode `s`: its block solved, then each off-diagonal row's
    /// update v handed to `direct(row, v)`, subtracted from x where that returns true.
    fn forward(
        &self,
        s: usize,
        x: &mut [T],
        tmp: &mut Vec<T>,
        mut direct: impl FnMut(usize, T) -> bool,
    ) {
        let (top, bot, pattern, start) = self.blocks(s);
        let width = top.ncols();
        let xt = MatMut::from_column_major_slice_mut(&mut x[start..start + width], width, 1);
        if self.unit {
            solve_unit_lower_triangular_in_place(top, xt, Par::Seq);
        } else {
            solve_lower_triangular_in_place(top, xt, Par::Seq);
        }
        if pattern.is_empty() {
            return;
        }
        tmp.clear();
        tmp.resize(pattern.len(), T::from_f64(0.0));
        let xt = MatRef::from_column_major_slice(&x[start..start + width], width, 1);
        // A large supernode's product by fixed blocks of rows on the threads: each row's sum
        // is its block's, whatever thread takes it.
        let rows = if width * pattern.len() >= SPLIT_ENTRIES {
            ROW_CHUNK
        } else {
            pattern.len()
        };
        in_blocks(tmp, rows, |c, out| {
            let m = out.len();
            let dst = MatMut::from_column_major_slice_mut(out, m, 1);
            let lhs = bot.subrows(c * rows, m);
            matmul(dst, Accum::Replace, lhs, xt, T::from_f64(1.0), Par::Seq);
        });
        for (&i, &v) in pattern.iter().zip(tmp.iter()) {
            if direct(i, v) {
                x[i] = x[i] - v;
            }
        }
    }

    /// x /= D for LDL^T (D on the diagonal of each supernode's diagonal block).
    fn scale_by_diagonal(&self, x: &mut [T]) {
        for s in 0..self.sn.n_supernodes() {
            let (top, _, _, start) = self.blocks(s);
            for k in 0..top.ncols() {
                x[start + k] = T::from_f64(x[start + k].to_f64() / top[(k, k)].to_f64());
            }
        }
    }

    /// The backward step of supernode `s`: its rows less the off-diagonal block's product
    /// with the rows above, then its transposed block solved.
    fn backward(&self, s: usize, x: &mut [T], tmp: &mut Vec<T>) {
        let (top, bot, pattern, start) = self.blocks(s);
        let width = top.ncols();
        if !pattern.is_empty() {
            tmp.clear();
            tmp.extend(pattern.iter().map(|&i| x[i]));
            let t = MatRef::from_column_major_slice(tmp, pattern.len(), 1);
            // By fixed blocks of the supernode's columns, each its own rows of x.
            let cols = if width * pattern.len() >= SPLIT_ENTRIES {
                COLUMN_CHUNK
            } else {
                width
            };
            in_blocks(&mut x[start..start + width], cols, |c, out| {
                let m = out.len();
                let xt = MatMut::from_column_major_slice_mut(out, m, 1);
                let lhs = bot.subcols(c * cols, m).transpose();
                matmul(xt, Accum::Add, lhs, t, T::from_f64(-1.0), Par::Seq);
            });
        }
        let xt = MatMut::from_column_major_slice_mut(&mut x[start..start + width], width, 1);
        if self.unit {
            solve_unit_upper_triangular_in_place(top.transpose(), xt, Par::Seq);
        } else {
            solve_upper_triangular_in_place(top.transpose(), xt, Par::Seq);
        }
    }
}

/// `f(k, block)` for the k-th block of `size` entries of `v`: on the threads where there are
/// several, directly where there is one (most supernodes, whose products are small).
fn in_blocks<T: Send>(v: &mut [T], size: usize, f: impl Fn(usize, &mut [T]) + Sync) {
    if size >= v.len() {
        f(0, v);
    } else {
        v.par_chunks_mut(size)
            .enumerate()
            .for_each(|(c, b)| f(c, b));
    }
}
