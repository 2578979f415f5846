//! What the static solve refuses before it starts: moduli out of range, loads and methods it
//! does not support, and a model free to move as a rigid body (issue 57, item 7).

use nalgebra::Vector3;

use super::super::Model;
use crate::material::Material;
use crate::{Error, InputKind, Result};

/// Moduli far out of range (E = 1e308 Pa) overflow the tangent: the factorization then met a
/// zero pivot ("the tangent stiffness is singular"), which named neither the cause nor the
/// keys. The static form of relaxation's wave-speed check, which also reads the density.
fn check_moduli<M: Material>(model: &Model<M>) -> Result<()> {
    for m in &model.forces.materials {
        let (lambda, mu) = m.lame();
        let p = lambda + 2.0 * mu;
        if !(p.is_finite() && p > 0.0 && mu.is_finite() && mu > 0.0 && p < 1e30) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "the dilatational modulus lambda + 2 mu of a material is {} Pa (mu {} Pa): the \
                     static solve's tangent cannot hold it; check the moduli (Pa) of [material] and \
                     [regions] (soft tissue: about 1e3-1e5 Pa)",
                    crate::error::Sci(p),
                    crate::error::Sci(mu)
                ),
            ));
        }
    }
    Ok(())
}

/// Refuses what the static solve does not handle yet, saying what to use instead.
pub(super) fn check_supported<M: Material>(model: &Model<M>) -> Result<()> {
    check_moduli(model)?;
    let what = if model
        .corrector
        .as_ref()
        .is_some_and(|c| c.linear_constraints(1.0).is_none())
    {
        Some("this model's corrected essential boundaries")
    } else {
        None
    };
    match what {
        Some(w) => Err(Error::input(
            InputKind::Unsupported,
            format!(
            "solver.mode = \"static\" does not handle {w} yet; set solver.mode = \"relaxation\""
        ),
        )),
        None => Ok(()),
    }
}

/// The rigid motions (translations, rotations about the body's centroid) that no prescribed
/// component holds, named; empty when the boundaries hold the body. A rigid motion is held
/// when some prescribed DOF moves under it: the null space of the 6 x 6 Gram matrix of the
/// motions restricted to the prescribed DOFs.
pub fn free_rigid_motions<M: Material>(model: &Model<M>) -> Vec<String> {
    let n = model.nodes.len();
    if n == 0 {
        return Vec::new();
    }
    let c: Vector3<f64> = model.nodes.iter().sum::<Vector3<f64>>() / n as f64;
    let size = model
        .nodes
        .iter()
        .map(|x| (x - c).norm())
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let mode = |m: usize, x: &Vector3<f64>| -> Vector3<f64> {
        if m < 3 {
            Vector3::ith(m, 1.0)
        } else {
            Vector3::ith(m - 3, 1.0).cross(&((x - c) / size))
        }
    };
    let mut g = nalgebra::SMatrix::<f64, 6, 6>::zeros();
    for (i, mask) in model.constraints.mask.iter().enumerate() {
        for k in 0..3 {
            if mask[k] {
                let r: [f64; 6] = std::array::from_fn(|m| mode(m, &model.nodes[i])[k]);
                for a in 0..6 {
                    for b in 0..6 {
                        g[(a, b)] += r[a] * r[b];
                    }
                }
            }
        }
    }
    if let Some(rows) = model
        .corrector
        .as_ref()
        .and_then(|c| c.linear_constraints(1.0))
    {
        for lc in &rows {
            let mut r = [0.0; 6];
            for &(j, w) in &lc.row {
                for (m, rm) in r.iter_mut().enumerate() {
                    *rm += w * mode(m, &model.nodes[j as usize])[lc.axis];
                }
            }
            for a in 0..6 {
                for b in 0..6 {
                    g[(a, b)] += r[a] * r[b];
                }
            }
        }
    }
    let eig = g.symmetric_eigen();
    let top = eig.eigenvalues.amax().max(1.0);
    let names = ["x", "y", "z"];
    let mut out = Vec::new();
    for m in 0..6 {
        if eig.eigenvalues[m] > 1e-10 * top {
            continue;
        }
        let v = eig.eigenvectors.column(m);
        let t = Vector3::new(v[0], v[1], v[2]);
        let r = Vector3::new(v[3], v[4], v[5]);
        let describe = |w: Vector3<f64>| {
            let k = w.iamax();
            let others = (0..3)
                .filter(|&j| j != k && w[j].abs() > 0.05 * w[k].abs())
                .count();
            if others == 0 {
                names[k].to_string()
            } else {
                format!(
                    "({:.2}, {:.2}, {:.2})",
                    w[0] / w[k],
                    w[1] / w[k],
                    w[2] / w[k]
                )
            }
        };
        if r.norm() < 1e-6 {
            out.push(format!("translation along {}", describe(t)));
        } else if t.norm() < 1e-6 {
            out.push(format!(
                "rotation about {} through ({:.4e}, {:.4e}, {:.4e}) m",
                describe(r),
                c.x,
                c.y,
                c.z
            ));
        } else {
            out.push(format!(
                "a combined translation and rotation (axis {})",
                describe(r)
            ));
        }
    }
    out
}
