//! The lane kernel: the force chunks, their work items, lane blocks of four points of one
//! kind evaluated together (AVX2 where the CPU has it, SSE2 otherwise, bitwise the same), the
//! deformation gradients, stresses and slot forces into the chunks' buffers.

use super::*;

impl<M: Material> Forces<M> {
    /// The point stage of [`Self::compute`]: every chunk's forces on its nodes, every point's
    /// J, and the smallest J ([`Self::min_j`]). Nodal forces then follow from
    /// [`Self::node_forces`], which the integrator fuses with its update.
    pub fn compute_points(&mut self, qp: &QuadraturePoints, slots: &NodeSlots, u: &[Vector3<f64>]) {
        // The kernel reads u unchecked: every slot's node id is below num_nodes (Self::new).
        assert!(
            u.len() >= self.num_nodes
                && qp.nodes.len() == self.plan.buffers.slot_entry.len()
                && slots.slots.len() == qp.nodes.len(),
            "force evaluation on {} nodes and {} slots; built for {} and {}",
            u.len(),
            qp.nodes.len(),
            self.num_nodes,
            self.plan.buffers.slot_entry.len()
        );
        // The groups' stresses come inside the chunks (`group_point`).
        if self.pressure.present {
            self.nodal_pressures(qp, u);
        }
        let gs = self.group_scratch();
        let cf = SharedMut(self.plan.chunk_forces.as_mut_ptr());
        let pj = SharedMut(self.point_j.as_mut_ptr());
        let this = &*self;
        self.min_j = crate::solver::two_ended::for_each_item(
            this.plan.chunks.len(),
            (f64::INFINITY, usize::MAX),
            |c| {
                let ch = &this.plan.chunks[c];
                // SAFETY: a chunk writes only its own buffer entries and its points' J
                // entries, and every node id is below u.len() (checked above and in
                // Self::new); `simd` was set only where the CPU has AVX2.
                unsafe {
                    #[cfg(target_arch = "x86_64")]
                    if this.simd {
                        return this.chunk_avx2(qp, ch, u, cf, pj, gs);
                    }
                    this.chunk::<false>(qp, ch, u, cf, pj, gs)
                }
            },
            min_by_j,
        );
    }

