//! Mean-dilatation groups (Nagtegaal, Parks, Rice 1974): the points of a group share their
//! weighted mean J. This room owns each group's mean J and the group pass's per-point scratch.

use nalgebra::Matrix3;

use crate::quadrature::QuadraturePoints;

use super::*;

/// The groups' J and the stresses of their points.
pub(super) struct Groups {
    /// Weighted mean J of each mean-dilatation group.
    pub(super) j: Vec<f64>,
    /// Per mean-dilatation group, the index of its first point in the arrays below (one
    /// entry per mean-dilatation point, in point order).
    pub(super) first: Vec<u32>,
    /// w P of each mean-dilatation point from the last force evaluation, N m
    /// ([`super::Forces::group_stress`]).
    pub(super) pk: Vec<Matrix3<f64>>,
    /// Scratch of the group pass per mean-dilatation point: its own F.
    pub(super) f: Vec<Matrix3<f64>>,
    /// Scratch of the group pass per mean-dilatation point: its own J, alpha = (J_mean /
    /// J)^(1/3) and tau = P(F_bar) : F_bar / 3 (Pa).
    pub(super) s: Vec<[f64; 3]>,
}

impl Groups {
    /// The groups of `qp` (`qp.groups`: each group's point range).
    pub(super) fn new(qp: &QuadraturePoints) -> Self {
        let mut first = Vec::with_capacity(qp.groups.len());
        let mut in_groups = 0u32;
        for &[a, b] in &qp.groups {
            first.push(in_groups);
            in_groups += b - a;
        }
        let in_groups = in_groups as usize;
        Groups {
            j: vec![1.0; qp.groups.len()],
            first,
            pk: vec![Matrix3::zeros(); in_groups],
            f: vec![Matrix3::zeros(); in_groups],
            s: vec![[0.0; 3]; in_groups],
        }
    }

    /// Heap bytes of its tables and scratch.
    pub(super) fn bytes(&self) -> usize {
        heap_bytes(&self.j)
            + heap_bytes(&self.first)
            + heap_bytes(&self.pk)
            + heap_bytes(&self.f)
            + heap_bytes(&self.s)
    }
}

/// Where the group pass writes (see [`Forces::group_stress`]): per mean-dilatation point w P,
/// its own F and (J, alpha, tau); per group its mean J.
#[derive(Clone, Copy)]
pub(super) struct GroupScratch {
    pub(super) pk: SharedMut<Matrix3<f64>>,
    pub(super) fs: SharedMut<Matrix3<f64>>,
    pub(super) ss: SharedMut<[f64; 3]>,
    pub(super) gj: SharedMut<f64>,
}

impl<M: Material> Forces<M> {
    /// The stress of every mean-dilatation point, w P into `group_pk`, and the groups' mean J.
    ///
    /// The energy of a group is sum_p w_p W(F_bar_p), F_bar_p = alpha_p F_p with
    /// alpha_p = (J_mean / J_p)^(1/3) and J_mean = sum_p w_p J_p / sum_p w_p. Its exact
    /// gradient (differentiating alpha_p through J_p and J_mean) is the first Piola-Kirchhoff
    /// stress
    ///
    ///   P_p = alpha_p P(F_bar_p) + (J_p T / J_mean - tau_p) F_p^-T,
    ///   tau_p = P(F_bar_p) : F_bar_p / 3,  T = sum_q w_q tau_q / sum_q w_q,
    ///
    /// which for a material split into isochoric and volumetric parts, W = W_iso(C_bar) + U(J)
    /// (neo-Hookean, Ogden), is P_iso(F_p) + J_p U'(J_mean) F_p^-T: the mean dilatation of
    /// Nagtegaal et al. 1974 (the volumetric part of selectively reduced integration). Taking
    /// P(F_bar_p) alone as the stress, as an F-bar ANP does, gives forces that are not the
    /// gradient of any energy: on the coupled cylinder compressed by 70 % and back they made
    /// 2.9 % of the peak work out of nothing. Parallel over groups; each group's sums run in
    /// point order, so the result does not depend on the thread count.
    pub(super) fn group_stresses(&mut self, qp: &QuadraturePoints, u: &[Vector3<f64>]) {
        if qp.groups.is_empty() {
            return;
        }
        let gs = self.group_scratch();
        // Unchecked reads of u in group_stress: every node id is below num_nodes (Self::new).
        let simd = self.simd && u.len() >= self.num_nodes;
        let this = &*self;
        (0..qp.groups.len())
            .into_par_iter()
            .with_min_len(CHUNK / 8)
            .for_each(|g| {
                // SAFETY: each group writes only its own scratch entries; `simd` is set only
                // where the CPU has AVX2 and u holds every node.
                unsafe {
                    #[cfg(target_arch = "x86_64")]
                    if simd {
                        return this.group_stress_avx2(qp, g, u, gs);
                    }
                    #[cfg(not(target_arch = "x86_64"))]
                    let _ = simd;
                    this.group_stress::<false>(qp, g, u, gs);
                }
            });
    }

