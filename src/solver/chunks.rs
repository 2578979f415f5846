//! Chunked force assembly: the points (in space-filling-curve order, see [`super::order`]) are
//! cut, once and for all, into chunks of consecutive, hence nearby, points;
//! each chunk sums its points' forces into a small buffer of its own with one entry per node it
//! reaches, and each node then sums its entries over the chunks in chunk order.
//!
//! The partition depends on the discretization only, never on the thread count, so the sums
//! are bitwise the same on any number of threads. Against one force per slot gathered node by
//! node, the chunk buffers are far smaller (the 21,218-node brain with 29-node supports went
//! from 1,801 to 1,240 bytes per point), they stay in cache while a chunk runs, and the nodal
//! sums read a few entries per node instead of every slot in scattered order.

use crate::quadrature::QuadraturePoints;

/// Where each slot's force goes: its node's entry in its chunk's buffer, and per node the
/// entries to sum, in chunk order.
#[derive(Debug, Clone, Default)]
pub struct Buffers {
    /// Per slot (indexed like `QuadraturePoints::nodes`): the buffer entry it adds into.
    pub slot_entry: Vec<u32>,
    /// Per chunk, its buffer's entry range [first, end); the last end is the buffers' total
    /// length ([`Buffers::len`]).
    pub ranges: Vec<[u32; 2]>,
    /// Per node: its first entry in chunk order, or [`Buffers::len`] for a node no point
    /// reaches (the force buffer keeps one zero entry past the chunks' for it).
    pub first: Vec<u32>,
    /// The entries after each node's first, as (node, entry), node by node and in chunk order
    /// within a node: node n's are `extras[extra_start[n]..extra_start[n + 1]]`. With `first`,
    /// the nodal sums run as two loops of fixed shape instead of one loop per node whose length
    /// the branch predictor cannot guess.
    pub extras: Vec<[u32; 2]>,
    /// Per node n (and n = num_nodes), where its extras start.
    pub extra_start: Vec<u32>,
}

/// Builds the buffers for chunks of consecutive points (`chunks[c]` = [first, end)), each
/// node's entry in a chunk numbered by its first appearance there.
///
/// # Panics
/// When the entries exceed u32 ids (about 4e9; the slots would not fit in memory first).
pub fn buffers(qp: &QuadraturePoints, chunks: &[[u32; 2]], num_nodes: usize) -> Buffers {
    let mut slot_entry = vec![0u32; qp.nodes.len()];
    // Per node: the chunk it was last seen in (+1) and its entry there.
    let mut seen = vec![(0u32, 0u32); num_nodes];
    let mut owner: Vec<u32> = Vec::new();
    let mut ranges = Vec::with_capacity(chunks.len());
    for (c, &[p0, p1]) in chunks.iter().enumerate() {
        let stamp = u32::try_from(c + 1).expect("chunk count beyond u32");
        let first = owner.len() as u32;
        for p in p0 as usize..p1 as usize {
            for s in qp.slots(p) {
                let n = qp.nodes[s] as usize;
                if seen[n].0 != stamp {
                    let e = u32::try_from(owner.len()).expect("buffer entries beyond u32");
                    seen[n] = (stamp, e);
                    owner.push(n as u32);
                }
                slot_entry[s] = seen[n].1;
            }
        }
        ranges.push([first, owner.len() as u32]);
    }
    let (offsets, entries) = by_node(&owner, num_nodes);
    let none = owner.len() as u32;
    let mut first = Vec::with_capacity(num_nodes);
    let mut extras = Vec::with_capacity(entries.len().saturating_sub(num_nodes));
    let mut extra_start = Vec::with_capacity(num_nodes + 1);
    for n in 0..num_nodes {
        let own = &entries[offsets[n] as usize..offsets[n + 1] as usize];
        extra_start.push(extras.len() as u32);
        first.push(own.first().copied().unwrap_or(none));
        extras.extend(own.iter().skip(1).map(|&e| [n as u32, e]));
    }
    extra_start.push(extras.len() as u32);
    Buffers {
        slot_entry,
        ranges,
        first,
        extras,
        extra_start,
    }
}

impl Buffers {
    /// Entries of all chunk buffers together.
    pub fn len(&self) -> usize {
        self.ranges.last().map_or(0, |r| r[1] as usize)
    }

    /// Whether no chunk reaches any node.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Entries grouped by node (`owner[e]` = the node of entry e): per node n,
/// `entries[offsets[n]..offsets[n + 1]]` in increasing entry order (a counting sort, so chunk
/// order is kept).
fn by_node(owner: &[u32], num_nodes: usize) -> (Vec<u32>, Vec<u32>) {
    let mut offsets = vec![0u32; num_nodes + 1];
    for &n in owner {
        offsets[n as usize + 1] += 1;
    }
    for i in 0..num_nodes {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut entries = vec![0u32; owner.len()];
    for (e, &n) in owner.iter().enumerate() {
        entries[fill[n as usize] as usize] = e as u32;
        fill[n as usize] += 1;
    }
    (offsets, entries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn every_slot_adds_into_its_own_nodes_entry_of_its_chunk() {
        let mut qp = QuadraturePoints::with_capacity(3, 9);
        let d = [Vector3::zeros(); 3];
        qp.push(&[0, 1, 2], &d, 1.0, crate::quadrature::PointKind::Standard);
        qp.push(&[2, 3, 1], &d, 1.0, crate::quadrature::PointKind::Standard);
        qp.push(&[3, 4, 0], &d, 1.0, crate::quadrature::PointKind::Standard);
        let b = buffers(&qp, &[[0, 2], [2, 3]], 5);
        // Chunk 0 reaches nodes 0, 1, 2, 3; chunk 1 nodes 3, 4, 0.
        assert_eq!(b.ranges, vec![[0, 4], [4, 7]]);
        assert_eq!(b.slot_entry, vec![0, 1, 2, 2, 3, 1, 4, 5, 6]);
        assert_eq!(b.len(), 7);
        // Node 0: entries 0 and 6, node 1: 1, node 2: 2, node 3: 3 and 4, node 4: 5 (chunk
        // order), as first entries and then the rest node by node.
        assert_eq!(b.first, vec![0, 1, 2, 3, 5]);
        assert_eq!(b.extras, vec![[0, 6], [3, 4]]);
        assert_eq!(b.extra_start, vec![0, 1, 1, 1, 2, 2]);
        // A node no point reaches gets the zero entry past the buffers.
        let b = buffers(&qp, &[[0, 3]], 6);
        assert_eq!(b.first[5], b.len() as u32);
        assert_eq!(b.extra_start, vec![0; 7]);
    }
}
