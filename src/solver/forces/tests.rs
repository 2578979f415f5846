use super::*;
use crate::fe::{element_points, ElementKind};
use crate::geometry::shapes::{box_hex, box_tet};
use crate::material::{NeoHookean, Solid};
use nalgebra::Matrix3;

/// A distorted displacement field with strains of several per cent.
fn field(nodes: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    nodes
        .iter()
        .map(|x| {
            Vector3::new(
                0.08 * x.z + 0.05 * (7.0 * x.y).sin(),
                -0.06 * x.x + 0.03 * x.z * x.z,
                -0.1 * x.z + 0.04 * (5.0 * x.x).cos() * x.y,
            )
        })
        .collect()
}

/// Nodal forces and J's with lane blocks (AVX2 where present), without AVX2, and point by
/// point.
fn three_ways(
    qp: &QuadraturePoints,
    nodes: &[Vector3<f64>],
    u: &[Vector3<f64>],
) -> Vec<(Vec<Vector3<f64>>, Vec<f64>)> {
    let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    three_ways_with(mat, qp, nodes, u)
}

/// [`three_ways`] for any material.
fn three_ways_with<M: Material>(
    mat: M,
    qp: &QuadraturePoints,
    nodes: &[Vector3<f64>],
    u: &[Vector3<f64>],
) -> Vec<(Vec<Vector3<f64>>, Vec<f64>)> {
    let slots = NodeSlots::new(qp, nodes.len());
    let mut out = Vec::new();
    for (blocks, simd) in [(true, simd_available()), (true, false), (false, false)] {
        let mut f = Forces::new(mat.clone(), qp, &slots, nodes.len());
        let plan = plan(qp, &[], nodes.len(), blocks);
        (f.plan.items, f.plan.lane_data, f.plan.chunks) = (plan.items, plan.lane_data, plan.chunks);
        f.simd = simd;
        let mut nodal = vec![Vector3::zeros(); nodes.len()];
        f.compute(qp, &slots, u, &mut nodal);
        out.push((nodal, f.point_j.clone()));
    }
    out
}

