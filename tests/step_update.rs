//! The critical step estimated again at the deformed state during a run
//! (`solver.step_update`): dynamic compressions that the reference step cannot carry complete
//! and agree with a run at a fixed step 2-4x shorter than the shortest update; relaxation at
//! 80 % converges after one restart to the fixed short step's equilibrium; a run whose
//! frequencies do not rise is bitwise the run without updates; shortened runs are bitwise the
//! same for any thread count; a column in uniaxial strain follows the exact spectrum to 95 %
//! and stops with the collapse message at 99.9 %.

mod common;
use common::*;

use hytled::simulation::{run_scene, RunOptions};
use hytled::solver::integrate::{DEFORMATION_ALLOWANCE, UPDATE_ALLOWANCE};

const CYL: &str = "cases/cylinder-compression.toml";

fn run(case: &str, overrides: &[&str]) -> hytled::Result<hytled::report::Summary> {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    run_scene(
        &hytled::scene::load(&path(case), &o)?,
        &RunOptions::default(),
    )
}

/// The O-grid cylinder at 4 x 2 x 8 cells compressed by 60 % over 3 s (dynamic, smooth).
fn compression(extra: &[&str]) -> Vec<String> {
    let mut o: Vec<String> = [
        "discretization.divisions=[4,2,8]",
        "references={}",
        "boundaries.top.displacement.z=-0.06",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    o.extend(extra.iter().map(|s| s.to_string()));
    o
}

fn run_o(o: &[String]) -> hytled::Result<hytled::report::Summary> {
    let r: Vec<&str> = o.iter().map(|s| s.as_str()).collect();
    run(CYL, &r)
}

#[test]
fn a_compression_the_reference_step_cannot_carry_completes_and_matches_a_short_fixed_step() {
    // (method, element, damping, how much shorter the fixed step is than the shortest update)
    for (method, element, damping, shorter) in [
        ("fe", "hex8", "solver.damping=0", 4.0),
        ("fe", "hex8", "solver.damping=2", 4.0),
        ("fe", "tet4-anp", "solver.damping=0", 4.0),
        // EBCIEM on the meshless nodes of both faces (2x only: 7,000 steps of 9,216 points).
        ("meshless", "hex8", "solver.damping=0", 2.0),
    ] {
        let (m, el) = (
            format!("discretization.method={method}"),
            format!("discretization.element={element}"),
        );
        let fe = [m.as_str(), el.as_str(), damping];
        let fixed = run_o(&compression(
            &[&fe[..], &["solver.step_update=false"]].concat(),
        ))
        .expect_err("the reference step at 60 % compression");
        println!("{method} {element}, {damping}, without updates: {fixed}");
        assert!(
            fixed.to_string().contains("made at the reference state"),
            "{fixed}"
        );

        let up = run_o(&compression(&fe))
            .unwrap_or_else(|e| panic!("{method} {element}, {damping}: {e}"));
        let u = up.step_updates.expect("step updates");
        println!(
            "{method} {element}, {damping}, with updates: {} steps, {u:?}",
            up.steps
        );
        assert!(u.reductions > 0 && u.dt_min < 0.8 * u.dt_initial, "{u:?}");
        let status = hytled::report::row_status(None, Some(&up));
        assert!(status.starts_with("ok, step shortened to 0."), "{status}");

        // Independent of the updates: a fixed step shorter than their shortest.
        let factor = format!(
            "solver.dt_factor={}",
            0.9 / shorter * u.dt_min / u.dt_initial
        );
        let reference = run_o(&compression(
            &[&fe[..], &["solver.step_update=false", &factor]].concat(),
        ))
        .unwrap_or_else(|e| panic!("{method} {element}, {damping}, reference: {e}"));
        let (a, b) = (up.reactions["top"][2], reference.reactions["top"][2]);
        let (ea, eb) = (
            up.energy.balance_error.expect("energy balance"),
            reference.energy.balance_error.expect("energy balance"),
        );
        println!(
            "{method} {element}, {damping}: F_z {a:.9e} N with updates, {b:.9e} N at the fixed step \
             ({} steps); energy balance error {ea:.3e} vs {eb:.3e}",
            reference.steps
        );
        assert!(a < -1.0 && ((a - b) / b).abs() < 1e-5, "{a} vs {b}");
        // The balance leaves out what damping dissipates, and the averaged pressure's forces
        // are not the gradient of the strain energy: compare with the fixed step's.
        assert!((ea - eb).abs() < 1e-5, "energy balance error {ea} vs {eb}");
    }
}

#[test]
fn updates_that_keep_the_step_leave_the_run_bitwise_unchanged() {
    // A rigid spin: the frequencies do not move, so the estimates (due to the motion) keep
    // the step; they must not disturb the state.
    let spin = |up: &str| {
        run(
            "cases/cube-spin.toml",
            &["solver.duration=2.0", "discretization.size=0.025", up],
        )
        .unwrap()
    };
    let (a, b) = (
        spin("solver.step_update=true"),
        spin("solver.step_update=false"),
    );
    let u = a.step_updates.expect("estimates");
    assert!(u.estimates > 0 && u.reductions == 0, "{u:?}");
    assert!(b.step_updates.is_none());
    assert_eq!(a.steps, b.steps);
    for (x, y) in [
        (a.energy.kinetic, b.energy.kinetic),
        (a.energy.strain_energy, b.energy.strain_energy),
    ] {
        assert_eq!(x.to_bits(), y.to_bits(), "{x} vs {y}");
    }
    let (ma, mb) = (a.momentum.unwrap(), b.momentum.unwrap());
    for k in 0..3 {
        assert_eq!(ma.angular_end[k].to_bits(), mb.angular_end[k].to_bits());
    }
    // Relaxation with physical masses never updates (its restarts serve instead); with the
    // fictitious masses of mass scaling (the default) it updates from the start, as its
    // answer does not keep the step's bits anyway.
    let relax = run(
        "cases/cube-compression.toml",
        &[
            "solver.mode=relaxation",
            "discretization.size=0.025",
            "solver.mass_scaling=false",
        ],
    )
    .unwrap();
    assert!(relax.step_updates.is_none());
    let scaled = run(
        "cases/cube-compression.toml",
        &["solver.mode=relaxation", "discretization.size=0.025"],
    )
    .unwrap();
    assert!(scaled.step_updates.is_some_and(|u| u.estimates > 0));
}

#[test]
fn relaxation_at_80_percent_converges_after_one_restart_with_updates() {
    // Relaxation keeps its step on the first attempt; after an instability it restarts at
    // 0.75x and estimates the step again as the body deforms. At 80 % compression the fixed
    // steps 0.9 -> 0.675 -> 0.506 all diverge (the run needs about 0.2 x the reference step
    // at full compression); with the updates one restart converges, to the equilibrium a
    // fixed short step reaches.
    let cases = [
        ("fe", "hex8", 0.1),
        ("fe", "tet4-anp", 0.15),
        ("coupled", "hex8", 0.15),
    ];
    for (method, element, fixed_factor) in cases {
        let base = [
            "discretization.divisions=[4,2,8]",
            "references={}",
            "solver.mode=relaxation",
            "boundaries.top.displacement.z=-0.08",
        ];
        let (m, el) = (
            format!("discretization.method={method}"),
            format!("discretization.element={element}"),
        );
        let with = |extra: &[&str]| {
            let mut o = base.to_vec();
            o.extend([m.as_str(), el.as_str()]);
            o.extend(extra);
            run(CYL, &o)
        };
        let e = with(&["solver.step_update=false"])
            .expect_err("fixed steps down to 0.506x")
            .to_string();
        assert!(e.contains("after 2 restart(s)"), "{method} {element}: {e}");

        let up = with(&[]).unwrap_or_else(|e| panic!("{method} {element}: {e}"));
        let u = up.step_updates.expect("updates in the restarted attempt");
        assert_eq!(up.restarts, 1, "{method} {element}");
        assert!(
            up.converged && u.reductions > 0 && u.dt_min < 0.4 * u.dt_initial,
            "{u:?}"
        );

        let factor = format!("solver.dt_factor={fixed_factor}");
        let reference = with(&[&factor, "solver.retries=0"])
            .unwrap_or_else(|e| panic!("{method} {element} at {fixed_factor}: {e}"));
        let (a, b) = (up.reactions["top"][2], reference.reactions["top"][2]);
        println!(
            "{method} {element}: F_z {a:.7e} N after a restart with updates ({} steps, step down \
             to {:.3}x), {b:.7e} N at {fixed_factor} x ({} steps)",
            up.steps,
            u.dt_min / u.dt_initial,
            reference.steps
        );
        assert!(((a - b) / b).abs() < 1e-6, "{a} vs {b}");
    }
}

#[test]
fn shortened_steps_are_bitwise_the_same_for_any_thread_count() {
    // The estimates sum in node order and the force kernel is thread-count independent, so a
    // run whose step is shortened dozens of times keeps the determinism of the fixed step.
    let o = compression(&["discretization.method=fe", "discretization.element=hex8"]);
    let sc = hytled::scene::load(&path(CYL), &o).unwrap();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut prep = hytled::simulation::prepare(&sc).unwrap();
            let s = hytled::simulation::settings(&sc, false);
            hytled::solver::run(&mut prep.model, &s).unwrap()
        })
    };
    let (a, b) = (run(1), run(2));
    assert!(a.step_updates.reductions > 10, "{:?}", a.step_updates);
    assert_eq!(a.step_updates, b.step_updates);
    assert_eq!(a.steps, b.steps);
    for (x, y) in a.u.iter().zip(&b.u) {
        for k in 0..3 {
            assert_eq!(x[k].to_bits(), y[k].to_bits());
        }
    }
}

