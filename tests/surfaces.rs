//! Issue 42, surfaces in: a body given as a closed surface file (`[geometry] surface`), STL
//! (ASCII and binary) or OBJ, checked and filled by TetGen for every method. The cube read as a
//! surface reproduces the exact homogeneous solution (docs/reference.md) with fe and within the
//! integration error with meshless; the cylinder read as a surface gives the built-in TetGen
//! cylinder's answer; broken surfaces are refused naming the file and where.

mod common;
use common::path;

use std::path::{Path, PathBuf};

use hytled::material::{uniaxial_stretch, NeoHookean};
use hytled::report::Summary;
use hytled::simulation::{run_scene, RunOptions};

fn folder(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hytled-surfaces-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

type Soup = (Vec<[f64; 3]>, Vec<[usize; 3]>);

/// The cube [0, 0.1]^3 as 12 outward triangles.
fn cube() -> Soup {
    (
        common::box_corners([0.0; 3], [0.1; 3]),
        common::box_triangles(),
    )
}

/// The cylinder of radius 0.05 m and height 0.1 m along z, base at z = 0, as the prism over
/// the regular `n`-gon: fans at the ends, two triangles per side.
fn cylinder(n: usize) -> Soup {
    let mut p = Vec::new();
    for z in [0.0, 0.1] {
        for k in 0..n {
            let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            p.push([0.05 * a.cos(), 0.05 * a.sin(), z]);
        }
    }
    p.push([0.0, 0.0, 0.0]);
    p.push([0.0, 0.0, 0.1]);
    let (cb, ct) = (2 * n, 2 * n + 1);
    let mut t = Vec::new();
    for k in 0..n {
        let k1 = (k + 1) % n;
        t.extend([
            [cb, k1, k],
            [ct, n + k, n + k1],
            [k, k1, n + k1],
            [k, n + k1, n + k],
        ]);
    }
    (p, t)
}

fn write_ascii_stl(file: &Path, (p, t): &Soup) {
    std::fs::write(file, common::ascii_stl(p, t)).unwrap();
}

/// The cube case on the surface `file` (its exact references need the built-in box: dropped,
/// and compared with here).
fn cube_run(file: &Path, extra: &[&str]) -> hytled::Result<Summary> {
    let mut o: Vec<String> = vec![
        format!("geometry={{ surface = \"{}\" }}", file.display()),
        "discretization.element=tet4-anp".into(),
        "discretization.size=0.025".into(),
        "references={}".into(),
        "solver.tolerance=1e-9".into(),
    ];
    o.extend(extra.iter().map(|s| s.to_string()));
    let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o)?;
    run_scene(&sc, &RunOptions::default())
}

/// Relative errors of the top force and the corner's lateral displacement against the exact
/// uniaxial solution (docs/reference.md: the cube compressed by 20 %) for a cube of `edge` m.
fn cube_errors(s: &Summary, edge: f64) -> (f64, f64) {
    let m = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let (a, _, sigma) = uniaxial_stretch(&m, 1.0 - 0.02 / edge);
    let f = sigma * (a * edge).powi(2);
    let u = (a - 1.0) * edge;
    (
        (s.reactions["top"][2] - f).abs() / f.abs(),
        (s.probes["corner"].displacement[0] - u).abs() / u,
    )
}