/// The lane kernel against the textbook formula f_k = w F S dphi_k (+ G G^T u for the
/// hexahedra), with S from `pk2_stress` and F from nalgebra; blocks with and without AVX2
/// against each other bitwise, and single points against blocks: the same J's, and nodal
/// forces that differ by the summation order only.
#[test]
#[allow(clippy::needless_range_loop)] // p indexes the points' J, slots and kinds together
fn lane_blocks_match_single_points_and_the_reference_formula() {
    let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let hex = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
    let tet = box_tet(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [3, 3, 1]).unwrap();
    for (mesh, kind, plain) in [
        (hex.clone(), ElementKind::Hex8, false),
        (hex, ElementKind::Hex8, true),
        (tet.clone(), ElementKind::Tet4, false),
        (tet, ElementKind::Tet4Anp, false),
    ] {
        let mut qp = element_points(&mesh, kind, 0.05, 1e5).unwrap();
        if plain {
            // Standard 8-node points (the nearest-8 MLS path).
            qp.kinds.iter_mut().for_each(|k| *k = PointKind::Standard);
        }
        let u = field(&mesh.nodes);
        let runs = three_ways(&qp, &mesh.nodes, &u);
        assert!(
            runs[1].0 == runs[0].0 && runs[1].1 == runs[0].1,
            "{kind:?}: AVX2 and SSE2 differ"
        );
        assert!(
            runs[2].1 == runs[0].1,
            "{kind:?}: J of single points differ"
        );
        let (nodal, pj) = &runs[0];
        let mut want_nodal = vec![Vector3::zeros(); mesh.nodes.len()];
        let mut scale = 0.0f64;
        // ANP (Bonet & Burton 1998): nodal J = volume-weighted mean of the points' J, nodal
        // pressure kappa (J_n - 1), element stress = the isochoric neo-Hookean stress of its
        // own F plus J p_mean F^-T, p_mean the mean of its nodes' pressures.
        let (mut vj, mut vw) = (vec![0.0; mesh.nodes.len()], vec![0.0; mesh.nodes.len()]);
        for p in 0..qp.len() {
            let j = deformation_gradient(&qp, p, &u).determinant();
            for s in qp.slots(p) {
                vj[qp.nodes[s] as usize] += qp.weights[p] * j;
                vw[qp.nodes[s] as usize] += qp.weights[p];
            }
        }
        for p in 0..qp.len() {
            let f = deformation_gradient(&qp, p, &u);
            let j = f.determinant();
            assert!((pj[p] - j).abs() < 1e-14, "J at {p}");
            let pk: Matrix3<f64> = if qp.kinds[p] == PointKind::Anp {
                let r = qp.slots(p);
                let p_mean = r
                    .clone()
                    .map(|s| {
                        mat.kappa * (vj[qp.nodes[s] as usize] / vw[qp.nodes[s] as usize] - 1.0)
                    })
                    .sum::<f64>()
                    / r.len() as f64;
                let f_inv_t = f.try_inverse().unwrap().transpose();
                let iso = (f - f_inv_t * ((f.transpose() * f).trace() / 3.0))
                    * (mat.mu * j.powf(-2.0 / 3.0));
                (iso + f_inv_t * (j * p_mean)) * qp.weights[p]
            } else {
                f * mat.pk2_stress(&f, j) * qp.weights[p]
            };
            let r = qp.slots(p);
            let mut want: Vec<Vector3<f64>> = qp.dphi[r.clone()].iter().map(|d| pk * d).collect();
            if let PointKind::Hourglass(h) = qp.kinds[p] {
                let g = qp.hourglass[h as usize];
                let hg = g * g.transpose();
                for a in 0..8 {
                    for b in 0..8 {
                        want[a] += u[qp.nodes[r.start + b] as usize] * hg[(a, b)];
                    }
                }
            }
            for (k, w) in want.iter().enumerate() {
                want_nodal[qp.nodes[r.start + k] as usize] += w;
                scale = scale.max(w.norm());
            }
        }
        let worst = nodal
            .iter()
            .zip(&want_nodal)
            .map(|(g, w)| (g - w).norm() / scale)
            .fold(0.0, f64::max);
        // Summation order only: a few ulps of the largest slot force.
        let order = nodal
            .iter()
            .zip(&runs[2].0)
            .map(|(g, s)| (g - s).norm() / scale)
            .fold(0.0, f64::max);
        assert!(
            order < 1e-14,
            "{kind:?}: singles differ from blocks by {order:e}"
        );
        assert!(
            worst < 1e-12,
            "{kind:?}: relative force difference {worst:e}"
        );
        // 45 hexahedra and 54 tetrahedra: full blocks and single points both run (ANP
        // blocks included).
        assert!(!qp.len().is_multiple_of(LANES) && qp.len() > LANES);
    }
}

/// 40 points with 3 to 31 support nodes on the nodes of `mesh` (4 and 8 among them, so
/// runs of single-evaluated points are cut by lane-mode points).
fn any_size_points(n: usize) -> QuadraturePoints {
    any_size_points_of(n, 40)
}

/// `count` points made as [`any_size_points`] makes its 40.
fn any_size_points_of(n: usize, count: usize) -> QuadraturePoints {
    let mut qp = QuadraturePoints::with_capacity(count, 20 * count);
    for p in 0..count {
        let size = 3 + (p * 11) % 29;
        let ids: Vec<usize> = (0..size).map(|k| (p * 17 + k * 5) % n).collect();
        let d: Vec<Vector3<f64>> = (0..size)
            .map(|k| {
                let s = (p * 31 + k * 7) as f64;
                Vector3::new((0.7 * s).sin(), (1.3 * s).cos(), (0.37 * s).sin() - 0.2) * 20.0
            })
            .collect();
        qp.push(&ids, &d, 1e-6 * (1.0 + (p % 3) as f64), PointKind::Standard);
    }
    qp
}

