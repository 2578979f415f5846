//! Issue 42, labelled images in: `[geometry] image` (NIfTI-1, NRRD) with the image's
//! orientation and spacing honoured, its labels as the body (voxels or an extracted surface),
//! label-0 holes kept, and `[regions] labels`. A voxel-aligned labelled box reproduces the
//! exact cube (docs/reference.md); an oblique copy of the image gives the same answer rotated.

mod common;
use common::{path, warnings_with};

use std::path::{Path, PathBuf};

use hytled::io::image::{write_image, Image};
use hytled::material::{uniaxial_stretch, NeoHookean};
use hytled::report::Summary;
use hytled::simulation::{run_scene, RunOptions};
use nalgebra::{Matrix3, Matrix4, Rotation3, Unit, Vector3};

fn folder(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hytled-images-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `n`^3 voxels of `s` m, label `label` on the voxels `pad..n - pad` along each axis, the
/// others 0; voxel (i, j, k) centred at `map` applied to (i, j, k).
fn labelled_box(n: usize, pad: usize, label: f64, map: Matrix4<f64>) -> Image {
    let mut im = Image::filled([n, n, n], map, 0.0);
    for k in pad..n - pad {
        for j in pad..n - pad {
            for i in pad..n - pad {
                let v = im.index(i, j, k);
                im.values[v] = label;
            }
        }
    }
    im
}

/// Index to world: voxels of `s` m along the axes, voxel `pad` centred at s / 2 (so the
/// labelled box spans [0, (n - 2 pad) s]).
fn aligned(s: f64, pad: usize) -> Matrix4<f64> {
    let mut m = Matrix4::identity() * s;
    m[(3, 3)] = 1.0;
    for a in 0..3 {
        m[(a, 3)] = (0.5 - pad as f64) * s;
    }
    m
}

/// Volume of a tet mesh, m^3.
fn tet_volume(mesh: &hytled::geometry::Mesh) -> f64 {
    (0..mesh.num_cells())
        .map(|e| {
            let c = mesh.cell(e);
            let x: Vec<Vector3<f64>> = c.iter().map(|&i| mesh.nodes[i]).collect();
            (x[1] - x[0])
                .cross(&(x[2] - x[0]))
                .dot(&(x[3] - x[0]))
                .abs()
                / 6.0
        })
        .sum()
}

fn cube_run(file: &Path, extra: &[&str]) -> hytled::Result<Summary> {
    let mut o: Vec<String> = vec![
        format!(
            "geometry={{ image = \"{}\", body = \"voxels\" }}",
            file.display()
        ),
        "discretization.element=hex8".into(),
        "discretization.size=0.0125".into(),
        "references={}".into(),
        "solver.tolerance=1e-9".into(),
    ];
    o.extend(extra.iter().map(|s| s.to_string()));
    let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o)?;
    run_scene(&sc, &RunOptions::default())
}

fn cube_errors(s: &Summary) -> (f64, f64) {
    let m = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let (a, _, sigma) = uniaxial_stretch(&m, 0.8);
    let f = sigma * (a * 0.1).powi(2);
    let u = (a - 1.0) * 0.1;
    (
        (s.reactions["top"][2] - f).abs() / f.abs(),
        (s.probes["corner"].displacement[0] - u).abs() / u,
    )
}

