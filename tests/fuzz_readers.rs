//! Random byte mutations of real sample files fed to every reader, and of the committed scene
//! files (bytes, and values replaced through `--set`) fed to the scene parser: errors are fine,
//! panics are not (proptest; 48 cases per test to keep the suite fast, PROPTEST_CASES raises it).
//! The third-party parsers (vtkio, mshio, stl_io, nifti) run under a last-resort catch with no
//! panic hook, so these tests also fail when a mutated file reaches a parser's panic (the
//! reader's error then says "failed on malformed data"): the readers' own checks must stop it
//! first.

use std::path::{Path, PathBuf};

use proptest::prelude::*;

fn data(rel: &str) -> Vec<u8> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Applies mutations: (position fraction, kind, byte).
fn mutate(mut b: Vec<u8>, edits: &[(f64, u8, u8)]) -> Vec<u8> {
    for &(f, kind, byte) in edits {
        if b.is_empty() {
            break;
        }
        let i = ((f * b.len() as f64) as usize).min(b.len() - 1);
        match kind % 5 {
            0 => b[i] = byte,
            1 => b.truncate(i),
            2 => b.insert(i, byte),
            3 => {
                b.remove(i);
            }
            _ => {
                // Duplicate a chunk (repeated lines and sections).
                let end = (i + 64).min(b.len());
                let chunk = b[i..end].to_vec();
                b.splice(i..i, chunk);
            }
        }
    }
    b
}

/// Fails when a reader's error is a third-party parser's caught panic (`io::guard_parser`).
fn no_parser_panic<T>(r: hytled::Result<T>, what: &str) -> Result<(), TestCaseError> {
    if let Err(e) = r {
        let e = e.to_string();
        prop_assert!(
            !e.contains("failed on malformed data"),
            "{what}: a parser panicked, which the reader's checks must prevent: {e}"
        );
    }
    Ok(())
}

/// A file in the temporary folder, unique to this process and call.
fn scratch(ext: &str) -> PathBuf {
    static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let k = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    std::env::temp_dir().join(format!("hytled-fuzz-{}-{k}.{ext}", std::process::id()))
}

/// A tetrahedron's surface as ASCII and as binary STL.
fn stl_samples() -> [Vec<u8>; 2] {
    let tris = [
        [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
        [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
    ];
    let mut ascii = String::from("solid t\n");
    let mut binary = vec![0u8; 80];
    binary.extend_from_slice(&(tris.len() as u32).to_le_bytes());
    for t in &tris {
        ascii.push_str(" facet normal 0 0 0\n  outer loop\n");
        binary.extend(std::iter::repeat_n(0u8, 12));
        for v in t {
            ascii.push_str(&format!("   vertex {} {} {}\n", v[0], v[1], v[2]));
            v.iter()
                .for_each(|c| binary.extend_from_slice(&c.to_le_bytes()));
        }
        ascii.push_str("  endloop\n endfacet\n");
        binary.extend_from_slice(&[0, 0]);
    }
    ascii.push_str("endsolid t\n");
    [ascii.into_bytes(), binary]
}

/// A 4 x 3 x 2 labelmap written as NIfTI-1 by hytled's writer.
fn nifti_sample() -> &'static [u8] {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES.get_or_init(|| {
        let mut to_world = nalgebra::Matrix4::identity() * 0.002;
        to_world[(3, 3)] = 1.0;
        let mut image = hytled::geometry::image::Image::filled([4, 3, 2], to_world, 0.0);
        image
            .values
            .iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = (i % 3) as f64);
        let p = scratch("nii");
        hytled::io::image::write_image(&p, &image).unwrap();
        let b = std::fs::read(&p).unwrap();
        let _ = std::fs::remove_file(&p);
        b
    })
}