#[test]
fn the_cube_read_as_stl_or_obj_is_exact() {
    let dir = folder("cube");
    let soup = cube();
    let ascii = dir.join("cube.stl");
    write_ascii_stl(&ascii, &soup);
    // fe: linear tets hold the homogeneous field exactly; meshless: its integration error on
    // this coarse cloud (as tests/contact.rs).
    for (method, tol_f, tol_u) in [
        ("discretization.method=fe", 1e-6, 1e-5),
        ("discretization.method=meshless", 1e-3, 5e-3),
    ] {
        let s = cube_run(&ascii, &[method]).unwrap_or_else(|e| panic!("{method}: {e}"));
        let (ef, eu) = cube_errors(&s, 0.1);
        println!(
            "{method}: nodes {}, force {ef:.2e}, lateral {eu:.2e}",
            s.nodes
        );
        assert!(ef < tol_f && eu < tol_u, "{method}: {ef:e} {eu:e}");
    }
    // Binary STL (single precision: the edge is 0.1f32 m) and OBJ with quad faces.
    let checked = hytled::io::surface_file::read_surface(&ascii, 1.0).unwrap();
    let binary = dir.join("cube-binary.stl");
    hytled::io::surface_file::write_stl(&binary, &checked).unwrap();
    let s = cube_run(&binary, &["discretization.method=fe"]).unwrap();
    let (ef, eu) = cube_errors(&s, 0.1f32 as f64);
    assert!(ef < 1e-6 && eu < 1e-5, "binary: {ef:e} {eu:e}");
    let obj = dir.join("cube.obj");
    let mut text = String::from("# cube\n");
    for v in &soup.0 {
        text += &format!("v {} {} {}\n", v[0] * 1000.0, v[1] * 1000.0, v[2] * 1000.0);
    }
    for q in common::BOX_QUADS {
        text += &format!("f {} {} {} {}\n", q[0] + 1, q[1] + 1, q[2] + 1, q[3] + 1);
    }
    std::fs::write(&obj, text).unwrap();
    // In millimetres, with `units`.
    let s = cube_run(&obj, &["discretization.method=fe", "geometry.units=0.001"]).unwrap();
    let (ef, eu) = cube_errors(&s, 0.1);
    assert!(ef < 1e-6 && eu < 1e-5, "obj: {ef:e} {eu:e}");
}

#[test]
fn the_cylinder_read_as_stl_gives_the_builtin_tetgen_cylinders_answer() {
    let dir = folder("cylinder");
    let h = 0.01;
    // The built-in TetGen cylinder is the prism over round(2 pi r / h) = 31 sides.
    let file = dir.join("cylinder.stl");
    write_ascii_stl(&file, &cylinder(31));
    let run = |o: &[String]| {
        let sc = hytled::scene::load(&path("cases/tet-cylinder-compression.toml"), o).unwrap();
        run_scene(&sc, &RunOptions::default()).unwrap()
    };
    let common: Vec<String> = [
        format!("discretization.size={h}"),
        "boundaries.bottom.select={ plane = { axis = \"z\", value = 0.0 } }".into(),
        "boundaries.top.select={ plane = { axis = \"z\", value = 0.1 } }".into(),
    ]
    .to_vec();
    let mut o = common.clone();
    o.push(format!("geometry={{ surface = \"{}\" }}", file.display()));
    let from_stl = run(&o);
    let mut o = common;
    o.extend([
        "geometry={ shape = \"cylinder\", radius = 0.05, height = 0.1 }".to_string(),
        "discretization.mesher=tetgen".to_string(),
    ]);
    let builtin = run(&o);
    let (fs, fb) = (from_stl.reactions["top"][2], builtin.reactions["top"][2]);
    let (us, ub) = (
        from_stl.probes["mid_edge"].displacement[0],
        builtin.probes["mid_edge"].displacement[0],
    );
    println!(
        "STL: {} nodes, F {fs:.5} N, u_x {us:.5e} m; built-in: {} nodes, F {fb:.5} N, u_x {ub:.5e} m",
        from_stl.nodes, builtin.nodes
    );
    // Two TetGen meshes of the same body differ in their interior points only: the answers
    // agree to the discretization error's scatter between such meshes.
    assert!((fs - fb).abs() < 0.01 * fb.abs(), "{fs} vs {fb}");
    assert!((us - ub).abs() < 0.01 * ub.abs(), "{us} vs {ub}");
}

