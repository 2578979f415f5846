//! The average nodal pressure of ANP tetrahedra (Bonet and Burton 1998; Joldes, Wittek,
//! Miller 2008): each pressure node's volume-weighted mean J over the ANP points around it, its
//! pressure U'(J_n), and each ANP point's pressure as the mean of its nodes'. This room owns the
//! pressure nodes' tables and scratch.

use crate::quadrature::{NodeSlots, PointKind, QuadraturePoints};

use super::*;

/// The pressure nodes of the ANP points and their scratch.
pub(super) struct NodalPressure {
    /// Volume-weighted average J of the ANP points at each pressure node (one per node, or per
    /// node and material where ANP points of several materials meet).
    pub(super) node_j: Vec<f64>,
    /// Pressure U'(J_n) of each pressure node, Pa (its material's U').
    pub(super) node_p: Vec<f64>,
    /// Pressure node of each slot where ANP points have several materials (empty: the slot's
    /// node).
    pub(super) slot_key: Vec<u32>,
    /// 1 / sum of ANP weights around each pressure node (0 where a node has no ANP point).
    pub(super) inv_weight: Vec<f64>,
    /// Per pressure node, its ANP points and their weights (compressed rows, slot order): the
    /// nodal averages read these instead of filtering every slot by kind.
    pub(super) offsets: Vec<u32>,
    /// Per pressure node, its mesh node.
    pub(super) key_node: Vec<u32>,
    pub(super) points: Vec<(u32, f64)>,
    /// The ANP points, ascending.
    pub(super) list: Vec<u32>,
    /// Whether any point is an ANP point.
    pub(super) present: bool,
}

impl NodalPressure {
    /// The pressure nodes of the ANP points of `qp` on `num_nodes` nodes, their points and
    /// weights (`point_material`: each point's material, empty: all the first).
    pub(super) fn new(
        qp: &QuadraturePoints,
        slots: &NodeSlots,
        point_material: &[u16],
        num_nodes: usize,
    ) -> Self {
        let present = qp.kinds.contains(&PointKind::Anp);
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
        if present {
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
        let list = (0..qp.len() as u32)
            .filter(|&p| qp.kinds[p as usize] == PointKind::Anp)
            .collect();
        NodalPressure {
            node_j: vec![1.0; inv_w.len()],
            node_p: vec![0.0; inv_w.len()],
            slot_key: anp_slot_key,
            inv_weight: inv_w,
            offsets: anp_offsets,
            key_node: anp_key_node,
            points: anp_points,
            list,
            present,
        }
    }

    /// Heap bytes of its tables and scratch.
    pub(super) fn bytes(&self) -> usize {
        heap_bytes(&self.node_j)
            + heap_bytes(&self.node_p)
            + heap_bytes(&self.slot_key)
            + heap_bytes(&self.inv_weight)
            + heap_bytes(&self.offsets)
            + heap_bytes(&self.key_node)
            + heap_bytes(&self.points)
            + heap_bytes(&self.list)
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

impl<M: Material> Forces<M> {
    /// Nodal J and pressure for ANP points (Bonet & Burton 1998): per pressure node J_n, the
    /// volume-weighted mean of the element J's around it, and p_n = U'(J_n) of their material.
    /// Parallel over points, then over pressure nodes.
    pub(super) fn nodal_pressures(&mut self, qp: &QuadraturePoints, u: &[Vector3<f64>]) {
        let pj = SharedMut(self.point_j.as_mut_ptr());
        self.pressure
            .list
            .par_iter()
            .with_min_len(CHUNK)
            .for_each(|&p| {
                let p = p as usize;
                let j = deformation_gradient(qp, p, u).determinant();
                // SAFETY: each p writes only its own entry.
                unsafe { *pj.get().add(p) = j };
            });
        let point_j = &self.point_j;
        let inv_w = &self.pressure.inv_weight;
        let (offsets, points) = (&self.pressure.offsets, &self.pressure.points);
        let (materials, point_material) = (&self.materials, &self.point_material);
        self.pressure
            .node_j
            .par_iter_mut()
            .zip(self.pressure.node_p.par_iter_mut())
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
    pub(super) fn pressure_node(&self, qp: &QuadraturePoints, s: usize) -> usize {
        if self.pressure.slot_key.is_empty() {
            qp.nodes[s] as usize
        } else {
            self.pressure.slot_key[s] as usize
        }
    }

    /// Mean of the nodal pressures over the slots of ANP point `p`, Pa.
    #[inline(always)]
    pub(super) fn anp_mean_pressure(&self, qp: &QuadraturePoints, p: usize) -> f64 {
        let r = qp.slots(p);
        let n = r.len() as f64;
        let mut sum = 0.0;
        for s in r {
            sum += self.pressure.node_p[self.pressure_node(qp, s)];
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
    pub(super) fn anp_stress<K: Material>(
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

    /// The average-nodal-pressure tables (empty without ANP points): per pressure node `n`,
    /// its (ANP point, weight in m^3) entries `points[offsets[n]..offsets[n + 1]]`, one per
    /// slot keyed to it, and 1 / their weight sum (1/m^3; 0 where a node has none). J_n is the
    /// weighted mean of the points' J over the entries; the static solve's tangent
    /// differentiates it ([`crate::solver::statics`]). Last, the mesh node of each pressure
    /// node (several pressure nodes share one where materials meet).
    pub(crate) fn anp_tables(&self) -> AnpTables<'_> {
        AnpTables {
            offsets: &self.pressure.offsets,
            points: &self.pressure.points,
            inv_weight: &self.pressure.inv_weight,
            node: &self.pressure.key_node,
        }
    }
}
