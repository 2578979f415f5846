//! The model flattened into the arrays the kernels read (built once on the host).

use crate::bc::Constraints;
use crate::material::Material;
use crate::quadrature::PointKind;
use crate::solver::Model;
use crate::{Error, InputKind, Result};

/// Host copies of everything the kernels read, in their layout: u32 ids, f64 values, vectors
/// as three consecutive components.
#[derive(Debug, Clone, Default)]
pub struct Tables {
    pub num_nodes: usize,
    pub offsets: Vec<u32>,
    pub nodes: Vec<u32>,
    pub dphi: Vec<f64>,
    pub weights: Vec<f64>,
    /// Per point: 0 standard, 1 one-point hexahedron, 2 ANP, 3 mean dilatation.
    pub mode: Vec<u32>,
    /// Per point: its hourglass matrix (mode 1) or group scratch entry (mode 3).
    pub aux: Vec<u32>,
    /// The points of at most `WIDE` (8) slots (a thread each) and the others (a warp each; by
    /// their count of 32-slot chunks, each count in point order).
    pub narrow: Vec<u32>,
    pub wide: Vec<u32>,
    pub point_mat: Vec<u32>,
    /// Per material: shear and bulk modulus, Pa.
    pub mu: Vec<f64>,
    pub kappa: Vec<f64>,
    /// Hourglass matrices G (8 x 4, column-major), one after another.
    pub hg: Vec<f64>,
    pub anp_list: Vec<u32>,
    pub anp_off: Vec<u32>,
    pub anp_pts: Vec<u32>,
    pub anp_w: Vec<f64>,
    pub inv_w: Vec<f64>,
    /// Per slot: its pressure node (read for ANP points only).
    pub pkey: Vec<u32>,
    /// Per group: [first point, end).
    pub groups: Vec<u32>,
    pub group_first: Vec<u32>,
    /// Points in groups (the group scratch's entries).
    pub in_groups: usize,
    /// Per group scratch entry: its point and its group.
    pub gpoint: Vec<u32>,
    pub ggroup: Vec<u32>,
    /// Per node: its entries `ent_off[n]..ent_off[n + 1]`; per entry its slots' forces at
    /// `con_off[e]..con_off[e + 1]` of the slot-force array, in the CPU's order.
    pub ent_off: Vec<u32>,
    pub con_off: Vec<u32>,
    /// Per slot: where the point kernels store its force (its place in that order).
    pub pos: Vec<u32>,
    pub mass: Vec<f64>,
    /// Prescribed DOFs as 3 node + component, their final values (m) and load curves (index
    /// into `curves`).
    pub dofs: Vec<u32>,
    pub amp: Vec<f64>,
    pub dof_curve: Vec<u32>,
    /// The distinct load curves of the prescribed DOFs.
    pub curves: Vec<crate::bc::LoadCurve>,
}

/// Points of more slots than this get a warp each (`point_forces_wide`); set
/// `HYTLED_GPU_WIDE` to another count to compare (a count above every support puts every
/// point on a thread).
pub(crate) const WIDE: usize = 8;

/// u32 of a count, or the error that the model is too large for the kernels' 32-bit ids.
fn id(n: usize, what: &str) -> Result<u32> {
    u32::try_from(n).map_err(|_| {
        Error::input(
            InputKind::Unsupported,
            format!(
            "--device gpu: {n} {what} exceed the GPU kernels' 32-bit ids; run with --device cpu"
        ),
        )
    })
}

