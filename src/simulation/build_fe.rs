//! A finite-element run's preparation: the mesh, its element points, boundaries, probes and loads.

use std::time::Instant;

use nalgebra::Vector3;

use crate::fe::ElementKind;
use crate::geometry::quality;
use crate::material::Material;
use crate::probe::Probe;
use crate::scene::Scene;
use crate::solver::Model;
use crate::{fe, Error, Result};

use super::surface::Discretized;
use super::translate::{load_mesh_input, material};
use super::{
    add_loads_and_contact, body_mesh, boundaries, centroid, hourglass_modulus, name_file_element,
    regions, select_nodes, set_probe, Prepared,
};

/// FE branch of [`prepare`].
pub(super) fn prepare_fe(scene: &Scene) -> Result<Prepared> {
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
