//! The one force kernel: internal nodal forces from every quadrature point, TLED style
//! (Miller et al. 2007): F = I + sum_a u_a (x) dphi_a, S = S(F), f_a = w F S dphi_a, plus the
//! hourglass force HG u for one-point hexahedra and the averaged pressure of ANP tetrahedra.
//!
//! Assembly is gather-style: each point writes only its own slots, then each node sums its
//! slots in a fixed order, so forces are bitwise identical for any number of threads.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::material::{inv_cbrt, Material};
use crate::quadrature::{NodeSlots, PointKind, QuadraturePoints};

/// A raw pointer that may cross threads: each parallel task writes a disjoint index range.
#[derive(Clone, Copy)]
struct SharedMut<T>(*mut T);
unsafe impl<T> Send for SharedMut<T> {}
unsafe impl<T> Sync for SharedMut<T> {}

impl<T> SharedMut<T> {
    /// The pointer; a method so closures capture the whole (Send + Sync) wrapper.
    #[inline(always)]
    fn get(self) -> *mut T {
        self.0
    }
}

/// Points per rayon task: large enough to amortise scheduling, small enough to balance.
const CHUNK: usize = 256;

/// Deformation gradient F = I + sum_a u_a (x) dphi_a at one point.
#[inline(always)]
pub fn deformation_gradient(qp: &QuadraturePoints, p: usize, u: &[Vector3<f64>]) -> Matrix3<f64> {
    let mut f = Matrix3::identity();
    for s in qp.slots(p) {
        let ua = &u[qp.nodes[s] as usize];
        let d = &qp.dphi[s];
        f += ua * d.transpose();
    }
    f
}

/// x^(1/3) = x (x^(-1/3))^2 through the fast [`inv_cbrt`].
#[inline(always)]
fn cbrt(x: f64) -> f64 {
    let r = inv_cbrt(x);
    x * (r * r)
}

/// Hourglass mode amplitudes G^T u (4 vectors) of a hexahedron with scaled hourglass vectors
/// `g` (8x4, column-major) and nodal displacements `u(a)`, a = 0..8.
#[inline(always)]
fn hourglass_modes(g: &[f64], u: impl Fn(usize) -> Vector3<f64>) -> [Vector3<f64>; 4] {
    let ul: [Vector3<f64>; 8] = std::array::from_fn(u);
    std::array::from_fn(|m| {
        let col = &g[8 * m..8 * m + 8];
        let mut acc = Vector3::zeros();
        for (r, ur) in ul.iter().enumerate() {
            acc += ur * col[r];
        }
        acc
    })
}

/// Internal-force evaluator with its preallocated scratch space (no allocation per call).
pub struct Forces<M: Material> {
    pub material: M,
    slot_forces: Vec<Vector3<f64>>,
    /// det F at each point from the last evaluation (after ANP averaging for ANP points).
    pub point_j: Vec<f64>,
    /// Volume-weighted average J at nodes (ANP only).
    node_j: Vec<f64>,
    /// 1 / sum of ANP weights around each node (0 where a node has no ANP point).
    node_anp_inv_weight: Vec<f64>,
    has_anp: bool,
    /// Weighted mean J of each mean-dilatation group.
    group_j: Vec<f64>,
    /// Per-point energies, reused so that energy evaluations do not allocate.
    energy_scratch: Vec<f64>,
    /// Nodes the evaluator was built for (every slot's node id is below it).
    num_nodes: usize,
    /// (smallest J, its point) of the last evaluation.
    min_j: (f64, usize),
}

/// The smaller J of two (J, point) pairs, the lower point among equals: associative and
/// commutative, so the parallel reduction gives the same pair for any thread count. A NaN J
/// never wins (NaN displacements are the divergence detector's to report).
#[inline]
fn min_by_j(a: (f64, usize), b: (f64, usize)) -> (f64, usize) {
    if b.0 < a.0 || (b.0 == a.0 && b.1 < a.1) {
        b
    } else {
        a
    }
}

