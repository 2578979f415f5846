//! The pipeline of one run: scene -> mesh -> quadrature points -> model -> solver -> outputs.

use std::path::PathBuf;
use std::time::Instant;

use nalgebra::Vector3;

mod build;
mod build_coupled;
mod build_fe;
mod build_meshless;
mod fields;
mod loads;
mod measured;
mod output;
mod regions;
mod session;
mod summary;
mod surface;
mod translate;

pub use build::Discretization;
use build_coupled::prepare_coupled;
use build_fe::prepare_fe;
use build_meshless::prepare_meshless;
pub use fields::{PointFields, ResultPoints};
pub use output::{
    write_outputs, write_results, BoundaryNodes, CellMaterial, FrameLabels, FrameWriter,
};
pub use session::{Checkpoint, Session, Solution};
pub use summary::{element_label, method_name, summarize};
use surface::Discretized;
pub use translate::{
    build_mesh, load_mesh_input, material, mesh_checks, meshless_settings, settings,
};
use translate::{load_curve, scene_path};

use crate::bc::Boundary;
use crate::coupling::CoupledBuild;
use crate::fe::ElementKind;
use crate::geometry::Mesh;
use crate::io::model::MeshInput;
use crate::io::vtu::VtuFormat;
use crate::material::{Material, Solid};
use crate::meshless::discretize::MeshlessBuild;
use crate::meshless::essential::Imposition;
use crate::probe::Probe;
use crate::report::{Summary, Warning, WarningKind};
use crate::scene::{BcMethod, Component, Geometry, Method, Scene};
use crate::solver::{self, Model, RunOutput};
pub use crate::solver::{Device, Mode, Settings};
use crate::{Error, InputKind, Result};

/// How to run a scene.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Directory for VTU frames, the time-history CSV and summary.json.
    pub out: Option<PathBuf>,
    /// Show a progress bar (on a terminal).
    pub progress: bool,
    /// Print a plain progress line to stderr about every this many seconds (batch jobs and
    /// logs, where a bar cannot draw).
    pub progress_lines: Option<f64>,
    pub vtu_format: VtuFormat,
}

/// Nodes of a selection, with the mesh file's sets available. `what` names it in messages
/// ("boundary 'top'"); an error has the scene key `key` (`boundaries.top.select`) as a fact.
fn select_nodes(
    sel: &crate::geometry::select::Selection,
    nodes: &[Vector3<f64>],
    what: &str,
    key: &str,
    input: Option<&MeshInput>,
) -> Result<Vec<usize>> {
    let lookup = |name: &str| -> std::result::Result<Vec<Vector3<f64>>, String> {
        let m = input.ok_or("no mesh file")?;
        Ok(m.set_nodes(name)?
            .into_iter()
            .map(|i| m.mesh.nodes[i])
            .collect())
    };
    let sets: Option<&crate::geometry::select::SetLookup> = input.map(|_| &lookup as _);
    sel.select_with(nodes, what, sets).map_err(|e| e.key(key))
}

/// The scene's boundaries with their selected nodes, then its measured displacements matched
/// to the nodes `surface()` lists (called only when the scene has some).
pub fn boundaries(
    scene: &Scene,
    nodes: &[Vector3<f64>],
    input: Option<&MeshInput>,
    surface: &dyn Fn() -> Result<Vec<usize>>,
) -> Result<Vec<Boundary>> {
    let mut out = boundaries_only(scene, nodes, input)?;
    if !scene.measured.is_empty() {
        let candidates = surface()?;
        for (name, m) in &scene.measured {
            out.push(measured::boundary(
                scene,
                name,
                m,
                nodes,
                &candidates,
                input,
            )?);
        }
    }
    Ok(out)
}

