//! The one representation every discretization produces: a flat list of quadrature points,
//! each a list of supporting node ids, the reference derivatives dphi/dX of their shape
//! functions at the point, and a weight (reference volume, m^3). Structure of arrays.

use nalgebra::{SMatrix, Vector3};

/// One sparse row of interpolation factors, the one type every method and condition uses:
/// (node index, value) pairs, e.g. the shape-function values of a point's supporting nodes, or
/// one column of the EBCIEM system.
pub type SparseRow = Vec<(u32, f64)>;

/// What the force kernel adds to the plain total-Lagrangian point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointKind {
    /// Plain point: forces f_a = w F S dphi_a.
    Standard,
    /// One-point hexahedron: plus the hourglass force HG u; index into `hourglass`.
    Hourglass(u32),
    /// Average-nodal-pressure tetrahedron (Bonet & Burton 1998): the stress of its own F with
    /// its pressure U'(J) swapped for the mean of its nodes' pressures U'(J_n), J_n the
    /// volume-weighted mean J of the elements around node n.
    Anp,
    /// Point of a fully integrated cell with mean dilatation (Nagtegaal et al. 1974; the
    /// volumetric part of selectively reduced integration): J replaced by the weighted mean J
    /// of the cell's points, `groups[g]`. Keeps fully integrated blended cells from locking
    /// as nu -> 0.5.
    MeanDilatation(u32),
}

/// Quadrature points in structure-of-arrays form. Point `p` owns the slots
/// `offsets[p]..offsets[p + 1]` of `nodes` and `dphi`.
#[derive(Debug, Clone, Default)]
pub struct QuadraturePoints {
    pub offsets: Vec<usize>,
    /// Supporting node ids, one per slot.
    pub nodes: Vec<u32>,
    /// dphi/dX of the slot's node at the point, 1/m.
    pub dphi: Vec<Vector3<f64>>,
    /// Integration weights (reference volume), m^3.
    pub weights: Vec<f64>,
    pub kinds: Vec<PointKind>,
    /// Scaled hourglass vectors G of one-point hexahedra (HG = G G^T, N/m), sqrt(N/m).
    pub hourglass: Vec<SMatrix<f64, 8, 4>>,
    /// Point ranges [first, end) of the mean-dilatation groups.
    pub groups: Vec<[u32; 2]>,
}

/// One point of a mean-dilatation group: (node ids, dphi/dX in 1/m, weight in m^3).
pub type GroupPoint = (Vec<usize>, Vec<Vector3<f64>>, f64);

impl QuadraturePoints {
    /// Empty list with room for `points` points and `slots` slots.
    pub fn with_capacity(points: usize, slots: usize) -> Self {
        let mut offsets = Vec::with_capacity(points + 1);
        offsets.push(0);
        QuadraturePoints {
            offsets,
            nodes: Vec::with_capacity(slots),
            dphi: Vec::with_capacity(slots),
            weights: Vec::with_capacity(points),
            kinds: Vec::with_capacity(points),
            hourglass: Vec::new(),
            groups: Vec::new(),
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }

    /// Slot range of point `p`.
    #[inline]
    pub fn slots(&self, p: usize) -> std::ops::Range<usize> {
        self.offsets[p]..self.offsets[p + 1]
    }

    /// Appends a point supported by `nodes` with derivatives `dphi` and weight `w`.
    pub fn push(&mut self, nodes: &[usize], dphi: &[Vector3<f64>], w: f64, kind: PointKind) {
        debug_assert_eq!(nodes.len(), dphi.len());
        self.nodes.extend(nodes.iter().map(|&n| n as u32));
        self.dphi.extend_from_slice(dphi);
        self.weights.push(w);
        self.kinds.push(kind);
        self.offsets.push(self.nodes.len());
    }

    /// Appends a one-point hexahedron with its hourglass matrix.
    pub fn push_hourglass(
        &mut self,
        nodes: &[usize],
        dphi: &[Vector3<f64>; 8],
        w: f64,
        hg: SMatrix<f64, 8, 4>,
    ) {
        let idx = self.hourglass.len() as u32;
        self.hourglass.push(hg);
        self.push(nodes, dphi, w, PointKind::Hourglass(idx));
    }

    /// Appends the points of one cell as a mean-dilatation group: `points` = (node ids,
    /// dphi/dX, weight) each.
    pub fn push_group(&mut self, points: &[GroupPoint]) {
        let g = self.groups.len() as u32;
        let first = self.len() as u32;
        for (ids, dphi, w) in points {
            self.push(ids, dphi, *w, PointKind::MeanDilatation(g));
        }
        self.groups.push([first, self.len() as u32]);
    }

    /// Total weight (integrated volume), m^3.
    pub fn total_weight(&self) -> f64 {
        self.weights.iter().sum()
    }

    /// Largest node id referenced plus one.
    pub fn node_bound(&self) -> usize {
        self.nodes
            .iter()
            .map(|&n| n as usize + 1)
            .max()
            .unwrap_or(0)
    }
}

/// For each node, the slots that refer to it, in increasing slot order (compressed rows).
/// Gathering node sums through this map fixes the summation order, so results do not depend
/// on the number of threads.
#[derive(Debug, Clone)]
pub struct NodeSlots {
    pub offsets: Vec<usize>,
    pub slots: Vec<u32>,
    /// Point that owns each slot of `slots` (same order).
    pub points: Vec<u32>,
}

impl NodeSlots {
    /// Builds the map for `num_nodes` nodes.
    pub fn new(qp: &QuadraturePoints, num_nodes: usize) -> Self {
        let mut count = vec![0usize; num_nodes + 1];
        for &n in &qp.nodes {
            count[n as usize + 1] += 1;
        }
        for i in 0..num_nodes {
            count[i + 1] += count[i];
        }
        let offsets = count.clone();
        let mut fill = count;
        let mut slots = vec![0u32; qp.nodes.len()];
        let mut points = vec![0u32; qp.nodes.len()];
        for p in 0..qp.len() {
            for s in qp.slots(p) {
                let n = qp.nodes[s] as usize;
                slots[fill[n]] = s as u32;
                points[fill[n]] = p as u32;
                fill[n] += 1;
            }
        }
        NodeSlots {
            offsets,
            slots,
            points,
        }
    }

    /// Range into `slots`/`points` for node `n`.
    #[inline]
    pub fn range(&self, n: usize) -> std::ops::Range<usize> {
        self.offsets[n]..self.offsets[n + 1]
    }
}
