//! Volume images: labelmaps and scalar images in (NIfTI-1 `.nii`, `.nii.gz`; NRRD `.nrrd`,
//! `.nhdr`), scalar images and displacement fields out, with the orientation and spacing of
//! the file honoured.
//!
//! World coordinates are those 3D Slicer shows: RAS (x increasing to the patient's Right, y to
//! Anterior, z to Superior), in metres inside hytled.
//! NIfTI stores RAS in millimetres (its sform, else its qform, else its voxel sizes); NRRD
//! stores its `space` (LPS for Slicer's files: x and y are negated into RAS) with `space
//! directions` and `space origin`, millimetres unless `space units` says otherwise.
//!
//! Displacement fields are written as ITK and 3D Slicer read them as a displacement-field
//! (grid) transform: vector components in LPS millimetres, on the image's grid (NIfTI: 5-D
//! with intent VECTOR, the ANTs convention; NRRD: a `vector` axis first, `space:
//! left-posterior-superior`).

use std::io::{BufRead, Read, Write};
use std::path::Path;

use nalgebra::{Matrix3, Matrix4, Vector3};

use super::file_error;
use crate::{Error, InputKind, Result};

pub use crate::geometry::image::Image;

/// Image file formats, by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    /// NIfTI-1, `.nii` or `.nii.gz`.
    Nifti,
    /// NRRD, `.nrrd` (attached) or `.nhdr` (detached header, reading only).
    Nrrd,
}

impl ImageFormat {
    /// The format a path's extension names.
    pub fn from_path(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            Some(ImageFormat::Nifti)
        } else if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
            Some(ImageFormat::Nrrd)
        } else {
            None
        }
    }
}

/// Largest image read (voxels): 1 GiB of f64 values.
const MAX_VOXELS: usize = 1 << 27;

/// Voxels of `dims`, refused past [`MAX_VOXELS`].
fn voxel_count(path: &Path, dims: [usize; 3]) -> Result<usize> {
    dims[0]
        .checked_mul(dims[1])
        .and_then(|v| v.checked_mul(dims[2]))
        .filter(|&n| n <= MAX_VOXELS)
        .ok_or_else(|| {
            file_error(
                path,
                format!("the image has {dims:?} voxels, more than the {MAX_VOXELS} hytled reads; crop or resample it"),
            )
        })
}

fn check_map(path: &Path, dims: [usize; 3], to_world: Matrix4<f64>) -> Result<Image> {
    if dims.contains(&0) {
        return Err(file_error(
            path,
            format!("the image has {dims:?} voxels; every axis needs at least one"),
        ));
    }
    let n = voxel_count(path, dims)?;
    let axes = to_world.fixed_view::<3, 3>(0, 0).into_owned();
    let det = axes.determinant();
    let scale = axes.column(0).norm() * axes.column(1).norm() * axes.column(2).norm();
    if !to_world.iter().all(|v| v.is_finite()) || !(det.abs() > 1e-6 * scale) || scale == 0.0 {
        return Err(file_error(
            path,
            format!(
                "the image's voxel axes (columns, m) {:?} are degenerate: the voxels have no volume; fix the header's spacing and direction",
                axes.as_slice()
            ),
        ));
    }
    debug_assert_eq!(n, dims[0] * dims[1] * dims[2]);
    Ok(Image::filled(dims, to_world, 0.0))
}

/// Reads a NIfTI-1 or NRRD image (by extension): its first 3-D volume, values scaled as the
/// file says, world positions RAS in metres.
pub fn read_image(path: &Path) -> Result<Image> {
    match ImageFormat::from_path(path) {
        Some(ImageFormat::Nifti) => read_nifti(path),
        Some(ImageFormat::Nrrd) => read_nrrd(path),
        None => Err(file_error(
            path,
            "unknown image format; use NIfTI (.nii, .nii.gz) or NRRD (.nrrd, .nhdr)",
        )),
    }
}

/// The NIfTI length unit in m (xyzt_units bits 0-2: 1 m, 2 mm, 3 micron; 0, unknown, read as
/// mm as 3D Slicer and ITK do).
fn nifti_unit(xyzt_units: u8) -> f64 {
    match xyzt_units & 7 {
        1 => 1.0,
        3 => 1e-6,
        _ => 1e-3,
    }
}

/// Decodes one voxel's bytes (big-endian when the flag says so).
type Decode = fn(&[u8], bool) -> f64;

/// Bytes per voxel and the decoder of one voxel (little- or big-endian) for a NIfTI-1
/// `datatype`, with the type's name for messages; `None` for the types hytled does not read
/// (complex, RGB, 128-bit).
fn nifti_type(datatype: i16) -> Option<(usize, &'static str, Decode)> {
    fn word<const N: usize>(b: &[u8], big: bool) -> [u8; N] {
        let mut a: [u8; N] = std::array::from_fn(|i| b[i]);
        if big {
            a.reverse();
        }
        a
    }
    Some(match datatype {
        2 => (1, "uint8", |b, _| b[0] as f64),
        256 => (1, "int8", |b, _| b[0] as i8 as f64),
        4 => (2, "int16", |b, e| i16::from_le_bytes(word(b, e)) as f64),
        512 => (2, "uint16", |b, e| u16::from_le_bytes(word(b, e)) as f64),
        8 => (4, "int32", |b, e| i32::from_le_bytes(word(b, e)) as f64),
        768 => (4, "uint32", |b, e| u32::from_le_bytes(word(b, e)) as f64),
        1024 => (8, "int64", |b, e| i64::from_le_bytes(word(b, e)) as f64),
        1280 => (8, "uint64", |b, e| u64::from_le_bytes(word(b, e)) as f64),
        16 => (4, "float32", |b, e| f32::from_le_bytes(word(b, e)) as f64),
        64 => (8, "float64", |b, e| f64::from_le_bytes(word(b, e))),
        _ => return None,
    })
}

