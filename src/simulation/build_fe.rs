//! A finite-element run's parts: the mesh (tet10: with its edge nodes), its element points and
//! their places, and the boundaries.

use crate::fe::ElementKind;
use crate::geometry::quality;
use crate::scene::Scene;
use crate::{fe, Result};

use super::build::{assemble, Discretization, MeshStart, Parts};
use super::surface::Discretized;
use super::{boundaries, centroid, name_file_element, regions, Prepared};

/// FE branch of [`super::prepare`].
pub(super) fn prepare_fe(scene: &Scene) -> Result<Prepared> {
    let MeshStart {
        t0,
        input,
        mesh,
        kind,
        lame: (lambda, mu),
        warnings,
    } = MeshStart::of(scene)?;
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
    let points = match &t10 {
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
    let min_dihedral = quality::min_dihedral_angle(&mesh);
    let (body, quadratic) = match t10 {
        Some(t) => (t.split(), Some((t, mesh))),
        None => (mesh, None),
    };
    let q = super::surface::QuadraticFe::of(&quadratic);
    let view = Discretized::Fe(&body, q);
    let mut bnd = boundaries(scene, &body.nodes, input.as_ref(), &|| view.surface_nodes())?;
    for b in bnd.iter_mut().filter(|b| b.node_values.is_none()) {
        view.extend_selection(&mut b.nodes);
    }
    log::info!("masses, boundaries, loads");
    let parts = Parts {
        mesh: body,
        method: Discretization::Fe,
        quadratic,
        points,
        places,
        boundaries: bnd,
        kind,
        min_dihedral,
        warnings,
    };
    assemble(scene, input.as_ref(), parts, t0)
}
