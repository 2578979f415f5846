//! Quadrature points in space-filling-curve order. Discretizations emit points in the order
//! of their elements or background cells (TetGen's order scatters them); the time loop streams
//! through the points, so the model stores them sorted along a Morton curve: the point data is
//! then read in order and a point's nodes were mostly touched by the points just before it.
//! Measured on the 21,218-node brain (379,548 points, 29 nodes each, 2 threads): 147 -> 48 ms
//! per step with the same chunked assembly, in back-to-back runs.

use nalgebra::{SMatrix, Vector3};

use crate::quadrature::{PointKind, QuadraturePoints};

/// Bits per axis of the Morton key (3 x 21 = 63 bits).
const MORTON_BITS: u32 = 21;

/// Spreads the low 21 bits of `v` to every third bit.
fn spread(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// Morton (Z-order) key of `x` in the box [lo, lo + size].
fn morton(x: &Vector3<f64>, lo: &Vector3<f64>, size: &Vector3<f64>) -> u64 {
    let scale = ((1u64 << MORTON_BITS) - 1) as f64;
    let q = |c: usize| {
        let t = if size[c] > 0.0 {
            ((x[c] - lo[c]) / size[c]).clamp(0.0, 1.0)
        } else {
            0.0
        };
        spread((t * scale) as u64)
    };
    q(0) | q(1) << 1 | q(2) << 2
}

/// `qp` reordered along a Morton curve through the centroids of the points' supports
/// (reference coordinates `nodes`, m); a mean-dilatation group moves as one, keyed by its
/// first point. Equal keys keep their order, so the result depends on the input alone.
/// Returns the reordered points and, for each, its id in `qp`.
pub fn spatial_order(qp: QuadraturePoints, nodes: &[Vector3<f64>]) -> (QuadraturePoints, Vec<u32>) {
    let n = qp.len();
    assert!(
        n < u32::MAX as usize,
        "{n} quadrature points exceed the u32 point ids"
    );
    // Units: [first, end) point ranges that stay together.
    let mut units: Vec<[usize; 2]> = Vec::with_capacity(n);
    let mut p = 0;
    while p < n {
        let end = match qp.kinds[p] {
            PointKind::MeanDilatation(g) => (qp.groups[g as usize][1] as usize).max(p + 1),
            _ => p + 1,
        };
        units.push([p, end]);
        p = end;
    }
    if nodes.is_empty() {
        return (qp, (0..n as u32).collect());
    }
    let (lo, hi) = crate::geometry::select::bounds(nodes);
    let size = hi - lo;
    let mut keyed: Vec<(u64, usize)> = units
        .iter()
        .enumerate()
        .map(|(i, &[p, _])| {
            let r = qp.slots(p);
            let len = r.len().max(1) as f64;
            let c = r.map(|s| nodes[qp.nodes[s] as usize]).sum::<Vector3<f64>>() / len;
            (morton(&c, &lo, &size), i)
        })
        .collect();
    keyed.sort_unstable();
    let mut out = QuadraturePoints::with_capacity(n, qp.nodes.len());
    let mut ids = Vec::with_capacity(n);
    let point = |p: usize| {
        let r = qp.slots(p);
        let v: Vec<usize> = qp.nodes[r.clone()].iter().map(|&x| x as usize).collect();
        (v, qp.dphi[r].to_vec(), qp.weights[p])
    };
    for (_, i) in keyed {
        let [a, b] = units[i];
        ids.extend(a as u32..b as u32);
        match qp.kinds[a] {
            PointKind::MeanDilatation(_) => {
                let pts: Vec<_> = (a..b).map(point).collect();
                out.push_group(&pts);
            }
            PointKind::Hourglass(h) => {
                let (v, d, w) = point(a);
                let d: [Vector3<f64>; 8] = d.try_into().expect("one-point hexahedra have 8 nodes");
                let g: SMatrix<f64, 8, 4> = qp.hourglass[h as usize];
                out.push_hourglass(&v, &d, w, g);
            }
            kind => {
                let (v, d, w) = point(a);
                out.push(&v, &d, w, kind);
            }
        }
    }
    (out, ids)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fe::{element_points, ElementKind};
    use crate::geometry::shapes::box_hex;

    #[test]
    fn morton_keys_interleave_the_axes() {
        assert_eq!(spread(0b101), 0b1_000_001);
        let (lo, size) = (Vector3::zeros(), Vector3::repeat(1.0));
        let k = |x, y, z| morton(&Vector3::new(x, y, z), &lo, &size);
        assert_eq!(k(0.0, 0.0, 0.0), 0);
        assert!(k(1.0, 0.0, 0.0) < k(0.0, 1.0, 0.0) && k(0.0, 1.0, 0.0) < k(0.0, 0.0, 1.0));
        assert_eq!(k(1.0, 1.0, 1.0), (1u64 << 63) - 1);
        // Outside the box clamps to its faces.
        assert_eq!(k(-1.0, 2.0, 0.5), k(0.0, 1.0, 0.5));
    }

    /// Every point keeps its data under its new id, groups stay whole, and the order follows
    /// the curve: in a 4 x 4 x 4 block of hexahedra the first 8 are the lowest 2 x 2 x 2 corner.
    #[test]
    fn reordering_keeps_every_point_and_groups_whole() {
        let mesh = box_hex(Vector3::zeros(), Vector3::repeat(1.0), [4, 4, 4]).unwrap();
        let hex = element_points(&mesh, ElementKind::Hex8, 0.05, 1e5).unwrap();
        // Each element's point twice at half weight as a mean-dilatation group.
        let mut groups = QuadraturePoints::default();
        groups.offsets.push(0);
        for p in 0..hex.len() {
            let r = hex.slots(p);
            let v: Vec<usize> = hex.nodes[r.clone()].iter().map(|&x| x as usize).collect();
            let d = hex.dphi[r].to_vec();
            let w = 0.5 * hex.weights[p];
            groups.push_group(&[(v.clone(), d.clone(), w), (v, d, w)]);
        }
        for (kind, qp) in [("hourglass", hex), ("groups", groups)] {
            let (sorted, ids) = spatial_order(qp.clone(), &mesh.nodes);
            assert_eq!(sorted.len(), qp.len());
            let mut seen = ids.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..qp.len() as u32).collect::<Vec<_>>());
            assert_ne!(
                ids, seen,
                "{kind:?}: the mesher's order is not the Morton order"
            );
            for (q, &p) in ids.iter().enumerate() {
                let p = p as usize;
                assert_eq!(sorted.nodes[sorted.slots(q)], qp.nodes[qp.slots(p)]);
                assert_eq!(sorted.dphi[sorted.slots(q)], qp.dphi[qp.slots(p)]);
                assert_eq!(sorted.weights[q], qp.weights[p]);
                match (sorted.kinds[q], qp.kinds[p]) {
                    (PointKind::Hourglass(a), PointKind::Hourglass(b)) => {
                        assert_eq!(sorted.hourglass[a as usize], qp.hourglass[b as usize])
                    }
                    (PointKind::MeanDilatation(a), PointKind::MeanDilatation(b)) => {
                        let [a0, a1] = sorted.groups[a as usize];
                        let [b0, b1] = qp.groups[b as usize];
                        assert_eq!(a1 - a0, b1 - b0);
                        assert_eq!(ids[a0 as usize], b0, "group moved whole");
                    }
                    (a, b) => assert_eq!(a, b),
                }
            }
            let per_cell = qp.len() / 64;
            let centroid = |q: usize| {
                let r = sorted.slots(q);
                r.clone()
                    .map(|s| mesh.nodes[sorted.nodes[s] as usize])
                    .sum::<Vector3<f64>>()
                    / r.len() as f64
            };
            for q in 0..8 * per_cell {
                assert!(
                    centroid(q).max() < 0.5,
                    "{kind:?}: point {q} outside the first octant"
                );
            }
        }
    }
}