/// The NIfTI-1 header's size field (`sizeof_hdr`), which also gives the byte order.
const NIFTI1_HEADER: i32 = 348;

/// Reads a single-file NIfTI-1 image (`.nii`, `.nii.gz`) as nibabel does: the header in
/// either byte order, the voxels from `vox_offset` (after any header extensions), scaled by
/// `scl_slope` and `scl_inter` where the slope is set (non-zero and finite), the sform where
/// its code is set, else the qform, else the voxel sizes.
fn read_nifti(path: &Path) -> Result<Image> {
    if !path.is_file() {
        return Err(file_error(path, "no such image file"));
    }
    let mut bytes = std::fs::read(path).map_err(|e| file_error(path, e))?;
    if bytes.starts_with(&[0x1f, 0x8b]) {
        let mut out = Vec::new();
        flate2::read::MultiGzDecoder::new(&bytes[..])
            .read_to_end(&mut out)
            .map_err(|e| file_error(path, format!("its gzip data could not be inflated: {e}")))?;
        bytes = out;
    }
    if bytes.len() < NIFTI1_HEADER as usize {
        return Err(file_error(
            path,
            format!(
                "the file holds {} bytes, less than NIfTI-1's {NIFTI1_HEADER}-byte header (truncated?)",
                bytes.len()
            ),
        ));
    }
    let size = [bytes[0], bytes[1], bytes[2], bytes[3]];
    if ![i32::from_le_bytes(size), i32::from_be_bytes(size)].contains(&NIFTI1_HEADER) {
        let why = if [i32::from_le_bytes(size), i32::from_be_bytes(size)].contains(&540) {
            "a NIfTI-2 file; hytled reads NIfTI-1 (save it as NIfTI-1, e.g. with nibabel's Nifti1Image or 3D Slicer)"
        } else {
            "not a NIfTI-1 file (its first 4 bytes are not the header size 348)"
        };
        return Err(file_error(path, why));
    }
    match &bytes[344..348] {
        b"n+1\0" => {}
        b"ni1\0" => {
            return Err(file_error(
                path,
                "a header-only NIfTI-1 (.hdr/.img pair); save the image as a single .nii or .nii.gz",
            ))
        }
        m => {
            return Err(file_error(
                path,
                format!(
                    "its magic is {:?}, not NIfTI-1's \"n+1\" (an ANALYZE 7.5 file?); save it as NIfTI-1",
                    String::from_utf8_lossy(m).trim_end_matches('\0')
                ),
            ))
        }
    }
    let h = super::guard_parser("nifti", || nifti::NiftiHeader::from_reader(&bytes[..348]))
        .map_err(|e| file_error(path, format!("its NIfTI-1 header could not be read: {e}")))?
        .map_err(|e| file_error(path, format!("its NIfTI-1 header could not be read: {e}")))?;
    let big = h.endianness == nifti::Endianness::Big;
    let ndim = h.dim[0] as usize;
    if !(1..=7).contains(&ndim) {
        return Err(file_error(
            path,
            format!("dim[0] = {}; NIfTI allows 1 to 7", h.dim[0]),
        ));
    }
    if let Some(a) = (1..=ndim).find(|&a| h.dim[a] < 1) {
        return Err(file_error(
            path,
            format!(
                "dim[{a}] = {}: every axis needs at least one voxel",
                h.dim[a]
            ),
        ));
    }
    let size = |a: usize| if a <= ndim { h.dim[a] as usize } else { 1 };
    let dims = [size(1), size(2), size(3)];
    let volumes: usize = (4..=ndim).map(size).product();
    if volumes > 1 {
        return Err(file_error(
            path,
            format!(
                "the image holds {volumes} volumes (dim = {:?}); hytled reads one 3-D volume: \
                 save the one you mean on its own (e.g. fslroi, or nibabel's img.slicer[..., 0])",
                &h.dim[..=ndim]
            ),
        ));
    }
    let Some((width, type_name, decode)) = nifti_type(h.datatype) else {
        return Err(file_error(
            path,
            format!(
                "datatype {} is not read (use uint8, int8, int16, uint16, int32, uint32, int64, uint64, float32 or float64)",
                h.datatype
            ),
        ));
    };
    let offset = h.vox_offset as f64;
    if !(offset >= 352.0) || !offset.is_finite() {
        return Err(file_error(
            path,
            format!(
                "vox_offset = {offset}: a single-file NIfTI-1's voxels start at byte 352 or later, after the header and its extension flag"
            ),
        ));
    }
    let offset = offset as usize;
    let voxels = voxel_count(path, dims)?;
    let need = voxels * width;
    if offset.saturating_add(need) > bytes.len() {
        return Err(file_error(
            path,
            format!(
                "the file is too short: its header says {dims:?} voxels of {type_name} ({need} bytes) from byte {offset} (vox_offset), \
                 but it holds {} bytes{}; the file is truncated or its header is wrong",
                bytes.len(),
                if path.to_string_lossy().ends_with(".gz") { " once inflated" } else { "" }
            ),
        ));
    }
    let unit = nifti_unit(h.xyzt_units);
    let mut to_world = nifti_affine(&h).map_err(|m| file_error(path, m))? * unit;
    to_world[(3, 3)] = 1.0;
    let mut image = check_map(path, dims, to_world)?;
    // nibabel's rule: a slope of 0 or one not finite means unscaled data; a finite slope needs
    // a finite intercept.
    let (slope, inter) = (h.scl_slope as f64, h.scl_inter as f64);
    let (slope, inter) = if slope == 0.0 || !slope.is_finite() {
        (1.0, 0.0)
    } else if !inter.is_finite() {
        return Err(file_error(
            path,
            format!("scl_slope = {slope} is set but scl_inter = {inter} is not a finite number"),
        ));
    } else {
        (slope, inter)
    };
    let data = &bytes[offset..offset + need];
    for (v, b) in image.values.iter_mut().zip(data.chunks_exact(width)) {
        *v = decode(b, big) * slope + inter;
    }
    if let Some(n) = image.values.iter().position(|v| !v.is_finite()) {
        return Err(file_error(
            path,
            format!("voxel {n} holds {}, not a finite number", image.values[n]),
        ));
    }
    Ok(image)
}

