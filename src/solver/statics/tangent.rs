//! The tangent stiffness K = dF_int/du of a model, assembled from the same quadrature points
//! the force kernel uses, for every point kind.
//!
//! Every point's energy splits into an isochoric part w W_iso(F_p) and a volumetric part. The
//! volumetric part is a sum over *units* V U(J_u), J_u = sum_p c_p J_p: a plain or hourglass
//! point is its own unit (V = w, c = 1); a mean-dilatation group is one (V = the group's
//! weight, c_p = w_p / V, Nagtegaal et al. 1974); an average-nodal-pressure node is one
//! (V_n = the points' volume shares at the node, c_p = w_p / sum w, Bonet & Burton 1998).
//! These are the energies whose exact gradients the force kernel evaluates
//! ([`crate::solver::Forces::strain_energy`]), so K is their exact Hessian and symmetric:
//!
//!   K_ab = sum_p [ w_p dphi_a . A_iso(F_p) . dphi_b + s_p d2J_p/du_a du_b ]
//!        + sum_u V_u U''(J_u) g_ua g_ub^T + HG_ab I (hexahedra),
//!
//! with A_iso = dP_iso/dF ([`Material::isochoric_tangent`]), s_p = sum_u V_u U'(J_u) c_up,
//! g_ua = sum_p c_up cof(F_p) dphi_a, and d2J/du_a du_b the 3x3 block [F (dphi_a x dphi_b)]
//! as the skew matrix of d2 det F / dF dF.
//!
//! The block pattern (node pairs that share a point or a unit) is built once per model; each
//! assembly gathers row by row (node by node, points in slot order), so the values do not
//! depend on the thread count. Only the blocks (a, b >= a) are computed; the others are
//! copied from them transposed, and each diagonal block is replaced by its symmetric part, so
//! K is exactly symmetric (c3: 34.6 against 37.2 ms an assembly).

use nalgebra::{Matrix3, SMatrix, Vector3};
use rayon::prelude::*;

use crate::geometry::cofactor;
use crate::material::Material;
use crate::quadrature::PointKind;
use crate::solver::forces::deformation_gradient;
use crate::solver::Model;

/// Volumetric units spanning several points (mean-dilatation groups, average-nodal-pressure
/// nodes), in compressed rows.
#[derive(Debug, Clone, Default)]
struct Units {
    /// Per unit: its (point, coefficient c_p) entries.
    point_offsets: Vec<u32>,
    points: Vec<(u32, f64)>,
    /// Per unit: V, m^3.
    volume: Vec<f64>,
    /// Per unit: the distinct nodes of its points, ascending.
    node_offsets: Vec<u32>,
    nodes: Vec<u32>,
    /// Per node: (unit, position of the node in the unit's `nodes`).
    by_node_offsets: Vec<u32>,
    by_node: Vec<(u32, u32)>,
    /// Per point: (unit, c_p) of the units it belongs to (compressed rows).
    by_point_offsets: Vec<u32>,
    by_point: Vec<(u32, f64)>,
    /// Units from this index on are average-nodal-pressure nodes, unit `first_nodal + i` that
    /// of node `pressure_node[i]`.
    first_nodal: usize,
    pressure_node: Vec<u32>,
}

impl Units {
    fn len(&self) -> usize {
        self.volume.len()
    }

    /// Units assembled into the blocks: all, or with `split` those before the nodal ones.
    fn blocked(&self, split: bool) -> usize {
        if split {
            self.first_nodal
        } else {
            self.len()
        }
    }

