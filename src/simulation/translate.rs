//! The scene schema translated into the typed settings of the lower layers: the body's mesh
//! (built-in shapes, TetGen, mesh files), the material, the meshless and coupled settings and
//! the integrator's. The only place besides the pipeline itself that reads a [`Scene`].

use crate::memory::PlannedMesh;
use std::path::PathBuf;

use nalgebra::Vector3;

use crate::bc::{CurveTable, LoadCurve};
use crate::fe::ElementKind;
use crate::geometry::domain::Domain;
use crate::geometry::{shapes, ElementShape, Mesh};
use crate::io::model::MeshInput;
use crate::material::Solid;
use crate::meshless::adaptive::AdaptiveSettings;
use crate::meshless::cloud;
use crate::meshless::discretize::{self, CloudSource, Integration, MeshlessSettings};
use crate::meshless::integration::TetRule;
use crate::meshless::mls::MlsSettings;
use crate::meshless::support::SupportRule;
use crate::scene::{
    BcMethod, CloudKind, ElementName, Geometry, ImageBody, IntegrationKind, Mesher, Method, Scene,
    SupportKind,
};
use crate::solver::Settings;
use crate::{Error, InputKind, Result};

/// The material a scene asks for (`[material]`; regions come on top, see `regions`).
pub fn material(scene: &Scene) -> Solid {
    scene.material.solid()
}

fn count(len: f64, h: f64, min: usize) -> usize {
    ((len / h).round() as usize).max(min)
}

/// Whether TetGen makes the scene's mesh: `mesher = "tetgen"`, or a surface file (which only
/// TetGen can fill).
pub fn tetgen_meshed(scene: &Scene) -> bool {
    scene.discretization.mesher == Mesher::Tetgen
        || matches!(
            scene.geometry,
            Geometry::Surface { .. }
                | Geometry::Image {
                    body: ImageBody::Surface,
                    ..
                }
        )
}

/// A scene's labelled image, read, and the file it came from.
pub struct SceneImage {
    pub image: crate::io::image::Image,
    pub path: PathBuf,
}

/// The scene's labelled image (`geometry.image`), read; None for other geometries.
pub fn geometry_image(scene: &Scene) -> Result<Option<SceneImage>> {
    match &scene.geometry {
        Geometry::Image { file, .. } => {
            let path = scene_path(scene, file);
            let image = crate::io::image::read_image(&path)?;
            log::info!(
                "image {}: {:?} voxels of {:.4e} x {:.4e} x {:.4e} m",
                path.display(),
                image.dims,
                image.spacing()[0],
                image.spacing()[1],
                image.spacing()[2]
            );
            Ok(Some(SceneImage { image, path }))
        }
        _ => Ok(None),
    }
}

/// The volume (m^3) the scene's geometry gives, and what gives it: a labelled image's chosen
/// voxels, or what a surface file encloses; None for built-in shapes and mesh files (their mesh
/// is the geometry).
pub fn geometry_volume(scene: &Scene) -> Result<Option<super::SourceVolume>> {
    match &scene.geometry {
        Geometry::Image { labels, .. } => {
            let Some(SceneImage { image, path }) = geometry_image(scene)? else {
                return Ok(None);
            };
            let mask = crate::geometry::image_body::tissue_mask(&image, labels);
            let voxel = image.axes().determinant().abs();
            let n = mask.iter().filter(|&&m| m).count();
            Ok(Some(super::SourceVolume {
                volume: n as f64 * voxel,
                of: format!("the {n} labelled voxels of {}", path.display()),
            }))
        }
        Geometry::Surface { file, units } => {
            let path = scene_path(scene, file);
            let surface = crate::io::surface_file::read_surface(&path, *units)?;
            Ok(Some(super::SourceVolume {
                volume: surface.volume(),
                of: format!("what {} encloses", path.display()),
            }))
        }
        _ => Ok(None),
    }
}

/// Voxels per block edge for an image body: the discretization's size over the smallest
/// voxel spacing, at least 1.
fn image_block(scene: &Scene, image: &crate::io::image::Image) -> usize {
    let h = scene.discretization.size.unwrap_or(0.0);
    let s = image.spacing().into_iter().fold(f64::INFINITY, f64::min);
    ((h / s).round() as usize).max(1)
}

/// A `shape = "surface"` contact's closed surface: read from a surface file, or extracted from
/// a labelled image's `labels` (as `geometry.image`'s, on blocks about `discretization.size`);
/// moved along its normals by `offset` (m) and, with `inside`, turned to face in (the solid is
/// then everything outside it: a skull around the tissue).
pub fn rigid_surface(
    scene: &Scene,
    path: &std::path::Path,
    c: &crate::scene::ContactSpec,
) -> Result<crate::geometry::closed_surface::ClosedSurface> {
    let what = path.display().to_string();
    let mut surface = if crate::io::image::ImageFormat::from_path(path).is_some() {
        let image = crate::io::image::read_image(path)?;
        let labels = c.labels.clone().unwrap_or_default();
        let mask = crate::geometry::image_body::body_mask(&image, &labels, &what)?;
        let block = image_block(scene, &image);
        crate::geometry::image_body::label_surface(
            &image,
            &mask,
            block,
            crate::scene::DEFAULT_IMAGE_SMOOTHING,
            false,
            &what,
        )?
        .0
    } else {
        crate::io::surface_file::read_surface(path, c.units.unwrap_or(1.0))?
    };
    if let Some(offset) = c.offset.filter(|&o| o != 0.0) {
        surface = crate::geometry::closed_surface::offset(&surface, offset, &what)?;
    }
    if c.inside == Some(true) {
        for t in surface.triangles.iter_mut() {
            t.swap(1, 2);
        }
    }
    Ok(surface)
}

