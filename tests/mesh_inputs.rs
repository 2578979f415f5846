//! Scenes that read their body from mesh files written by external tools (meshes/README.md).

mod common;
use common::*;

/// The built-in O-grid cylinder [4, 2, 8] and the same mesh read back from an ABAQUS .inp and
/// Gmsh 2.2 / 4.1 files written by meshio: the same reaction (the files hold the same doubles).
#[test]
fn cylinder_from_inp_and_msh_matches_the_built_in_mesh() {
    let base = ["discretization.divisions=[4,2,8]", "solver.mode=relaxation"];
    let builtin = run_case("cases/cylinder-compression.toml", &base);
    let f0 = builtin.reactions["top"][2];
    for file in [
        "cylinder-428-hex8.inp",
        "cylinder-428-hex8-v22.msh",
        "cylinder-428-hex8-v41.msh",
    ] {
        let g = format!("geometry={{ mesh = \"../meshes/{file}\" }}");
        let s = run_case(
            "cases/cylinder-compression.toml",
            &[base[0], base[1], g.as_str()],
        );
        let f = s.reactions["top"][2];
        println!("{file}: F_z = {f} N (built-in {f0} N)");
        assert_eq!(s.nodes, builtin.nodes);
        assert!((f - f0).abs() <= 0.005 * f0.abs(), "{file}: {f} vs {f0}");
    }
}

#[test]
fn mesh_geometry_errors_are_clear() {
    let o = |g: &str| vec![format!("geometry={g}")];
    let err = |g: &str| {
        let sc = hytled::scene::load(&path("cases/cylinder-compression.toml"), &o(g));
        match sc {
            Err(e) => e.to_string(),
            Ok(sc) => hytled::simulation::prepare(&sc)
                .err()
                .expect("must fail")
                .to_string(),
        }
    };
    assert!(err("{ mesh = \"../meshes/nothing.inp\" }").contains("nothing.inp"));
    assert!(err("{ mesh = \"../meshes/x.stl\" }").contains("unknown extension"));
    assert!(err("{ mesh = \"../meshes/cylinder-428-hex8.inp\", radius = 1.0 }").contains("radius"));
    assert!(err("{ mesh = \"../meshes/cylinder-428-hex8.inp\", units = -1.0 }").contains("units"));
    // A hexahedral mesh with a tetrahedral element asked for.
    let sc = hytled::scene::load(
        &path("cases/cylinder-compression.toml"),
        &[
            "geometry={ mesh = \"../meshes/cylinder-428-hex8.inp\" }".into(),
            "discretization.element=tet4-anp".into(),
        ],
    )
    .unwrap();
    let e = hytled::simulation::prepare(&sc).err().unwrap().to_string();
    assert!(e.contains("hexahedral") && e.contains("hex8"), "{e}");
    // A set name that does not exist lists the available ones.
    let sc = hytled::scene::load(
        &path("cases/cylinder-compression.toml"),
        &[
            "geometry={ mesh = \"../meshes/cylinder-428-hex8.inp\" }".into(),
            "boundaries.top.select={ set = \"lid\" }".into(),
        ],
    )
    .unwrap();
    let e = hytled::simulation::prepare(&sc).err().unwrap().to_string();
    assert!(e.contains("lid") && e.contains("available"), "{e}");
}

/// A Gmsh-made tet cylinder whose physical groups "bottom" and "top" select the boundaries:
/// the same reaction as selecting the same nodes by planes.
#[test]
fn gmsh_physical_groups_select_boundaries() {
    let g = "geometry={ mesh = \"../tests/data/msh/cyl_v41.msh\" }";
    let base = [
        g,
        "discretization.element=tet4-anp",
        "solver.mode=relaxation",
    ];
    let planes = run_case("cases/cylinder-compression.toml", &base);
    let mut with_sets = base.to_vec();
    with_sets.extend([
        "boundaries.bottom.select={ set = \"bottom\" }",
        "boundaries.top.select={ set = \"top\" }",
    ]);
    with_sets.push("probes.lid={ select = { set = \"top\" } }");
    let sets = run_case("cases/cylinder-compression.toml", &with_sets);
    // A probe over a set averages its nodes: the driven lid moved 0.02 m down.
    let lid = sets.probes["lid"].displacement;
    assert!(
        (lid[2] + 0.02).abs() < 1e-12 && (sets.probes["lid"].position[2] - 0.1).abs() < 1e-12,
        "{lid:?}"
    );
    let (a, b) = (planes.reactions["top"][2], sets.reactions["top"][2]);
    println!(
        "Gmsh cylinder ({} nodes): planes {a} N, sets {b} N",
        sets.nodes
    );
    assert_eq!(a, b);
    assert!(a < 0.0);
}

