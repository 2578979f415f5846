//! The evaluation plan: the points cut once into chunks of nearby points (fixed by the
//! discretization, so the sums do not depend on the thread count), each chunk's work items
//! (lane blocks of one kind and material, or single points), the lane-ordered copies of the
//! blocks' data, and the chunks' force buffers.

use super::*;

/// Force chunks hold about 1/`CHUNKS` of the slots, but at least `MIN_CHUNK_SLOTS` (so that a
/// chunk's work dwarfs its scheduling and the nodes it shares with other chunks) and at most
/// `MAX_CHUNK_SLOTS` (so that its buffer, one entry per node it reaches, stays in L2).
/// Fixed by the discretization alone: the sums do not depend on the thread count. The cap
/// acts only above 4 million slots. On the brain (11 million slots), 100 steps, ms per step at
/// 1 / 2 threads, interleaved: cap 16,384 (four rounds) 83-138 / 48-59, 65,536 (four rounds,
/// faster in each) 79-94 / 46-56, 4,096 (two) 102-105 / 64-68, 262,144 (two, i.e. 1/64 of the
/// slots) 75-85 / 44-55.
pub(super) const CHUNKS: usize = 64;

pub(super) const MIN_CHUNK_SLOTS: usize = 1024;

pub(super) const MAX_CHUNK_SLOTS: usize = 65536;

/// How a work item evaluates its points (see [`Forces::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Mode {
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
pub(super) struct Item {
    pub(super) first: u32,
    pub(super) count: u8,
    pub(super) mode: Mode,
    /// Index into `Forces::materials` of every point of the item.
    pub(super) material: u16,
    /// Blocks: first entry of the block's data in `Forces::lane_data`.
    pub(super) lane: u32,
}

/// A chunk: its work items `items[first..end]` and its buffer entries `first..end`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Chunk {
    pub(super) items: [u32; 2],
    pub(super) buf: [u32; 2],
}

/// The mode of point `p` by its kind and support size.
pub(super) fn point_mode(qp: &QuadraturePoints, p: usize) -> Mode {
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
pub(super) struct Plan {
    /// The points in evaluation order (chunk by chunk), grouped into lane blocks where
    /// possible.
    pub(super) items: Vec<Item>,
    /// Lane-ordered copies of the blocks' constant data, so the kernel reads them as vectors:
    /// per block dphi as [k][c][lane] (N x 3 entries), then for hexahedra G as [m][r][lane]
    /// (4 x 8 entries).
    pub(super) lane_data: Vec<[f64; LANES]>,
    /// The chunks in evaluation order.
    pub(super) chunks: Vec<Chunk>,
    /// Where each slot adds its force, and each node's entries.
    pub(super) buffers: Buffers,
    /// The chunks' force buffers (one entry per node a chunk reaches, and one more, always
    /// zero: the `first` entry of nodes no point reaches), N.
    pub(super) chunk_forces: Vec<Vector3<f64>>,
}

impl Plan {
    /// Heap bytes of the items, lane data, chunks, buffer maps and force buffers.
    pub(super) fn bytes(&self) -> usize {
        let b = &self.buffers;
        heap_bytes(&self.items)
            + heap_bytes(&self.lane_data)
            + heap_bytes(&self.chunks)
            + heap_bytes(&self.chunk_forces)
            + heap_bytes(&b.slot_entry)
            + heap_bytes(&b.ranges)
            + heap_bytes(&b.first)
            + heap_bytes(&b.extras)
            + heap_bytes(&b.extra_start)
    }
}

/// Work items covering every point once in order, cut into chunks of consecutive points
/// (about `qp.nodes.len() / CHUNKS` slots each). Within a chunk, `LANES` consecutive points of
/// one lane mode and one material become a block (when `blocks`; for `Other` points a stress
/// batch), the rest single points. The chunks do not depend on `blocks`.
pub(super) fn plan(
    qp: &QuadraturePoints,
    point_material: &[u16],
    num_nodes: usize,
    blocks: bool,
) -> Plan {
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
        chunk_forces: vec![Vector3::zeros(); buffers.len() + 1],
        buffers,
    }
}

impl<M: Material> Forces<M> {
    /// The slots in the order the chunks add their forces into the buffer entries: chunk by
    /// chunk, item by item; a lane block slot by slot across its points, any other item point
    /// by point. Another evaluator (the GPU one, [`crate::solver::gpu`]) that sums each entry's slot
    /// forces in this order from zero gets bitwise the CPU's entries.
    pub fn contribution_order(&self, qp: &QuadraturePoints) -> Vec<u32> {
        let mut out = Vec::with_capacity(qp.nodes.len());
        for it in &self.plan.items {
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
}