    fn of<M: Material>(model: &Model<M>) -> Self {
        let q = &model.points;
        let mut u = Units {
            point_offsets: vec![0],
            node_offsets: vec![0],
            ..Default::default()
        };
        let push = |u: &mut Units, entries: Vec<(u32, f64)>, volume: f64| {
            let mut nodes: Vec<u32> = entries
                .iter()
                .flat_map(|&(p, _)| q.nodes[q.slots(p as usize)].iter().copied())
                .collect();
            nodes.sort_unstable();
            nodes.dedup();
            u.points.extend(entries);
            u.point_offsets.push(u.points.len() as u32);
            u.nodes.extend(nodes);
            u.node_offsets.push(u.nodes.len() as u32);
            u.volume.push(volume);
        };
        for &[a, b] in &q.groups {
            let w: f64 = (a..b).map(|p| q.weights[p as usize]).sum();
            let entries = (a..b).map(|p| (p, q.weights[p as usize] / w)).collect();
            push(&mut u, entries, w);
        }
        let t = model.forces.anp_tables();
        let (offsets, entries, inv_w, key_node) = (t.offsets, t.points, t.inv_weight, t.node);
        u.first_nodal = u.len();
        for key in 0..inv_w.len() {
            if !(inv_w[key] > 0.0) {
                continue;
            }
            u.pressure_node.push(key_node[key]);
            let around = &entries[offsets[key] as usize..offsets[key + 1] as usize];
            // Each entry is one slot keyed to this pressure node: the point's energy holds the
            // slot's share w_p / n_p of U(J_n).
            let volume: f64 = around
                .iter()
                .map(|&(p, w)| w / q.slots(p as usize).len() as f64)
                .sum();
            let list = around.iter().map(|&(p, w)| (p, w * inv_w[key])).collect();
            push(&mut u, list, volume);
        }
        let n = model.nodes.len();
        let mut count = vec![0u32; n + 1];
        for &j in &u.nodes {
            count[j as usize + 1] += 1;
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        u.by_node = vec![(0, 0); u.nodes.len()];
        let mut fill = count.clone();
        for k in 0..u.len() {
            let r = u.node_offsets[k] as usize..u.node_offsets[k + 1] as usize;
            for (pos, &j) in u.nodes[r].iter().enumerate() {
                u.by_node[fill[j as usize] as usize] = (k as u32, pos as u32);
                fill[j as usize] += 1;
            }
        }
        u.by_node_offsets = count;
        let np = q.len();
        let mut count = vec![0u32; np + 1];
        for &(p, _) in &u.points {
            count[p as usize + 1] += 1;
        }
        for i in 0..np {
            count[i + 1] += count[i];
        }
        u.by_point = vec![(0, 0.0); u.points.len()];
        let mut fill = count.clone();
        for k in 0..u.len() {
            for &(p, c) in &u.points[u.point_offsets[k] as usize..u.point_offsets[k + 1] as usize] {
                u.by_point[fill[p as usize] as usize] = (k as u32, c);
                fill[p as usize] += 1;
            }
        }
        u.by_point_offsets = count;
        u
    }

    fn node_range(&self, k: usize) -> std::ops::Range<usize> {
        self.node_offsets[k] as usize..self.node_offsets[k + 1] as usize
    }

    fn point_range(&self, k: usize) -> std::ops::Range<usize> {
        self.point_offsets[k] as usize..self.point_offsets[k + 1] as usize
    }

    fn bytes(&self) -> usize {
        use std::mem::size_of_val;
        size_of_val(self.point_offsets.as_slice())
            + size_of_val(self.points.as_slice())
            + size_of_val(self.volume.as_slice())
            + size_of_val(self.node_offsets.as_slice())
            + size_of_val(self.nodes.as_slice())
            + size_of_val(self.by_node_offsets.as_slice())
            + size_of_val(self.by_node.as_slice())
            + size_of_val(self.by_point_offsets.as_slice())
            + size_of_val(self.by_point.as_slice())
            + size_of_val(self.pressure_node.as_slice())
    }
}

/// Per point, what its blocks need: the isochoric tangent times the weight, F, cof F, the
/// geometric factor s_p and, for a point that is its own unit, w U''(J).
#[derive(Clone, Copy)]
struct PointState {
    a: SMatrix<f64, 9, 9>,
    f: Matrix3<f64>,
    cof: Matrix3<f64>,
    s: f64,
    r: f64,
}

/// The tangent stiffness of a model in 3x3 blocks by node rows (full rows: both triangles),
/// with the pattern built once and values assembled at any displacement.
pub struct Tangent {
    /// Block rows: node a's columns `cols[offsets[a]..offsets[a + 1]]`, ascending.
    pub offsets: Vec<usize>,
    pub cols: Vec<u32>,
    /// One 3x3 block per entry of `cols`, N/m: row DOFs of node a, column DOFs of the column.
    pub values: Vec<Matrix3<f64>>,
    /// Per entry (a, b), the entry (b, a): the assembly computes the blocks with b >= a and
    /// copies the others transposed (K is symmetric), half the work of every row's points.
    mirror: Vec<u32>,
    units: Units,
    states: Vec<PointState>,
    /// Per unit: (V U''(J_u), then g_ua for each of its nodes in `gradients`).
    unit_scale: Vec<f64>,
    gradients: Vec<Vector3<f64>>,
    /// The average-nodal-pressure units are kept apart as the low-rank sum
    /// sum_n D_n g_n g_n^T (D_n = V_n U''(J_n)) instead of in the blocks, whose pattern then
    /// joins only the nodes of one element: their outer products join every two nodes of a
    /// node's two rings, and the factor of such a matrix held 3-5 times the nonzeros. The
    /// factorization takes them as extra unknowns q_n = D_n g_n . u ([`super::factor`]).
    split: bool,
}

impl Tangent {
    /// The block pattern of `model`: node pairs joined by a point's support or a unit, and
    /// those of each of `cliques` (node lists a constraint row joins). `split`: the
    /// average-nodal-pressure units stay out of the blocks (see [`Tangent::pressure_units`]).
    pub fn new<M: Material>(model: &Model<M>, cliques: &[Vec<u32>], split: bool) -> Self {
        let units = Units::of(model);
        let kept = units.blocked(split);
        let q = &model.points;
        let slots = &model.slots;
        let n = model.nodes.len();
        let mut in_clique: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (c, nodes) in cliques.iter().enumerate() {
            for &j in nodes {
                in_clique[j as usize].push(c as u32);
            }
        }
        let rows: Vec<Vec<u32>> = (0..n)
            .into_par_iter()
            .map(|a| {
                let mut cols: Vec<u32> = Vec::new();
                for k in slots.range(a) {
                    let p = slots.points[k] as usize;
                    cols.extend_from_slice(&q.nodes[q.slots(p)]);
                }
                let r = units.by_node_offsets[a] as usize..units.by_node_offsets[a + 1] as usize;
                for &(k, _) in &units.by_node[r] {
                    if (k as usize) < kept {
                        cols.extend_from_slice(&units.nodes[units.node_range(k as usize)]);
                    }
                }
                for &c in &in_clique[a] {
                    cols.extend_from_slice(&cliques[c as usize]);
                }
                cols.sort_unstable();
                cols.dedup();
                cols
            })
            .collect();
        let mut offsets = Vec::with_capacity(n + 1);
        offsets.push(0);
        for r in &rows {
            offsets.push(offsets.last().copied().unwrap_or(0) + r.len());
        }
        let cols: Vec<u32> = rows.into_iter().flatten().collect();
        let values = vec![Matrix3::zeros(); cols.len()];
        // The pattern is symmetric (a pair joined by a point, a unit or a clique is joined
        // both ways), so every (b, a) is there.
        let mirror: Vec<u32> = (0..n)
            .into_par_iter()
            .flat_map_iter(|a| {
                let (offsets, cols) = (&offsets, &cols);
                cols[offsets[a]..offsets[a + 1]].iter().map(move |&b| {
                    let row = &cols[offsets[b as usize]..offsets[b as usize + 1]];
                    row.binary_search(&(a as u32))
                        .map_or(u32::MAX, |k| (offsets[b as usize] + k) as u32)
                })
            })
            .collect();
        let gradients = vec![Vector3::zeros(); units.nodes.len()];
        Tangent {
            offsets,
            cols,
            values,
            mirror,
            unit_scale: vec![0.0; units.len()],
            gradients,
            states: Vec::new(),
            units,
            split,
        }
    }

