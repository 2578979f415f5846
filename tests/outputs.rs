//! Issue 23, results for ParaView: nodal Cauchy stress, Green-Lagrange strain and principal
//! stretches, boundary labels and regions as VTU arrays, checked on the exact cube
//! (docs/reference.md: F = diag(a, a, 0.8), sigma_zz = -613.1215 Pa, lateral stress zero).

mod common;
use common::path;

use std::collections::BTreeMap;

use hytled::simulation::{run_scene, RunOptions};

const A: f64 = 1.11574668;

/// Point arrays, cell arrays (by name) and point coordinates of a frame.
type Frame = (
    BTreeMap<String, Vec<f64>>,
    BTreeMap<String, Vec<f64>>,
    Vec<f64>,
);

/// The arrays of the last frame of a run written to `dir`: point and cell arrays by name.
fn last_frame(dir: &std::path::Path, name: &str, frame: usize) -> Frame {
    let vtk = vtkio::Vtk::import(dir.join(format!("{name}_{frame:04}.vtu")))
        .expect("vtkio reads the frame");
    let vtkio::model::DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
        panic!("not an unstructured grid");
    };
    let piece = pieces[0].load_piece_data(None).unwrap();
    let read = |attrs: &[vtkio::model::Attribute]| -> BTreeMap<String, Vec<f64>> {
        attrs
            .iter()
            .filter_map(|a| match a {
                vtkio::model::Attribute::DataArray(d) => {
                    Some((d.name.clone(), d.data.clone().cast_into::<f64>().unwrap()))
                }
                _ => None,
            })
            .collect()
    };
    let points: Vec<f64> = piece.points.clone().cast_into().unwrap();
    (read(&piece.data.point), read(&piece.data.cell), points)
}

fn run(dir: &std::path::Path, overrides: &[&str]) -> hytled::report::Summary {
    let _ = std::fs::remove_dir_all(dir);
    let mut o: Vec<String> = vec![
        "discretization.size=0.025".into(),
        "solver.tolerance=1e-9".into(),
    ];
    o.extend(overrides.iter().map(|s| s.to_string()));
    let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
    run_scene(
        &sc,
        &RunOptions {
            out: Some(dir.to_path_buf()),
            ..Default::default()
        },
    )
    .unwrap()
}

/// At every node of the compressed cube the nodal stress is the exact uniaxial one, the strain
/// E = (F^T F - I) / 2 with F = diag(a, a, 0.8), the principal stretches (a, a, 0.8); the top
/// boundary's label marks exactly the top face's nodes.
#[test]
fn nodal_fields_and_labels_on_the_exact_cube() {
    for (run_id, (method, tol)) in [
        (&["discretization.method=fe"][..], 1e-6_f64),
        (
            &[
                "discretization.method=fe",
                "discretization.element=tet4-anp",
            ],
            1e-6,
        ),
        // tet10 is written as the eight linear tets of each element's split, every one with
        // its element's cell values.
        (
            &["discretization.method=fe", "discretization.element=tet10"],
            1e-5,
        ),
        // Meshless: smoothed by the shape functions, with the integration error of the cube
        // tests (2 %).
        (&["discretization.method=meshless"], 2e-2),
    ]
    .into_iter()
    .enumerate()
    {
        let dir =
            std::env::temp_dir().join(format!("hytled-outputs-{run_id}-{}", std::process::id()));
        let _s = run(&dir, method);
        let (point, cell, xyz) = last_frame(&dir, "cube-compression", 1);
        for k in [
            "displacement",
            "cauchy_stress",
            "green_lagrange_strain",
            "principal_stretches",
            "von_mises",
            "J",
            "boundary_top",
            "boundary_bottom",
        ] {
            assert!(
                point.contains_key(k),
                "{method:?}: no point array {k}: {:?}",
                point.keys()
            );
        }
        // One value per cell, each the cell's mean of the exact uniaxial stress.
        let cell_sig = &cell["cauchy_stress"];
        let cells = cell["J"].len();
        assert_eq!(cell_sig.len(), 9 * cells, "{method:?}");
        for c in 0..cells {
            let zz = cell_sig[9 * c + 8];
            assert!(
                (zz + 613.1215).abs() < 613.1215 * tol,
                "{method:?}: cell {c} {zz}"
            );
        }
        let n = xyz.len() / 3;
        let (sig, e, l) = (
            &point["cauchy_stress"],
            &point["green_lagrange_strain"],
            &point["principal_stretches"],
        );
        let exact_e = [0.5 * (A * A - 1.0), 0.5 * (A * A - 1.0), 0.5 * (0.64 - 1.0)];
        let mut worst: f64 = 0.0;
        for v in 0..n {
            worst = worst.max((sig[9 * v + 8] + 613.1215).abs() / 613.1215);
            worst = worst.max(sig[9 * v].abs() / 613.1215);
            for k in 0..3 {
                worst = worst.max((e[9 * v + 4 * k] - exact_e[k]).abs() / exact_e[k].abs());
            }
            worst = worst
                .max((l[3 * v] - A).abs() / A)
                .max((l[3 * v + 2] - 0.8).abs() / 0.8);
        }
        println!("{method:?}: worst relative error of the nodal fields {worst:.3e}");
        assert!(worst < tol, "{method:?}: {worst}");
        let top = &point["boundary_top"];
        for v in 0..n {
            let on_top = (xyz[3 * v + 2] - 0.1).abs() < 1e-12;
            assert_eq!(top[v] == 1.0, on_top, "{method:?}: vertex {v}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// With a region, every cell carries its material index: the cells of the region's half 1,
/// the others 0 (tet10: each of an element's eight split cells its element's index).
#[test]
fn region_cells_are_labelled() {
    for (element, cells) in [("hex8", 64), ("tet10", 64 * 6 * 8)] {
        let dir = std::env::temp_dir().join(format!(
            "hytled-outputs-region-{element}-{}",
            std::process::id()
        ));
        let e = format!("discretization.element={element}");
        run(
            &dir,
            &[
                "references={}",
                &e,
                "regions.hard.select={ box = { min = [0.05, -1.0, -1.0], max = [1.0, 1.0, 1.0] } }",
                "regions.hard.youngs_modulus=6000",
            ],
        );
        let (_, cell, _) = last_frame(&dir, "cube-compression", 1);
        let r = &cell["region"];
        assert_eq!(r.len(), cells, "{element}");
        assert_eq!(
            r.iter().filter(|&&x| x == 1.0).count(),
            cells / 2,
            "{element}"
        );
        assert!(r.iter().all(|&x| x == 0.0 || x == 1.0));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