/// The 0.1 m cube as label 3 in 12.5 mm voxels (NIfTI and NRRD): its voxels as hexahedra
/// reproduce the exact solution with fe (hex8) and meshless on their corners.
#[test]
fn a_voxel_aligned_labelled_box_reproduces_the_exact_cube() {
    let dir = folder("cube");
    let im = labelled_box(12, 2, 3.0, aligned(0.0125, 2));
    for name in ["cube.nii.gz", "cube.nrrd"] {
        let file = dir.join(name);
        write_image(&file, &im).unwrap();
        for (method, tol_f, tol_u) in [
            ("discretization.method=fe", 1e-6, 1e-5),
            ("discretization.method=meshless", 2e-3, 5e-3),
        ] {
            if name.ends_with("nrrd") && method.ends_with("meshless") {
                continue;
            }
            let s = cube_run(&file, &[method, "geometry.labels=[3]"])
                .unwrap_or_else(|e| panic!("{name} {method}: {e}"));
            let (ef, eu) = cube_errors(&s);
            println!(
                "{name} {method}: nodes {}, force {ef:.2e}, lateral {eu:.2e}",
                s.nodes
            );
            assert_eq!(s.nodes, 729, "{name}: 8^3 voxels make 9^3 nodes");
            assert!(ef < tol_f && eu < tol_u, "{name} {method}: {ef:e} {eu:e}");
        }
    }
    // A label the image lacks is an error naming it.
    let file = dir.join("cube.nii.gz");
    let e = cube_run(&file, &["geometry.labels=[7]"])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cube.nii.gz") && e.contains("label(s) [7]"),
        "{e}"
    );
}

/// The same voxels under an oblique (rotated, anisotropic-free) map: the body, the tied
/// spheres, gravity and the probe rotated with it give the aligned answer rotated.
#[test]
fn an_oblique_image_gives_the_same_answer_rotated() {
    let dir = folder("oblique");
    let s = 0.0125;
    let r = Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)), 0.7);
    let t = Vector3::new(0.02, -0.03, 0.05);
    let a = aligned(s, 2);
    let mut rot = Matrix4::identity();
    rot.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    rot.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
    let place = |x: Vector3<f64>| r * x + t;
    let run = |map: Matrix4<f64>, f: &dyn Fn(Vector3<f64>) -> Vector3<f64>, dir_g: Matrix3<f64>| {
        let file = dir.join(format!("b{}.nii", map[(0, 1)].abs() > 0.0));
        write_image(&file, &labelled_box(12, 2, 1.0, map)).unwrap();
        let v = |x: Vector3<f64>| format!("[{:.17e}, {:.17e}, {:.17e}]", x.x, x.y, x.z);
        let g = dir_g * Vector3::new(0.0, 0.0, -9.81);
        let mut o = vec![
            format!(
                "geometry={{ image = \"{}\", body = \"voxels\" }}",
                file.display()
            ),
            "discretization.element=hex8".into(),
            "discretization.size=0.0125".into(),
            "references={}".into(),
            "boundaries={}".into(),
            "solver.tolerance=1e-10".into(),
            "material.youngs_modulus=300000.0".into(),
            format!("loads.g={{ gravity = {} }}", v(g)),
            format!(
                "probes.corner={{ position = {} }}",
                v(f(Vector3::new(0.1, 0.1, 0.1)))
            ),
        ];
        for (k, c) in [[0.0, 0.0], [0.1, 0.0], [0.0, 0.1], [0.1, 0.1]]
            .iter()
            .enumerate()
        {
            let centre = f(Vector3::new(c[0], c[1], 0.0));
            o.push(format!(
                "boundaries.tie{k}={{ select = {{ sphere = {{ center = {}, radius = 0.02 }} }}, fix = [\"x\", \"y\", \"z\"] }}",
                v(centre)
            ));
        }
        let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
        run_scene(&sc, &RunOptions::default()).unwrap()
    };
    let base = run(a, &|x| x, Matrix3::identity());
    let turned = run(rot * a, &place, *r.matrix());
    let ua = Vector3::from(base.probes["corner"].displacement);
    let ub = Vector3::from(turned.probes["corner"].displacement);
    let diff = (ub - r * ua).norm() / ua.norm();
    println!(
        "aligned {ua:?} ({}, {} steps), oblique {ub:?} ({}, {} steps), rotated difference {diff:.2e}",
        base.status, base.steps, turned.status, turned.steps
    );
    assert_eq!(base.nodes, turned.nodes);
    assert!(ua.norm() > 1e-4, "the cube sags: {ua}");
    assert!(diff < 1e-6, "{diff:e}");
}