/// The NIfTI index-to-world map in the file's unit (RAS): the sform where its code is set, else
/// the qform (quaternion, offsets, voxel sizes and qfac), else the voxel sizes alone.
fn nifti_affine(h: &nifti::NiftiHeader) -> std::result::Result<Matrix4<f64>, String> {
    let p = |a: usize| h.pixdim[a] as f64;
    if h.sform_code > 0 {
        let r = [h.srow_x, h.srow_y, h.srow_z];
        let mut m = Matrix4::identity();
        for (row, s) in r.iter().enumerate() {
            for c in 0..4 {
                m[(row, c)] = s[c] as f64;
            }
        }
        return Ok(m);
    }
    for a in 1..=3 {
        if !(p(a) > 0.0 && p(a).is_finite()) {
            return Err(format!(
                "voxel size pixdim[{a}] = {} must be positive (no sform is set, so the spacing comes from pixdim)",
                p(a)
            ));
        }
    }
    let scale = Matrix3::from_diagonal(&Vector3::new(p(1), p(2), p(3)));
    let (r, offset) = if h.qform_code > 0 {
        let (b, c, d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let mut r = Matrix3::new(
            a * a + b * b - c * c - d * d,
            2.0 * (b * c - a * d),
            2.0 * (b * d + a * c),
            2.0 * (b * c + a * d),
            a * a + c * c - b * b - d * d,
            2.0 * (c * d - a * b),
            2.0 * (b * d - a * c),
            2.0 * (c * d + a * b),
            a * a + d * d - c * c - b * b,
        );
        if h.pixdim[0] < 0.0 {
            r.column_mut(2).neg_mut();
        }
        (
            r,
            Vector3::new(h.quatern_x as f64, h.quatern_y as f64, h.quatern_z as f64),
        )
    } else {
        (Matrix3::identity(), Vector3::zeros())
    };
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(r * scale));
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(&offset);
    Ok(m)
}

/// NRRD header fields (lower-case keys) and where its data starts.
struct NrrdHeader {
    fields: Vec<(String, String)>,
}

impl NrrdHeader {
    /// A field the format requires; its absence is a format error naming the file.
    fn need(&self, key: &str, path: &Path) -> Result<&str> {
        self.get(key)
            .ok_or_else(|| file_error(path, format!("the NRRD header has no '{key}' field")))
    }