/// Nodal forces by the textbook formula f_k = w F S dphi_k, S from `pk2_stress`, and the
/// largest slot force; asserts the kernel's J's.
fn reference_forces<M: Material>(
    mat: &M,
    qp: &QuadraturePoints,
    u: &[Vector3<f64>],
    j_kernel: &[f64],
) -> (Vec<Vector3<f64>>, f64) {
    let mut want = vec![Vector3::zeros(); u.len()];
    let mut scale = 0.0f64;
    assert_eq!(j_kernel.len(), qp.len());
    for (p, &jk) in j_kernel.iter().enumerate() {
        let f = deformation_gradient(qp, p, u);
        let j = f.determinant();
        assert!(j > 0.5, "test field inverts point {p}: J = {j}");
        assert!((jk - j).abs() < 1e-14, "J at {p}");
        let pk: Matrix3<f64> = f * mat.pk2_stress(&f, j) * qp.weights[p];
        for s in qp.slots(p) {
            let fk = pk * qp.dphi[s];
            want[qp.nodes[s] as usize] += fk;
            scale = scale.max(fk.norm());
        }
    }
    (want, scale)
}

fn worst_relative(got: &[Vector3<f64>], want: &[Vector3<f64>], scale: f64) -> f64 {
    got.iter()
        .zip(want)
        .map(|(g, w)| (g - w).norm() / scale)
        .fold(0.0, f64::max)
}

/// Points with 3 to 31 support nodes (the MLS and transition points' path), with AVX2
/// against without bitwise, and against the textbook formula f_k = w F S dphi_k.
#[test]
fn any_size_points_match_without_avx2_and_the_reference_formula() {
    let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
    let qp = any_size_points(mesh.nodes.len());
    let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
    let runs = three_ways(&qp, &mesh.nodes, &u);
    assert!(
        runs[1].0 == runs[0].0 && runs[1].1 == runs[0].1,
        "any-size points: AVX2 and SSE2 differ"
    );
    let (want, scale) = reference_forces(&mat, &qp, &u, &runs[0].1);
    let worst = worst_relative(&runs[0].0, &want, scale);
    assert!(worst < 1e-12, "relative force difference {worst:e}");
}

/// The any-size points in consecutive mean-dilatation groups of 2 to 6 points.
fn grouped_points(n: usize) -> QuadraturePoints {
    grouped_points_of(n, 40)
}

/// `count` any-size points in groups as [`grouped_points`] makes them.
fn grouped_points_of(n: usize, count: usize) -> QuadraturePoints {
    let qp = any_size_points_of(n, count);
    let mut out = QuadraturePoints::with_capacity(qp.len(), qp.nodes.len());
    let (mut p, mut size) = (0, 2);
    while p < qp.len() {
        let end = (p + size).min(qp.len());
        let pts: Vec<_> = (p..end)
            .map(|q| {
                let r = qp.slots(q);
                let ids = qp.nodes[r.clone()].iter().map(|&x| x as usize).collect();
                (ids, qp.dphi[r].to_vec(), qp.weights[q])
            })
            .collect();
        out.push_group(&pts);
        p = end;
        size = 2 + size % 5;
    }
    out
}

/// Mean-dilatation groups against Nagtegaal's closed form for the neo-Hookean solid,
/// P_p = mu J_p^(-2/3) (F_p - tr(C_p) / 3 F_p^-T) + J_p kappa (J_mean - 1) F_p^-T: the same
/// forces to 1e-12, bitwise with and without AVX2, and every point's own J.
#[test]
fn mean_dilatation_is_nagtegaal_for_the_neo_hookean_solid() {
    let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
    let qp = grouped_points(mesh.nodes.len());
    let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
    let runs = three_ways(&qp, &mesh.nodes, &u);
    for (k, r) in runs.iter().enumerate().skip(1) {
        assert!(r == &runs[0], "run {k} differs from the AVX2 run");
    }
    let (want, scale, spread) = nagtegaal_forces(&mat, &qp, &u, &runs[0].1);
    // The field must make the points of a group differ, or any J_mean scaling would pass.
    assert!(spread > 0.05, "J within a group varies by {spread:e} only");
    let worst = worst_relative(&runs[0].0, &want, scale);
    assert!(worst < 1e-12, "relative force difference {worst:e}");
}

