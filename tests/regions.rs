//! Issue 23, tissue regions and the Ogden material: exact homogeneous solutions of the cube
//! (docs/reference.md) with one-term Ogden tissue, and with two regions side by side.

use std::path::PathBuf;

use hytled::material::{uniaxial_stretch, NeoHookean, Ogden};
use hytled::report::Summary;
use hytled::simulation::{prepare, run_scene, RunOptions};

mod common;
use common::{box_inp, path, ALL_METHODS};

/// FE passes the patch test; meshless and coupled carry their integration error (the bounds
/// of the displacement-driven cube tests: 2 % for the reaction).
fn tolerance(method: &[&str]) -> f64 {
    if method[0].ends_with("=fe") {
        1e-5
    } else {
        2e-2
    }
}

fn cube(extra: &[&str]) -> Summary {
    // The uniaxial references hold for one material: regions compare with their own.
    let o: Vec<String> = [
        "solver.tolerance=1e-9",
        "discretization.size=0.025",
        "references={}",
    ]
    .iter()
    .chain(extra)
    .map(|s| s.to_string())
    .collect();
    let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
    run_scene(&sc, &RunOptions::default()).unwrap_or_else(|e| panic!("{extra:?}: {e}"))
}

/// The cube of one-term Ogden brain tissue (mu = 842 Pa, alpha = -4.7, kappa = 100 mu; Miller
/// and Chinzei 2002) compressed by 20 %: the reaction against the closed-form uniaxial
/// solution, which the scene's `exact = "uniaxial"` reference computes for the Ogden model.
#[test]
fn an_ogden_cube_matches_its_exact_uniaxial_solution_for_every_method() {
    let m = Ogden {
        mu: 842.0,
        alpha: -4.7,
        kappa: 84200.0,
        density: 1000.0,
    };
    let (a, _, sigma) = m.uniaxial(0.8);
    let want = sigma * (0.1 * a) * (0.1 * a);
    // The cube case with the Ogden material in place of its neo-Hookean one.
    let text = std::fs::read_to_string(path("cases/cube-compression.toml"))
        .unwrap()
        .replace(
            "model = \"neo-hookean\"\nyoungs_modulus = 3000.0  # Pa\npoisson_ratio = 0.49\n",
            "model = \"ogden\"\nalpha = -4.7\nshear_modulus = 842.0\nbulk_modulus = 84200.0\n",
        );
    assert!(text.contains("ogden"));
    let dir = std::env::temp_dir().join(format!("hytled-ogden-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("cube.toml");
    std::fs::write(&file, text).unwrap();
    for method in ALL_METHODS {
        let o: Vec<String> = ["solver.tolerance=1e-9", "discretization.size=0.025"]
            .iter()
            .chain(method.iter())
            .map(|s| s.to_string())
            .collect();
        let sc = hytled::scene::load(&file, &o).unwrap();
        let s = run_scene(&sc, &RunOptions::default()).unwrap();
        let f = s.reactions["top"][2];
        let r = &s.reference["top_force"];
        println!(
            "{method:?}: Ogden F_z = {f:.6} N, exact {want:.6} N ({:.4} %), lateral {:.4} %",
            100.0 * r.relative_error,
            100.0 * s.reference["lateral"].relative_error
        );
        assert!(
            (r.value - want).abs() < 1e-9 * want.abs(),
            "{} vs {want}",
            r.value
        );
        assert!(r.relative_error < tolerance(method), "{method:?}");
        assert!(
            s.reference["lateral"].relative_error < tolerance(method),
            "{method:?}"
        );
    }
}

/// Two regions side by side (x < 0.05 m and x > 0.05 m, E = 3000 and 6000 Pa, the same nu):
/// under the same axial stretch both halves take the same lateral stretch, so the exact
/// solution stays homogeneous in each and the top reaction is the mean of the two exact
/// reactions. Each region's point count is reported.
#[test]
fn two_regions_side_by_side_reproduce_the_exact_mean_reaction() {
    let soft = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let hard = NeoHookean::from_young_poisson(6000.0, 0.49, 1000.0);
    let (a, _, s1) = uniaxial_stretch(&soft, 0.8);
    let (a2, _, s2) = uniaxial_stretch(&hard, 0.8);
    assert!((a - a2).abs() < 1e-12, "same nu, same lateral stretch");
    let want = 0.5 * (s1 + s2) * (0.1 * a) * (0.1 * a);
    for method in ALL_METHODS {
        let mut o = vec![
            "regions.hard.select={ box = { min = [0.05, -1.0, -1.0], max = [1.0, 1.0, 1.0] } }",
            "regions.hard.youngs_modulus=6000",
        ];
        o.extend_from_slice(method);
        let s = cube(&o);
        let f = s.reactions["top"][2];
        let err = (f - want).abs() / want.abs();
        let u = s.probes["corner"].displacement[0];
        let err_u = (u - (a - 1.0) * 0.1).abs() / ((a - 1.0) * 0.1);
        println!(
            "{method:?}: F_z = {f:.6} N, exact {want:.6} N ({:.4} %), corner u_x {:.4} %",
            100.0 * err,
            100.0 * err_u
        );
        assert!(
            err < tolerance(method) && err_u < tolerance(method),
            "{method:?}"
        );
    }
    // FE: each of the 64 elements takes one material, half of them the region's.
    let sc = hytled::scene::load(
        &path("cases/cube-compression.toml"),
        &[
            "discretization.size=0.025".into(),
            "references={}".into(),
            "regions.hard.select={ box = { min = [0.05, -1.0, -1.0], max = [1.0, 1.0, 1.0] } }"
                .into(),
            "regions.hard.youngs_modulus=6000".into(),
        ],
    )
    .unwrap();
    let p = prepare(&sc).unwrap();
    assert_eq!(
        p.regions,
        vec![hytled::simulation::RegionPoints {
            name: "hard".to_string(),
            points: 32
        }]
    );
    assert_eq!(p.point_material.iter().filter(|&&m| m == 1).count(), 32);
}

/// An ABAQUS box of 6 x 6 x 6 hexahedra in two element sets, LEFT (x < 0.05 m) and RIGHT.
fn two_set_box() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hytled-regions-inp-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let f = dir.join("box.inp");
    std::fs::write(&f, box_inp(6, 1, &[("LEFT", 0..3), ("RIGHT", 3..6)])).unwrap();
    f
}

/// A region given as an element set of the mesh file: FE elements, meshless points (through
/// their background tet, the cloud being the file's vertices) and coupled points (through
/// their cell) take its material; the exact mean reaction follows as above.
#[test]
fn element_set_regions_reach_every_method() {
    let inp = two_set_box();
    let soft = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let (a, _, s1) = uniaxial_stretch(&soft, 0.8);
    let want = 0.5 * (s1 + 2.0 * s1) * (0.1 * a) * (0.1 * a);
    for method in [
        &["discretization.method=fe"][..],
        &["discretization.method=meshless"],
        &[
            "discretization.method=coupled",
            "discretization.fe_layers=1",
        ],
    ] {
        let mut o: Vec<String> = vec![
            format!("geometry={{ mesh = \"{}\" }}", inp.display()),
            "regions.hard.elements=RIGHT".into(),
            "regions.hard.youngs_modulus=6000".into(),
            "references={}".into(),
            "probes={}".into(),
            "solver.tolerance=1e-9".into(),
        ];
        o.extend(method.iter().map(|s| s.to_string()));
        let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
        let s = run_scene(&sc, &RunOptions::default()).unwrap();
        let f = s.reactions["top"][2];
        let err = (f - want).abs() / want.abs();
        println!(
            "{method:?}: F_z = {f:.6} N, exact {want:.6} N ({:.4} %)",
            100.0 * err
        );
        assert!(err < tolerance(method), "{method:?}");
        let p = prepare(&sc).unwrap();
        let hytled::simulation::RegionPoints {
            name,
            points: count,
        } = &p.regions[0];
        assert_eq!(name, "hard");
        assert!(
            *count * 2 >= p.model.points().len() * 9 / 10
                && *count * 2 <= p.model.points().len() * 11 / 10,
            "{count} of {}",
            p.model.points().len()
        );
    }
}

/// Overlapping regions, a region that holds no point, an unknown element set and an Ogden
/// material without its exponent are input errors naming them; a near-incompressible region
/// meshed with plain tet4 gets the locking warning.
#[test]
fn region_errors_and_warnings_name_the_region() {
    let err = |extra: &[&str]| {
        let mut o: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        o.push("references={}".into());
        hytled::scene::load(&path("cases/cube-compression.toml"), &o)
            .and_then(|sc| prepare(&sc).map(|_| ()))
            .unwrap_err()
            .to_string()
    };
    let e = err(&[
        "regions.a.select={ box = { min = [0.0, 0.0, 0.0], max = [0.06, 0.1, 0.1] } }",
        "regions.a.youngs_modulus=6000",
        "regions.b.select={ box = { min = [0.04, 0.0, 0.0], max = [0.1, 0.1, 0.1] } }",
        "regions.b.youngs_modulus=9000",
    ]);
    assert!(e.contains("regions 'a' and 'b' overlap"), "{e}");
    let e = err(&[
        "regions.far.select={ sphere = { center = [1.0, 1.0, 1.0], radius = 0.01 } }",
        "regions.far.youngs_modulus=6000",
    ]);
    assert!(e.contains("region 'far'"), "{e}");
    let e = err(&["regions.s.elements=TUMOUR", "regions.s.youngs_modulus=6000"]);
    assert!(e.contains("region 's'") && e.contains("mesh file"), "{e}");
    let e = err(&["material.model=ogden"]);
    assert!(e.contains("alpha"), "{e}");
    let e = err(&[
        "regions.p.select={ plane = { axis = \"x\", value = 0.05 } }",
        "regions.p.youngs_modulus=6000",
    ]);
    assert!(
        e.contains("regions.p.select") && e.contains("volume"),
        "{e}"
    );
    let sc = hytled::scene::load(
        &path("cases/cube-compression.toml"),
        &[
            "references={}".into(),
            "discretization.element=tet4".into(),
            "regions.core.select={ sphere = { center = [0.05, 0.05, 0.05], radius = 0.03 } }"
                .into(),
            "regions.core.poisson_ratio=0.4999".into(),
        ],
    )
    .unwrap();
    let p = prepare(&sc).unwrap();
    assert!(
        p.warnings
            .iter()
            .any(|w| w.contains("locking") && w.contains("tet4")),
        "{:?}",
        p.warnings
    );
}