    /// Pointers to the group scratch, for passes that write each group's entries from one
    /// task.
    pub(super) fn group_scratch(&mut self) -> GroupScratch {
        GroupScratch {
            pk: SharedMut(self.groups.pk.as_mut_ptr()),
            fs: SharedMut(self.groups.f.as_mut_ptr()),
            ss: SharedMut(self.groups.s.as_mut_ptr()),
            gj: SharedMut(self.groups.j.as_mut_ptr()),
        }
    }

    /// [`Self::group_stress`] compiled for AVX2.
    ///
    /// # Safety
    /// As [`Self::group_stress`], and the CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn group_stress_avx2(
        &self,
        qp: &QuadraturePoints,
        g: usize,
        u: &[Vector3<f64>],
        gs: GroupScratch,
    ) {
        self.group_stress::<true>(qp, g, u, gs)
    }

    /// Group `g` of [`Self::group_stresses`]: its points' F, J and w P into the scratch, its
    /// mean J into `group_j`. Each sum runs in point order.
    ///
    /// # Safety
    /// The group's scratch entries belong to the caller alone; every node id is below
    /// `u.len()`; AVX only where the CPU has AVX2.
    #[inline(always)]
    pub(super) unsafe fn group_stress<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        g: usize,
        u: &[Vector3<f64>],
        gs: GroupScratch,
    ) {
        let [a, b] = qp.groups[g];
        let (a, b) = (a as usize, b as usize);
        let i0 = self.groups.first[g] as usize;
        // SAFETY: group g owns the entries i0 .. i0 + (b - a) (prefix sums of the group
        // sizes, built in `with_materials`).
        let (pk, fs, ss) = (
            std::slice::from_raw_parts_mut(gs.pk.get().add(i0), b - a),
            std::slice::from_raw_parts_mut(gs.fs.get().add(i0), b - a),
            std::slice::from_raw_parts_mut(gs.ss.get().add(i0), b - a),
        );
        // The AVX2 gradient makes the portable loop's products and sums in its order (bitwise
        // the same F); MLS points have 20-60 supports.
        for (k, p) in (a..b).enumerate() {
            let r = qp.slots(p);
            fs[k] = Self::gradient_any::<AVX>(qp, r.start, r.end, u);
        }
        let (mut wj, mut w) = (0.0, 0.0);
        for (k, p) in (a..b).enumerate() {
            let j = fs[k].determinant();
            ss[k][0] = j;
            wj += qp.weights[p] * j;
            w += qp.weights[p];
        }
        let j_mean = wj / w;
        *gs.gj.get().add(g) = j_mean;
        // P(F_bar) of LANES points of one material at once (`first_pk_stress_lanes`, bitwise
        // each point's `first_pk_stress`); the sums stay in point order.
        let mat = |p: usize| self.point_material.get(p).copied().unwrap_or(0) as usize;
        let mut wt = 0.0;
        let mut k = 0;
        while k < b - a {
            let (p, m) = (a + k, mat(a + k));
            let lanes = if k + LANES <= b - a && (p..p + LANES).all(|q| mat(q) == m) {
                LANES
            } else {
                1
            };
            let mut fl = [[0.0; LANES]; 9];
            let mut alpha = [0.0; LANES];
            for l in 0..lanes {
                alpha[l] = cbrt(j_mean / ss[k + l][0]);
                let fb = fs[k + l] * alpha[l];
                for (i, e) in fl.iter_mut().enumerate() {
                    e[l] = fb[(i / 3, i % 3)];
                }
            }
            let pbl = if lanes == LANES {
                self.materials[m].first_pk_stress_lanes(&fl, &[j_mean; LANES])
            } else {
                let fb = Matrix3::from_fn(|r, c| fl[3 * r + c][0]);
                let pb = self.materials[m].first_pk_stress(&fb, j_mean);
                std::array::from_fn(|i| {
                    let mut o = [0.0; LANES];
                    o[0] = pb[(i / 3, i % 3)];
                    o
                })
            };
            for l in 0..lanes {
                let fb = Matrix3::from_fn(|r, c| fl[3 * r + c][l]);
                let pb = Matrix3::from_fn(|r, c| pbl[3 * r + c][l]);
                let tau = pb.dot(&fb) / 3.0;
                pk[k + l] = pb;
                ss[k + l] = [ss[k + l][0], alpha[l], tau];
                wt += qp.weights[p + l] * tau;
            }
            k += lanes;
        }
        let t_mean = wt / w;
        for (k, p) in (a..b).enumerate() {
            let [j, alpha, tau] = ss[k];
            // J F^-T, the cofactor matrix.
            let cof = crate::geometry::cofactor(&fs[k]);
            pk[k] = (pk[k] * alpha + cof * (t_mean / j_mean - tau / j)) * qp.weights[p];
        }
    }
}