/// The closed surface of `[regions.NAME] surface`, read (checked, outward).
pub fn region_surface(
    scene: &Scene,
    name: &str,
) -> Result<crate::geometry::closed_surface::ClosedSurface> {
    let r = scene
        .regions
        .get(name)
        .ok_or_else(|| Error::input(InputKind::Selection, format!("no region '{name}'")))?;
    let file = r
        .surface
        .as_ref()
        .ok_or_else(|| Error::input(InputKind::Value, format!("region '{name}' has no surface")))?;
    crate::io::surface_file::read_surface(&scene_path(scene, file), r.units.unwrap_or(1.0))
}

/// The body's surface with the scene's region surfaces inside it, for TetGen to mesh as
/// internal boundaries (checked: inside the body's material, crossing neither it nor each
/// other).
#[cfg(feature = "tetgen")]
fn with_region_surfaces(
    scene: &Scene,
    body: crate::geometry::closed_surface::ClosedSurface,
) -> Result<(
    crate::geometry::closed_surface::ClosedSurface,
    Vec<Vec<usize>>,
)> {
    let mut inner = Vec::new();
    for (name, r) in &scene.regions {
        if r.surface.is_some() {
            inner.push((name.clone(), region_surface(scene, name)?));
        }
    }
    crate::geometry::closed_surface::nest(body, &inner)
}

/// The hexahedra of an image's voxels (`body = "voxels"`), split into tets for tet elements.
fn image_voxel_mesh(scene: &Scene, shape: ElementShape) -> Result<Mesh> {
    let Some(SceneImage { image, path }) = geometry_image(scene)? else {
        unreachable!("called for image geometries")
    };
    let Geometry::Image { labels, .. } = &scene.geometry else {
        unreachable!("called for image geometries")
    };
    let what = path.display().to_string();
    let mask = crate::geometry::image_body::body_mask(&image, labels, &what)?;
    let block = image_block(scene, &image);
    let (mesh, dropped) = crate::geometry::image_body::voxel_mesh(&image, &mask, block, &what)?;
    if dropped > 0 {
        log::warn!("{what}: {dropped} block(s) of tissue apart from the body were dropped (they would float free)");
    }
    log::info!(
        "voxel mesh of {what}: {} hexahedra of {block}^3 voxels, {} nodes",
        mesh.num_cells(),
        mesh.nodes.len()
    );
    Ok(match shape {
        ElementShape::Hex8 => mesh,
        ElementShape::Tet4 => crate::geometry::mesh::hex_to_tets(mesh),
    })
}

/// The surface of an image's tissue (`body = "surface"`), for TetGen.
#[cfg(feature = "tetgen")]
fn image_surface(scene: &Scene) -> Result<crate::geometry::closed_surface::ClosedSurface> {
    let Some(SceneImage { image, path }) = geometry_image(scene)? else {
        unreachable!("called for image geometries")
    };
    let Geometry::Image {
        labels, smoothing, ..
    } = &scene.geometry
    else {
        unreachable!("called for image geometries")
    };
    let what = path.display().to_string();
    let mask = crate::geometry::image_body::body_mask(&image, labels, &what)?;
    let block = image_block(scene, &image);
    let (surface, report) =
        crate::geometry::image_body::label_surface(&image, &mask, block, *smoothing, true, &what)?;
    if report.islands > 0 {
        log::warn!(
            "{what}: {} piece(s) of tissue apart from the body were dropped (they would float free)",
            report.islands
        );
    }
    log::info!(
        "surface of {what}: {} triangles at {block} voxel(s) a block, {} cavit{}, {:.4e} m^3",
        surface.triangles.len(),
        report.cavities,
        if report.cavities == 1 { "y" } else { "ies" },
        surface.volume()
    );
    Ok(surface)
}

