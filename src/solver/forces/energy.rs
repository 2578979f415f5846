//! Strain energy, summed in a fixed order from per-point energies kept in this room's
//! scratch.

use super::*;

/// The per-point energies of [`Forces::strain_energy`], reused so that energy evaluations do
/// not allocate.
pub(super) struct Energy {
    pub(super) per_point: Vec<f64>,
}

impl Energy {
    pub(super) fn new(points: usize) -> Self {
        Energy {
            per_point: vec![0.0; points],
        }
    }

    /// Heap bytes of its scratch.
    pub(super) fn bytes(&self) -> usize {
        heap_bytes(&self.per_point)
    }
}

impl<M: Material> Forces<M> {
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
        let mut per_point = std::mem::take(&mut self.energy.per_point);
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
                    .map(|s| {
                        mat.volumetric(this.pressure.node_j[this.pressure_node(qp, s)])
                            .0
                    })
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
        self.energy.per_point = per_point;
        total
    }
}
