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
    for file in ["cylinder-428-hex8.inp", "cylinder-428-hex8-v22.msh", "cylinder-428-hex8-v41.msh"] {
        let g = format!("geometry={{ mesh = \"../meshes/{file}\" }}");
        let s = run_case("cases/cylinder-compression.toml", &[base[0], base[1], g.as_str()]);
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
            Ok(sc) => hytled::simulation::prepare(&sc).err().expect("must fail").to_string(),
        }
    };
    assert!(err("{ mesh = \"../meshes/nothing.inp\" }").contains("nothing.inp"));
    assert!(err("{ mesh = \"../meshes/x.stl\" }").contains("unknown extension"));
    assert!(err("{ mesh = \"../meshes/cylinder-428-hex8.inp\", radius = 1.0 }").contains("radius"));
    assert!(err("{ mesh = \"../meshes/cylinder-428-hex8.inp\", units = -1.0 }").contains("units"));
    // A hexahedral mesh with a tetrahedral element asked for.
    let sc = hytled::scene::load(
        &path("cases/cylinder-compression.toml"),
        &["geometry={ mesh = \"../meshes/cylinder-428-hex8.inp\" }".into(), "discretization.element=tet4-anp".into()],
    )
    .unwrap();
    let e = hytled::simulation::prepare(&sc).err().unwrap().to_string();
    assert!(e.contains("hexahedral") && e.contains("hex8"), "{e}");
    // A set name that does not exist lists the available ones.
    let sc = hytled::scene::load(
        &path("cases/cylinder-compression.toml"),
        &["geometry={ mesh = \"../meshes/cylinder-428-hex8.inp\" }".into(), "boundaries.top.select={ set = \"lid\" }".into()],
    )
    .unwrap();
    let e = hytled::simulation::prepare(&sc).err().unwrap().to_string();
    assert!(e.contains("lid") && e.contains("available"), "{e}");
}
