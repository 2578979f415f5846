//! Stable time step from the discretization itself: the per-point bound of Joldes et al.
//! (thesis eq. 4.1-4.2) and a nodal block-Gershgorin bound; the run takes the larger step,
//! since both bound the largest eigenvalue of the reference stiffness.

use nalgebra::Vector3;

use crate::quadrature::QuadraturePoints;

/// Per point p: [P-wave modulus lambda + 2 mu, shear modulus mu, bulk modulus kappa (Pa),
/// density (kg/m^3)] of its material.
pub type Moduli<'a> = dyn Fn(usize) -> [f64; 4] + 'a;

/// Critical step, s: min over points I of 2 / (c_I sqrt(n_I sum_j |dphi_j/dX|^2)), with c_I
/// the dilatational wave speed sqrt((lambda + 2 mu) / rho) of I's material (m/s) and the
/// point's mass split evenly over its n_I nodes. Returns the step and the point that sets it.
pub fn critical_time_step(qp: &QuadraturePoints, moduli: &Moduli) -> (f64, usize) {
    let mut best = (f64::INFINITY, 0);
    for p in 0..qp.len() {
        let r = qp.slots(p);
        let n = r.len() as f64;
        let sum: f64 = qp.dphi[r].iter().map(|d| d.norm_squared()).sum();
        let [m, _, _, rho] = moduli(p);
        let dt = 2.0 / ((m / rho).sqrt() * (n * sum).sqrt());
        if dt < best.0 {
            best = (dt, p);
        }
    }
    best
}

/// Node `i` has all three components prescribed (`prescribed`: per node and component).
fn fully_prescribed(prescribed: &[[bool; 3]], i: usize) -> bool {
    prescribed.get(i).is_some_and(|c| c.iter().all(|&c| c))
}

/// Nodal (block Gershgorin) bound on the stable step, s: with lumped masses m_i (kg) and the
/// reference stiffness blocks |K_ij| <= sum_p w_p (lambda + 2 mu)_p |dphi_i| |dphi_j|,
/// lambda_max(M^-1 K) <= max_i (1 / m_i) sum_p w_p (lambda + 2 mu)_p |dphi_i(p)| sum_j
/// |dphi_j(p)| (the modulus of each point's material).
/// Nodes whose three components are all prescribed (`prescribed[i]`, e.g. the direct
/// constraints' mask) are not integrated, so their rows are left out: the free block of
/// M^-1 K has its eigenvalues within the discs of the free rows (the rows keep their
/// couplings to prescribed nodes, so the bound only gets looser). Without this, FE nodes of
/// a driven face that blended points reach with little mass set a step 3x below what the
/// free nodes need (4,208-node Gmsh cylinder, FE layer around the driven faces).
/// Returns the step 2 / sqrt(lambda_max) and the node that sets it.
pub fn nodal_time_step(
    qp: &QuadraturePoints,
    slots: &crate::quadrature::NodeSlots,
    mass: &[f64],
    prescribed: &[[bool; 3]],
    moduli: &Moduli,
) -> (f64, usize) {
    let rows = gershgorin_rows(qp, slots, moduli);
    let mut best = (f64::INFINITY, 0);
    for (i, &m) in mass.iter().enumerate() {
        if fully_prescribed(prescribed, i) {
            continue;
        }
        let lam = rows[i] / m;
        let dt = 2.0 / lam.sqrt();
        if dt < best.0 {
            best = (dt, i);
        }
    }
    best
}