/// Builds the scene's mesh (structured hex/tet or TetGen tets).
pub fn build_mesh(scene: &Scene) -> Result<Mesh> {
    crate::interrupt::check(|| "before meshing".into())?;
    let d = &scene.discretization;
    let kind: ElementKind = d.element.into();
    let shape = kind.shape();
    if let Geometry::Mesh { .. } = &scene.geometry {
        return Ok(load_mesh(scene)?.mesh);
    }
    if let Geometry::Image {
        body: ImageBody::Voxels,
        ..
    } = &scene.geometry
    {
        return image_voxel_mesh(scene, shape);
    }
    if tetgen_meshed(scene) {
        if shape != ElementShape::Tet4 {
            let what = match &scene.geometry {
                Geometry::Image { .. } => "geometry.image with body = \"surface\" (TetGen fills the labels' surface) makes tetrahedra: use element = 'tet4-anp', 'tet4' or 'tet10', or body = \"voxels\" for hexahedra",
                Geometry::Surface { .. } => "geometry.surface (TetGen fills it) makes tetrahedra: use element = 'tet4-anp', 'tet4' or 'tet10'",
                _ => "discretization.mesher = 'tetgen' makes tetrahedra: use element = 'tet4-anp', 'tet4' or 'tet10'",
            };
            return Err(Error::input(InputKind::Unsupported, what));
        }
        log::info!("meshing with TetGen");
        let m = tetgen_mesh(scene)?;
        log::info!(
            "TetGen mesh: {} nodes, {} tets",
            m.nodes.len(),
            m.num_cells()
        );
        return Ok(m);
    }
    match (&scene.geometry, structured_divisions(scene)?) {
        (Geometry::Box { min, max }, Some(div)) => {
            let (lo, hi) = (Vector3::from(*min), Vector3::from(*max));
            match shape {
                ElementShape::Hex8 => shapes::box_hex(lo, hi, div),
                ElementShape::Tet4 => shapes::box_tet(lo, hi, div),
            }
        }
        (Geometry::Cylinder { radius, height }, Some([ni, nr, nz])) => match shape {
            ElementShape::Hex8 => shapes::cylinder_hex(*radius, *height, ni, nr, nz),
            ElementShape::Tet4 => shapes::cylinder_tet(*radius, *height, ni, nr, nz),
        },
        (Geometry::HalfEllipsoid { .. }, _) => Err(Error::input(
            InputKind::Unsupported,
            "geometry.shape = 'half_ellipsoid' has no structured mesh: use mesher = 'tetgen' \
             (discretization.mesher = \"tetgen\" with element = 'tet4-anp' or 'tet4')",
        )),
        _ => Ok(load_mesh(scene)?.mesh),
    }
}

/// The divisions of the structured mesh of a box ([nx, ny, nz]) or cylinder ([n_inner,
/// n_radial, n_axial]): `divisions`, or from `size`. None for other geometry.
fn structured_divisions(scene: &Scene) -> Result<Option<[usize; 3]>> {
    let d = &scene.discretization;
    let from_size = |h: f64| match &scene.geometry {
        Geometry::Box { min, max } => Some(std::array::from_fn(|k| count(max[k] - min[k], h, 1))),
        Geometry::Cylinder { radius, height } => Some([
            count(*radius, h, 2),
            count(0.5 * radius, h, 1),
            count(*height, h, 1),
        ]),
        _ => None,
    };
    match (&scene.geometry, d.divisions, d.size) {
        (Geometry::Box { .. } | Geometry::Cylinder { .. }, Some(div), _) => Ok(Some(div)),
        (_, _, Some(h)) => Ok(from_size(h)),
        (Geometry::Box { .. } | Geometry::Cylinder { .. }, None, None) => unreachable_sizing(),
        _ => Ok(None),
    }
}

/// The built-in shape's mesh of `shape` elements before it is made: (nodes, elements, what it
/// is, for messages). Exact for a structured mesh; for TetGen at the fewest it is expected to
/// make ([`tetgen_tets`]; about 6.5 tets a node). None for a mesh file (read, not planned) or
/// a scene that cannot be meshed so (its error comes from [`build_mesh`]).
pub fn planned_mesh(scene: &Scene, shape: ElementShape) -> Option<PlannedMesh> {
    if let Geometry::Mesh { .. } = &scene.geometry {
        return None;
    }
    if let Some(TetgenEstimate { tets, edge }) =
        tetgen_tets(scene).filter(|_| shape == ElementShape::Tet4)
    {
        return Some(PlannedMesh {
            nodes: tets / 6.5,
            elements: tets,
            what: format!("a TetGen mesh of about {tets:.0} tets or more (edge {edge} m)"),
        });
    }
    let div = structured_divisions(scene).ok()??;
    let (nodes, cells) = match &scene.geometry {
        Geometry::Box { .. } => shapes::box_counts(div, shape),
        _ => shapes::cylinder_counts(div, shape),
    };
    Some(PlannedMesh {
        nodes,
        elements: cells,
        what: format!("the structured mesh ({nodes:.0} nodes, {cells:.0} elements)"),
    })
}

fn unreachable_sizing<T>() -> Result<T> {
    Err(Error::input(
        InputKind::Value,
        "discretization: give `size` (m) or `divisions`",
    ))
}

/// TetGen's tets per (volume / maximum tet volume), at least: see [`tetgen_tets`].
const TETGEN_TETS_PER_BOUND: f64 = 1.8;