    /// The units kept apart from the blocks (empty unless built with `split`).
    pub fn pressure_units(&self) -> std::ops::Range<usize> {
        if self.split {
            self.units.first_nodal..self.units.len()
        } else {
            0..0
        }
    }

    /// Unit `k`'s node (an average-nodal-pressure unit is that of one node).
    pub fn unit_key(&self, k: usize) -> usize {
        self.units.pressure_node[k - self.units.first_nodal] as usize
    }

    /// Unit `k`'s nodes (ascending), with g_ua = dJ_u/du_a for each (1), and D_u = V U''(J_u)
    /// (N m), at the last assembly.
    pub fn unit(&self, k: usize) -> (&[u32], &[Vector3<f64>], f64) {
        let r = self.units.node_range(k);
        (
            &self.units.nodes[r.clone()],
            &self.gradients[r],
            self.unit_scale[k],
        )
    }

    /// Block entries (node pairs) of the pattern.
    pub fn blocks(&self) -> usize {
        self.cols.len()
    }

    /// Bytes held: the pattern, the values and the per-point and per-unit scratch.
    pub fn bytes(&self, points: usize) -> usize {
        use std::mem::size_of;
        self.offsets.len() * size_of::<usize>()
            + self.cols.len() * (2 * size_of::<u32>() + size_of::<Matrix3<f64>>())
            + self.units.bytes()
            + points * size_of::<PointState>()
            + self.unit_scale.len() * size_of::<f64>()
            + self.gradients.len() * size_of::<Vector3<f64>>()
    }

