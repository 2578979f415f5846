//! Stable time step from the discretization itself: the per-point bound of Joldes et al.
//! (thesis eq. 4.1-4.2) and a nodal block-Gershgorin bound; the run takes the larger step,
//! since both bound the largest eigenvalue of the reference stiffness.

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
    // |dphi| summed over each point's slots, times its weight and P-wave modulus.
    let abs_sum: Vec<f64> = (0..qp.len())
        .map(|p| {
            let s: f64 = qp.dphi[qp.slots(p)].iter().map(|d| d.norm()).sum();
            s * qp.weights[p] * moduli(p)[0]
        })
        .collect();
    let mut best = (f64::INFINITY, 0);
    for (i, &m) in mass.iter().enumerate() {
        if fully_prescribed(prescribed, i) {
            continue;
        }
        let mut row = 0.0;
        for k in slots.range(i) {
            let p = slots.points[k] as usize;
            let s = slots.slots[k] as usize;
            row += qp.dphi[s].norm() * abs_sum[p];
        }
        let lam = row / m;
        let dt = 2.0 / lam.sqrt();
        if dt < best.0 {
            best = (dt, i);
        }
    }
    best
}

/// Stable step of a model whose points are all average-nodal-pressure tets (Joldes et al.
/// 2009), s, and the node that sets it. Linearized at the reference state the ANP stiffness
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
/// Nodes whose three components are prescribed (`prescribed`) are left out of G (their DOFs are
/// not integrated). Each point's mu and rho are its material's; kappa is the largest over the
/// points (an upper bound where regions differ). Masses in kg.
pub fn anp_time_step(
    qp: &QuadraturePoints,
    slots: &crate::quadrature::NodeSlots,
    mass: &[f64],
    prescribed: &[[bool; 3]],
    moduli: &Moduli,
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
    // g_n as sorted (node j, V_p b_pj summed over the points p at n that reach j).
    let mut w = vec![0.0; n];
    let g: Vec<Vec<(usize, nalgebra::Vector3<f64>)>> = (0..n)
        .map(|node| {
            let mut acc: Vec<(usize, nalgebra::Vector3<f64>)> = Vec::new();
            for k in slots.range(node) {
                let p = slots.points[k] as usize;
                w[node] += qp.weights[p];
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
            acc
        })
        .collect();
    let mut best = (f64::INFINITY, 0);
    let mut row: Vec<f64> = vec![0.0; n];
    let mut seen = vec![false; n];
    let mut touched: Vec<usize> = Vec::new();
    for a in 0..n {
        if !(w[a] > 0.0) {
            continue;
        }
        // S_ab = sum_j g_a[j] . g_b[j] / m_j / sqrt(W_a W_b); the b with g_b[j] != 0 are the
        // nodes that share a point with j, i.e. the entries of g_j.
        for &(j, ga) in &g[a] {
            for &(b, _) in &g[j] {
                if let Ok(k) = g[b].binary_search_by_key(&j, |e| e.0) {
                    if !seen[b] {
                        seen[b] = true;
                        touched.push(b);
                    }
                    row[b] += ga.dot(&g[b][k].1) / mass[j];
                }
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
            best = (dt, a);
        }
    }
    best
}

#[cfg(test)]
mod tests {
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
}