/// The target edge length (m) of a TetGen mesh: `size`, or for the half ellipsoid the
/// smallest of its bounding box [2a, 2b, c] divided by `divisions`.
fn tetgen_edge(scene: &Scene) -> Result<f64> {
    let d = &scene.discretization;
    match (d.size, d.divisions, &scene.geometry) {
        (Some(h), _, _) => Ok(h),
        (None, Some(div), Geometry::HalfEllipsoid { semi_axes: s }) => {
            Ok([2.0 * s[0], 2.0 * s[1], s[2]]
                .iter()
                .zip(div)
                .map(|(len, n)| len / n.max(1) as f64)
                .fold(f64::INFINITY, f64::min))
        }
        _ => Err(Error::input(
            InputKind::Value,
            "discretization.mesher = 'tetgen' needs `size` (target edge length, m)",
        )),
    }
}

/// The largest tet TetGen may make for edge `h` (m^3): a regular tetrahedron's volume.
fn tetgen_max_volume(h: f64) -> f64 {
    h.powi(3) / (6.0 * 2f64.sqrt())
}

/// The fewest tets TetGen is expected to make for a scene, and the edge length (m) it meshes
/// at ([`tetgen_tets`]).
pub struct TetgenEstimate {
    pub tets: f64,
    pub edge: f64,
}

/// About how many tets TetGen will make for a built-in shape, at the fewest, and the edge
/// length (m); None when the scene is not meshed by TetGen. No tet exceeds the volume bound,
/// so the volume over it is the fewest TetGen can make; it made 1.9-2.1x that on cubes (0.1 m
/// at h = 10 and 5 mm, 0.6 m at 8 mm, 1.5 m at 20 mm) and 2.6-3.9x on the brain (h = 6 and
/// 3 mm; radius-edge ratio 2 and 20), and this says 1.8x. The builds refuse a model of that
/// many before TetGen runs (minutes at millions of tets): [`planned_mesh`].
pub fn tetgen_tets(scene: &Scene) -> Option<TetgenEstimate> {
    if !tetgen_meshed(scene) {
        return None;
    }
    let h = tetgen_edge(scene).ok()?;
    let dom = domain(scene)?;
    Some(TetgenEstimate {
        tets: TETGEN_TETS_PER_BOUND * dom.volume() / tetgen_max_volume(h),
        edge: h,
    })
}

#[cfg(feature = "tetgen")]
fn tetgen_mesh(scene: &Scene) -> Result<Mesh> {
    use crate::geometry::tetgen;
    let d = &scene.discretization;
    let h = tetgen_edge(scene)?;
    let max_volume = Some(tetgen_max_volume(h));
    match &scene.geometry {
        Geometry::Box { min, max } => tetgen::tetgen_box(
            Vector3::from(*min),
            Vector3::from(*max),
            max_volume,
            d.radius_edge_ratio,
        ),
        Geometry::Cylinder { radius, height } => {
            let n_circ = count(2.0 * std::f64::consts::PI * radius, h, 8);
            tetgen::tetgen_cylinder(*radius, *height, n_circ, max_volume, d.radius_edge_ratio)
        }
        Geometry::HalfEllipsoid { semi_axes } => {
            let outlines = dome_outlines(scene, *semi_axes)?;
            if outlines.is_empty() {
                tetgen::tetgen_half_ellipsoid(*semi_axes, h, max_volume, d.radius_edge_ratio)
            } else {
                tetgen::tetgen_half_ellipsoid_outlined(
                    *semi_axes,
                    h,
                    max_volume,
                    d.radius_edge_ratio,
                    &outlines,
                )
            }
        }
        Geometry::Surface { file, units } => {
            let path = scene_path(scene, file);
            let surface = crate::io::surface_file::read_surface(&path, *units)?;
            log::info!(
                "surface {}: {} triangles, {:.4e} m^3",
                path.display(),
                surface.triangles.len(),
                surface.volume()
            );
            let (surface, extra) = with_region_surfaces(scene, surface)?;
            let what = surface_what(scene, &format!("surface {}", path.display()));
            tetgen::tetgen_surface(&surface, &extra, max_volume, d.radius_edge_ratio, &what)
        }
        Geometry::Image { file, .. } => {
            let (surface, extra) = with_region_surfaces(scene, image_surface(scene)?)?;
            let what = surface_what(
                scene,
                &format!("surface of the labels of {}", scene_path(scene, file).display()),
            );
            tetgen::tetgen_surface(&surface, &extra, max_volume, d.radius_edge_ratio, &what)
        }
        Geometry::Mesh { .. } => Err(Error::input(InputKind::Value,
            "discretization.mesher = 'tetgen' meshes built-in shapes; a mesh file is used as it is (remove mesher)",
        )),
    }
}

/// `body` and, where regions give surfaces, those surfaces' files: what TetGen meshes, for
/// its messages.
fn surface_what(scene: &Scene, body: &str) -> String {
    let regions: Vec<String> = scene
        .regions
        .iter()
        .filter_map(|(name, r)| {
            r.surface
                .as_ref()
                .map(|f| format!("region '{name}' ({})", scene_path(scene, f).display()))
        })
        .collect();
    if regions.is_empty() {
        body.to_string()
    } else {
        format!("{body} with {}", regions.join(", "))
    }
}

