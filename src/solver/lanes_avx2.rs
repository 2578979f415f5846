//! The slot-force stage of the lane kernel ([`super::forces`]) in AVX2 intrinsics, and the
//! deformation gradient and slot forces of points with any number of support nodes.
//!
//! Left to itself the compiler vectorizes that stage across x, y, z (the order of the scatter
//! into the chunk buffer) instead of across the four points of a block, and spills: perf put
//! about 45 % of the hexahedron kernel's samples there, in scalar and 2-wide code. Here each
//! operation acts on the four points at once, and only the final adds into the buffer go
//! lane by lane.
//!
//! Every value is computed with exactly the operations, in exactly the order, of the portable
//! loop in `Forces::lanes` (no fused multiply-add, the same association), and the adds into the
//! buffer come in the same order, slot by slot and lane by lane: the forces are bitwise those
//! of the SSE2 path (`lane_blocks_match_single_points_and_the_reference_formula`).

use std::arch::x86_64::*;

use nalgebra::{Matrix3, Vector3};

/// Adds the slot forces of a block of four points with N support nodes each into the chunk
/// buffer: for slot k and lane l, o = (P_r0 d_0 + P_r1 d_1) + P_r2 d_2 per row r, plus for
/// hexahedra (HG) the hourglass force (((0 + G_0k q_0) + G_1k q_1) + G_2k q_2) + G_3k q_3.
/// `pk` is the weighted first Piola-Kirchhoff stress (Pa m^3, row-major), `dl` the lanes'
/// dphi/dX (1/m), `gl` and `q` the hourglass vectors and mode amplitudes (N/m, m), lanes
/// innermost; the forces are N.
///
/// # Safety
/// The CPU supports AVX2; `entries` holds 4 N buffer indices (lane-major, `l * N + k`), each
/// below the buffer's length, and the entries belong to the caller alone.
#[target_feature(enable = "avx2")]
#[inline]
#[allow(clippy::needless_range_loop)] // k indexes dl, gl (through kk) and the entries together
pub(super) unsafe fn slot_forces<const N: usize, const HG: bool>(
    pk: &[[f64; 4]; 9],
    dl: &[[[f64; 4]; 3]; N],
    gl: &[[[f64; 4]; 8]; 4],
    q: &[[[f64; 4]; 3]; 4],
    entries: *const u32,
    cf: *mut Vector3<f64>,
) {
    let ld = |a: &[f64; 4]| _mm256_loadu_pd(a.as_ptr());
    let p: [__m256d; 9] = std::array::from_fn(|i| ld(&pk[i]));
    for k in 0..N {
        let d = [ld(&dl[k][0]), ld(&dl[k][1]), ld(&dl[k][2])];
        let mut o: [__m256d; 3] = std::array::from_fn(|r| {
            _mm256_add_pd(
                _mm256_add_pd(
                    _mm256_mul_pd(p[3 * r], d[0]),
                    _mm256_mul_pd(p[3 * r + 1], d[1]),
                ),
                _mm256_mul_pd(p[3 * r + 2], d[2]),
            )
        });
        if HG {
            let kk = k.min(7);
            for (c, oc) in o.iter_mut().enumerate() {
                let mut acc = _mm256_setzero_pd();
                for m in 0..4 {
                    acc = _mm256_add_pd(acc, _mm256_mul_pd(ld(&gl[m][kk]), ld(&q[m][c])));
                }
                *oc = _mm256_add_pd(*oc, acc);
            }
        }
        // (x, y) of lanes 0, 2 and 1, 3 pair up under unpack; z goes lane by lane.
        let even = _mm256_unpacklo_pd(o[0], o[1]);
        let odd = _mm256_unpackhi_pd(o[0], o[1]);
        let xy = [
            _mm256_castpd256_pd128(even),
            _mm256_castpd256_pd128(odd),
            _mm256_extractf128_pd::<1>(even),
            _mm256_extractf128_pd::<1>(odd),
        ];
        let (zlo, zhi) = (
            _mm256_castpd256_pd128(o[2]),
            _mm256_extractf128_pd::<1>(o[2]),
        );
        let z = [
            _mm_cvtsd_f64(zlo),
            _mm_cvtsd_f64(_mm_unpackhi_pd(zlo, zlo)),
            _mm_cvtsd_f64(zhi),
            _mm_cvtsd_f64(_mm_unpackhi_pd(zhi, zhi)),
        ];
        for l in 0..4 {
            // Vector3<f64> is three contiguous f64 (x, y, z).
            let t = cf.add(*entries.add(l * N + k) as usize) as *mut f64;
            _mm_storeu_pd(t, _mm_add_pd(_mm_loadu_pd(t), xy[l]));
            *t.add(2) += z[l];
        }
    }
}