/// The scene's `[boundaries]` with their selected nodes.
fn boundaries_only(
    scene: &Scene,
    nodes: &[Vector3<f64>],
    input: Option<&MeshInput>,
) -> Result<Vec<Boundary>> {
    let mut out = Vec::new();
    for (name, b) in &scene.boundaries {
        let sel = select_nodes(
            &b.select,
            nodes,
            &format!("boundary '{name}'"),
            &format!("boundaries.{name}.select"),
            input,
        )?;
        let mut comps = [None; 3];
        for c in &b.fix {
            match c {
                Component::X => comps[0] = Some(0.0),
                Component::Y => comps[1] = Some(0.0),
                Component::Z => comps[2] = Some(0.0),
                Component::All => comps = [Some(0.0); 3],
            }
        }
        if let Some(d) = &b.displacement {
            for (k, v) in [d.x, d.y, d.z].into_iter().enumerate() {
                if let Some(v) = v {
                    comps[k] = Some(v);
                }
            }
        }
        out.push(Boundary {
            name: name.clone(),
            nodes: sel,
            components: comps,
            node_values: None,
            curve: load_curve(scene, &b.curve)?,
            measured: None,
        });
    }
    Ok(out)
}

/// A scene turned into a model, ready to run.
pub struct Prepared {
    /// FE mesh (tet10: its linear split over all nodes), the meshless background tets, or the
    /// coupled FE layer: the geometry outputs are written on.
    pub mesh: Mesh,
    /// The method and what it keeps beside the model.
    pub method: Discretization,
    /// Things the user should know that do not stop the run.
    pub warnings: Vec<Warning>,
    pub model: Model<Solid>,
    /// Each quadrature point's material (discretization order: elements, meshless or coupled
    /// points): 0 is `[material]`, k the k-th region; empty without regions.
    pub point_material: Vec<u16>,
    /// Regions and the points each holds.
    pub regions: Vec<RegionPoints>,
    pub probes: Vec<Probe>,
    pub kind: ElementKind,
    /// The smallest dihedral angle of the FE mesh's tets and its element (None without tets).
    pub min_dihedral: Option<MinDihedral>,
    pub preprocess_seconds: f64,
    /// The volume the geometry gives (m^3) and what gives it, for a labelled image (its
    /// labelled voxels) or a surface file (what it encloses): the mesh's volume is compared
    /// with it (`translate::geometry_volume`).
    pub source_volume: Option<SourceVolume>,
}

/// A region and the integration points it holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RegionPoints {
    pub name: String,
    pub points: usize,
}

pub use crate::geometry::quality::MinDihedral;

/// The volume the geometry gives (m^3) and what gives it (a labelled image's voxels, what a
/// surface file encloses).
#[derive(Debug, Clone, PartialEq)]
pub struct SourceVolume {
    pub volume: f64,
    pub of: String,
}

impl Prepared {
    /// The meshless build, for meshless scenes.
    pub fn meshless(&self) -> Option<&MeshlessBuild> {
        self.method.meshless()
    }

    /// The coupled build, for coupled scenes.
    pub fn coupled(&self) -> Option<&CoupledBuild> {
        self.method.coupled()
    }

    /// How essential conditions act on meshless nodes (None for FE, and for coupled scenes
    /// whose conditions hold FE nodes only).
    pub fn bc_method(&self) -> Option<BcMethod> {
        self.method.bc_method()
    }
}

/// The body's mesh: the mesh file's (its reader's warnings and the duplicate-node check go to
/// `warnings`) or the built-in shape's; refused before its points are built when their model
/// would not fit in memory ([`crate::fe::check_model_memory`]), and a built-in shape's before
/// it is meshed ([`translate::planned_mesh`]: TetGen takes minutes at millions of tets).
fn body_mesh(
    scene: &Scene,
    input: Option<&MeshInput>,
    warnings: &mut Vec<Warning>,
) -> Result<Mesh> {
    let mesh = match input {
        Some(m) => {
            warnings.extend(Warning::all(WarningKind::Input, m.warnings.iter().cloned()));
            warnings.extend(Warning::all(WarningKind::Input, mesh_checks(&m.mesh)));
            m.mesh.clone()
        }
        None => {
            let kind: crate::fe::ElementKind = scene.discretization.element.into();
            if let Some(planned) = translate::planned_mesh(scene, kind.shape()) {
                crate::fe::check_model_memory(planned.elements, kind, &planned.what)?;
            }
            build_mesh(scene)?
        }
    };
    let kind: crate::fe::ElementKind = scene.discretization.element.into();
    crate::fe::check_model_memory(
        mesh.num_cells() as f64,
        kind,
        &format!(
            "the mesh ({} nodes, {} {} elements)",
            mesh.nodes.len(),
            mesh.num_cells(),
            kind.name()
        ),
    )?;
    Ok(mesh)
}