/// The outlines a TetGen half-ellipsoid follows ([`crate::geometry::dome`]): each boundary
/// that selects a cylinder of tissue about the z axis from a floor `min` below the dome to its
/// top (an indenter's plug), and each rigid cylinder tool along the z axis moved along it,
/// graded where `discretization.refine` names them. Other selections and tools are not
/// features: their nodes are whichever the mesh has inside them. `refine` naming anything else
/// is an error.
pub fn dome_outlines(
    scene: &Scene,
    semi_axes: [f64; 3],
) -> Result<Vec<crate::geometry::dome::Outline>> {
    use crate::geometry::dome::{Grading, Outline};
    use crate::geometry::select::{Axis, Selection};
    let [a, b, c] = semi_axes;
    let reach = 0.8 * a.min(b);
    let tiny = 1e-9 * c;
    let mut found: Vec<(String, Outline)> = Vec::new();
    for (name, bc) in &scene.boundaries {
        if let Selection::Cylinder {
            axis: Axis::Z,
            center,
            radius,
            min: Some(floor),
            max,
        } = &bc.select
        {
            // Lowest point of the circle on the dome (on the shorter semi-axis).
            let lowest = c * (1.0 - (radius / a.min(b)).powi(2)).max(0.0).sqrt();
            if center[0].abs() <= tiny
                && center[1].abs() <= tiny
                && *radius > 0.0
                && *radius <= reach
                && *floor > 0.0
                && *floor < lowest
                && max.is_none_or(|m| m >= c)
            {
                let o = Outline {
                    radius: *radius,
                    floor: Some(*floor),
                    grading: None,
                };
                found.push((format!("boundaries.{name}"), o));
            }
        }
    }
    for (name, t) in &scene.contact {
        let (Some(center), Some(axis), Some(radius)) = (t.center, t.axis, t.radius) else {
            continue;
        };
        let along_z = |v: [f64; 3]| {
            let m = Vector3::from(v).amax();
            v[0].abs() <= 1e-9 * m && v[1].abs() <= 1e-9 * m
        };
        if t.shape == "cylinder"
            && along_z(axis)
            && (t.motion == [0.0; 3] || along_z(t.motion))
            && center[0].abs() <= tiny
            && center[1].abs() <= tiny
            && radius > 0.0
            && radius <= reach
        {
            let o = Outline {
                radius,
                floor: None,
                grading: None,
            };
            found.push((format!("contact.{name}"), o));
        }
    }
    for r in &scene.discretization.refine {
        let hits: Vec<usize> = found
            .iter()
            .enumerate()
            .filter(|(_, (key, _))| {
                key.split_once('.').map(|(_, n)| n) == Some(r.near.as_str()) || *key == r.near
            })
            .map(|(i, _)| i)
            .collect();
        if hits.is_empty() {
            let known =
                scene.boundaries.contains_key(&r.near) || scene.contact.contains_key(&r.near);
            return Err(Error::input(
                InputKind::Selection,
                if known {
                    format!(
                    "discretization.refine: near = '{}' has no outline the half-ellipsoid's mesh can                      follow; only a boundary selecting a cylinder about the z axis from a floor                      `min` below the dome (an indenter's plug) and a rigid cylinder tool along the                      z axis are features (radius at most {reach} m)",
                    r.near
                )
                } else {
                    format!(
                    "discretization.refine: near = '{}' names no [boundaries] or [contact] entry",
                    r.near
                )
                },
            ));
        }
        for i in hits {
            let g = Grading {
                size: r.size,
                growth: r.growth,
            };
            let o = &mut found[i].1;
            o.grading = match o.grading {
                Some(old) if old.size <= g.size => Some(old),
                _ => Some(g),
            };
        }
    }
    Ok(found.into_iter().map(|(_, o)| o).collect())
}

#[cfg(not(feature = "tetgen"))]
fn tetgen_mesh(_scene: &Scene) -> Result<Mesh> {
    Err(Error::input(InputKind::Unsupported, "this hytled was built without the `tetgen` feature; use mesher = 'structured' or rebuild with default features"))
}

/// The scene's mesh file, read and scaled to m, checked against the element the scene asks for.
/// None for built-in shapes.
pub fn load_mesh_input(scene: &Scene) -> Result<Option<MeshInput>> {
    let Geometry::Mesh {
        file,
        format,
        units,
        merge_duplicates,
    } = &scene.geometry
    else {
        return Ok(None);
    };
    let path = scene_path(scene, file);
    let mut m = crate::io::mesh_file::read_mesh(&path, *format, *units)?;
    if *merge_duplicates {
        let k = crate::io::mesh_file::merge_duplicate_nodes(&mut m);
        if k > 0 {
            m.warnings.push(format!(
                "merged {k} duplicate node(s) (geometry.merge_duplicates)"
            ));
        }
    }
    let kind: ElementKind = scene.discretization.element.into();
    let meshless = scene.discretization.method == Method::Meshless;
    if !meshless && m.mesh.shape != kind.shape() {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "{}: the mesh has {} cells but discretization.element = '{}'; use {}",
                path.display(),
                if m.mesh.shape == ElementShape::Hex8 {
                    "hexahedral"
                } else {
                    "tetrahedral"
                },
                kind.name(),
                if m.mesh.shape == ElementShape::Hex8 {
                    "element = 'hex8'"
                } else {
                    "element = 'tet4-anp' (or 'tet4')"
                }
            ),
        ));
    }
    Ok(Some(m))
}