/// Per node i, the block-Gershgorin row sum of the reference stiffness, N/m:
/// sum_p w_p (lambda + 2 mu)_p |dphi_i(p)| sum_j |dphi_j(p)| over the points p that i supports
/// ([`nodal_time_step`] divides it by the mass). It bounds the rows of the fully integrated
/// stiffness; the averaged volumetric stiffness of tet4-anp and of mean-dilatation groups is
/// below that stiffness in the positive semi-definite order (Cauchy-Schwarz on the averaged
/// J), so lambda_max(M^-1 K) <= max_i rows_i / m_i holds for them too.
pub fn gershgorin_rows(
    qp: &QuadraturePoints,
    slots: &crate::quadrature::NodeSlots,
    moduli: &Moduli,
) -> Vec<f64> {
    // |dphi| summed over each point's slots, times its weight and P-wave modulus.
    let abs_sum: Vec<f64> = (0..qp.len())
        .map(|p| {
            let s: f64 = qp.dphi[qp.slots(p)].iter().map(|d| d.norm()).sum();
            s * qp.weights[p] * moduli(p)[0]
        })
        .collect();
    (0..slots.offsets.len().saturating_sub(1))
        .map(|i| {
            slots
                .range(i)
                .map(|k| {
                    let p = slots.points[k] as usize;
                    qp.dphi[slots.slots[k] as usize].norm() * abs_sum[p]
                })
                .sum()
        })
        .collect()
}

