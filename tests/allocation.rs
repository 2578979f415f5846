//! The time loop allocates nothing per step (issue 7): a counting global allocator sees the
//! same number of allocations for runs of 100 and of 400 steps (same history rows and frames),
//! for every kind of discretization and essential-boundary treatment.
//!
//! One test function only: the counter is global, and tests running beside it would add their
//! allocations.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use hytled::simulation;
use hytled::solver::{self, Mode};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

/// Counts allocations made on the pool's worker threads, where the time loop runs: the caller's
/// own thread allocates a block of rayon's injection queue every 63 jobs it hands the pool
/// (`solver::run` hands it one per run), which is not the loop's doing.
fn count() {
    if rayon::current_thread_index().is_some() {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `solver::run` over `steps` dynamic steps of the scene.
fn allocations(sets: &[&str], steps: usize, mode: Mode) -> usize {
    let mut o: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    o.push("discretization.size=0.025".into());
    let sc = hytled::scene::load(Path::new("cases/cube-compression.toml"), &o).unwrap();
    let mut prep = simulation::prepare(&sc).unwrap();
    let mut s = simulation::settings(&sc, false);
    s.mode = mode;
    // The run's own estimate (the global one allocates its Lanczos vectors once, before the
    // loop: the same count for both lengths).
    let (dt, _) = solver::integrate::critical_step(&mut prep.model, s.step_estimate);
    s.duration = steps as f64 * s.dt_factor * dt * (1.0 - 1e-9);
    s.max_steps = steps;
    s.history_rows = 10;
    s.frames = 2;
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    let out = solver::run(&mut prep.model, &s).unwrap();
    let n = ALLOCATIONS.load(Ordering::SeqCst) - before;
    assert!(out.steps >= steps, "{} of {steps} steps", out.steps);
    n
}

#[test]
fn the_time_loop_does_not_allocate() {
    let cases: [&[&str]; 5] = [
        &["discretization.method=fe", "discretization.element=hex8"],
        &[
            "discretization.method=fe",
            "discretization.element=tet4-anp",
        ],
        &[
            "discretization.method=meshless",
            "discretization.bc_method=ebciem",
        ],
        &[
            "discretization.method=meshless",
            "discretization.bc_method=sebciem",
        ],
        &[
            "discretization.method=coupled",
            "discretization.fe_layers=1",
        ],
    ];
    // A worker's first steal registers it with crossbeam-epoch (rayon's deques), a one-time
    // allocation that lands in whichever run the worker first steals in: with fast kernels a
    // worker can sit out the warm-up and register during the 100- or the 400-step run (seen
    // as 87 against 88 allocations, about one test run in twenty). Register every worker first.
    rayon::broadcast(|_| drop(crossbeam_epoch::pin()));
    for sets in cases {
        // Lazily built pool internals allocate during the first runs; measure after one.
        allocations(sets, 100, Mode::Dynamic);
        let short = allocations(sets, 100, Mode::Dynamic);
        let long = allocations(sets, 400, Mode::Dynamic);
        assert_eq!(
            short, long,
            "{sets:?}: {short} allocations in 100 steps, {long} in 400"
        );
    }
}