/// An inverted-element error with the element's id in the mesh file.
fn name_file_element(e: Error, input: Option<&MeshInput>) -> Error {
    match (&e, input) {
        (Error::InvalidElement { element, volume }, Some(m)) => Error::input(InputKind::Mesh, format!(
            "element {} (id {} in the mesh file) is inverted or degenerate: volume {sci_volume:.6e} m^3; its volume (a hexahedron: its Jacobian \
             determinant at a corner or Gauss point) is not positive or below 1e-12 of its size cubed; check its node order and coordinates (a node far from the others makes a needle)",
            element,
            m.element_ids.get(*element).copied().unwrap_or(0)
        , sci_volume = crate::error::Sci(*volume))).element(*element).value(*volume),
        _ => e,
    }
}

/// The corrector's distribution of boundary forces for a resolved `bc_method` (the methods
/// other than EBCIEM that reach a corrector lump them).
fn imposition(method: BcMethod) -> Imposition {
    if method == BcMethod::Ebciem {
        Imposition::Ebciem
    } else {
        Imposition::Sebciem
    }
}

/// The scene's loads and rigid contact on `model`, built on discretization `d` (after its
/// masses are final: gravity takes them).
fn add_loads_and_contact(
    model: &mut Model<Solid>,
    scene: &Scene,
    d: Discretized<'_>,
    input: Option<&MeshInput>,
    warnings: &mut Vec<Warning>,
) -> Result<()> {
    model.set_loads(loads::scene_loads(scene, d, input)?)?;
    // Mass scaling by default except for models of tet4-anp elements only: their elements'
    // own J, which the averaged pressure does not hold, collapsed at the driven rim of the
    // indentation benchmark under the scaled masses (restarts on levels c3 and c5, a failure
    // on c3 with the ramp curve; none with the physical masses), so they keep those unless the
    // scene asks.
    let all_anp = !model.points().is_empty()
        && model
            .points()
            .kinds
            .iter()
            .all(|&k| k == crate::quadrature::PointKind::Anp);
    let scale = match scene.solver.mass_scaling {
        Some(s) => s,
        None => !all_anp,
    };
    let contact = loads::scene_contact(scene, d, input, model.boundaries(), warnings)?;
    model.set_contact(contact);
    // A static solve's relaxed start relaxes with the masses relaxation would have (the MNI
    // brain's relaxed start with its physical masses, the ventricles' small tets setting the
    // step, had not converged after 115,000 steps); the static solve uses no masses, and
    // gravity took the physical ones above.
    // So does the relaxation a static solve falls back to (solver.relaxation_fallback: the
    // 0.6 mm rim relaxed in 95,230 steps with the physical masses, 9,115 with scaled ones).
    let relaxed = scene.solver.mode == Mode::Static
        && (scene.solver.relaxation_fallback
            || crate::solver::integrate::relaxed_start_applies(
                model,
                &translate::settings(scene, false),
            ));
    if (scene.solver.mode == Mode::Relaxation || relaxed) && scale {
        model.scale_masses()?;
    }
    Ok(())
}

/// Centroid of cell `e` of `mesh`, m.
fn centroid(mesh: &Mesh, e: usize) -> Vector3<f64> {
    let c = mesh.cell(e);
    c.iter().map(|&i| mesh.nodes[i]).sum::<Vector3<f64>>() / c.len() as f64
}