fn load_mesh(scene: &Scene) -> Result<MeshInput> {
    load_mesh_input(scene)?
        .ok_or_else(|| Error::input(InputKind::Value, "the scene has no mesh file"))
}

/// Warnings a mesh file deserves: duplicate nodes (coincident within 1e-9 x the bounding-box
/// diagonal). Nodes no cell uses were already dropped on reading.
pub fn mesh_checks(mesh: &Mesh) -> Vec<String> {
    let mut w = Vec::new();
    let (map, keep) = crate::io::mesh_file::coincident_nodes(mesh);
    let dups = mesh.nodes.len() - keep.len();
    if let Some(i) = (0..map.len()).find(|&i| keep[map[i]] != i) {
        w.push(format!(
            "{dups} duplicate node(s) (e.g. nodes {} and {i} coincide); the mesh is not connected there: \
             merge them in the mesher or set geometry.merge_duplicates = true",
            keep[map[i]]
        ));
    }
    w
}

/// The node sets of a cloud file's label column, as a cell-less mesh input for set selection.
pub(super) fn cloud_sets(scene: &Scene) -> Result<Option<MeshInput>> {
    let d = &scene.discretization;
    let Some(rel) = d
        .cloud_file
        .as_ref()
        .filter(|_| d.cloud == crate::scene::CloudKind::File)
    else {
        return Ok(None);
    };
    let path = scene_path(scene, rel);
    if crate::io::mesh_file::MeshFormat::from_path(&path).is_some() {
        let m = crate::io::mesh_file::read_mesh(&path, None, 1.0)?;
        return Ok(Some(m));
    }
    let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
    let (nodes, node_sets) = crate::meshless::cloud::parse_cloud_sets(&text, &path)?;
    let n = nodes.len() as u64;
    Ok(Some(MeshInput {
        mesh: Mesh {
            nodes,
            shape: ElementShape::Tet4,
            cells: Vec::new(),
        },
        node_ids: (1..=n).collect(),
        element_ids: Vec::new(),
        node_sets,
        element_sets: Default::default(),
        face_sets: Default::default(),
        warnings: Vec::new(),
    }))
}

/// Integrator settings from the scene.
pub fn settings(scene: &Scene, progress: bool) -> Settings {
    let s = &scene.solver;
    Settings {
        mode: s.mode,
        duration: s.duration,
        load_time: s.load_time.unwrap_or(s.duration),
        load_steps: s.load_steps,
        dt_factor: s.dt_factor,
        step_estimate: s.time_step,
        damping: s.damping,
        tolerance: s.tolerance,
        max_steps: s.max_steps,
        estimate_interval: s.estimate_interval,
        retries: s
            .retries
            .unwrap_or(crate::solver::integrate::DEFAULT_RETRIES),
        step_update: s.step_update,
        history_rows: scene.output.history_rows,
        frames: scene.output.frames.unwrap_or(crate::scene::DEFAULT_FRAMES),
        progress,
        progress_lines: None,
        device: s.device,
        stages: stages(scene),
        warm_start: None,
        static_variant: s.static_variant,
        relaxed_start: s.relaxed_start,
        relaxation_fallback: s.relaxation_fallback,
        refresh_factor: false,
        initial_velocity: None,
        initial_motion: scene.initial.as_ref().map(|i| {
            [
                Vector3::from(i.velocity),
                Vector3::from(i.angular_velocity),
                Vector3::from(i.center),
            ]
        }),
    }
}

/// The load fractions below 1 at which references are compared (`at`), ascending: the
/// relaxation's load stages.
pub fn stages(scene: &Scene) -> Vec<f64> {
    let mut v: Vec<f64> = scene
        .references
        .values()
        .filter_map(|r| r.at)
        .filter(|&a| a > 0.0 && a < 1.0)
        .collect();
    v.sort_by(f64::total_cmp);
    v.dedup();
    v
}

/// The scene's shape as a meshless domain (None for a mesh file, whose shape is its cells).
pub fn domain(scene: &Scene) -> Option<Domain> {
    match &scene.geometry {
        Geometry::Box { min, max } => Some(Domain::Box {
            min: Vector3::from(*min),
            max: Vector3::from(*max),
        }),
        Geometry::Cylinder { radius, height } => Some(Domain::Cylinder {
            radius: *radius,
            height: *height,
        }),
        Geometry::HalfEllipsoid { semi_axes } => Some(Domain::HalfEllipsoid {
            semi_axes: Vector3::from(*semi_axes),
        }),
        Geometry::Mesh { .. } | Geometry::Surface { .. } | Geometry::Image { .. } => None,
    }
}

fn need_domain(scene: &Scene, what: &str) -> Result<Domain> {
    domain(scene).ok_or_else(|| {
        Error::input(InputKind::Unsupported, format!(
            "{what} needs a built-in shape (box or cylinder); with geometry.mesh use cloud = 'mesh' or 'file' and integration = 'tets'"
        ))
    })
}