/// A labelled ball with a label-0 cavity and a second label inside: the surface body (TetGen,
/// tet4-anp) keeps the cavity as a hole, its volume is the labelled volume within the
/// voxel resolution, and `[regions] labels` gives the inner label its own material.
#[test]
fn a_labelled_ball_with_a_cavity_and_a_region() {
    let dir = folder("ball");
    let (n, s) = (28usize, 0.0025);
    let c = (n as f64 - 1.0) / 2.0;
    let mut im = Image::filled([n, n, n], aligned(s, 0), 0.0);
    let (mut tissue, mut cavity) = (0usize, 0usize);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let d = Vector3::new(i as f64 - c, j as f64 - c, k as f64 - c);
                let v = im.index(i, j, k);
                // Ball of radius 12 voxels, a cavity of radius 4 off-centre along x, a harder
                // label-2 ball of radius 3 on the other side.
                if d.norm() <= 12.0 {
                    let cav = (d - Vector3::new(5.0, 0.0, 0.0)).norm() <= 4.0;
                    let hard = (d + Vector3::new(6.0, 0.0, 0.0)).norm() <= 3.0;
                    im.values[v] = if cav {
                        0.0
                    } else if hard {
                        2.0
                    } else {
                        1.0
                    };
                    if cav {
                        cavity += 1
                    } else {
                        tissue += 1
                    }
                }
            }
        }
    }
    let file = dir.join("ball.nii.gz");
    write_image(&file, &im).unwrap();
    let labelled = tissue as f64 * s.powi(3);
    let centre = Vector3::repeat(c * s);
    let o = vec![
        format!("geometry={{ image = \"{}\" }}", file.display()),
        "discretization={ method = \"fe\", size = 0.005 }".into(),
        "references={}".into(),
        "boundaries={}".into(),
        "probes={}".into(),
        format!(
            "boundaries.base={{ select = {{ box = {{ min = [0.0, 0.0, 0.0], max = [1.0, 1.0, {:.6}] }} }}, fix = [\"x\", \"y\", \"z\"] }}",
            centre.z - 0.022
        ),
        "loads.g={ gravity = [0.0, 0.0, -9.81] }".into(),
        "regions.hard={ labels = [2], youngs_modulus = 30000.0 }".into(),
        "material.youngs_modulus=30000.0".into(),
        "solver.mass_scaling=true".into(),
        "solver.tolerance=1e-8".into(),
    ];
    let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
    let prep = hytled::simulation::prepare(&sc).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(prep.kind.name(), "tet4-anp");
    let volume = tet_volume(&prep.mesh);
    // No node in the cavity (it is a hole, not filled).
    let cav_centre = centre + Vector3::new(5.0 * s, 0.0, 0.0);
    let nearest = prep
        .mesh
        .nodes
        .iter()
        .map(|x| (x - cav_centre).norm())
        .fold(f64::INFINITY, f64::min);
    let rel = (volume - labelled).abs() / labelled;
    println!(
        "ball: {} nodes, volume {volume:.4e} m^3 vs labelled {labelled:.4e} ({rel:.2e}), cavity voxels {cavity}, nearest node to the cavity's centre {nearest:.3e} m, regions {:?}",
        prep.mesh.nodes.len(),
        prep.regions
    );
    // The cavity (radius 4 voxels, 10 mm) is a hole: no node near its centre.
    assert!(nearest > 2.5 * s, "{nearest:e}");
    // The surface nets and smoothing move the boundary by a fraction of a voxel: the volume
    // within a half-voxel shell's share (4 pi r^2 s / 2 over 4/3 pi r^3 = 1.5 s / r = 12.5 %
    // at r = 12 voxels; the cavity adds its own).
    assert!(rel < 0.06, "{rel:e}");
    let hard = prep
        .regions
        .iter()
        .find(|r| r.name == "hard")
        .map(|r| r.points);
    assert!(hard.is_some_and(|n| n > 0), "{:?}", prep.regions);
    let out = run_scene(&sc, &RunOptions::default()).unwrap();
    println!(
        "ball under gravity: steps {}, status {}",
        out.steps, out.status
    );
    assert_eq!(out.status, "converged");
}

