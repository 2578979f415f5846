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

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::chunks::{self, Buffers};
use super::SharedMut;
use crate::material::{inv_cbrt, Concrete, Material};
use crate::quadrature::{NodeSlots, PointKind, QuadraturePoints};
use crate::simd_available;

/// Points per rayon task in the per-point and per-node loops outside the force chunks.
const CHUNK: usize = 256;

/// Force chunks hold about 1/`CHUNKS` of the slots, but at least `MIN_CHUNK_SLOTS` (so that a
/// chunk's work dwarfs its scheduling and the nodes it shares with other chunks) and at most
/// `MAX_CHUNK_SLOTS` (so that its buffer, one entry per node it reaches, stays in L2).
/// Fixed by the discretization alone: the sums do not depend on the thread count. The cap
/// acts only above 4 million slots. On the brain (11 million slots), 100 steps, ms per step at
/// 1 / 2 threads, interleaved: cap 16,384 (four rounds) 83-138 / 48-59, 65,536 (four rounds,
/// faster in each) 79-94 / 46-56, 4,096 (two) 102-105 / 64-68, 262,144 (two, i.e. 1/64 of the
/// slots) 75-85 / 44-55.
const CHUNKS: usize = 64;
const MIN_CHUNK_SLOTS: usize = 1024;
const MAX_CHUNK_SLOTS: usize = 65536;

/// Points evaluated together by the lane kernel: four f64 lanes fill an AVX register and two
/// SSE registers, and four independent points hide the latency of each point's dependent
/// chain (F, det F, the cube-root Newton steps, the division by J).
const LANES: usize = 4;
/// Nodes per task of the nodal sums and the integrator's update ([`Forces::node_forces`]);
/// small enough that the two ends of the update loop (`two_ended`) meet near the middle
/// (the 4,389-node cylinder has 18 blocks; with 1,024 nodes it had 5).
pub const NODE_BLOCK: usize = 256;

/// How a work item evaluates its points (see [`Forces::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Standard points with 8 support nodes (nearest-8 MLS, fully integrated hex cells).
    Plain8,
    /// Standard points with 4 support nodes (tetrahedra).
    Plain4,
    /// One-point hexahedra with their hourglass force.
    Hourglass8,
    /// Average-nodal-pressure tetrahedra: the pressure of the stress swapped for the mean of
    /// the nodal pressures ([`Forces::anp_stress`]).
    Anp4,
    /// Anything else (other sizes): F point by point, the stresses of four consecutive ones
    /// as one lane block.
    Other,
    /// Mean-dilatation points: at a group's first point the chunk evaluates the whole group's
    /// stresses ([`Forces::group_stress`]), then adds each point's slot forces.
    Group,
}

/// A run of consecutive points: `LANES` points of one [`Mode`] and one material (for
/// `Other`, a stress batch), or one point. Fixed at construction, so each point is always
/// evaluated by the same code whatever the number of threads.
#[derive(Debug, Clone, Copy)]
struct Item {
    first: u32,
    count: u8,
    mode: Mode,
    /// Index into `Forces::materials` of every point of the item.
    material: u16,
    /// Blocks: first entry of the block's data in `Forces::lane_data`.
    lane: u32,
}

/// A chunk: its work items `items[first..end]` and its buffer entries `first..end`.
#[derive(Debug, Clone, Copy)]
struct Chunk {
    items: [u32; 2],
    buf: [u32; 2],
}

/// Where the group pass writes (see [`Forces::group_stress`]): per mean-dilatation point w P,
/// its own F and (J, alpha, tau); per group its mean J.
#[derive(Clone, Copy)]
struct GroupScratch {
    pk: SharedMut<Matrix3<f64>>,
    fs: SharedMut<Matrix3<f64>>,
    ss: SharedMut<[f64; 3]>,
    gj: SharedMut<f64>,
}

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
    /// The model's materials (one per region); `point_material` says which each point has.
    pub materials: Vec<M>,
    /// Index into `materials` of each point (empty: every point has the first).
    point_material: Vec<u16>,
    /// The chunks in evaluation order.
    chunks: Vec<Chunk>,
    /// Where each slot adds its force, and each node's entries.
    buffers: Buffers,
    /// The chunks' force buffers (one entry per node a chunk reaches), N.
    chunk_forces: Vec<Vector3<f64>>,
    /// det F at each point from the last evaluation (each point's own, ANP and
    /// mean-dilatation points included).
    pub point_j: Vec<f64>,
    /// Volume-weighted average J of the ANP points at each pressure node (one per node, or per
    /// node and material where ANP points of several materials meet; ANP only).
    node_j: Vec<f64>,
    /// Pressure U'(J_n) of each pressure node, Pa (its material's U'; ANP only).
    node_p: Vec<f64>,
    /// Pressure node of each slot where ANP points have several materials (empty: the slot's
    /// node).
    anp_slot_key: Vec<u32>,
    /// 1 / sum of ANP weights around each pressure node (0 where a node has no ANP point).
    node_anp_inv_weight: Vec<f64>,
    /// Per pressure node, its ANP points and their weights (compressed rows, slot order): the
    /// nodal averages read these instead of filtering every slot by kind.
    anp_offsets: Vec<u32>,
    /// Per pressure node, its mesh node.
    anp_key_node: Vec<u32>,
    anp_points: Vec<(u32, f64)>,
    /// The ANP points, ascending.
    anp_list: Vec<u32>,
    has_anp: bool,
    /// Weighted mean J of each mean-dilatation group.
    group_j: Vec<f64>,
    /// Per mean-dilatation group, the index of its first point in the arrays below (one
    /// entry per mean-dilatation point, in point order).
    group_first: Vec<u32>,
    /// w P of each mean-dilatation point from the last force evaluation, N m
    /// ([`Self::group_stress`]).
    group_pk: Vec<Matrix3<f64>>,
    /// Scratch of the group pass per mean-dilatation point: its own F.
    group_f: Vec<Matrix3<f64>>,
    /// Scratch of the group pass per mean-dilatation point: its own J, alpha = (J_mean /
    /// J)^(1/3) and tau = P(F_bar) : F_bar / 3 (Pa).
    group_s: Vec<[f64; 3]>,
    /// Per-point energies, reused so that energy evaluations do not allocate.
    energy_scratch: Vec<f64>,
    /// Nodes the evaluator was built for (every slot's node id is below it).
    num_nodes: usize,
    /// (smallest J, its point) of the last evaluation.
    min_j: (f64, usize),
    /// The points in evaluation order (chunk by chunk), grouped into lane blocks where
    /// possible.
    items: Vec<Item>,
    /// Lane-ordered copies of the blocks' constant data, so the kernel reads them as vectors:
    /// per block dphi as [k][c][lane] (N x 3 entries), then for hexahedra G as [m][r][lane]
    /// (4 x 8 entries).
    lane_data: Vec<[f64; LANES]>,
    /// The CPU has AVX2: blocks run through [`Self::item_avx2`].
    simd: bool,
}

/// The mode of point `p` by its kind and support size.
fn point_mode(qp: &QuadraturePoints, p: usize) -> Mode {
    match (qp.kinds[p], qp.offsets[p + 1] - qp.offsets[p]) {
        (PointKind::Standard, 8) => Mode::Plain8,
        (PointKind::Standard, 4) => Mode::Plain4,
        (PointKind::Hourglass(_), 8) => Mode::Hourglass8,
        (PointKind::Anp, 4) => Mode::Anp4,
        (PointKind::MeanDilatation(_), _) => Mode::Group,
        _ => Mode::Other,
    }
}

/// The evaluation plan: work items, lane data, chunks and their buffers.
struct Plan {
    items: Vec<Item>,
    lane_data: Vec<[f64; LANES]>,
    chunks: Vec<Chunk>,
    buffers: Buffers,
}