    /// One chunk: clears its buffer, then adds its items' forces into it in order; returns
    /// the smallest (J, point) of its points.
    ///
    /// # Safety
    /// The chunk's buffer entries and points belong to it alone, and every node id is below
    /// `u.len()`.
    #[inline(always)]
    pub(super) unsafe fn chunk<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        ch: &Chunk,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        for e in ch.buf[0] as usize..ch.buf[1] as usize {
            *cf.get().add(e) = Vector3::zeros();
        }
        let mut best = (f64::INFINITY, usize::MAX);
        for it in self
            .plan
            .items
            .get_unchecked(ch.items[0] as usize..ch.items[1] as usize)
        {
            best = min_by_j(best, self.item::<AVX>(qp, it, u, cf, pj, gs));
        }
        best
    }

    /// [`Self::chunk`] compiled for AVX2, so the four lanes of a block fill one register. Rust
    /// never fuses a multiply and an add on its own, so every lane computes exactly the
    /// operations of the SSE2 path: the forces are bitwise the same on either.
    ///
    /// # Safety
    /// As [`Self::chunk`], and the CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn chunk_avx2(
        &self,
        qp: &QuadraturePoints,
        ch: &Chunk,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        self.chunk::<true>(qp, ch, u, cf, pj, gs)
    }

    /// One work item: adds its points' forces into the chunk buffer and writes their J's;
    /// returns their smallest (J, point).
    ///
    /// # Safety
    /// As [`Self::chunk`] for the item's chunk.
    #[inline(always)]
    pub(super) unsafe fn item<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        it: &Item,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        if it.mode == Mode::Group {
            return self.group_point::<AVX>(qp, it.first as usize, u, cf, pj, gs);
        }
        // Each concrete material gets its own copy of the kernels (see Material::concrete).
        match self
            .materials
            .get_unchecked(it.material as usize)
            .concrete()
        {
            Concrete::NeoHookean(m) => self.item_with::<AVX, _>(qp, m, it, u, cf, pj),
            Concrete::Ogden(m) => self.item_out_of_line::<AVX, _>(qp, m, it, u, cf, pj),
            Concrete::Itself(m) => self.item_out_of_line::<AVX, _>(qp, m, it, u, cf, pj),
        }
    }

    /// [`Self::item_with`] out of line: the kernels of the other materials stay out of the
    /// neo-Hookean chunk loop (inlined there they slowed it by 7-10 %, hex8 on one thread).
    ///
    /// # Safety
    /// As [`Self::chunk`] for the item's chunk.
    #[inline(never)]
    pub(super) unsafe fn item_out_of_line<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        it: &Item,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        self.item_with::<AVX, K>(qp, mat, it, u, cf, pj)
    }

    /// [`Self::item`] with the item's material `mat` as its concrete type.
    ///
    /// # Safety
    /// As [`Self::chunk`] for the item's chunk.
    #[inline(always)]
    pub(super) unsafe fn item_with<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        it: &Item,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        let p = it.first as usize;
        match (it.mode, it.count as usize) {
            (Mode::Plain8, LANES) => {
                self.lanes::<8, LANES, false, false, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Plain8, _) => self.lanes::<8, 1, false, false, AVX, K>(qp, mat, p, 0, u, cf, pj),
            (Mode::Plain4, LANES) => {
                self.lanes::<4, LANES, false, false, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Anp4, LANES) => {
                self.lanes::<4, LANES, false, true, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Plain4, _) => self.lanes::<4, 1, false, false, AVX, K>(qp, mat, p, 0, u, cf, pj),
            (Mode::Hourglass8, LANES) => {
                self.lanes::<8, LANES, true, false, AVX, K>(qp, mat, p, it.lane, u, cf, pj)
            }
            (Mode::Hourglass8, _) => {
                self.lanes::<8, 1, true, false, AVX, K>(qp, mat, p, 0, u, cf, pj)
            }
            (Mode::Group, _) => unreachable!("group points are evaluated by `item`"),
            (Mode::Other, LANES) => self.stress_batch::<AVX, K>(qp, mat, p, u, cf, pj),
            (Mode::Other, _) | (Mode::Anp4, _) => {
                let (f, a) = self.gradient::<AVX>(qp, p, u);
                let j = self.stress_to_chunk::<AVX, K>(qp, mat, p, a, f, cf);
                *pj.get().add(p) = j;
                (j, p)
            }
        }
    }

    /// LANES consecutive points evaluated one at a time up to F (as single points), with their
    /// stresses evaluated side by side ([`Material::first_pk_stress_lanes`]), then their slot forces
    /// added in point order: every point gets bitwise its single-point result.
    ///
    /// # Safety
    /// As [`Self::chunk`] for the points `p0..p0 + LANES`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn stress_batch<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        p0: usize,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        let mut fl = [[0.0; LANES]; 9];
        let mut jl = [0.0; LANES];
        let mut first = [0; LANES];
        for l in 0..LANES {
            // Mean-dilatation points never come here (Mode::Group): the plain F's stress.
            let (f, a) = self.gradient::<AVX>(qp, p0 + l, u);
            let j = f.determinant();
            for (i, e) in fl.iter_mut().enumerate() {
                e[l] = f[(i / 3, i % 3)];
            }
            jl[l] = j;
            first[l] = a;
        }
        let pk = mat.first_pk_stress_lanes(&fl, &jl);
        for l in 0..LANES {
            let p = p0 + l;
            let pkl = Matrix3::from_fn(|r, c| pk[3 * r + c][l]) * qp.weights[p];
            let d = &qp.dphi[first[l]..qp.offsets[p + 1]];
            self.forces_to_chunk::<AVX>(first[l], &pkl, d, cf);
        }
        Self::block_j(p0, &jl, pj)
    }

    /// The slot forces of mean-dilatation point `p`; at the group's first point, first the
    /// group's stresses ([`Self::group_stress`]), so each group's dphi is read from memory once
    /// per step and its second read, for the forces, finds it in cache. The point's J is its
    /// own det F (not the group's mean, so that a Gauss point inverting inside a cell that
    /// keeps its volume still stops the run).
    ///
    /// # Safety
    /// As [`Self::chunk`] for the point `p`.
    #[inline(never)]
    pub(super) unsafe fn group_point<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
        gs: GroupScratch,
    ) -> (f64, usize) {
        let PointKind::MeanDilatation(g) = qp.kinds[p] else {
            unreachable!("group mode of a point outside the groups");
        };
        let g = g as usize;
        let first = qp.groups[g][0] as usize;
        if p == first {
            // The chunk holds the whole group (`plan`).
            #[cfg(target_arch = "x86_64")]
            if AVX {
                self.group_stress_avx2(qp, g, u, gs);
            } else {
                self.group_stress::<false>(qp, g, u, gs);
            }
            #[cfg(not(target_arch = "x86_64"))]
            self.group_stress::<false>(qp, g, u, gs);
        }
        let i = self.groups.first[g] as usize + (p - first);
        let a = qp.offsets[p];
        let pk = *gs.pk.get().add(i);
        self.forces_to_chunk::<AVX>(a, &pk, &qp.dphi[a..qp.offsets[p + 1]], cf);
        let j = (*gs.ss.get().add(i))[0];
        *pj.get().add(p) = j;
        (j, p)
    }

    /// F of point `p` and its first slot: fixed-size loops for 8 and 4 support nodes (ANP
    /// tetrahedra, 8-node mean-dilatation points), any size otherwise.
    ///
    /// # Safety
    /// Every node id of the point is below `u.len()`.
    #[inline(always)]
    pub(super) unsafe fn gradient<const AVX: bool>(
        &self,
        qp: &QuadraturePoints,
        p: usize,
        u: &[Vector3<f64>],
    ) -> (Matrix3<f64>, usize) {
        let (a, b) = (qp.offsets[p], qp.offsets[p + 1]);
        let f = match b - a {
            8 => Self::gradient_fixed::<8>(qp, a, u),
            4 => Self::gradient_fixed::<4>(qp, a, u),
            _ => Self::gradient_any::<AVX>(qp, a, b, u),
        };
        (f, a)
    }

    /// F of a point with exactly N support nodes from slot `a`: the loops unroll and the slot
    /// slices are checked once.
    ///
    /// # Safety
    /// Every node id of the slots is below `u.len()`.
    #[inline(always)]
    pub(super) unsafe fn gradient_fixed<const N: usize>(
        qp: &QuadraturePoints,
        a: usize,
        u: &[Vector3<f64>],
    ) -> Matrix3<f64> {
        let ids = &qp.nodes[a..a + N];
        let d = &qp.dphi[a..a + N];
        let ul: [Vector3<f64>; N] = std::array::from_fn(|k| *u.get_unchecked(ids[k] as usize));
        let mut f = Matrix3::identity();
        for k in 0..N {
            f += ul[k] * d[k].transpose();
        }
        f
    }

    /// F of a point with any number of support nodes (slots a..b).
    ///
    /// # Safety
    /// Every node id of the slots is below `u.len()`; AVX only where the CPU has AVX2.
    #[inline(always)]
    pub(super) unsafe fn gradient_any<const AVX: bool>(
        qp: &QuadraturePoints,
        a: usize,
        b: usize,
        u: &[Vector3<f64>],
    ) -> Matrix3<f64> {
        let d = &qp.dphi[a..b];
        let ids = &qp.nodes[a..b];
        #[cfg(target_arch = "x86_64")]
        if AVX {
            // SAFETY: AVX is set only under chunk_avx2; ids are below u.len() (see Safety).
            return crate::solver::lanes_avx2::any_gradient(ids, d, u.as_ptr());
        }
        let mut f = Matrix3::identity();
        for (&id, dk) in ids.iter().zip(d) {
            f += *u.get_unchecked(id as usize) * dk.transpose();
        }
        f
    }

    /// L consecutive points `p0..p0 + L` of N support nodes each (slots contiguous from
    /// `offsets[p0]`), Standard kind, with `HG` one-point hexahedra, with `ANP`
    /// average-nodal-pressure tetrahedra: F, J, P and the slot forces w P dphi_k (+ the
    /// hourglass force G G^T u) with the lanes innermost, so each
    /// operation runs on all L points at once. L = 1 evaluates single points with the same
    /// operations per point.
    /// Writes the points' J and returns their smallest (J, point).
    ///
    /// # Safety
    /// The points' chunk buffer belongs to the caller alone, and every node id is below
    /// `u.len()`.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // index loops over lanes are what vectorizes
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn lanes<
        const N: usize,
        const L: usize,
        const HG: bool,
        const ANP: bool,
        const AVX: bool,
        K: Material,
    >(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        p0: usize,
        lane: u32,
        u: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        let a0 = *qp.offsets.get_unchecked(p0);
        let nodes = qp.nodes.as_ptr().add(a0);
        // dphi and G in lane order: blocks read the copies made at construction; a single
        // point (L = 1) reads its own slots, which are already in that order.
        let mut own_d = [[[0.0; L]; 3]; N];
        let mut own_g = [[[0.0; L]; 8]; 4];
        type Dphi<const N: usize, const L: usize> = [[[f64; L]; 3]; N];
        type HourglassG<const L: usize> = [[[f64; L]; 8]; 4];
        let (dl, gl): (&Dphi<N, L>, &HourglassG<L>) = if L == LANES {
            let base = self.plan.lane_data.as_ptr().add(lane as usize) as *const f64;
            // G follows dphi only in hexahedron blocks; other blocks never form its reference.
            let g = if HG {
                &*(base.add(N * 3 * L) as *const [[[f64; L]; 8]; 4])
            } else {
                &own_g
            };
            (&*(base as *const [[[f64; L]; 3]; N]), g)
        } else {
            for k in 0..N {
                let d = qp.dphi.get_unchecked(a0 + k);
                for c in 0..3 {
                    own_d[k][c][0] = d[c];
                }
            }
            if HG {
                if let PointKind::Hourglass(h) = *qp.kinds.get_unchecked(p0) {
                    let g = qp.hourglass.get_unchecked(h as usize).as_slice();
                    for m in 0..4 {
                        for r in 0..8 {
                            own_g[m][r][0] = g[8 * m + r];
                        }
                    }
                }
            }
            (&own_d, &own_g)
        };
        let load = |k: usize| -> [[f64; L]; 3] {
            std::array::from_fn(|c| {
                std::array::from_fn(|l| (*u.get_unchecked(*nodes.add(l * N + k) as usize))[c])
            })
        };
        // F = I + sum_k u_k (x) dphi_k, row-major: f[3 r + c].
        let mut f = [[0.0; L]; 9];
        for r in 0..3 {
            f[4 * r] = [1.0; L];
        }
        for k in 0..N {
            let uk = load(k);
            for r in 0..3 {
                for c in 0..3 {
                    for l in 0..L {
                        f[3 * r + c][l] += uk[r][l] * dl[k][c][l];
                    }
                }
            }
        }
        let mut j = [0.0; L];
        for l in 0..L {
            let m = |i: usize| f[i][l];
            j[l] = m(0) * (m(4) * m(8) - m(7) * m(5)) - m(1) * (m(3) * m(8) - m(6) * m(5))
                + m(2) * (m(3) * m(7) - m(6) * m(4));
        }
        let mut pk = mat.first_pk_stress_lanes(&f, &j);
        if ANP {
            // As Self::anp_stress, the lanes side by side: P + (p_mean - U'(J)) cof(F), the
            // cofactors by the products and signs of geometry::cofactor.
            let mut s = [0.0; L];
            for l in 0..L {
                let mut sum = 0.0;
                for k in 0..N {
                    sum += *self
                        .pressure
                        .node_p
                        .get_unchecked(self.pressure_node(qp, a0 + l * N + k));
                }
                s[l] = sum / N as f64 - mat.volumetric(j[l]).1;
            }
            let minor = |a: usize, b: usize, c: usize, d: usize, l: usize| {
                f[a][l] * f[b][l] - f[c][l] * f[d][l]
            };
            for l in 0..L {
                let cof = [
                    minor(4, 8, 5, 7, l),
                    -minor(3, 8, 5, 6, l),
                    minor(3, 7, 4, 6, l),
                    -minor(1, 8, 2, 7, l),
                    minor(0, 8, 2, 6, l),
                    -minor(0, 7, 1, 6, l),
                    minor(1, 5, 2, 4, l),
                    -minor(0, 5, 2, 3, l),
                    minor(0, 4, 1, 3, l),
                ];
                for (row, c) in pk.iter_mut().zip(cof) {
                    row[l] += c * s[l];
                }
            }
        }
        let w: [f64; L] = std::array::from_fn(|l| *qp.weights.get_unchecked(p0 + l));
        for row in pk.iter_mut() {
            for l in 0..L {
                row[l] *= w[l];
            }
        }
        // Hexahedra: hourglass modes q_m = sum_r G_rm u_r (G column-major 8 x 4).
        let mut q = [[[0.0; L]; 3]; 4];
        if HG {
            for r in 0..N.min(8) {
                let ur = load(r);
                for m in 0..4 {
                    for c in 0..3 {
                        for l in 0..L {
                            q[m][c][l] += gl[m][r][l] * ur[c][l];
                        }
                    }
                }
            }
        }
        // Slot forces w P dphi_k (+ sum_m G_km q_m for hexahedra), added to the chunk buffer
        // slot by slot, the four points of a slot in turn (measured faster than point by point
        // through a transposed copy: hex8 cylinder 0.46 -> 0.44 ms per step on one thread).
        let entries = self.plan.buffers.slot_entry.as_ptr().add(a0);
        #[cfg(target_arch = "x86_64")]
        if AVX && L == LANES {
            // SAFETY: AVX is set only under chunk_avx2 (the CPU has AVX2), L == 4 makes the
            // casts exact, and the entries are the block's own (see Safety).
            crate::solver::lanes_avx2::slot_forces::<N, HG>(
                &*(pk.as_ptr() as *const [[f64; 4]; 9]),
                &*(dl as *const Dphi<N, L> as *const [[[f64; 4]; 3]; N]),
                &*(gl as *const HourglassG<L> as *const [[[f64; 4]; 8]; 4]),
                &*(q.as_ptr() as *const [[[f64; 4]; 3]; 4]),
                entries,
                cf.get(),
            );
            return Self::block_j(p0, &j, pj);
        }
        for k in 0..N {
            let mut o = [[0.0; L]; 3];
            for r in 0..3 {
                for l in 0..L {
                    o[r][l] = pk[3 * r][l] * dl[k][0][l]
                        + pk[3 * r + 1][l] * dl[k][1][l]
                        + pk[3 * r + 2][l] * dl[k][2][l];
                }
            }
            if HG {
                let kk = k.min(7);
                for c in 0..3 {
                    for l in 0..L {
                        let mut acc = 0.0;
                        for m in 0..4 {
                            acc += gl[m][kk][l] * q[m][c][l];
                        }
                        o[c][l] += acc;
                    }
                }
            }
            for l in 0..L {
                let t = &mut *cf.get().add(*entries.add(l * N + k) as usize);
                t.x += o[0][l];
                t.y += o[1][l];
                t.z += o[2][l];
            }
        }
        Self::block_j(p0, &j, pj)
    }

    /// Writes the J's of the points `p0..p0 + L` and returns their smallest (J, point).
    ///
    /// # Safety
    /// The points' J entries belong to the caller alone.
    #[inline(always)]
    pub(super) unsafe fn block_j<const L: usize>(
        p0: usize,
        j: &[f64; L],
        pj: SharedMut<f64>,
    ) -> (f64, usize) {
        let mut best = (f64::INFINITY, usize::MAX);
        for (l, &jl) in j.iter().enumerate() {
            *pj.get().add(p0 + l) = jl;
            best = min_by_j(best, (jl, p0 + l));
        }
        best
    }

    /// From the plain F of point `p` (slots from `a`): the stress (ANP points:
    /// [`Self::anp_stress`]) and the slot forces w P dphi_k, added to the chunk buffer. Returns
    /// det F.
    ///
    /// # Safety
    /// The point's chunk buffer belongs to the caller alone.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn stress_to_chunk<const AVX: bool, K: Material>(
        &self,
        qp: &QuadraturePoints,
        mat: &K,
        p: usize,
        a: usize,
        f: Matrix3<f64>,
        cf: SharedMut<Vector3<f64>>,
    ) -> f64 {
        // Mean-dilatation points never come here (Mode::Group).
        let j = f.determinant();
        let pk = if qp.kinds[p] == PointKind::Anp {
            self.anp_stress(qp, mat, p, &f, j)
        } else {
            mat.first_pk_stress(&f, j)
        };
        let pk = pk * qp.weights[p];
        self.forces_to_chunk::<AVX>(a, &pk, &qp.dphi[a..qp.offsets[p + 1]], cf);
        j
    }

    /// The slot forces P dphi_k (P already times the weight) of the point whose slots start at
    /// `a` (derivatives `d`), added to the chunk buffer.
    ///
    /// # Safety
    /// The point's chunk buffer belongs to the caller alone; AVX only where the CPU has AVX2.
    #[inline(always)]
    pub(super) unsafe fn forces_to_chunk<const AVX: bool>(
        &self,
        a: usize,
        pk: &Matrix3<f64>,
        d: &[Vector3<f64>],
        cf: SharedMut<Vector3<f64>>,
    ) {
        let entries = &self.plan.buffers.slot_entry[a..a + d.len()];
        #[cfg(target_arch = "x86_64")]
        if AVX {
            // SAFETY: AVX is set only under chunk_avx2; the entries are the point's own.
            crate::solver::lanes_avx2::any_forces(pk, d, entries, cf.get());
            return;
        }
        // Column by column, the association lanes_avx2::any_forces repeats.
        let (c0, c1, c2) = (pk.column(0), pk.column(1), pk.column(2));
        for (dk, &e) in d.iter().zip(entries) {
            *cf.get().add(e as usize) += c0 * dk.x + c1 * dk.y + c2 * dk.z;
        }
    }
}
