//! Shared helpers for the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use hytled::report::Summary;
use hytled::scene::Scene;
use hytled::simulation::{run_scene, RunOptions};

/// The largest difference of any component between two fields, m.
pub fn largest_difference(a: &[nalgebra::Vector3<f64>], b: &[nalgebra::Vector3<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).amax())
        .fold(0.0, f64::max)
}

/// Path of a file in the crate.
pub fn path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Loads a scene file of the crate (`rel`, e.g. `cases/cube-compression.toml`) with `--set`
/// style overrides; panics naming the file and the error.
pub fn load_scene(rel: &str, overrides: &[&str]) -> Scene {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    hytled::scene::load(&path(rel), &o).unwrap_or_else(|e| panic!("{rel} {overrides:?}: {e}"))
}

/// The text of the exact cube's scene file.
pub fn cube_text() -> String {
    std::fs::read_to_string(path("cases/cube-compression.toml")).unwrap()
}

/// The exact cube (`cases/cube-compression.toml`) with `--set` style overrides.
pub fn cube_scene(overrides: &[&str]) -> Scene {
    load_scene("cases/cube-compression.toml", overrides)
}

/// Runs a committed case with `--set` style overrides.
pub fn run_case(case: &str, overrides: &[&str]) -> Summary {
    let scene = load_scene(case, overrides);
    run_scene(&scene, &RunOptions::default())
        .unwrap_or_else(|e| panic!("{case} {overrides:?}: {e}"))
}

/// Relative error of a reference comparison in a summary.
pub fn rel_err(s: &Summary, name: &str) -> f64 {
    s.reference
        .get(name)
        .unwrap_or_else(|| panic!("no reference '{name}'"))
        .relative_error
}

/// Every method on the 0.1 m cube: fe hex8, fe tet4-anp, meshless MLS and MMLS, coupled (which
/// needs a meshless interior inside its two FE layers: 12.5 mm cells).
pub const ALL_METHODS: [&[&str]; 5] = [
    &["discretization.method=fe"],
    &[
        "discretization.method=fe",
        "discretization.element=tet4-anp",
    ],
    &["discretization.method=meshless"],
    &[
        "discretization.method=meshless",
        "discretization.basis=quadratic",
    ],
    &[
        "discretization.method=coupled",
        "discretization.size=0.0125",
    ],
];

/// Node id of grid point (i, j, k) of an n x n x n box of hexahedra whose ids start at `first`.
pub fn box_node_id(n: usize, first: usize, i: usize, j: usize, k: usize) -> usize {
    first + i + (n + 1) * (j + (n + 1) * k)
}

/// An ABAQUS file of the 0.1 m cube as n x n x n C3D8 hexahedra, node ids from `first`
/// ([`box_node_id`]), the elements split into element sets by x: `sets` gives each set's name
/// and its range of cell columns i.
pub fn box_inp(n: usize, first: usize, sets: &[(&str, std::ops::Range<usize>)]) -> String {
    let h = 0.1 / n as f64;
    let id = |i, j, k| box_node_id(n, first, i, j, k);
    let mut s = String::from("*HEADING\nbox\n*NODE\n");
    for k in 0..=n {
        for j in 0..=n {
            for i in 0..=n {
                s += &format!(
                    "{}, {}, {}, {}\n",
                    id(i, j, k),
                    i as f64 * h,
                    j as f64 * h,
                    k as f64 * h
                );
            }
        }
    }
    let mut e = 1;
    for (name, range) in sets {
        s += &format!("*ELEMENT, TYPE=C3D8, ELSET={name}\n");
        for k in 0..n {
            for j in 0..n {
                for i in range.clone() {
                    let c = [
                        id(i, j, k),
                        id(i + 1, j, k),
                        id(i + 1, j + 1, k),
                        id(i, j + 1, k),
                        id(i, j, k + 1),
                        id(i + 1, j, k + 1),
                        id(i + 1, j + 1, k + 1),
                        id(i, j + 1, k + 1),
                    ];
                    let c: Vec<String> = c.iter().map(|x| x.to_string()).collect();
                    s += &format!("{e}, {}\n", c.join(", "));
                    e += 1;
                }
            }
        }
    }
    s
}

/// The outward quads of a box over its corners numbered i = x + 2 y + 4 z (bit k: max along k).
pub const BOX_QUADS: [[usize; 4]; 6] = [
    [0, 2, 3, 1],
    [4, 5, 7, 6],
    [0, 1, 5, 4],
    [2, 6, 7, 3],
    [0, 4, 6, 2],
    [1, 3, 7, 5],
];

/// The corners of the box [lo, hi] (m), numbered as [`BOX_QUADS`] takes them.
pub fn box_corners(lo: [f64; 3], hi: [f64; 3]) -> Vec<[f64; 3]> {
    (0..8)
        .map(|i| std::array::from_fn(|k| if (i >> k) & 1 == 0 { lo[k] } else { hi[k] }))
        .collect()
}

/// The box's surface as 12 outward triangles.
pub fn box_triangles() -> Vec<[usize; 3]> {
    BOX_QUADS
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect()
}

/// An ASCII STL file's text for `triangles` over `points` (m).
pub fn ascii_stl(points: &[[f64; 3]], triangles: &[[usize; 3]]) -> String {
    let mut s = String::from("solid body\n");
    for tri in triangles {
        s += "  facet normal 0 0 0\n    outer loop\n";
        for &i in tri {
            let p = points[i];
            s += &format!("      vertex {:.9e} {:.9e} {:.9e}\n", p[0], p[1], p[2]);
        }
        s += "    endloop\n  endfacet\n";
    }
    s + "endsolid body\n"
}

/// `hytled run` on the cube at 27 nodes, dynamic over 0.3 s (about 60 steps).
pub fn coarse_dynamic_cube() -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_hytled"));
    c.arg("run").arg(path("cases/cube-compression.toml")).args([
        "--set",
        "discretization.size=0.05",
        "--set",
        "solver.mode=dynamic",
        "--set",
        "solver.duration=0.3",
    ]);
    c
}

/// The messages of a run's warnings that contain `text`.
pub fn warnings_with<'a>(s: &'a Summary, text: &str) -> Vec<&'a str> {
    s.warnings
        .iter()
        .map(|w| w.message.as_str())
        .filter(|m| m.contains(text))
        .collect()
}