impl Tables {
    /// Flattens `model` with the constraints `cons` of the run. Errors where the model uses
    /// something the GPU loop does not evaluate yet.
    pub fn new<M: Material>(model: &Model<M>, cons: &Constraints) -> Result<Self> {
        let unsupported = |what: &str| {
            Err(Error::input(
                InputKind::Unsupported,
                format!(
                    "--device gpu does not evaluate {what} yet; run this scene with --device cpu"
                ),
            ))
        };
        let qp = &model.points;
        let n = model.nodes.len();
        let np = qp.len();
        let ns = qp.nodes.len();
        id(3 * n, "node components")?;
        id(3 * ns, "slot components")?;
        id(np + 1, "points")?;
        let mut mu = Vec::new();
        let mut kappa = Vec::new();
        for m in &model.forces.materials {
            let Some((a, b)) = m.neo_hookean() else {
                return unsupported("materials other than neo-Hookean (here an Ogden solid)");
            };
            mu.push(a);
            kappa.push(b);
        }
        let ft = model.forces.tables();
        let pm = model.forces.point_materials();
        let mut t = Tables {
            num_nodes: n,
            offsets: qp.offsets.iter().map(|&o| o as u32).collect(),
            nodes: qp.nodes.clone(),
            dphi: qp.dphi.iter().flat_map(|d| [d.x, d.y, d.z]).collect(),
            weights: qp.weights.clone(),
            point_mat: (0..np)
                .map(|p| pm.get(p).copied().unwrap_or(0) as u32)
                .collect(),
            mu,
            kappa,
            hg: qp
                .hourglass
                .iter()
                .flat_map(|g| g.as_slice().to_vec())
                .collect(),
            anp_list: ft.anp_list.to_vec(),
            anp_off: ft.anp_offsets.to_vec(),
            anp_pts: ft.anp_points.iter().map(|&(p, _)| p).collect(),
            anp_w: ft.anp_points.iter().map(|&(_, w)| w).collect(),
            inv_w: ft.node_anp_inv_weight.to_vec(),
            pkey: if ft.anp_list.is_empty() {
                Vec::new()
            } else if ft.anp_slot_key.is_empty() {
                qp.nodes.clone()
            } else {
                ft.anp_slot_key.to_vec()
            },
            groups: qp.groups.iter().flat_map(|g| [g[0], g[1]]).collect(),
            group_first: ft.group_first.to_vec(),
            in_groups: qp.groups.iter().map(|g| (g[1] - g[0]) as usize).sum(),
            mass: model.mass.clone(),
            dofs: cons
                .dofs
                .iter()
                .map(|&(node, c)| 3 * node + c as u32)
                .collect(),
            ..Default::default()
        };
        let wide_from = std::env::var("HYTLED_GPU_WIDE")
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
            .unwrap_or(WIDE);
        for p in 0..np {
            let len = qp.offsets[p + 1] - qp.offsets[p];
            if len > wide_from {
                t.wide.push(p as u32);
            } else {
                t.narrow.push(p as u32);
            }
        }
        let chunks = |p: &u32| (qp.offsets[*p as usize + 1] - qp.offsets[*p as usize]).div_ceil(32);
        t.wide.sort_by_key(chunks);
        for p in 0..np {
            let (m, a) = match qp.kinds[p] {
                PointKind::Standard => (0, 0),
                PointKind::Hourglass(h) => (1, h),
                PointKind::Anp => (2, 0),
                PointKind::MeanDilatation(g) => {
                    let g = g as usize;
                    (3, ft.group_first[g] + (p as u32 - qp.groups[g][0]))
                }
            };
            t.mode.push(m);
            t.aux.push(a);
        }
        for (g, (&[a, b], &first)) in qp.groups.iter().zip(ft.group_first).enumerate() {
            for p in a..b {
                debug_assert_eq!(t.gpoint.len(), (first + p - a) as usize);
                t.gpoint.push(p);
                t.ggroup.push(g as u32);
            }
        }
        t.amp = cons.amplitude.clone();
        for c in &cons.curve {
            let i = match t.curves.iter().position(|k| k == c) {
                Some(i) => i,
                None => {
                    t.curves.push(c.clone());
                    t.curves.len() - 1
                }
            };
            t.dof_curve.push(i as u32);
        }
        t.node_sums(&model.forces.contribution_order(qp), ft.buffers);
        Ok(t)
    }

    /// The per-node entry lists and per-entry slot lists of the chunk sums: node n sums its
    /// chunk entries (first, then the extras, in chunk order), each entry its slots in the
    /// order `order` adds them. A node no point reaches gets one empty entry (the CPU's zero
    /// entry).
    fn node_sums(&mut self, order: &[u32], b: &crate::solver::chunks::Buffers) {
        let entries = b.len();
        let mut count = vec![0u32; entries + 1];
        for &s in order {
            count[b.slot_entry[s as usize] as usize + 1] += 1;
        }
        for e in 0..entries {
            count[e + 1] += count[e];
        }
        let mut fill = count.clone();
        let mut by_entry = vec![0u32; order.len()];
        for &s in order {
            let e = b.slot_entry[s as usize] as usize;
            by_entry[fill[e] as usize] = s;
            fill[e] += 1;
        }
        let n = self.num_nodes;
        self.ent_off = Vec::with_capacity(n + 1);
        self.con_off = vec![0];
        let mut con_slot = Vec::with_capacity(order.len());
        self.ent_off.push(0);
        let push = |e: usize, con_off: &mut Vec<u32>, con_slot: &mut Vec<u32>| {
            if e < entries {
                con_slot.extend_from_slice(&by_entry[count[e] as usize..count[e + 1] as usize]);
            }
            con_off.push(con_slot.len() as u32);
        };
        for node in 0..n {
            push(b.first[node] as usize, &mut self.con_off, &mut con_slot);
            let ex = &b.extras[b.extra_start[node] as usize..b.extra_start[node + 1] as usize];
            for &[_, e] in ex {
                push(e as usize, &mut self.con_off, &mut con_slot);
            }
            self.ent_off.push((self.con_off.len() - 1) as u32);
        }
        self.pos = vec![0; con_slot.len()];
        for (k, &s) in con_slot.iter().enumerate() {
            self.pos[s as usize] = k as u32;
        }
    }

    /// Device bytes of the tables and of the run's state and scratch arrays.
    pub fn device_bytes(&self) -> usize {
        let u32s = self.offsets.len()
            + self.narrow.len()
            + self.wide.len()
            + self.nodes.len()
            + self.mode.len()
            + self.aux.len()
            + self.point_mat.len()
            + self.anp_list.len()
            + self.anp_off.len()
            + self.anp_pts.len()
            + self.pkey.len()
            + self.groups.len()
            + self.group_first.len()
            + 2 * self.in_groups
            + self.ent_off.len()
            + self.con_off.len()
            + self.pos.len()
            + self.num_nodes
            + 2 * self.dofs.len()
            + self.curves.len();
        let np = self.weights.len();
        let f64s = self.dphi.len()
            + self.weights.len()
            + self.hg.len()
            + self.anp_w.len()
            + 3 * self.inv_w.len()
            + self.mass.len()
            // u(n-1), u(n), u(n+1), f; slot forces; point J; group scratch; partials.
            + 12 * self.num_nodes
            + 3 * self.nodes.len()
            + np
            + 21 * self.in_groups
            + self.groups.len()
            + 3 * (np / 8 + self.num_nodes / 256 + 2)
            + 3 * self.con_off.len()
            + 5 * self.dofs.len()
            + 8;
        4 * u32s + 8 * f64s
    }
}