/// The modulus that scales hex8 hourglass stiffness for material `m` (Pa).
fn hourglass_modulus(scene: &Scene, m: &Solid) -> f64 {
    let (lambda, mu) = m.lame();
    scene.discretization.hourglass_scale(lambda, mu).1
}

/// `[initial]` motion where boundaries hold nodes: those start at their prescribed motion
/// while their neighbours move, an impact at t = 0 (the cylinder at 1 m/s against its fixed
/// base diverged at dt_factor 0.9 and completed at 0.5). Names the boundary and the speed.
fn initial_velocity_warning(scene: &Scene, p: &Prepared) -> Option<String> {
    let i = scene.initial.as_ref().filter(|_| scene.mode_is_dynamic())?;
    let (v, w, c) = (
        Vector3::from(i.velocity),
        Vector3::from(i.angular_velocity),
        Vector3::from(i.center),
    );
    let mut worst: Option<(f64, &str)> = None;
    for b in p.model.boundaries() {
        for &n in &b.nodes {
            let v0 = v + w.cross(&(p.model.nodes()[n] - c));
            for k in 0..3 {
                if b.components[k].is_some() && v0[k].abs() > worst.map_or(0.0, |x| x.0) {
                    worst = Some((v0[k].abs(), b.name.as_str()));
                }
            }
        }
    }
    let (speed, name) = worst?;
    Some(format!(
        "[initial] motion: boundary '{name}' holds its nodes to their prescribed motion, so they start \
         {speed:.3e} m/s apart from the body's initial velocity there: an impact at t = 0, whose shock may \
         need a smaller solver.dt_factor; leave those components free or start the body at rest"
    ))
}

/// A mesh file's body larger than any organ or phantom (bounding-box diagonal over
/// `LARGEST_BODY`): most likely a file in millimetres read as metres (a 100 mm cube becomes
/// 100 m, its gravity and stiffness scaled to match), issue 41.
/// Largest relative difference between the model's volume and the volume its labelled image
/// or surface gives before it is warned of.
pub const VOLUME_WARNING: f64 = 0.02;

/// The model's volume (its points' weights) against the geometry's, where they differ by more
/// than [`VOLUME_WARNING`] (issue 56: a labelled ball 15 % smaller at size 6 mm, 37 % at 8 mm,
/// without a word), with the size that would bring them within it: the error of the blocks'
/// surface shrinks as the square of the size, so `size sqrt(0.02 / difference)`.
fn volume_warning(scene: &Scene, p: &Prepared) -> Option<String> {
    let SourceVolume {
        volume: source,
        of: what,
    } = p.source_volume.as_ref()?;
    let volume = p.model.points().total_weight();
    let d = (volume - source) / source;
    if !(d.abs() > VOLUME_WARNING) {
        return None;
    }
    let size = scene
        .discretization
        .size
        .map(|h| {
            format!(
                "; a discretization.size of about {:.3e} m (now {h:.3e} m) should bring it within {:.0} %",
                0.9 * h * (VOLUME_WARNING / d.abs()).sqrt(),
                100.0 * VOLUME_WARNING
            )
        })
        .unwrap_or_default();
    Some(format!(
        "the model's volume {volume:.4e} m^3 is {:.1} % {} than the {source:.4e} m^3 of {what}, and its mass and \
         weight with it{size}",
        100.0 * d.abs(),
        if d < 0.0 { "less" } else { "more" },
    ))
}

fn units_warning(scene: &Scene, nodes: &[Vector3<f64>]) -> Option<String> {
    let (file, units) = match &scene.geometry {
        Geometry::Mesh { file, units, .. } | Geometry::Surface { file, units } => (file, units),
        _ => return None,
    };
    let (lo, hi) = crate::geometry::select::bounds(nodes);
    let diag = (hi - lo).norm();
    (diag > LARGEST_BODY).then(|| {
        format!(
            "the body read from {} spans {:.4e} x {:.4e} x {:.4e} m (diagonal {diag:.3e} m, \
             geometry.units = {units}): lengths are in metres; if the file is in millimetres set \
             geometry.units = 0.001",
            file.display(),
            hi.x - lo.x,
            hi.y - lo.y,
            hi.z - lo.z
        )
    })
}

