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
    // Quadratic elements: the tet mesh gains its edge nodes; the linear split of each element
    // over all nodes is the geometry that surfaces, selections and outputs work on.
    let t10 = if kind == ElementKind::Tet10 {
        Some(fe::tet10::Tet10Mesh::from_tet4(&mesh)?)
    } else {
        None
    };
    let mut points = match &t10 {
        Some(t) => t.points(),
        None => fe::element_points(&mesh, kind, kappa_hg, modulus),
    }
    .map_err(|e| name_file_element(e, input.as_ref()))?;
    let per_element = points.len() / mesh.num_cells().max(1);
    let places = regions::Places {
        position: (0..points.len())
            .map(|p| centroid(&mesh, p / per_element))
            .collect(),
        element: (0..points.len()).map(|p| Some(p / per_element)).collect(),
    };
    let (materials, point_material, region_counts) =
        regions::point_materials(scene, input.as_ref(), &places)?;
    regions::scale_hourglass(
        &mut points,
        &point_material,
        &|m| hourglass_modulus(scene, m),
        &materials,
    );
    let linear = mesh;
    let mesh = t10.as_ref().map_or_else(|| linear.clone(), |t| t.split());
    // A selection takes the edge nodes between the vertices it holds (named sets are of the
    // linear mesh's vertices).
    let extend = |ids: &mut Vec<usize>| {
        if let Some(t) = &t10 {
            t.extend_selection(ids);
        }
    };
    let mut bnd = boundaries(scene, &mesh.nodes, input.as_ref(), &|| {
        Discretized::Fe(&mesh).surface_nodes()
    })?;
    for b in bnd.iter_mut().filter(|b| b.node_values.is_none()) {
        extend(&mut b.nodes);
    }
    let probes = scene
        .probes
        .iter()
        .map(|(name, p)| match (&p.select, p.position) {
            (Some(sel), _) => {
                let mut ids =
                    select_nodes(sel, &mesh.nodes, &format!("probe '{name}'"), input.as_ref())?;
                extend(&mut ids);
                let w = 1.0 / ids.len() as f64;
                Ok(set_probe(
                    name,
                    &mesh.nodes,
                    ids.iter().map(|&i| (i, w)).collect(),
                ))
            }
            (None, Some(x)) => {
                let mut pr = Probe::locate(name, Vector3::from(x), &linear)?;
                if let Some(t) = &t10 {
                    // The element's quadratic shape functions at the point's barycentric
                    // coordinates.
                    let l = [pr.weights[0], pr.weights[1], pr.weights[2], pr.weights[3]];
                    (pr.nodes, pr.weights) = t.weights(pr.element, l).into_iter().unzip();
                }
                Ok(pr)
            }
            (None, None) => Err(Error::Input(format!(
                "probe '{name}' has neither position nor select"
            ))),
        })
        .collect::<Result<Vec<_>>>()?;
    let min_dihedral = quality::min_dihedral_angle(&linear);
    log::info!("masses, boundaries, loads");
    // HRZ lumping, from the points in element order (the model sorts them).
    let t10_mass = t10.as_ref().map(|t| {
        let rho = |e: usize| {
            let m = point_material.get(4 * e).copied().unwrap_or(0) as usize;
            materials[m].density()
        };
        t.lumped_masses(&points, &rho)
    });
    let mut model = Model::with_materials(
        mesh.nodes.clone(),
        points,
        materials,
        point_material.clone(),
        bnd,
    )?;
    if let Some(mass) = &t10_mass {
        model.set_lumped_masses(mass)?;
    }
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
        source_volume: None,
    })
}