fn edits() -> impl Strategy<Value = Vec<(f64, u8, u8)>> {
    prop::collection::vec((0.0..1.0f64, any::<u8>(), any::<u8>()), 1..8)
}

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: std::env::var("PROPTEST_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(48),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn inp_reader_never_panics(e in edits()) {
        for f in ["meshes/cylinder-428-hex8.inp", "tests/data/inp/gmsh_cube_tet4.inp", "tests/data/inp/abaqus_cae_block_hex8.inp", "tests/data/inp/abaqus_cae_two_instances.inp"] {
            let b = mutate(data(f), &e);
            let _ = hytled::io::inp::parse_inp(&String::from_utf8_lossy(&b), Path::new("fuzz.inp"));
        }
    }

    #[test]
    fn msh_reader_never_panics(e in edits()) {
        for f in ["tests/data/msh/cyl_v22.msh", "tests/data/msh/cyl_v41.msh", "tests/data/msh/cyl_v41_bin.msh"] {
            let b = mutate(data(f), &e);
            no_parser_panic(hytled::io::msh::parse_msh(&b, Path::new("fuzz.msh")), f)?;
        }
    }

    #[test]
    fn cloud_reader_never_panics(e in edits()) {
        let text = "x,y,z,set\n0,0,0,1\n0.1,0,0,1\n0,0.1,0,2\n0,0,0.1,2\n0.05,0.05,0.05,3\n";
        let b = mutate(text.as_bytes().to_vec(), &e);
        let _ = hytled::meshless::cloud::parse_cloud(&String::from_utf8_lossy(&b), Path::new("fuzz.csv"));
    }

    #[test]
    fn stl_reader_never_panics(e in edits()) {
        for (k, sample) in stl_samples().into_iter().enumerate() {
            let p = scratch("stl");
            std::fs::write(&p, mutate(sample, &e)).unwrap();
            let r = hytled::io::surface_file::read_surface(&p, 1.0);
            let _ = std::fs::remove_file(&p);
            no_parser_panic(r, ["ascii stl", "binary stl"][k])?;
        }
    }

    /// The header (the first 352 bytes) mutated: what the nifti crate parses.
    #[test]
    fn nifti_reader_never_panics(e in edits()) {
        let b = nifti_sample().to_vec();
        let (head, data) = b.split_at(352);
        let mut b = mutate(head.to_vec(), &e);
        b.extend_from_slice(data);
        let p = scratch("nii");
        std::fs::write(&p, b).unwrap();
        let r = hytled::io::image::read_image(&p);
        let _ = std::fs::remove_file(&p);
        no_parser_panic(r, "nifti")?;
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn vtk_reader_never_panics(e in edits()) {
        for (f, name) in [("tests/data/vtk/cyl.vtu", "fuzz.vtu"), ("tests/data/vtk/cyl.vtk", "fuzz.vtk"), ("tests/data/vtk/cyl_v51.vtk", "fuzz.vtk"), ("tests/data/vtk/box_hex_b64.vtu", "fuzz.vtu"), ("meshes/cylinder-coarse-tet4.vtu", "fuzz.vtu"), ("tests/data/vtk/box_hex_v51_bin.vtk", "fuzz.vtk"), ("tests/data/vtk/cyl_v51_bin.vtk", "fuzz.vtk"), ("tests/data/vtk/cyl_zlib.vtu", "fuzz.vtu"), ("tests/data/vtk/box_hex_zlib_u64.vtu", "fuzz.vtu"), ("tests/data/vtk/box_hex_meshio_b64.vtu", "fuzz.vtu")] {
            let b = mutate(data(f), &e);
            no_parser_panic(hytled::io::vtk::parse_vtk(&b, Path::new(name)), f)?;
        }
    }
}

proptest! {
    #![proptest_config(config())]

    /// Scene files: byte mutations of every committed case, parsed and validated (the mesh
    /// and the run are left out: their inputs are fuzzed above).
    #[test]
    fn scene_parser_never_panics(e in edits()) {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("cases");
        let mut files: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|f| f.unwrap().path()).collect();
        files.sort();
        for f in files {
            let b = mutate(std::fs::read(&f).unwrap(), &e);
            let _ = hytled::scene::parse(&String::from_utf8_lossy(&b), &f, &[]);
        }
    }
}

/// Dotted paths of every value in a TOML table (array elements excluded).
fn leaf_paths(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
    for (k, v) in t {
        let p = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            toml::Value::Table(sub) => leaf_paths(sub, &p, out),
            _ => out.push(p),
        }
    }
}

const VALUES: &[&str] = &[
    "0",
    "-1",
    "1",
    "2",
    "0.5",
    "-0.5",
    "1e308",
    "-1e308",
    "1e-300",
    "9223372036854775807",
    "-9223372036854775808",
    "nan",
    "inf",
    "true",
    "\"\"",
    "\"x\"",
    "\"all\"",
    "[]",
    "[0]",
    "[1, 2]",
    "[0, 0, 0]",
    "[-1, -1, -1]",
    "[1e308, 1, 1]",
    "[\"x\"]",
    "{}",
    "{ x = 1 }",
    "[[1, 2], [3]]",
    "\"../no/such/file.vtu\"",
];

proptest! {
    #![proptest_config(config())]

    /// Scene values: one to three values of a committed case replaced by odd ones (zero,
    /// negative, huge, NaN, wrong type, empty) through `--set`, parsed and validated.
    #[test]
    fn scene_values_never_panic(picks in prop::collection::vec((any::<prop::sample::Index>(), 0..VALUES.len()), 1..4), case in any::<prop::sample::Index>()) {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("cases");
        let mut files: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|f| f.unwrap().path()).collect();
        files.sort();
        let f = case.get(&files);
        let text = std::fs::read_to_string(f).unwrap();
        let mut paths = Vec::new();
        leaf_paths(&toml::from_str(&text).unwrap(), "", &mut paths);
        let sets: Vec<String> = picks.iter().map(|(i, v)| format!("{}={}", i.get(&paths), VALUES[*v])).collect();
        let _ = hytled::scene::parse(&text, f, &sets);
    }
}