    /// Assembles K at displacements `u` (m) into `values`. Parallel; deterministic.
    pub fn assemble<M: Material>(&mut self, model: &Model<M>, u: &[Vector3<f64>]) {
        // The parts the parallel loops share (the model itself is not Sync: its corrector).
        let (q, slots, forces, n) = (
            &model.points,
            &model.slots,
            &model.forces,
            model.nodes.len(),
        );
        let units = &self.units;
        // Per point: F, its isochoric tangent and, for a point that is its own unit, U', U''.
        let mut states = std::mem::take(&mut self.states);
        states.resize(
            q.len(),
            PointState {
                a: SMatrix::zeros(),
                f: Matrix3::zeros(),
                cof: Matrix3::zeros(),
                s: 0.0,
                r: 0.0,
            },
        );
        states.par_iter_mut().enumerate().for_each(|(p, st)| {
            let m = forces.material_at(p);
            let f = deformation_gradient(q, p, u);
            let w = q.weights[p];
            st.a = m.isochoric_tangent(&f) * w;
            st.f = f;
            st.cof = cofactor(&f);
            let own = matches!(q.kinds[p], PointKind::Standard | PointKind::Hourglass(_));
            if own {
                let j = f.determinant();
                st.s = w * m.volumetric(j).1;
                st.r = w * m.volumetric_stiffness(j);
            } else {
                st.s = 0.0;
                st.r = 0.0;
            }
        });
        // Per unit: J_u, V U''(J_u) and g_u; then each point's s_p gathers its units' V U' c_p.
        let mut unit_p = vec![0.0; units.len()];
        {
            let states = &states;
            let chunks: Vec<(usize, &mut f64, &mut f64)> = self
                .unit_scale
                .iter_mut()
                .zip(unit_p.iter_mut())
                .enumerate()
                .map(|(k, (s, p))| (k, s, p))
                .collect();
            let grads = crate::solver::SharedMut(self.gradients.as_mut_ptr());
            chunks.into_par_iter().for_each(|(k, scale, pressure)| {
                let entries = &units.points[units.point_range(k)];
                let j: f64 = entries
                    .iter()
                    .map(|&(p, c)| c * states[p as usize].f.determinant())
                    .sum();
                let m = forces.material_at(entries[0].0 as usize);
                let v = units.volume[k];
                *scale = v * m.volumetric_stiffness(j);
                *pressure = v * m.volumetric(j).1;
                let nodes = &units.nodes[units.node_range(k)];
                let base = units.node_offsets[k] as usize;
                // SAFETY: unit k writes only its own entries base..base + nodes.len().
                let g =
                    unsafe { std::slice::from_raw_parts_mut(grads.get().add(base), nodes.len()) };
                g.iter_mut().for_each(|x| *x = Vector3::zeros());
                for &(p, c) in entries {
                    let p = p as usize;
                    let cof = states[p].cof;
                    for s in q.slots(p) {
                        let at = nodes.binary_search(&q.nodes[s]).unwrap_or(0);
                        g[at] += cof * q.dphi[s] * c;
                    }
                }
            });
        }
        states.par_iter_mut().enumerate().for_each(|(p, st)| {
            let r = units.by_point_offsets[p] as usize..units.by_point_offsets[p + 1] as usize;
            for &(k, c) in &units.by_point[r] {
                st.s += unit_p[k as usize] * c;
            }
        });
        // Row by row: the points of node a in slot order, then its units.
        let offsets = &self.offsets;
        let cols = &self.cols;
        let (scale, grads) = (&self.unit_scale, &self.gradients);
        let kept = units.blocked(self.split);
        let vals = crate::solver::SharedMut(self.values.as_mut_ptr());
        let states_ref = &states;
        (0..n).into_par_iter().with_min_len(64).for_each_init(
            || vec![u32::MAX; n],
            |marker, a| {
                let row = offsets[a]..offsets[a + 1];
                // SAFETY: row a owns its entries of `values`.
                let out =
                    unsafe { std::slice::from_raw_parts_mut(vals.get().add(row.start), row.len()) };
                let rc = &cols[row.clone()];
                for (k, &c) in rc.iter().enumerate() {
                    marker[c as usize] = k as u32;
                }
                out.iter_mut().for_each(|b| *b = Matrix3::zeros());
                for k in slots.range(a) {
                    let p = slots.points[k] as usize;
                    let sa = slots.slots[k] as usize;
                    let st = &states_ref[p];
                    let da = q.dphi[sa];
                    // T[i][kL] = sum_J da_J A[(i, J), (k, L)]
                    let mut t = [[0.0f64; 9]; 3];
                    for (i, ti) in t.iter_mut().enumerate() {
                        for (kl, tv) in ti.iter_mut().enumerate() {
                            *tv = da.x * st.a[(3 * i, kl)]
                                + da.y * st.a[(3 * i + 1, kl)]
                                + da.z * st.a[(3 * i + 2, kl)];
                        }
                    }
                    let ga = st.cof * da;
                    let hg = match q.kinds[p] {
                        PointKind::Hourglass(h) => {
                            Some((&q.hourglass[h as usize], sa - q.offsets[p]))
                        }
                        _ => None,
                    };
                    for sb in q.slots(p) {
                        let b = q.nodes[sb] as usize;
                        if b < a {
                            continue;
                        }
                        let db = q.dphi[sb];
                        let mut blk = Matrix3::from_fn(|i, kk| {
                            t[i][3 * kk] * db.x + t[i][3 * kk + 1] * db.y + t[i][3 * kk + 2] * db.z
                        });
                        let v = st.f * da.cross(&db) * st.s;
                        blk[(0, 1)] += v.z;
                        blk[(0, 2)] -= v.y;
                        blk[(1, 0)] -= v.z;
                        blk[(1, 2)] += v.x;
                        blk[(2, 0)] += v.y;
                        blk[(2, 1)] -= v.x;
                        if st.r != 0.0 {
                            blk += ga * (st.cof * db).transpose() * st.r;
                        }
                        if let Some((g, ia)) = hg {
                            let ib = sb - q.offsets[p];
                            let h: f64 = (0..4).map(|m| g[(ia, m)] * g[(ib, m)]).sum();
                            blk[(0, 0)] += h;
                            blk[(1, 1)] += h;
                            blk[(2, 2)] += h;
                        }
                        out[marker[b] as usize] += blk;
                    }
                }
                let r = units.by_node_offsets[a] as usize..units.by_node_offsets[a + 1] as usize;
                for &(k, pos) in &units.by_node[r] {
                    let k = k as usize;
                    if k >= kept {
                        continue;
                    }
                    let base = units.node_offsets[k] as usize;
                    let ga = grads[base + pos as usize] * scale[k];
                    for (i, &b) in units.nodes[units.node_range(k)].iter().enumerate() {
                        if (b as usize) >= a {
                            out[marker[b as usize] as usize] += ga * grads[base + i].transpose();
                        }
                    }
                }
                for &c in rc {
                    marker[c as usize] = u32::MAX;
                }
            },
        );
        // The lower blocks from the upper ones: row a writes its entries (a, b < a) and reads
        // (b, a), an upper entry of row b, which no row writes here.
        let mirror = &self.mirror;
        (0..n).into_par_iter().with_min_len(256).for_each(|a| {
            for e in offsets[a]..offsets[a + 1] {
                let b = cols[e] as usize;
                if b < a {
                    let m = mirror[e] as usize;
                    debug_assert!(mirror[e] != u32::MAX, "the pattern is symmetric");
                    // SAFETY: entry e is row a's own and lower; entry m is upper (see above).
                    unsafe { *vals.get().add(e) = (*vals.get().add(m)).transpose() };
                } else if b == a {
                    // The diagonal block, symmetric but for rounding, made exactly so.
                    // SAFETY: row a's own entry.
                    unsafe {
                        let d = &mut *vals.get().add(e);
                        *d = (*d + d.transpose()) * 0.5;
                    }
                }
            }
        });
        self.states = states;
    }