impl<M: Material> Forces<M> {
    /// Prepares scratch space for `qp` on `num_nodes` nodes.
    ///
    /// # Panics
    /// When a point refers to a node id at or above `num_nodes` (discretizations validate ids
    /// before they get here; [`Model::new`](super::Model::new) builds the node map first).
    pub fn new(material: M, qp: &QuadraturePoints, slots: &NodeSlots, num_nodes: usize) -> Self {
        assert!(
            qp.node_bound() <= num_nodes,
            "quadrature points refer to node {} of {num_nodes}",
            qp.node_bound().saturating_sub(1)
        );
        let has_anp = qp.kinds.contains(&PointKind::Anp);
        let mut inv_w = vec![0.0; num_nodes];
        if has_anp {
            for (n, iw) in inv_w.iter_mut().enumerate() {
                let w: f64 = slots
                    .range(n)
                    .map(|i| slots.points[i] as usize)
                    .filter(|&p| qp.kinds[p] == PointKind::Anp)
                    .map(|p| qp.weights[p])
                    .sum();
                *iw = if w > 0.0 { 1.0 / w } else { 0.0 };
            }
        }
        Forces {
            material,
            slot_forces: vec![Vector3::zeros(); qp.nodes.len()],
            point_j: vec![1.0; qp.len()],
            node_j: vec![1.0; if has_anp { num_nodes } else { 0 }],
            node_anp_inv_weight: inv_w,
            has_anp,
            group_j: vec![1.0; qp.groups.len()],
            energy_scratch: vec![0.0; qp.len()],
            num_nodes,
            min_j: (f64::INFINITY, usize::MAX),
        }
    }

    /// Bytes of the scratch arrays.
    pub fn scratch_bytes(&self) -> usize {
        use std::mem::size_of_val;
        size_of_val(self.slot_forces.as_slice())
            + size_of_val(self.point_j.as_slice())
            + size_of_val(self.node_j.as_slice())
            + size_of_val(self.node_anp_inv_weight.as_slice())
            + size_of_val(self.group_j.as_slice())
            + size_of_val(self.energy_scratch.as_slice())
    }

    /// The averaged J's the modified points need (ANP nodal averages, group means).
    fn averages(&mut self, qp: &QuadraturePoints, slots: &NodeSlots, u: &[Vector3<f64>]) {
        if self.has_anp {
            self.average_nodal_j(qp, slots, u);
        }
        if !qp.groups.is_empty() {
            self.group_j
                .par_iter_mut()
                .with_min_len(CHUNK / 8)
                .zip(&qp.groups)
                .for_each(|(gj, &[a, b])| {
                    let (mut wj, mut w) = (0.0, 0.0);
                    for p in a as usize..b as usize {
                        wj += qp.weights[p] * deformation_gradient(qp, p, u).determinant();
                        w += qp.weights[p];
                    }
                    *gj = wj / w;
                });
        }
    }

    /// Averaged nodal J for ANP points (Joldes et al. 2009): per node the volume-weighted mean of
    /// the element J's around it. Parallel over points, then over nodes.
    fn average_nodal_j(&mut self, qp: &QuadraturePoints, slots: &NodeSlots, u: &[Vector3<f64>]) {
        let pj = SharedMut(self.point_j.as_mut_ptr());
        (0..qp.len())
            .into_par_iter()
            .with_min_len(CHUNK)
            .for_each(|p| {
                if qp.kinds[p] == PointKind::Anp {
                    let j = deformation_gradient(qp, p, u).determinant();
                    // SAFETY: each p writes only its own entry.
                    unsafe { *pj.get().add(p) = j };
                }
            });
        let point_j = &self.point_j;
        let inv_w = &self.node_anp_inv_weight;
        self.node_j
            .par_iter_mut()
            .with_min_len(CHUNK)
            .enumerate()
            .for_each(|(n, nj)| {
                if inv_w[n] > 0.0 {
                    let mut acc = 0.0;
                    for i in slots.range(n) {
                        let p = slots.points[i] as usize;
                        if qp.kinds[p] == PointKind::Anp {
                            acc += qp.weights[p] * point_j[p];
                        }
                    }
                    *nj = acc * inv_w[n];
                }
            });
    }

    /// F used for the stress at point `p`: the plain F, or for ANP points F scaled by
    /// (J_avg / J)^(1/3) with J_avg the mean of the point's nodal averaged J's (mean-dilatation
    /// points: J_avg the weighted mean J of the point's cell).
    #[inline(always)]
    fn stress_gradient(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        u: &[Vector3<f64>],
    ) -> (Matrix3<f64>, f64) {
        self.modified(qp, p, deformation_gradient(qp, p, u))
    }