#[test]
fn broken_surfaces_are_refused_naming_the_file_and_where() {
    let dir = folder("broken");
    let (p, t) = cube();
    let load = |file: &Path| {
        cube_run(file, &["discretization.method=fe"])
            .map(|_| ())
            .unwrap_err()
            .to_string()
    };
    let open = dir.join("open.stl");
    write_ascii_stl(&open, &(p.clone(), t[1..].to_vec()));
    let e = load(&open);
    assert!(
        e.contains("open.stl") && e.contains("open") && e.contains("borders only triangle"),
        "{e}"
    );
    let mut q = p.clone();
    q[7] = [0.03, 0.03, -0.05];
    let crossing = dir.join("crossing.stl");
    write_ascii_stl(&crossing, &(q, t.clone()));
    let e = load(&crossing);
    assert!(
        e.contains("crossing.stl") && e.contains("crosses itself"),
        "{e}"
    );
    let e = load(&dir.join("missing.stl"));
    assert!(e.contains("missing.stl"), "{e}");
    let garbage = dir.join("garbage.stl");
    std::fs::write(
        &garbage,
        "solid x\nfacet normal 0 0 0\nouter loop\nvertex 1 2\n",
    )
    .unwrap();
    let e = load(&garbage);
    assert!(e.contains("garbage.stl") && e.contains("STL"), "{e}");
    let e = hytled::scene::load(
        &path("cases/cube-compression.toml"),
        &["geometry={ surface = \"body.ply\" }".to_string()],
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("body.ply") && e.contains(".stl"), "{e}");
}

/// VTK poly data: legacy 4.2 ASCII with quad POLYGONS, and XML .vtp with triangles.
#[test]
fn the_cube_read_as_vtk_poly_data_is_exact() {
    let dir = folder("vtk");
    let (p, t) = cube();
    let quads = common::BOX_QUADS;
    let mut legacy = format!(
        "# vtk DataFile Version 4.2\ncube\nASCII\nDATASET POLYDATA\nPOINTS {} double\n",
        p.len()
    );
    for v in &p {
        legacy += &format!("{} {} {}\n", v[0], v[1], v[2]);
    }
    legacy += "POLYGONS 6 30\n";
    for q in quads {
        legacy += &format!("4 {} {} {} {}\n", q[0], q[1], q[2], q[3]);
    }
    let vtk = dir.join("cube.vtk");
    std::fs::write(&vtk, legacy).unwrap();
    let coords: Vec<String> = p
        .iter()
        .map(|v| format!("{} {} {}", v[0], v[1], v[2]))
        .collect();
    let conn: Vec<String> = t
        .iter()
        .map(|t| format!("{} {} {}", t[0], t[1], t[2]))
        .collect();
    let offsets: Vec<String> = (1..=t.len()).map(|k| (3 * k).to_string()).collect();
    let vtp = dir.join("cube.vtp");
    std::fs::write(
        &vtp,
        format!(
            r#"<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian">
  <PolyData>
    <Piece NumberOfPoints="{}" NumberOfVerts="0" NumberOfLines="0" NumberOfStrips="0" NumberOfPolys="{}">
      <Points>
        <DataArray type="Float64" NumberOfComponents="3" format="ascii">{}</DataArray>
      </Points>
      <Polys>
        <DataArray type="Int64" Name="connectivity" format="ascii">{}</DataArray>
        <DataArray type="Int64" Name="offsets" format="ascii">{}</DataArray>
      </Polys>
    </Piece>
  </PolyData>
</VTKFile>
"#,
            p.len(),
            t.len(),
            coords.join(" "),
            conn.join(" "),
            offsets.join(" ")
        ),
    )
    .unwrap();
    for file in [vtk, vtp] {
        let s = cube_run(&file, &["discretization.method=fe"])
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let (ef, eu) = cube_errors(&s, 0.1);
        assert!(ef < 1e-6 && eu < 1e-5, "{}: {ef:e} {eu:e}", file.display());
    }
    // A volume mesh is no surface.
    let grid = dir.join("tet.vtk");
    std::fs::write(
        &grid,
        "# vtk DataFile Version 4.2\ntet\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 double\n\
         0 0 0\n1 0 0\n0 1 0\n0 0 1\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n",
    )
    .unwrap();
    let e = cube_run(&grid, &["discretization.method=fe"])
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("tet.vtk") && e.contains("no poly data"), "{e}");
}

