//! A meshless run's parts: the node cloud, integration points and supports, boundaries, and
//! their EBCIEM / SEBCIEM correction where the shape functions do not interpolate.

use std::time::Instant;

use nalgebra::Vector3;

use crate::fe::ElementKind;
use crate::material::Solid;
use crate::meshless::discretize::{self, MeshlessBuild};
use crate::meshless::essential::MeshlessCorrector;
use crate::report::{Warning, WarningKind};
use crate::scene::{BcMethod, ProbeSpec, Scene};
use crate::solver::Model;
use crate::Result;

use super::build::{assemble, Discretization, Parts};
use super::surface::Discretized;
use super::translate::{cloud_sets, load_mesh_input, meshless_settings};
use super::{boundaries, imposition, regions, select_nodes, Prepared};

/// Meshless branch of [`super::prepare`]: cloud, integration points, supports and shape functions,
/// masses, boundaries (EBCIEM / SEBCIEM correction or prescribed nodal parameters) and probes
/// interpolated with the shape functions.
pub(super) fn prepare_meshless(scene: &Scene) -> Result<Prepared> {
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
            let x = match p {
                ProbeSpec::Select(sel) => {
                    let what = format!("probe '{name}'");
                    v.extend(select_nodes(
                        sel,
                        nodes,
                        &what,
                        &format!("probes.{name}.select"),
                        input.as_ref(),
                    )?);
                    continue;
                }
                ProbeSpec::Position(x) => Vector3::from(*x),
            };
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
    let mut warnings = Warning::all(WarningKind::Discretization, build.warnings.clone());
    if method == BcMethod::Ebciem
        && scene.discretization.support == crate::scene::SupportKind::Nearest
    {
        warnings.push(Warning::new(WarningKind::Boundary, "bc_method = 'ebciem' with support = 'nearest': the nearest-node shape functions jump where the \
             support changes, and EBCIEM runs of this kind diverged in our tests; prefer 'sebciem' (the default, 'auto')",
                ));
    }
    let bnd = boundaries(scene, &build.nodes, input.as_ref(), &|| {
        Discretized::Meshless(&build).surface_nodes()
    })?;
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
            .map(|&o| o.filter(|_| from_file.is_some()).map(|o| o / per_cell))
            .collect(),
    };
    let parts = Parts {
        mesh: build.background.clone(),
        points: build.points.clone(),
        method: Discretization::Meshless {
            build: Box::new(build),
            bc_method: method,
        },
        quadratic: None,
        places,
        boundaries: bnd,
        kind: ElementKind::Tet4,
        min_dihedral: None,
        warnings,
    };
    assemble(scene, input.as_ref(), parts, t0)
}

/// The EBCIEM / SEBCIEM correction of the boundaries of `model` that prescribe components
/// (`method` other than direct correction), built after the masses are final.
pub(super) fn impose(
    build: &MeshlessBuild,
    method: BcMethod,
    model: &mut Model<Solid>,
    warnings: &mut Vec<Warning>,
) -> Result<()> {
    let corrected: Vec<bool> = model
        .boundaries()
        .iter()
        .map(|b| method != BcMethod::Correction && b.components.iter().any(|c| c.is_some()))
        .collect();
    if !corrected.iter().any(|&c| c) {
        return Ok(());
    }
    let (corr, report) =
        MeshlessCorrector::new(build, model.boundaries(), model.mass(), imposition(method))?;
    if report.lumped_nodes > 0 {
        warnings.push(Warning::new(WarningKind::Boundary, format!(
            "EBCIEM: {} constrained node(s) lie on no boundary triangle whose vertices are all constrained; \
             their boundary force is lumped at the node (SEBCIEM)",
            report.lumped_nodes
        )));
    }
    model.set_corrector(Box::new(corr), corrected)
}