    /// (F used for the stress, its J) from the plain F of point `p` (see `stress_gradient`).
    #[inline(always)]
    fn modified(&self, qp: &QuadraturePoints, p: usize, f: Matrix3<f64>) -> (Matrix3<f64>, f64) {
        let j = f.determinant();
        match qp.kinds[p] {
            PointKind::Anp => {
                let r = qp.slots(p);
                let n = r.len() as f64;
                let j_avg: f64 = r.map(|s| self.node_j[qp.nodes[s] as usize]).sum::<f64>() / n;
                (cbrt(j_avg / j) * f, j_avg)
            }
            PointKind::MeanDilatation(g) => {
                let j_avg = self.group_j[g as usize];
                (cbrt(j_avg / j) * f, j_avg)
            }
            _ => (f, j),
        }
    }

    /// Internal nodal forces F_int(u), N, into `out` (one entry per node). Parallel.
    pub fn compute(
        &mut self,
        qp: &QuadraturePoints,
        slots: &NodeSlots,
        u: &[Vector3<f64>],
        out: &mut [Vector3<f64>],
    ) {
        self.compute_slots(qp, slots, u);
        self.gather(slots, out);
    }

    /// Nodal forces from the last [`Self::compute_slots`] into `out`, N. Parallel over nodes.
    pub fn gather(&self, slots: &NodeSlots, out: &mut [Vector3<f64>]) {
        out.par_iter_mut()
            .with_min_len(CHUNK)
            .enumerate()
            .for_each(|(n, o)| *o = self.node_force(slots, n));
    }