/// Images out: the exact cube (fe hex8) with `output.image` a smooth synthetic image. The
/// written field is the pull-back d(x) = F^-1 x - x inside the deformed cube (to the solver's
/// tolerance) and zero outside; its file holds LPS millimetre components (d_x < 0 in RAS, so
/// positive in LPS; d_z > 0 in both); the warped image matches the analytic warp I(F^-1 x)
/// within trilinear interpolation's error bound (s^2 / 8 times the second derivatives).
#[test]
fn the_exact_cube_warps_a_synthetic_image_as_the_analytic_warp() {
    use nifti::{IntoNdArray, NiftiObject};
    let dir = folder("warp");
    let s = 0.0025;
    let n = 57;
    let mut map = Matrix4::identity() * s;
    map[(3, 3)] = 1.0;
    for a in 0..3 {
        map[(a, 3)] = -0.01;
    }
    let field = |x: &Vector3<f64>| (40.0 * x.x).sin() * (30.0 * x.y).cos() + 10.0 * x.z;
    // |d2I/dx2| <= 1600, |d2I/dy2| <= 900, d2I/dz2 = 0.
    let bound = s * s / 8.0 * (1600.0 + 900.0);
    let mut im = Image::filled([n, n, n], map, 0.0);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let x = im.world(&Vector3::new(i as f64, j as f64, k as f64));
                let v = im.index(i, j, k);
                im.values[v] = field(&x);
            }
        }
    }
    let file = dir.join("t1.nii.gz");
    write_image(&file, &im).unwrap();
    let out = dir.join("out");
    let o = vec![
        format!("output.image=\"{}\"", file.display()),
        "solver.tolerance=1e-9".into(),
    ];
    let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
    let opts = RunOptions {
        out: Some(out.clone()),
        ..RunOptions::default()
    };
    let summary = run_scene(&sc, &opts).unwrap();
    assert_eq!(summary.status, "converged");
    let m = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
    let (a, _, _) = uniaxial_stretch(&m, 0.8);
    let finv = Matrix3::from_diagonal(&Vector3::new(1.0 / a, 1.0 / a, 1.0 / 0.8));
    let d = nifti::ReaderOptions::new()
        .read_file(out.join("cube-compression_displacement.nii.gz"))
        .unwrap();
    assert_eq!(d.header().intent_code, 1007);
    let d = d.into_volume().into_ndarray::<f64>().unwrap();
    let w = hytled::io::image::read_image(&out.join("cube-compression_warped.nii.gz")).unwrap();
    let (mut inside, mut worst_d, mut worst_i) = (0usize, 0.0f64, 0.0f64);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let x = im.world(&Vector3::new(i as f64, j as f64, k as f64));
                let back = finv * x;
                // LPS millimetres in the file, RAS metres here.
                let lps = Vector3::new(d[[i, j, k, 0, 0]], d[[i, j, k, 0, 1]], d[[i, j, k, 0, 2]]);
                let got = Vector3::new(-lps.x, -lps.y, lps.z) * 1e-3;
                let v = im.index(i, j, k);
                let margin = 1e-6;
                if back.iter().all(|&c| (margin..=0.1 - margin).contains(&c)) {
                    inside += 1;
                    worst_d = worst_d.max((got - (back - x)).norm());
                    worst_i = worst_i.max((w.values[v] - field(&back)).abs());
                    if x.x > 0.01 {
                        assert!(lps.x > 0.0, "d_x in LPS at {x}: {lps}");
                    }
                    if x.z > 0.01 {
                        assert!(lps.z > 0.0, "d_z at {x}: {lps}");
                    }
                } else if back.iter().any(|&c| !(-margin..=0.1 + margin).contains(&c)) {
                    assert_eq!(got, Vector3::zeros(), "outside at {x}");
                    assert!((w.values[v] - im.values[v]).abs() < 1e-6, "outside at {x}");
                }
            }
        }
    }
    println!(
        "warp: {inside} voxels inside the deformed cube, largest field error {worst_d:.3e} m, \
         largest image error {worst_i:.3e} (trilinear bound {bound:.3e}, f32 storage)"
    );
    assert!(inside > 20_000, "{inside}");
    assert!(worst_d < 1e-7, "{worst_d:e}");
    assert!(worst_i < bound + 1e-5, "{worst_i:e} vs {bound:e}");
}