/// A scene on a surface that names no element gets tet4-anp (TetGen fills the surface with
/// tetrahedra; the hex8 default could not be used); one that asks for hex8 is told why not.
#[test]
fn a_surface_scene_without_an_element_takes_tet4_anp() {
    let dir = folder("default-element");
    write_ascii_stl(&dir.join("cube.stl"), &cube());
    let text = "[geometry]\nsurface = \"cube.stl\"\n[discretization]\nsize = 0.05\n\
                [material]\nyoungs_modulus = 3000.0\npoisson_ratio = 0.49\ndensity = 1000.0\n\
                [boundaries.bottom]\nselect = { plane = { axis = \"z\", value = 0.0 } }\nfix = [\"all\"]\n";
    let file = dir.join("scene.toml");
    std::fs::write(&file, text).unwrap();
    let sc = hytled::scene::load(&file, &[]).unwrap();
    assert_eq!(
        sc.discretization.element,
        hytled::scene::ElementName::Tet4Anp
    );
    let sc = hytled::scene::load(&file, &["discretization.element=\"hex8\"".into()]).unwrap();
    let e = hytled::simulation::prepare(&sc)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("tetrahedra") && e.contains("tet4-anp"), "{e}");
}

/// A region given by a closed surface nested in the body (`[regions.NAME] surface`): TetGen
/// meshes it as an internal boundary, so every tet lies on one side of it. With the region's
/// material the body's, the cube read as STL is still exact (the internal facets change the
/// mesh, not the answer); a stiffer inclusion stiffens it; a surface outside the body, or
/// crossing it, is refused naming the region.
#[test]
fn a_nested_surface_is_a_conforming_region() {
    let dir = folder("nested");
    let body = dir.join("cube.stl");
    write_ascii_stl(&body, &cube());
    let inner = dir.join("inclusion.stl");
    write_ascii_stl(
        &inner,
        &(
            common::box_corners([0.03, 0.03, 0.03], [0.07, 0.07, 0.07]),
            common::box_triangles(),
        ),
    );
    let region = |file: &Path, e: f64| {
        format!(
            "regions.inclusion={{ surface = \"{}\", youngs_modulus = {e} }}",
            file.display()
        )
    };
    let same = cube_run(
        &body,
        &["discretization.method=fe", &region(&inner, 3000.0)],
    )
    .unwrap();
    let (ef, eu) = cube_errors(&same, 0.1);
    println!(
        "inclusion of the same material: force {ef:.2e}, lateral {eu:.2e}, {} nodes",
        same.nodes
    );
    assert!(ef < 1e-6 && eu < 1e-5, "{ef:e} {eu:e}");
    // The tets conform: each has all its vertices on one side of the inclusion's faces (or on
    // them).
    let o = vec![
        format!("geometry={{ surface = \"{}\" }}", body.display()),
        "discretization.element=tet4-anp".into(),
        "discretization.size=0.025".into(),
        "references={}".into(),
        region(&inner, 30000.0),
    ];
    let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
    let prep = hytled::simulation::prepare(&sc).unwrap();
    let inside = |x: &nalgebra::Vector3<f64>, strict: bool| {
        // STL holds single precision: 0.03 reads as 0.029999999329...
        let eps = if strict { -1e-7 } else { 1e-7 };
        x.iter().all(|&c| c > 0.03 - eps && c < 0.07 + eps)
    };
    let on_faces = prep
        .mesh
        .nodes
        .iter()
        .filter(|x| inside(x, false) && !inside(x, true))
        .count();
    println!("nodes on the inclusion's faces: {on_faces}");
    let mut straddling = 0;
    for e in 0..prep.mesh.num_cells() {
        let c = prep.mesh.cell(e);
        let any_in = c.iter().any(|&i| inside(&prep.mesh.nodes[i], true));
        let any_out = c.iter().any(|&i| !inside(&prep.mesh.nodes[i], false));
        if any_in && any_out {
            straddling += 1;
        }
    }
    let points = prep
        .regions
        .iter()
        .find(|r| r.name == "inclusion")
        .map(|r| r.points);
    println!(
        "stiff inclusion: {} tets, {straddling} straddling, region points {points:?}",
        prep.mesh.num_cells()
    );
    assert_eq!(straddling, 0);
    assert!(points.is_some_and(|n| n > 0));
    let stiff = cube_run(
        &body,
        &["discretization.method=fe", &region(&inner, 30000.0)],
    )
    .unwrap();
    let (f0, f1) = (same.reactions["top"][2], stiff.reactions["top"][2]);
    println!("top force: uniform {f0:.6} N, stiff inclusion {f1:.6} N");
    assert!(f1 < f0 && stiff.status == "converged", "{f0} {f1}");
    // Outside the body, and crossing it.
    let outside = dir.join("outside.stl");
    write_ascii_stl(
        &outside,
        &(
            common::box_corners([0.2, 0.2, 0.2], [0.3, 0.3, 0.3]),
            common::box_triangles(),
        ),
    );
    let crossing = dir.join("crossing.stl");
    write_ascii_stl(
        &crossing,
        &(
            common::box_corners([0.05, 0.03, 0.03], [0.15, 0.07, 0.07]),
            common::box_triangles(),
        ),
    );
    for (file, says) in [(&outside, "outside the body"), (&crossing, "cross")] {
        let e = cube_run(&body, &["discretization.method=fe", &region(file, 3000.0)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("region 'inclusion'") && e.contains(says), "{e}");
    }
}

/// The cylinder cases read as an STL prism of 63 sides (its cross-section 0.17 % below the
/// circle's; 31 sides, 0.68 % below, put the extension and shear forces 0.8-0.9 % low), meshed by
/// TetGen at 10 mm and solved with the quadratic tet10: within docs/reference.md's tolerances
/// (compression force 2 %, u_x 1 %; extension and shear 0.5 %). Measured on 2026-11-27 (28,329
/// nodes): compression -6.785973 N (1.94 %; below the band -6.98 ... -6.85) and u_x 0.27 %,
/// extension 0.27 % and 0.15 %, shear 0.16 % and 0.000 %; 27-73 s each on 2 cores.
/// `cargo test --release --test surfaces -- --ignored within_the_reference`.
#[test]
#[ignore]
fn the_cylinder_read_as_stl_is_within_the_reference_with_tet10() {
    let dir = folder("cylinder-tet10");
    let file = dir.join("cylinder.stl");
    write_ascii_stl(&file, &cylinder(63));
    // (case, reaction component, reaction, its tolerance, u_x, its tolerance)
    let cases = [
        ("compression", 2, -6.92, 0.02, 0.00699, 0.01),
        ("extension", 2, 4.664, 0.005, -0.005083, 0.005),
        ("shear", 0, 1.115, 0.005, 0.009506, 0.005),
    ];
    for (case, c, f_ref, tol_f, u_ref, tol_u) in cases {
        let o: Vec<String> = vec![
            "discretization.size=0.01".into(),
            "discretization.element=tet10".into(),
            "boundaries.bottom.select={ plane = { axis = \"z\", value = 0.0 } }".into(),
            "boundaries.top.select={ plane = { axis = \"z\", value = 0.1 } }".into(),
            format!("geometry={{ surface = \"{}\" }}", file.display()),
        ];
        let scene = format!("cases/tet-cylinder-{case}.toml");
        let sc = hytled::scene::load(&path(&scene), &o).unwrap();
        let s = run_scene(&sc, &RunOptions::default()).unwrap();
        let f = s.reactions["top"][c];
        let u = s.probes["mid_edge"].displacement[0];
        let (ef, eu) = (
            (f - f_ref).abs() / f_ref.abs(),
            (u - u_ref).abs() / u_ref.abs(),
        );
        println!(
            "{case}: {} nodes, F {f:.6} N ({ef:.2e}), u_x {u:.6e} m ({eu:.2e})",
            s.nodes
        );
        assert!(ef < tol_f && eu < tol_u, "{case}: {ef:e} {eu:e}");
    }
}
