// hytled's explicit time loop on an NVIDIA GPU (f64). Compiled at run time by NVRTC with
// --fmad=false, so that every operation is the one the CPU path (src/solver/forces.rs,
// src/material.rs, src/solver/integrate/predict.rs) performs, in the same order: the forces,
// displacements and step counts match the CPU run bitwise. Each formula below names the CPU
// code it repeats; change both together.
//
// The same source also compiles as C++ (g++, with the shim of emulate.rs): the tests run these
// kernels on the CPU without a GPU.

#define BLOCK 256
#define INF __longlong_as_double(0x7ff0000000000000LL)

typedef unsigned int u32;
typedef unsigned long long usize;

// material::inv_cbrt: magic start and four Newton steps; library cube root outside
// [f64::MIN_POSITIVE, 1e300).
__device__ __forceinline__ double inv_cbrt(double x) {
    unsigned long long bits = (unsigned long long)__double_as_longlong(x);
    double y = __longlong_as_double((long long)(0x553ef0ff289dd796ULL - bits / 3ULL));
    double x3 = x * (1.0 / 3.0);
    for (int i = 0; i < 4; i++) {
        double y2 = y * y;
        y = (4.0 / 3.0) * y - x3 * (y2 * y2);
    }
    if (!(x >= 2.2250738585072014e-308 && x < 1e300)) {
        y = 1.0 / cbrt(x);
    }
    return y;
}

// forces.rs cbrt: x (x^(-1/3))^2.
__device__ __forceinline__ double cbrt_fast(double x) {
    double r = inv_cbrt(x);
    return x * (r * r);
}

// predict.rs nan_max.
__device__ __forceinline__ double nan_max(double a, double b) {
    if (a != a || b != b) return a + b;  // NaN
    return a > b ? a : b;
}

// nalgebra's 3x3 determinant (= the lane kernel's J), row-major f.
__device__ __forceinline__ double det3(const double* m) {
    return m[0] * (m[4] * m[8] - m[7] * m[5]) - m[1] * (m[3] * m[8] - m[6] * m[5])
        + m[2] * (m[3] * m[7] - m[6] * m[4]);
}

// F = I + sum_k u_k (x) dphi_k over slots a..b, row-major.
__device__ __forceinline__ void gradient(const u32* nodes, const double* dphi, const double* u,
                                         u32 a, u32 b, double* f) {
    for (int i = 0; i < 9; i++) f[i] = (i % 4 == 0) ? 1.0 : 0.0;
    for (u32 s = a; s < b; s++) {
        const double* uk = u + 3 * (usize)nodes[s];
        const double* d = dphi + 3 * (usize)s;
        double u0 = uk[0], u1 = uk[1], u2 = uk[2];
        double d0 = d[0], d1 = d[1], d2 = d[2];
        f[0] += u0 * d0; f[1] += u0 * d1; f[2] += u0 * d2;
        f[3] += u1 * d0; f[4] += u1 * d1; f[5] += u1 * d2;
        f[6] += u2 * d0; f[7] += u2 * d1; f[8] += u2 * d2;
    }
}

// NeoHookean::first_pk_stress_lanes for one lane: P = mu J^(-2/3) F + b cof(F).
__device__ __forceinline__ void neo_pk(const double* m, double j, double mu, double kappa,
                                       double* out) {
    double cof[9];
    cof[0] = m[4] * m[8] - m[5] * m[7];
    cof[1] = m[5] * m[6] - m[3] * m[8];
    cof[2] = m[3] * m[7] - m[4] * m[6];
    cof[3] = m[2] * m[7] - m[1] * m[8];
    cof[4] = m[0] * m[8] - m[2] * m[6];
    cof[5] = m[1] * m[6] - m[0] * m[7];
    cof[6] = m[1] * m[5] - m[2] * m[4];
    cof[7] = m[2] * m[3] - m[0] * m[5];
    cof[8] = m[0] * m[4] - m[1] * m[3];
    double r = inv_cbrt(j);
    double mu_j = mu * (r * r);
    double tr_c = 0.0;
    for (int i = 0; i < 9; i++) tr_c += m[i] * m[i];
    double b = (kappa * j * (j - 1.0) - mu_j * tr_c * (1.0 / 3.0)) / j;
    for (int i = 0; i < 9; i++) out[i] = m[i] * mu_j + cof[i] * b;
}

