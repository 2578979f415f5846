//! The one force kernel: internal nodal forces from every quadrature point, TLED style
//! (Miller et al. 2007): F = I + sum_a u_a (x) dphi_a, S = S(F), f_a = w F S dphi_a, plus the
//! hourglass force HG u for one-point hexahedra and the averaged pressure of ANP tetrahedra.
//!
//! Assembly is chunked (see [`super::chunks`]): the points are cut once into chunks of nearby
//! points; each chunk sums its points' forces, in a fixed order, into a buffer of its own, and
//! each node then sums its entries over the chunks in chunk order. The partition does not
//! depend on the thread count, so forces are bitwise identical for any number of threads.
//!
//! Runs of four points of one kind (hexahedra, standard 8- and 4-node points) are evaluated
//! together with the points in the innermost index (SIMD lanes; AVX2 where the CPU has it).
//! Each lane computes exactly the operations of the point alone, and AVX2 and SSE2 give bitwise
//! the same forces. A block adds its slot forces slot by slot across its four points, so at a
//! node two of them share, the sum runs in another order than point by point: the blocking,
//! fixed by the discretization, moves forces by rounding only (the unit test bounds it).
//!
//! The rooms, one job each, each owning its scratch and reporting its bytes:
//!
//! | room | job |
//! |---|---|
//! | `plan` | chunks, work items, lane data and the chunks' force buffers |
//! | `lanes` | the kernel: deformation gradients, stresses and slot forces, lane by lane |
//! | `pressure` | average nodal pressure of ANP tetrahedra |
//! | `groups` | mean-dilatation groups |
//! | `energy` | strain energy |
//! | `fields` | output fields (stress, strain, J) at the points |

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

mod energy;
mod fields;
mod groups;
mod lanes;
mod plan;
mod pressure;
#[cfg(test)]
mod tests;

use energy::Energy;
pub use fields::Fields;
use groups::{GroupScratch, Groups};
use plan::{plan, Chunk, Item, Mode, Plan};
use pressure::NodalPressure;

use super::chunks::{self, Buffers};
use super::SharedMut;
use crate::material::{inv_cbrt, Concrete, Material};
use crate::quadrature::{NodeSlots, PointKind, QuadraturePoints};
use crate::simd_available;

/// Points per rayon task in the per-point and per-node loops outside the force chunks.
const CHUNK: usize = 256;

/// Points evaluated together by the lane kernel: four f64 lanes fill an AVX register and two
/// SSE registers, and four independent points hide the latency of each point's dependent
/// chain (F, det F, the cube-root Newton steps, the division by J).
const LANES: usize = 4;
/// Nodes per task of the nodal sums and the integrator's update ([`Forces::node_forces`]);
/// small enough that the two ends of the update loop (`two_ended`) meet near the middle
/// (the 4,389-node cylinder has 18 blocks; with 1,024 nodes it had 5).
pub const NODE_BLOCK: usize = 256;

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

/// Internal-force evaluator with its preallocated scratch space (no allocation per call). Its
/// memory is held in rooms, one per job, each reporting its own bytes
/// ([`Self::scratch_bytes`] is their sum): the evaluation plan and chunk buffers
/// (`plan`), the average nodal pressure (`pressure`), the mean-dilatation groups
/// (`groups`), the per-point energies (`energy`).
pub struct Forces<M: Material> {
    /// The model's materials (one per region); `point_material` says which each point has.
    pub materials: Vec<M>,
    /// Index into `materials` of each point (empty: every point has the first).
    point_material: Vec<u16>,
    /// Work items, lane data, chunks and their force buffers.
    plan: Plan,
    /// det F at each point from the last evaluation (each point's own, ANP and
    /// mean-dilatation points included).
    pub point_j: Vec<f64>,
    /// The ANP tetrahedra's pressure nodes and their averages.
    pressure: NodalPressure,
    /// The mean-dilatation groups' J and stresses.
    groups: Groups,
    /// Per-point energies.
    energy: Energy,
    /// Nodes the evaluator was built for (every slot's node id is below it).
    num_nodes: usize,
    /// (smallest J, its point) of the last evaluation.
    min_j: (f64, usize),
    /// The CPU has AVX2: chunks run through [`Self::chunk_avx2`].
    simd: bool,
}

