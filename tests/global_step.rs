//! The global (Lanczos) estimate of the critical step (solver::spectrum, issue 21): checked
//! against the largest eigenvalue of the assembled, dense M^-1/2 K M^-1/2 on small models of
//! every point family, and for stability: safe through 20 % compression at 1.0 x the step,
//! divergent at twice it.

mod common;
use common::*;

use std::path::Path;

use hytled::simulation;
use hytled::solver::integrate::{critical_step, stable_step, Critical, DEFORMATION_ALLOWANCE};
use hytled::solver::spectrum::largest_eigenvalue;
use hytled::solver::StepEstimate;
use nalgebra::{DMatrix, Vector3};

fn prepared(case: &str, overrides: &[&str]) -> simulation::Prepared {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let s = hytled::scene::load(Path::new(&format!("cases/{case}.toml")), &o).unwrap();
    simulation::prepare(&s).unwrap()
}

/// Largest eigenvalue of M^-1/2 K_0 M^-1/2 on the free DOFs, from K_0 assembled column by
/// column with central differences of the internal force (independent of the Lanczos code:
/// no start vector, no tridiagonal, a dense symmetric eigensolver).
fn dense_lambda_max(p: &mut simulation::Prepared) -> f64 {
    let m = &mut p.model;
    let n = m.nodes().len();
    let free: Vec<(usize, usize)> = (0..n)
        .flat_map(|i| (0..3).map(move |k| (i, k)))
        .filter(|&(i, k)| !m.constraints().mask[i][k])
        .collect();
    let size = m
        .nodes()
        .iter()
        .fold(0.0f64, |a, x| a.max(x.amax()))
        .max(1e-3);
    let h = 1e-7 * size;
    let nf = free.len();
    let mut a = DMatrix::<f64>::zeros(nf, nf);
    let mut u = vec![Vector3::zeros(); n];
    let (mut fp, mut fm) = (vec![Vector3::zeros(); n], vec![Vector3::zeros(); n]);
    for (c, &(j, l)) in free.iter().enumerate() {
        u[j][l] = h;
        m.internal_forces(&u, &mut fp);
        u[j][l] = -h;
        m.internal_forces(&u, &mut fm);
        u[j][l] = 0.0;
        for (r, &(i, k)) in free.iter().enumerate() {
            a[(r, c)] = (fp[i][k] - fm[i][k]) / (2.0 * h) / (m.mass()[i] * m.mass()[j]).sqrt();
        }
    }
    let sym = (&a + a.transpose()) * 0.5;
    let asym = (&a - a.transpose()).abs().max();
    assert!(
        asym < 1e-6 * sym.abs().max(),
        "reference stiffness not symmetric: {asym:e}"
    );
    sym.symmetric_eigen().eigenvalues.max()
}

/// Lanczos finds the largest eigenvalue of the assembled operator to its 1e-3 tolerance, from
/// above (the residual is added), for hex8 with hourglass control, tet4, tet4-anp, linear and
/// quadratic MLS and the coupled method, and it is never above the nodal and per-point bounds.
#[test]
fn lanczos_matches_the_dense_largest_eigenvalue() {
    let coarse = "discretization.size=0.05";
    for overrides in [
        vec![coarse],
        vec![coarse, "discretization.element=tet4"],
        vec![coarse, "discretization.element=tet4-anp"],
        vec![coarse, "discretization.method=meshless"],
        vec![
            coarse,
            "discretization.method=meshless",
            "discretization.basis=quadratic",
        ],
        vec![
            "discretization.size=0.025",
            "discretization.method=coupled",
            "discretization.fe_layers=1",
        ],
    ] {
        let mut p = prepared("cube-compression", &overrides);
        let exact = dense_lambda_max(&mut p);
        let e = largest_eigenvalue(&mut p.model, 200, 1e-3).expect("an estimate");
        let (bound_dt, _) = stable_step(&p.model);
        let bound = (2.0 / bound_dt).powi(2);
        println!(
            "{overrides:?}: dense {exact:.6e}, Ritz {:.6e}, estimate {:.6e} ({} iterations), bounds {bound:.6e}",
            e.ritz, e.lambda_max, e.iterations
        );
        assert!(
            e.ritz <= exact * (1.0 + 1e-6),
            "Ritz value above the spectrum"
        );
        assert!(
            e.lambda_max >= exact * (1.0 - 1e-6) && e.lambda_max <= exact * 1.01,
            "{overrides:?}: estimate {} vs {exact}",
            e.lambda_max
        );
        assert!(exact <= bound * (1.0 + 1e-9), "the bounds must hold");
    }
}

