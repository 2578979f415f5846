//! `[geometry]`: the body, a built-in shape or a mesh file (lengths in m).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// The body: a built-in shape, or a mesh file. Lengths in m.
///
/// Written `[geometry] shape = "box"` with `min`, `max`; `shape = "cylinder"` with `radius`,
/// `height`; `shape = "half_ellipsoid"` with `semi_axes = [a, b, c]`; or `mesh = "meshes/part.inp"` (any of .inp, .msh, .vtk, .vtu, by extension or
/// `format`) with `units` (the factor that turns the file's lengths into m, e.g. 0.001 for mm).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "GeometryToml", into = "GeometryToml")]
pub enum Geometry {
    /// Axis-aligned box [min, max].
    Box { min: [f64; 3], max: [f64; 3] },
    /// Circular cylinder along z, base at z = 0, centred on x = y = 0.
    Cylinder { radius: f64, height: f64 },
    /// Half-ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0, with `semi_axes` = [a, b, c]:
    /// flat elliptical base (semi-axes a along x, b along y) on z = 0 centred on x = y = 0,
    /// apex at (0, 0, c). Meshed by TetGen only (`mesher = "tetgen"`).
    HalfEllipsoid { semi_axes: [f64; 3] },
    /// A closed surface file (STL, OBJ), meshed by TetGen for every method (relative paths
    /// are resolved against the scene file's directory).
    Surface {
        file: PathBuf,
        /// File length unit in m (1 for m, 0.001 for mm).
        units: f64,
    },
    /// A labelled image (NIfTI-1 .nii/.nii.gz or NRRD .nrrd/.nhdr; relative paths against the
    /// scene file's directory), its orientation and spacing honoured (world RAS, as 3D Slicer
    /// shows it): the voxels whose label is in `labels` (every nonzero label when empty) are
    /// the body, as a smoothed surface TetGen fills or as hexahedra on blocks of voxels.
    Image {
        file: PathBuf,
        labels: Vec<i64>,
        body: ImageBody,
        /// Taubin smoothing iterations of the extracted surface.
        smoothing: usize,
    },
    /// A mesh file (relative paths are resolved against the scene file's directory).
    Mesh {
        file: PathBuf,
        format: Option<MeshFormat>,
        /// File length unit in m (1 for m, 0.001 for mm).
        units: f64,
        /// Merge coincident nodes (within 1e-9 x the bounding-box diagonal) on load.
        merge_duplicates: bool,
    },
}

pub use crate::io::mesh_file::MeshFormat;

/// How a labelled image becomes the body (`geometry.body`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ImageBody {
    /// The labels' surface, extracted (surface nets on the tissue fraction of blocks of
    /// voxels about `discretization.size`), smoothed, and filled by TetGen (tets).
    #[default]
    Surface,
    /// Hexahedra on blocks of voxels about `discretization.size` (a voxel-aligned body
    /// exactly; a staircase on curved ones).
    Voxels,
}

/// Taubin iterations of an image's surface unless `geometry.smoothing` says.
pub const DEFAULT_IMAGE_SMOOTHING: usize = 10;

/// `[geometry]` as written.
#[derive(Debug, Clone, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct GeometryToml {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shape: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    min: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    max: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    height: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    semi_axes: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mesh: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    surface: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    image: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    labels: Option<Vec<i64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    body: Option<ImageBody>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    smoothing: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    format: Option<MeshFormat>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    units: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    merge_duplicates: Option<bool>,
}

