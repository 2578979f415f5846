//! Closed surfaces from files (`[geometry] surface = "FILE"`): STL, ASCII or binary (the
//! stl_io crate, which merges a triangle soup's identical vertices), Wavefront OBJ (the
//! tobj crate; polygons are fanned into triangles) and VTK poly data, legacy `.vtk` or XML
//! `.vtp` (vtkio, as the volume meshes; polygons fanned, strips split). Lengths are multiplied by `units` (0.001
//! for a file in millimetres), then the surface is checked
//! ([`crate::geometry::closed_surface::check_closed_surface`]).

use std::path::Path;

use nalgebra::Vector3;

use super::file_error;
use crate::geometry::closed_surface::{check_closed_surface, ClosedSurface};
use crate::{Error, Result};

/// The surface formats, by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurfaceFormat {
    Stl,
    Obj,
    /// VTK poly data: legacy `.vtk` (`DATASET POLYDATA`) or XML `.vtp`.
    Vtk,
}

impl SurfaceFormat {
    /// From the file's extension (case-insensitive); None for any other.
    pub fn from_path(path: &Path) -> Option<Self> {
        match path
            .extension()?
            .to_string_lossy()
            .to_ascii_lowercase()
            .as_str()
        {
            "stl" => Some(SurfaceFormat::Stl),
            "obj" => Some(SurfaceFormat::Obj),
            "vtk" | "vtp" => Some(SurfaceFormat::Vtk),
            _ => None,
        }
    }
}

/// Reads and checks the closed surface in `path`, lengths times `units` (m per file unit).
pub fn read_surface(path: &Path, units: f64) -> Result<ClosedSurface> {
    let (points, triangles) = match SurfaceFormat::from_path(path) {
        Some(SurfaceFormat::Stl) => read_stl(path)?,
        Some(SurfaceFormat::Obj) => read_obj(path)?,
        Some(SurfaceFormat::Vtk) => super::vtk::read_polydata_triangles(path)?,
        None => {
            return Err(file_error(
                path,
                "unknown surface format; use .stl (ASCII or binary), .obj, or VTK poly data (.vtk, .vtp)",
            ))
        }
    };
    let points = points.into_iter().map(|p| p * units).collect();
    check_closed_surface(&path.display().to_string(), points, triangles)
}

/// Points (m, or the file's unit before scaling) and triangles over them, as read.
pub(crate) type Soup = (Vec<Vector3<f64>>, Vec<[usize; 3]>);

/// The first line of an ASCII STL or an OBJ whose numbers the parsers would refuse without
/// saying where: a vertex coordinate that is not a finite number, or (OBJ) a face index that
/// names no vertex. None for binary files and files without such a line.
fn first_bad_line(path: &Path, obj: bool) -> Option<String> {
    let text = std::fs::read(path).ok()?;
    let text = std::str::from_utf8(&text).ok()?;
    if !obj && !text.trim_start().starts_with("solid") {
        return None;
    }
    let mut vertices = 0i64;
    for (n, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or("");
        let coordinates = (obj && key == "v") || (!obj && key == "vertex");
        if coordinates {
            vertices += 1;
            for w in words.clone().take(3) {
                if !w.parse::<f64>().is_ok_and(f64::is_finite) {
                    return Some(format!(
                        "line {}: vertex coordinate '{}' is not a finite number",
                        n + 1,
                        super::clip(w)
                    ));
                }
            }
        } else if obj && key == "f" {
            for w in words {
                let index = w.split('/').next().unwrap_or("");
                let ok = index
                    .parse::<i64>()
                    .is_ok_and(|i| (1..=vertices).contains(&i) || (-vertices..=-1).contains(&i));
                if !ok {
                    return Some(format!(
                        "line {}: face index '{}' names no vertex (the {vertices} vertices before it are numbered from 1, or from -1 backwards)",
                        n + 1,
                        super::clip(w)
                    ));
                }
            }
        }
    }
    None
}

fn read_stl(path: &Path) -> Result<Soup> {
    if let Some(m) = first_bad_line(path, false) {
        return Err(file_error(path, m));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let mesh = super::guard_parser("stl_io", || stl_io::read_stl(&mut reader))
        .map_err(|e| file_error(path, format!("not a readable STL file: {e}")))?
        .map_err(|e| file_error(path, format!("not a readable STL file ({e})")))?;
    let points = mesh
        .vertices
        .iter()
        .map(|v| Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64))
        .collect();
    let triangles = mesh.faces.iter().map(|f| f.vertices).collect();
    Ok((points, triangles))
}

fn read_obj(path: &Path) -> Result<Soup> {
    if let Some(m) = first_bad_line(path, true) {
        return Err(file_error(path, m));
    }
    let options = tobj::LoadOptions {
        triangulate: true,
        ..Default::default()
    };
    let (models, _) = tobj::load_obj(path, &options)
        .map_err(|e| file_error(path, format!("not a readable OBJ file ({e})")))?;
    let (mut points, mut triangles) = (Vec::new(), Vec::new());
    for m in &models {
        let base = points.len();
        points.extend(
            m.mesh
                .positions
                .chunks_exact(3)
                .map(|p| Vector3::new(p[0], p[1], p[2])),
        );
        triangles.extend(
            m.mesh
                .indices
                .chunks_exact(3)
                .map(|t| [0, 1, 2].map(|k| base + t[k] as usize)),
        );
    }
    Ok((points, triangles))
}

/// Writes `surface` as a binary STL file (single precision, as the format holds).
pub fn write_stl(path: &Path, surface: &ClosedSurface) -> Result<()> {
    let tris: Vec<stl_io::Triangle> = surface
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| surface.points[i]);
            let n = (b - a).cross(&(c - a)).normalize();
            let v = |p: Vector3<f64>| stl_io::Vertex::new([p.x as f32, p.y as f32, p.z as f32]);
            stl_io::Triangle {
                normal: stl_io::Normal::new([n.x as f32, n.y as f32, n.z as f32]),
                vertices: [v(a), v(b), v(c)],
            }
        })
        .collect();
    let mut file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    stl_io::write_stl(&mut file, tris.iter()).map_err(|e| Error::io(path, e))
}