fn dynamic_compression(
    overrides: &[&str],
    factor: &str,
) -> hytled::Result<hytled::report::Summary> {
    let mut o: Vec<String> = vec![
        "solver.mode=dynamic".into(),
        format!("solver.dt_factor={factor}"),
        "geometry.mesh=../meshes/cylinder-gmsh-h75.msh".into(),
    ];
    o.extend(overrides.iter().map(|s| s.to_string()));
    let scene = hytled::scene::load(&path("cases/tet-cylinder-compression.toml"), &o)?;
    simulation::run_scene(&scene, &Default::default())
}

/// The global step (the allowance x 2 / omega_max) completes the 20 % compression of the
/// 1,982-node Gmsh cylinder at 1.0 x the step, coupled and meshless, and twice it diverges:
/// the estimate is neither unsafe nor loose. It sets the step of these models (2.0x the
/// bounds' step on this coupled cylinder, 2.3x on the 4,208-node one) and leaves tet4-anp on
/// its own bound.
#[test]
fn global_step_is_safe_under_compression_and_not_loose() {
    for method in [
        "discretization.method=coupled",
        "discretization.method=meshless",
    ] {
        let ok = dynamic_compression(&[method, "solver.duration=0.5"], "1.0")
            .unwrap_or_else(|e| panic!("{method} at 1.0 x the global step: {e}"));
        assert!(ok.converged, "{method}: did not complete");
        let e = dynamic_compression(&[method, "solver.duration=0.5"], "2.0")
            .expect_err("twice the global step must diverge");
        let e = e.to_string();
        assert!(
            e.contains("diverged") || e.contains("inverted (J ="),
            "{method}: {e}"
        );
    }
    // With the physical masses (relaxation scales them by default: every node then has the
    // same Gershgorin bound, and the global estimate is 1.56x it on this cylinder).
    let mut p = prepared(
        "tet-cylinder-compression",
        &[
            "geometry.mesh=../meshes/cylinder-gmsh-h75.msh",
            "discretization.method=coupled",
            "solver.mass_scaling=false",
        ],
    );
    let (bounds, _) = stable_step(&p.model);
    let (global, crit) = critical_step(&mut p.model, StepEstimate::Global);
    println!("coupled: bounds {bounds:e} s, global {global:e} s ({crit})");
    assert!(matches!(crit, Critical::Global(_)));
    assert!(global > 1.8 * bounds, "{global} vs {bounds}");
    let e = largest_eigenvalue(&mut p.model, 60, 1e-3).unwrap();
    assert_eq!(global, DEFORMATION_ALLOWANCE * e.critical_step());
    let mut anp = prepared(
        "tet-cylinder-compression",
        &[
            "geometry.mesh=../meshes/cylinder-gmsh-h75.msh",
            "solver.mode=relaxation",
            "solver.mass_scaling=false",
        ],
    );
    let b = stable_step(&anp.model);
    assert_eq!(critical_step(&mut anp.model, StepEstimate::Global), b);
    // Mass-scaled in relaxation (asked for: tet4-anp models keep their physical masses by
    // default; the case solves statically, where no masses enter), tet4-anp
    // takes the global estimate, never below
    // the nodal bound, which holds for any masses.
    let mut scaled = prepared(
        "tet-cylinder-compression",
        &[
            "geometry.mesh=../meshes/cylinder-gmsh-h75.msh",
            "solver.mode=relaxation",
            "solver.mass_scaling=true",
        ],
    );
    assert!(scaled.model.mass_scaled());
    let (b, crit) = stable_step(&scaled.model);
    assert!(matches!(crit, Critical::Node(_)));
    let (global, crit) = critical_step(&mut scaled.model, StepEstimate::Global);
    assert!(
        matches!(crit, Critical::Global(_)) && global > b,
        "{global} vs {b}"
    );
}