/// A rigid closed surface around the tissue (`inside = true`, a skull): the 0.1 m cube on
/// symmetry planes x = 0, y = 0, hanging 1 mm above the floor of a closed box surface (STL,
/// and a larger labelled box extracted from an image, its floor on the cube's base, moved out
/// by `offset`), falls onto it under gravity. The floor carries the weight (rho V g = 9.81 N), and the answer is the analytic
/// plane's at the same height.
#[test]
fn the_tissue_rests_inside_a_rigid_closed_surface() {
    let dir = folder("skull");
    let skull = dir.join("skull.stl");
    let gap = 0.001;
    std::fs::write(
        &skull,
        common::ascii_stl(
            &common::box_corners([-0.05, -0.05, -gap], [0.15, 0.15, 0.15]),
            &common::box_triangles(),
        ),
    )
    .unwrap();
    // A labelled box in 5 mm voxels whose floor lies at z = 0 on a block boundary (blocks of
    // 3 voxels, from z = -0.06 m): its surface, moved out by the gap, is the skull.
    let labels = dir.join("labels.nii.gz");
    let mut map = Matrix4::identity() * 0.005;
    map[(3, 3)] = 1.0;
    for a in 0..3 {
        map[(a, 3)] = -0.06 + 0.0025;
    }
    let mut im = Image::filled([48, 48, 48], map, 0.0);
    for k in 0..48 {
        for j in 0..48 {
            for i in 0..48 {
                let x = im.world(&Vector3::new(i as f64, j as f64, k as f64));
                if x.z > 0.0
                    && x.z < 0.165
                    && (-0.045..0.165).contains(&x.x)
                    && (-0.045..0.165).contains(&x.y)
                {
                    let v = im.index(i, j, k);
                    im.values[v] = 1.0;
                }
            }
        }
    }
    write_image(&labels, &im).unwrap();
    let scene = dir.join("hanging-cube.toml");
    std::fs::write(
        &scene,
        r#"
name = "hanging-cube"
[geometry]
shape = "box"
min = [0.0, 0.0, 0.0]
max = [0.1, 0.1, 0.1]
[discretization]
method = "fe"
element = "hex8"
size = 0.0125
[material]
model = "neo-hookean"
youngs_modulus = 30000.0
poisson_ratio = 0.49
density = 1000.0
[boundaries.symmetry_x]
select = { plane = { axis = "x", value = 0.0 } }
fix = ["x"]
[boundaries.symmetry_y]
select = { plane = { axis = "y", value = 0.0 } }
fix = ["y"]
[loads.g]
gravity = [0.0, 0.0, -9.81]
[solver]
mode = "relaxation"
tolerance = 1e-10
[probes.base_centre]
position = [0.05, 0.05, 0.0]
"#,
    )
    .unwrap();
    let base = |extra: &[String]| {
        let sc = hytled::scene::load(&scene, extra).unwrap();
        run_scene(&sc, &RunOptions::default()).unwrap_or_else(|e| panic!("{extra:?}: {e}"))
    };
    let plane = base(&[format!(
        "contact.floor={{ shape = \"plane\", point = [0.0, 0.0, {}], normal = [0.0, 0.0, 1.0] }}",
        -gap
    )]);
    let stl = base(&[format!(
        "contact.floor={{ shape = \"surface\", file = \"{}\", inside = true }}",
        skull.display()
    )]);
    let image = base(&[
        format!(
            "contact.floor={{ shape = \"surface\", file = \"{}\", labels = [1], offset = {gap}, inside = true }}",
            labels.display()
        ),
    ]);
    let weight = 1000.0 * 1e-3 * 9.81;
    for (what, s) in [("plane", &plane), ("stl", &stl), ("image", &image)] {
        let f = s.reactions["floor"];
        let u = s.probes["base_centre"].displacement;
        println!(
            "{what}: floor reaction {:?} N, base centre u_z {:.6e} m, {} steps, {}",
            f, u[2], s.steps, s.status
        );
        assert_eq!(s.status, "converged", "{what}");
        assert!((f[2] - weight).abs() < 1e-6 * weight, "{what}: {f:?}");
        let du = (u[2] - plane.probes["base_centre"].displacement[2]).abs();
        // The STL floor is the plane; the image's floor is flat only to the Taubin smoothing's
        // reach from the rounded walls (within 5.6e-5 m of z = 0 under the cube, measured on
        // this image: 1 % of the gap holds it).
        let (tol_u, tol_lateral) = if what == "image" {
            (0.01 * gap, 0.01)
        } else {
            (1e-9, 1e-9)
        };
        assert!(du < tol_u, "{what}: {du:e}");
        assert!(
            f[0].abs().max(f[1].abs()) < tol_lateral * weight,
            "{what}: {f:?}"
        );
    }
}