// geometry::cofactor (J F^-T), row-major.
__device__ __forceinline__ void cofactor(const double* a, double* c) {
    c[0] = a[4] * a[8] - a[5] * a[7];
    c[1] = -(a[3] * a[8] - a[5] * a[6]);
    c[2] = a[3] * a[7] - a[4] * a[6];
    c[3] = -(a[1] * a[8] - a[2] * a[7]);
    c[4] = a[0] * a[8] - a[2] * a[6];
    c[5] = -(a[0] * a[7] - a[1] * a[6]);
    c[6] = a[1] * a[5] - a[2] * a[4];
    c[7] = -(a[0] * a[5] - a[2] * a[3]);
    c[8] = a[0] * a[4] - a[1] * a[3];
}

// The weighted stress w P of a point's own F (forces.rs lanes, stress_to_chunk): neo-Hookean,
// and for ANP points (mode 2) the pressure U'(J) swapped for the mean `psum / n` of their nodal
// pressures (forces.rs anp_stress).
__device__ __forceinline__ void point_stress(const double* f, double j, double mu, double kappa,
                                             u32 md, double psum, u32 n, double w, double* pk) {
    neo_pk(f, j, mu, kappa, pk);
    if (md == 2) {
        double sv = psum / (double)n - kappa * (j - 1.0);
        double cof[9];
        cofactor(f, cof);
        for (int q = 0; q < 9; q++) pk[q] += cof[q] * sv;
    }
    for (int q = 0; q < 9; q++) pk[q] *= w;
}

// forces.rs min_by_j over a block: the smallest (J, point) of sj/sp into entry 0 (the lower
// point among equal J). Every thread of the block calls it.
__device__ __forceinline__ void block_min_j(double* sj, u32* sp) {
    for (u32 h = BLOCK / 2; h > 0; h >>= 1) {
        if (threadIdx.x < h) {
            double jb = sj[threadIdx.x + h];
            u32 pb = sp[threadIdx.x + h];
            if (jb < sj[threadIdx.x] || (jb == sj[threadIdx.x] && pb < sp[threadIdx.x])) {
                sj[threadIdx.x] = jb;
                sp[threadIdx.x] = pb;
            }
        }
        __syncthreads();
    }
}

// predict.rs nan_max over a block, two arrays at once, into entry 0. Every thread calls it.
__device__ __forceinline__ void block_max2(double* a, double* b) {
    for (u32 h = BLOCK / 2; h > 0; h >>= 1) {
        if (threadIdx.x < h) {
            a[threadIdx.x] = nan_max(a[threadIdx.x], a[threadIdx.x + h]);
            b[threadIdx.x] = nan_max(b[threadIdx.x], b[threadIdx.x + h]);
        }
        __syncthreads();
    }
}

// forces.rs nodal_pressures, first loop: J of every ANP point.
extern "C" __global__ void anp_point_j(u32 n, const u32* list, const u32* offsets,
                                       const u32* nodes, const double* dphi, const double* u,
                                       double* point_j) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    u32 p = list[i];
    double f[9];
    gradient(nodes, dphi, u, offsets[p], offsets[p + 1], f);
    point_j[p] = det3(f);
}

// forces.rs nodal_pressures, second loop: J_n and p_n = U'(J_n) = kappa (J_n - 1).
extern "C" __global__ void anp_nodes(u32 n, const u32* off, const u32* pts, const double* w,
                                     const double* inv_w, const u32* point_mat,
                                     const double* kappa, const double* point_j, double* node_j,
                                     double* node_p) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    if (!(inv_w[i] > 0.0)) return;
    double acc = 0.0;
    for (u32 k = off[i]; k < off[i + 1]; k++) acc += w[k] * point_j[pts[k]];
    double nj = acc * inv_w[i];
    node_j[i] = nj;
    node_p[i] = kappa[point_mat[pts[off[i]]]] * (nj - 1.0);
}