/// Heap bytes of a vector's allocation (its capacity, not its length: what the allocator gave).
fn heap_bytes<T>(v: &Vec<T>) -> usize {
    v.capacity() * std::mem::size_of::<T>()
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
    /// Prepares the evaluation plan and scratch space for `qp` on `num_nodes` nodes. The
    /// points are taken in their order, which should be spatially coherent
    /// ([`Model::new`](super::Model::new) sorts them along a Morton curve).
    ///
    /// # Panics
    /// When a point refers to a node id at or above `num_nodes` (discretizations validate ids
    /// before they get here; [`Model::new`](super::Model::new) builds the node map first).
    pub fn new(material: M, qp: &QuadraturePoints, slots: &NodeSlots, num_nodes: usize) -> Self {
        Self::with_materials(vec![material], Vec::new(), qp, slots, num_nodes)
    }

    /// As [`Self::new`] with one material per region: point `p` has
    /// `materials[point_material[p]]` (`point_material` empty: all the first).
    ///
    /// # Panics
    /// As [`Self::new`], and when `point_material` is neither empty nor one entry per point
    /// below `materials.len()`.
    pub fn with_materials(
        materials: Vec<M>,
        point_material: Vec<u16>,
        qp: &QuadraturePoints,
        slots: &NodeSlots,
        num_nodes: usize,
    ) -> Self {
        assert!(
            !materials.is_empty()
                && (point_material.is_empty()
                    || (point_material.len() == qp.len()
                        && point_material
                            .iter()
                            .all(|&m| (m as usize) < materials.len()))),
            "{} point materials for {} points and {} materials",
            point_material.len(),
            qp.len(),
            materials.len()
        );
        assert!(
            qp.node_bound() <= num_nodes,
            "quadrature points refer to node {} of {num_nodes}",
            qp.node_bound().saturating_sub(1)
        );
        Forces {
            plan: plan(qp, &point_material, num_nodes, true),
            pressure: NodalPressure::new(qp, slots, &point_material, num_nodes),
            groups: Groups::new(qp),
            energy: Energy::new(qp.len()),
            point_j: vec![1.0; qp.len()],
            materials,
            point_material,
            num_nodes,
            min_j: (f64::INFINITY, usize::MAX),
            simd: simd_available(),
        }
    }

    /// Heap bytes the evaluator holds: the sum of its rooms' (`Plan::bytes`,
    /// `NodalPressure::bytes`, `Groups::bytes`, `Energy::bytes`) and its own per-point
    /// J, material indices and materials. The memory estimate adds these; a buffer added to a
    /// room must be counted in its `bytes` (the test `the_memory_estimate_counts_every_buffer`
    /// measures what the allocator gives).
    pub fn scratch_bytes(&self) -> usize {
        self.plan.bytes()
            + self.pressure.bytes()
            + self.groups.bytes()
            + self.energy.bytes()
            + heap_bytes(&self.point_j)
            + heap_bytes(&self.point_material)
            + heap_bytes(&self.materials)
    }

    /// The tables behind the modified points and the chunk sums, for another evaluator.
    pub fn tables(&self) -> ForceTables<'_> {
        ForceTables {
            buffers: &self.plan.buffers,
            anp_slot_key: &self.pressure.slot_key,
            node_anp_inv_weight: &self.pressure.inv_weight,
            anp_offsets: &self.pressure.offsets,
            anp_points: &self.pressure.points,
            anp_list: &self.pressure.list,
            group_first: &self.groups.first,
            num_pressure_nodes: self.pressure.node_p.len(),
        }
    }

    /// The material of point `p`.
    #[inline(always)]
    pub fn material_at(&self, p: usize) -> &M {
        let m = self.point_material.get(p).copied().unwrap_or(0);
        &self.materials[m as usize]
    }

    /// Index into [`Self::materials`] of each point (empty: all the first).
    pub fn point_materials(&self) -> &[u16] {
        &self.point_material
    }

    /// What the modified points need before their stress: the ANP nodal pressures, and the
    /// mean-dilatation groups' mean J and stresses.
    fn averages(&mut self, qp: &QuadraturePoints, u: &[Vector3<f64>]) {
        if self.pressure.present {
            self.nodal_pressures(qp, u);
        }
        self.group_stresses(qp, u);
    }

    /// F whose energy W(F) point `p` holds: the plain F, or for mean-dilatation points F scaled
    /// by (J_avg / J)^(1/3) with J_avg the weighted mean J of the point's cell. (ANP points hold
    /// W(F) - U(J) plus their share of the nodal U(J_n): see [`Self::strain_energy`].)
    #[inline(always)]
    fn stress_gradient(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        u: &[Vector3<f64>],
    ) -> (Matrix3<f64>, f64) {
        let f = deformation_gradient(qp, p, u);
        let j = f.determinant();
        match qp.kinds[p] {
            PointKind::MeanDilatation(g) => {
                let j_avg = self.groups.j[g as usize];
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
        self.compute_points(qp, slots, u);
        self.gather(out);
    }

    /// Nodal forces from the last [`Self::compute_points`] into `out`, N. Parallel over nodes.
    pub fn gather(&self, out: &mut [Vector3<f64>]) {
        out.par_chunks_mut(NODE_BLOCK)
            .enumerate()
            .for_each(|(b, o)| self.node_forces(b * NODE_BLOCK, o));
    }

    /// Nodal forces of the nodes `n0..n0 + out.len()` from the last [`Self::compute_points`]
    /// into `out`, N: each node's chunk entries summed in chunk order (from zero: the first
    /// entry, then the others), as two loops of fixed shape (see `Buffers::extras`).
    ///
    /// # Panics
    /// If the nodes run past the model's.
    #[inline]
    pub fn node_forces(&self, n0: usize, out: &mut [Vector3<f64>]) {
        let b = &self.plan.buffers;
        let cf = &self.plan.chunk_forces;
        let n1 = n0 + out.len();
        for (o, &e) in out.iter_mut().zip(&b.first[n0..n1]) {
            *o = Vector3::zeros();
            *o += cf[e as usize];
        }
        let extras = &b.extras[b.extra_start[n0] as usize..b.extra_start[n1] as usize];
        for &[n, e] in extras {
            out[n as usize - n0] += cf[e as usize];
        }
    }

    /// Smallest det F over the points of the last evaluation, and the point that has it
    /// (the lowest index among equals).
    pub fn min_j(&self) -> (f64, usize) {
        self.min_j
    }
}

/// [`Forces::tables`]: what the CPU evaluator built once for the ANP pressures, the
/// mean-dilatation groups and the chunk sums.
pub struct ForceTables<'a> {
    pub buffers: &'a Buffers,
    /// Per slot of an ANP point: its pressure node (empty: the node itself).
    pub anp_slot_key: &'a [u32],
    /// Per pressure node: 1 / the weight of its ANP points (0: none).
    pub node_anp_inv_weight: &'a [f64],
    /// Per pressure node: its (ANP point, weight) in `anp_points[anp_offsets[n]..]`.
    pub anp_offsets: &'a [u32],
    pub anp_points: &'a [(u32, f64)],
    /// The ANP points.
    pub anp_list: &'a [u32],
    /// Per mean-dilatation group: its first entry in the group scratch.
    pub group_first: &'a [u32],
    pub num_pressure_nodes: usize,
}