/// The MNI case (cases/mni-brain-shift.toml) prepares: the labelmap's brain with its
/// ventricles as cavities (no node near their centre), the white matter and tumour regions,
/// the craniotomy measurements on surface nodes, the skull around the brain.
#[test]
fn the_mni_case_prepares() {
    let sc = hytled::scene::load(&path("cases/mni-brain-shift.toml"), &[]).unwrap();
    let prep = hytled::simulation::prepare(&sc).unwrap_or_else(|e| panic!("{e}"));
    let nodes = prep.mesh.nodes.len();
    let regions: std::collections::BTreeMap<_, _> = prep
        .regions
        .iter()
        .map(|r| (r.name.clone(), r.points))
        .collect();
    println!(
        "mni: {nodes} nodes, {} tets, regions {regions:?}",
        prep.mesh.num_cells()
    );
    assert!((8_000..20_000).contains(&nodes), "{nodes}");
    assert!(
        regions["white_matter"] > 10_000 && regions["tumour"] > 10,
        "{regions:?}"
    );
    // The mesh's volume is the labelled brain's less the ventricles (scripts/make_mni_case.py:
    // 1731.2 cm^3), within the surface's block resolution.
    let volume = tet_volume(&prep.mesh);
    println!("mni: volume {:.1} cm^3", volume * 1e6);
    assert!((volume * 1e6 - 1731.2).abs() < 0.03 * 1731.2, "{volume}");
}

/// The whole MNI case (about 30 s on 2 cores, at 5e-7 m): converged, the weight carried by the skull,
/// the craniotomy and the brainstem, the tumour displaced, the warped T1 written.
/// `cargo test --release --test images -- --ignored mni_case_runs`.
#[test]
#[ignore]
fn the_mni_case_runs() {
    let dir = folder("mni");
    let sc = hytled::scene::load(&path("cases/mni-brain-shift.toml"), &[]).unwrap();
    let opts = RunOptions {
        out: Some(dir.clone()),
        ..RunOptions::default()
    };
    let s = run_scene(&sc, &opts).unwrap();
    let total: f64 = ["skull", "craniotomy", "brainstem"]
        .iter()
        .map(|b| s.reactions[*b][2])
        .sum();
    let u = Vector3::from(s.probes["tumour_centre"].displacement);
    println!(
        "mni: {} steps, {}, {:.1} s, reactions carry {total:.4} N, tumour {u:?} m",
        s.steps, s.status, s.wall_seconds.total
    );
    assert_eq!(s.status, "converged");
    // Settled at 5e-7 m (issue 57; 1,389 steps): the reactions carry the weight to 1e-4
    // (measured 3e-7), and nothing sideways.
    assert!((total - s.loads["gravity"][2].abs()).abs() < 1e-4 * total);
    let lateral: f64 = ["skull", "craniotomy", "brainstem"]
        .iter()
        .map(|b| s.reactions[*b][0])
        .sum();
    assert!(lateral.abs() < 1e-4 * total, "{lateral}");
    assert!(u.norm() > 1e-3);
    assert!(dir.join("mni-brain-shift_warped.nii.gz").is_file());
}