/// Work items covering every point once in order, cut into chunks of consecutive points
/// (about `qp.nodes.len() / CHUNKS` slots each). Within a chunk, `LANES` consecutive points of
/// one lane mode and one material become a block (when `blocks`; for `Other` points a stress
/// batch), the rest single points. The chunks do not depend on `blocks`.
fn plan(qp: &QuadraturePoints, point_material: &[u16], num_nodes: usize, blocks: bool) -> Plan {
    let mat = |p: usize| point_material.get(p).copied().unwrap_or(0);
    let n = qp.len();
    assert!(
        n < u32::MAX as usize,
        "{n} quadrature points exceed the u32 point ids"
    );
    let modes: Vec<Mode> = (0..n).map(|p| point_mode(qp, p)).collect();
    let target = (qp.nodes.len() / CHUNKS).clamp(MIN_CHUNK_SLOTS, MAX_CHUNK_SLOTS);
    let mut ranges: Vec<[u32; 2]> = Vec::new();
    // A chunk never cuts a mean-dilatation group: the chunk that holds it evaluates the
    // group's stresses just before its slot forces (`Forces::group_stress`), while its
    // supports' dphi are still in cache.
    let inside_group = |p: usize| match qp.kinds[p] {
        PointKind::MeanDilatation(g) => p + 1 < qp.groups[g as usize][1] as usize,
        _ => false,
    };
    let mut first = 0;
    for p in 0..n {
        if (qp.offsets[p + 1] - qp.offsets[first] >= target && !inside_group(p)) || p + 1 == n {
            ranges.push([first as u32, p as u32 + 1]);
            first = p + 1;
        }
    }
    let mut items = Vec::with_capacity(n / LANES + 1);
    let mut lanes = Vec::new();
    let mut chunk_items = Vec::with_capacity(ranges.len());
    for &[c0, c1] in &ranges {
        let (mut p, end) = (c0 as usize, c1 as usize);
        let first_item = items.len() as u32;
        while p < end {
            let m = modes[p];
            let run = blocks
                && m != Mode::Group
                && p + LANES <= end
                && modes[p..p + LANES].iter().all(|&x| x == m)
                && (p..p + LANES).all(|q| mat(q) == mat(p));
            let block = run && m != Mode::Other;
            let count = if run { LANES } else { 1 };
            let lane = u32::try_from(lanes.len()).expect("lane data beyond u32 entries");
            if block {
                let a0 = qp.offsets[p];
                let nn = qp.offsets[p + 1] - a0;
                for k in 0..nn {
                    for c in 0..3 {
                        lanes.push(std::array::from_fn(|l| qp.dphi[a0 + l * nn + k][c]));
                    }
                }
                if m == Mode::Hourglass8 {
                    let g: Vec<&[f64]> = (0..LANES)
                        .map(|l| match qp.kinds[p + l] {
                            PointKind::Hourglass(h) => qp.hourglass[h as usize].as_slice(),
                            _ => unreachable!("hourglass block of other points"),
                        })
                        .collect();
                    for mm in 0..4 {
                        for r in 0..8 {
                            lanes.push(std::array::from_fn(|l| g[l][8 * mm + r]));
                        }
                    }
                }
            }
            items.push(Item {
                first: p as u32,
                count: count as u8,
                mode: m,
                material: mat(p),
                lane,
            });
            p += count;
        }
        chunk_items.push([first_item, items.len() as u32]);
    }
    let buffers = chunks::buffers(qp, &ranges, num_nodes);
    let chunks = chunk_items
        .into_iter()
        .zip(&buffers.ranges)
        .map(|(items, &buf)| Chunk { items, buf })
        .collect();
    Plan {
        items,
        lane_data: lanes,
        chunks,
        buffers,
    }
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
        let has_anp = qp.kinds.contains(&PointKind::Anp);
        // Pressure nodes: per node, one for each material of the ANP points around it (one
        // material: the nodes themselves, so no map is kept), each with its ANP points and
        // weights in slot order and 1 / their weight sum. Several materials meeting at a node
        // keep a pressure each: averaged across them, the exact homogeneous state of each
        // region (different bulk moduli under the same J) would not hold.
        let mat = |p: usize| point_material.get(p).copied().unwrap_or(0);
        let mut inv_w = Vec::new();
        let mut anp_offsets = vec![0u32];
        let mut anp_points = Vec::new();
        let mut anp_slot_key = Vec::new();
        let mut anp_key_node = Vec::new();
        if has_anp {
            let mut seen = Vec::new();
            let anp = |p: usize| qp.kinds[p] == PointKind::Anp;
            let first_material = (0..qp.len()).find(|&p| anp(p)).map(mat);
            let single = (0..qp.len()).all(|p| !anp(p) || Some(mat(p)) == first_material);
            if !single {
                anp_slot_key = vec![u32::MAX; qp.nodes.len()];
            }
            for n in 0..num_nodes {
                seen.clear();
                for i in slots.range(n) {
                    let p = slots.points[i] as usize;
                    if anp(p) && !seen.contains(&mat(p)) {
                        seen.push(mat(p));
                    }
                }
                if single && seen.is_empty() {
                    // Keeps pressure node n = node n.
                    seen.push(0);
                }
                for &m in &seen {
                    let key = u32::try_from(inv_w.len()).expect("pressure nodes beyond u32");
                    let first = anp_points.len();
                    for i in slots.range(n) {
                        let p = slots.points[i] as usize;
                        if anp(p) && mat(p) == m {
                            anp_points.push((p as u32, qp.weights[p]));
                            if !single {
                                anp_slot_key[slots.slots[i] as usize] = key;
                            }
                        }
                    }
                    let w: f64 = anp_points[first..].iter().map(|&(_, w)| w).sum();
                    inv_w.push(if w > 0.0 { 1.0 / w } else { 0.0 });
                    anp_offsets.push(anp_points.len() as u32);
                    anp_key_node.push(n as u32);
                }
            }
        }
        let anp_list = (0..qp.len() as u32)
            .filter(|&p| qp.kinds[p as usize] == PointKind::Anp)
            .collect();
        let plan = plan(qp, &point_material, num_nodes, true);
        let mut group_first = Vec::with_capacity(qp.groups.len());
        let mut in_groups = 0u32;
        for &[a, b] in &qp.groups {
            group_first.push(in_groups);
            in_groups += b - a;
        }
        let in_groups = in_groups as usize;
        Forces {
            anp_key_node,
            anp_offsets,
            anp_points,
            anp_list,
            materials,
            point_material,
            chunks: plan.chunks,
            // One more entry, always zero: the `first` entry of nodes no point reaches.
            chunk_forces: vec![Vector3::zeros(); plan.buffers.len() + 1],
            buffers: plan.buffers,
            point_j: vec![1.0; qp.len()],
            node_j: vec![1.0; inv_w.len()],
            node_p: vec![0.0; inv_w.len()],
            anp_slot_key,
            node_anp_inv_weight: inv_w,
            has_anp,
            group_j: vec![1.0; qp.groups.len()],
            group_first,
            group_pk: vec![Matrix3::zeros(); in_groups],
            group_f: vec![Matrix3::zeros(); in_groups],
            group_s: vec![[0.0; 3]; in_groups],
            energy_scratch: vec![0.0; qp.len()],
            num_nodes,
            min_j: (f64::INFINITY, usize::MAX),
            items: plan.items,
            lane_data: plan.lane_data,
            simd: simd_available(),
        }
    }

    /// Bytes of the scratch arrays, the chunk buffers and maps, and the lane-ordered copies of
    /// the blocks' data.
    pub fn scratch_bytes(&self) -> usize {
        use std::mem::size_of_val;
        size_of_val(self.chunk_forces.as_slice())
            + size_of_val(self.chunks.as_slice())
            + size_of_val(self.buffers.slot_entry.as_slice())
            + size_of_val(self.buffers.ranges.as_slice())
            + size_of_val(self.buffers.first.as_slice())
            + size_of_val(self.buffers.extras.as_slice())
            + size_of_val(self.buffers.extra_start.as_slice())
            + size_of_val(self.point_j.as_slice())
            + size_of_val(self.node_j.as_slice())
            + size_of_val(self.node_p.as_slice())
            + size_of_val(self.anp_slot_key.as_slice())
            + size_of_val(self.node_anp_inv_weight.as_slice())
            + size_of_val(self.anp_offsets.as_slice())
            + size_of_val(self.anp_key_node.as_slice())
            + size_of_val(self.anp_points.as_slice())
            + size_of_val(self.anp_list.as_slice())
            + size_of_val(self.group_j.as_slice())
            + size_of_val(self.group_first.as_slice())
            + size_of_val(self.group_pk.as_slice())
            + size_of_val(self.group_f.as_slice())
            + size_of_val(self.group_s.as_slice())
            + size_of_val(self.energy_scratch.as_slice())
            + size_of_val(self.lane_data.as_slice())
            + size_of_val(self.items.as_slice())
            + size_of_val(self.point_material.as_slice())
    }

    /// The slots in the order the chunks add their forces into the buffer entries: chunk by
    /// chunk, item by item; a lane block slot by slot across its points, any other item point
    /// by point. Another evaluator (the GPU one, [`super::gpu`]) that sums each entry's slot
    /// forces in this order from zero gets bitwise the CPU's entries.
    pub fn contribution_order(&self, qp: &QuadraturePoints) -> Vec<u32> {
        let mut out = Vec::with_capacity(qp.nodes.len());
        for it in &self.items {
            let p0 = it.first as usize;
            let block = it.count as usize == LANES
                && matches!(
                    it.mode,
                    Mode::Plain8 | Mode::Plain4 | Mode::Hourglass8 | Mode::Anp4
                );
            if block {
                let a0 = qp.offsets[p0];
                let n = qp.offsets[p0 + 1] - a0;
                for k in 0..n {
                    for l in 0..LANES {
                        out.push((a0 + l * n + k) as u32);
                    }
                }
            } else {
                for p in p0..p0 + it.count as usize {
                    out.extend(qp.slots(p).map(|s| s as u32));
                }
            }
        }
        out
    }

    /// The tables behind the modified points and the chunk sums, for another evaluator.
    pub fn tables(&self) -> ForceTables<'_> {
        ForceTables {
            buffers: &self.buffers,
            anp_slot_key: &self.anp_slot_key,
            node_anp_inv_weight: &self.node_anp_inv_weight,
            anp_offsets: &self.anp_offsets,
            anp_points: &self.anp_points,
            anp_list: &self.anp_list,
            group_first: &self.group_first,
            num_pressure_nodes: self.node_p.len(),
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
        if self.has_anp {
            self.nodal_pressures(qp, u);
        }
        self.group_stresses(qp, u);
    }

    /// The stress of every mean-dilatation point, w P into `group_pk`, and the groups' mean J.
    ///
    /// The energy of a group is sum_p w_p W(F_bar_p), F_bar_p = alpha_p F_p with
    /// alpha_p = (J_mean / J_p)^(1/3) and J_mean = sum_p w_p J_p / sum_p w_p. Its exact
    /// gradient (differentiating alpha_p through J_p and J_mean) is the first Piola-Kirchhoff
    /// stress
    ///
    ///   P_p = alpha_p P(F_bar_p) + (J_p T / J_mean - tau_p) F_p^-T,
    ///   tau_p = P(F_bar_p) : F_bar_p / 3,  T = sum_q w_q tau_q / sum_q w_q,
    ///
    /// which for a material split into isochoric and volumetric parts, W = W_iso(C_bar) + U(J)
    /// (neo-Hookean, Ogden), is P_iso(F_p) + J_p U'(J_mean) F_p^-T: the mean dilatation of
    /// Nagtegaal et al. 1974 (the volumetric part of selectively reduced integration). Taking
    /// P(F_bar_p) alone as the stress, as an F-bar ANP does, gives forces that are not the
    /// gradient of any energy: on the coupled cylinder compressed by 70 % and back they made
    /// 2.9 % of the peak work out of nothing. Parallel over groups; each group's sums run in
    /// point order, so the result does not depend on the thread count.
    fn group_stresses(&mut self, qp: &QuadraturePoints, u: &[Vector3<f64>]) {
        if qp.groups.is_empty() {
            return;
        }
        let gs = self.group_scratch();
        // Unchecked reads of u in group_stress: every node id is below num_nodes (Self::new).
        let simd = self.simd && u.len() >= self.num_nodes;
        let this = &*self;
        (0..qp.groups.len())
            .into_par_iter()
            .with_min_len(CHUNK / 8)
            .for_each(|g| {
                // SAFETY: each group writes only its own scratch entries; `simd` is set only
                // where the CPU has AVX2 and u holds every node.
                unsafe {
                    #[cfg(target_arch = "x86_64")]
                    if simd {
                        return this.group_stress_avx2(qp, g, u, gs);
                    }
                    #[cfg(not(target_arch = "x86_64"))]
                    let _ = simd;
                    this.group_stress::<false>(qp, g, u, gs);
                }
            });
    }

    /// Pointers to the group scratch, for passes that write each group's entries from one
    /// task.
    fn group_scratch(&mut self) -> GroupScratch {
        GroupScratch {
            pk: SharedMut(self.group_pk.as_mut_ptr()),
            fs: SharedMut(self.group_f.as_mut_ptr()),
            ss: SharedMut(self.group_s.as_mut_ptr()),
            gj: SharedMut(self.group_j.as_mut_ptr()),
        }
    }

    /// [`Self::group_stress`] compiled for AVX2.
    ///
    /// # Safety
    /// As [`Self::group_stress`], and the CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn group_stress_avx2(
        &self,
        qp: &QuadraturePoints,
        g: usize,
        u: &[Vector3<f64>],
        gs: GroupScratch,
    ) {
        self.group_stress::<true>(qp, g, u, gs)
    }

    /// Group `g` of [`Self::group_stresses`]: its points' F, J and w P into the scratch, its
    /// mean J into `group_j`. Each sum runs in point order.
    ///
    /// # Safety
    /// The group's scratch entries belong to the caller alone; every node id is below
    /// `u.len()`; AVX only where the CPU has AVX2.
    #[inline(always)]
    unsafe fn group_stress<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        g: usize,
        u: &[Vector3<f64>],
        gs: GroupScratch,
    ) {
        let [a, b] = qp.groups[g];
        let (a, b) = (a as usize, b as usize);
        let i0 = self.group_first[g] as usize;
        // SAFETY: group g owns the entries i0 .. i0 + (b - a) (prefix sums of the group
        // sizes, built in `with_materials`).
        let (pk, fs, ss) = (
            std::slice::from_raw_parts_mut(gs.pk.get().add(i0), b - a),
            std::slice::from_raw_parts_mut(gs.fs.get().add(i0), b - a),
            std::slice::from_raw_parts_mut(gs.ss.get().add(i0), b - a),
        );
        // The AVX2 gradient makes the portable loop's products and sums in its order (bitwise
        // the same F); MLS points have 20-60 supports.
        for (k, p) in (a..b).enumerate() {
            let r = qp.slots(p);
            fs[k] = Self::gradient_any::<AVX>(qp, r.start, r.end, u);
        }
        let (mut wj, mut w) = (0.0, 0.0);
        for (k, p) in (a..b).enumerate() {
            let j = fs[k].determinant();
            ss[k][0] = j;
            wj += qp.weights[p] * j;
            w += qp.weights[p];
        }
        let j_mean = wj / w;
        *gs.gj.get().add(g) = j_mean;
        // P(F_bar) of LANES points of one material at once (`first_pk_stress_lanes`, bitwise
        // each point's `first_pk_stress`); the sums stay in point order.
        let mat = |p: usize| self.point_material.get(p).copied().unwrap_or(0) as usize;
        let mut wt = 0.0;
        let mut k = 0;
        while k < b - a {
            let (p, m) = (a + k, mat(a + k));
            let lanes = if k + LANES <= b - a && (p..p + LANES).all(|q| mat(q) == m) {
                LANES
            } else {
                1
            };
            let mut fl = [[0.0; LANES]; 9];
            let mut alpha = [0.0; LANES];
            for l in 0..lanes {
                alpha[l] = cbrt(j_mean / ss[k + l][0]);
                let fb = fs[k + l] * alpha[l];
                for (i, e) in fl.iter_mut().enumerate() {
                    e[l] = fb[(i / 3, i % 3)];
                }
            }
            let pbl = if lanes == LANES {
                self.materials[m].first_pk_stress_lanes(&fl, &[j_mean; LANES])
            } else {
                let fb = Matrix3::from_fn(|r, c| fl[3 * r + c][0]);
                let pb = self.materials[m].first_pk_stress(&fb, j_mean);
                std::array::from_fn(|i| {
                    let mut o = [0.0; LANES];
                    o[0] = pb[(i / 3, i % 3)];
                    o
                })
            };
            for l in 0..lanes {
                let fb = Matrix3::from_fn(|r, c| fl[3 * r + c][l]);
                let pb = Matrix3::from_fn(|r, c| pbl[3 * r + c][l]);
                let tau = pb.dot(&fb) / 3.0;
                pk[k + l] = pb;
                ss[k + l] = [ss[k + l][0], alpha[l], tau];
                wt += qp.weights[p + l] * tau;
            }
            k += lanes;
        }
        let t_mean = wt / w;
        for (k, p) in (a..b).enumerate() {
            let [j, alpha, tau] = ss[k];
            // J F^-T, the cofactor matrix.
            let cof = crate::geometry::cofactor(&fs[k]);
            pk[k] = (pk[k] * alpha + cof * (t_mean / j_mean - tau / j)) * qp.weights[p];
        }
    }

    /// Nodal J and pressure for ANP points (Bonet & Burton 1998): per pressure node J_n, the
    /// volume-weighted mean of the element J's around it, and p_n = U'(J_n) of their material.
    /// Parallel over points, then over pressure nodes.
    fn nodal_pressures(&mut self, qp: &QuadraturePoints, u: &[Vector3<f64>]) {
        let pj = SharedMut(self.point_j.as_mut_ptr());
        self.anp_list.par_iter().with_min_len(CHUNK).for_each(|&p| {
            let p = p as usize;
            let j = deformation_gradient(qp, p, u).determinant();
            // SAFETY: each p writes only its own entry.
            unsafe { *pj.get().add(p) = j };
        });
        let point_j = &self.point_j;
        let inv_w = &self.node_anp_inv_weight;
        let (offsets, points) = (&self.anp_offsets, &self.anp_points);
        let (materials, point_material) = (&self.materials, &self.point_material);
        self.node_j
            .par_iter_mut()
            .zip(self.node_p.par_iter_mut())
            .with_min_len(CHUNK)
            .enumerate()
            .for_each(|(n, (nj, np))| {
                if inv_w[n] > 0.0 {
                    let around = &points[offsets[n] as usize..offsets[n + 1] as usize];
                    let mut acc = 0.0;
                    for &(p, w) in around {
                        acc += w * point_j[p as usize];
                    }
                    *nj = acc * inv_w[n];
                    // A pressure node's points share one material.
                    let m = point_material
                        .get(around[0].0 as usize)
                        .copied()
                        .unwrap_or(0);
                    *np = materials[m as usize].volumetric(*nj).1;
                }
            });
    }

    /// Pressure node of slot `s` of an ANP point.
    #[inline(always)]
    fn pressure_node(&self, qp: &QuadraturePoints, s: usize) -> usize {
        if self.anp_slot_key.is_empty() {
            qp.nodes[s] as usize
        } else {
            self.anp_slot_key[s] as usize
        }
    }

    /// Mean of the nodal pressures over the slots of ANP point `p`, Pa.
    #[inline(always)]
    fn anp_mean_pressure(&self, qp: &QuadraturePoints, p: usize) -> f64 {
        let r = qp.slots(p);
        let n = r.len() as f64;
        let mut sum = 0.0;
        for s in r {
            sum += self.node_p[self.pressure_node(qp, s)];
        }
        sum / n
    }

    /// First Piola-Kirchhoff stress of ANP point `p` (Pa) from its own F and J: the element's
    /// pressure swapped for the mean of its nodal pressures (Bonet & Burton 1998),
    /// P = P(F) + (p_mean - U'(J)) cof(F), with cof(F) = J F^-T. It is the exact gradient of
    /// sum_e V_e (W(F_e) - U(J_e)) + sum_n V_n U(J_n) (V_n a quarter of the volume around
    /// node n); the F-bar stress P((J_avg / J)^(1/3) F) of Joldes et al. 2009 and NiftySim's
    /// T4ANP, used up to 2026-11-26, is the gradient of no energy: the brain indentation's
    /// energy balance was off by 3.4 % with it.
    #[inline(always)]
    fn anp_stress<K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        p: usize,
        f: &Matrix3<f64>,
        j: f64,
    ) -> Matrix3<f64> {
        let p_mean = self.anp_mean_pressure(qp, p);
        let (_, dp) = mat.volumetric(j);
        mat.first_pk_stress(f, j) + crate::geometry::cofactor(f) * (p_mean - dp)
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
        let b = &self.buffers;
        let cf = &self.chunk_forces;
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

    /// The point stage of [`Self::compute`]: every chunk's forces on its nodes, every point's
    /// J, and the smallest J ([`Self::min_j`]). Nodal forces then follow from
    /// [`Self::node_forces`], which the integrator fuses with its update.
    pub fn compute_points(&mut self, qp: &QuadraturePoints, slots: &NodeSlots, u: &[Vector3<f64>]) {
        // The kernel reads u unchecked: every slot's node id is below num_nodes (Self::new).
        assert!(
            u.len() >= self.num_nodes
                && qp.nodes.len() == self.buffers.slot_entry.len()
                && slots.slots.len() == qp.nodes.len(),
            "force evaluation on {} nodes and {} slots; built for {} and {}",
            u.len(),
            qp.nodes.len(),
            self.num_nodes,
            self.buffers.slot_entry.len()
        );
        // The groups' stresses come inside the chunks (`group_point`).
        if self.has_anp {
            self.nodal_pressures(qp, u);
        }
        let gs = self.group_scratch();
        let cf = SharedMut(self.chunk_forces.as_mut_ptr());
        let pj = SharedMut(self.point_j.as_mut_ptr());
        let this = &*self;
        self.min_j = super::two_ended::for_each_item(
            this.chunks.len(),
            (f64::INFINITY, usize::MAX),
            |c| {
                let ch = &this.chunks[c];
                // SAFETY: a chunk writes only its own buffer entries and its points' J
                // entries, and every node id is below u.len() (checked above and in
                // Self::new); `simd` was set only where the CPU has AVX2.
                unsafe {
                    #[cfg(target_arch = "x86_64")]
                    if this.simd {
                        return this.chunk_avx2(qp, ch, u, cf, pj, gs);
                    }
                    this.chunk::<false>(qp, ch, u, cf, pj, gs)
                }
            },
            min_by_j,
        );
    }

    /// One chunk: clears its buffer, then adds its items' forces into it in order; returns
    /// the smallest (J, point) of its points.
    ///
    /// # Safety
    /// The chunk's buffer entries and points belong to it alone, and every node id is below
    /// `u.len()`.
    #[inline(always)]
    unsafe fn chunk<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        ch: &Chunk,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        for e in ch.buf[0] as usize..ch.buf[1] as usize {
            *cf.get().add(e) = Vector3::zeros();
        }
        let mut best = (f64::INFINITY, usize::MAX);
        for it in self
            .items
            .get_unchecked(ch.items[0] as usize..ch.items[1] as usize)
        {
            best = min_by_j(best, self.item::<AVX>(qp, it, u, cf, pj, gs));
        }
        best
    }

    /// [`Self::chunk`] compiled for AVX2, so the four lanes of a block fill one register. Rust
    /// never fuses a multiply and an add on its own, so every lane computes exactly the
    /// operations of the SSE2 path: the forces are bitwise the same on either.
    ///
    /// # Safety
    /// As [`Self::chunk`], and the CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn chunk_avx2(
        &self,
        qp: &QuadraturePoints,
        ch: &Chunk,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        self.chunk::<true>(qp, ch, u, cf, pj, gs)
    }

    /// One work item: adds its points' forces into the chunk buffer and writes their J's;
    /// returns their smallest (J, point).
    ///
    /// # Safety
    /// As [`Self::chunk`] for the item's chunk.
    #[inline(always)]
    unsafe fn item<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        it: &Item,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        if it.mode == Mode::Group {
            return self.group_point::<AVX>(qp, it.first as usize, u, cf, pj, gs);
        }
        // Each concrete material gets its own copy of the kernels (see Material::concrete).
        match self
            .materials
            .get_unchecked(it.material as usize)
            .concrete()
        {
            Concrete::NeoHookean(m) => self.item_with::<AVX, _>(qp, m, it, u, cf, pj),
            Concrete::Ogden(m) => self.item_out_of_line::<AVX, _>(qp, m, it, u, cf, pj),
            Concrete::Itself(m) => self.item_out_of_line::<AVX, _>(qp, m, it, u, cf, pj),
        }
    }

    /// [`Self::item_with`] out of line: the kernels of the other materials stay out of the
    /// neo-Hookean chunk loop (inlined there they slowed it by 7-10 %, hex8 on one thread).
    ///
    /// # Safety
    /// As [`Self::chunk`] for the item's chunk.
    #[inline(never)]
    unsafe fn item_out_of_line<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        it: &Item,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        self.item_with::<AVX, K>(qp, mat, it, u, cf, pj)
    }

    /// [`Self::item`] with the item's material `mat` as its concrete type.
    ///
    /// # Safety
    /// As [`Self::chunk`] for the item's chunk.
    #[inline(always)]
    unsafe fn item_with<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        it: &Item,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        let p = it.first as usize;
        match (it.mode, it.count as usize) {
            (Mode::Plain8, LANES) => {
                self.lanes::<8, LANES, false, false, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Plain8, _) => self.lanes::<8, 1, false, false, AVX, K>(qp, mat, p, 0, u, cf, pj),
            (Mode::Plain4, LANES) => {
                self.lanes::<4, LANES, false, false, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Anp4, LANES) => {
                self.lanes::<4, LANES, false, true, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Plain4, _) => self.lanes::<4, 1, false, false, AVX, K>(qp, mat, p, 0, u, cf, pj),
            (Mode::Hourglass8, LANES) => {
                self.lanes::<8, LANES, true, false, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Hourglass8, _) => {
                self.lanes::<8, 1, true, false, AVX, K>(qp, mat, p, 0, u, cf, pj)
            }
            (Mode::Group, _) => unreachable!("group points are evaluated by `item`"),
            (Mode::Other, LANES) => self.stress_batch::<AVX, K>(qp, mat, p, u, cf, pj),
            (Mode::Other, _) | (Mode::Anp4, _) => {
                let (f, a) = self.gradient::<AVX>(qp, p, u);
                let j = self.stress_to_chunk::<AVX, K>(qp, mat, p, a, f, cf);
                *pj.get().add(p) = j;
                (j, p)
            }
        }
    }

    /// LANES consecutive points evaluated one at a time up to F (as single points), with their
    /// stresses evaluated side by side ([`Material::first_pk_stress_lanes`]), then their slot forces
    /// added in point order: every point gets bitwise its single-point result.
    ///
    /// # Safety
    /// As [`Self::chunk`] for the points `p0..p0 + LANES`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn stress_batch<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        p0: usize,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        let mut fl = [[0.0; LANES]; 9];
        let mut jl = [0.0; LANES];
        let mut first = [0; LANES];
        for l in 0..LANES {
            // Mean-dilatation points never come here (Mode::Group): the plain F's stress.
            let (f, a) = self.gradient::<AVX>(qp, p0 + l, u);
            let j = f.determinant();
            for (i, e) in fl.iter_mut().enumerate() {
                e[l] = f[(i / 3, i % 3)];
            }
            jl[l] = j;
            first[l] = a;
        }
        let pk = mat.first_pk_stress_lanes(&fl, &jl);
        for l in 0..LANES {
            let p = p0 + l;
            let pkl = Matrix3::from_fn(|r, c| pk[3 * r + c][l]) * qp.weights[p];
            let d = &qp.dphi[first[l]..qp.offsets[p + 1]];
            self.forces_to_chunk::<AVX>(first[l], &pkl, d, cf);
        }
        Self::block_j(p0, &jl, pj)
    }

    /// The slot forces of mean-dilatation point `p`; at the group's first point, first the
    /// group's stresses ([`Self::group_stress`]), so each group's dphi is read from memory once
    /// per step and its second read, for the forces, finds it in cache. The point's J is its
    /// own det F (not the group's mean, so that a Gauss point inverting inside a cell that
    /// keeps its volume still stops the run).
    ///
    /// # Safety
    /// As [`Self::chunk`] for the point `p`.
    #[inline(never)]
    unsafe fn group_point<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        let PointKind::MeanDilatation(g) = qp.kinds[p] else {
            unreachable!("group mode of a point outside the groups");
        };
        let g = g as usize;
        let first = qp.groups[g][0] as usize;
        if p == first {
            // The chunk holds the whole group (`plan`).
            #[cfg(target_arch = "x86_64")]
            if AVX {
                self.group_stress_avx2(qp, g, u, gs);
            } else {
                self.group_stress::<false>(qp, g, u, gs);
            }
            #[cfg(not(target_arch = "x86_64"))]
            self.group_stress::<false>(qp, g, u, gs);
        }
        let i = self.group_first[g] as usize + (p - first);
        let a = qp.offsets[p];
        let pk = *gs.pk.get().add(i);
        self.forces_to_chunk::<AVX>(a, &pk, &qp.dphi[a..qp.offsets[p + 1]], cf);
        let j = (*gs.ss.get().add(i))[0];
        *pj.get().add(p) = j;
        (j, p)
    }

    /// F of point `p` and its first slot: fixed-size loops for 8 and 4 support nodes (ANP
    /// tetrahedra, 8-node mean-dilatation points), any size otherwise.
    ///
    /// # Safety
    /// Every node id of the point is below `u.len()`.
    #[inline(always)]
    unsafe fn gradient<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        u: &[Vector3<f64>],
    ) -> (Matrix3<f64>, usize) {
        let (a, b) = (qp.offsets[p], qp.offsets[p + 1]);
        let f = match b - a {
            8 => Self::gradient_fixed::<8>(qp, a, u),
            4 => Self::gradient_fixed::<4>(qp, a, u),
            _ => Self::gradient_any::<AVX>(qp, a, b, u),
        };
        (f, a)
    }

    /// F of a point with exactly N support nodes from slot `a`: the loops unroll and the slot
    /// slices are checked once.
    ///
    /// # Safety
    /// Every node id of the slots is below `u.len()`.
    #[inline(always)]
    unsafe fn gradient_fixed<const N: usize>(
        qp: &QuadraturePoints,
        a: usize,
        u: &[Vector3<f64>],
    ) -> Matrix3<f64> {
        let ids = &qp.nodes[a..a + N];
        let d = &qp.dphi[a..a + N];
        let ul: [Vector3<f64>; N] = std::array::from_fn(|k| *u.get_unchecked(ids[k] as usize));
        let mut f = Matrix3::identity();
        for k in 0..N {
            f += ul[k] * d[k].transpose();
        }
        f
    }

    /// F of a point with any number of support nodes (slots a..b).
    ///
    /// # Safety
    /// Every node id of the slots is below `u.len()`; AVX only where the CPU has AVX2.
    #[inline(always)]
    unsafe fn gradient_any<const AVX: bool>(
        qp: &QuadraturePoints,
        a: usize,
        b: usize,
        u: &[Vector3<f64>],
    ) -> Matrix3<f64> {
        let d = &qp.dphi[a..b];
        let ids = &qp.nodes[a..b];
        #[cfg(target_arch = "x86_64")]
        if AVX {
            // SAFETY: AVX is set only under chunk_avx2; ids are below u.len() (see Safety).
            return super::lanes_avx2::any_gradient(ids, d, u.as_ptr());
        }
        let mut f = Matrix3::identity();
        for (&id, dk) in ids.iter().zip(d) {
            f += *u.get_unchecked(id as usize) * dk.transpose();
        }
        f
    }

    /// L consecutive points `p0..p0 + L` of N support nodes each (slots contiguous from
    /// `offsets[p0]`), Standard kind, with `HG` one-point hexahedra, with `ANP`
    /// average-nodal-pressure tetrahedra: F, J, P and the slot forces w P dphi_k (+ the
    /// hourglass force G G^T u) with the lanes innermost, so each
    /// operation runs on all L points at once. L = 1 evaluates single points with the same
    /// operations per point.
    /// Writes the points' J and returns their smallest (J, point).
    ///
    /// # Safety
    /// The points' chunk buffer belongs to the caller alone, and every node id is below
    /// `u.len()`.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // index loops over lanes are what vectorizes
    #[allow(clippy::too_many_arguments)]
    unsafe fn lanes<
        const N: usize,
        const L: usize,
        const HG: bool,
        const ANP: bool,
        const AVX: bool,
        K: Material,
    >(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        p0: usize,
        lane: u32,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        let a0 = *qp.offsets.get_unchecked(p0);
        let nodes = qp.nodes.as_ptr().add(a0);
        // dphi and G in lane order: blocks read the copies made at construction; a single
        // point (L = 1) reads its own slots, which are already in that order.
        let mut own_d = [[[0.0; L]; 3]; N];
        let mut own_g = [[[0.0; L]; 8]; 4];
        type Dphi<const N: usize, const L: usize> = [[[f64; L]; 3]; N];
        type HourglassG<const L: usize> = [[[f64; L]; 8]; 4];
        let (dl, gl): (&Dphi<N, L>, &HourglassG<L>) = if L == LANES {
            let base = self.lane_data.as_ptr().add(lane as usize) as *const f64;
            // G follows dphi only in hexahedron blocks; other blocks never form its reference.
            let g = if HG {
                &*(base.add(N * 3 * L) as *const [[[f64; L]; 8]; 4])
            } else {
                &own_g
            };
            (&*(base as *const [[[f64; L]; 3]; N]), g)
        } else {
            for k in 0..N {
                let d = qp.dphi.get_unchecked(a0 + k);
                for c in 0..3 {
                    own_d[k][c][0] = d[c];
                }
            }
            if HG {
                if let PointKind::Hourglass(h) = *qp.kinds.get_unchecked(p0) {
                    let g = qp.hourglass.get_unchecked(h as usize).as_slice();
                    for m in 0..4 {
                        for r in 0..8 {
                            own_g[m][r][0] = g[8 * m + r];
                        }
                    }
                }
            }
            (&own_d, &own_g)
        };
        let load = |k: usize| -> [[f64; L]; 3] {
            std::array::from_fn(|c| {
                std::array::from_fn(|l| (*u.get_unchecked(*nodes.add(l * N + k) as usize))[c])
            })
        };
        // F = I + sum_k u_k (x) dphi_k, row-major: f[3 r + c].
        let mut f = [[0.0; L]; 9];
        for r in 0..3 {
            f[4 * r] = [1.0; L];
        }
        for k in 0..N {
            let uk = load(k);
            for r in 0..3 {
                for c in 0..3 {
                    for l in 0..L {
                        f[3 * r + c][l] += uk[r][l] * dl[k][c][l];
                    }
                }
            }
        }
        let mut j = [0.0; L];
        for l in 0..L {
            let m = |i: usize| f[i][l];
            j[l] = m(0) * (m(4) * m(8) - m(7) * m(5)) - m(1) * (m(3) * m(8) - m(6) * m(5))
                + m(2) * (m(3) * m(7) - m(6) * m(4));
        }
        let mut pk = mat.first_pk_stress_lanes(&f, &j);
        if ANP {
            // As Self::anp_stress, the lanes side by side: P + (p_mean - U'(J)) cof(F), the
            // cofactors by the products and signs of geometry::cofactor.
            let mut s = [0.0; L];
            for l in 0..L {
                let mut sum = 0.0;
                for k in 0..N {
                    sum += *self
                        .node_p
                        .get_unchecked(self.pressure_node(qp, a0 + l * N + k));
                }
                s[l] = sum / N as f64 - mat.volumetric(j[l]).1;
            }
            let minor = |a: usize, b: usize, c: usize, d: usize, l: usize| {
                f[a][l] * f[b][l] - f[c][l] * f[d][l]
            };
            for l in 0..L {
                let cof = [
                    minor(4, 8, 5, 7, l),
                    -minor(3, 8, 5, 6, l),
                    minor(3, 7, 4, 6, l),
                    -minor(1, 8, 2, 7, l),
                    minor(0, 8, 2, 6, l),
                    -minor(0, 7, 1, 6, l),
                    minor(1, 5, 2, 4, l),
                    -minor(0, 5, 2, 3, l),
                    minor(0, 4, 1, 3, l),
                ];
                for (row, c) in pk.iter_mut().zip(cof) {
                    row[l] += c * s[l];
                }
            }
        }
        let w: [f64; L] = std::array::from_fn(|l| *qp.weights.get_unchecked(p0 + l));
        for row in pk.iter_mut() {
            for l in 0..L {
                row[l] *= w[l];
            }
        }
        // Hexahedra: hourglass modes q_m = sum_r G_rm u_r (G column-major 8 x 4).
        let mut q = [[[0.0; L]; 3]; 4];
        if HG {
            for r in 0..N.min(8) {
                let ur = load(r);
                for m in 0..4 {
                    for c in 0..3 {
                        for l in 0..L {
                            q[m][c][l] += gl[m][r][l] * ur[c][l];
                        }
                    }
                }
            }
        }
        // Slot forces w P dphi_k (+ sum_m G_km q_m for hexahedra), added to the chunk buffer
        // slot by slot, the four points of a slot in turn (measured faster than point by point
        // through a transposed copy: hex8 cylinder 0.46 -> 0.44 ms per step on one thread).
        let entries = self.buffers.slot_entry.as_ptr().add(a0);
        #[cfg(target_arch = "x86_64")]
        if AVX && L == LANES {
            // SAFETY: AVX is set only under chunk_avx2 (the CPU has AVX2), L == 4 makes the
            // casts exact, and the entries are the block's own (see Safety).
            super::lanes_avx2::slot_forces::<N, HG>(
                &*(pk.as_ptr() as *const [[f64; 4]; 9]),
                &*(dl as *const Dphi<N, L> as *const [[[f64; 4]; 3]; N]),
                &*(gl as *const HourglassG<L> as *const [[[f64; 4]; 8]; 4]),
                &*(q.as_ptr() as *const [[[f64; 4]; 3]; 4]),
                entries,
                cf.get(),
            );
            return Self::block_j(p0, &j, pj);
        }
        for k in 0..N {
            let mut o = [[0.0; L]; 3];
            for r in 0..3 {
                for l in 0..L {
                    o[r][l] = pk[3 * r][l] * dl[k][0][l]
                        + pk[3 * r + 1][l] * dl[k][1][l]
                        + pk[3 * r + 2][l] * dl[k][2][l];
                }
            }
            if HG {
                let kk = k.min(7);
                for c in 0..3 {
                    for l in 0..L {
                        let mut acc = 0.0;
                        for m in 0..4 {
                            acc += gl[m][kk][l] * q[m][c][l];
                        }
                        o[c][l] += acc;
                    }
                }
            }
            for l in 0..L {
                let t = &mut *cf.get().add(*entries.add(l * N + k) as usize);
                t.x += o[0][l];
                t.y += o[1][l];
                t.z += o[2][l];
            }
        }
        Self::block_j(p0, &j, pj)
    }

    /// Writes the J's of the points `p0..p0 + L` and returns their smallest (J, point).
    ///
    /// # Safety
    /// The points' J entries belong to the caller alone.
    #[inline(always)]
    unsafe fn block_j<const L: usize>(p0: usize, j: &[f64; L], pj: SharedMut<f64>) -> (f64, usize) {
        let mut best = (f64::INFINITY, usize::MAX);
        for (l, &jl) in j.iter().enumerate() {
            *pj.get().add(p0 + l) = jl;
            best = min_by_j(best, (jl, p0 + l));
        }
        best
    }

    /// From the plain F of point `p` (slots from `a`): the stress (ANP points:
    /// [`Self::anp_stress`]) and the slot forces w P dphi_k, added to the chunk buffer. Returns
    /// det F.
    ///
    /// # Safety
    /// The point's chunk buffer belongs to the caller alone.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn stress_to_chunk<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        p: usize,
        a: usize,
        f: Matrix3<f64>,
        cf: SharedMut<Vector3<f64>>,
    ) -> f64 {
        // Mean-dilatation points never come here (Mode::Group).
        let j = f.determinant();
        let pk = if qp.kinds[p] == PointKind::Anp {
            self.anp_stress(qp, mat, p, &f, j)
        } else {
            mat.first_pk_stress(&f, j)
        };
        let pk = pk * qp.weights[p];
        self.forces_to_chunk::<AVX>(a, &pk, &qp.dphi[a..qp.offsets[p + 1]], cf);
        j
    }

    /// The slot forces P dphi_k (P already times the weight) of the point whose slots start at
    /// `a` (derivatives `d`), added to the chunk buffer.
    ///
    /// # Safety
    /// The point's chunk buffer belongs to the caller alone; AVX only where the CPU has AVX2.
    #[inline(always)]
    unsafe fn forces_to_chunk<const AVX: bool>(
        &self,
        a: usize,
        pk: &Matrix3<f64>,
        d: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
    ) {
        let entries = &self.buffers.slot_entry[a..a + d.len()];
        #[cfg(target_arch = "x86_64")]
        if AVX {
            // SAFETY: AVX is set only under chunk_avx2; the entries are the point's own.
            super::lanes_avx2::any_forces(pk, d, entries, cf.get());
            return;
        }
        // Column by column, the association lanes_avx2::any_forces repeats.
        let (c0, c1, c2) = (pk.column(0), pk.column(1), pk.column(2));
        for (dk, &e) in d.iter().zip(entries) {
            *cf.get().add(e as usize) += c0 * dk.x + c1 * dk.y + c2 * dk.z;
        }
    }

    /// The average-nodal-pressure tables (empty without ANP points): per pressure node `n`,
    /// its (ANP point, weight in m^3) entries `points[offsets[n]..offsets[n + 1]]`, one per
    /// slot keyed to it, and 1 / their weight sum (1/m^3; 0 where a node has none). J_n is the
    /// weighted mean of the points' J over the entries; the static solve's tangent
    /// differentiates it ([`crate::solver::statics`]). Last, the mesh node of each pressure
    /// node (several pressure nodes share one where materials meet).
    pub(crate) fn anp_tables(&self) -> AnpTables<'_> {
        AnpTables {
            offsets: &self.anp_offsets,
            points: &self.anp_points,
            inv_weight: &self.node_anp_inv_weight,
            node: &self.anp_key_node,
        }
    }

    /// Smallest det F over the points of the last evaluation, and the point that has it
    /// (the lowest index among equals).
    pub fn min_j(&self) -> (f64, usize) {
        self.min_j
    }

    /// Strain energy sum_p w_p W(F_p) + sum_hex u^T HG u / 2, J (mean-dilatation points: W of
    /// their F_bar; ANP points: w (W(F) - U(J) + the mean of U(J_n) over their nodes), so the
    /// volumetric part is sum_n V_n U(J_n)), the energy whose exact gradient the forces are.
    /// Deterministic (fixed-order sum).
    pub fn strain_energy(
        &mut self,
        qp: &QuadraturePoints,
        slots: &NodeSlots,
        u: &[Vector3<f64>],
    ) -> f64 {
        debug_assert_eq!(
            slots.slots.len(),
            qp.nodes.len(),
            "node slots of other points"
        );
        self.averages(qp, u);
        let mut per_point = std::mem::take(&mut self.energy_scratch);
        let this = &*self;
        per_point.par_iter_mut().enumerate().for_each(|(p, e)| {
            let (f, _) = this.stress_gradient(qp, p, u);
            let mat = this.material_at(p);
            let mut w = qp.weights[p] * mat.strain_energy(&f);
            if qp.kinds[p] == PointKind::Anp {
                // W(F) - U(J) + the point's share of its nodes' U(J_n) (see `anp_stress`).
                let r = qp.slots(p);
                let n = r.len() as f64;
                let nodal = r
                    .map(|s| mat.volumetric(this.node_j[this.pressure_node(qp, s)]).0)
                    .sum::<f64>()
                    / n;
                w += qp.weights[p] * (nodal - mat.volumetric(f.determinant()).0);
            }
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

    /// Per point: Cauchy stress P F^T / J (Pa) of the stress the kernel uses (ANP:
    /// the nodal-pressure stress `anp_stress`; mean-dilatation points: the group stress of `group_stresses`), Green-Lagrange
    /// strain E = (F^T F - I) / 2, von Mises stress (Pa) and J = det F, all of the point's own
    /// F.
    pub fn stress_fields(
        &mut self,
        qp: &QuadraturePoints,
        slots: &NodeSlots,
        u: &[Vector3<f64>],
    ) -> Fields {
        debug_assert_eq!(
            slots.slots.len(),
            qp.nodes.len(),
            "node slots of other points"
        );
        self.averages(qp, u);
        let mut out = Fields::zeros(qp.len());
        for p in 0..qp.len() {
            let plain = deformation_gradient(qp, p, u);
            let (c, j) = match qp.kinds[p] {
                PointKind::MeanDilatation(g) => {
                    let g = g as usize;
                    let i = self.group_first[g] as usize + (p - qp.groups[g][0] as usize);
                    let j = self.group_s[i][0];
                    (
                        self.group_pk[i] * plain.transpose() / (qp.weights[p] * j),
                        j,
                    )
                }
                PointKind::Anp => {
                    let j = plain.determinant();
                    let pk = self.anp_stress(qp, self.material_at(p), p, &plain, j);
                    // The volume change its pressure comes from: the mean of its nodes' J_n.
                    let r = qp.slots(p);
                    let n = r.len() as f64;
                    let j_nodes: f64 = r
                        .map(|s| self.node_j[self.pressure_node(qp, s)])
                        .sum::<f64>()
                        / n;
                    (pk * plain.transpose() / j, j_nodes)
                }
                _ => {
                    let j = plain.determinant();
                    let s = self.material_at(p).pk2_stress(&plain, j);
                    (plain * s * plain.transpose() / j, j)
                }
            };
            let e = (plain.transpose() * plain - Matrix3::identity()) * 0.5;
            out.set(p, &c, &e, j);
            out.j_own[p] = plain.determinant();
        }
        out
    }
}

/// The average-nodal-pressure tables ([`Forces::anp_tables`]).
pub(crate) struct AnpTables<'a> {
    /// Per pressure node, its (point, weight in m^3) entries `points[offsets[n]..offsets[n + 1]]`.
    pub offsets: &'a [u32],
    pub points: &'a [(u32, f64)],
    /// Per pressure node, 1 / the weight sum, 1/m^3 (0 where it has no entry).
    pub inv_weight: &'a [f64],
    /// Per pressure node, its mesh node.
    pub node: &'a [u32],
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

/// Fields of the deformation per point or per node: Cauchy stress (Pa) and Green-Lagrange
/// strain (dimensionless), each 9 values row-major per entry, von Mises stress (Pa) and J.
#[derive(Debug, Clone, PartialEq)]
pub struct Fields {
    pub cauchy: Vec<f64>,
    pub green: Vec<f64>,
    pub von_mises: Vec<f64>,
    /// The volume change the formulation uses: the point's own det F, or the averaged one
    /// where the element averages it (tet4-anp: the mean of its nodes' J_n, the volume-weighted
    /// mean J around each node; mean-dilatation groups: the group's weighted mean J).
    pub j: Vec<f64>,
    /// det F of the point's own deformation gradient. With averaged volume changes it may
    /// vary from element to element in a checkerboard that carries no pressure (tet4-anp:
    /// only the nodal J_n enter the volumetric energy).
    pub j_own: Vec<f64>,
}

impl Fields {
    /// `n` entries of zeros.
    pub fn zeros(n: usize) -> Self {
        Fields {
            cauchy: vec![0.0; 9 * n],
            green: vec![0.0; 9 * n],
            von_mises: vec![0.0; n],
            j: vec![0.0; n],
            j_own: vec![0.0; n],
        }
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.j.len()
    }

    /// No entry.
    pub fn is_empty(&self) -> bool {
        self.j.is_empty()
    }

    /// Entry `p` from its Cauchy stress `c`, strain `e` and J (von Mises from `c`).
    pub fn set(&mut self, p: usize, c: &Matrix3<f64>, e: &Matrix3<f64>, j: f64) {
        for r in 0..3 {
            for k in 0..3 {
                self.cauchy[9 * p + 3 * r + k] = c[(r, k)];
                self.green[9 * p + 3 * r + k] = e[(r, k)];
            }
        }
        let dev = c - Matrix3::identity() * (c.trace() / 3.0);
        self.von_mises[p] = (1.5 * dev.norm_squared()).sqrt();
        self.j[p] = j;
        self.j_own[p] = j;
    }

    /// Cauchy stress of entry `p`, Pa.
    pub fn cauchy_at(&self, p: usize) -> Matrix3<f64> {
        Matrix3::from_row_slice(&self.cauchy[9 * p..9 * p + 9])
    }

    /// Green-Lagrange strain of entry `p`.
    pub fn green_at(&self, p: usize) -> Matrix3<f64> {
        Matrix3::from_row_slice(&self.green[9 * p..9 * p + 9])
    }

    /// Principal stretches of entry `p`, largest first: sqrt of the eigenvalues of
    /// C = 2 E + I.
    pub fn principal_stretches(&self, p: usize) -> [f64; 3] {
        let c = self.green_at(p) * 2.0 + Matrix3::identity();
        let e = nalgebra::SymmetricEigen::new(c).eigenvalues;
        let mut l = [
            e.x.max(0.0).sqrt(),
            e.y.max(0.0).sqrt(),
            e.z.max(0.0).sqrt(),
        ];
        l.sort_by(|a, b| b.total_cmp(a));
        l
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fe::{element_points, ElementKind};
    use crate::geometry::shapes::{box_hex, box_tet};
    use crate::material::{NeoHookean, Solid};
    use nalgebra::Matrix3;

    /// A distorted displacement field with strains of several per cent.
    fn field(nodes: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        nodes
            .iter()
            .map(|x| {
                Vector3::new(
                    0.08 * x.z + 0.05 * (7.0 * x.y).sin(),
                    -0.06 * x.x + 0.03 * x.z * x.z,
                    -0.1 * x.z + 0.04 * (5.0 * x.x).cos() * x.y,
                )
            })
            .collect()
    }

    /// Nodal forces and J's with lane blocks (AVX2 where present), without AVX2, and point by
    /// point.
    fn three_ways(
        qp: &QuadraturePoints,
        nodes: &[Vector3<f64>],
        u: &[Vector3<f64>],
    ) -> Vec<(Vec<Vector3<f64>>, Vec<f64>)> {
        let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        three_ways_with(mat, qp, nodes, u)
    }

    /// [`three_ways`] for any material.
    fn three_ways_with<M: Material>(
        mat: M,
        qp: &QuadraturePoints,
        nodes: &[Vector3<f64>],
        u: &[Vector3<f64>],
    ) -> Vec<(Vec<Vector3<f64>>, Vec<f64>)> {
        let slots = NodeSlots::new(qp, nodes.len());
        let mut out = Vec::new();
        for (blocks, simd) in [(true, simd_available()), (true, false), (false, false)] {
            let mut f = Forces::new(mat.clone(), qp, &slots, nodes.len());
            let plan = plan(qp, &[], nodes.len(), blocks);
            (f.items, f.lane_data, f.chunks) = (plan.items, plan.lane_data, plan.chunks);
            f.simd = simd;
            let mut nodal = vec![Vector3::zeros(); nodes.len()];
            f.compute(qp, &slots, u, &mut nodal);
            out.push((nodal, f.point_j.clone()));
        }
        out
    }

    /// The lane kernel against the textbook formula f_k = w F S dphi_k (+ G G^T u for the
    /// hexahedra), with S from `pk2_stress` and F from nalgebra; blocks with and without AVX2
    /// against each other bitwise, and single points against blocks: the same J's, and nodal
    /// forces that differ by the summation order only.
    #[test]
    #[allow(clippy::needless_range_loop)] // p indexes the points' J, slots and kinds together
    fn lane_blocks_match_single_points_and_the_reference_formula() {
        let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        let hex = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
        let tet = box_tet(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [3, 3, 1]).unwrap();
        for (mesh, kind, plain) in [
            (hex.clone(), ElementKind::Hex8, false),
            (hex, ElementKind::Hex8, true),
            (tet.clone(), ElementKind::Tet4, false),
            (tet, ElementKind::Tet4Anp, false),
        ] {
            let mut qp = element_points(&mesh, kind, 0.05, 1e5).unwrap();
            if plain {
                // Standard 8-node points (the nearest-8 MLS path).
                qp.kinds.iter_mut().for_each(|k| *k = PointKind::Standard);
            }
            let u = field(&mesh.nodes);
            let runs = three_ways(&qp, &mesh.nodes, &u);
            assert!(
                runs[1].0 == runs[0].0 && runs[1].1 == runs[0].1,
                "{kind:?}: AVX2 and SSE2 differ"
            );
            assert!(
                runs[2].1 == runs[0].1,
                "{kind:?}: J of single points differ"
            );
            let (nodal, pj) = &runs[0];
            let mut want_nodal = vec![Vector3::zeros(); mesh.nodes.len()];
            let mut scale = 0.0f64;
            // ANP (Bonet & Burton 1998): nodal J = volume-weighted mean of the points' J, nodal
            // pressure kappa (J_n - 1), element stress = the isochoric neo-Hookean stress of its
            // own F plus J p_mean F^-T, p_mean the mean of its nodes' pressures.
            let (mut vj, mut vw) = (vec![0.0; mesh.nodes.len()], vec![0.0; mesh.nodes.len()]);
            for p in 0..qp.len() {
                let j = deformation_gradient(&qp, p, &u).determinant();
                for s in qp.slots(p) {
                    vj[qp.nodes[s] as usize] += qp.weights[p] * j;
                    vw[qp.nodes[s] as usize] += qp.weights[p];
                }
            }
            for p in 0..qp.len() {
                let f = deformation_gradient(&qp, p, &u);
                let j = f.determinant();
                assert!((pj[p] - j).abs() < 1e-14, "J at {p}");
                let pk: Matrix3<f64> = if qp.kinds[p] == PointKind::Anp {
                    let r = qp.slots(p);
                    let p_mean = r
                        .clone()
                        .map(|s| {
                            mat.kappa * (vj[qp.nodes[s] as usize] / vw[qp.nodes[s] as usize] - 1.0)
                        })
                        .sum::<f64>()
                        / r.len() as f64;
                    let f_inv_t = f.try_inverse().unwrap().transpose();
                    let iso = (f - f_inv_t * ((f.transpose() * f).trace() / 3.0))
                        * (mat.mu * j.powf(-2.0 / 3.0));
                    (iso + f_inv_t * (j * p_mean)) * qp.weights[p]
                } else {
                    f * mat.pk2_stress(&f, j) * qp.weights[p]
                };
                let r = qp.slots(p);
                let mut want: Vec<Vector3<f64>> =
                    qp.dphi[r.clone()].iter().map(|d| pk * d).collect();
                if let PointKind::Hourglass(h) = qp.kinds[p] {
                    let g = qp.hourglass[h as usize];
                    let hg = g * g.transpose();
                    for a in 0..8 {
                        for b in 0..8 {
                            want[a] += u[qp.nodes[r.start + b] as usize] * hg[(a, b)];
                        }
                    }
                }
                for (k, w) in want.iter().enumerate() {
                    want_nodal[qp.nodes[r.start + k] as usize] += w;
                    scale = scale.max(w.norm());
                }
            }
            let worst = nodal
                .iter()
                .zip(&want_nodal)
                .map(|(g, w)| (g - w).norm() / scale)
                .fold(0.0, f64::max);
            // Summation order only: a few ulps of the largest slot force.
            let order = nodal
                .iter()
                .zip(&runs[2].0)
                .map(|(g, s)| (g - s).norm() / scale)
                .fold(0.0, f64::max);
            assert!(
                order < 1e-14,
                "{kind:?}: singles differ from blocks by {order:e}"
            );
            assert!(
                worst < 1e-12,
                "{kind:?}: relative force difference {worst:e}"
            );
            // 45 hexahedra and 54 tetrahedra: full blocks and single points both run (ANP
            // blocks included).
            assert!(!qp.len().is_multiple_of(LANES) && qp.len() > LANES);
        }
    }

    /// 40 points with 3 to 31 support nodes on the nodes of `mesh` (4 and 8 among them, so
    /// runs of single-evaluated points are cut by lane-mode points).
    fn any_size_points(n: usize) -> QuadraturePoints {
        any_size_points_of(n, 40)
    }

    /// `count` points made as [`any_size_points`] makes its 40.
    fn any_size_points_of(n: usize, count: usize) -> QuadraturePoints {
        let mut qp = QuadraturePoints::with_capacity(count, 20 * count);
        for p in 0..count {
            let size = 3 + (p * 11) % 29;
            let ids: Vec<usize> = (0..size).map(|k| (p * 17 + k * 5) % n).collect();
            let d: Vec<Vector3<f64>> = (0..size)
                .map(|k| {
                    let s = (p * 31 + k * 7) as f64;
                    Vector3::new((0.7 * s).sin(), (1.3 * s).cos(), (0.37 * s).sin() - 0.2) * 20.0
                })
                .collect();
            qp.push(&ids, &d, 1e-6 * (1.0 + (p % 3) as f64), PointKind::Standard);
        }
        qp
    }

    /// Nodal forces by the textbook formula f_k = w F S dphi_k, S from `pk2_stress`, and the
    /// largest slot force; asserts the kernel's J's.
    fn reference_forces<M: Material>(
        mat: &M,
        qp: &QuadraturePoints,
        u: &[Vector3<f64>],
        j_kernel: &[f64],
    ) -> (Vec<Vector3<f64>>, f64) {
        let mut want = vec![Vector3::zeros(); u.len()];
        let mut scale = 0.0f64;
        assert_eq!(j_kernel.len(), qp.len());
        for (p, &jk) in j_kernel.iter().enumerate() {
            let f = deformation_gradient(qp, p, u);
            let j = f.determinant();
            assert!(j > 0.5, "test field inverts point {p}: J = {j}");
            assert!((jk - j).abs() < 1e-14, "J at {p}");
            let pk: Matrix3<f64> = f * mat.pk2_stress(&f, j) * qp.weights[p];
            for s in qp.slots(p) {
                let fk = pk * qp.dphi[s];
                want[qp.nodes[s] as usize] += fk;
                scale = scale.max(fk.norm());
            }
        }
        (want, scale)
    }

    fn worst_relative(got: &[Vector3<f64>], want: &[Vector3<f64>], scale: f64) -> f64 {
        got.iter()
            .zip(want)
            .map(|(g, w)| (g - w).norm() / scale)
            .fold(0.0, f64::max)
    }

    /// Points with 3 to 31 support nodes (the MLS and transition points' path), with AVX2
    /// against without bitwise, and against the textbook formula f_k = w F S dphi_k.
    #[test]
    fn any_size_points_match_without_avx2_and_the_reference_formula() {
        let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
        let qp = any_size_points(mesh.nodes.len());
        let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
        let runs = three_ways(&qp, &mesh.nodes, &u);
        assert!(
            runs[1].0 == runs[0].0 && runs[1].1 == runs[0].1,
            "any-size points: AVX2 and SSE2 differ"
        );
        let (want, scale) = reference_forces(&mat, &qp, &u, &runs[0].1);
        let worst = worst_relative(&runs[0].0, &want, scale);
        assert!(worst < 1e-12, "relative force difference {worst:e}");
    }

    /// The any-size points in consecutive mean-dilatation groups of 2 to 6 points.
    fn grouped_points(n: usize) -> QuadraturePoints {
        grouped_points_of(n, 40)
    }

    /// `count` any-size points in groups as [`grouped_points`] makes them.
    fn grouped_points_of(n: usize, count: usize) -> QuadraturePoints {
        let qp = any_size_points_of(n, count);
        let mut out = QuadraturePoints::with_capacity(qp.len(), qp.nodes.len());
        let (mut p, mut size) = (0, 2);
        while p < qp.len() {
            let end = (p + size).min(qp.len());
            let pts: Vec<_> = (p..end)
                .map(|q| {
                    let r = qp.slots(q);
                    let ids = qp.nodes[r.clone()].iter().map(|&x| x as usize).collect();
                    (ids, qp.dphi[r].to_vec(), qp.weights[q])
                })
                .collect();
            out.push_group(&pts);
            p = end;
            size = 2 + size % 5;
        }
        out
    }

    /// Mean-dilatation groups against Nagtegaal's closed form for the neo-Hookean solid,
    /// P_p = mu J_p^(-2/3) (F_p - tr(C_p) / 3 F_p^-T) + J_p kappa (J_mean - 1) F_p^-T: the same
    /// forces to 1e-12, bitwise with and without AVX2, and every point's own J.
    #[test]
    fn mean_dilatation_is_nagtegaal_for_the_neo_hookean_solid() {
        let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
        let qp = grouped_points(mesh.nodes.len());
        let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
        let runs = three_ways(&qp, &mesh.nodes, &u);
        for (k, r) in runs.iter().enumerate().skip(1) {
            assert!(r == &runs[0], "run {k} differs from the AVX2 run");
        }
        let (want, scale, spread) = nagtegaal_forces(&mat, &qp, &u, &runs[0].1);
        // The field must make the points of a group differ, or any J_mean scaling would pass.
        assert!(spread > 0.05, "J within a group varies by {spread:e} only");
        let worst = worst_relative(&runs[0].0, &want, scale);
        assert!(worst < 1e-12, "relative force difference {worst:e}");
    }

    /// Nodal forces of mean-dilatation groups by Nagtegaal's closed form (see the test above),
    /// the largest slot force and the largest |J / J_mean - 1| in a group; asserts the
    /// kernel's J's.
    fn nagtegaal_forces(
        mat: &NeoHookean,
        qp: &QuadraturePoints,
        u: &[Vector3<f64>],
        j_kernel: &[f64],
    ) -> (Vec<Vector3<f64>>, f64, f64) {
        let mut want = vec![Vector3::zeros(); u.len()];
        let (mut scale, mut spread) = (0.0f64, 0.0f64);
        for &[a, b] in &qp.groups {
            let (a, b) = (a as usize, b as usize);
            let fs: Vec<Matrix3<f64>> = (a..b).map(|p| deformation_gradient(qp, p, u)).collect();
            let w: f64 = qp.weights[a..b].iter().sum();
            let j_mean = (a..b)
                .map(|p| qp.weights[p] * fs[p - a].determinant())
                .sum::<f64>()
                / w;
            for p in a..b {
                let f = fs[p - a];
                let j = f.determinant();
                assert_eq!(j_kernel[p], j, "the kernel's J of point {p}");
                spread = spread.max((j / j_mean - 1.0).abs());
                let f_inv_t = f.try_inverse().unwrap().transpose();
                let iso = (f - f_inv_t * ((f.transpose() * f).trace() / 3.0))
                    * (mat.mu * j.powf(-2.0 / 3.0));
                let pk = (iso + f_inv_t * (j * mat.kappa * (j_mean - 1.0))) * qp.weights[p];
                for s in qp.slots(p) {
                    let fk = pk * qp.dphi[s];
                    want[qp.nodes[s] as usize] += fk;
                    scale = scale.max(fk.norm());
                }
            }
        }
        (want, scale, spread)
    }

    /// Groups over many chunks (600 points, 10,183 slots: 10 chunks): no chunk cuts a group, as
    /// the chunk holding a group evaluates its stresses just before its forces
    /// (`group_point`); the stresses are bitwise those of the separate pass
    /// (`group_stresses`, which the energies and output fields use) and, evaluated four points
    /// at a time, bitwise those of one point at a time; the forces are the same for any
    /// thread count, and Nagtegaal's to 1e-12 (as in the test above).
    #[test]
    fn no_chunk_cuts_a_mean_dilatation_group() {
        let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
        let qp = grouped_points_of(mesh.nodes.len(), 600);
        let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
        let slots = NodeSlots::new(&qp, mesh.nodes.len());
        let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        let mut f = Forces::new(mat.clone(), &qp, &slots, mesh.nodes.len());
        assert!(f.chunks.len() > 4, "{} chunks", f.chunks.len());
        let mut cut_somewhere = false;
        for ch in &f.chunks {
            let items = &f.items[ch.items[0] as usize..ch.items[1] as usize];
            let (a, b) = (
                items[0].first,
                items.last().map(|i| i.first + i.count as u32),
            );
            let b = b.unwrap();
            for &[g0, g1] in &qp.groups {
                assert!(
                    g1 <= a || g0 >= b || (g0 >= a && g1 <= b),
                    "group {g0}..{g1} cut"
                );
            }
            cut_somewhere |= b < qp.len() as u32;
        }
        assert!(cut_somewhere);
        let run = |threads: usize, f: &mut Forces<NeoHookean>| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut nodal = vec![Vector3::zeros(); u.len()];
            pool.install(|| f.compute(&qp, &slots, &u, &mut nodal));
            nodal
        };
        let one = run(1, &mut f);
        let (pk, j) = (f.group_pk.clone(), f.group_j.clone());
        assert_eq!(run(3, &mut f), one);
        f.group_stresses(&qp, &u);
        assert!(f.group_pk == pk && f.group_j == j);
        // The stresses, evaluated four points at a time, bitwise those of one point at a
        // time (as the GPU kernel takes them).
        for (g, &[a, b]) in qp.groups.iter().enumerate() {
            let (a, b, i0) = (a as usize, b as usize, f.group_first[g] as usize);
            let fs: Vec<_> = (a..b).map(|p| deformation_gradient(&qp, p, &u)).collect();
            let w: f64 = (a..b).map(|p| qp.weights[p]).sum();
            let jm = (a..b)
                .map(|p| qp.weights[p] * fs[p - a].determinant())
                .sum::<f64>()
                / w;
            let bar: Vec<_> = fs.iter().map(|f| f * cbrt(jm / f.determinant())).collect();
            let pb: Vec<_> = bar.iter().map(|fb| mat.first_pk_stress(fb, jm)).collect();
            let tau: Vec<f64> = (0..b - a).map(|k| pb[k].dot(&bar[k]) / 3.0).collect();
            let t = (a..b).map(|p| qp.weights[p] * tau[p - a]).sum::<f64>() / w;
            for (k, p) in (a..b).enumerate() {
                let (jp, alpha) = (fs[k].determinant(), cbrt(jm / fs[k].determinant()));
                let cof = crate::geometry::cofactor(&fs[k]);
                let want = (pb[k] * alpha + cof * (t / jm - tau[k] / jp)) * qp.weights[p];
                assert_eq!(f.group_pk[i0 + k], want, "point {p}");
            }
        }
        let runs = three_ways(&qp, &mesh.nodes, &u);
        assert_eq!(runs[0].0, one);
        for (k, r) in runs.iter().enumerate().skip(1) {
            assert!(r == &runs[0], "run {k} differs from the AVX2 run");
        }
        let (want, scale, spread) = nagtegaal_forces(&mat, &qp, &u, &runs[0].1);
        assert!(spread > 0.05, "{spread:e}");
        let worst = worst_relative(&one, &want, scale);
        assert!(worst < 1e-12, "relative force difference {worst:e}");
    }

    /// Internal forces are the gradient of the strain energy the run reports (the energy
    /// balance depends on it): central differences of `strain_energy` against `compute` for
    /// one-point hexahedra with hourglass control, points of any support size, mean-dilatation
    /// groups (neo-Hookean and Ogden) and ANP tetrahedra (one material, and two materials with
    /// different bulk moduli meeting at shared nodes). The F-bar stress of the modified points,
    /// w P(F_bar) dphi with F_bar = (J_avg / J)^(1/3) F (groups before `group_stresses`, ANP as
    /// Joldes et al. 2009 and NiftySim), misses the gradient by far more than the tolerance.
    #[test]
    fn forces_are_the_gradient_of_the_strain_energy() {
        fn check<M: Material>(
            name: &str,
            materials: Vec<M>,
            point_material: Vec<u16>,
            qp: &QuadraturePoints,
            nodes: &[Vector3<f64>],
            u: &[Vector3<f64>],
        ) -> f64 {
            let slots = NodeSlots::new(qp, nodes.len());
            let mut f = Forces::with_materials(materials, point_material, qp, &slots, nodes.len());
            let mut got = vec![Vector3::zeros(); nodes.len()];
            f.compute(qp, &slots, u, &mut got);
            let h = 1e-7;
            let mut grad = vec![Vector3::zeros(); nodes.len()];
            let mut v = u.to_vec();
            for n in 0..nodes.len() {
                for c in 0..3 {
                    v[n][c] = u[n][c] + h;
                    let ep = f.strain_energy(qp, &slots, &v);
                    v[n][c] = u[n][c] - h;
                    let em = f.strain_energy(qp, &slots, &v);
                    v[n][c] = u[n][c];
                    grad[n][c] = (ep - em) / (2.0 * h);
                }
            }
            let scale = got.iter().map(|g| g.norm()).fold(0.0, f64::max);
            assert!(scale > 0.0);
            let worst = worst_relative(&got, &grad, scale);
            println!("{name}: |F_int - dE/du| / max |F_int| = {worst:e}");
            assert!(
                worst < 1e-6,
                "{name}: forces miss the energy gradient by {worst:e}"
            );
            // F-bar alone. `strain_energy` left the nodal and group J's of u (its last call).
            f.averages(qp, u);
            let mut fbar = vec![Vector3::zeros(); nodes.len()];
            for p in 0..qp.len() {
                let plain = deformation_gradient(qp, p, u);
                let j = plain.determinant();
                let j_avg = match qp.kinds[p] {
                    PointKind::Anp => {
                        let r = qp.slots(p);
                        let n = r.len() as f64;
                        r.map(|s| f.node_j[f.pressure_node(qp, s)]).sum::<f64>() / n
                    }
                    PointKind::MeanDilatation(g) => f.group_j[g as usize],
                    _ => j,
                };
                let fb = plain * (j_avg / j).cbrt();
                let pk = f.material_at(p).first_pk_stress(&fb, j_avg) * qp.weights[p];
                for s in qp.slots(p) {
                    fbar[qp.nodes[s] as usize] += pk * qp.dphi[s];
                }
            }
            worst_relative(&fbar, &grad, scale)
        }
        let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
        let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
        let nh = NeoHookean::from_young_poisson(3000.0, 0.45, 1000.0);
        let ogden = crate::material::Ogden {
            mu: 1006.7,
            alpha: -4.7,
            kappa: 1006.7 * 20.0,
            density: 1040.0,
        };
        let hex = element_points(&mesh, ElementKind::Hex8, 0.05, 1e5).unwrap();
        check(
            "hex8 with hourglass",
            vec![nh],
            vec![],
            &hex,
            &mesh.nodes,
            &u,
        );
        let any = any_size_points(mesh.nodes.len());
        check("any-size points", vec![nh], vec![], &any, &mesh.nodes, &u);
        let groups = grouped_points(mesh.nodes.len());
        let tet = box_tet(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
        let tu = field(&tet.nodes);
        let anp = element_points(&tet, ElementKind::Tet4Anp, 0.05, 1e5).unwrap();
        // Two tissues split at x = 0.05 m: neo-Hookean (nu = 0.45) and Ogden (kappa = 20 mu).
        let two: Vec<u16> = (0..anp.len())
            .map(|p| {
                let r = anp.slots(p);
                let x = r.map(|s| tet.nodes[anp.nodes[s] as usize].x).sum::<f64>() / 4.0;
                u16::from(x > 0.05)
            })
            .collect();
        let solids = vec![Solid::from(nh), Solid::Ogden(ogden)];
        for (name, off) in [
            (
                "groups, neo-Hookean",
                check(
                    "groups, neo-Hookean",
                    vec![nh],
                    vec![],
                    &groups,
                    &mesh.nodes,
                    &u,
                ),
            ),
            (
                "groups, Ogden",
                check(
                    "groups, Ogden",
                    vec![ogden],
                    vec![],
                    &groups,
                    &mesh.nodes,
                    &u,
                ),
            ),
            (
                "ANP, neo-Hookean",
                check("ANP, neo-Hookean", vec![nh], vec![], &anp, &tet.nodes, &tu),
            ),
            (
                "ANP, two materials",
                check("ANP, two materials", solids, two, &anp, &tet.nodes, &tu),
            ),
        ] {
            println!("{name}: F-bar stress alone misses the gradient by {off:e}");
            assert!(
                off > 1e-4,
                "{name}: the test field cannot tell F-bar from its gradient ({off:e})"
            );
        }
    }

    /// Points taken four at a time for the stress (`Mode::Other` blocks) give bitwise the forces and
    /// J's of the points taken one by one, with and without AVX2, and match the textbook
    /// formula: Ogden and neo-Hookean.
    #[test]
    fn stress_batches_match_single_points_bitwise() {
        fn check<M: Material>(mat: M) {
            let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
            let qp = any_size_points(mesh.nodes.len());
            let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
            let p = plan(&qp, &[], mesh.nodes.len(), true);
            let batches = p
                .items
                .iter()
                .filter(|it| it.mode == Mode::Other && it.count as usize == LANES)
                .count();
            assert!(batches >= 3, "only {batches} stress batches in the test");
            let runs = three_ways_with(mat.clone(), &qp, &mesh.nodes, &u);
            for (k, r) in runs.iter().enumerate().skip(1) {
                assert!(
                    r.0 == runs[0].0 && r.1 == runs[0].1,
                    "run {k} differs from the batched AVX2 run"
                );
            }
            let (want, scale) = reference_forces(&mat, &qp, &u, &runs[0].1);
            let worst = worst_relative(&runs[0].0, &want, scale);
            assert!(worst < 1e-12, "relative force difference {worst:e}");
        }
        check(crate::material::Ogden {
            mu: 1006.7,
            alpha: -4.7,
            kappa: 1006.7 * 100.0,
            density: 1040.0,
        });
        check(NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0));
    }
}