/// Stable step of a model whose points are all average-nodal-pressure tets (Bonet & Burton
/// 1998), s, and the node that sets it. Linearized at the reference state the ANP stiffness
/// splits into the points' deviatoric part, with modulus 2 mu, and a volumetric part built
/// from the nodal averages: with the nodal volumes W_n = sum of V_p over the points at n and
/// g_n = sum over those points of V_p b_p (b_p the point's divergence row),
/// K_vol = (kappa / 4) sum_n g_n g_n^T / W_n (the 1/4 is the mean over a tet's four nodes).
/// By Weyl's inequality lambda_max(M^-1 K) <= lambda_dev + lambda_vol, where
/// - lambda_dev <= max_p n_p (2 mu / rho) sum_j |b_j|^2 (per point, its mass split evenly);
/// - lambda_vol = (kappa / 4) lambda_max(S), S = W^-1/2 G M^-1 G^T W^-1/2 (nodes x nodes, the
///   same nonzero eigenvalues as M^-1 K_vol), bounded by S's largest absolute row sum
///   (Gershgorin). S keeps the cancellations of the averaged pressure that a per-point bound
///   with lambda + 2 mu cannot see.
///
/// Where points of several materials meet at a node (`material`: each point's, empty: one),
/// each material's points there form a pressure node of their own, as in the force kernel
/// (splitting a node's g_n raises K_vol, so a bound over whole nodes would not hold there).
/// Nodes whose three components are prescribed (`prescribed`) are left out of G (their DOFs are
/// not integrated). Each point's mu and rho are its material's; kappa is the largest over the
/// points (an upper bound where regions differ). Masses in kg.
pub fn anp_time_step(
    qp: &QuadraturePoints,
    slots: &crate::quadrature::NodeSlots,
    mass: &[f64],
    prescribed: &[[bool; 3]],
    moduli: &Moduli,
    material: &[u16],
) -> (f64, usize) {
    let n = mass.len();
    let lam_dev = (0..qp.len())
        .map(|p| {
            let r = qp.slots(p);
            let sum: f64 = qp.dphi[r.clone()].iter().map(|d| d.norm_squared()).sum();
            let [_, mu, _, density] = moduli(p);
            r.len() as f64 * 2.0 * mu / density * sum
        })
        .fold(0.0, f64::max);
    let kappa = (0..qp.len()).map(|p| moduli(p)[2]).fold(0.0, f64::max);
    let mat = |p: usize| material.get(p).copied().unwrap_or(0);
    // Pressure nodes a (per node, one per material of the points there, as the force kernel
    // keeps them), their volumes W_a and g_a as sorted (node j, V_p b_pj summed over the
    // points p of a that reach j).
    let mut w = Vec::with_capacity(n);
    // The node of each pressure node (reported as what sets the step).
    let mut node_of = Vec::with_capacity(n);
    let mut g: Vec<Vec<(usize, nalgebra::Vector3<f64>)>> = Vec::with_capacity(n);
    let mut materials = Vec::new();
    for node in 0..n {
        materials.clear();
        for k in slots.range(node) {
            let m = mat(slots.points[k] as usize);
            if !materials.contains(&m) {
                materials.push(m);
            }
        }
        if materials.is_empty() {
            materials.push(0);
        }
        for &m in &materials {
            let mut acc: Vec<(usize, nalgebra::Vector3<f64>)> = Vec::new();
            let mut wa = 0.0;
            for k in slots.range(node) {
                let p = slots.points[k] as usize;
                if mat(p) != m {
                    continue;
                }
                wa += qp.weights[p];
                for s in qp.slots(p) {
                    let j = qp.nodes[s] as usize;
                    if fully_prescribed(prescribed, j) {
                        continue;
                    }
                    let v = qp.dphi[s] * qp.weights[p];
                    match acc.iter_mut().find(|a| a.0 == j) {
                        Some(a) => a.1 += v,
                        None => acc.push((j, v)),
                    }
                }
            }
            acc.sort_unstable_by_key(|a| a.0);
            w.push(wa);
            node_of.push(node);
            g.push(acc);
        }
    }
    // Per node j, the pressure nodes b with an entry g_b[j], ascending.
    let mut reach: Vec<Vec<(usize, nalgebra::Vector3<f64>)>> = vec![Vec::new(); n];
    for (b, gb) in g.iter().enumerate() {
        for &(j, v) in gb {
            reach[j].push((b, v));
        }
    }
    let np = w.len();
    let mut best = (f64::INFINITY, 0);
    let mut row: Vec<f64> = vec![0.0; np];
    let mut seen = vec![false; np];
    let mut touched: Vec<usize> = Vec::new();
    for a in 0..np {
        if !(w[a] > 0.0) {
            continue;
        }
        // S_ab = sum_j g_a[j] . g_b[j] / m_j / sqrt(W_a W_b).
        for &(j, ga) in &g[a] {
            for &(b, gb) in &reach[j] {
                if !seen[b] {
                    seen[b] = true;
                    touched.push(b);
                }
                row[b] += ga.dot(&gb) / mass[j];
            }
        }
        let mut sum = 0.0;
        for &b in &touched {
            sum += row[b].abs() / (w[a] * w[b]).sqrt();
            row[b] = 0.0;
            seen[b] = false;
        }
        touched.clear();
        let lam = lam_dev + 0.25 * kappa * sum;
        let dt = 2.0 / lam.sqrt();
        if dt < best.0 {
            best = (dt, node_of[a]);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    /// The points named for a collapsing step are those a deformation squeezed: a node pushed
    /// into its neighbours makes the elements around it the first, each with its J, and an
    /// undeformed body has every bound at its reference value.
    #[test]
    fn stiffened_points_are_the_squeezed_ones() {
        use crate::fe::{element_points, ElementKind};
        use crate::geometry::shapes::box_tet;
        let mesh = box_tet(Vector3::zeros(), Vector3::repeat(0.04), [2, 2, 2]).unwrap();
        let qp = element_points(&mesh, ElementKind::Tet4, 0.0, 1.0).unwrap();
        let mat = crate::material::NeoHookean::from_young_poisson(3000.0, 0.45, 1000.0);
        let model = crate::solver::Model::new(mesh.nodes.clone(), qp, mat, Vec::new()).unwrap();
        let centre = mesh
            .nodes
            .iter()
            .position(|x| (x - Vector3::repeat(0.02)).norm() < 1e-12)
            .unwrap();
        let mut u = vec![Vector3::zeros(); mesh.nodes.len()];
        let rest = stiffened_points(&model, &u, 1);
        assert!((rest[0].ratio - 1.0).abs() < 1e-12 && (rest[0].j - 1.0).abs() < 1e-12);
        u[centre] = Vector3::new(0.009, 0.0, 0.0);
        let worst = stiffened_points(&model, &u, 3);
        for w in &worst {
            assert!(mesh.cell(w.id as usize).contains(&centre), "{w:?}");
            assert!(w.ratio < 1.0);
        }
        assert!(worst[0].ratio <= worst[1].ratio && worst[1].ratio <= worst[2].ratio);
    }

    use super::*;
    use crate::quadrature::{NodeSlots, PointKind, QuadraturePoints};
    use nalgebra::Vector3;

    /// One linear tet: with node 0 prescribed, its row drops out and the step is the one the
    /// free rows give, written out here from the bound's formula.
    #[test]
    fn prescribed_nodes_do_not_set_the_nodal_step() {
        let x = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        let (d, v) = crate::fe::tet4::derivatives(&x).unwrap();
        let mut qp = QuadraturePoints::with_capacity(1, 4);
        qp.push(&[0, 1, 2, 3], &d, v, PointKind::Standard);
        let slots = NodeSlots::new(&qp, 4);
        // Node 0 far lighter than the others: it sets the step while it is free.
        let mass = [1e-6, 1.0, 1.0, 1.0];
        let (c, rho) = (2.0, 1000.0);
        let abs_sum: f64 = d.iter().map(|g| g.norm()).sum();
        let step = |i: usize| 2.0 / (c * c * rho / mass[i] * v * d[i].norm() * abs_sum).sqrt();
        let moduli = |_: usize| [c * c * rho, 0.0, 0.0, rho];
        let free = nodal_time_step(&qp, &slots, &mass, &[[false; 3]; 4], &moduli);
        assert_eq!(free.1, 0);
        assert!((free.0 - step(0)).abs() < 1e-12 * step(0));
        let mut mask = [[false; 3]; 4];
        mask[0] = [true; 3];
        let held = nodal_time_step(&qp, &slots, &mass, &mask, &moduli);
        let expect = (1..4).map(step).fold(f64::INFINITY, f64::min);
        assert_ne!(held.1, 0);
        assert!(
            (held.0 - expect).abs() < 1e-12 * expect,
            "{held:?} vs {expect}"
        );
        // A node with only some components prescribed still counts.
        mask[0] = [true, true, false];
        assert_eq!(nodal_time_step(&qp, &slots, &mass, &mask, &moduli).1, 0);
    }

    /// The ANP bound against the exact critical step 2 / sqrt(lambda_max(M^-1 K)) of a small
    /// tet block (K by central differences of the kernel's forces, which are the gradient of
    /// an energy, so K is symmetric), bottom face fixed: safe (never above it) and within 3x,
    /// with one material and with two (bulk moduli 1 : 8) meeting along x = 0.5, where each
    /// keeps its own nodal pressure.
    #[test]
    fn anp_bound_is_safe_against_the_exact_spectrum() {
        use crate::fe::{element_points, ElementKind};
        use crate::material::{Material, NeoHookean};
        use crate::solver::forces::Forces;
        let mesh =
            crate::geometry::shapes::box_tet(Vector3::zeros(), Vector3::repeat(1.0), [2, 2, 2])
                .unwrap();
        let qp = element_points(&mesh, ElementKind::Tet4Anp, 0.0, 1.0).unwrap();
        let n = mesh.nodes.len();
        let slots = NodeSlots::new(&qp, n);
        let soft = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        let hard = NeoHookean {
            kappa: 8.0 * soft.kappa,
            ..soft
        };
        let halves: Vec<u16> = (0..qp.len())
            .map(|p| {
                let x: f64 = qp
                    .slots(p)
                    .map(|s| mesh.nodes[qp.nodes[s] as usize].x)
                    .sum();
                u16::from(x / 4.0 > 0.5)
            })
            .collect();
        let mut mass = vec![0.0; n];
        for p in 0..qp.len() {
            for s in qp.slots(p) {
                mass[qp.nodes[s] as usize] += soft.density * qp.weights[p] / 4.0;
            }
        }
        let prescribed: Vec<[bool; 3]> = mesh.nodes.iter().map(|x| [x.z == 0.0; 3]).collect();
        let free: Vec<usize> = (0..3 * n).filter(|&d| !prescribed[d / 3][d % 3]).collect();
        for (name, materials, material) in [
            ("one material", vec![soft], vec![]),
            ("two materials", vec![soft, hard], halves),
        ] {
            let mut forces =
                Forces::with_materials(materials.clone(), material.clone(), &qp, &slots, n);
            let h = 1e-7;
            let mut k = nalgebra::DMatrix::zeros(free.len(), free.len());
            let (mut fp, mut fm) = (vec![Vector3::zeros(); n], vec![Vector3::zeros(); n]);
            for (c, &d) in free.iter().enumerate() {
                let mut u = vec![Vector3::zeros(); n];
                u[d / 3][d % 3] = h;
                forces.compute(&qp, &slots, &u, &mut fp);
                u[d / 3][d % 3] = -h;
                forces.compute(&qp, &slots, &u, &mut fm);
                for (r, &e) in free.iter().enumerate() {
                    k[(r, c)] = (fp[e / 3][e % 3] - fm[e / 3][e % 3])
                        / (2.0 * h)
                        / (mass[e / 3] * mass[d / 3]).sqrt();
                }
            }
            let asym = (&k - k.transpose()).abs().max() / k.abs().max();
            assert!(asym < 1e-6, "{name}: K not symmetric ({asym:e})");
            let k = (&k + k.transpose()) * 0.5;
            let lambda = k.symmetric_eigenvalues().max();
            let exact = 2.0 / lambda.sqrt();
            let moduli = |p: usize| {
                let m = &materials[material.get(p).copied().unwrap_or(0) as usize];
                let (l, mu) = m.lame();
                [l + 2.0 * mu, mu, l + 2.0 * mu / 3.0, m.density()]
            };
            let (bound, _) = anp_time_step(&qp, &slots, &mass, &prescribed, &moduli, &material);
            println!("{name}: ANP bound {bound:e} s, exact critical step {exact:e} s");
            assert!(
                bound <= exact,
                "{name}: bound {bound:e} above the exact {exact:e}"
            );
            assert!(
                bound > exact / 3.0,
                "{name}: bound {bound:e} loose against {exact:e}"
            );
        }
    }
}

/// A point whose step bound has fallen most under deformation ([`stiffened_points`]).
#[derive(Debug, Clone, Copy)]
pub struct Stiffened {
    /// The point's id in the discretization (its element for FE meshes).
    pub id: u32,
    /// det F at the point.
    pub j: f64,
    /// Its step bound at the deformed state over its reference one:
    /// sqrt(sum_a |dphi_a|^2 / sum_a |F^-T dphi_a|^2).
    pub ratio: f64,
}

/// The `k` points of `model` whose per-point step bound has fallen most at displacements `u`
/// (m): the ratio of sqrt(sum_a |dphi_a|^2) in the reference to the same sum over the deformed
/// gradients F^-T dphi_a, smallest first; an inverted point first of all (ratio 0).
pub fn stiffened_points<M: crate::material::Material>(
    model: &super::Model<M>,
    u: &[Vector3<f64>],
    k: usize,
) -> Vec<Stiffened> {
    let q = &model.points;
    let mut all: Vec<Stiffened> = (0..q.len())
        .map(|p| {
            let f = super::forces::deformation_gradient(q, p, u);
            let j = f.determinant();
            let reference: f64 = q.slots(p).map(|s| q.dphi[s].norm_squared()).sum();
            let ratio = match f.try_inverse() {
                Some(fi) if j > 0.0 => {
                    let fit = fi.transpose();
                    let deformed: f64 = q.slots(p).map(|s| (fit * q.dphi[s]).norm_squared()).sum();
                    (reference / deformed).sqrt()
                }
                _ => 0.0,
            };
            Stiffened {
                id: model.point_ids[p],
                j,
                ratio,
            }
        })
        .collect();
    all.sort_by(|a, b| a.ratio.total_cmp(&b.ratio).then(a.id.cmp(&b.id)));
    all.truncate(k);
    all
}