/// A column 0.01 x 0.01 x 0.1 m of ten hex8 cells in uniaxial strain (every node held in x and
/// y, the base in z), its top driven down by `d` m (smooth, dynamic, 20 s, 300x the slowest
/// wave's transit: quasi-static). The deformation is homogeneous, F = diag(1, 1, l).
fn column(d: f64) -> String {
    format!(
        r#"name = "column"
description = "uniaxial strain column"
[geometry]
shape = "box"
min = [0.0, 0.0, 0.0]
max = [0.01, 0.01, 0.1]
[discretization]
method = "fe"
element = "hex8"
size = 0.01
[material]
model = "neo-hookean"
youngs_modulus = 3000.0
poisson_ratio = 0.3
density = 1000.0
[boundaries.lateral]
select = {{ box = {{ min = [-1.0, -1.0, -1.0], max = [1.0, 1.0, 1.0] }} }}
fix = ["x", "y"]
[boundaries.bottom]
select = {{ plane = {{ axis = "z", value = 0.0 }} }}
fix = ["z"]
[boundaries.top]
select = {{ plane = {{ axis = "z", value = 0.1 }} }}
displacement = {{ z = {} }}
curve = "smooth"
[solver]
mode = "dynamic"
duration = 20.0
"#,
        -d
    )
}

