//! The pipeline of one run: scene -> mesh -> quadrature points -> model -> solver -> outputs.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use nalgebra::Vector3;

mod loads;
mod measured;
mod output;
mod regions;
mod surface;
mod translate;

pub use output::{write_outputs, write_results, FrameLabels, FrameWriter};
use surface::Discretized;
pub use translate::{
    build_mesh, load_mesh_input, material, mesh_checks, meshless_settings, settings,
};
use translate::{cloud_sets, load_curve, scene_path};

use crate::bc::Boundary;
use crate::coupling::{self, CoupledBuild, NodeRole};
use crate::fe::{self, ElementKind};
use crate::geometry::{quality, Mesh};
use crate::io::model::MeshInput;
use crate::io::vtu::VtuFormat;
use crate::material::{Material, Solid};
use crate::meshless::discretize::{self, MeshlessBuild};
use crate::meshless::essential::{Imposition, MeshlessCorrector};
use crate::probe::Probe;
use crate::report::{
    Comparison, CoupledInfo, Energy, MeshInfo, MeshlessInfo, ProbeResult, Summary, SupportNodes,
    WallSeconds,
};
use crate::scene::{BcMethod, Component, Method, Scene};
use crate::solver::{self, Model, RunOutput};
pub use crate::solver::{Mode, Settings};
use crate::{Error, Result};

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

/// Nodes of a selection, with the mesh file's sets available.
fn select_nodes(
    sel: &crate::geometry::select::Selection,
    nodes: &[Vector3<f64>],
    what: &str,
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
    sel.select_with(nodes, what, sets)
}

/// A probe that averages nodal values with the given (node, weight) pairs; its position is the
/// weighted centroid of the nodes.
fn set_probe(name: &str, nodes: &[Vector3<f64>], w: Vec<(usize, f64)>) -> Probe {
    let position = w
        .iter()
        .fold(Vector3::zeros(), |a, &(i, x)| a + nodes[i] * x);
    Probe {
        name: name.into(),
        position,
        nodes: w.iter().map(|p| p.0).collect(),
        weights: w.iter().map(|p| p.1).collect(),
        element: usize::MAX,
    }
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
        let sel = select_nodes(&b.select, nodes, &format!("boundary '{name}'"), input)?;
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
        });
    }
    Ok(out)
}

/// A scene turned into a model, ready to run.
pub struct Prepared {
    /// FE mesh, or the meshless background tets (VTU geometry).
    pub mesh: Mesh,
    /// The meshless discretization, for meshless scenes.
    pub meshless: Option<MeshlessBuild>,
    /// The coupled FE + meshless discretization, for coupled scenes.
    pub coupled: Option<CoupledBuild>,
    /// How essential conditions act on meshless nodes (None for FE).
    pub bc_method: Option<BcMethod>,
    /// Things the user should know that do not stop the run.
    pub warnings: Vec<String>,
    pub model: Model<Solid>,
    /// Each quadrature point's material (discretization order: elements, meshless or coupled
    /// points): 0 is `[material]`, k the k-th region; empty without regions.
    pub point_material: Vec<u16>,
    /// Regions and the points each holds.
    pub regions: Vec<(String, usize)>,
    pub probes: Vec<Probe>,
    pub kind: ElementKind,
    pub min_dihedral: Option<(f64, usize)>,
    pub preprocess_seconds: f64,
}

/// The body's mesh: the mesh file's (its reader's warnings and the duplicate-node check go to
/// `warnings`) or the built-in shape's.
fn body_mesh(scene: &Scene, input: Option<&MeshInput>, warnings: &mut Vec<String>) -> Result<Mesh> {
    match input {
        Some(m) => {
            warnings.extend(m.warnings.iter().cloned());
            warnings.extend(mesh_checks(&m.mesh));
            Ok(m.mesh.clone())
        }
        None => build_mesh(scene),
    }
}