/// The largest body diagonal (m) a mesh file gives without [`units_warning`].
const LARGEST_BODY: f64 = 3.0;

/// Meshes the scene, builds the quadrature points, masses, constraints and probes.
pub fn prepare(scene: &Scene) -> Result<Prepared> {
    if let Some(f) = &scene.output.image {
        let p = translate::scene_path(scene, f);
        if !p.is_file() {
            return Err(Error::input(
                InputKind::Value,
                format!(
                "output.image = '{}': no such file ({}); give the image to warp (the run would \
                 fail at its end)",
                f.display(),
                p.display()
            ),
            ));
        }
    }
    if scene.solver.device == Device::Gpu {
        // Before the preprocessing, which can take minutes: a missing driver, NVRTC or GPU is
        // said at once (run, compare and sweep all prepare here).
        solver::gpu::probe()?;
    }
    log::info!(
        "preparing the {} discretization",
        format!("{:?}", scene.discretization.method).to_lowercase()
    );
    let mut p = match scene.discretization.method {
        Method::Meshless => prepare_meshless(scene)?,
        Method::Coupled => prepare_coupled(scene)?,
        Method::Fe => prepare_fe(scene)?,
    };
    crate::interrupt::check(|| "while preparing the model".into())?;
    if let Some(w) = locking_warning(scene, &p) {
        p.warnings
            .push(Warning::new(WarningKind::Discretization, w));
    }
    if let Some(w) = initial_velocity_warning(scene, &p) {
        p.warnings.push(Warning::new(WarningKind::Boundary, w));
    }
    if let Some(w) = units_warning(scene, p.model.nodes()) {
        p.warnings.push(Warning::new(WarningKind::Input, w));
    }
    p.source_volume = translate::geometry_volume(scene)?;
    if let Some(w) = volume_warning(scene, &p) {
        p.warnings.push(Warning::new(WarningKind::Input, w));
    }
    if let (true, Some(n)) = (scene.solver.mode.is_steady(), scene.output.frames) {
        p.warnings.push(Warning::new(
            WarningKind::SteadyFrames,
            format!(
            "output.frames = {n} applies to dynamic runs: relaxation writes the unloaded state, \
             each load stage (a reference's `at`) and the converged state (its path in \
             pseudo-time is no physical history); for the states along the load, give \
             references with `at` or run in dynamics"
        ),
        ));
    }
    let free = crate::bc::free_parts(
        p.model.nodes().len(),
        p.model.points(),
        p.model.boundaries(),
    );
    if let Some(&(count, node)) = free.first() {
        let x = p.model.nodes()[node];
        p.warnings.push(Warning::new(WarningKind::Boundary, format!(
            "{} part(s) of the body are held by no boundary (the largest: {count} nodes, node {node} at \
             ({:.4e}, {:.4e}, {:.4e}) m): they can move as rigid bodies, and relaxation cannot settle them \
             if anything pushes them; select some of their nodes in a boundary or remove them",
            free.len(),
            x.x,
            x.y,
            x.z
        )));
    }
    Ok(p)
}

/// Bulk-to-shear ratio kappa / mu (1,000: nu = 0.4995) from which the discretizations below
/// are reported as locking. On the bonded cylinder in compression at nu = 0.4999 (kappa / mu
/// = 5,000; relaxation) the reaction was, in N, at [4, 2, 8] / [8, 4, 20] divisions: hex8
/// with the shear-scaled hourglass 7.14 / 7.06, tet4-anp 8.16 / 7.44, coupled 7.27 / -,
/// MMLS with one point per tet 8.32 / -; locking: tet4 102.9 at [4, 2, 8], hex8 with the
/// (lambda + 2 mu)-scaled hourglass 19.0 / 10.0, MLS with four points per tet 10.03 at
/// [4, 2, 8] (at nu = 0.499, kappa / mu = 500, all of these were within 8 % of tet4-anp).
const LOCKING_KAPPA_OVER_MU: f64 = 1000.0;