// forces.rs group_stresses in five phases, each over the group scratch's entries (k: point
// gpoint[k] of group ggroup[k]) or over the groups, with the CPU's operations and sums in its
// order: 0 F and J per point; 1 the groups' mean J; 2 per point alpha = (J_mean / J)^(1/3),
// P(alpha F) and tau; 3 the groups' mean tau; 4 per point the stress w P.
extern "C" __global__ void group_stress(u32 phase, u32 n, const u32* groups,
                                        const u32* group_first, const u32* gpoint,
                                        const u32* ggroup, const u32* offsets,
                                        const u32* nodes, const double* dphi,
                                        const double* weights, const u32* point_mat,
                                        const double* mu, const double* kappa, const double* u,
                                        double* gf, double* gs, double* gpk, double* group_j,
                                        double* group_t) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    if (phase == 1 || phase == 3) {
        u32 a = groups[2 * i], b = groups[2 * i + 1], i0 = group_first[i];
        double acc = 0.0, w = 0.0;
        for (u32 p = a; p < b; p++) {
            acc += weights[p] * gs[3 * (usize)(i0 + p - a) + (phase == 1 ? 0 : 2)];
            w += weights[p];
        }
        if (phase == 1) group_j[i] = acc / w;
        else group_t[i] = acc / w;
        return;
    }
    usize k = i;
    u32 p = gpoint[k];
    double* f = gf + 9 * k;
    if (phase == 0) {
        gradient(nodes, dphi, u, offsets[p], offsets[p + 1], f);
        gs[3 * k] = det3(f);
    } else if (phase == 2) {
        double j_mean = group_j[ggroup[k]];
        double alpha = cbrt_fast(j_mean / gs[3 * k]);
        double fb[9];
        for (int q = 0; q < 9; q++) fb[q] = f[q] * alpha;
        u32 m = point_mat[p];
        double* pb = gpk + 9 * k;
        neo_pk(fb, j_mean, mu[m], kappa[m], pb);
        // nalgebra's Matrix3::dot: column by column, each column after four zero adds.
        double dot = 0.0;
        for (int c = 0; c < 3; c++) {
            dot += 0.0 + 0.0; dot += 0.0 + 0.0; dot += 0.0 + 0.0; dot += 0.0 + 0.0;
            for (int r = 0; r < 3; r++) dot += pb[3 * r + c] * fb[3 * r + c];
        }
        gs[3 * k + 1] = alpha;
        gs[3 * k + 2] = dot / 3.0;
    } else {
        u32 g = ggroup[k];
        double j = gs[3 * k], alpha = gs[3 * k + 1], tau = gs[3 * k + 2];
        double cof[9];
        cofactor(f, cof);
        double s = group_t[g] / group_j[g] - tau / j;
        double* pk = gpk + 9 * k;
        for (int q = 0; q < 9; q++) pk[q] = (pk[q] * alpha + cof[q] * s) * weights[p];
    }
}