    /// Adds `m` to block (a, b), which must be in the pattern.
    pub fn add(&mut self, a: usize, b: usize, m: &Matrix3<f64>) {
        let row = &self.cols[self.offsets[a]..self.offsets[a + 1]];
        if let Ok(k) = row.binary_search(&(b as u32)) {
            self.values[self.offsets[a] + k] += m;
        }
    }

    /// The diagonal block of node `a` (with the split units' part).
    pub fn diagonal(&self, a: usize) -> Matrix3<f64> {
        let row = &self.cols[self.offsets[a]..self.offsets[a + 1]];
        let mut d = row
            .binary_search(&(a as u32))
            .map_or_else(|_| Matrix3::zeros(), |k| self.values[self.offsets[a] + k]);
        let split = self.pressure_units();
        let u = &self.units;
        for &(k, pos) in
            &u.by_node[u.by_node_offsets[a] as usize..u.by_node_offsets[a + 1] as usize]
        {
            if split.contains(&(k as usize)) {
                let g = self.gradients[u.node_offsets[k as usize] as usize + pos as usize];
                d += g * g.transpose() * self.unit_scale[k as usize];
            }
        }
        d
    }

    /// y = K x over all DOFs (x, y one vector per node), the split units' D_u g_u (g_u . x)
    /// included. Parallel by rows and units; deterministic.
    pub fn multiply(&self, x: &[Vector3<f64>], y: &mut [Vector3<f64>]) {
        let offsets = &self.offsets;
        let split = self.pressure_units();
        let u = &self.units;
        let q: Vec<f64> = split
            .clone()
            .into_par_iter()
            .with_min_len(256)
            .map(|k| {
                let r = u.node_range(k);
                let gx: f64 = u.nodes[r.clone()]
                    .iter()
                    .zip(&self.gradients[r])
                    .map(|(&j, g)| g.dot(&x[j as usize]))
                    .sum();
                gx * self.unit_scale[k]
            })
            .collect();
        y.par_iter_mut()
            .enumerate()
            .with_min_len(256)
            .for_each(|(a, ya)| {
                let mut acc = Vector3::zeros();
                for k in offsets[a]..offsets[a + 1] {
                    acc += self.values[k] * x[self.cols[k] as usize];
                }
                if !split.is_empty() {
                    let r = u.by_node_offsets[a] as usize..u.by_node_offsets[a + 1] as usize;
                    for &(k, pos) in &u.by_node[r] {
                        let k = k as usize;
                        if k >= split.start {
                            let g = self.gradients[u.node_offsets[k] as usize + pos as usize];
                            acc += g * q[k - split.start];
                        }
                    }
                }
                *ya = acc;
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fe::{element_points, ElementKind};
    use crate::geometry::shapes::{box_hex, box_tet};
    use crate::material::{NeoHookean, Ogden, Solid};
    use crate::solver::Model;

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 11) as f64) / ((1u64 << 53) as f64)
    }