/// Node spacing (m) the scene's sizing asks for: `size`, or the smallest division length.
pub fn spacing(scene: &Scene) -> Result<f64> {
    let d = &scene.discretization;
    if let Some(h) = d.size {
        return Ok(h);
    }
    let div = d.divisions.ok_or_else(|| {
        Error::input(
            InputKind::Value,
            "discretization: give `size` (node spacing, m) or `divisions`",
        )
    })?;
    Ok(match &scene.geometry {
        Geometry::Box { min, max } => (0..3)
            .map(|k| (max[k] - min[k]) / div[k].max(1) as f64)
            .fold(f64::INFINITY, f64::min),
        Geometry::Cylinder { radius, height } => {
            (radius / div[0].max(1) as f64 * 2.0).min(height / div[2].max(1) as f64)
        }
        // As the box: the bounding box [2a, 2b, c] divided by [nx, ny, nz].
        Geometry::HalfEllipsoid { semi_axes: s } => [2.0 * s[0], 2.0 * s[1], s[2]]
            .iter()
            .zip(div)
            .map(|(len, n)| len / n.max(1) as f64)
            .fold(f64::INFINITY, f64::min),
        Geometry::Mesh { .. } | Geometry::Surface { .. } | Geometry::Image { .. } => {
            return Err(Error::input(
                InputKind::Value,
                "a node spacing from `divisions` needs a built-in shape; give discretization.size",
            ))
        }
    })
}

pub fn mls_settings(scene: &Scene) -> MlsSettings {
    let d = &scene.discretization;
    MlsSettings {
        basis: match d.basis {
            crate::scene::Basis::Linear => crate::meshless::mls::Basis::Linear,
            crate::scene::Basis::Quadratic => crate::meshless::mls::Basis::Quadratic,
        },
        mu: d.mu,
        min_rcond: d.min_rcond,
    }
}

pub fn support_rule(scene: &Scene) -> SupportRule {
    let d = &scene.discretization;
    let quadratic = d.basis == crate::scene::Basis::Quadratic;
    match d.support {
        SupportKind::Radius => SupportRule::Radius {
            dilatation: d.dilatation.unwrap_or(if quadratic { 2.0 } else { 1.6 }),
        },
        SupportKind::Nearest => SupportRule::Nearest {
            n: d.support_nodes.unwrap_or(if quadratic { 16 } else { 8 }),
            alpha: d.alpha,
        },
    }
}

/// A generated node cloud: its nodes (m), a description for reports and its spacing h (m).
pub struct GeneratedCloud {
    pub nodes: Vec<Vector3<f64>>,
    pub description: String,
    pub spacing: f64,
}

/// The generated cloud (`cloud = "lattice"` or `"halton"`) over the scene's built-in shape.
pub fn generated_cloud(scene: &Scene) -> Result<GeneratedCloud> {
    let d = &scene.discretization;
    let h = spacing(scene)?;
    match d.cloud {
        CloudKind::Lattice => Ok(GeneratedCloud {
            nodes: cloud::jittered_lattice(
                &need_domain(scene, "cloud = 'lattice'")?,
                h,
                d.jitter,
                d.seed,
            )?,
            description: format!(
                "lattice h = {h:.4e} m, jitter {}, seed {}",
                d.jitter, d.seed
            ),
            spacing: h,
        }),
        CloudKind::Halton => {
            let domain = &need_domain(scene, "cloud = 'halton'")?;
            // Fill to saturation (random sequential packing at 0.85 h is about as dense as the
            // lattice of spacing h); the cap only bounds the work.
            let count = 3 * cloud::jittered_lattice(domain, h, 0.0, 0)?.len();
            let nodes =
                cloud::halton_fill(domain, count, d.min_spacing * h, d.seed).map_err(|e| {
                    Error::input(
                        InputKind::Value,
                        format!(
                    "discretization.cloud = 'halton' with min_spacing = {} (x size {h} m): {e}; \
                     min_spacing is a fraction of size (default 0.85)",
                    d.min_spacing
                ),
                    )
                })?;
            Ok(GeneratedCloud {
                nodes,
                description: format!(
                    "Halton fill, min spacing {:.4e} m, seed {}",
                    d.min_spacing * h,
                    d.seed
                ),
                spacing: h,
            })
        }
        other => Err(Error::input(
            InputKind::Value,
            format!("cloud = '{other:?}' is not a generated cloud (use 'lattice' or 'halton')"),
        )),
    }
}

/// The scene's rule per background tet (`tet_rule`: 1, 4 or 5 points).
pub fn tet_rule(scene: &Scene) -> Result<TetRule> {
    let n = scene.discretization.tet_rule();
    TetRule::from_points(n).ok_or_else(|| {
        Error::input(
            InputKind::Value,
            format!("discretization.tet_rule = {n}: use 1, 4 or 5"),
        )
    })
}

/// The scene's adaptive-integration settings: `tolerance`, `tet_rule` (the base rule),
/// `subdivision`, `max_level`.
pub fn adaptive_settings(scene: &Scene) -> Result<AdaptiveSettings> {
    let d = &scene.discretization;
    Ok(AdaptiveSettings {
        tolerance: d.tolerance,
        rule: tet_rule(scene)?,
        subdivision: d.subdivision,
        max_level: d.max_level,
    })
}

