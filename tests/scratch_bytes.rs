//! The memory estimate counts every buffer of the force evaluator (issue 58): a global
//! allocator that tracks live bytes sees exactly what `Forces::scratch_bytes` reports, the sum
//! of its rooms' (plan, nodal pressure, groups, energy) and its own, for discretizations that
//! fill each room. A buffer added to a room but left out of its `bytes` fails here.
//!
//! One test function only: the counter is global, and tests running beside it would add their
//! allocations.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicIsize, Ordering};

use hytled::simulation;
use hytled::solver::Forces;

struct Live;

static LIVE: AtomicIsize = AtomicIsize::new(0);

unsafe impl GlobalAlloc for Live {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LIVE.fetch_add(layout.size() as isize, Ordering::SeqCst);
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size() as isize, Ordering::SeqCst);
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LIVE.fetch_add(new_size as isize - layout.size() as isize, Ordering::SeqCst);
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Live = Live;

#[test]
fn the_memory_estimate_counts_every_buffer() {
    // One worker, warmed up by a first construction: the pool's own queues then hold what
    // they need, and the second construction's live bytes are the evaluator's alone.
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let cases: [&[&str]; 5] = [
        // hex8 with hourglass control: the plan's lane blocks and hourglass data.
        &["discretization.size=0.0125"],
        // tet4-anp: the nodal-pressure room.
        &[
            "discretization.size=0.0125",
            "discretization.element=tet4-anp",
        ],
        // Two materials meeting at ANP nodes: a pressure node per node and material.
        &[
            "discretization.size=0.0125",
            "discretization.element=tet4-anp",
            "regions.hard.select={ box = { min = [0.05, -1.0, -1.0], max = [1.0, 1.0, 1.0] } }",
            "regions.hard.youngs_modulus=6000",
            "references={}",
        ],
        // Meshless MLS: points of other support sizes.
        &["discretization.method=meshless"],
        // Coupled with mean dilatation: the groups room.
        &[
            "discretization.method=coupled",
            "discretization.size=0.0125",
            "discretization.mean_dilatation=true",
        ],
    ];
    for overrides in cases {
        let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        let scene = hytled::scene::load(
            std::path::Path::new(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/cases/cube-compression.toml"
            )),
            &o,
        )
        .unwrap_or_else(|e| panic!("{overrides:?}: {e}"));
        let prep = simulation::prepare(&scene).unwrap();
        let m = &prep.model;
        let n = m.nodes().len();
        let (materials, point_material) = (&m.forces().materials, m.forces().point_materials());
        let (points, slots) = (m.points(), m.slots());
        let build =
            || Forces::with_materials(materials.clone(), point_material.to_vec(), points, slots, n);
        let (measured, reported) = pool.install(|| {
            drop(build());
            let before = LIVE.load(Ordering::SeqCst);
            let f = build();
            let after = LIVE.load(Ordering::SeqCst);
            ((after - before) as usize, f.scratch_bytes())
        });
        println!(
            "{overrides:?}: {} points, allocated {measured} B, reported {reported} B",
            points.len()
        );
        assert_eq!(
            measured, reported,
            "{overrides:?}: the evaluator holds {measured} B and reports {reported} B"
        );
    }
}
