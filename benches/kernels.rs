//! Kernel benchmarks (issue 7): internal-force evaluation per quadrature point and step for
//! each point kind, and preprocessing per point. One thread, so the figures are per core.
//!
//!     cargo bench --bench kernels            (all)
//!     cargo bench --bench kernels -- mls     (a filter)
//!
//! Criterion reports time per evaluation of all the points of a model; with the throughput set
//! to the point count it also reports points per second, whose inverse is the ns per
//! point-step listed in benches/README.md.

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use nalgebra::Vector3;

use hytled::quadrature::{NodeSlots, PointKind, QuadraturePoints};
use hytled::scene;
use hytled::simulation::{self, Prepared};
use hytled::solver::Forces;

const CYLINDER: &str = "cases/cylinder-compression.toml";

fn prepare(sets: &[&str]) -> Prepared {
    let o: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let sc = scene::load(Path::new(CYLINDER), &o).expect("cylinder scene");
    simulation::prepare(&sc).expect("prepare")
}

/// A smooth displacement field of a few per cent strain, so every point sees a non-trivial F.
fn field(nodes: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    nodes
        .iter()
        .map(|x| {
            Vector3::new(
                0.02 * x.z + 0.01 * x.y,
                -0.01 * x.x,
                -0.05 * x.z + 0.01 * x.x * x.x,
            )
        })
        .collect()
}

/// The points of `qp` that pass `keep` (mean-dilatation groups kept whole).
fn subset(qp: &QuadraturePoints, keep: impl Fn(PointKind) -> bool) -> QuadraturePoints {
    let mut out = QuadraturePoints::default();
    out.offsets.push(0);
    let mut p = 0;
    while p < qp.len() {
        let k = qp.kinds[p];
        if !keep(k) {
            p += 1;
            continue;
        }
        if let PointKind::MeanDilatation(g) = k {
            let [a, b] = qp.groups[g as usize];
            let pts: Vec<_> = (a as usize..b as usize)
                .map(|q| {
                    let r = qp.slots(q);
                    let ids: Vec<usize> = qp.nodes[r.clone()].iter().map(|&n| n as usize).collect();
                    (ids, qp.dphi[r].to_vec(), qp.weights[q])
                })
                .collect();
            out.push_group(&pts);
            p = b as usize;
        } else {
            let r = qp.slots(p);
            let ids: Vec<usize> = qp.nodes[r.clone()].iter().map(|&n| n as usize).collect();
            out.push(&ids, &qp.dphi[r], qp.weights[p], k);
            p += 1;
        }
    }
    out
}

fn bench_points(c: &mut Criterion, name: &str, prep: &Prepared, qp: &QuadraturePoints) {
    let n = prep.model.nodes().len();
    let slots = NodeSlots::new(qp, n);
    let mut forces = Forces::new(prep.model.forces().materials[0], qp, &slots, n);
    let u = field(prep.model.nodes());
    let mut out = vec![Vector3::zeros(); n];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut g = c.benchmark_group("force");
    g.throughput(Throughput::Elements(qp.len() as u64));
    let mean_support = qp.nodes.len() as f64 / qp.len().max(1) as f64;
    g.bench_function(
        BenchmarkId::new(
            name,
            format!("{} points, {:.1} nodes each", qp.len(), mean_support),
        ),
        |b| {
            b.iter(|| {
                pool.install(|| forces.compute(qp, &slots, black_box(&u), &mut out));
                black_box(&out);
            })
        },
    );
    g.finish();
}

fn kernels(c: &mut Criterion) {
    let hex = prepare(&["discretization.method=fe", "discretization.element=hex8"]);
    bench_points(c, "hex8+hourglass", &hex, hex.model.points());
    let tet = prepare(&["discretization.method=fe", "discretization.element=tet4"]);
    bench_points(c, "tet4", &tet, tet.model.points());
    let anp = prepare(&[
        "discretization.method=fe",
        "discretization.element=tet4-anp",
    ]);
    bench_points(c, "tet4-anp", &anp, anp.model.points());
    for k in ["8", "12", "16"] {
        let sn = format!("discretization.support_nodes={k}");
        let m = prepare(&[
            "discretization.method=meshless",
            "discretization.integration=grid",
            "discretization.support=nearest",
            &sn,
        ]);
        bench_points(c, &format!("mls-{k}-nodes"), &m, m.model.points());
    }
    let cpl = prepare(&["discretization.method=coupled"]);
    let blended = subset(cpl.model.points(), |k| {
        matches!(k, PointKind::MeanDilatation(_))
    });
    bench_points(c, "blended-transition", &cpl, &blended);
}

fn preprocessing(c: &mut Criterion) {
    let mut g = c.benchmark_group("preprocess");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    for (name, basis) in [("mls", "linear"), ("mmls", "quadratic")] {
        let sets: Vec<String> = vec![
            "discretization.method=meshless".into(),
            format!("discretization.basis={basis}"),
            "discretization.divisions=[4,2,10]".into(),
        ];
        let sc = scene::load(Path::new(CYLINDER), &sets).expect("scene");
        let points = simulation::prepare(&sc)
            .expect("prepare")
            .model
            .points()
            .len();
        g.throughput(Throughput::Elements(points as u64));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        g.bench_function(BenchmarkId::new(name, format!("{points} points")), |b| {
            b.iter(|| pool.install(|| black_box(simulation::prepare(&sc).expect("prepare"))))
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    targets = kernels, preprocessing
}
criterion_main!(benches);