/// Meshless points per free displacement component above which the meshless part locks
/// near incompressibility: MLS with four points per tet (6 per free component at [4, 2, 8])
/// locked, MMLS with one (1.5) did not; see [`LOCKING_KAPPA_OVER_MU`].
const LOCKING_POINTS_PER_DOF: f64 = 3.0;

/// A warning when the discretization is known to lock at the material's kappa / mu: plain
/// tet4 elements, hexahedra whose hourglass stiffness scales with lambda, or more meshless
/// points per free DOF than [`LOCKING_POINTS_PER_DOF`]. Names the element and the setting to
/// change (points per constraint as in Hughes, The Finite Element Method, sect. 4.3).
fn locking_warning(scene: &Scene, p: &Prepared) -> Option<String> {
    let (ratio, m) = regions::stiffest_ratio(&p.model.forces().materials);
    if !(ratio >= LOCKING_KAPPA_OVER_MU) {
        return None;
    }
    let d = &scene.discretization;
    let (kappa, mu) = (m.kappa(), m.lame().1);
    let nu = (3.0 * kappa - 2.0 * mu) / (2.0 * (3.0 * kappa + mu));
    let head = format!("nu = {nu:.5} (kappa / mu = {ratio:.0}): possible volumetric locking:");
    let fe_used = d.method != Method::Meshless;
    if fe_used && d.element == crate::scene::ElementName::Tet4 {
        return Some(format!(
            "{head} plain tet4 elements impose one volumetric constraint each and lock \
             (cylinder at nu = 0.4999: 14x the tet4-anp reaction); set discretization.element = 'tet4-anp'"
        ));
    }
    if fe_used
        && d.element == crate::scene::ElementName::Hex8
        && d.hourglass_modulus == crate::scene::HourglassModulus::PWave
    {
        return Some(format!(
            "{head} hex8 hourglass stiffness scaled by lambda + 2 mu grows with kappa and resists volume change \
             (cylinder at nu = 0.4999: reaction 1.4-2.7x hex8's with the shear scaling); \
             set discretization.hourglass_modulus = 'shear'"
        ));
    }
    // The coupled table holds its FE and transition points first, the interior's last.
    let (mls_points, free) = match &p.method {
        Discretization::Meshless { .. } => {
            (volumetric_constraints(p.model.points(), 0), free_dofs(p))
        }
        Discretization::Coupled { build: c, .. } => (
            volumetric_constraints(p.model.points(), c.fe_points + c.transition_points),
            3 * c.mls_nodes.len(),
        ),
        Discretization::Fe => return None,
    };
    let per_dof = mls_points as f64 / free.max(1) as f64;
    if per_dof > LOCKING_POINTS_PER_DOF {
        return Some(format!(
            "{head} {mls_points} meshless integration points on {free} free displacement components \
             ({per_dof:.1} per component; a mean-dilatation patch counts once) over-constrain the volume \
             (MLS with 4 points per tet: 23 % above tet4-anp on the cylinder at nu = 0.4999); use fewer \
             points: discretization.tet_rule = 1 (or integration = 'grid' with point_ratio <= 2), or \
             share J over patches (discretization.mean_dilatation_patch = 8)"
        ));
    }
    None
}

/// Volumetric constraints of the points `first..` of a point table: one per point, and one per
/// mean-dilatation group for the points that share its J.
fn volumetric_constraints(q: &crate::quadrature::QuadraturePoints, first: usize) -> usize {
    let tail = q.groups.iter().filter(|g| g[0] as usize >= first);
    let (groups, grouped) = tail.fold((0, 0), |(n, k), g| (n + 1, k + (g[1] - g[0]) as usize));
    q.len().saturating_sub(first) - grouped + groups
}

/// Displacement components not prescribed directly.
fn free_dofs(p: &Prepared) -> usize {
    3 * p.model.nodes().len() - p.model.constraints().dofs.len()
}