// Point modes (forces.rs Mode, by kind): 0 standard, 1 one-point hexahedron (aux = its
// hourglass matrix), 2 ANP tetrahedron, 3 mean-dilatation point (aux = its group entry).
// Each point writes its slot forces w P dphi_k (+ G q) and its J; each block the smallest
// (J, point) of its points (forces.rs min_by_j: the lower point among equal J, NaN never).
extern "C" __global__ void point_forces(u32 np, const u32* list, const u32* offsets,
                                        const u32* nodes,
                                        const double* dphi, const double* weights,
                                        const u32* mode, const u32* aux, const u32* point_mat,
                                        const double* mu, const double* kappa,
                                        const double* hg, const double* node_p,
                                        const u32* pkey, const double* gpk, const double* gs,
                                        const double* u, const u32* pos, double* slot_force,
                                        double* point_j,
                                        double* blk_j, u32* blk_p) {
    __shared__ double sj[BLOCK];
    __shared__ u32 sp[BLOCK];
    u32 idx = blockIdx.x * blockDim.x + threadIdx.x;
    double jmin = INF;
    u32 pmin = 0xffffffffu;
    if (idx < np) {
        u32 p = list[idx];
        u32 a = offsets[p], b = offsets[p + 1];
        u32 md = mode[p];
        double pk[9];
        double j;
        if (md == 3) {
            usize i = aux[p];
            for (int q = 0; q < 9; q++) pk[q] = gpk[9 * i + q];
            j = gs[3 * i];
        } else {
            double f[9];
            gradient(nodes, dphi, u, a, b, f);
            j = det3(f);
            u32 m = point_mat[p];
            double psum = 0.0;
            if (md == 2)
                for (u32 s = a; s < b; s++) psum += node_p[pkey[s]];
            point_stress(f, j, mu[m], kappa[m], md, psum, b - a, weights[p], pk);
        }
        bool hgp = (md == 1) && (b - a == 8);
        double qm[4][3];
        const double* g = hg + 32 * (usize)(hgp ? aux[p] : 0);
        if (hgp) {
            for (int m = 0; m < 4; m++)
                for (int c = 0; c < 3; c++) qm[m][c] = 0.0;
            for (int r = 0; r < 8; r++) {
                const double* ur = u + 3 * (usize)nodes[a + r];
                for (int m = 0; m < 4; m++)
                    for (int c = 0; c < 3; c++) qm[m][c] += g[8 * m + r] * ur[c];
            }
        }
        for (u32 s = a; s < b; s++) {
            const double* d = dphi + 3 * (usize)s;
            double o[3];
            for (int r = 0; r < 3; r++)
                o[r] = pk[3 * r] * d[0] + pk[3 * r + 1] * d[1] + pk[3 * r + 2] * d[2];
            if (hgp) {
                u32 kk = s - a;
                for (int c = 0; c < 3; c++) {
                    double acc = 0.0;
                    for (int m = 0; m < 4; m++) acc += g[8 * m + kk] * qm[m][c];
                    o[c] += acc;
                }
            }
            double* t = slot_force + 3 * (usize)pos[s];
            t[0] = o[0];
            t[1] = o[1];
            t[2] = o[2];
        }
        point_j[p] = j;
        if (j < jmin) {
            jmin = j;
            pmin = p;
        }
    }
    sj[threadIdx.x] = jmin;
    sp[threadIdx.x] = pmin;
    __syncthreads();
    block_min_j(sj, sp);
    if (threadIdx.x == 0) {
        blk_j[blockIdx.x] = sj[0];
        blk_p[blockIdx.x] = sp[0];
    }
}

