//! Output fields at the points: Cauchy stress, Green-Lagrange strain, von Mises stress and J.

use super::*;

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
    /// det F of the point's own deformation gradient (fields at points; zero in nodal
    /// fields, which [`Self::set`] writes). With averaged volume changes it may vary from
    /// element to element in a checkerboard that carries no pressure (tet4-anp: only the nodal
    /// J_n enter the volumetric energy).
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

    /// Entry `p` from its Cauchy stress `c`, strain `e` and J (von Mises from `c`); `j_own`
    /// is the caller's to write where it has one.
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

impl<M: Material> Forces<M> {
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
                    let i = self.groups.first[g] as usize + (p - qp.groups[g][0] as usize);
                    let j = self.groups.s[i][0];
                    (
                        self.groups.pk[i] * plain.transpose() / (qp.weights[p] * j),
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
                        .map(|s| self.pressure.node_j[self.pressure_node(qp, s)])
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