/// Runs a scene end to end and returns its summary; writes outputs when `opts.out` is set.
///
/// With `opts.out`, the folder is checked and claimed before anything is computed
/// ([`crate::io::out_dir::OutDir`]): it then holds exactly this run's files, or after a failure
/// a summary.json with `"status": "failed"` and the message.
pub fn run_scene(scene: &Scene, opts: &RunOptions) -> Result<Summary> {
    let t0 = Instant::now();
    let dir = opts
        .out
        .as_deref()
        .map(crate::io::out_dir::OutDir::open)
        .transpose()?;
    let result = (|| {
        // Read before anything is computed, so a file that cannot be used costs no solve.
        let out_image = match &dir {
            Some(_) => output::output_image(scene)?,
            None => None,
        };
        let mut prep = prepare(scene)?;
        let mut settings = settings(scene, opts.progress);
        settings.progress_lines = opts.progress_lines;
        let Some(d) = &dir else {
            let out = solver::run(&mut prep.model, &settings)
                .map_err(|e| with_setup_warnings(e, &prep.warnings))?;
            return Ok(summarize(scene, &prep, &out, t0.elapsed().as_secs_f64()));
        };
        // Frames go to disk as they are produced: a run that fails leaves those before the
        // failure (OutDir::fail keeps them, with their .pvd) for debugging.
        let staging = d.staging()?;
        let name = scene.name.clone().unwrap_or_else(|| "run".into());
        let labels = FrameLabels::of(&prep);
        let Prepared {
            model,
            mesh,
            method,
            ..
        } = &mut prep;
        let mut frames = FrameWriter::new(&staging, &name, mesh, method, labels, opts.vtu_format)?;
        let run = solver::run_streaming(model, &settings, &mut |m, t, u| frames.write(m, t, u));
        frames.write_series()?;
        let image_written = match &run {
            Ok(out) => {
                output::write_image_outputs(&staging, &name, out_image.as_ref(), &frames, &out.u)
            }
            Err(_) => Ok(()),
        };
        let out = run.map_err(|e| with_setup_warnings(e, &prep.warnings))?;
        image_written?;
        let summary = summarize(scene, &prep, &out, t0.elapsed().as_secs_f64());
        write_results(&staging, &name, &prep, &out, &summary, opts.vtu_format)?;
        d.commit()?;
        Ok(summary)
    })();
    if let (Err(e), Some(d)) = (&result, &dir) {
        d.fail(e);
    }
    result
}

/// Runs a prepared scene's model with `settings` to the end of its dynamic interval or to
/// relaxation convergence (see [`solver::run`]); commands built on the pipeline solve through
/// this, so the pipeline stays the one place that knows both the scene and the solver.
pub fn solve(prep: &mut Prepared, settings: &Settings) -> Result<RunOutput> {
    solver::run(&mut prep.model, settings).map_err(|e| with_setup_warnings(e, &prep.warnings))
}

/// A run that fails takes the preparation's warnings along in its message: they are printed
/// with the summary, which a failed run never reaches, and they often name the cause (a
/// rigid body that starts inside the body, removed meshless nodes).
fn with_setup_warnings(e: Error, warnings: &[Warning]) -> Error {
    match e {
        Error::Unstable(msg) if !warnings.is_empty() => Error::Unstable(format!(
            "{msg}\n  the setup warned: {}",
            warnings.join("\n  the setup warned: ")
        )),
        e => e,
    }
}

/// The critical time step of a prepared scene, s, and what sets it, by the scene's estimate
/// (`solver.time_step`); an error where there is none (every degree of freedom prescribed) or
/// where a rigid body starts too deep inside the body for the scene's step.
pub fn critical_step(
    scene: &Scene,
    prep: &mut Prepared,
) -> Result<(f64, solver::integrate::Critical)> {
    let (dt, critical) = solver::integrate::critical_step(&mut prep.model, scene.solver.time_step);
    solver::integrate::check_critical_step(&prep.model, dt)?;
    solver::integrate::check_contact_start(&prep.model, scene.solver.dt_factor * dt)?;
    Ok((dt, critical))
}
