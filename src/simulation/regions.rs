//! Tissue regions: which material each quadrature point takes.

use nalgebra::Vector3;

use crate::io::model::MeshInput;
use crate::material::{Material, Solid};
use crate::quadrature::{PointKind, QuadraturePoints};
use crate::scene::Scene;
use crate::{Error, InputKind, Result};

/// Where each quadrature point lies (discretization order): the position tested against a
/// region's `select` (m) and the mesh-file element it belongs to (for `elements`; None for
/// points of cells the file does not hold).
pub(super) struct Places {
    pub position: Vec<Vector3<f64>>,
    pub element: Vec<Option<usize>>,
}

/// The model's materials, each point's index into them and each region's point count.
pub(super) type PointMaterials = (Vec<Solid>, Vec<u16>, Vec<super::RegionPoints>);

/// The model's materials and each point's index into them: 0 is `[material]`, k the k-th
/// `[regions]` entry in name order. Without regions the index list is empty (every point has
/// `[material]`). A point in two regions, or a region with no point, is an error naming it.
pub(super) fn point_materials(
    scene: &Scene,
    input: Option<&MeshInput>,
    places: &Places,
) -> Result<PointMaterials> {
    let mut materials = vec![scene.material.solid()];
    if scene.regions.is_empty() {
        return Ok((materials, Vec::new(), Vec::new()));
    }
    let n = places.position.len();
    let mut index = vec![0u16; n];
    let mut counts = Vec::new();
    let names: Vec<&String> = scene.regions.keys().collect();
    let image = if scene.regions.values().any(|r| r.labels.is_some()) {
        super::translate::geometry_image(scene)?
    } else {
        None
    };
    for (k, (name, r)) in scene.regions.iter().enumerate() {
        let what = format!("region '{name}'");
        let members: Vec<usize> = match (&r.select, &r.elements) {
            _ if r.surface.is_some() => {
                let surface = super::translate::region_surface(scene, name)?;
                let tool = crate::geometry::surface_distance::SurfaceDistance::new(surface)?;
                let v: Vec<usize> = (0..n)
                    .filter(|&p| tool.signed_distance(&places.position[p]).0 > 0.0)
                    .collect();
                if v.is_empty() {
                    return Err(Error::input(InputKind::Selection, format!(
                        "{what}: no integration point lies inside its surface (is it inside the body, in the body's units?)"
                    )));
                }
                v
            }
            _ if r.labels.is_some() => {
                let labels = r.labels.as_deref().unwrap_or_default();
                let Some(super::translate::SceneImage { image: im, path }) = image.as_ref() else {
                    return Err(Error::input(
                        InputKind::Value,
                        format!(
                        "{what}: labels select voxels of geometry.image, which this scene has not"
                    ),
                    ));
                };
                let v: Vec<usize> = (0..n)
                    .filter(|&p| {
                        im.nearest(&places.position[p])
                            .is_some_and(|l| labels.contains(&(l.round() as i64)))
                    })
                    .collect();
                if v.is_empty() {
                    return Err(Error::input(
                        InputKind::Selection,
                        format!(
                        "{what}: no integration point lies in a voxel labelled {labels:?} of {} \
                         (the labels' tissue may be smaller than the discretization.size)",
                        path.display()
                    ),
                    ));
                }
                v
            }
            (Some(sel), _) => sel.select(&places.position, &what).map_err(|e| {
                Error::input(
                    InputKind::Value,
                    format!("{e} (a region selects integration points)"),
                )
            })?,
            (None, Some(set)) => {
                let m = input.ok_or_else(|| {
                    Error::input(InputKind::Value, format!(
                        "{what}: elements = '{set}' needs a mesh file (geometry.mesh) with that element set"
                    ))
                })?;
                let cells = m.element_sets.get(set).ok_or_else(|| {
                    let known: Vec<&String> = m.element_sets.keys().collect();
                    Error::input(
                        InputKind::Selection,
                        format!(
                            "{what}: the mesh file has no element set '{set}' (it has {known:?})"
                        ),
                    )
                })?;
                let mut inside = vec![false; m.mesh.num_cells()];
                for &e in cells {
                    if let Some(x) = inside.get_mut(e) {
                        *x = true;
                    }
                }
                let v: Vec<usize> = (0..n)
                    .filter(|&p| places.element[p].is_some_and(|e| inside.get(e) == Some(&true)))
                    .collect();
                if v.is_empty() {
                    return Err(Error::input(
                        InputKind::Selection,
                        format!(
                        "{what}: no integration point lies in element set '{set}' (meshless \
                         points know their element only when the cloud is the mesh file's vertices)"
                    ),
                    ));
                }
                v
            }
            (None, None) => unreachable!("validated: a region selects"),
        };
        let id = u16::try_from(k + 1)
            .map_err(|_| Error::input(InputKind::Limit, "more than 65,534 regions"))?;
        for &p in &members {
            if index[p] != 0 {
                let x = places.position[p];
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                    "regions '{}' and '{name}' overlap at the point at ({:.4e}, {:.4e}, {:.4e}) m; \
                     a point takes one material: make the selections disjoint",
                    names[index[p] as usize - 1],
                    crate::error::Sci(x.x),
                    crate::error::Sci(x.y),
                    crate::error::Sci(x.z)),
                ));
            }
            index[p] = id;
        }
        counts.push(super::RegionPoints {
            name: name.clone(),
            points: members.len(),
        });
        materials.push(scene.material.with(r).solid());
    }
    Ok((materials, index, counts))
}

/// Scales the hourglass vectors G of one-point hexahedra built with the first material's
/// hourglass modulus to their own material's: HG = G G^T grows with the modulus (Joldes et
/// al. 2008), so G by sqrt(modulus_r / modulus_0). `modulus(m)` is material m's (Pa).
pub(super) fn scale_hourglass(
    qp: &mut QuadraturePoints,
    point_material: &[u16],
    modulus: &dyn Fn(&Solid) -> f64,
    materials: &[Solid],
) {
    if point_material.is_empty() {
        return;
    }
    let m0 = modulus(&materials[0]);
    for (p, &m) in point_material.iter().enumerate() {
        if let (PointKind::Hourglass(h), true) = (qp.kinds[p], m != 0) {
            let f = (modulus(&materials[m as usize]) / m0).sqrt();
            qp.hourglass[h as usize] *= f;
        }
    }
}

/// The largest bulk-to-shear ratio kappa / mu over the materials, and its material.
pub(super) fn stiffest_ratio(materials: &[Solid]) -> (f64, &Solid) {
    materials
        .iter()
        .map(|m| (m.kappa() / m.lame().1, m))
        .fold((0.0, &materials[0]), |a, b| if b.0 > a.0 { b } else { a })
}
