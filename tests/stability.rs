//! Stability at the limits: a step beyond the stable one is reported unstable, dt_factor 0.9
//! runs, the same displacements on one and two threads, and materials whose numbers overflow.

mod common;
use common::*;

use hytled::simulation::{prepare, run_scene, settings, RunOptions};

/// The per-point bound is nearly tight for hex8 and tet4, so twice it diverges. For tet4-anp the
/// averaged pressure softens the highest mode and the bound is conservative by a factor of about
/// 1.5-2 (stable at 2.0 on the cube and at 3.0 on the cylinder; diverging at 3.0 and 4.0), so it
/// is driven at 4.0.
#[test]
fn beyond_the_stable_step_is_reported_unstable_for_every_element() {
    for (el, factor) in [("hex8", 2.0), ("tet4", 2.0), ("tet4-anp", 4.0)] {
        let sc = cube_scene(&[
            "solver.mode=dynamic",
            "solver.duration=0.5",
            &format!("solver.dt_factor={factor}"),
            &format!("discretization.element={el}"),
        ]);
        let dir = std::env::temp_dir().join(format!("hytled-unstable-{el}-{}", std::process::id()));
        let err = run_scene(
            &sc,
            &RunOptions {
                out: Some(dir.clone()),
                ..Default::default()
            },
        )
        .expect_err(el)
        .to_string();
        println!("{el}: {err}");
        assert!(
            err.contains("step") && err.contains("critical estimate") && err.contains("dt_factor"),
            "{el}: {err}"
        );
        // No results, only the failure (issue 22): summary.json with the status and message,
        // and the frames written before the divergence (at least the initial one) for debugging.
        let mut names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .filter(|n| !n.ends_with(".vtu"))
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                ".hytled-lock",
                ".hytled-manifest",
                "cube-compression.pvd",
                "summary.json"
            ],
            "{el}"
        );
        assert!(dir.join("cube-compression_0000.vtu").exists(), "{el}");
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(v["status"], "failed", "{el}");
        assert_eq!(v["message"], err.as_str(), "{el}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn dt_factor_0_9_is_stable_dynamic() {
    for el in ["hex8", "tet4-anp"] {
        let sc = cube_scene(&[
            "solver.mode=dynamic",
            "solver.duration=1.0",
            &format!("discretization.element={el}"),
        ]);
        let s = run_scene(&sc, &RunOptions::default()).unwrap_or_else(|e| panic!("{el}: {e}"));
        assert!(s.reactions["top"][2].is_finite());
    }
}

#[test]
fn one_and_two_threads_give_bitwise_identical_displacements() {
    let run = |threads: usize| {
        let sc = hytled::scene::load(
            &path("cases/cylinder-compression.toml"),
            &[
                "solver.duration=0.3".into(),
                "discretization.divisions=[4, 2, 8]".into(),
                "discretization.element=tet4-anp".into(),
            ],
        )
        .unwrap();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut prep = prepare(&sc).unwrap();
            hytled::solver::run(&mut prep.model, &settings(&sc, false)).unwrap()
        })
    };
    let (a, b) = (run(1), run(2));
    assert!(a.u.iter().any(|v| v.norm() > 0.0));
    for (x, y) in a.u.iter().zip(&b.u) {
        for k in 0..3 {
            assert_eq!(x[k].to_bits(), y[k].to_bits());
        }
    }
    assert_eq!(a.external_work.to_bits(), b.external_work.to_bits());
}

/// Moduli far out of range overflow the wave speed: the error says so and names the material
/// keys (it said "the discretization has no usable points").
#[test]
fn an_overflowing_wave_speed_names_the_material() {
    // Issue 57: the static solve says so too (it said "the tangent stiffness is singular").
    let said: [(&str, [&str; 3]); 2] = [
        ("relaxation", ["wave speed", "is inf m/s", "[material]"]),
        ("static", ["lambda + 2 mu", "inf Pa", "[material]"]),
    ];
    for method in ["fe", "meshless", "coupled"] {
        for (mode, needles) in &said {
            let sc = cube_scene(&[
                &format!("discretization.method={method}"),
                "material.youngs_modulus=1e308",
                &format!("solver.mode={mode}"),
            ]);
            let err = run_scene(&sc, &RunOptions::default())
                .expect_err(method)
                .to_string();
            assert!(
                needles.iter().all(|n| err.contains(n)),
                "{mode} {method}: {err}"
            );
        }
    }
}

/// Issue 41: Ogden exponents whose energy keeps no digits (1e-10: rounding / alpha^2; 1e-300:
/// alpha^2 underflows to 0, a NaN energy) or overflows (1e4) are refused with the key and the
/// range; the range's ends and the brain's -4.7 are taken.
#[test]
fn ogden_exponents_outside_what_f64_holds_are_refused() {
    let case = common::path("cases/cube-compression.toml");
    let load = |alpha: &str| {
        hytled::scene::load(
            &case,
            &[
                "material.model=ogden".to_string(),
                format!("material.alpha={alpha}"),
                "references={}".to_string(),
            ],
        )
    };
    for bad in ["1e-10", "1e-300", "-1e-300", "1e4", "-150.0"] {
        let e = load(bad).unwrap_err().to_string();
        assert!(
            e.contains("material.alpha") && e.contains("0.01 <= |alpha| <= 100"),
            "{bad}: {e}"
        );
    }
    for good in ["-4.7", "0.01", "-100.0", "2.0"] {
        load(good).unwrap_or_else(|e| panic!("{good}: {e}"));
    }
}