    /// K v against the central difference of the internal forces along v, at a deformed state
    /// (stretch, shear and a random part), for every point kind and both material models.
    fn check(model: &mut Model<Solid>, what: &str, split: bool) {
        let n = model.nodes.len();
        let mut st = 11u64;
        let u: Vec<Vector3<f64>> = model
            .nodes
            .iter()
            .map(|x| {
                Vector3::new(0.15 * x.x + 0.1 * x.y, -0.05 * x.y, 0.08 * x.x * 10.0 * x.z)
                    + Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st)) * 4e-4
            })
            .collect();
        let v: Vec<Vector3<f64>> = (0..n)
            .map(|_| Vector3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st)) - Vector3::repeat(0.5))
            .collect();
        let mut k = Tangent::new(model, &[], split);
        k.assemble(model, &u);
        let mut kv = vec![Vector3::zeros(); n];
        k.multiply(&v, &mut kv);
        let h = 1e-7;
        let shifted =
            |s: f64| -> Vec<Vector3<f64>> { u.iter().zip(&v).map(|(a, b)| a + b * s).collect() };
        let (mut fp, mut fm) = (vec![Vector3::zeros(); n], vec![Vector3::zeros(); n]);
        model
            .forces
            .compute(&model.points, &model.slots, &shifted(h), &mut fp);
        model
            .forces
            .compute(&model.points, &model.slots, &shifted(-h), &mut fm);
        let fd: Vec<Vector3<f64>> = fp
            .iter()
            .zip(&fm)
            .map(|(a, b)| (a - b) / (2.0 * h))
            .collect();
        let scale = fd.iter().map(|x| x.amax()).fold(0.0, f64::max);
        let worst = kv
            .iter()
            .zip(&fd)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-6 * scale,
            "{what}: |Kv - dF| = {worst:e} of {scale:e}"
        );
        // Symmetric: block (a, b) is block (b, a) transposed, exactly (the assembly computes
        // the upper blocks and mirrors them, so every entry is mapped and none left zero, and
        // makes each diagonal block symmetric).
        for a in 0..n {
            for e in k.offsets[a]..k.offsets[a + 1] {
                let b = k.cols[e] as usize;
                let back = (k.offsets[b]..k.offsets[b + 1])
                    .find(|&f| k.cols[f] as usize == a)
                    .expect("symmetric pattern");
                assert_eq!(
                    k.values[e],
                    k.values[back].transpose(),
                    "{what}: asymmetric block {a} {b}"
                );
            }
        }
    }

    fn materials() -> [Solid; 2] {
        let nh = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        [
            Solid::NeoHookean(nh),
            Solid::Ogden(Ogden {
                mu: nh.mu,
                alpha: -4.7,
                kappa: nh.kappa,
                density: 1000.0,
            }),
        ]
    }

    #[test]
    fn tangent_is_the_derivative_of_the_forces_for_every_element() {
        // hex8: hourglass points; tet4: plain; tet4-anp: nodal-pressure units; tet10:
        // mean-dilatation groups.
        let lo = Vector3::zeros();
        let hi = Vector3::new(0.04, 0.03, 0.02);
        for mat in materials() {
            for kind in [
                ElementKind::Hex8,
                ElementKind::Tet4,
                ElementKind::Tet4Anp,
                ElementKind::Tet10,
            ] {
                let mesh = match kind {
                    ElementKind::Hex8 => box_hex(lo, hi, [3, 2, 2]).unwrap(),
                    _ => box_tet(lo, hi, [3, 2, 2]).unwrap(),
                };
                // tet10: four points per element in a mean-dilatation group, on the edge nodes
                // added to the linear mesh.
                let nodes = if kind == ElementKind::Tet10 {
                    crate::fe::tet10::Tet10Mesh::from_tet4(&mesh).unwrap().nodes
                } else {
                    mesh.nodes.clone()
                };
                let qp = element_points(&mesh, kind, 0.05, 1e4).unwrap();
                let mut model = Model::new(nodes, qp, mat, Vec::new()).unwrap();
                for split in [false, true] {
                    check(
                        &mut model,
                        &format!("{kind:?} {mat:?} split {split}"),
                        split,
                    );
                }
            }
        }
    }
}