/// Issue 57: the MNI case in the static solve (about 100 s on 2 cores). From the unloaded
/// state: the brain settles into its skull, its reactions those of relaxation and summing to
/// the weight (the solve stopped at 0.78 % of gravity before contact's stall window and
/// inverting predictors were handled). Warm, from a relaxation at a 100 x looser tolerance:
/// one load step, with the contact forces of that state estimated from its residual (without
/// them its first tangent had no contact, the brain fell through the skull in the predictor,
/// and the solve went back to the unloaded state).
/// `cargo test --release --test images -- --ignored mni_case_settles_statically`.
#[test]
#[ignore]
fn the_mni_case_settles_statically() {
    let bodies = ["skull", "craniotomy", "brainstem"];
    let reactions =
        |s: &Summary| -> Vec<[f64; 3]> { bodies.iter().map(|b| s.reactions[*b]).collect() };
    let load = |mode: &str| {
        hytled::scene::load(
            &path("cases/mni-brain-shift.toml"),
            &[format!("solver.mode={mode}"), "output={}".into()],
        )
        .unwrap()
    };
    let rx = run_scene(&load("relaxation"), &RunOptions::default()).unwrap();
    // Newton's load steps from the unloaded state (the relaxed start is below).
    let cold = hytled::scene::load(
        &path("cases/mni-brain-shift.toml"),
        &[
            "solver.mode=static".into(),
            "solver.relaxed_start=false".into(),
            "output={}".into(),
        ],
    )
    .unwrap();
    let st = run_scene(&cold, &RunOptions::default()).unwrap();
    let weight = st.loads["gravity"][2].abs();
    let worst = |a: &Summary, b: &Summary| {
        reactions(a)
            .iter()
            .zip(reactions(b))
            .flat_map(|(x, y)| (0..3).map(move |k| (x[k] - y[k]).abs()))
            .fold(0.0f64, f64::max)
    };
    let total: f64 = reactions(&st).iter().map(|r| r[2]).sum();
    let s = st.statics.as_ref().unwrap();
    println!(
        "mni static: {} load steps, {} Newton iterations, {} factorizations, {:.1} s; \
         relaxation {:.1} s; reactions {:?} against {:?}, largest difference {:.2e} N of a \
         weight of {weight:.4} N, sum {total:.6} N",
        s.load_steps,
        s.newton_iterations,
        s.factorizations,
        st.wall_seconds.total,
        rx.wall_seconds.total,
        reactions(&st),
        reactions(&rx),
        worst(&st, &rx)
    );
    assert!(st.converged && rx.converged);
    // Newton's own answer, not the fallback's relaxation: with CG runs of a kept factor
    // judged at 6 iterations (2026-12-01) the load steps stopped at 99.8 % and relaxed.
    assert!(
        s.fallback_from.is_none(),
        "the load steps stopped at {:?} and relaxed",
        s.fallback_from
    );
    assert!((total - weight).abs() < 1e-6 * weight, "{total} {weight}");
    assert!(worst(&st, &rx) < 1e-4 * weight);

    // The case's default: relaxation to 100 x the tolerance, then the static solve from there
    // (13.3 s against relaxation's 16 s; 1,024 force evaluations against 1,498).
    let rs = run_scene(&load("static"), &RunOptions::default()).unwrap();
    let r = rs.statics.as_ref().unwrap();
    let rs_total: f64 = reactions(&rs).iter().map(|r| r[2]).sum();
    println!(
        "mni relaxed start: {} relaxation steps ({:.1} s), {} Newton iterations, {} \
         factorizations, {} force evaluations against relaxation's {}, {:.1} s, largest \
         difference {:.2e} N",
        r.relaxed_start_steps,
        r.relaxed_start_seconds,
        r.newton_iterations,
        r.factorizations,
        rs.force_evaluations,
        rx.force_evaluations,
        rs.wall_seconds.total,
        worst(&rs, &rx)
    );
    assert!(rs.converged && r.relaxed_start_steps > 0 && r.load_steps == 1);
    assert!(rs.force_evaluations < rx.force_evaluations);
    assert!(
        (rs_total - weight).abs() < 1e-6 * weight,
        "{rs_total} {weight}"
    );
    assert!(worst(&rs, &rx) < 1e-4 * weight);

    let mut session = hytled::simulation::Session::new(load("relaxation")).unwrap();
    let tight = session.settings_mut().tolerance;
    session.settings_mut().mode = hytled::solver::Mode::Relaxation;
    session.settings_mut().tolerance = 100.0 * tight;
    let loose = session.solve().unwrap();
    session.settings_mut().mode = hytled::solver::Mode::Static;
    session.settings_mut().tolerance = tight;
    let warm = session.solve().unwrap();
    let w = warm.summary.statics.as_ref().unwrap();
    let fell_back = warnings_with(&warm.summary, "warm start");
    println!(
        "mni warm static after relaxation at {:.0e} m ({:.1} s): {} Newton iterations, {} \
         factorizations, {:.1} s, largest difference {:.2e} N; {fell_back:?}",
        100.0 * tight,
        loose.summary.wall_seconds.solve,
        w.newton_iterations,
        w.factorizations,
        warm.summary.wall_seconds.solve,
        worst(&warm.summary, &rx)
    );
    assert!(
        warm.warm && warm.summary.converged && fell_back.is_empty(),
        "{fell_back:?}"
    );
    assert_eq!(w.load_steps, 1);
    assert!(worst(&warm.summary, &rx) < 1e-4 * weight);
}