/// Nodal forces of mean-dilatation groups by Nagtegaal's closed form (see the test above),
/// the largest slot force and the largest |J / J_mean - 1| in a group; asserts the
/// kernel's J's.
fn nagtegaal_forces(
    mat: &NeoHookean,
    qp: &QuadraturePoints,
    u: &[Vector3<f64>],
    j_kernel: &[f64],
) -> (Vec<Vector3<f64>>, f64, f64) {
    let mut want = vec![Vector3::zeros(); u.len()];
    let (mut scale, mut spread) = (0.0f64, 0.0f64);
    for &[a, b] in &qp.groups {
        let (a, b) = (a as usize, b as usize);
        let fs: Vec<Matrix3<f64>> = (a..b).map(|p| deformation_gradient(qp, p, u)).collect();
        let w: f64 = qp.weights[a..b].iter().sum();
        let j_mean = (a..b)
            .map(|p| qp.weights[p] * fs[p - a].determinant())
            .sum::<f64>()
            / w;
        for p in a..b {
            let f = fs[p - a];
            let j = f.determinant();
            assert_eq!(j_kernel[p], j, "the kernel's J of point {p}");
            spread = spread.max((j / j_mean - 1.0).abs());
            let f_inv_t = f.try_inverse().unwrap().transpose();
            let iso =
                (f - f_inv_t * ((f.transpose() * f).trace() / 3.0)) * (mat.mu * j.powf(-2.0 / 3.0));
            let pk = (iso + f_inv_t * (j * mat.kappa * (j_mean - 1.0))) * qp.weights[p];
            for s in qp.slots(p) {
                let fk = pk * qp.dphi[s];
                want[qp.nodes[s] as usize] += fk;
                scale = scale.max(fk.norm());
            }
        }
    }
    (want, scale, spread)
}

/// Groups over many chunks (600 points, 10,183 slots: 10 chunks): no chunk cuts a group, as
/// the chunk holding a group evaluates its stresses just before its forces
/// (`group_point`); the stresses are bitwise those of the separate pass
/// (`group_stresses`, which the energies and output fields use) and, evaluated four points
/// at a time, bitwise those of one point at a time; the forces are the same for any
/// thread count, and Nagtegaal's to 1e-12 (as in the test above).
#[test]
fn no_chunk_cuts_a_mean_dilatation_group() {
    let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
    let qp = grouped_points_of(mesh.nodes.len(), 600);
    let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
    let slots = NodeSlots::new(&qp, mesh.nodes.len());
    let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let mut f = Forces::new(mat, &qp, &slots, mesh.nodes.len());
    assert!(f.plan.chunks.len() > 4, "{} chunks", f.plan.chunks.len());
    let mut cut_somewhere = false;
    for ch in &f.plan.chunks {
        let items = &f.plan.items[ch.items[0] as usize..ch.items[1] as usize];
        let (a, b) = (
            items[0].first,
            items.last().map(|i| i.first + i.count as u32),
        );
        let b = b.unwrap();
        for &[g0, g1] in &qp.groups {
            assert!(
                g1 <= a || g0 >= b || (g0 >= a && g1 <= b),
                "group {g0}..{g1} cut"
            );
        }
        cut_somewhere |= b < qp.len() as u32;
    }
    assert!(cut_somewhere);
    let run = |threads: usize, f: &mut Forces<NeoHookean>| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut nodal = vec![Vector3::zeros(); u.len()];
        pool.install(|| f.compute(&qp, &slots, &u, &mut nodal));
        nodal
    };
    let one = run(1, &mut f);
    let (pk, j) = (f.groups.pk.clone(), f.groups.j.clone());
    assert_eq!(run(3, &mut f), one);
    f.group_stresses(&qp, &u);
    assert!(f.groups.pk == pk && f.groups.j == j);
    // The stresses, evaluated four points at a time, bitwise those of one point at a
    // time (as the GPU kernel takes them).
    for (g, &[a, b]) in qp.groups.iter().enumerate() {
        let (a, b, i0) = (a as usize, b as usize, f.groups.first[g] as usize);
        let fs: Vec<_> = (a..b).map(|p| deformation_gradient(&qp, p, &u)).collect();
        let w: f64 = (a..b).map(|p| qp.weights[p]).sum();
        let jm = (a..b)
            .map(|p| qp.weights[p] * fs[p - a].determinant())
            .sum::<f64>()
            / w;
        let bar: Vec<_> = fs.iter().map(|f| f * cbrt(jm / f.determinant())).collect();
        let pb: Vec<_> = bar.iter().map(|fb| mat.first_pk_stress(fb, jm)).collect();
        let tau: Vec<f64> = (0..b - a).map(|k| pb[k].dot(&bar[k]) / 3.0).collect();
        let t = (a..b).map(|p| qp.weights[p] * tau[p - a]).sum::<f64>() / w;
        for (k, p) in (a..b).enumerate() {
            let (jp, alpha) = (fs[k].determinant(), cbrt(jm / fs[k].determinant()));
            let cof = crate::geometry::cofactor(&fs[k]);
            let want = (pb[k] * alpha + cof * (t / jm - tau[k] / jp)) * qp.weights[p];
            assert_eq!(f.groups.pk[i0 + k], want, "point {p}");
        }
    }
    let runs = three_ways(&qp, &mesh.nodes, &u);
    assert_eq!(runs[0].0, one);
    for (k, r) in runs.iter().enumerate().skip(1) {
        assert!(r == &runs[0], "run {k} differs from the AVX2 run");
    }
    let (want, scale, spread) = nagtegaal_forces(&mat, &qp, &u, &runs[0].1);
    assert!(spread > 0.05, "{spread:e}");
    let worst = worst_relative(&one, &want, scale);
    assert!(worst < 1e-12, "relative force difference {worst:e}");
}