    /// The point stage of [`Self::compute`]: every point's share of its nodes' forces (slot
    /// forces), its J, and the smallest J ([`Self::min_j`]). Nodal forces then follow from
    /// [`Self::node_force`], which the integrator fuses with its update.
    pub fn compute_slots(&mut self, qp: &QuadraturePoints, slots: &NodeSlots, u: &[Vector3<f64>]) {
        // The kernel reads u unchecked: every slot's node id is below num_nodes (Self::new).
        assert!(
            u.len() >= self.num_nodes && qp.nodes.len() == self.slot_forces.len(),
            "force evaluation on {} nodes and {} slots; built for {} and {}",
            u.len(),
            qp.nodes.len(),
            self.num_nodes,
            self.slot_forces.len()
        );
        self.averages(qp, slots, u);
        let sf = SharedMut(self.slot_forces.as_mut_ptr());
        let pj = SharedMut(self.point_j.as_mut_ptr());
        let this = &*self;
        self.min_j = (0..qp.len())
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|p| {
                let (a, b) = (qp.offsets[p], qp.offsets[p + 1]);
                // SAFETY: point p writes only its own slots a..b and entry p; ids < u.len().
                let j = unsafe {
                    match b - a {
                        8 => this.point_fixed::<8>(qp, p, a, u, sf),
                        4 => this.point_fixed::<4>(qp, p, a, u, sf),
                        _ => this.point_any(qp, p, a, b, u, sf),
                    }
                };
                unsafe { *pj.get().add(p) = j };
                (j, p)
            })
            .reduce(|| (f64::INFINITY, usize::MAX), min_by_j);
    }

    /// Internal force on node `n` from the last [`Self::compute_slots`]: its slots summed in
    /// a fixed order, N.
    #[inline(always)]
    pub fn node_force(&self, slots: &NodeSlots, n: usize) -> Vector3<f64> {
        let mut acc = Vector3::zeros();
        for &s in &slots.slots[slots.range(n)] {
            acc += self.slot_forces[s as usize];
        }
        acc
    }

    /// Point with exactly N support nodes (hexahedra, tetrahedra, nearest-8 MLS): the loops
    /// unroll and the slot slices are checked once. Returns the J used for the stress.
    ///
    /// # Safety
    /// Slots a..a+N belong to point p alone, and every node id is below `u.len()`.
    #[inline(always)]
    unsafe fn point_fixed<const N: usize>(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        a: usize,
        u: &[Vector3<f64>],
        sf: SharedMut<Vector3<f64>>,
    ) -> f64 {
        let ids = &qp.nodes[a..a + N];
        let d = &qp.dphi[a..a + N];
        let ul: [Vector3<f64>; N] = std::array::from_fn(|k| *u.get_unchecked(ids[k] as usize));
        let mut f = Matrix3::identity();
        for k in 0..N {
            f += ul[k] * d[k].transpose();
        }
        let j = self.stress_to_slots(qp, p, a, f, d, sf);
        if N == 8 {
            if let PointKind::Hourglass(h) = qp.kinds[p] {
                // HG u = G (G^T u); G is column-major, so each column is 8 contiguous values.
                let g = qp.hourglass[h as usize].as_slice();
                let q = hourglass_modes(g, |r| ul[r]);
                let out = sf.get().add(a);
                for r in 0..8 {
                    let mut acc = Vector3::zeros();
                    for (m, qm) in q.iter().enumerate() {
                        acc += qm * g[8 * m + r];
                    }
                    *out.add(r) += acc;
                }
            }
        }
        j
    }

    /// Point with any number of support nodes (hourglass points always have 8: fixed path).
    ///
    /// # Safety
    /// As [`Self::point_fixed`] for slots a..b.
    #[inline(always)]
    unsafe fn point_any(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        a: usize,
        b: usize,
        u: &[Vector3<f64>],
        sf: SharedMut<Vector3<f64>>,
    ) -> f64 {
        let d = &qp.dphi[a..b];
        let mut f = Matrix3::identity();
        for (&id, dk) in qp.nodes[a..b].iter().zip(d) {
            f += *u.get_unchecked(id as usize) * dk.transpose();
        }
        self.stress_to_slots(qp, p, a, f, d, sf)
    }

    /// From the plain F of point `p` (slots from `a`, derivatives `d`): the stress (ANP /
    /// mean-dilatation modified) and the slot forces w P dphi_k. Returns the J used for the
    /// stress.
    ///
    /// # Safety
    /// As [`Self::point_fixed`]: the point's slots belong to it alone.
    #[inline(always)]
    unsafe fn stress_to_slots(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        a: usize,
        f: Matrix3<f64>,
        d: &[Vector3<f64>],
        sf: SharedMut<Vector3<f64>>,
    ) -> f64 {
        let (f, j) = self.modified(qp, p, f);
        let pk = self.material.first_pk_stress(&f, j) * qp.weights[p];
        let out = sf.get().add(a);
        for (k, dk) in d.iter().enumerate() {
            *out.add(k) = pk * dk;
        }
        j
    }

    /// Smallest det F over the points of the last evaluation, and the point that has it
    /// (the lowest index among equals).
    pub fn min_j(&self) -> (f64, usize) {
        self.min_j
    }

    /// Strain energy sum_p w_p W(F_p) + sum_hex u^T HG u / 2, J. Deterministic (fixed-order sum).
    pub fn strain_energy(
        &mut self,
        qp: &QuadraturePoints,
        slots: &NodeSlots,
        u: &[Vector3<f64>],
    ) -> f64 {
        self.averages(qp, slots, u);
        let mut per_point = std::mem::take(&mut self.energy_scratch);
        let this = &*self;
        per_point.par_iter_mut().enumerate().for_each(|(p, e)| {
            let (f, _) = this.stress_gradient(qp, p, u);
            let mut w = qp.weights[p] * this.material.strain_energy(&f);
            if let PointKind::Hourglass(h) = qp.kinds[p] {
                // u^T HG u / 2 = |G^T u|^2 / 2 over the three components.
                let base = qp.offsets[p];
                let ids = &qp.nodes[base..base + 8];
                let q =
                    hourglass_modes(qp.hourglass[h as usize].as_slice(), |a| u[ids[a] as usize]);
                w += 0.5 * q.iter().map(|qm| qm.norm_squared()).sum::<f64>();
            }
            *e = w;
        });
        let total = per_point.iter().sum();
        self.energy_scratch = per_point;
        total
    }

    /// Per point: Cauchy stress (Pa, row-major 9 values), von Mises stress (Pa) and J.
    pub fn stress_fields(
        &mut self,
        qp: &QuadraturePoints,
        slots: &NodeSlots,
        u: &[Vector3<f64>],
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        self.averages(qp, slots, u);
        let mut sig = vec![0.0; 9 * qp.len()];
        let mut vm = vec![0.0; qp.len()];
        let mut jj = vec![0.0; qp.len()];
        for p in 0..qp.len() {
            let (f, j) = self.stress_gradient(qp, p, u);
            let s = self.material.pk2_stress(&f, j);
            let c = f * s * f.transpose() / j;
            for r in 0..3 {
                for k in 0..3 {
                    sig[9 * p + 3 * r + k] = c[(r, k)];
                }
            }
            let dev = c - Matrix3::identity() * (c.trace() / 3.0);
            vm[p] = (1.5 * dev.norm_squared()).sqrt();
            jj[p] = j;
        }
        (sig, vm, jj)
    }
}