/// Broken or unusable images are refused naming the file and what is wrong; a hexahedral
/// element with the surface body says to use tets or the voxels body.
#[test]
fn broken_images_are_refused_naming_the_file() {
    let dir = folder("broken");
    let truncated = dir.join("truncated.nii");
    std::fs::write(&truncated, b"garbage").unwrap();
    let short = dir.join("short.nrrd");
    std::fs::write(
        &short,
        b"NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n\0\0",
    )
    .unwrap();
    let sizes = dir.join("sizes.nrrd");
    std::fs::write(
        &sizes,
        b"NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2\nencoding: raw\n\n",
    )
    .unwrap();
    let missing = dir.join("missing.nii.gz");
    let run = |file: &Path, element: &str| {
        let o = vec![
            format!("geometry={{ image = \"{}\" }}", file.display()),
            "references={}".into(),
            format!("discretization.element={element}"),
        ];
        let sc = hytled::scene::load(&path("cases/cube-compression.toml"), &o).unwrap();
        run_scene(&sc, &RunOptions::default())
            .unwrap_err()
            .to_string()
    };
    for (file, says) in [
        (&truncated, "truncated"),
        (&short, "32"),
        (&sizes, "sizes must list 3"),
        (&missing, "no such image file"),
    ] {
        let e = run(file, "tet4-anp");
        assert!(
            e.contains(&file.display().to_string()) && e.contains(says),
            "{e}"
        );
    }
    let e = run(&missing, "hex8");
    assert!(e.contains("body = \"voxels\""), "{e}");
}