    fn get(&self, key: &str) -> Option<&str> {
        self.fields
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

fn parse_vector(s: &str) -> Option<Vec<f64>> {
    let t = s.trim();
    let inner = t.strip_prefix('(')?.strip_suffix(')')?;
    inner.split(',').map(|v| v.trim().parse().ok()).collect()
}

/// A NRRD image (`.nrrd`, or a `.nhdr` header with its data file beside it): the header's
/// fields ([`nrrd_header`]), the axes ([`nrrd_axes`]), the voxel-to-world map
/// ([`nrrd_to_world`]), the sample type ([`nrrd_type`]) and the decoded data ([`nrrd_data`]).
fn read_nrrd(path: &Path) -> Result<Image> {
    let file = std::fs::File::open(path).map_err(|e| file_error(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let h = nrrd_header(&mut reader, path)?;
    let NrrdAxes {
        dimension,
        lead,
        dims,
    } = nrrd_axes(&h, path)?;
    let components = 1; // nrrd_axes refuses more
    let to_world = nrrd_to_world(&h, path, dimension, lead)?;
    let mut image = check_map(path, dims, to_world)?;
    let kind = h.need("type", path)?.to_ascii_lowercase();
    let (bytes, read) = nrrd_type(&kind, path)?;
    let big = h
        .get("endian")
        .is_some_and(|e| e.eq_ignore_ascii_case("big"));
    let raw = nrrd_data(&h, path, &mut reader)?;
    let need_bytes = image.len() * components * bytes;
    if raw.len() < need_bytes {
        return Err(file_error(
            path,
            format!("it holds {} bytes of data; {dims:?} voxels of {components} {kind} need {need_bytes}", raw.len()),
        ));
    }
    // `byte skip` as pynrrd and Teem read it: bytes before the data (after decompression for
    // gzip), -1 for "the data are the file's last bytes"; none, the data start at once.
    let start = match h.get("byte skip").or_else(|| h.get("byteskip")) {
        None => 0,
        Some(v) => match v.trim().parse::<i64>() {
            Ok(-1) => raw.len() - need_bytes,
            Ok(k) if k >= 0 && (k as usize).saturating_add(need_bytes) <= raw.len() => k as usize,
            _ => {
                return Err(file_error(
                    path,
                    format!(
                    "byte skip '{}' is not -1 or a whole number of bytes the data leave room for",
                    super::clip(v)
                ),
                ))
            }
        },
    };
    for (n, v) in image.values.iter_mut().enumerate() {
        let at = start + n * components * bytes;
        *v = read(&raw[at..at + bytes], big);
    }
    if let Some(n) = image.values.iter().position(|v| !v.is_finite()) {
        return Err(file_error(
            path,
            format!("voxel {n} holds {}, not a finite number", image.values[n]),
        ));
    }
    Ok(image)
}

/// The header's fields, lower-case names, up to the blank line that ends it; `reader` is left
/// at the data.
fn nrrd_header(reader: &mut impl BufRead, path: &Path) -> Result<NrrdHeader> {
    let mut fields = Vec::new();
    let mut first = true;
    let mut line_no = 0usize;
    let mut line = String::new();
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .map_err(|e| file_error(path, format!("the header is not text: {e}")))?;
        line_no += 1;
        let l = line.trim_end_matches(['\n', '\r']);
        if first {
            if !l.starts_with("NRRD000") {
                return Err(file_error(
                    path,
                    "not a NRRD file (it does not begin with NRRD000N)",
                ));
            }
            first = false;
            continue;
        }
        if n == 0 || l.is_empty() {
            break;
        }
        if l.starts_with('#') {
            continue;
        }
        if let Some((k, v)) = l.split_once(": ") {
            fields.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
        } else if l.contains(":=") {
            continue; // key/value pairs carry no geometry
        } else {
            return Err(super::line_err(
                path,
                line_no,
                format!("'{}' is not a NRRD field (\"name: value\")", super::clip(l)),
            ));
        }
    }
    Ok(NrrdHeader { fields })
}

/// The axes of a scalar 3-D NRRD: its dimension, the leading non-spatial axis count (0 or 1)
/// and the voxel counts of the three spatial axes.
struct NrrdAxes {
    dimension: usize,
    lead: usize,
    dims: [usize; 3],
}

fn nrrd_axes(h: &NrrdHeader, path: &Path) -> Result<NrrdAxes> {
    let dimension: usize = h
        .need("dimension", path)?
        .parse()
        .map_err(|_| file_error(path, "dimension is not a whole number"))?;
    let sizes: Vec<usize> = h
        .need("sizes", path)?
        .split_whitespace()
        .map(|s| s.parse().ok())
        .collect::<Option<Vec<_>>>()
        .filter(|v: &Vec<usize>| v.len() == dimension)
        .ok_or_else(|| file_error(path, format!("sizes must list {dimension} whole numbers")))?;
    let kinds: Vec<String> = h
        .get("kinds")
        .map(|k| {
            k.split_whitespace()
                .map(|s| s.to_ascii_lowercase())
                .collect()
        })
        .unwrap_or_default();
    // The spatial axes: kinds 'domain'/'space' where given, else all axes (3 of them).
    let spatial: Vec<usize> = if kinds.len() == dimension {
        (0..dimension)
            .filter(|&a| matches!(kinds[a].as_str(), "domain" | "space" | "time"))
            .take(3)
            .collect()
    } else {
        (0..dimension.min(3)).collect()
    };
    if spatial.len() != 3 || dimension > 4 {
        return Err(file_error(
            path,
            format!("a 3-D image (three domain axes, at most one more) is needed; it has dimension {dimension} with kinds {kinds:?}"),
        ));
    }
    if spatial
        .iter()
        .enumerate()
        .any(|(i, &a)| a != i + dimension - 3)
    {
        return Err(file_error(
            path,
            "the three domain axes must be the last ones (a component axis first)",
        ));
    }
    let lead = dimension - 3;
    let components = if lead == 1 { sizes[0] } else { 1 };
    if components > 1 {
        return Err(file_error(
            path,
            format!(
                "the image holds {components} values per voxel (sizes {sizes:?}, kinds {kinds:?}); hytled reads one scalar 3-D volume: save the one you mean on its own"
            ),
        ));
    }
    let dims = [sizes[lead], sizes[lead + 1], sizes[lead + 2]];
    Ok(NrrdAxes {
        dimension,
        lead,
        dims,
    })
}

/// The map from voxel index to world position (RAS, m): `space directions` and
/// `space origin` (LPS and LAS turned to RAS, `space units` to metres) or `spacings`.
fn nrrd_to_world(
    h: &NrrdHeader,
    path: &Path,
    dimension: usize,
    lead: usize,
) -> Result<Matrix4<f64>> {
    // Space directions (one per axis, 'none' for non-spatial) or spacings.
    let space = h.get("space").map(|s| s.to_ascii_lowercase());
    let flip = match space.as_deref() {
        None => [1.0, 1.0, 1.0],
        Some("right-anterior-superior" | "ras" | "scanner-xyz" | "3d-right-handed") => [1.0, 1.0, 1.0],
        Some("left-posterior-superior" | "lps") => [-1.0, -1.0, 1.0],
        Some("left-anterior-superior" | "las") => [-1.0, 1.0, 1.0],
        Some(s) => {
            return Err(file_error(
                path,
                format!("space '{s}' is not supported; use right-anterior-superior or left-posterior-superior"),
            ))
        }
    };
    let unit = match h.get("space units") {
        None => 1e-3,
        Some(u) => {
            let first = u
                .split_whitespace()
                .next()
                .unwrap_or("")
                .trim_matches('"')
                .to_ascii_lowercase();
            match first.as_str() {
                "mm" | "" => 1e-3,
                "m" => 1.0,
                "cm" => 1e-2,
                "um" | "micron" => 1e-6,
                other => {
                    return Err(file_error(
                        path,
                        format!("space units '{other}' unknown; use mm, cm, m or um"),
                    ))
                }
            }
        }
    };
    let mut to_world = Matrix4::identity();
    if let Some(d) = h.get("space directions") {
        let mut parts = Vec::new();
        let mut rest = d.trim();
        while !rest.is_empty() {
            if let Some(r) = rest.strip_prefix("none") {
                parts.push(None);
                rest = r.trim_start();
            } else if let Some(end) = rest.find(')') {
                let v = parse_vector(&rest[..=end])
                    .filter(|v| v.len() == 3)
                    .ok_or_else(|| {
                        file_error(
                            path,
                            format!(
                                "space directions: '{}' is not a 3-vector",
                                super::clip(&rest[..=end])
                            ),
                        )
                    })?;
                parts.push(Some(v));
                rest = rest[end + 1..].trim_start();
            } else {
                return Err(file_error(
                    path,
                    "space directions: expected (x,y,z) vectors or none",
                ));
            }
        }
        if parts.len() != dimension {
            return Err(file_error(
                path,
                format!(
                    "space directions lists {} axes; dimension is {dimension}",
                    parts.len()
                ),
            ));
        }
        for a in 0..3 {
            let v = parts[lead + a].clone().ok_or_else(|| {
                file_error(
                    path,
                    format!("space directions: domain axis {} is 'none'", lead + a),
                )
            })?;
            for r in 0..3 {
                to_world[(r, a)] = v[r] * flip[r] * unit;
            }
        }
        if let Some(o) = h.get("space origin") {
            let o = parse_vector(o)
                .filter(|v| v.len() == 3)
                .ok_or_else(|| file_error(path, "space origin is not a 3-vector (x,y,z)"))?;
            for r in 0..3 {
                to_world[(r, 3)] = o[r] * flip[r] * unit;
            }
        }
    } else if let Some(s) = h.get("spacings") {
        let v: Vec<f64> = s
            .split_whitespace()
            .map(|x| x.parse().unwrap_or(f64::NAN))
            .collect();
        if v.len() != dimension {
            return Err(file_error(path, "spacings must list one value per axis"));
        }
        for a in 0..3 {
            to_world[(a, a)] = v[lead + a] * unit;
        }
    } else {
        for a in 0..3 {
            to_world[(a, a)] = unit;
        }
    }
    Ok(to_world)
}

/// The bytes per sample and the decoder of a NRRD `type`.
fn nrrd_type(kind: &str, path: &Path) -> Result<(usize, Decode)> {
    Ok(match kind {
        "signed char" | "int8" | "int8_t" => (1, |b, _| b[0] as i8 as f64),
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => (1, |b, _| b[0] as f64),
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            (2, |b, be| {
                let a = [b[0], b[1]];
                (if be {
                    i16::from_be_bytes(a)
                } else {
                    i16::from_le_bytes(a)
                }) as f64
            })
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            (2, |b, be| {
                let a = [b[0], b[1]];
                (if be {
                    u16::from_be_bytes(a)
                } else {
                    u16::from_le_bytes(a)
                }) as f64
            })
        }
        "int" | "signed int" | "int32" | "int32_t" => (4, |b, be| {
            let a = [b[0], b[1], b[2], b[3]];
            (if be {
                i32::from_be_bytes(a)
            } else {
                i32::from_le_bytes(a)
            }) as f64
        }),
        "uint" | "unsigned int" | "uint32" | "uint32_t" => (4, |b, be| {
            let a = [b[0], b[1], b[2], b[3]];
            (if be {
                u32::from_be_bytes(a)
            } else {
                u32::from_le_bytes(a)
            }) as f64
        }),
        "float" => (4, |b, be| {
            let a = [b[0], b[1], b[2], b[3]];
            (if be {
                f32::from_be_bytes(a)
            } else {
                f32::from_le_bytes(a)
            }) as f64
        }),
        "double" => (8, |b, be| {
            let a: [u8; 8] = std::array::from_fn(|i| b[i]);
            if be {
                f64::from_be_bytes(a)
            } else {
                f64::from_le_bytes(a)
            }
        }),
        other => {
            return Err(file_error(
                path,
                format!("type '{other}' is not supported (use an integer type, float or double)"),
            ))
        }
    })
}

/// The data after the header (or in its `data file`), decoded (`encoding` raw or gzip).
fn nrrd_data(h: &NrrdHeader, path: &Path, reader: &mut impl Read) -> Result<Vec<u8>> {
    let encoding = h.need("encoding", path)?.to_ascii_lowercase();
    let mut raw = Vec::new();
    match h.get("data file").or_else(|| h.get("datafile")) {
        Some(f) => {
            // Only a file beside the header (or below it) is read: a header must not be able
            // to name any file on the machine (`data file: /etc/passwd`).
            let rel = Path::new(f);
            if rel.is_absolute()
                || rel.components().any(|c| {
                    !matches!(
                        c,
                        std::path::Component::Normal(_) | std::path::Component::CurDir
                    )
                })
            {
                return Err(file_error(
                    path,
                    format!(
                        "data file '{}' is not a path below the header's folder; hytled reads detached data from a relative path beside the .nhdr (move the data file there and name it relatively)",
                        super::clip(f)
                    ),
                ));
            }
            if f.eq_ignore_ascii_case("LIST") || f.contains('%') {
                return Err(file_error(
                    path,
                    format!("data file '{}': lists of data files are not read; join the slices into one data file", super::clip(f)),
                ));
            }
            let data_path = path.parent().unwrap_or(Path::new(".")).join(f);
            std::fs::File::open(&data_path)
                .and_then(|mut d| d.read_to_end(&mut raw))
                .map_err(|e| file_error(&data_path, format!("the NRRD data file: {e}")))?;
        }
        None => {
            reader
                .read_to_end(&mut raw)
                .map_err(|e| file_error(path, e))?;
        }
    }
    Ok(match encoding.as_str() {
        "raw" => raw,
        "gzip" | "gz" => {
            let mut out = Vec::new();
            flate2::read::MultiGzDecoder::new(&raw[..])
                .read_to_end(&mut out)
                .map_err(|e| {
                    file_error(path, format!("its gzip data could not be inflated: {e}"))
                })?;
            out
        }
        other => {
            return Err(file_error(
                path,
                format!("encoding '{other}' is not supported (use raw or gzip)"),
            ))
        }
    })
}

/// LPS from RAS (and back): x and y negated.
fn lps(v: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(-v.x, -v.y, v.z)
}

fn io_error(path: &Path, e: impl std::fmt::Display) -> Error {
    file_error(path, format!("could not be written: {e}"))
}

/// The NIfTI header of a 3-D image on `grid`'s voxels (sform and qform, mm, RAS).
fn nifti_header(grid: &Image) -> nifti::NiftiHeader {
    let mut h = nifti::NiftiHeader::default();
    let m = grid.to_world * 1e3;
    let axes = grid.axes() * 1e3;
    let s = grid.spacing().map(|v| v * 1e3);
    for (row, dst) in [&mut h.srow_x, &mut h.srow_y, &mut h.srow_z]
        .into_iter()
        .enumerate()
    {
        for c in 0..4 {
            dst[c] = m[(row, c)] as f32;
        }
    }
    h.sform_code = 1;
    // qform: the rotation of the normalized axes (a reflection goes into qfac).
    let mut r = Matrix3::from_fn(|i, j| axes[(i, j)] / s[j]);
    let qfac = if r.determinant() < 0.0 {
        r.column_mut(2).neg_mut();
        -1.0
    } else {
        1.0
    };
    let q = nalgebra::UnitQuaternion::from_matrix(&r);
    let q = if q.w < 0.0 {
        -q.into_inner()
    } else {
        q.into_inner()
    };
    h.quatern_b = q.i as f32;
    h.quatern_c = q.j as f32;
    h.quatern_d = q.k as f32;
    h.quatern_x = m[(0, 3)] as f32;
    h.quatern_y = m[(1, 3)] as f32;
    h.quatern_z = m[(2, 3)] as f32;
    h.qform_code = 1;
    h.pixdim = [
        qfac as f32,
        s[0] as f32,
        s[1] as f32,
        s[2] as f32,
        1.0,
        1.0,
        1.0,
        1.0,
    ];
    h.xyzt_units = 2; // mm
    h
}

/// Writes a scalar image (f32 values) as NIfTI-1 or NRRD (by extension), mm, RAS/LPS as
/// the format keeps them.
pub fn write_image(path: &Path, image: &Image) -> Result<()> {
    match ImageFormat::from_path(path) {
        Some(ImageFormat::Nifti) => {
            let mut a = ndarray::Array3::<f32>::zeros(image.dims);
            for k in 0..image.dims[2] {
                for j in 0..image.dims[1] {
                    for i in 0..image.dims[0] {
                        a[[i, j, k]] = image.values[image.index(i, j, k)] as f32;
                    }
                }
            }
            let h = nifti_header(image);
            nifti::writer::WriterOptions::new(path)
                .reference_header(&h)
                .write_nifti(&a)
                .map_err(|e| io_error(path, e))
        }
        Some(ImageFormat::Nrrd) => {
            let data: Vec<u8> = image
                .values
                .iter()
                .flat_map(|&v| (v as f32).to_le_bytes())
                .collect();
            write_nrrd(path, image, 1, &data)
        }
        None => Err(file_error(
            path,
            "unknown image format; name it .nii, .nii.gz or .nrrd",
        )),
    }
}

/// Writes the displacement field `u` (RAS, m; one vector per voxel of `grid`, i fastest) as
/// a displacement-field transform ITK and 3D Slicer read: components in LPS millimetres,
/// NIfTI (5-D, intent VECTOR) or NRRD (vector axis first, LPS space), by extension.
pub fn write_displacement_field(path: &Path, grid: &Image, u: &[Vector3<f64>]) -> Result<()> {
    if u.len() != grid.len() {
        return Err(Error::input(
            InputKind::Value,
            format!("{} displacements for {} voxels", u.len(), grid.len()),
        ));
    }
    match ImageFormat::from_path(path) {
        Some(ImageFormat::Nifti) => {
            let [nx, ny, nz] = grid.dims;
            let mut a = ndarray::Array5::<f32>::zeros((nx, ny, nz, 1, 3));
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let v = lps(&u[grid.index(i, j, k)]) * 1e3;
                        for c in 0..3 {
                            a[[i, j, k, 0, c]] = v[c] as f32;
                        }
                    }
                }
            }
            let mut h = nifti_header(grid);
            h.intent_code = 1007; // NIFTI_INTENT_VECTOR, as ANTs and ITK write fields
            nifti::writer::WriterOptions::new(path)
                .reference_header(&h)
                .write_nifti(&a)
                .map_err(|e| io_error(path, e))
        }
        Some(ImageFormat::Nrrd) => {
            let data: Vec<u8> = u
                .iter()
                .flat_map(|v| {
                    let w = lps(v) * 1e3;
                    [w.x as f32, w.y as f32, w.z as f32]
                })
                .flat_map(f32::to_le_bytes)
                .collect();
            write_nrrd(path, grid, 3, &data)
        }
        None => Err(file_error(
            path,
            "unknown image format; name it .nii, .nii.gz or .nrrd",
        )),
    }
}