// The points with more than 8 slots (MLS, blended), a warp each: lane l takes slots a + l,
// a + l + 32, ... of its point, so that the loads of the slots' data and the stores of their
// forces are coalesced. Every lane adds the slots' products u_k (x) dphi_k (and the ANP
// pressures) in slot order through shared memory, so each lane holds bitwise the F (and P) of
// point_forces. Each block loops over the 32-slot chunks of its largest point (the same trip
// count in all its threads, which the barriers need); the host lists the points by chunk count,
// so that a block's points have about the same.
#define WARPS (BLOCK / 32)
extern "C" __global__ void point_forces_wide(u32 np, const u32* list, u32 has_anp,
                                             const u32* offsets, const u32* nodes,
                                             const double* dphi, const double* weights,
                                             const u32* mode, const u32* aux,
                                             const u32* point_mat, const double* mu,
                                             const double* kappa, const double* node_p,
                                             const u32* pkey, const double* gpk,
                                             const double* gs, const double* u,
                                             const u32* pos, double* slot_force,
                                             double* point_j,
                                             double* blk_j, u32* blk_p) {
    __shared__ double sc[BLOCK * 9];
    __shared__ double sj[WARPS];
    __shared__ u32 sp[WARPS];
    __shared__ u32 sn[WARPS];
    u32 warp = threadIdx.x / 32, lane = threadIdx.x % 32;
    u32 idx = blockIdx.x * WARPS + warp;
    bool active = idx < np;
    u32 p = active ? list[idx] : 0;
    u32 a = active ? offsets[p] : 0, b = active ? offsets[p + 1] : 0;
    u32 md = active ? mode[p] : 0;
    if (lane == 0) sn[warp] = (b - a + 31) / 32;
    __syncthreads();
    u32 chunks = 0;
    for (u32 w = 0; w < WARPS; w++) chunks = sn[w] > chunks ? sn[w] : chunks;
    bool own = active && md != 3;
    // Lane c < 9 sums component c of F over the slots, in slot order.
    double fc = (lane % 4 == 0) ? 1.0 : 0.0;
    double psum = 0.0;
    for (u32 ch = 0; ch < chunks; ch++) {
        u32 first = a + 32 * ch;
        u32 s = first + lane;
        double* mine = sc + 9 * threadIdx.x;
        if (own && s < b) {
            const double* uk = u + 3 * (usize)nodes[s];
            const double* d = dphi + 3 * (usize)s;
            double u0 = uk[0], u1 = uk[1], u2 = uk[2];
            double d0 = d[0], d1 = d[1], d2 = d[2];
            mine[0] = u0 * d0; mine[1] = u0 * d1; mine[2] = u0 * d2;
            mine[3] = u1 * d0; mine[4] = u1 * d1; mine[5] = u1 * d2;
            mine[6] = u2 * d0; mine[7] = u2 * d1; mine[8] = u2 * d2;
        }
        __syncthreads();
        u32 cnt = (own && first < b && lane < 9) ? ((b - first < 32) ? b - first : 32) : 0;
        for (u32 k = 0; k < cnt; k++) fc += sc[9 * (warp * 32 + k) + lane];
        __syncthreads();
    }
    // Every lane takes the whole F (the stress is evaluated by all of them alike).
    if (lane < 9) sc[9 * warp * 32 + lane] = fc;
    __syncthreads();
    double f[9];
    for (int q = 0; q < 9; q++) f[q] = sc[9 * warp * 32 + q];
    __syncthreads();
    bool anp = own && md == 2;
    // ANP: the nodal pressures summed in slot order (`has_anp` is the same in every thread,
    // so every thread reaches the barriers).
    for (u32 ch = 0; has_anp && ch < chunks; ch++) {
        u32 first = a + 32 * ch;
        u32 s = first + lane;
        if (anp && s < b) sc[threadIdx.x] = node_p[pkey[s]];
        __syncthreads();
        u32 cnt = (anp && first < b) ? ((b - first < 32) ? b - first : 32) : 0;
        for (u32 k = 0; k < cnt; k++) psum += sc[warp * 32 + k];
        __syncthreads();
    }
    double pk[9];
    double j = INF;
    if (active) {
        if (md == 3) {
            usize i = aux[p];
            for (int q = 0; q < 9; q++) pk[q] = gpk[9 * i + q];
            j = gs[3 * i];
        } else {
            j = det3(f);
            u32 m = point_mat[p];
            point_stress(f, j, mu[m], kappa[m], md, psum, b - a, weights[p], pk);
        }
        for (u32 s = a + lane; s < b; s += 32) {
            const double* d = dphi + 3 * (usize)s;
            double* t = slot_force + 3 * (usize)pos[s];
            for (int r = 0; r < 3; r++)
                t[r] = pk[3 * r] * d[0] + pk[3 * r + 1] * d[1] + pk[3 * r + 2] * d[2];
        }
        if (lane == 0) point_j[p] = j;
    }
    // The block's smallest (J, point) from its warps' lane 0 (forces.rs min_by_j: the lower
    // point among equal J, a NaN J never wins).
    if (lane == 0) {
        bool cand = active && j < INF;
        sj[warp] = cand ? j : INF;
        sp[warp] = cand ? p : 0xffffffffu;
    }
    __syncthreads();
    if (threadIdx.x == 0) {
        double jm = INF;
        u32 pm = 0xffffffffu;
        for (u32 w = 0; w < WARPS; w++) {
            if (sj[w] < jm || (sj[w] == jm && sp[w] < pm)) {
                jm = sj[w];
                pm = sp[w];
            }
        }
        blk_j[blockIdx.x] = jm;
        blk_p[blockIdx.x] = pm;
    }
}