/// `hytled convert` .msh -> .inp -> .vtu keeps nodes, cells and sets.
#[test]
fn convert_round_trip_keeps_nodes_cells_and_sets() {
    use hytled::io::mesh_file::{read_mesh, write_mesh_file};
    use hytled::io::vtu::VtuFormat;
    let dir = std::env::temp_dir().join(format!("hytled-convert-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let src = read_mesh(&path("tests/data/msh/cyl_v41.msh"), None, 1.0).unwrap();
    let inp = dir.join("c.inp");
    write_mesh_file(&inp, &src, VtuFormat::Ascii).unwrap();
    let a = read_mesh(&inp, None, 1.0).unwrap();
    let vtu = dir.join("c.vtu");
    write_mesh_file(&vtu, &a, VtuFormat::Binary).unwrap();
    let b = read_mesh(&vtu, None, 1.0).unwrap();
    for m in [&a, &b] {
        assert_eq!(m.mesh.nodes, src.mesh.nodes);
        assert_eq!(m.mesh.cells, src.mesh.cells);
        for (name, v) in &src.node_sets {
            assert_eq!(m.node_sets.get(name), Some(v), "node set {name}");
        }
        for (name, v) in &src.element_sets {
            assert_eq!(m.element_sets.get(name), Some(v), "element set {name}");
        }
    }
    for (name, f) in &src.face_sets {
        assert_eq!(
            a.face_sets.get(name).map(|x| x.len()),
            Some(f.len()),
            "face set {name}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Meshless on a Gmsh mesh: its vertices are the nodes, its tets the integration cells, and its
/// physical groups select the constrained nodes (41 on each face).
#[test]
fn meshless_on_a_gmsh_mesh_with_physical_groups() {
    let sc = hytled::scene::load(
        &path("cases/cylinder-compression.toml"),
        &[
            "geometry={ mesh = \"../tests/data/msh/cyl_v41.msh\" }".into(),
            "discretization.method=meshless".into(),
            "discretization.tet_rule=1".into(),
            "boundaries.bottom.select={ set = \"bottom\" }".into(),
            "boundaries.top.select={ set = \"top\" }".into(),
            "solver.mode=relaxation".into(),
        ],
    )
    .unwrap();
    let prep = hytled::simulation::prepare(&sc).unwrap();
    assert_eq!(prep.model.nodes().len(), 196);
    for b in prep.model.boundaries() {
        assert_eq!(b.nodes.len(), 41, "{}", b.name);
    }
    let s = hytled::simulation::run_scene(&sc, &Default::default()).unwrap();
    let f = s.reactions["top"][2];
    println!(
        "meshless Gmsh cylinder: F_z = {f} N, error {:.2} %",
        100.0 * rel_err(&s, "force")
    );
    assert!(s.converged && f < 0.0 && (s.reactions["bottom"][2] + f).abs() < 1e-3 * f.abs());
    // A mesh file has no exact shape volume to compare the weights with (it printed NaN).
    let m = s.meshless.as_ref().unwrap();
    assert!(m.exact_volume.is_none());
    assert!(m.cloud.contains("cyl_v41.msh"), "{}", m.cloud);
    let table = s.table();
    assert!(
        !table.contains("NaN") && !table.contains("exact volume"),
        "{table}"
    );
}

#[test]
fn duplicate_nodes_are_reported_and_merged_on_request() {
    let dir = std::env::temp_dir().join(format!("hytled-dups-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Two tets sharing a face whose nodes are written twice (a disconnected mesh).
    let inp = "*NODE\n1, 0, 0, 0\n2, 0.1, 0, 0\n3, 0, 0.1, 0\n4, 0, 0, 0.1\n5, 0.1, 0, 0\n6, 0, 0.1, 0\n7, 0, 0, 0.1\n8, 0.1, 0.1, 0.1\n\
*ELEMENT, TYPE=C3D4\n1, 1, 2, 3, 4\n2, 5, 6, 7, 8\n";
    let file = dir.join("dups.inp");
    std::fs::write(&file, inp).unwrap();
    let text = format!(
        "[geometry]\nmesh = \"{}\"\n[discretization]\nelement = \"tet4\"\n[material]\nyoungs_modulus = 3000.0\npoisson_ratio = 0.3\ndensity = 1000.0\n",
        file.display()
    );
    let prep = |extra: &[String]| {
        let sc = hytled::scene::parse(&text, &dir.join("s.toml"), extra).unwrap();
        hytled::simulation::prepare(&sc).unwrap()
    };
    let a = prep(&[]);
    assert!(
        a.warnings.iter().any(|w| w.contains("3 duplicate node")),
        "{:?}",
        a.warnings
    );
    assert_eq!(a.model.nodes().len(), 8);
    let b = prep(&["geometry.merge_duplicates=true".into()]);
    assert!(
        b.warnings.iter().any(|w| w.contains("merged 3 duplicate")),
        "{:?}",
        b.warnings
    );
    assert_eq!(b.model.nodes().len(), 5);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Files `hytled mesh` writes in the default encoding read back (vtkio) with the same nodes.
#[test]
fn default_vtu_output_reads_back() {
    let dir = std::env::temp_dir().join(format!("hytled-default-vtu-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("cyl.vtu");
    let ok = std::process::Command::new(env!("CARGO_BIN_EXE_hytled"))
        .args([
            "mesh",
            path("cases/cylinder-compression.toml").to_str().unwrap(),
        ])
        .args([
            "--set",
            "discretization.divisions=[4,2,8]",
            "--out",
            file.to_str().unwrap(),
        ])
        .status()
        .unwrap()
        .success();
    assert!(ok);
    let back = hytled::io::mesh_file::read_mesh(&file, None, 1.0).unwrap();
    let inp =
        hytled::io::mesh_file::read_mesh(&path("meshes/cylinder-428-hex8.inp"), None, 1.0).unwrap();
    assert_eq!(back.mesh.nodes, inp.mesh.nodes);
    assert_eq!(back.mesh.cells, inp.mesh.cells);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Legacy VTK 5.1 (OFFSETS/CONNECTIVITY cells, what VTK 9 and ParaView write) reads like 4.2.
#[test]
fn legacy_vtk_5_1_reads_like_4_2() {
    use hytled::io::mesh_file::read_mesh;
    let a = read_mesh(&path("tests/data/vtk/cyl.vtk"), None, 1.0).unwrap();
    let b = read_mesh(&path("tests/data/vtk/cyl_v51.vtk"), None, 1.0).unwrap();
    assert_eq!(a.mesh.nodes, b.mesh.nodes);
    assert_eq!(a.mesh.cells, b.mesh.cells);
    assert_eq!(a.element_sets, b.element_sets);
    assert_eq!(a.face_sets, b.face_sets);
    assert_eq!(b.mesh.num_cells(), 617);
}

/// Raw-appended VTU (hytled's earlier default; ParaView's default data mode) reads back.
#[test]
fn raw_appended_vtu_reads_back() {
    use hytled::io::mesh_file::read_mesh;
    let m = read_mesh(&path("meshes/cylinder-compression-hex8.vtu"), None, 1.0).unwrap();
    let sc = hytled::scene::load(&path("cases/cylinder-compression.toml"), &[]).unwrap();
    let builtin = hytled::simulation::build_mesh(&sc).unwrap();
    assert_eq!(m.mesh.nodes, builtin.nodes);
    assert_eq!(m.mesh.cells, builtin.cells);
    let t = read_mesh(&path("meshes/cylinder-coarse-tet4.vtu"), None, 1.0).unwrap();
    assert_eq!(t.mesh.num_cells(), 2304);
}

/// meshio's binary outputs: legacy VTK 5.1 BINARY and zlib-compressed VTU (UInt32 and UInt64
/// headers) read as the ASCII files of the same mesh, sets included.
#[test]
fn meshio_binary_vtk_5_1_and_zlib_vtu_read_like_ascii() {
    use hytled::io::mesh_file::read_mesh;
    let read = |f: &str| read_mesh(&path(&format!("tests/data/vtk/{f}")), None, 1.0).unwrap();
    let ascii = read("cyl_v51.vtk");
    for f in ["cyl_v51_bin.vtk", "cyl_zlib.vtu"] {
        let b = read(f);
        assert_eq!(b.mesh.nodes, ascii.mesh.nodes, "{f}");
        assert_eq!(b.mesh.cells, ascii.mesh.cells, "{f}");
        assert_eq!(b.element_sets, ascii.element_sets, "{f}");
        assert_eq!(b.face_sets, ascii.face_sets, "{f}");
    }
    let box42 = read("box_hex_bin.vtk");
    for f in ["box_hex_v51_bin.vtk", "box_hex_zlib_u64.vtu"] {
        let b = read(f);
        assert_eq!(b.mesh.nodes, box42.mesh.nodes, "{f}");
        assert_eq!(b.mesh.cells, box42.mesh.cells, "{f}");
        assert_eq!(b.element_sets, box42.element_sets, "{f}");
        // The integer point array `fixed` (1 on z = 0) is a node set.
        let fixed = &b.node_sets["fixed"];
        assert_eq!(fixed.len(), 20, "{f}");
        assert!(fixed.iter().all(|&i| b.mesh.nodes[i].z == 0.0), "{f}");
    }
}

/// meshio names sets "gmsh:physical=2"; ABAQUS cannot carry '=' in a name, so converting to
/// .inp renames them (with a message) instead of failing, and the sets survive the round trip.
#[test]
fn set_names_that_abaqus_cannot_carry_are_renamed_for_inp() {
    use hytled::io::mesh_file::{inp_safe_set_names, read_mesh, write_mesh_file};
    let mut m = read_mesh(
        std::path::Path::new("tests/data/vtk/cyl_zlib.vtu"),
        None,
        1.0,
    )
    .unwrap();
    let faces = m.face_sets.len();
    let msgs = inp_safe_set_names(&mut m);
    assert!(
        !msgs.is_empty() && msgs.iter().all(|s| s.contains("renamed")),
        "{msgs:?}"
    );
    let out = std::env::temp_dir().join("hytled-renamed-sets.inp");
    write_mesh_file(&out, &m, hytled::io::vtu::VtuFormat::Binary).unwrap();
    let back = read_mesh(&out, None, 1.0).unwrap();
    assert_eq!(back.mesh.nodes.len(), m.mesh.nodes.len());
    assert_eq!(back.mesh.cells, m.mesh.cells);
    assert_eq!(back.face_sets.len(), faces);
    assert!(back
        .face_sets
        .keys()
        .any(|k| k.eq_ignore_ascii_case("gmsh:physical_2")));
}

/// Issue 41: a mesh file in millimetres read without `units` is a body of tens of metres; the
/// preparation says so and how to fix it (here the metre mesh of the cylinder case scaled by
/// 1000, the same numbers), and the metre mesh itself gets no such warning.
#[test]
fn a_body_of_tens_of_metres_from_a_mesh_file_is_questioned() {
    let case = path("cases/tet-cylinder-compression.toml");
    let warned = |set: &[&str]| {
        let o: Vec<String> = set.iter().map(|s| s.to_string()).collect();
        let scene = hytled::scene::load(&case, &o).unwrap();
        let prep = hytled::simulation::prepare(&scene).unwrap();
        prep.warnings
            .iter()
            .any(|w| w.contains("spans") && w.contains("geometry.units = 0.001"))
    };
    assert!(warned(&["geometry.units=1000"]));
    assert!(!warned(&[]));
}