/// An inverted-element error with the element's id in the mesh file.
fn name_file_element(e: Error, input: Option<&MeshInput>) -> Error {
    match (&e, input) {
        (Error::InvalidElement { element, volume }, Some(m)) => Error::Input(format!(
            "element {} (id {} in the mesh file) is inverted or degenerate: volume {volume:.6e} m^3, not positive \
             or below 1e-12 of its size cubed; check its node order and coordinates (a node far from the others makes a needle)",
            element,
            m.element_ids.get(*element).copied().unwrap_or(0)
        )),
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
    warnings: &mut Vec<String>,
) -> Result<()> {
    model.set_loads(loads::scene_loads(scene, d, input)?)?;
    model.contact = loads::scene_contact(scene, d, input, warnings)?;
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
    for b in &p.model.boundaries {
        for &n in &b.nodes {
            let v0 = v + w.cross(&(p.model.nodes[n] - c));
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

/// Meshes the scene, builds the quadrature points, masses, constraints and probes.
pub fn prepare(scene: &Scene) -> Result<Prepared> {
    log::info!(
        "preparing the {} discretization",
        format!("{:?}", scene.discretization.method).to_lowercase()
    );
    let mut p = match scene.discretization.method {
        Method::Meshless => prepare_meshless(scene)?,
        Method::Coupled => prepare_coupled(scene)?,
        Method::Fe => prepare_fe(scene)?,
    };
    if let Some(w) = locking_warning(scene, &p) {
        p.warnings.push(w);
    }
    if let Some(w) = initial_velocity_warning(scene, &p) {
        p.warnings.push(w);
    }
    let free = crate::bc::free_parts(p.model.nodes.len(), &p.model.points, &p.model.boundaries);
    if let Some(&(count, node)) = free.first() {
        let x = p.model.nodes[node];
        p.warnings.push(format!(
            "{} part(s) of the body are held by no boundary (the largest: {count} nodes, node {node} at \
             ({:.4e}, {:.4e}, {:.4e}) m): they can move as rigid bodies, and relaxation cannot settle them \
             if anything pushes them; select some of their nodes in a boundary or remove them",
            free.len(),
            x.x,
            x.y,
            x.z
        ));
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
    let (ratio, m) = regions::stiffest_ratio(&p.model.forces.materials);
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
    let (mls_points, free) = match (&p.meshless, &p.coupled) {
        (Some(_), _) => (p.model.points.len(), free_dofs(p)),
        (_, Some(c)) => (c.meshless_points, 3 * c.mls_nodes.len()),
        _ => return None,
    };
    let per_dof = mls_points as f64 / free.max(1) as f64;
    if per_dof > LOCKING_POINTS_PER_DOF {
        return Some(format!(
            "{head} {mls_points} meshless integration points on {free} free displacement components \
             ({per_dof:.1} per component) over-constrain the volume (MLS with 4 points per tet: 23 % above \
             tet4-anp on the cylinder at nu = 0.4999); use fewer points: discretization.tet_rule = 1 \
             (or integration = 'grid' with point_ratio <= 2)"
        ));
    }
    None
}

/// Displacement components not prescribed directly.
fn free_dofs(p: &Prepared) -> usize {
    3 * p.model.nodes.len() - p.model.constraints.dofs.len()
}

/// FE branch of [`prepare`].
fn prepare_fe(scene: &Scene) -> Result<Prepared> {
    let t0 = Instant::now();
    let input = load_mesh_input(scene)?;
    let mut warnings = Vec::new();
    let mesh = body_mesh(scene, input.as_ref(), &mut warnings)?;
    let mat = material(scene);
    let kind: ElementKind = scene.discretization.element.into();
    let (lambda, mu) = mat.lame();
    let (kappa_hg, modulus) = scene.discretization.hourglass_scale(lambda, mu);
    log::info!(
        "mesh: {} nodes, {} elements; element derivatives",
        mesh.nodes.len(),
        mesh.num_cells()
    );
    let mut points = fe::element_points(&mesh, kind, kappa_hg, modulus)
        .map_err(|e| name_file_element(e, input.as_ref()))?;
    let places = regions::Places {
        position: (0..mesh.num_cells()).map(|e| centroid(&mesh, e)).collect(),
        element: (0..mesh.num_cells()).map(Some).collect(),
    };
    let (materials, point_material, region_counts) =
        regions::point_materials(scene, input.as_ref(), &places)?;
    regions::scale_hourglass(
        &mut points,
        &point_material,
        &|m| hourglass_modulus(scene, m),
        &materials,
    );
    let bnd = boundaries(scene, &mesh.nodes, input.as_ref(), &|| {
        Discretized::Fe(&mesh).surface_nodes()
    })?;
    let probes = scene
        .probes
        .iter()
        .map(|(name, p)| match (&p.select, p.position) {
            (Some(sel), _) => {
                let ids =
                    select_nodes(sel, &mesh.nodes, &format!("probe '{name}'"), input.as_ref())?;
                let w = 1.0 / ids.len() as f64;
                Ok(set_probe(
                    name,
                    &mesh.nodes,
                    ids.iter().map(|&i| (i, w)).collect(),
                ))
            }
            (None, Some(x)) => Probe::locate(name, Vector3::from(x), &mesh),
            (None, None) => Err(Error::Input(format!(
                "probe '{name}' has neither position nor select"
            ))),
        })
        .collect::<Result<Vec<_>>>()?;
    let min_dihedral = quality::min_dihedral_angle(&mesh);
    log::info!("masses, boundaries, loads");
    let mut model = Model::with_materials(
        mesh.nodes.clone(),
        points,
        materials,
        point_material.clone(),
        bnd,
    )?;
    add_loads_and_contact(
        &mut model,
        scene,
        Discretized::Fe(&mesh),
        input.as_ref(),
        &mut warnings,
    )?;
    Ok(Prepared {
        mesh,
        meshless: None,
        coupled: None,
        bc_method: None,
        warnings,
        model,
        point_material,
        regions: region_counts,
        probes,
        kind,
        min_dihedral,
        preprocess_seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Meshless branch of [`prepare`]: cloud, integration points, supports and shape functions,
/// masses, boundaries (EBCIEM / SEBCIEM correction or prescribed nodal parameters) and probes
/// interpolated with the shape functions.
fn prepare_meshless(scene: &Scene) -> Result<Prepared> {
    let t0 = Instant::now();
    let input = match load_mesh_input(scene)? {
        Some(m) => Some(m),
        None => cloud_sets(scene)?,
    };
    let method = scene
        .discretization
        .bc_method
        .resolve(scene.discretization.support);
    // Nodes that must survive the removal of poorly supported nodes: boundary nodes and the
    // nodes nearest to each probe.
    let protected = |nodes: &[Vector3<f64>]| -> Result<Vec<usize>> {
        let mut v = Vec::new();
        // Measured points are matched to any node here: the surface is not known yet.
        for b in boundaries(scene, nodes, input.as_ref(), &|| {
            Ok((0..nodes.len()).collect())
        })? {
            v.extend(b.nodes);
        }
        for (name, p) in &scene.probes {
            if let Some(sel) = &p.select {
                v.extend(select_nodes(
                    sel,
                    nodes,
                    &format!("probe '{name}'"),
                    input.as_ref(),
                )?);
                continue;
            }
            let x = Vector3::from(p.position.unwrap_or_default());
            if let Some((i, _)) = nodes
                .iter()
                .enumerate()
                .map(|(i, n)| (i, (n - x).norm_squared()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
            {
                v.push(i);
            }
        }
        v.sort_unstable();
        v.dedup();
        Ok(v)
    };
    let build = discretize::build(meshless_settings(scene)?, &protected)?;
    let mut warnings = build.warnings.clone();
    if method == BcMethod::Ebciem
        && scene.discretization.support == crate::scene::SupportKind::Nearest
    {
        warnings.push(
            "bc_method = 'ebciem' with support = 'nearest': the nearest-node shape functions jump where the \
             support changes, and EBCIEM runs of this kind diverged in our tests; prefer 'sebciem' (the default, 'auto')"
                .into(),
        );
    }
    let bnd = boundaries(scene, &build.nodes, input.as_ref(), &|| {
        Discretized::Meshless(&build).surface_nodes()
    })?;
    let dom = translate::domain(scene);
    let h = translate::spacing(scene).unwrap_or(0.0);
    let probes = scene
        .probes
        .iter()
        .map(|(name, p)| {
            if let Some(sel) = &p.select {
                // Mean of the interpolated displacements at the selected nodes.
                let ids = select_nodes(
                    sel,
                    &build.nodes,
                    &format!("probe '{name}'"),
                    input.as_ref(),
                )?;
                let mut acc: BTreeMap<usize, f64> = BTreeMap::new();
                for &i in &ids {
                    let s = build.shape_values(&build.nodes[i], &|| format!("probe '{name}'"))?;
                    for (&j, &w) in s.ids.iter().zip(&s.phi) {
                        *acc.entry(j).or_default() += w / ids.len() as f64;
                    }
                }
                let mut pr = set_probe(name, &build.nodes, acc.into_iter().collect());
                let c = ids
                    .iter()
                    .fold(Vector3::zeros(), |a, &i| a + build.nodes[i])
                    / ids.len() as f64;
                pr.position = c;
                return Ok(pr);
            }
            let position = p.position.unwrap_or_default();
            let x = Vector3::from(position);
            if dom
                .as_ref()
                .is_some_and(|d| !d.contains(&x, 0.05 * h.max(1e-12)))
            {
                return Err(Error::Input(format!(
                    "probe '{name}' at {position:?} m lies outside the body; move it inside"
                )));
            }
            let s = build.shape_values(&x, &|| format!("probe '{name}'"))?;
            Ok(Probe {
                name: name.clone(),
                position: x,
                nodes: s.ids,
                weights: s.phi,
                element: usize::MAX,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    // Element sets reach meshless points through their background tet when the cloud is the
    // vertices of the scene's mesh file (hexahedra split into six tets each).
    let from_file = input.as_ref().filter(|m| {
        !m.mesh.cells.is_empty() && scene.discretization.cloud == crate::scene::CloudKind::Mesh
    });
    let per_cell = match from_file.map(|m| m.mesh.shape) {
        Some(crate::geometry::ElementShape::Hex8) => 6,
        _ => 1,
    };
    let places = regions::Places {
        position: build.positions.clone(),
        element: build
            .owner
            .iter()
            .map(|&o| (from_file.is_some() && o != usize::MAX).then_some(o / per_cell))
            .collect(),
    };
    let (materials, point_material, region_counts) =
        regions::point_materials(scene, input.as_ref(), &places)?;
    let mut model = Model::with_materials(
        build.nodes.clone(),
        build.points.clone(),
        materials,
        point_material.clone(),
        bnd.clone(),
    )?;
    add_loads_and_contact(
        &mut model,
        scene,
        Discretized::Meshless(&build),
        input.as_ref(),
        &mut warnings,
    )?;
    let corrected: Vec<bool> = bnd
        .iter()
        .map(|b| method != BcMethod::Correction && b.components.iter().any(|c| c.is_some()))
        .collect();
    if corrected.iter().any(|&c| c) {
        let (corr, report) = MeshlessCorrector::new(&build, &bnd, &model.mass, imposition(method))?;
        if report.lumped_nodes > 0 {
            warnings.push(format!(
                "EBCIEM: {} constrained node(s) lie on no boundary triangle whose vertices are all constrained; \
                 their boundary force is lumped at the node (SEBCIEM)",
                report.lumped_nodes
            ));
        }
        model.set_corrector(Box::new(corr), corrected)?;
    }
    Ok(Prepared {
        mesh: build.background.clone(),
        meshless: Some(build),
        coupled: None,
        bc_method: Some(method),
        warnings,
        model,
        point_material,
        regions: region_counts,
        probes,
        kind: ElementKind::Tet4,
        min_dihedral: None,
        preprocess_seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Warnings for the boundaries that drive a load concentrated on a few nodes
/// ([`is_concentrated_drive`]) where their transition cells keep one point.
fn concentrated_drives(bnd: &[crate::bc::Boundary], surface_nodes: usize) -> Vec<String> {
    bnd.iter()
        .filter(|b| is_concentrated_drive(b, surface_nodes))
        .map(|b| {
            format!(
                "boundary '{}' drives {} of the {surface_nodes} surface nodes: with one point per \
                 transition tet (transition_rule = 'interior') a load concentrated on a few nodes \
                 is under-integrated (brain indentation: 10-31 % below fe tet4-anp), and a given \
                 FE shell does not yet get the full rule next to it; set \
                 discretization.transition_rule = 'full'",
                b.name,
                b.nodes.len()
            )
        })
        .collect()
}

/// A boundary that drives (a non-zero or measured displacement) fewer than 5 % of the surface
/// nodes. With one point per transition tet the blended cells next to it are under-integrated
/// and the body answers soft: brain indentation, 15 of 2,582 surface nodes driven, 10-31 % below
/// fe tet4-anp at nu = 0.49 and 0.3 (`studies/brain-convergence`, `studies/brain-compressible`),
/// where the full rule in the cells within two of the driven nodes gives the full rule's answer
/// everywhere to 0.05 % for 1.7 % more points.
fn is_concentrated_drive(b: &crate::bc::Boundary, surface_nodes: usize) -> bool {
    let driven =
        b.node_values.is_some() || b.components.iter().any(|c| c.is_some_and(|v| v != 0.0));
    driven && (b.nodes.len() as f64) < 0.05 * surface_nodes as f64
}

/// Coupled branch of [`prepare`]: the scene's mesh (built-in or file) split into an FE layer
/// of `fe_layers` cells on the boundary and a meshless interior, blended in the transition
/// cells. Conditions on FE nodes are imposed directly.
fn prepare_coupled(scene: &Scene) -> Result<Prepared> {
    let t0 = Instant::now();
    let input = load_mesh_input(scene)?;
    let mut warnings = Vec::new();
    let mesh = body_mesh(scene, input.as_ref(), &mut warnings)?;
    let mat = material(scene);
    let kind: ElementKind = scene.discretization.element.into();
    let (lambda, mu) = mat.lame();
    let d = &scene.discretization;
    let mixed = input.is_some() && d.cloud == crate::scene::CloudKind::File;
    let generated = matches!(
        d.cloud,
        crate::scene::CloudKind::Lattice | crate::scene::CloudKind::Halton
    );
    // The boundaries on the mesh's nodes (the coupled build keeps them): where the FE layer
    // goes around the essential boundaries, and which drives are concentrated.
    let mesh_boundaries = if mixed || generated {
        None
    } else {
        Some(boundaries(scene, &mesh.nodes, input.as_ref(), &|| {
            Discretized::Fe(&mesh).surface_nodes()
        })?)
    };
    let full_rule_near: Vec<usize> = match (&mesh_boundaries, d.transition_rule()) {
        (Some(bnd), crate::scene::TransitionRuleKind::Interior) => {
            let surface = Discretized::Fe(&mesh).surface_nodes()?.len();
            bnd.iter()
                .filter(|b| is_concentrated_drive(b, surface))
                .flat_map(|b| b.nodes.iter().cloned())
                .collect()
        }
        _ => Vec::new(),
    };
    let fe_region = match d.fe_region() {
        crate::scene::FeRegionKind::Surface => coupling::FeRegion::Surface,
        crate::scene::FeRegionKind::Essential if mixed || generated => {
            return Err(Error::Input(
                "discretization.fe_region = 'essential' places the FE layer within the scene's mesh; \
                 with cloud = 'file', 'lattice' or 'halton' the FE layer is the given shell: use fe_region = 'surface'"
                    .into(),
            ))
        }
        crate::scene::FeRegionKind::Essential => {
            let bnd = mesh_boundaries
                .as_ref()
                .expect("boundaries on the mesh are found for every non-mixed, non-generated build");
            let mut nodes: Vec<usize> = bnd
                .iter()
                .filter(|b| b.components.iter().any(|c| c.is_some()))
                .flat_map(|b| b.nodes.iter().cloned())
                .collect();
            nodes.sort_unstable();
            nodes.dedup();
            coupling::FeRegion::Around(nodes)
        }
    };
    let (kappa_hg, hourglass_modulus) = d.hourglass_scale(lambda, mu);
    let settings = coupling::CoupledSettings {
        fe_layers: d.fe_layers(),
        fe_region,
        element: kind,
        hourglass: kappa_hg,
        hourglass_modulus,
        mls: translate::mls_settings(scene),
        rule: translate::support_rule(scene),
        interface_scale: d.interface_scale,
        mean_dilatation: d.mean_dilatation,
        transition_rule: match d.transition_rule() {
            crate::scene::TransitionRuleKind::Full => coupling::TransitionRule::Full,
            crate::scene::TransitionRuleKind::Interior => coupling::TransitionRule::Interior,
        },
        full_rule_near,
        tet_rule: translate::tet_rule(scene)?,
        tets_per_point: d.tets_per_point(),
        adaptive: if d.integration == crate::scene::IntegrationKind::Adaptive {
            Some(translate::adaptive_settings(scene)?)
        } else {
            None
        },
    };
    let min_dihedral = quality::min_dihedral_angle(&mesh);
    let tets = |p: &[Vector3<f64>]| -> Result<Vec<[usize; 4]>> {
        Ok(discretize::delaunay(p)?
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect())
    };
    let built = if mixed {
        let path = scene_path(scene, &d.cloud_file.clone().unwrap_or_default());
        let cloud = crate::meshless::cloud::read_cloud(&path)?;
        coupling::mixed::build(mesh, &cloud, 0.0, &settings, &tets).map(|(b, _)| b)
    } else if generated {
        // A generated interior: the outer fe_layers of the mesh stay FE, the generator's nodes
        // fill the cavity (those within half a spacing of the inner surface dropped).
        let (cloud, _, h) = translate::generated_cloud(scene)?;
        let (shell, _) = coupling::regions::split_inputs(&mesh, d.fe_layers())?;
        coupling::mixed::build(shell, &cloud, 0.5 * h, &settings, &tets).map(|(b, _)| b)
    } else {
        coupling::build(mesh, &settings)
    };
    let build = built.map_err(|e| name_file_element(e, input.as_ref()))?;
    warnings.extend(build.warnings.iter().cloned());
    let bnd = boundaries(scene, &build.nodes, input.as_ref(), &|| {
        Discretized::Coupled(&build).surface_nodes()
    })?;
    // Builds on the scene's own mesh give the cells next to a concentrated drive the full
    // rule (`full_rule_near`); a given FE shell with a cloud cannot yet, so it is said.
    if settings.transition_rule == coupling::TransitionRule::Interior
        && mesh_boundaries.is_none()
        && build.fe_mesh.shape == crate::geometry::ElementShape::Tet4
    {
        warnings.extend(concentrated_drives(
            &bnd,
            Discretized::Coupled(&build).surface_nodes()?.len(),
        ));
    }
    // Boundaries that reach interface or meshless nodes (no Kronecker delta there) are
    // imposed by EBCIEM / SEBCIEM correction, the alternate path; the rest directly.
    let corrected: Vec<bool> = bnd
        .iter()
        .map(|b| {
            b.components.iter().any(|c| c.is_some())
                && b.nodes
                    .iter()
                    .any(|&i| build.regions.node[i] != NodeRole::Fe)
        })
        .collect();
    let bc_method = corrected
        .iter()
        .any(|&c| c)
        .then(|| d.bc_method.resolve(d.support));
    if bc_method == Some(BcMethod::Correction) {
        return Err(Error::Input(
            "bc_method = 'correction' cannot impose conditions on the meshless nodes of a coupled scene; \
             use 'ebciem' or 'sebciem' (or select FE-layer nodes only)"
                .into(),
        ));
    }
    let vertex = build.vertex_weights()?;
    let probes = scene
        .probes
        .iter()
        .map(|(name, p)| match (&p.select, p.position) {
            (Some(sel), _) => {
                let ids = select_nodes(
                    sel,
                    &build.nodes,
                    &format!("probe '{name}'"),
                    input.as_ref(),
                )?;
                let mut acc: BTreeMap<usize, f64> = BTreeMap::new();
                for &i in &ids {
                    for &(j, w) in &vertex[i] {
                        *acc.entry(j).or_default() += w / ids.len() as f64;
                    }
                }
                let mut pr = set_probe(name, &build.nodes, acc.into_iter().collect());
                pr.position = ids
                    .iter()
                    .fold(Vector3::zeros(), |a, &i| a + build.nodes[i])
                    / ids.len() as f64;
                Ok(pr)
            }
            (None, Some(x)) => {
                let x = Vector3::from(x);
                let w = build.shape_values(name, &x)?;
                Ok(Probe {
                    name: name.clone(),
                    position: x,
                    nodes: w.iter().map(|p| p.0).collect(),
                    weights: w.iter().map(|p| p.1).collect(),
                    element: usize::MAX,
                })
            }
            (None, None) => Err(Error::Input(format!(
                "probe '{name}' has neither position nor select"
            ))),
        })
        .collect::<Result<Vec<_>>>()?;
    // Each point takes the material of its cell (the FE-layer or interior cell it belongs to).
    let nf = build.fe_mesh.num_cells();
    let cell_centroid = |o: usize| {
        if o < nf {
            centroid(&build.fe_mesh, o)
        } else {
            centroid(&build.interior, o - nf)
        }
    };
    let places = regions::Places {
        position: build.owner.iter().map(|&o| cell_centroid(o)).collect(),
        element: build
            .owner
            .iter()
            .map(|&o| {
                build
                    .source_cell
                    .get(o)
                    .copied()
                    .filter(|&c| c != usize::MAX)
            })
            .collect(),
    };
    let (materials, point_material, region_counts) =
        regions::point_materials(scene, input.as_ref(), &places)?;
    let mut points = build.points.clone();
    regions::scale_hourglass(
        &mut points,
        &point_material,
        &|m| self::hourglass_modulus(scene, m),
        &materials,
    );
    let masses = build.lumped_masses(&|p| {
        materials[point_material.get(p).copied().unwrap_or(0) as usize].density()
    });
    let mut model = Model::with_materials(
        build.nodes.clone(),
        points,
        materials,
        point_material.clone(),
        bnd.clone(),
    )?;
    model.set_lumped_masses(&masses)?;
    add_loads_and_contact(
        &mut model,
        scene,
        Discretized::Coupled(&build),
        input.as_ref(),
        &mut warnings,
    )?;
    if let Some(method) = bc_method {
        let tris: Vec<[usize; 3]> = if method == BcMethod::Ebciem {
            let mut faces = quality::boundary_faces(&build.fe_mesh)
                .map_err(|e| Error::Input(format!("coupled FE layer: {e}")))?;
            faces.extend(
                quality::boundary_faces(&build.interior)
                    .map_err(|e| Error::Input(format!("coupled interior: {e}")))?,
            );
            // Faces on both sides of the interface are inside the body.
            let mut seen: BTreeMap<Vec<usize>, usize> = BTreeMap::new();
            for f in &faces {
                let mut k = f.clone();
                k.sort_unstable();
                *seen.entry(k).or_default() += 1;
            }
            faces
                .into_iter()
                .filter(|f| {
                    let mut k = f.clone();
                    k.sort_unstable();
                    seen[&k] == 1
                })
                .flat_map(|f| {
                    if f.len() == 4 {
                        vec![[f[0], f[1], f[2]], [f[0], f[2], f[3]]]
                    } else {
                        vec![[f[0], f[1], f[2]]]
                    }
                })
                .collect()
        } else {
            Vec::new()
        };
        let shape = |x: &Vector3<f64>| -> Result<crate::bc::ebciem::SparseVec> {
            Ok(build
                .shape_values("essential-boundary point", x)?
                .into_iter()
                .map(|(i, p)| (i as u32, p))
                .collect())
        };
        let (corr, report) = MeshlessCorrector::from_parts(
            &build.nodes,
            &tris,
            &shape,
            &bnd,
            &model.mass,
            imposition(method),
        )?;
        if report.lumped_nodes > 0 {
            warnings.push(format!(
                "{}: {} constrained meshless node(s) lie on no boundary triangle whose vertices are all constrained; \
                 their boundary force is lumped at the node (SEBCIEM)",
                method.name(),
                report.lumped_nodes
            ));
        }
        let names: Vec<&str> = bnd
            .iter()
            .zip(&corrected)
            .filter(|(_, &c)| c)
            .map(|(b, _)| b.name.as_str())
            .collect();
        warnings.push(format!(
            "boundaries {names:?} act on meshless nodes of the coupled discretization; imposed by {} (alternate path)",
            method.name()
        ));
        model.set_corrector(Box::new(corr), corrected)?;
    }
    Ok(Prepared {
        mesh: build.fe_mesh.clone(),
        meshless: None,
        coupled: Some(build),
        bc_method,
        warnings,
        model,
        point_material,
        regions: region_counts,
        probes,
        kind,
        min_dihedral,
        preprocess_seconds: t0.elapsed().as_secs_f64(),
    })
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
            meshless,
            coupled,
            ..
        } = &mut prep;
        let mut frames = FrameWriter::new(
            &staging,
            &name,
            mesh,
            meshless.as_ref(),
            coupled.as_ref(),
            labels,
            opts.vtu_format,
        )?;
        let run = solver::run_streaming(model, &settings, &mut |m, t, u| frames.write(m, t, u));
        frames.write_series()?;
        let out = run.map_err(|e| with_setup_warnings(e, &prep.warnings))?;
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
fn with_setup_warnings(e: Error, warnings: &[String]) -> Error {
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

/// "fe", "coupled" or "meshless".
pub fn method_name(prep: &Prepared) -> &'static str {
    if prep.meshless.is_some() {
        "meshless"
    } else if prep.coupled.is_some() {
        "coupled"
    } else {
        "fe"
    }
}

/// The element or basis of a prepared scene: "hex8", "mls", "hex8+mls", ...
pub fn element_label(scene: &Scene, prep: &Prepared) -> String {
    match (&prep.meshless, &prep.coupled) {
        (Some(_), _) => basis_name(scene).into(),
        (None, Some(_)) => format!("{}+{}", prep.kind.name(), basis_name(scene)),
        (None, None) => prep.kind.name().into(),
    }
}

/// The largest |F_int - F_ext| at a free DOF over the largest |F_int| component at any node
/// ([`crate::report::Summary::equilibrium_residual`]). Nodes a corrector or contact moves
/// after the update carry constraint forces, not residuals, and are left out.
fn equilibrium_residual<M: crate::material::Material>(
    model: &crate::solver::Model<M>,
    f_int: &[nalgebra::Vector3<f64>],
) -> f64 {
    let n = f_int.len().min(model.constraints.mask.len());
    let mut moved = vec![false; n];
    for i in model.corrected_nodes() {
        if let Some(m) = moved.get_mut(i as usize) {
            *m = true;
        }
    }
    let (mut residual, mut scale) = (0.0f64, 0.0f64);
    for i in 0..n {
        let fe = model
            .f_ext
            .get(i)
            .copied()
            .unwrap_or_else(nalgebra::Vector3::zeros);
        for k in 0..3 {
            scale = scale.max(f_int[i][k].abs());
            if !moved[i] && !model.constraints.mask[i][k] {
                residual = residual.max((f_int[i][k] - fe[k]).abs());
            }
        }
    }
    if scale > 0.0 {
        residual / scale
    } else {
        0.0
    }
}

/// Builds the summary of a finished run.
pub fn summarize(scene: &Scene, prep: &Prepared, out: &RunOutput, total_seconds: f64) -> Summary {
    let model = &prep.model;
    let reactions: BTreeMap<String, [f64; 3]> = model
        .reaction_names()
        .into_iter()
        .zip(model.reactions(&out.f_int))
        .map(|(b, r)| (b, [r.x, r.y, r.z]))
        .collect();
    let mut warnings = prep.warnings.clone();
    warnings.extend(out.restarts.iter().cloned());
    let equilibrium_residual = out
        .load_steps
        .is_some()
        .then(|| equilibrium_residual(model, &out.f_int));
    if let Some(r) = equilibrium_residual.filter(|&r| r > crate::report::RESIDUAL_WARNING) {
        warnings.push(format!(
            "equilibrium: the largest out-of-balance force at a free node is {r:.2e} of the \
             largest nodal force at the end of this relaxation (more than {:.0e}): the \
             displacements are not at equilibrium to the digits shown; lower solver.tolerance \
             or raise solver.max_steps",
            crate::report::RESIDUAL_WARNING
        ));
    }
    let balance_error = (scene.solver.mode == Mode::Dynamic).then(|| {
        let input = out.external_work + out.initial_kinetic;
        let scale = input
            .abs()
            .max(out.peak_external_work + out.initial_kinetic);
        (input - out.strain_energy - out.kinetic_energy - out.damping_dissipation).abs()
            / scale.max(f64::MIN_POSITIVE)
    });
    if let Some(b) = balance_error.filter(|&b| b > crate::report::ENERGY_WARNING) {
        warnings.push(format!(
            "energy balance: {:.2} % of the work put in is unaccounted for at the end of this \
             dynamic run (more than {:.0} %): an instability that grew without diverging, most \
             likely; the step ended at {:.4e} s against a critical estimate of {:.4e} s at the \
             start (solver.dt_factor {:.3}). Rerun with a smaller solver.dt_factor and compare",
            100.0 * b,
            100.0 * crate::report::ENERGY_WARNING,
            out.dt,
            out.dt_critical,
            scene.solver.dt_factor,
        ));
    }
    if let Some(c) = &model.contact {
        if c.worst_penetration() > c.tolerance() {
            warnings.push(format!(
                "contact: a step left a surface point {:.3e} m inside a rigid body, more than the \
                 tolerance {:.1e} m (the corrections did not converge within their sweeps; a \
                 sharp edge of the rigid surface or a large step per load increment)",
                c.worst_penetration(),
                c.tolerance()
            ));
        }
    }
    let probes: BTreeMap<String, ProbeResult> = prep
        .probes
        .iter()
        .map(|p| {
            let d = p.displacement(&out.u);
            (
                p.name.clone(),
                ProbeResult {
                    position: [p.position.x, p.position.y, p.position.z],
                    displacement: [d.x, d.y, d.z],
                },
            )
        })
        .collect();
    let reference = scene
        .references
        .iter()
        .filter_map(|(name, r)| {
            let parts: Vec<&str> = r.quantity.split('.').collect();
            let k = match parts.get(2) {
                Some(&"x") => 0,
                Some(&"y") => 1,
                _ => 2,
            };
            let computed = match parts[0] {
                "reaction" => reactions.get(parts[1])?[k],
                _ => probes.get(parts[1])?.displacement[k],
            };
            let value = r.value?;
            let relative_error = (computed - value).abs() / value.abs().max(f64::MIN_POSITIVE);
            Some((
                name.clone(),
                Comparison {
                    quantity: r.quantity.clone(),
                    value,
                    computed,
                    relative_error,
                    source: r.source.clone(),
                },
            ))
        })
        .collect();
    let w = out.external_work;
    Summary {
        scene: scene.name.clone().unwrap_or_default(),
        units: "SI: m, kg, s, N, Pa, J",
        method: method_name(prep).into(),
        element: element_label(scene, prep),
        mode: match scene.solver.mode {
            Mode::Dynamic => "dynamic".into(),
            Mode::Relaxation => "relaxation".into(),
        },
        nodes: model.nodes.len(),
        integration_points: model.points.len(),
        // The step the run started with (step_updates has the shortest one).
        dt: out.step_updates.dt_initial,
        dt_critical: out.dt_critical,
        dt_factor: out.step_updates.dt_initial / out.dt_critical,
        steps: out.steps,
        failed_steps: out.failed_steps,
        restarts: out.restarts.len(),
        step_updates: (out.step_updates.estimates > 0).then_some(out.step_updates),
        simulated_time: out.simulated_time,
        status: match (out.load_steps.is_some(), out.converged) {
            (false, _) => "completed",
            (true, true) => "converged",
            (true, false) => "not converged",
        },
        converged: out.converged,
        equilibrium_residual,
        threads: rayon::current_num_threads(),
        wall_seconds: WallSeconds {
            preprocess: prep.preprocess_seconds,
            solve: out.solve_seconds,
            total: total_seconds,
        },
        reactions,
        contact: model
            .contact
            .as_ref()
            .map(|c| {
                c.names()
                    .enumerate()
                    .map(|(b, name)| {
                        (
                            name.to_string(),
                            crate::report::ContactInfo {
                                points_in_contact: c.points_in_contact()[b],
                                max_penetration: c.worst_penetration(),
                                tolerance: c.tolerance(),
                            },
                        )
                    })
                    .collect()
            })
            .unwrap_or_default(),
        loads: model
            .loads
            .names()
            .iter()
            .zip(model.loads.totals())
            .map(|(n, t)| (n.clone(), [t.x, t.y, t.z]))
            .collect(),
        probes,
        energy: Energy {
            external_work: w,
            strain_energy: out.strain_energy,
            kinetic: out.kinetic_energy,
            peak_external_work: out.peak_external_work,
            damping_dissipation: (out.damping_dissipation > 0.0).then_some(out.damping_dissipation),
            // Initial kinetic energy (initial velocities) is energy put in, like the work.
            balance_error,
        },
        reference,
        mesh: MeshInfo {
            elements: prep.mesh.num_cells(),
            min_dihedral_deg: prep.min_dihedral.map(|m| m.0),
            min_dihedral_element: prep.min_dihedral.map(|m| m.1),
            critical: out.critical,
            volume: model.points.total_weight(),
        },
        support_nodes: prep
            .meshless
            .as_ref()
            .map(|m| m.support_statistics())
            .or_else(|| prep.coupled.as_ref().map(|c| c.support_statistics()))
            .map(|(mean, min, max)| SupportNodes { mean, min, max }),
        removed_nodes: prep.meshless.as_ref().map(|m| m.removed_nodes),
        bc_method: prep.bc_method.map(|b| b.name().to_string()),
        meshless: prep.meshless.as_ref().map(|m| MeshlessInfo {
            cloud: m.cloud.clone(),
            integration: m.integration.clone(),
            basis: basis_long(scene),
            support_rule: m.support.describe(),
            exact_volume: m.exact_volume,
            adaptive: m.adaptive.clone(),
        }),
        coupled: prep.coupled.as_ref().map(|c| {
            use crate::coupling::{CellRole, NodeRole};
            CoupledInfo {
                fe_layers: scene.discretization.fe_layers(),
                fe_cells: c.regions.cells(CellRole::Fe),
                transition_cells: c.regions.cells(CellRole::Transition),
                meshless_cells: c.interior.num_cells(),
                fe_nodes: c.regions.nodes(NodeRole::Fe),
                interface_nodes: c.regions.nodes(NodeRole::Interface),
                meshless_nodes: c.regions.nodes(NodeRole::Meshless),
                fe_points: c.fe_points,
                transition_points: c.transition_points,
                meshless_points: c.meshless_points,
                full_rule_cells: c.full_rule_cells,
                basis: basis_long(scene),
                support_rule: c.support.describe(),
                adaptive: c.adaptive.clone(),
            }
        }),
        warnings,
        relaxation: out.relaxation.clone(),
        load_steps: out.load_steps,
        momentum: (scene.mode_is_dynamic()).then_some(out.momentum),
    }
}

fn basis_name(scene: &Scene) -> &'static str {
    match scene.discretization.basis {
        crate::scene::Basis::Linear => "mls",
        crate::scene::Basis::Quadratic => "mmls",
    }
}

fn basis_long(scene: &Scene) -> String {
    match scene.discretization.basis {
        crate::scene::Basis::Linear => "linear MLS".into(),
        crate::scene::Basis::Quadratic => {
            format!("quadratic MMLS (mu = {:e})", scene.discretization.mu)
        }
    }
}