// forces.rs chunk buffers: entry e (a force chunk's entry for one node) sums its slot forces
// from zero in the order the CPU chunk added them. The point kernels store each slot's force at
// its place in that order (`pos`), so an entry's forces lie side by side.
extern "C" __global__ void entry_sums(u32 ne, const u32* con_off, const double* slot_force,
                                      double* entry_force) {
    u32 e = blockIdx.x * blockDim.x + threadIdx.x;
    if (e >= ne) return;
    double t0 = 0.0, t1 = 0.0, t2 = 0.0;
    for (u32 k = con_off[e]; k < con_off[e + 1]; k++) {
        const double* s = slot_force + 3 * (usize)k;
        t0 += s[0];
        t1 += s[1];
        t2 += s[2];
    }
    entry_force[3 * (usize)e] = t0;
    entry_force[3 * (usize)e + 1] = t1;
    entry_force[3 * (usize)e + 2] = t2;
}

// forces.rs node_forces: node i sums its entries (one per force chunk that reaches it, in chunk
// order) from zero.
__device__ __forceinline__ void node_force(u32 i, const u32* ent_off, const double* entry_force,
                                           double* o) {
    o[0] = 0.0; o[1] = 0.0; o[2] = 0.0;
    for (u32 e = ent_off[i]; e < ent_off[i + 1]; e++) {
        const double* t = entry_force + 3 * (usize)e;
        o[0] += t[0];
        o[1] += t[1];
        o[2] += t[2];
    }
}

extern "C" __global__ void node_forces(u32 n, const u32* ent_off, const double* entry_force,
                                       double* f) {
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    node_force(i, ent_off, entry_force, f + 3 * (usize)i);
}

// predict.rs Predictor::update: the nodal force (unless `gathered`), the net force f - f_ext
// (where `has_ext`), u(n+1) = -(A / m) f + B u(n) + C u(n-1) on the free components (mask
// bits 0-2 set where constrained), and per block the largest change and the largest
// displacement over the nodes that are not late (mask bit 3: corrections move them after the
// update, and the host measures them then).
extern "C" __global__ void update(u32 n, u32 gathered, const u32* ent_off,
                                  const double* entry_force, double* f,
                                  u32 has_ext, const double* f_ext, const double* mass,
                                  const u32* mask, double ca, double cb, double cc,
                                  const double* u, const double* u_prev, double* u_next,
                                  double* blk_du, double* blk_u) {
    __shared__ double sdu[BLOCK];
    __shared__ double su[BLOCK];
    u32 i = blockIdx.x * blockDim.x + threadIdx.x;
    double mdu = 0.0, mu_ = 0.0;
    if (i < n) {
        double* fi = f + 3 * (usize)i;
        if (!gathered) node_force(i, ent_off, entry_force, fi);
        double inv_m = ca / mass[i];
        u32 mk = mask[i];
        double* un = u_next + 3 * (usize)i;
        const double* ui = u + 3 * (usize)i;
        const double* up = u_prev + 3 * (usize)i;
        const double* fe = f_ext + 3 * (usize)i;
        for (int k = 0; k < 3; k++) {
            if (!((mk >> k) & 1u)) {
                double fk = has_ext ? fi[k] - fe[k] : fi[k];
                double v = -inv_m * fk + cb * ui[k] + cc * up[k];
                un[k] = v;
                mdu = nan_max(mdu, fabs(v - ui[k]));
            }
        }
        if ((mk >> 3) & 1u) {
            mdu = 0.0;
        } else {
            mu_ = nan_max(fabs(un[0]), nan_max(fabs(un[1]), fabs(un[2])));
        }
    }
    sdu[threadIdx.x] = mdu;
    su[threadIdx.x] = mu_;
    __syncthreads();
    block_max2(sdu, su);
    if (threadIdx.x == 0) {
        blk_du[blockIdx.x] = sdu[0];
        blk_u[blockIdx.x] = su[0];
    }
}