/// Internal forces are the gradient of the strain energy the run reports (the energy
/// balance depends on it): central differences of `strain_energy` against `compute` for
/// one-point hexahedra with hourglass control, points of any support size, mean-dilatation
/// groups (neo-Hookean and Ogden) and ANP tetrahedra (one material, and two materials with
/// different bulk moduli meeting at shared nodes). The F-bar stress of the modified points,
/// w P(F_bar) dphi with F_bar = (J_avg / J)^(1/3) F (groups before `group_stresses`, ANP as
/// Joldes et al. 2009 and NiftySim), misses the gradient by far more than the tolerance.
#[test]
fn forces_are_the_gradient_of_the_strain_energy() {
    fn check<M: Material>(
        name: &str,
        materials: Vec<M>,
        point_material: Vec<u16>,
        qp: &QuadraturePoints,
        nodes: &[Vector3<f64>],
        u: &[Vector3<f64>],
    ) -> f64 {
        let slots = NodeSlots::new(qp, nodes.len());
        let mut f = Forces::with_materials(materials, point_material, qp, &slots, nodes.len());
        let mut got = vec![Vector3::zeros(); nodes.len()];
        f.compute(qp, &slots, u, &mut got);
        let h = 1e-7;
        let mut grad = vec![Vector3::zeros(); nodes.len()];
        let mut v = u.to_vec();
        for n in 0..nodes.len() {
            for c in 0..3 {
                v[n][c] = u[n][c] + h;
                let ep = f.strain_energy(qp, &slots, &v);
                v[n][c] = u[n][c] - h;
                let em = f.strain_energy(qp, &slots, &v);
                v[n][c] = u[n][c];
                grad[n][c] = (ep - em) / (2.0 * h);
            }
        }
        let scale = got.iter().map(|g| g.norm()).fold(0.0, f64::max);
        assert!(scale > 0.0);
        let worst = worst_relative(&got, &grad, scale);
        println!("{name}: |F_int - dE/du| / max |F_int| = {worst:e}");
        assert!(
            worst < 1e-6,
            "{name}: forces miss the energy gradient by {worst:e}"
        );
        // F-bar alone. `strain_energy` left the nodal and group J's of u (its last call).
        f.averages(qp, u);
        let mut fbar = vec![Vector3::zeros(); nodes.len()];
        for p in 0..qp.len() {
            let plain = deformation_gradient(qp, p, u);
            let j = plain.determinant();
            let j_avg = match qp.kinds[p] {
                PointKind::Anp => {
                    let r = qp.slots(p);
                    let n = r.len() as f64;
                    r.map(|s| f.pressure.node_j[f.pressure_node(qp, s)])
                        .sum::<f64>()
                        / n
                }
                PointKind::MeanDilatation(g) => f.groups.j[g as usize],
                _ => j,
            };
            let fb = plain * (j_avg / j).cbrt();
            let pk = f.material_at(p).first_pk_stress(&fb, j_avg) * qp.weights[p];
            for s in qp.slots(p) {
                fbar[qp.nodes[s] as usize] += pk * qp.dphi[s];
            }
        }
        worst_relative(&fbar, &grad, scale)
    }
    let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
    let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
    let nh = NeoHookean::from_young_poisson(3000.0, 0.45, 1000.0);
    let ogden = crate::material::Ogden {
        mu: 1006.7,
        alpha: -4.7,
        kappa: 1006.7 * 20.0,
        density: 1040.0,
    };
    let hex = element_points(&mesh, ElementKind::Hex8, 0.05, 1e5).unwrap();
    check(
        "hex8 with hourglass",
        vec![nh],
        vec![],
        &hex,
        &mesh.nodes,
        &u,
    );
    let any = any_size_points(mesh.nodes.len());
    check("any-size points", vec![nh], vec![], &any, &mesh.nodes, &u);
    let groups = grouped_points(mesh.nodes.len());
    let tet = box_tet(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
    let tu = field(&tet.nodes);
    let anp = element_points(&tet, ElementKind::Tet4Anp, 0.05, 1e5).unwrap();
    // Two tissues split at x = 0.05 m: neo-Hookean (nu = 0.45) and Ogden (kappa = 20 mu).
    let two: Vec<u16> = (0..anp.len())
        .map(|p| {
            let r = anp.slots(p);
            let x = r.map(|s| tet.nodes[anp.nodes[s] as usize].x).sum::<f64>() / 4.0;
            u16::from(x > 0.05)
        })
        .collect();
    let solids = vec![Solid::from(nh), Solid::Ogden(ogden)];
    for (name, off) in [
        (
            "groups, neo-Hookean",
            check(
                "groups, neo-Hookean",
                vec![nh],
                vec![],
                &groups,
                &mesh.nodes,
                &u,
            ),
        ),
        (
            "groups, Ogden",
            check(
                "groups, Ogden",
                vec![ogden],
                vec![],
                &groups,
                &mesh.nodes,
                &u,
            ),
        ),
        (
            "ANP, neo-Hookean",
            check("ANP, neo-Hookean", vec![nh], vec![], &anp, &tet.nodes, &tu),
        ),
        (
            "ANP, two materials",
            check("ANP, two materials", solids, two, &anp, &tet.nodes, &tu),
        ),
    ] {
        println!("{name}: F-bar stress alone misses the gradient by {off:e}");
        assert!(
            off > 1e-4,
            "{name}: the test field cannot tell F-bar from its gradient ({off:e})"
        );
    }
}

/// Points taken four at a time for the stress (`Mode::Other` blocks) give bitwise the forces and
/// J's of the points taken one by one, with and without AVX2, and match the textbook
/// formula: Ogden and neo-Hookean.
#[test]
fn stress_batches_match_single_points_bitwise() {
    fn check<M: Material>(mat: M) {
        let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.07, 0.05), [5, 3, 3]).unwrap();
        let qp = any_size_points(mesh.nodes.len());
        let u: Vec<Vector3<f64>> = field(&mesh.nodes).iter().map(|v| v * 0.05).collect();
        let p = plan(&qp, &[], mesh.nodes.len(), true);
        let batches = p
            .items
            .iter()
            .filter(|it| it.mode == Mode::Other && it.count as usize == LANES)
            .count();
        assert!(batches >= 3, "only {batches} stress batches in the test");
        let runs = three_ways_with(mat.clone(), &qp, &mesh.nodes, &u);
        for (k, r) in runs.iter().enumerate().skip(1) {
            assert!(
                r.0 == runs[0].0 && r.1 == runs[0].1,
                "run {k} differs from the batched AVX2 run"
            );
        }
        let (want, scale) = reference_forces(&mat, &qp, &u, &runs[0].1);
        let worst = worst_relative(&runs[0].0, &want, scale);
        assert!(worst < 1e-12, "relative force difference {worst:e}");
    }
    check(crate::material::Ogden {
        mu: 1006.7,
        alpha: -4.7,
        kappa: 1006.7 * 100.0,
        density: 1040.0,
    });
    check(NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0));
}