/// Rows of F = I + sum_k u_k (x) dphi_k of one point with any number of support nodes: the
/// three rows as 4-wide vectors (the fourth lane unused), so each support node costs 3
/// multiplies and 3 adds instead of 9 and 9. The same products and sums, in the same order, as
/// the portable `f += u_k * dphi_k^T` from the identity.
///
/// # Safety
/// The CPU supports AVX2; every id is below the length of the array `u` points at, and
/// `ids.len() == dphi.len()`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) unsafe fn any_gradient(
    ids: &[u32],
    dphi: &[Vector3<f64>],
    u: *const Vector3<f64>,
) -> Matrix3<f64> {
    let mut rows = [
        _mm256_set_pd(0.0, 0.0, 0.0, 1.0),
        _mm256_set_pd(0.0, 0.0, 1.0, 0.0),
        _mm256_set_pd(0.0, 1.0, 0.0, 0.0),
    ];
    for (&id, d) in ids.iter().zip(dphi) {
        let dv = load3(d.as_ptr());
        let uk = (*u.add(id as usize)).as_ptr();
        for (r, row) in rows.iter_mut().enumerate() {
            *row = _mm256_add_pd(*row, _mm256_mul_pd(_mm256_broadcast_sd(&*uk.add(r)), dv));
        }
    }
    let mut a = [[0.0f64; 4]; 3];
    for (out, row) in a.iter_mut().zip(rows) {
        _mm256_storeu_pd(out.as_mut_ptr(), row);
    }
    Matrix3::new(
        a[0][0], a[0][1], a[0][2], a[1][0], a[1][1], a[1][2], a[2][0], a[2][1], a[2][2],
    )
}

/// Adds the slot forces `(P_:0 d_x + P_:1 d_y) + P_:2 d_z` (N; `pk` the weighted first
/// Piola-Kirchhoff stress, Pa m^3, `dphi` 1/m) of one point into its chunk buffer entries, with
/// the columns of P as 4-wide vectors: the operations and order of the portable loop in
/// `Forces::stress_to_chunk`.
///
/// # Safety
/// The CPU supports AVX2; every entry is below the buffer's length and belongs to the caller
/// alone; `entries.len() == dphi.len()`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) unsafe fn any_forces(
    pk: &Matrix3<f64>,
    dphi: &[Vector3<f64>],
    entries: &[u32],
    cf: *mut Vector3<f64>,
) {
    // nalgebra stores matrices column by column.
    let p = pk.as_ptr();
    let cols = [load3(p), load3(p.add(3)), load3(p.add(6))];
    for (d, &e) in dphi.iter().zip(entries) {
        let o = _mm256_add_pd(
            _mm256_add_pd(
                _mm256_mul_pd(cols[0], _mm256_set1_pd(d.x)),
                _mm256_mul_pd(cols[1], _mm256_set1_pd(d.y)),
            ),
            _mm256_mul_pd(cols[2], _mm256_set1_pd(d.z)),
        );
        let t = cf.add(e as usize) as *mut f64;
        _mm_storeu_pd(t, _mm_add_pd(_mm_loadu_pd(t), _mm256_castpd256_pd128(o)));
        *t.add(2) += _mm_cvtsd_f64(_mm256_extractf128_pd::<1>(o));
    }
}

/// The three f64 at `p` in the low lanes of a vector, the fourth lane zero: never reads past
/// them (the last Vector3 may end its array).
///
/// # Safety
/// The CPU supports AVX2 and `p..p + 3` are readable.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn load3(p: *const f64) -> __m256d {
    _mm256_insertf128_pd::<1>(
        _mm256_castpd128_pd256(_mm_loadu_pd(p)),
        _mm_load_sd(p.add(2)),
    )
}