// The prescribed DOFs: bc Constraints::prescribe, u(n+1) = amplitude x the value of the DOF's
// load curve at this step (the distinct curves' values c0..c3, then `more`, made on the host);
// and with `kind` < 3 energy.rs dof_work, each DOF's work over the step,
// (f + inertia) (u(n+1) - u(n-1)) / 2, into out[4 + k] (the host sums them in DOF order).
// kind: 0 relaxation (no inertia), 1 dynamic with dt = dt_prev, 2 dynamic with a changed
// step, 3 no terms.
extern "C" __global__ void dofs(u32 n, const u32* dof, const double* amp, const u32* curve,
                                double c0, double c1, double c2, double c3,
                                const double* more, const double* mass, const double* f,
                                double* u_next, const double* u, const double* u_prev,
                                u32 kind, double dt, double dt_prev, double* out) {
    u32 k = blockIdx.x * blockDim.x + threadIdx.x;
    if (k >= n) return;
    u32 d = dof[k];
    u32 ci = curve[k];
    double cv = ci == 0 ? c0 : ci == 1 ? c1 : ci == 2 ? c2 : ci == 3 ? c3 : more[ci - 4];
    double un = amp[k] * cv;
    u_next[d] = un;
    if (kind == 3) return;
    double m = mass[d / 3];
    double uc = u[d], up = u_prev[d];
    double inertia = 0.0;
    if (kind == 1) {
        inertia = m * (un - 2.0 * uc + up) / (dt * dt);
    } else if (kind == 2) {
        double vn = (un - uc) / dt, vp = (uc - up) / dt_prev;
        inertia = m * (vn - vp) / (0.5 * (dt + dt_prev));
    }
    out[4 + (usize)k] = (f[d] + inertia) * 0.5 * (un - up);
}

// The nodes of a window (ascending ids): their u(n+1), u(n), u(n-1) and f packed for the host.
extern "C" __global__ void window_gather(u32 nw, const u32* w, const double* u_next,
                                         const double* u, const double* u_prev,
                                         const double* f, double* out) {
    u32 k = blockIdx.x * blockDim.x + threadIdx.x;
    if (k >= nw) return;
    usize i = 3 * (usize)w[k];
    usize o = 3 * (usize)k, s = 3 * (usize)nw;
    for (int c = 0; c < 3; c++) {
        out[o + c] = u_next[i + c];
        out[s + o + c] = u[i + c];
        out[2 * s + o + c] = u_prev[i + c];
        out[3 * s + o + c] = f[i + c];
    }
}

// The host's corrected u(n+1) of a window's nodes back into the field.
extern "C" __global__ void window_scatter(u32 nw, const u32* w, const double* in,
                                          double* u_next) {
    u32 k = blockIdx.x * blockDim.x + threadIdx.x;
    if (k >= nw) return;
    usize i = 3 * (usize)w[k];
    for (int c = 0; c < 3; c++) u_next[i + c] = in[3 * (usize)k + c];
}

// The block partials of point_forces and update reduced by one block: out = [min J, its
// point (as a double), largest change, largest displacement].
// With `ndof`, the largest displacement also covers the prescribed DOFs' u(n+1) (attempt.rs
// advance).
extern "C" __global__ void finish_reduce(u32 nj, const double* blk_j, const u32* blk_p,
                                         u32 nu, const double* blk_du, const double* blk_u,
                                         u32 ndof, const u32* dof, const double* u_next,
                                         double* out) {
    __shared__ double sj[BLOCK];
    __shared__ u32 sp[BLOCK];
    __shared__ double sdu[BLOCK];
    __shared__ double su[BLOCK];
    double jmin = INF;
    u32 pmin = 0xffffffffu;
    double mdu = 0.0, mu_ = 0.0;
    for (u32 k = threadIdx.x; k < nj; k += BLOCK) {
        double jb = blk_j[k];
        u32 pb = blk_p[k];
        if (jb < jmin || (jb == jmin && pb < pmin)) {
            jmin = jb;
            pmin = pb;
        }
    }
    for (u32 k = threadIdx.x; k < nu; k += BLOCK) {
        mdu = nan_max(mdu, blk_du[k]);
        mu_ = nan_max(mu_, blk_u[k]);
    }
    for (u32 k = threadIdx.x; k < ndof; k += BLOCK) mu_ = nan_max(mu_, fabs(u_next[dof[k]]));
    sj[threadIdx.x] = jmin;
    sp[threadIdx.x] = pmin;
    sdu[threadIdx.x] = mdu;
    su[threadIdx.x] = mu_;
    __syncthreads();
    block_min_j(sj, sp);
    block_max2(sdu, su);
    if (threadIdx.x == 0) {
        out[0] = sj[0];
        out[1] = (double)sp[0];
        out[2] = sdu[0];
        out[3] = su[0];
    }
}