impl TryFrom<GeometryToml> for Geometry {
    type Error = String;
    fn try_from(g: GeometryToml) -> std::result::Result<Self, String> {
        let only = |allowed: &[&str]| -> std::result::Result<(), String> {
            let given = [
                ("min", g.min.is_some()),
                ("max", g.max.is_some()),
                ("radius", g.radius.is_some()),
                ("height", g.height.is_some()),
                ("semi_axes", g.semi_axes.is_some()),
                ("format", g.format.is_some()),
                ("units", g.units.is_some()),
                ("merge_duplicates", g.merge_duplicates.is_some()),
                ("labels", g.labels.is_some()),
                ("body", g.body.is_some()),
                ("smoothing", g.smoothing.is_some()),
            ];
            match given.iter().find(|(k, set)| *set && !allowed.contains(k)) {
                Some((k, _)) => Err(format!(
                    "geometry: `{k}` does not apply here (allowed: {})",
                    allowed.join(", ")
                )),
                None => Ok(()),
            }
        };
        if let Some(file) = g.image.clone() {
            if g.mesh.is_some() || g.shape.is_some() || g.surface.is_some() {
                return Err(
                    "geometry: give one of `image = \"file\"`, `surface = \"file\"`, `mesh = \"file\"` or `shape`"
                        .into(),
                );
            }
            only(&["labels", "body", "smoothing"])?;
            let body = g.body.unwrap_or_default();
            if body == ImageBody::Voxels && g.smoothing.is_some() {
                return Err(
                    "geometry: `smoothing` applies to body = \"surface\" (voxels are not smoothed)"
                        .into(),
                );
            }
            return Ok(Geometry::Image {
                file,
                labels: g.labels.unwrap_or_default(),
                body,
                smoothing: g.smoothing.unwrap_or(DEFAULT_IMAGE_SMOOTHING),
            });
        }
        if let Some(file) = g.surface.clone() {
            if g.mesh.is_some() || g.shape.is_some() {
                return Err(
                    "geometry: give one of `surface = \"file\"`, `mesh = \"file\"` or `shape`"
                        .into(),
                );
            }
            only(&["units"])?;
            return Ok(Geometry::Surface {
                file,
                units: g.units.unwrap_or(1.0),
            });
        }
        match (g.mesh.clone(), g.shape.as_deref()) {
            (Some(file), None) | (Some(file), Some("mesh")) => {
                only(&["format", "units", "merge_duplicates"])?;
                Ok(Geometry::Mesh {
                    file,
                    format: g.format,
                    units: g.units.unwrap_or(1.0),
                    merge_duplicates: g.merge_duplicates.unwrap_or(false),
                })
            }
            (None, Some("box")) => {
                only(&["min", "max"])?;
                match (g.min, g.max) {
                    (Some(min), Some(max)) => Ok(Geometry::Box { min, max }),
                    _ => Err("geometry: a box needs `min` and `max` (m)".into()),
                }
            }
            (None, Some("cylinder")) => {
                only(&["radius", "height"])?;
                match (g.radius, g.height) {
                    (Some(radius), Some(height)) => Ok(Geometry::Cylinder { radius, height }),
                    _ => Err("geometry: a cylinder needs `radius` and `height` (m)".into()),
                }
            }
            (None, Some("half_ellipsoid")) => {
                only(&["semi_axes"])?;
                match g.semi_axes {
                    Some(semi_axes) => Ok(Geometry::HalfEllipsoid { semi_axes }),
                    None => Err("geometry: a half_ellipsoid needs `semi_axes = [a, b, c]` (m; base semi-axes a along x, b along y, height c along z)".into()),
                }
            }
            (Some(_), Some(s)) => Err(format!("geometry: give either `mesh = \"file\"` or `shape = \"{s}\"`, not both")),
            (None, Some(s)) => Err(format!("geometry: unknown shape '{s}'; use \"box\", \"cylinder\", \"half_ellipsoid\", `mesh = \"file.inp|.msh|.vtk|.vtu\"`, `surface = \"file.stl|.obj\"` or `image = \"labels.nii.gz|.nrrd\"`")),
            (None, None) => Err("geometry: give `shape = \"box\" | \"cylinder\" | \"half_ellipsoid\"`, `mesh = \"file\"`, `surface = \"file.stl|.obj\"` or `image = \"labels.nii.gz|.nrrd\"`".into()),
        }
    }
}

impl From<Geometry> for GeometryToml {
    fn from(g: Geometry) -> Self {
        match g {
            Geometry::Box { min, max } => GeometryToml {
                shape: Some("box".into()),
                min: Some(min),
                max: Some(max),
                ..Default::default()
            },
            Geometry::Cylinder { radius, height } => GeometryToml {
                shape: Some("cylinder".into()),
                radius: Some(radius),
                height: Some(height),
                ..Default::default()
            },
            Geometry::HalfEllipsoid { semi_axes } => GeometryToml {
                shape: Some("half_ellipsoid".into()),
                semi_axes: Some(semi_axes),
                ..Default::default()
            },
            Geometry::Image {
                file,
                labels,
                body,
                smoothing,
            } => GeometryToml {
                image: Some(file),
                labels: (!labels.is_empty()).then_some(labels),
                body: Some(body),
                smoothing: (body == ImageBody::Surface).then_some(smoothing),
                ..Default::default()
            },
            Geometry::Surface { file, units } => GeometryToml {
                surface: Some(file),
                units: Some(units),
                ..Default::default()
            },
            Geometry::Mesh {
                file,
                format,
                units,
                merge_duplicates,
            } => GeometryToml {
                mesh: Some(file),
                format,
                units: Some(units),
                merge_duplicates: Some(merge_duplicates),
                ..Default::default()
            },
        }
    }
}
