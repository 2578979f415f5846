//! A meshless run's preparation: the node cloud, integration points and supports, boundaries
//! (EBCIEM / SEBCIEM where not interpolating), probes and loads.

use std::time::Instant;

use nalgebra::Vector3;

use crate::fe::ElementKind;
use crate::meshless::discretize;
use crate::meshless::essential::MeshlessCorrector;
use crate::probe::Probe;
use crate::scene::{BcMethod, Scene};
use crate::solver::Model;
use crate::{Error, Result};

use super::surface::Discretized;
use super::translate::{cloud_sets, load_mesh_input, meshless_settings};
use super::{
    add_loads_and_contact, boundaries, imposition, mean_probe, regions, select_nodes, translate,
    Prepared,
};

/// Meshless branch of [`prepare`]: cloud, integration points, supports and shape functions,
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
                return mean_probe(name, sel, &build.nodes, input.as_ref(), |i| {
                    let s = build.shape_values(&build.nodes[i], &|| format!("probe '{name}'"))?;
                    Ok(s.ids.into_iter().zip(s.phi).collect())
                });
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
        source_volume: None,
    })
}