/// Neo-Hookean (docs/reference.md's form, W = mu/2 (J^-2/3 tr C - 3) + kappa/2 (J - 1)^2) in
/// uniaxial strain l: the nominal stress dW/dl (Pa) and the tangent d2W/dl2 (Pa), written out
/// by hand. E = 3 kPa, nu = 0.3.
fn uniaxial_strain(l: f64) -> (f64, f64) {
    let (e, nu) = (3000.0, 0.3);
    let (mu, kappa) = (e / (2.0 * (1.0 + nu)), e / (3.0 * (1.0 - 2.0 * nu)));
    let p = 0.5 * mu * (-2.0 / 3.0 * l.powf(-5.0 / 3.0) * (2.0 + l * l) + 2.0 * l.powf(1.0 / 3.0))
        + kappa * (l - 1.0);
    let c = mu * (10.0 / 9.0 * l.powf(-8.0 / 3.0) + 2.0 / 9.0 * l.powf(-2.0 / 3.0)) + kappa;
    (p, c)
}

fn run_column(d: f64) -> hytled::Result<hytled::report::Summary> {
    let sc = hytled::scene::parse(&column(d), &path("column.toml"), &[])?;
    run_scene(&sc, &RunOptions::default())
}

#[test]
fn a_column_crushed_to_95_percent_tracks_the_exact_spectrum_and_at_99_9_stops_clearly() {
    // The largest frequency of a homogeneous column follows the tangent d2W/dl2: the critical
    // step at stretch l is sqrt(C(1) / C(l)) of the initial one.
    let s = run_column(0.095).expect("95 % uniaxial strain");
    let l = 0.05;
    let (p, c) = uniaxial_strain(l);
    let top = s.reactions["top"][2];
    assert!(
        ((top - p * 1e-4) / (p * 1e-4)).abs() < 1e-5,
        "top force {top} N vs exact {} N",
        p * 1e-4
    );
    let exact_ratio = (uniaxial_strain(1.0).1 / c).sqrt();
    // The initial step sits at DEFORMATION_ALLOWANCE of the initial estimate, the updates at
    // UPDATE_ALLOWANCE of theirs: the step may fall less than the spectrum by their ratio.
    let u = s.step_updates.as_ref().expect("step updates on by default");
    let ratio = u.dt_min / u.dt_initial;
    assert!(
        ratio <= exact_ratio * UPDATE_ALLOWANCE / DEFORMATION_ALLOWANCE * 1.01
            && ratio >= exact_ratio * 0.9,
        "step fell to {ratio:.4} of the initial, the exact spectrum to {exact_ratio:.4}"
    );
    // Stable: the last step is below the exact critical step at the end (the initial one being
    // the Lanczos estimate, dt_critical / DEFORMATION_ALLOWANCE).
    let crit_end = s.dt_critical / DEFORMATION_ALLOWANCE * exact_ratio;
    assert!(u.dt_min < crit_end, "{} vs critical {crit_end}", u.dt_min);

    // 99.9 %: the frequency would rise about 2,000x; the run stops once the step would fall
    // below 1 % of the initial one, that is once the frequency has risen
    // 100 x UPDATE_ALLOWANCE / DEFORMATION_ALLOWANCE.
    let e = run_column(0.0999)
        .expect_err("99.9 % uniaxial strain")
        .to_string();
    assert!(
        e.contains("below 1 % of the initial step") && e.contains("collapsing"),
        "{e}"
    );
    let t: f64 = e
        .split("t = ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no time in: {e}"));
    let l = 1.0 - 0.0999 / 0.1 * hytled::bc::LoadCurve::Smooth.value(t / 20.0);
    let rise = (uniaxial_strain(l).1 / uniaxial_strain(1.0).1).sqrt();
    let threshold = 100.0 * UPDATE_ALLOWANCE / DEFORMATION_ALLOWANCE;
    println!(
        "95 %: top {top:.6e} N (exact {:.6e}), step ratio {ratio:.5} (spectrum {exact_ratio:.5}); \
         99.9 %: stopped at t = {t} s, l = {l:.5}, exact rise {rise:.1}x (threshold {threshold:.1}x)",
        p * 1e-4
    );
    assert!(
        rise > 0.97 * threshold && rise < 1.1 * threshold,
        "stopped at t = {t} s, l = {l:.5}: exact frequency rise {rise:.1}x, threshold {threshold:.1}x"
    );
}