/// The scene's path `rel` resolved against the scene file's folder.
pub(super) fn scene_path(scene: &Scene, rel: &std::path::Path) -> PathBuf {
    if rel.is_absolute() {
        rel.to_path_buf()
    } else {
        scene.base_dir.join(rel)
    }
}

/// The meshless settings of a scene: its cloud (the vertices of the scene's tet mesh, a
/// generated cloud or a node file), integration, MLS basis and support rule.
pub fn meshless_settings(scene: &Scene) -> Result<MeshlessSettings> {
    let d = &scene.discretization;
    let integration = integration(scene)?;
    let cloud = match d.cloud {
        CloudKind::Mesh => {
            let mut s = scene.clone();
            if s.discretization.element == ElementName::Hex8 {
                s.discretization.element = ElementName::Tet4;
            }
            if let Some(planned) = planned_mesh(&s, ElementShape::Tet4) {
                discretize::check_build_memory(&planned, &integration, support_rule(scene))?;
            }
            let mesh = build_mesh(&s)?;
            let description = match &scene.geometry {
                Geometry::Mesh { file, .. } => format!(
                    "vertices of the mesh file {}{}",
                    file.display(),
                    if mesh.shape == ElementShape::Hex8 {
                        " (hexahedra split into six tets each)"
                    } else {
                        ""
                    }
                ),
                Geometry::Surface { file, .. } => {
                    format!(
                        "vertices of a TetGen tet mesh of the surface {}",
                        file.display()
                    )
                }
                Geometry::Image {
                    file,
                    body: ImageBody::Surface,
                    ..
                } => format!(
                    "vertices of a TetGen tet mesh of the labels' surface in {}",
                    file.display()
                ),
                Geometry::Image { file, .. } => format!(
                    "corners of the labelled voxels of {} (hexahedra split into six tets each)",
                    file.display()
                ),
                _ if d.mesher == Mesher::Tetgen => "vertices of a TetGen tet mesh".into(),
                _ => "vertices of a structured tet mesh".into(),
            };
            CloudSource::Mesh { mesh, description }
        }
        CloudKind::Lattice | CloudKind::Halton => {
            let GeneratedCloud {
                nodes, description, ..
            } = generated_cloud(scene)?;
            CloudSource::Nodes { nodes, description }
        }
        CloudKind::File => {
            let path = scene_path(scene, &d.cloud_file.clone().unwrap_or_default());
            CloudSource::Nodes {
                nodes: cloud::read_cloud(&path)?,
                description: format!("file {}", path.display()),
            }
        }
    };
    Ok(MeshlessSettings {
        cloud,
        domain: domain(scene),
        integration,
        mls: mls_settings(scene),
        support: support_rule(scene),
        // EBCIEM integrates over the boundary triangles, surface loads act on them.
        boundary_tets: d.bc_method.resolve(d.support) == BcMethod::Ebciem
            || scene.loads.values().any(|l| l.on_faces()),
        mean_dilatation_patch: d.meshless_mean_dilatation_patch(),
    })
}

/// The meshless integration of a scene.
fn integration(scene: &Scene) -> Result<Integration> {
    let d = &scene.discretization;
    Ok(match d.integration {
        IntegrationKind::Adaptive => Integration::Adaptive(adaptive_settings(scene)?),
        IntegrationKind::Tets => Integration::Tets {
            rule: tet_rule(scene)?,
            tets_per_point: d.tets_per_point(),
        },
        IntegrationKind::Grid => Integration::Grid {
            point_ratio: d.point_ratio,
        },
    })
}

/// The load curve a scene names: built in, or its `[curves.NAME]` table with the times mapped
/// to load fractions by `solver.load_time` (default: the duration).
pub(super) fn load_curve(scene: &Scene, name: &str) -> Result<LoadCurve> {
    if let Some(c) = LoadCurve::builtin(name) {
        return Ok(c);
    }
    let spec = scene.curves.get(name).ok_or_else(|| {
        Error::input(
            InputKind::Selection,
            format!("no curve '{name}' (built in: smooth, ramp, constant, smooth-return)"),
        )
    })?;
    let what = format!("curves.{name}");
    let points = match (&spec.points, &spec.file) {
        (Some(p), _) => p.clone(),
        (None, Some(f)) => {
            let path = scene_path(scene, f);
            let named = format!("{} (curves.{name}.file)", path.display());
            let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&named, e))?;
            crate::bc::curve::parse_curve_csv(&text, &named).map_err(|e| {
                let line = e.fault().and_then(|f| f.facts.line);
                let e = e.key(format!("curves.{name}.file"));
                // Its sentences name the file already.
                match line {
                    Some(l) => e.placed(&path, l),
                    None => e,
                }
            })?
        }
        (None, None) => Vec::new(),
    };
    let load_time = scene.solver.load_time.unwrap_or(scene.solver.duration);
    Ok(LoadCurve::Table(std::sync::Arc::new(
        CurveTable::from_times(&points, load_time, &what)?,
    )))
}