/// An attached, gzip-encoded NRRD in LPS millimetres: `components` float values per voxel
/// (a `vector` axis first when more than one).
fn write_nrrd(path: &Path, grid: &Image, components: usize, data: &[u8]) -> Result<()> {
    let m = grid.to_world;
    let dir = |a: usize| {
        let v = lps(&Vector3::new(m[(0, a)], m[(1, a)], m[(2, a)])) * 1e3;
        format!("({:.17e},{:.17e},{:.17e})", v.x, v.y, v.z)
    };
    let origin = lps(&Vector3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)])) * 1e3;
    let [nx, ny, nz] = grid.dims;
    let (dimension, sizes, directions, kinds) = if components > 1 {
        (
            4,
            format!("{components} {nx} {ny} {nz}"),
            format!("none {} {} {}", dir(0), dir(1), dir(2)),
            "vector domain domain domain",
        )
    } else {
        (
            3,
            format!("{nx} {ny} {nz}"),
            format!("{} {} {}", dir(0), dir(1), dir(2)),
            "domain domain domain",
        )
    };
    let header = format!(
        "NRRD0004\n# written by hytled\ntype: float\ndimension: {dimension}\nspace: left-posterior-superior\n\
         sizes: {sizes}\nspace directions: {directions}\nkinds: {kinds}\nendian: little\nencoding: gzip\n\
         space origin: ({:.17e},{:.17e},{:.17e})\nspace units: \"mm\" \"mm\" \"mm\"\n\n",
        origin.x, origin.y, origin.z
    );
    let file = std::fs::File::create(path).map_err(|e| io_error(path, e))?;
    let mut w = std::io::BufWriter::new(file);
    w.write_all(header.as_bytes())
        .map_err(|e| io_error(path, e))?;
    let mut gz = flate2::write::GzEncoder::new(w, flate2::Compression::fast());
    gz.write_all(data).map_err(|e| io_error(path, e))?;
    gz.finish()
        .and_then(|mut w| w.flush())
        .map_err(|e| io_error(path, e))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// An oblique, anisotropic map: a rotation about an oblique axis times spacings, offset.
    pub(crate) fn oblique() -> Matrix4<f64> {
        let r = nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)),
            0.4,
        );
        let s = Matrix3::from_diagonal(&Vector3::new(1.0e-3, 1.5e-3, 2.0e-3));
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(r.matrix() * s));
        m.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&Vector3::new(0.01, -0.02, 0.03));
        m
    }

    fn ramp(dims: [usize; 3], to_world: Matrix4<f64>) -> Image {
        let mut im = Image::filled(dims, to_world, 0.0);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let n = im.index(i, j, k);
                    im.values[n] = (i + 10 * j + 100 * k) as f64;
                }
            }
        }
        im
    }

    /// Written and read back, in both formats and with an oblique reflected map: the same
    /// voxels and the same world positions (within f32 header precision for NIfTI).
    #[test]
    fn images_round_trip_with_their_orientation() {
        let dir = std::env::temp_dir().join(format!("hytled-image-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut reflected = oblique();
        reflected.column_mut(1).neg_mut();
        for map in [oblique(), reflected] {
            let im = ramp([4, 3, 5], map);
            for name in ["a.nii", "a.nii.gz", "a.nrrd"] {
                let p = dir.join(name);
                write_image(&p, &im).unwrap();
                let back = read_image(&p).unwrap();
                assert_eq!(back.dims, im.dims, "{name}");
                assert_eq!(back.values, im.values, "{name}");
                for ijk in [Vector3::zeros(), Vector3::new(3.0, 2.0, 4.0)] {
                    let (a, b) = (im.world(&ijk), back.world(&ijk));
                    assert!((a - b).norm() < 1e-9, "{name}: {a} vs {b}");
                }
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// The qform alone (no sform) gives the same map as the sform: the quaternion, qfac and
    /// offsets are read as the NIfTI standard says.
    #[test]
    fn the_qform_gives_the_sforms_map() {
        let mut m = oblique();
        m.column_mut(2).neg_mut();
        let im = Image::filled([2, 2, 2], m, 0.0);
        let mut h = nifti_header(&im);
        let with_sform = nifti_affine(&h).unwrap();
        h.sform_code = 0;
        let with_qform = nifti_affine(&h).unwrap();
        assert!(
            (with_sform - with_qform).amax() < 1e-5,
            "{with_sform} vs {with_qform}"
        );
        assert!((with_sform * 1e-3 - m).fixed_view::<3, 4>(0, 0).amax() < 1e-9);
    }

    /// Interpolation: exact for a linear field, None outside, nearest picks the voxel.
    #[test]
    fn trilinear_is_exact_for_a_linear_field() {
        let im = ramp([4, 3, 5], oblique());
        let ijk = Vector3::new(1.25, 0.5, 3.75);
        let x = im.world(&ijk);
        let v = im.trilinear(&x).unwrap();
        assert!((v - (1.25 + 5.0 + 375.0)).abs() < 1e-9, "{v}");
        assert_eq!(im.nearest(&x), Some((1 + 10 + 400) as f64));
        assert!(im
            .trilinear(&im.world(&Vector3::new(-0.1, 0.0, 0.0)))
            .is_none());
    }

    /// A displacement field written as NRRD: LPS millimetre components after a vector axis.
    #[test]
    fn a_displacement_field_is_written_in_lps_millimetres() {
        let dir = std::env::temp_dir().join(format!("hytled-field-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let grid = Image::filled([2, 1, 1], Matrix4::identity() * 1e-3, 0.0);
        let mut grid = grid;
        grid.to_world[(3, 3)] = 1.0;
        let u = vec![
            Vector3::new(1e-3, 2e-3, 3e-3),
            Vector3::new(-4e-3, 0.0, 0.5e-3),
        ];
        let p = dir.join("u.nrrd");
        write_displacement_field(&p, &grid, &u).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        let split = bytes.windows(2).position(|w| w == b"\n\n").unwrap();
        let header = String::from_utf8_lossy(&bytes[..split]);
        assert!(
            header.contains("kinds: vector domain domain domain"),
            "{header}"
        );
        assert!(
            header.contains("space: left-posterior-superior"),
            "{header}"
        );
        let mut raw = Vec::new();
        flate2::read::GzDecoder::new(&bytes[split + 2..])
            .read_to_end(&mut raw)
            .unwrap();
        let v: Vec<f32> = raw
            .chunks(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(v, vec![-1.0, -2.0, 3.0, 4.0, -0.0, 0.5]);
        // NIfTI: 5-D, intent VECTOR, the same components.
        let p = dir.join("u.nii");
        write_displacement_field(&p, &grid, &u).unwrap();
        use nifti::{IntoNdArray, NiftiObject};
        let o = nifti::ReaderOptions::new().read_file(&p).unwrap();
        assert_eq!(o.header().intent_code, 1007);
        assert_eq!(&o.header().dim[..6], &[5, 2, 1, 1, 1, 3]);
        let a = o.into_volume().into_ndarray::<f32>().unwrap();
        assert_eq!(a[[0, 0, 0, 0, 0]], -1.0);
        assert_eq!(a[[0, 0, 0, 0, 1]], -2.0);
        assert_eq!(a[[1, 0, 0, 0, 0]], 4.0);
        assert_eq!(a[[1, 0, 0, 0, 2]], 0.5);
        std::fs::remove_dir_all(&dir).ok();
    }
}
