//! VTK unstructured-grid reader: legacy `.vtk` (ASCII or binary, file versions up to 5.x) and
//! XML `.vtu` (ASCII, base64 binary, zlib-compressed, raw or base64 appended), parsed by the
//! `vtkio` crate.
//!
//! What is read:
//! - **Volume cells**: `VTK_TETRA` (10) become [`ElementShape::Tet4`], `VTK_HEXAHEDRON` (12)
//!   [`ElementShape::Hex8`], connectivity as written (VTK's node order is hytled's). A file with
//!   both is an error, as is one with neither.
//! - **Boundary faces**: `VTK_TRIANGLE` (5) and `VTK_QUAD` (9) go to the face set `vtk_faces`
//!   (node-index lists in the file's order).
//! - `VTK_VERTEX`, `VTK_POLY_VERTEX`, `VTK_LINE` and `VTK_POLY_LINE` (1-4) are ignored; any other
//!   cell type is an error naming the type and the cell's index.
//! - **Pieces**: all pieces of the file are concatenated; point and cell indices are offset by
//!   the points and cells of the pieces before.
//!
//! **Sets from data arrays.** A point- or cell-data array with one component whose values are
//! integers (an integer array, or a float array whose values are all whole numbers) becomes
//! sets, one per distinct nonzero value `v` of array `A`:
//! - point data: node set `A=v` (the points with value `v`);
//! - cell data: element set `A=v` (the volume cells with value `v`) and face set `A=v` (the
//!   triangles/quads with value `v`); values on ignored cells (vertices, lines) are dropped.
//!
//! An array with a single distinct nonzero value is also exposed under its own name `A` (a
//! 0/1 mask array `fixed` gives the set `fixed`). Zero means "not in a set". Arrays with more
//! than [`MAX_SET_VALUES`] distinct nonzero values (ids such as `vtkOriginalPointIds`) are data,
//! not sets, and are skipped with a warning. A set name can be both a node set (point array)
//! and an element set (cell array); [`MeshInput::set_nodes`] then takes the node set. Meshes
//! written by meshio from Gmsh files carry the integer cell array `gmsh:physical`, so their
//! physical groups come back as `gmsh:physical=<tag>`.
//!
//! Node ids ([`MeshInput::node_ids`]) are the 0-based point indices over all pieces; element
//! ids are the 0-based indices of the volume cells among all cells of the file (the cell ids
//! ParaView shows for a single piece). Coordinates are returned as written; the scene applies
//! its units factor afterwards.
//!
//! Limits of `vtkio` and how they are met:
//! - XML files with compressed (zlib, meshio's default) or appended (raw or base64) arrays, or
//!   with binary cell types other than UInt8 (meshio writes Int64), are rewritten with every
//!   binary array inline as uncompressed base64 and UInt8 cell types before parsing
//!   (`vtk_xml`); LZ4 / LZMA compressed files go to vtkio as they are.
//! - Binary legacy files of version 5.x (VTK 9 / ParaView / meshio `binary=True`; vtkio reads
//!   binary files up to 4.2) are read by `vtk_legacy5`; ASCII legacy 5.x files are rewritten
//!   to the 4.2 layout (OFFSETS/CONNECTIVITY cells to count-prefixed cells, vtktype* names to
//!   C names) and read by vtkio.
//!
//! No input makes the reader panic: legacy headers are checked against the file size before
//! parsing, inline arrays without data are refused, and the parse runs under
//! `super::guard_parser` as a last resort (no mutated file in the fuzz tests reaches it). Errors name the file and the line or byte
//! offset where the reader can tell it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use nalgebra::Vector3;
use vtkio::model::{Attribute, CellType, DataSet, IOBuffer, Piece, VertexNumbers};

use super::model::MeshInput;
use super::vtk_xml::find;
use super::{clip, file_error as fail, line_err};
use crate::geometry::{ElementShape, Mesh};
use crate::{Error, Result};

/// Integer arrays with more distinct nonzero values than this are not turned into sets.
pub const MAX_SET_VALUES: usize = 256;

/// Name of the face set holding every triangle and quad cell of the file.
pub const FACE_SET: &str = "vtk_faces";

/// Reads a VTK legacy (`.vtk`) or XML unstructured-grid (`.vtu`) file; see the module
/// documentation for what becomes cells, faces and sets. Coordinates are as written in the
/// file (no unit conversion). Files with another extension are recognised by their content.
pub fn read_vtk(path: &Path) -> Result<MeshInput> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_vtk(&bytes, path)
}

/// [`read_vtk`] on the bytes of a file already in memory; `path` only names the file in
/// messages and chooses legacy (`.vtk`) or XML (`.vtu`) by its extension.
pub fn parse_vtk(bytes: &[u8], path: &Path) -> Result<MeshInput> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let legacy = match ext.as_str() {
        "vtk" => true,
        "vtu" => false,
        _ => {
            let start = bytes
                .iter()
                .position(|b| !b.is_ascii_whitespace())
                .map_or(&[][..], |i| &bytes[i..]);
            if start.starts_with(b"#") {
                true
            } else if start.starts_with(b"<") {
                false
            } else {
                return Err(fail(
                    path,
                    "neither a legacy VTK file (first line '# vtk DataFile Version ...') nor an \
                     XML VTK file",
                ));
            }
        }
    };
    let vtk = if legacy {
        import_legacy(bytes, path)?
    } else {
        import_xml(bytes, path)?
    };
    convert(vtk, path)
}

/// The triangles of a VTK poly data file (legacy `.vtk` with `DATASET POLYDATA`, or XML
/// `.vtp`): its points (as written) and its polygons fanned into triangles and its triangle
/// strips split, over all pieces; for [`super::surface_file`].
pub(crate) fn read_polydata_triangles(path: &Path) -> Result<super::surface_file::Soup> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let legacy = !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vtp"));
    let vtk = if legacy {
        import_legacy(&bytes, path)?
    } else {
        import_xml(&bytes, path)?
    };
    let DataSet::PolyData { pieces, .. } = vtk.data else {
        return Err(fail(
            path,
            "the file holds no poly data; a surface is VTK poly data (DATASET POLYDATA, or .vtp) \
             with POLYGONS or triangle strips",
        ));
    };
    let (mut points, mut triangles) = (Vec::new(), Vec::new());
    for (pi, piece) in pieces.into_iter().enumerate() {
        let at = format!(" (piece {})", pi + 1);
        if let Piece::Source(src, _) = &piece {
            return Err(fail(
                path,
                format!("piece{at} is stored in another file ('{}')", clip(src)),
            ));
        }
        let data = loaded(piece, &at, path)?;
        let coords = coordinates(data.points, &at, path)?;
        let base = points.len();
        let n = coords.len() / 3;
        points.extend(
            coords
                .chunks_exact(3)
                .map(|c| Vector3::new(c[0], c[1], c[2])),
        );
        let index = |v: u64, k: usize| -> Result<usize> {
            usize::try_from(v)
                .ok()
                .filter(|&i| i < n)
                .map(|i| base + i)
                .ok_or_else(|| fail(path, format!("cell {k}{at} refers to point {v} of {n}")))
        };
        if let Some(polys) = data.polys {
            let lists = cell_lists(polys, &at, path)?;
            for (k, &(a, b)) in lists.ranges.iter().enumerate() {
                let ids = &lists.conn[a..b];
                if ids.len() < 3 {
                    return Err(fail(
                        path,
                        format!("polygon {k}{at} has {} points", ids.len()),
                    ));
                }
                for m in 1..ids.len() - 1 {
                    triangles.push([index(ids[0], k)?, index(ids[m], k)?, index(ids[m + 1], k)?]);
                }
            }
        }
        if let Some(strips) = data.strips {
            let lists = cell_lists(strips, &at, path)?;
            for (k, &(a, b)) in lists.ranges.iter().enumerate() {
                let ids = &lists.conn[a..b];
                for m in 0..ids.len().saturating_sub(2) {
                    let (p, q, r) = (
                        index(ids[m], k)?,
                        index(ids[m + 1], k)?,
                        index(ids[m + 2], k)?,
                    );
                    // Every other triangle of a strip turns the other way.
                    triangles.push(if m % 2 == 0 { [p, q, r] } else { [q, p, r] });
                }
            }
        }
    }
    if triangles.is_empty() {
        return Err(fail(
            path,
            "the poly data has no polygons or triangle strips",
        ));
    }
    Ok((points, triangles))
}

/// A piece's data, loaded (`at` names the piece in messages).
fn loaded<P: vtkio::model::PieceData>(piece: Piece<P>, at: &str, path: &Path) -> Result<P> {
    super::guard_parser("vtkio", || piece.into_loaded_piece_data(None))
        .map_err(|e| fail(path, format!("piece{at}: {e}")))?
        .map_err(|e| fail(path, format!("piece{at}: {e}")))
}

/// A piece's point coordinates, x y z after each other.
fn coordinates(points: IOBuffer, at: &str, path: &Path) -> Result<Vec<f64>> {
    let coords: Vec<f64> = points
        .cast_into()
        .ok_or_else(|| fail(path, format!("the points{at} are not numbers")))?;
    if !coords.len().is_multiple_of(3) {
        return Err(fail(
            path,
            format!(
                "{} point coordinates{at}, not a multiple of 3",
                coords.len()
            ),
        ));
    }
    Ok(coords)
}

fn import_legacy(bytes: &[u8], path: &Path) -> Result<vtkio::Vtk> {
    let first_end = bytes
        .iter()
        .position(|&b| b == b'\n')
        .unwrap_or(bytes.len());
    let first = String::from_utf8_lossy(&bytes[..first_end]);
    let first = first.trim();
    let lower = first.to_ascii_lowercase();
    let Some(version) = lower
        .strip_prefix('#')
        .map(str::trim_start)
        .and_then(|s| s.strip_prefix("vtk"))
        .map(str::trim_start)
        .and_then(|s| s.strip_prefix("datafile"))
        .map(str::trim_start)
        .and_then(|s| s.strip_prefix("version"))
        .map(str::trim)
    else {
        if bytes.is_empty() {
            return Err(fail(path, "the file is empty: not a VTK file"));
        }
        return Err(fail(
            path,
            format!(
                "line 1: expected '# vtk DataFile Version x.y', found '{}': not a legacy VTK file",
                clip(first)
            ),
        ));
    };
    let major: Option<u32> = version.split('.').next().and_then(|m| m.parse().ok());
    if major == Some(5) {
        if lower_has_binary(bytes) {
            // VTK 9 / ParaView / meshio binary: read by this crate (vtkio reads binary <= 4.2).
            return super::vtk_legacy5::read(bytes, path);
        }
        // VTK 9 / ParaView default: rewrite the OFFSETS/CONNECTIVITY cells as version 4.2.
        let text = legacy5_to_42(bytes, path)?;
        return import_legacy(text.as_bytes(), path);
    }
    match major {
        Some(m) if m >= 5 => {
            return Err(fail(
                path,
                format!(
                    "legacy VTK file version {version} is not supported (versions up to 5.x \
                     are read); write legacy version 5.1 or 4.2 or an XML .vtu file"
                ),
            ))
        }
        Some(_) => {}
        None => {
            return Err(fail(
                path,
                format!("line 1: unreadable legacy VTK version '{}'", clip(version)),
            ))
        }
    }
    check_legacy_counts(bytes, path)?;
    let parsed = super::guard_parser("vtkio", || vtkio::Vtk::parse_legacy_be(bytes));
    match parsed {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(fail(
            path,
            match locate_ascii_problem(bytes) {
                Some(where_) => format!("cannot parse the legacy VTK file: {where_}"),
                None => format!(
                    "cannot parse the legacy VTK file (vtkio: {e}); check that the counts in the \
                     POINTS, CELLS, CELL_TYPES, POINT_DATA and CELL_DATA headers match the data \
                     that follows and that the file is complete"
                ),
            },
        )),
        Err(e) => Err(fail(path, format!("cannot parse the legacy VTK file: {e}"))),
    }
}

/// True when the legacy header (line 3) says BINARY.
fn lower_has_binary(bytes: &[u8]) -> bool {
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(4096)]).to_ascii_lowercase();
    head.lines().nth(2).is_some_and(|l| l.trim() == "binary")
}

/// Rewrites an ASCII legacy file of version 5.x, whose CELLS section holds `OFFSETS` and
/// `CONNECTIVITY` arrays, into the version 4.2 layout (one `count i0 i1 ...` line per cell),
/// leaving every other section as it is.
fn legacy5_to_42(bytes: &[u8], path: &Path) -> Result<String> {
    let text = String::from_utf8_lossy(bytes);
    let mut out = String::with_capacity(text.len());
    let mut lines = text.lines().enumerate().peekable();
    let mut first = true;
    while let Some((ln, line)) = lines.next() {
        if first {
            out.push_str("# vtk DataFile Version 4.2\n");
            first = false;
            continue;
        }
        let mut words = line.split_whitespace();
        let head = words.next();
        if head.is_some_and(|w| w.eq_ignore_ascii_case("METADATA")) {
            // Version 5 metadata (INFORMATION blocks) runs to the next blank line.
            for (_, l) in lines.by_ref() {
                if l.trim().is_empty() {
                    break;
                }
            }
            continue;
        }
        if !head.is_some_and(|w| w.eq_ignore_ascii_case("CELLS")) {
            // Version 5 spells fixed-size types as vtktype*; version 4.2 uses C names.
            let mapped: Vec<&str> = line
                .split(' ')
                .map(|w| match w {
                    "vtktypeint64" => "long",
                    "vtktypeuint64" => "unsigned_long",
                    "vtktypeint32" => "int",
                    "vtktypeuint32" => "unsigned_int",
                    "vtktypeint16" => "short",
                    "vtktypeuint16" => "unsigned_short",
                    "vtktypeint8" => "char",
                    "vtktypeuint8" => "unsigned_char",
                    "vtktypefloat32" => "float",
                    "vtktypefloat64" => "double",
                    w => w,
                })
                .collect();
            out.push_str(&mapped.join(" "));
            out.push('\n');
            continue;
        }
        let counts: Vec<usize> = words.filter_map(|w| w.parse().ok()).collect();
        let [n_off, n_conn] = counts[..] else {
            return Err(line_err(
                path,
                ln + 1,
                "expected 'CELLS n_offsets n_connectivity'",
            ));
        };
        // Read the two arrays: all numbers after their keyword lines.
        let mut read_array = |name: &str, n: usize| -> Result<Vec<usize>> {
            let (kl, kw) = lines
                .next()
                .ok_or_else(|| line_err(path, ln + 2, format!("the file ends before {name}")))?;
            if !kw.trim_start().to_ascii_uppercase().starts_with(name) {
                return Err(line_err(
                    path,
                    kl + 1,
                    format!("expected {name}, found '{}'", clip(kw)),
                ));
            }
            let mut v = Vec::with_capacity(n.min(bytes.len()));
            while v.len() < n {
                let (l, t) = lines.next().ok_or_else(|| {
                    fail(
                        path,
                        format!("the file ends inside {name} ({} of {n} values)", v.len()),
                    )
                })?;
                for w in t.split_whitespace() {
                    v.push(w.parse().map_err(|_| {
                        line_err(
                            path,
                            l + 1,
                            format!("'{}' in {name} is not an index", clip(w)),
                        )
                    })?);
                }
            }
            if v.len() != n {
                return Err(fail(
                    path,
                    format!("{name} has {} values, the CELLS line says {n}", v.len()),
                ));
            }
            Ok(v)
        };
        let off = read_array("OFFSETS", n_off)?;
        let conn = read_array("CONNECTIVITY", n_conn)?;
        let ncell = n_off.saturating_sub(1);
        out.push_str(&format!("CELLS {ncell} {}\n", ncell + n_conn));
        for c in 0..ncell {
            let (a, b) = (off[c], off[c + 1]);
            if a > b || b > conn.len() {
                return Err(fail(
                    path,
                    format!("OFFSETS entry {c} ({a}..{b}) is out of order or beyond CONNECTIVITY"),
                ));
            }
            out.push_str(&(b - a).to_string());
            for &i in &conn[a..b] {
                out.push(' ');
                out.push_str(&i.to_string());
            }
            out.push('\n');
        }
    }
    Ok(out)
}

/// Checks the counts on the keyword lines of a legacy file against the file size before vtkio
/// parses it: vtkio reserves memory for the announced count first, so a corrupt count could
/// otherwise exhaust memory.
/// Where an ASCII legacy file's geometry goes wrong, for the parser's error (vtkio says only
/// "Parse error: Alt"): walks the POINTS, CELLS and CELL_TYPES sections after the four header
/// lines and names the line of the first token that is not a number where one is due, an
/// unknown section keyword, or data that ends early. None for binary files, when the
/// geometry reads through (the problem is in the attribute data), or on anything unexpected.
fn locate_ascii_problem(bytes: &[u8]) -> Option<String> {
    let text = std::str::from_utf8(bytes).ok()?;
    let mut lines = text.lines().enumerate();
    let header: Vec<&str> = lines.by_ref().take(4).map(|(_, l)| l).collect();
    if header.len() < 4 || !header[2].trim().eq_ignore_ascii_case("ascii") {
        return None;
    }
    let mut tokens = lines.flat_map(|(i, l)| l.split_whitespace().map(move |t| (i + 1, t)));
    loop {
        let (line, kw) = tokens.next()?;
        let upper = kw.to_ascii_uppercase();
        let (count, ints, what) = match upper.as_str() {
            "POINTS" => {
                let (_, n) = tokens.next()?;
                let n: usize = n.parse().ok()?;
                tokens.next()?; // data type
                (3 * n, false, "POINTS")
            }
            "CELLS" => {
                let (_, cells) = tokens.next()?;
                let (_, size) = tokens.next()?;
                cells.parse::<usize>().ok()?;
                (size.parse().ok()?, true, "CELLS")
            }
            "CELL_TYPES" => {
                let (_, n) = tokens.next()?;
                (n.parse().ok()?, true, "CELL_TYPES")
            }
            "POINT_DATA" | "CELL_DATA" | "FIELD" | "METADATA" => return None,
            _ => {
                return Some(format!(
                    "line {line}: '{}' where a section keyword (POINTS, CELLS, CELL_TYPES, \
                     POINT_DATA, CELL_DATA) is due; check the count of the section before it",
                    clip(kw)
                ))
            }
        };
        for k in 0..count {
            let Some((l, t)) = tokens.next() else {
                return Some(format!(
                    "the file ends after {k} of the {count} values {what} announces"
                ));
            };
            let ok = if ints {
                t.parse::<i64>().is_ok()
            } else {
                t.parse::<f64>().is_ok()
            };
            if !ok {
                return Some(format!(
                    "line {l}: '{}' is not {} (value {} of the {count} that {what} announces)",
                    clip(t),
                    if ints { "an integer" } else { "a number" },
                    k + 1
                ));
            }
        }
    }
}

fn check_legacy_counts(bytes: &[u8], path: &Path) -> Result<()> {
    let len = bytes.len() as u128 + 16;
    let mut attr_count: u128 = 0;
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        if i < 2 || line.len() > 200 || !line.first().is_some_and(u8::is_ascii_alphabetic) {
            continue;
        }
        let Ok(text) = std::str::from_utf8(line) else {
            continue;
        };
        let t: Vec<&str> = text.split_whitespace().collect();
        let int = |k: usize| -> Option<u128> { t.get(k).and_then(|s| s.parse::<u128>().ok()) };
        let kw = t[0].to_ascii_uppercase();
        let need: Option<u128> = match kw.as_str() {
            "POINTS" => int(1).map(|n| n.saturating_mul(3)),
            "CELLS" | "POLYGONS" | "LINES" | "VERTICES" | "TRIANGLE_STRIPS" => {
                match (int(1), int(2)) {
                    (Some(a), Some(b)) => Some(a.max(b)),
                    (a, b) => a.or(b),
                }
            }
            "CELL_TYPES" | "X_COORDINATES" | "Y_COORDINATES" | "Z_COORDINATES" => int(1),
            "POINT_DATA" | "CELL_DATA" => {
                attr_count = int(1).unwrap_or(0);
                int(1)
            }
            "SCALARS" => Some(int(3).unwrap_or(1).saturating_mul(attr_count)),
            "COLOR_SCALARS" | "TEXTURE_COORDINATES" => int(2).map(|c| c.saturating_mul(attr_count)),
            "VECTORS" | "NORMALS" => Some(attr_count.saturating_mul(3)),
            "TENSORS" => Some(attr_count.saturating_mul(9)),
            "LOOKUP_TABLE" => int(2).map(|n| n.saturating_mul(4)),
            "FIELD" => int(2),
            _ => {
                // A FIELD array line: name numComponents numTuples dataType.
                if t.len() == 4 {
                    match (int(1), int(2)) {
                        (Some(a), Some(b)) => Some(a.saturating_mul(b)),
                        _ => None,
                    }
                } else {
                    None
                }
            }
        };
        let bits = t.iter().any(|s| s.eq_ignore_ascii_case("bit"));
        let limit = if bits { len.saturating_mul(8) } else { len };
        if let Some(n) = need {
            if n > limit {
                return Err(line_err(
                    path,
                    i + 1,
                    format!(
                        "'{}' announces {n} values, more than the file ({} bytes) holds: \
                         wrong count or corrupt file",
                        clip(text.trim()),
                        bytes.len()
                    ),
                ));
            }
        }
    }
    Ok(())
}

fn import_xml(bytes: &[u8], path: &Path) -> Result<vtkio::Vtk> {
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(fail(path, "the file is empty: not a VTK file"));
    }
    // Compressed or appended arrays, and binary cell types other than UInt8, are rewritten
    // inline as uncompressed base64 with UInt8 cell types (see `vtk_xml`).
    let original = bytes;
    super::vtk_xml::check_empty_arrays(bytes, path)?;
    let normalized = super::vtk_xml::normalize(bytes, path)?;
    let bytes: &[u8] = normalized.as_deref().unwrap_or(bytes);
    let fixed = fix_cell_types(bytes, path)?;
    let input: &[u8] = fixed.as_deref().unwrap_or(bytes);
    let parsed = super::guard_parser("vtkio", || vtkio::Vtk::parse_xml(input));
    match parsed {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => {
            // The parser's message can quote a whole array: 300 characters tell enough.
            let mut e = e.to_string();
            if let Some((cut, _)) = e.char_indices().nth(300) {
                e.truncate(cut);
                e.push_str("...");
            }
            let place = super::vtk_xml::locate_parse_error(original, &e)
                .map_or(String::new(), |p| format!("{p}: "));
            Err(fail(
                path,
                format!("{place}cannot read the XML VTK file: {e}"),
            ))
        }
        Err(e) => Err(fail(path, format!("cannot read the XML VTK file: {e}"))),
    }
}

/// The value of attribute `name` in the tag text `tag` (`name="value"`), with its range.
fn attribute<'a>(tag: &'a [u8], name: &[u8]) -> Option<(&'a [u8], usize, usize)> {
    let mut from = 0;
    while let Some(rel) = find(&tag[from..], name) {
        let at = from + rel;
        let before_ok = at > 0 && tag[at - 1].is_ascii_whitespace();
        let mut i = at + name.len();
        while i < tag.len() && tag[i].is_ascii_whitespace() {
            i += 1;
        }
        if before_ok && i < tag.len() && tag[i] == b'=' {
            i += 1;
            while i < tag.len() && tag[i].is_ascii_whitespace() {
                i += 1;
            }
            if i < tag.len() && (tag[i] == b'"' || tag[i] == b'\'') {
                let q = tag[i];
                let s = i + 1;
                let e = tag[s..].iter().position(|&b| b == q).map(|p| s + p)?;
                return Some((&tag[s..e], s, e));
            }
        }
        from = at + 1;
    }
    None
}

/// vtkio reads the `types` array of `<Cells>` only as UInt8; meshio writes it as Int64. An
/// ASCII `types` array of another integer type is retyped UInt8 (its values are small); a
/// binary one cannot be, and is an error saying how to re-export. Returns the corrected bytes
/// when something was changed.
fn fix_cell_types(bytes: &[u8], path: &Path) -> Result<Option<Vec<u8>>> {
    let mut edits: Vec<(usize, usize)> = Vec::new();
    let mut from = 0;
    while let Some(rel) = find(&bytes[from..], b"<Cells") {
        let cells = from + rel;
        let end = find(&bytes[cells..], b"</Cells>").map_or(bytes.len(), |e| cells + e);
        let mut i = cells;
        while let Some(r) = find(&bytes[i..end], b"<DataArray") {
            let t0 = i + r;
            let t1 = bytes[t0..end]
                .iter()
                .position(|&b| b == b'>')
                .map_or(end, |p| t0 + p);
            let tag = &bytes[t0..t1];
            if attribute(tag, b"Name").is_some_and(|(v, _, _)| v == b"types") {
                if let Some((ty, s, e)) = attribute(tag, b"type") {
                    if ty != b"UInt8" {
                        let ascii = attribute(tag, b"format")
                            .is_some_and(|(f, _, _)| f.eq_ignore_ascii_case(b"ascii"));
                        let integer = [
                            &b"Int8"[..],
                            b"Int16",
                            b"UInt16",
                            b"Int32",
                            b"UInt32",
                            b"Int64",
                            b"UInt64",
                        ]
                        .contains(&ty);
                        if !ascii || !integer {
                            return Err(fail(
                                path,
                                format!(
                                    "the cell types array is {} in {} encoding, which the \
                                     reader (vtkio) cannot read (it needs UInt8; meshio writes \
                                     Int64): write the file with ASCII encoding (meshio: \
                                     write(..., binary=False)), as legacy .vtk (meshio: \
                                     fmt_version=\"4.2\"), or from ParaView",
                                    String::from_utf8_lossy(ty),
                                    String::from_utf8_lossy(
                                        attribute(tag, b"format").map_or(&b"?"[..], |f| f.0)
                                    )
                                ),
                            ));
                        }
                        edits.push((t0 + s, t0 + e));
                    }
                }
            }
            i = t1.max(t0 + 1);
        }
        from = end.max(cells + 1);
    }
    if edits.is_empty() {
        return Ok(None);
    }
    let mut out = Vec::with_capacity(bytes.len());
    let mut last = 0;
    for (s, e) in edits {
        out.extend_from_slice(&bytes[last..s]);
        out.extend_from_slice(b"UInt8");
        last = e;
    }
    out.extend_from_slice(&bytes[last..]);
    Ok(Some(out))
}

/// What a VTK cell is to this reader.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Volume(ElementShape),
    Face,
    Ignored,
}

fn role(ct: CellType) -> Option<(Role, Option<usize>)> {
    Some(match ct {
        CellType::Tetra => (Role::Volume(ElementShape::Tet4), Some(4)),
        CellType::Hexahedron => (Role::Volume(ElementShape::Hex8), Some(8)),
        CellType::Triangle => (Role::Face, Some(3)),
        CellType::Quad => (Role::Face, Some(4)),
        CellType::Vertex => (Role::Ignored, Some(1)),
        CellType::Line => (Role::Ignored, Some(2)),
        CellType::PolyVertex | CellType::PolyLine => (Role::Ignored, None),
        _ => return None,
    })
}

fn vtk_name(ct: CellType) -> &'static str {
    match ct {
        CellType::Tetra => "VTK_TETRA",
        CellType::Hexahedron => "VTK_HEXAHEDRON",
        CellType::Triangle => "VTK_TRIANGLE",
        CellType::Quad => "VTK_QUAD",
        CellType::Vertex => "VTK_VERTEX",
        CellType::Line => "VTK_LINE",
        CellType::PolyVertex => "VTK_POLY_VERTEX",
        CellType::PolyLine => "VTK_POLY_LINE",
        CellType::TriangleStrip => "VTK_TRIANGLE_STRIP",
        CellType::Polygon => "VTK_POLYGON",
        CellType::Pixel => "VTK_PIXEL",
        CellType::Voxel => "VTK_VOXEL",
        CellType::Wedge => "VTK_WEDGE",
        CellType::Pyramid => "VTK_PYRAMID",
        CellType::QuadraticTetra => "VTK_QUADRATIC_TETRA",
        CellType::QuadraticHexahedron => "VTK_QUADRATIC_HEXAHEDRON",
        CellType::QuadraticTriangle => "VTK_QUADRATIC_TRIANGLE",
        CellType::QuadraticQuad => "VTK_QUADRATIC_QUAD",
        CellType::QuadraticEdge => "VTK_QUADRATIC_EDGE",
        CellType::QuadraticWedge => "VTK_QUADRATIC_WEDGE",
        CellType::QuadraticPyramid => "VTK_QUADRATIC_PYRAMID",
        CellType::TriquadraticHexahedron => "VTK_TRIQUADRATIC_HEXAHEDRON",
        _ => "",
    }
}

/// Cell `i`'s point ranges into a flat connectivity.
struct CellLists {
    conn: Vec<u64>,
    ranges: Vec<(usize, usize)>,
}

fn cell_lists(cells: VertexNumbers, piece: &str, path: &Path) -> Result<CellLists> {
    match cells {
        VertexNumbers::Legacy {
            num_cells,
            vertices,
        } => {
            let conn: Vec<u64> = vertices.into_iter().map(u64::from).collect();
            let mut ranges = Vec::with_capacity((num_cells as usize).min(conn.len()));
            let mut pos = 0usize;
            for i in 0..num_cells as usize {
                let n = *conn.get(pos).ok_or_else(|| {
                    fail(
                        path,
                        format!(
                            "CELLS{piece}: the list ends at cell {i} of the {num_cells} announced"
                        ),
                    )
                })? as usize;
                let end = pos
                    .checked_add(1 + n)
                    .filter(|&e| e <= conn.len())
                    .ok_or_else(|| {
                        fail(
                            path,
                            format!(
                                "CELLS{piece}: cell {i} has {n} points, past the end of the list"
                            ),
                        )
                    })?;
                ranges.push((pos + 1, end));
                pos = end;
            }
            if pos != conn.len() {
                return Err(fail(
                    path,
                    format!(
                        "CELLS{piece}: the header's size {} does not match the {num_cells} cells \
                         listed ({pos} numbers)",
                        conn.len()
                    ),
                ));
            }
            Ok(CellLists { conn, ranges })
        }
        VertexNumbers::XML {
            connectivity,
            offsets,
        } => {
            let mut ranges = Vec::with_capacity(offsets.len());
            let mut prev = 0usize;
            for (i, &o) in offsets.iter().enumerate() {
                let o = usize::try_from(o).unwrap_or(usize::MAX);
                if o < prev || o > connectivity.len() {
                    return Err(fail(
                        path,
                        format!(
                            "Cells{piece}: offset {o} of cell {i} is outside the connectivity \
                             ({} entries) or decreasing",
                            connectivity.len()
                        ),
                    ));
                }
                ranges.push((prev, o));
                prev = o;
            }
            Ok(CellLists {
                conn: connectivity,
                ranges,
            })
        }
    }
}

/// One-component values as integers, or None when the array is not an integer array.
fn integer_values(buf: IOBuffer) -> Option<Vec<i64>> {
    fn floats<T: Into<f64> + Copy>(v: Vec<T>) -> Option<Vec<i64>> {
        v.into_iter()
            .map(|x| {
                let f: f64 = x.into();
                (f.is_finite() && f.fract() == 0.0 && f.abs() < 9.0e15).then_some(f as i64)
            })
            .collect()
    }
    match buf {
        IOBuffer::Bit(_) => None,
        IOBuffer::U8(v) => Some(v.into_iter().map(i64::from).collect()),
        IOBuffer::I8(v) => Some(v.into_iter().map(i64::from).collect()),
        IOBuffer::U16(v) => Some(v.into_iter().map(i64::from).collect()),
        IOBuffer::I16(v) => Some(v.into_iter().map(i64::from).collect()),
        IOBuffer::U32(v) => Some(v.into_iter().map(i64::from).collect()),
        IOBuffer::I32(v) => Some(v.into_iter().map(i64::from).collect()),
        IOBuffer::U64(v) => v.into_iter().map(|x| i64::try_from(x).ok()).collect(),
        IOBuffer::I64(v) => Some(v),
        IOBuffer::F32(v) => floats(v),
        IOBuffer::F64(v) => floats(v),
    }
}

/// One-component arrays of a piece's attributes: (name, values) for integer ones, names of the
/// others.
fn arrays(attrs: Vec<Attribute>) -> (Vec<(String, Vec<i64>)>, Vec<String>) {
    let mut ints = Vec::new();
    let mut others = Vec::new();
    let mut take = |name: String, comps: usize, data: IOBuffer| {
        if comps != 1 {
            others.push(name);
            return;
        }
        match integer_values(data) {
            Some(v) => ints.push((name, v)),
            None => others.push(name),
        }
    };
    for a in attrs {
        match a {
            Attribute::DataArray(d) => {
                let comps = d.num_comp();
                take(d.name, comps, d.data);
            }
            Attribute::Field { data_array, .. } => {
                for f in data_array {
                    let comps = f.num_comp();
                    take(f.name, comps, f.data);
                }
            }
        }
    }
    (ints, others)
}

/// Values of one array by set value: node indices (point data) or volume cells and faces
/// (cell data).
#[derive(Default)]
struct ValueSets {
    nodes: BTreeMap<i64, Vec<usize>>,
    cells: BTreeMap<i64, Vec<usize>>,
    faces: BTreeMap<i64, Vec<Vec<usize>>>,
}

impl ValueSets {
    fn values(&self) -> BTreeSet<i64> {
        self.nodes
            .keys()
            .chain(self.cells.keys())
            .chain(self.faces.keys())
            .copied()
            .collect()
    }
}

fn convert(vtk: vtkio::Vtk, path: &Path) -> Result<MeshInput> {
    let pieces = match vtk.data {
        DataSet::UnstructuredGrid { pieces, .. } => pieces,
        other => {
            let kind = match other {
                DataSet::ImageData { .. } => "image data (structured points)",
                DataSet::StructuredGrid { .. } => "a structured grid",
                DataSet::RectilinearGrid { .. } => "a rectilinear grid",
                DataSet::PolyData { .. } => "poly data (surfaces)",
                DataSet::Field { .. } => "field data",
                DataSet::UnstructuredGrid { .. } => "an unstructured grid",
            };
            return Err(fail(
                path,
                format!(
                    "the file holds {kind}, not an unstructured grid; hytled reads volume meshes \
                     from VTK unstructured grids (DATASET UNSTRUCTURED_GRID, or .vtu)"
                ),
            ));
        }
    };
    if pieces.is_empty() {
        return Err(fail(path, "the unstructured grid has no pieces"));
    }
    let multi = pieces.len() > 1;

    let mut merged = Merged::default();
    for (pi, piece) in pieces.into_iter().enumerate() {
        let at = if multi {
            format!(" (piece {})", pi + 1)
        } else {
            String::new()
        };
        if let Piece::Source(src, _) = &piece {
            return Err(fail(
                path,
                format!(
                    "piece{at} is stored in another file ('{}'); parallel files (.pvtu) are not \
                     read: merge the pieces into one .vtu",
                    clip(src)
                ),
            ));
        }
        merged.add_piece(loaded(piece, &at, path)?, &at, path)?;
    }
    merged.finish(path)
}

/// The pieces of an unstructured grid read so far: points, volume cells and boundary faces in
/// file order, and the integer arrays that may name node, element and face sets.
#[derive(Default)]
struct Merged {
    nodes: Vec<Vector3<f64>>,
    cells: Vec<usize>,
    element_ids: Vec<u64>,
    faces: Vec<Vec<usize>>,
    /// The volume cells' shape and the first cell that has it.
    shape: Option<(ElementShape, usize)>,
    point_sets: BTreeMap<String, ValueSets>,
    cell_sets: BTreeMap<String, ValueSets>,
    /// Arrays that are not one-component integer arrays in some piece.
    not_sets: BTreeSet<String>,
    warnings: Vec<String>,
    /// Cells of the pieces before this one.
    cell_offset: usize,
}

impl Merged {
    /// Adds a piece (`at` names it in messages): its points, its cells (volume cells, faces,
    /// or ignored) and its integer arrays.
    fn add_piece(
        &mut self,
        data: vtkio::model::UnstructuredGridPiece,
        at: &str,
        path: &Path,
    ) -> Result<()> {
        // Points.
        let coords = coordinates(data.points, at, path)?;
        let node_offset = self.nodes.len();
        let n_points = coords.len() / 3;
        for (i, c) in coords.chunks_exact(3).enumerate() {
            let p = Vector3::new(c[0], c[1], c[2]);
            if !p.iter().all(|x| x.is_finite()) {
                return Err(fail(
                    path,
                    format!("point {}{at} has a non-finite coordinate", node_offset + i),
                ));
            }
            self.nodes.push(p);
        }

        let became = self.add_cells(data.cells, n_points, node_offset, at, path)?;
        // Data arrays.
        let (pints, pothers) = arrays(data.data.point);
        self.not_sets
            .extend(pothers.into_iter().map(|n| format!("point:{n}")));
        for (name, vals) in pints {
            if vals.len() != n_points {
                self.warnings.push(format!(
                    "point array '{name}'{at} has {} values for {n_points} points; not used as \
                     sets",
                    vals.len()
                ));
                self.not_sets.insert(format!("point:{name}"));
                continue;
            }
            let vs = self.point_sets.entry(name).or_default();
            for (i, v) in vals.into_iter().enumerate() {
                if v != 0 {
                    vs.nodes.entry(v).or_default().push(node_offset + i);
                }
            }
        }
        let (cints, cothers) = arrays(data.data.cell);
        self.not_sets
            .extend(cothers.into_iter().map(|n| format!("cell:{n}")));
        for (name, vals) in cints {
            if vals.len() != became.len() {
                self.warnings.push(format!(
                    "cell array '{name}'{at} has {} values for {} self.cells; not used as sets",
                    vals.len(),
                    became.len()
                ));
                self.not_sets.insert(format!("cell:{name}"));
                continue;
            }
            let vs = self.cell_sets.entry(name).or_default();
            for (b, v) in became.iter().zip(vals) {
                match (b, v) {
                    (_, 0) | (None, _) => {}
                    (Some((Role::Volume(_), c)), v) => vs.cells.entry(v).or_default().push(*c),
                    (Some((_, f)), v) => {
                        vs.faces.entry(v).or_default().push(self.faces[*f].clone())
                    }
                }
            }
        }
        self.cell_offset += became.len();
        Ok(())
    }

    /// A piece's cells: volume cells of one shape and boundary faces, others ignored; returns
    /// what each became (volume cell or face, and its index).
    fn add_cells(
        &mut self,
        cells: vtkio::model::Cells,
        n_points: usize,
        node_offset: usize,
        at: &str,
        path: &Path,
    ) -> Result<Vec<Option<(Role, usize)>>> {
        let cell_offset = self.cell_offset;
        // Cells.
        let lists = cell_lists(cells.cell_verts, at, path)?;
        let types = cells.types;
        if types.len() != lists.ranges.len() {
            return Err(fail(
                path,
                format!(
                    "{} self.cells but {} cell types{at}",
                    lists.ranges.len(),
                    types.len()
                ),
            ));
        }
        // What each cell of the piece became: volume cell or face index.
        let mut became: Vec<Option<(Role, usize)>> = Vec::with_capacity(types.len());
        for (i, (&ct, &(s, e))) in types.iter().zip(&lists.ranges).enumerate() {
            let gi = cell_offset + i;
            let (r, n) = role(ct).ok_or_else(|| {
                let name = vtk_name(ct);
                let name = if name.is_empty() {
                    format!("{ct:?}")
                } else {
                    name.to_string()
                };
                fail(
                    path,
                    format!(
                        "unsupported VTK cell type {} ({name}) at cell {gi}{at}; hytled reads \
                         VTK_TETRA (10) or VTK_HEXAHEDRON (12) volume self.cells, with VTK_TRIANGLE \
                         (5) or VTK_QUAD (9) boundary faces: convert the mesh to linear \
                         tetrahedra or hexahedra",
                        ct as u8
                    ),
                )
            })?;
            let verts = &lists.conn[s..e];
            if let Some(n) = n {
                if verts.len() != n {
                    return Err(fail(
                        path,
                        format!(
                            "cell {gi}{at} is a {} with {} points; it needs {n}",
                            vtk_name(ct),
                            verts.len()
                        ),
                    ));
                }
            }
            if r == Role::Ignored {
                became.push(None);
                continue;
            }
            let idx = verts
                .iter()
                .map(|&v| {
                    usize::try_from(v)
                        .ok()
                        .filter(|&v| v < n_points)
                        .map(|v| v + node_offset)
                        .ok_or_else(|| {
                            fail(
                                path,
                                format!(
                                    "cell {gi}{at} references point {v}, but the piece has \
                                     {n_points} points"
                                ),
                            )
                        })
                })
                .collect::<Result<Vec<usize>>>()?;
            match r {
                Role::Volume(sh) => {
                    match self.shape {
                        None => self.shape = Some((sh, gi)),
                        Some((s0, g0)) if s0 != sh => {
                            return Err(fail(
                                path,
                                format!(
                                    "mixed VTK_TETRA and VTK_HEXAHEDRON self.cells (cell {g0} is a {}, \
                                     cell {gi}{at} a {}) are not supported; use one element self.shape",
                                    if s0 == ElementShape::Tet4 {
                                        "VTK_TETRA"
                                    } else {
                                        "VTK_HEXAHEDRON"
                                    },
                                    vtk_name(ct)
                                ),
                            ))
                        }
                        _ => {}
                    }
                    became.push(Some((r, self.element_ids.len())));
                    self.cells.extend_from_slice(&idx);
                    self.element_ids.push(gi as u64);
                }
                Role::Face => {
                    became.push(Some((r, self.faces.len())));
                    self.faces.push(idx);
                }
                Role::Ignored => unreachable!(),
            }
        }

        Ok(became)
    }

    /// The mesh and its sets: a one-component integer array NAME gives a set `NAME=v` per
    /// value v (and `NAME` itself when it has one value), of nodes, elements or faces.
    fn finish(self, path: &Path) -> Result<MeshInput> {
        let Merged {
            nodes,
            cells,
            element_ids,
            faces,
            shape,
            point_sets,
            cell_sets,
            not_sets,
            mut warnings,
            ..
        } = self;
        let Some((shape, _)) = shape else {
            return Err(fail(
                path,
                "no volume cells: the file has no VTK_TETRA (10) or VTK_HEXAHEDRON (12) cells",
            ));
        };

        let mut node_sets: BTreeMap<String, Vec<usize>> = BTreeMap::new();
        let mut element_sets: BTreeMap<String, Vec<usize>> = BTreeMap::new();
        let mut face_sets: BTreeMap<String, Vec<Vec<usize>>> = BTreeMap::new();
        for (kind, sets) in [("point", point_sets), ("cell", cell_sets)] {
            for (name, vs) in sets {
                if not_sets.contains(&format!("{kind}:{name}")) {
                    continue;
                }
                let values = vs.values();
                if values.len() > MAX_SET_VALUES {
                    warnings.push(format!(
                        "{kind} array '{name}' has {} distinct values; it is treated as data, not \
                             as sets (at most {MAX_SET_VALUES})",
                        values.len()
                    ));
                    continue;
                }
                let alias = values.len() == 1;
                for (v, mut idx) in vs.nodes {
                    idx.sort_unstable();
                    idx.dedup();
                    if alias {
                        node_sets.insert(name.clone(), idx.clone());
                    }
                    node_sets.insert(format!("{name}={v}"), idx);
                }
                for (v, idx) in vs.cells {
                    if alias {
                        element_sets.insert(name.clone(), idx.clone());
                    }
                    element_sets.insert(format!("{name}={v}"), idx);
                }
                for (v, f) in vs.faces {
                    if alias {
                        face_sets.insert(name.clone(), f.clone());
                    }
                    face_sets.insert(format!("{name}={v}"), f);
                }
            }
        }
        if !faces.is_empty() {
            face_sets.insert(FACE_SET.to_string(), faces);
        }

        let node_ids = (0..nodes.len() as u64).collect();
        Ok(MeshInput {
            mesh: Mesh {
                nodes,
                shape,
                cells,
            },
            node_ids,
            element_ids,
            node_sets,
            element_sets,
            face_sets,
            warnings,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::quality::tet_signed_volume;
    use crate::io::msh::read_msh;
    use crate::io::vtk_xml::base64;
    use std::path::PathBuf;

    fn data(dir: &str, name: &str) -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(dir)
            .join(name)
    }

    fn read(name: &str) -> MeshInput {
        read_vtk(&data("vtk", name)).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    fn expected() -> serde_json::Value {
        let text = std::fs::read_to_string(data("vtk", "expected.json")).unwrap();
        serde_json::from_str(&text).unwrap()
    }

    fn err(bytes: &[u8], name: &str) -> String {
        match parse_vtk(bytes, Path::new(name)) {
            Ok(_) => panic!("expected an error"),
            Err(e) => {
                eprintln!("{e}");
                e.to_string()
            }
        }
    }

    fn max_abs_diff(a: &MeshInput, b: &MeshInput) -> f64 {
        assert_eq!(a.mesh.nodes.len(), b.mesh.nodes.len());
        a.mesh
            .nodes
            .iter()
            .zip(&b.mesh.nodes)
            .map(|(p, q)| (p - q).amax())
            .fold(0.0, f64::max)
    }

    #[test]
    fn cylinder_vtu_and_vtk_match_the_msh() {
        let exp = expected();
        let msh = read_msh(&data("msh", "cyl_v41.msh")).unwrap();
        let vtu = read("cyl.vtu");
        let vtk = read("cyl.vtk");
        for m in [&vtu, &vtk] {
            assert_eq!(
                m.mesh.nodes.len() as u64,
                exp["cyl"]["points"].as_u64().unwrap()
            );
            assert_eq!(m.mesh.shape, ElementShape::Tet4);
            assert_eq!(
                m.mesh.num_cells() as u64,
                exp["cyl"]["cells"]["tetra"].as_u64().unwrap()
            );
            assert_eq!(
                m.face_sets[FACE_SET].len() as u64,
                exp["cyl"]["cells"]["triangle"].as_u64().unwrap()
            );
            assert_eq!(m.mesh.cells, msh.mesh.cells);
            // Physical groups through gmsh:physical: 1 bottom, 2 top, 3 lateral, 4 volume.
            for (tag, name) in [(1, "bottom"), (2, "top"), (3, "lateral")] {
                let set = format!("gmsh:physical={tag}");
                assert_eq!(m.face_sets[&set], msh.face_sets[name], "{set}");
                assert!(!m.element_sets.contains_key(&set));
            }
            assert_eq!(
                m.element_sets["gmsh:physical=4"],
                msh.element_sets["volume"]
            );
            // Several values: no alias set named after the array.
            assert!(!m.element_sets.contains_key("gmsh:physical"));
            for e in 0..m.mesh.num_cells() {
                let c = m.mesh.cell(e);
                let p = |k: usize| &m.mesh.nodes[c[k]];
                assert!(tet_signed_volume(p(0), p(1), p(2), p(3)) > 0.0);
            }
            // Element ids: positions among all cells (the 330 triangles come first).
            assert_eq!(m.element_ids[0], 330);
        }
        // Legacy 4.2 from meshio keeps full precision; the VTU ASCII writer 12 digits.
        assert_eq!(max_abs_diff(&vtk, &msh), 0.0);
        let d = max_abs_diff(&vtu, &msh);
        assert!(d < 1e-13, "vtu vs msh: {d}");
        eprintln!("cylinder: VTU ASCII vs MSH coordinates differ by at most {d:.2e} m");
        assert_eq!(vtu.mesh.cells, vtk.mesh.cells);
        assert_eq!(vtu.set_names(), vtk.set_names());
    }

    #[test]
    fn hex_box_base64_vtu_and_binary_vtk_match_the_msh() {
        let exp = expected();
        let msh = read_msh(&data("msh", "box_hex_v41.msh")).unwrap();
        for name in ["box_hex_b64.vtu", "box_hex_bin.vtk"] {
            let m = read(name);
            assert_eq!(m.mesh.shape, ElementShape::Hex8, "{name}");
            assert_eq!(
                m.mesh.num_cells() as u64,
                exp["box_hex"]["cells"]["hexahedron"].as_u64().unwrap()
            );
            assert_eq!(
                m.mesh.nodes.len() as u64,
                exp["box_hex"]["points"].as_u64().unwrap()
            );
            // Binary doubles from meshio's exact parse of the ASCII msh: bit for bit.
            assert_eq!(max_abs_diff(&m, &msh), 0.0, "{name}");
            assert_eq!(m.mesh.cells, msh.mesh.cells, "{name}");
            assert_eq!(
                m.face_sets[FACE_SET].len() as u64,
                exp["box_hex"]["cells"]["quad"].as_u64().unwrap()
            );
            // gmsh:physical 1 on the faces, 2 on the hexahedra.
            assert_eq!(
                m.face_sets["gmsh:physical=1"], msh.face_sets["fixed"],
                "{name}"
            );
            assert_eq!(
                m.element_sets["gmsh:physical=2"], msh.element_sets["tissue"],
                "{name}"
            );
        }
    }

    /// Everything but the warnings.
    fn same(a: &MeshInput, b: &MeshInput, what: &str) {
        assert_eq!(a.mesh.shape, b.mesh.shape, "{what}");
        assert_eq!(max_abs_diff(a, b), 0.0, "{what}");
        assert_eq!(a.mesh.cells, b.mesh.cells, "{what}");
        assert_eq!(a.node_ids, b.node_ids, "{what}");
        assert_eq!(a.element_ids, b.element_ids, "{what}");
        assert_eq!(a.node_sets, b.node_sets, "{what}");
        assert_eq!(a.element_sets, b.element_sets, "{what}");
        assert_eq!(a.face_sets, b.face_sets, "{what}");
    }

    #[test]
    fn meshio_binary_vtu_with_int64_cell_types_reads() {
        // meshio's uncompressed binary VTU: Int64 cell types, header base64-encoded apart.
        same(
            &read("box_hex_meshio_b64.vtu"),
            &read("box_hex_bin.vtk"),
            "meshio b64",
        );
    }

    #[test]
    fn binary_legacy_5_1_reads_like_ascii() {
        // meshio binary=True (version 5.1, vtktypeint64 OFFSETS/CONNECTIVITY, big-endian).
        let bin = read("cyl_v51_bin.vtk");
        same(&bin, &read("cyl_v51.vtk"), "cyl 5.1 binary vs ASCII");
        same(&bin, &read("cyl.vtk"), "cyl 5.1 binary vs 4.2 ASCII");
        assert_eq!(bin.mesh.num_cells(), 617);
        assert_eq!(bin.element_sets["gmsh:physical=4"].len(), 617);
        // The hex box with an integer point array `fixed` (FIELD under POINT_DATA).
        let msh = read_msh(&data("msh", "box_hex_v41.msh")).unwrap();
        let b51 = read("box_hex_v51_bin.vtk");
        let b42 = read("box_hex_bin.vtk");
        assert_eq!(max_abs_diff(&b51, &b42), 0.0);
        assert_eq!(b51.mesh.cells, b42.mesh.cells);
        assert_eq!(b51.element_sets, b42.element_sets);
        assert_eq!(b51.face_sets, b42.face_sets);
        assert_eq!(b51.node_sets["fixed"], msh.set_nodes("fixed").unwrap());
        assert_eq!(b51.node_sets["fixed=1"].len(), 20);
    }

    #[test]
    fn zlib_compressed_vtu_from_meshio_reads() {
        // meshio's default VTU: zlib, UInt32 header, Int64 connectivity/offsets/types.
        let z = read("cyl_zlib.vtu");
        same(&z, &read("cyl.vtk"), "cyl zlib vs legacy");
        // header_type UInt64, with the point array.
        let b = read("box_hex_zlib_u64.vtu");
        same(
            &b,
            &read("box_hex_v51_bin.vtk"),
            "box zlib u64 vs legacy 5.1 binary",
        );
    }

    /// A one-tet VTU with its arrays appended, raw or base64, zlib-compressed in blocks of
    /// `block` bytes (several blocks and a partial last one for the points).
    fn compressed_appended(raw: bool, block: usize) -> Vec<u8> {
        use flate2::write::ZlibEncoder;
        use std::io::Write;
        let arrays: Vec<Vec<u8>> = vec![
            [0.0f64, 0., 0., 1., 0., 0., 0., 1., 0., 0., 0., 1.]
                .iter()
                .flat_map(|x| x.to_le_bytes())
                .collect(),
            [0i64, 1, 2, 3]
                .iter()
                .flat_map(|x| x.to_le_bytes())
                .collect(),
            4i64.to_le_bytes().to_vec(),
            10i64.to_le_bytes().to_vec(),
        ];
        let mut blobs = Vec::new();
        for a in &arrays {
            let chunks: Vec<&[u8]> = a.chunks(block).collect();
            let comp: Vec<Vec<u8>> = chunks
                .iter()
                .map(|c| {
                    let mut e = ZlibEncoder::new(Vec::new(), flate2::Compression::default());
                    e.write_all(c).unwrap();
                    e.finish().unwrap()
                })
                .collect();
            let last = a.len() % block;
            let mut head: Vec<u64> = vec![chunks.len() as u64, block as u64, last as u64];
            head.extend(comp.iter().map(|c| c.len() as u64));
            let hb: Vec<u8> = head
                .iter()
                .flat_map(|x| (*x as u32).to_le_bytes())
                .collect();
            let body: Vec<u8> = comp.concat();
            blobs.push(if raw {
                [hb, body].concat()
            } else {
                [base64(&hb), base64(&body)].concat().into_bytes()
            });
        }
        let mut offsets = Vec::new();
        let mut at = 0;
        for b in &blobs {
            offsets.push(at);
            at += b.len();
        }
        let mut f = format!(
            r#"<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian" compressor="vtkZLibDataCompressor">
<UnstructuredGrid>
<Piece NumberOfPoints="4" NumberOfCells="1">
<Points>
<DataArray type="Float64" NumberOfComponents="3" format="appended" offset="{}"/>
</Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="appended" offset="{}"/>
<DataArray type="Int64" Name="offsets" format="appended" offset="{}"/>
<DataArray type="Int64" Name="types" format="appended" offset="{}"></DataArray>
</Cells>
</Piece>
</UnstructuredGrid>
<AppendedData encoding="{}">
_"#,
            offsets[0],
            offsets[1],
            offsets[2],
            offsets[3],
            if raw { "raw" } else { "base64" }
        )
        .into_bytes();
        for b in &blobs {
            f.extend_from_slice(b);
        }
        f.extend_from_slice(b"\n</AppendedData>\n</VTKFile>\n");
        f
    }

    #[test]
    fn compressed_appended_data_reads() {
        for raw in [true, false] {
            for block in [7, 32, 1 << 15] {
                let f = compressed_appended(raw, block);
                let m = parse_vtk(&f, Path::new("app.vtu"))
                    .unwrap_or_else(|e| panic!("raw {raw} block {block}: {e}"));
                assert_eq!(m.mesh.cells, vec![0, 1, 2, 3]);
                assert_eq!(m.mesh.nodes[3], Vector3::new(0.0, 0.0, 1.0));
            }
        }
    }

    #[test]
    fn malformed_binary_and_compressed_files_give_clear_errors() {
        // Legacy 5.1 binary, truncated inside the points.
        let bin = std::fs::read(data("vtk", "cyl_v51_bin.vtk")).unwrap();
        let e = err(&bin[..2000], "t.vtk");
        assert!(
            e.contains(
                "t.vtk: byte 103: POINTS: the file ends inside the data (4704 bytes announced"
            ),
            "{e}"
        );
        // Truncated inside the cell data.
        let e = err(&bin[..bin.len() - 100], "t.vtk");
        assert!(
            e.contains("FIELD array 'gmsh:geometrical'") && e.contains("truncated"),
            "{e}"
        );
        // A wrong count: the reader lands in binary data where a keyword should be.
        let wrong = |from: &str, to: &str| -> Vec<u8> {
            let i = find(&bin, from.as_bytes()).unwrap();
            [&bin[..i], to.as_bytes(), &bin[i + from.len()..]].concat()
        };
        let e = err(&wrong("POINTS 196 double", "POINTS 195 double"), "c.vtk");
        assert!(
            e.contains("c.vtk: byte 4783:") && e.contains("wrong count"),
            "{e}"
        );
        // CELLS counts that disagree with OFFSETS.
        let e = err(&wrong("CELLS 948 3458", "CELLS 948 3457"), "c.vtk");
        assert!(e.contains("wrong count") || e.contains("OFFSETS"), "{e}");
        let e = err(&wrong("CELL_TYPES 947", "CELL_TYPES 946"), "c.vtk");
        assert!(
            e.contains("c.vtk: byte 43919: expected a keyword line, found binary data"),
            "{e}"
        );
        // An unsupported data type.
        let e = err(&wrong("POINTS 196 double", "POINTS 196 string"), "s.vtk");
        assert!(e.contains("unsupported data type 'string'"), "{e}");
        // An absurd count is refused without allocating.
        let e = err(
            &wrong("CELLS 948 3458", "CELLS 99999999999999 3458"),
            "big.vtk",
        );
        assert!(
            e.contains("OFFSETS") && e.contains("truncated file or wrong count"),
            "{e}"
        );
        // Not an unstructured grid.
        let e = err(&wrong("UNSTRUCTURED_GRID", "POLYDATA"), "p.vtk");
        assert!(e.contains("not an unstructured grid"), "{e}");

        // Compressed VTU: a corrupt zlib stream in the points.
        let z = std::fs::read(data("vtk", "cyl_zlib.vtu")).unwrap();
        let tag = find(&z, b"Name=\"Points\"").unwrap();
        let body = tag + z[tag..].iter().position(|&b| b == b'>').unwrap() + 1;
        let mut bad = z.clone();
        bad[body + 60..body + 68].copy_from_slice(b"AAAAAAAA");
        let e = err(&bad, "z.vtu");
        assert!(
            e.contains("z.vtu: byte ") && e.contains("DataArray 'Points': zlib block 1 of 1"),
            "{e}"
        );
        // Truncated compressed data.
        let e = err(&z[..body + 200], "z.vtu");
        assert!(
            e.contains("DataArray 'Points'") && e.contains("truncated"),
            "{e}"
        );
        // A header announcing more blocks than the data holds.
        let mut bad = z.clone();
        bad[body..body + 4].copy_from_slice(b"/w==");
        let e = err(&bad, "z.vtu");
        assert!(e.contains("DataArray 'Points'"), "{e}");
        // Not base64.
        let mut bad = z.clone();
        bad[body + 30] = b'%';
        let e = err(&bad, "z.vtu");
        assert!(e.contains("invalid base64"), "{e}");
        // Appended: an offset past the data; a truncated compressed block.
        let f = compressed_appended(true, 32);
        let s = String::from_utf8_lossy(&f).into_owned();
        let i = s.find("offset=\"").unwrap();
        let bad = format!("{}offset=\"99999{}", &s[..i], &s[i + 8..]);
        let e = err(bad.as_bytes(), "a.vtu");
        assert!(e.contains("past the end of the appended data"), "{e}");
        let e = err(&f[..f.len() - 40], "a.vtu");
        assert!(
            e.contains("DataArray 'types'") || e.contains("truncated"),
            "{e}"
        );
    }

    /// Two pieces of one tetrahedron each, a point mask and a float cell array.
    const TWO_PIECES: &str = r#"<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
<UnstructuredGrid>
<Piece NumberOfPoints="4" NumberOfCells="2">
<PointData>
<DataArray type="Int32" Name="fixed" format="ascii">1 1 0 0</DataArray>
<DataArray type="Float64" Name="temp" format="ascii">0.5 1 2 3</DataArray>
</PointData>
<CellData>
<DataArray type="Float64" Name="region" format="ascii">3 7</DataArray>
</CellData>
<Points>
<DataArray type="Float64" NumberOfComponents="3" format="ascii">0 0 0 1 0 0 0 1 0 0 0 1</DataArray>
</Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3 0 2 1</DataArray>
<DataArray type="Int64" Name="offsets" format="ascii">4 7</DataArray>
<DataArray type="UInt8" Name="types" format="ascii">10 5</DataArray>
</Cells>
</Piece>
<Piece NumberOfPoints="4" NumberOfCells="1">
<PointData>
<DataArray type="Int32" Name="fixed" format="ascii">0 0 1 0</DataArray>
<DataArray type="Float64" Name="temp" format="ascii">0 0 0 0</DataArray>
</PointData>
<CellData>
<DataArray type="Float64" Name="region" format="ascii">3</DataArray>
</CellData>
<Points>
<DataArray type="Float64" NumberOfComponents="3" format="ascii">2 0 0 3 0 0 2 1 0 2 0 1</DataArray>
</Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3</DataArray>
<DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>
<DataArray type="UInt8" Name="types" format="ascii">10</DataArray>
</Cells>
</Piece>
</UnstructuredGrid>
</VTKFile>
"#;

    /// Issue 22: errors of the XML parser carry the line and byte of the fault: a mismatched
    /// end tag, an element left open, a non-integer count, an unknown type name.
    #[test]
    fn xml_parser_errors_name_the_line() {
        let cases = [
            (
                "</Points>",
                "</Pointz>",
                "line 14 (byte ",
                "</Pointz> does not close <Points>, opened on line 12",
            ),
            (
                "NumberOfComponents=\"3\"",
                "NumberOfComponents=\"x\"",
                "line 13 (byte ",
                "NumberOfComponents=\"x\" is not",
            ),
            (
                "type=\"Float64\" Name=\"temp\"",
                "type=\"Float65\" Name=\"temp\"",
                "line 7 (byte ",
                "'Float65'",
            ),
        ];
        for (from, to, at, what) in cases {
            let bad = TWO_PIECES.replacen(from, to, 1);
            assert_ne!(bad, TWO_PIECES);
            let e = err(bad.as_bytes(), "x.vtu");
            assert!(
                e.starts_with("x.vtu: ") && e.contains(at) && e.contains(what),
                "{e}"
            );
        }
        let open = TWO_PIECES.replace("</VTKFile>\n", "");
        let e = err(open.as_bytes(), "x.vtu");
        assert!(
            e.contains("the file ends inside <VTKFile>, opened on line 2"),
            "{e}"
        );
    }

    #[test]
    fn pieces_concatenate_and_arrays_become_sets() {
        let m = parse_vtk(TWO_PIECES.as_bytes(), Path::new("two.vtu")).unwrap();
        assert_eq!(m.mesh.nodes.len(), 8);
        assert_eq!(m.mesh.cells, vec![0, 1, 2, 3, 4, 5, 6, 7]);
        assert_eq!(m.element_ids, vec![0, 2]);
        assert_eq!(m.node_ids, (0..8).collect::<Vec<u64>>());
        assert_eq!(m.node_sets["fixed=1"], vec![0, 1, 6]);
        assert_eq!(m.node_sets["fixed"], vec![0, 1, 6]);
        // A float array with a non-integer value is data.
        assert!(!m.node_sets.keys().any(|k| k.starts_with("temp")));
        assert_eq!(m.element_sets["region=3"], vec![0, 1]);
        assert_eq!(m.face_sets["region=7"], vec![vec![0, 2, 1]]);
        assert!(!m.element_sets.contains_key("region"));
        assert_eq!(m.face_sets[FACE_SET], vec![vec![0, 2, 1]]);
        assert_eq!(m.set_nodes("fixed").unwrap(), vec![0, 1, 6]);
    }

    #[test]
    fn malformed_files_give_clear_errors() {
        let vtu = std::fs::read_to_string(data("vtk", "cyl.vtu")).unwrap();
        let vtk = std::fs::read_to_string(data("vtk", "cyl.vtk")).unwrap();

        // Unsupported cell type, named with its index.
        let bad = TWO_PIECES.replace(">10 5</DataArray>", ">13 5</DataArray>");
        let e = err(bad.as_bytes(), "w.vtu");
        assert!(
            e.contains("unsupported VTK cell type 13 (VTK_WEDGE) at cell 0 (piece 1)"),
            "{e}"
        );
        // Mixed shapes.
        let bad = TWO_PIECES
            .replace(">0 1 2 3</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">4</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">10<",
                ">0 1 2 3 0 1 2 3</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">8</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">12<");
        assert_ne!(bad, TWO_PIECES);
        let e = err(bad.as_bytes(), "mixed.vtu");
        assert!(e.contains("mixed VTK_TETRA and VTK_HEXAHEDRON"), "{e}");
        // A cell referencing a missing point.
        let bad = TWO_PIECES.replace(">0 1 2 3 0 2 1<", ">0 1 2 9 0 2 1<");
        let e = err(bad.as_bytes(), "p.vtu");
        assert!(e.contains("cell 0 (piece 1) references point 9"), "{e}");
        // Legacy 5.1 (OFFSETS/CONNECTIVITY).
        let e = err(
            vtk.replacen("Version 4.2", "Version 5.1", 1).as_bytes(),
            "v5.vtk",
        );
        // ASCII 5.x is rewritten to 4.2; this one lacks its OFFSETS array.
        assert!(e.contains("OFFSETS") && e.contains("line 8"), "{e}");
        // Truncated legacy file.
        let e = err(&vtk.as_bytes()[..vtk.len() / 2], "t.vtk");
        assert!(e.contains("cannot parse the legacy VTK file"), "{e}");
        // An absurd count is refused before parsing.
        let e = err(
            vtk.replacen("POINTS 196 double", "POINTS 99999999999 double", 1)
                .as_bytes(),
            "big.vtk",
        );
        assert!(e.contains("line 5") && e.contains("99999999999"), "{e}");
        // Truncated XML.
        let e = err(&vtu.as_bytes()[..vtu.len() / 2], "t.vtu");
        assert!(e.contains("cannot read the XML VTK file"), "{e}");
        // Not an unstructured grid.
        let poly = "# vtk DataFile Version 2.0\ntri\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n\
                    0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 2\n";
        let e = err(poly.as_bytes(), "poly.vtk");
        assert!(
            e.contains("poly data") && e.contains("not an unstructured grid"),
            "{e}"
        );
        // No volume cells.
        let e = err(
            TWO_PIECES
                .replace(">10 5<", ">5 5<")
                .replace(">0 1 2 3 0 2 1<", ">0 1 2 0 2 1<")
                .replace(">4 7<", ">3 6<")
                .replace(">10</DataArray>", ">5</DataArray>")
                .replace(">0 1 2 3</DataArray>", ">0 1 2</DataArray>")
                .replace(
                    ">4</DataArray>\n<DataArray type=\"UInt8\"",
                    ">3</DataArray>\n<DataArray type=\"UInt8\"",
                )
                .as_bytes(),
            "faces.vtu",
        );
        assert!(e.contains("no volume cells"), "{e}");
        // Inline arrays without data (vtkio indexed their missing first block and panicked):
        // an empty body, a self-closing ASCII tag, an empty base64 body.
        let e = err(
            TWO_PIECES
                .replacen(">0 1 2 3 0 2 1</DataArray>", "> \n </DataArray>", 1)
                .as_bytes(),
            "c.vtu",
        );
        assert!(
            e.contains("c.vtu: line 16: the DataArray 'connectivity' holds no data"),
            "{e}"
        );
        let e = err(
            TWO_PIECES
                .replacen(
                    r#"format="ascii">0 0 0 1 0 0 0 1 0 0 0 1</DataArray>"#,
                    r#"format="ascii"/>"#,
                    1,
                )
                .as_bytes(),
            "p.vtu",
        );
        assert!(
            e.contains("p.vtu: line 13: the DataArray '(unnamed)' holds no data"),
            "{e}"
        );
        let e = err(
            TWO_PIECES
                .replace(
                    r#"Name="offsets" format="ascii">4 7<"#,
                    r#"Name="offsets" format="binary"><"#,
                )
                .as_bytes(),
            "o.vtu",
        );
        assert!(
            e.contains("line 17: the DataArray 'offsets' holds no data"),
            "{e}"
        );
        // Empty and foreign content.
        assert!(err(b"", "e.vtu").contains("empty"));
        assert!(err(b"", "e.vtk").contains("empty"));
        assert!(err(b"hello", "x.mesh").contains("neither"));
    }

    #[test]
    fn raw_appended_data_with_a_lt_byte_is_read() {
        // Raw appended Float64 data holding a '<' byte (0x3c), which vtkio alone cannot parse:
        // the reader moves the appended arrays inline as base64 first.
        let mut f: Vec<u8> = br#"<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">
<UnstructuredGrid>
<Piece NumberOfPoints="4" NumberOfCells="1">
<Points>
<DataArray type="Float64" NumberOfComponents="3" format="appended" offset="0"/>
</Points>
<Cells>
<DataArray type="Int64" Name="connectivity" format="appended" offset="104"/>
<DataArray type="Int64" Name="offsets" format="appended" offset="144"/>
<DataArray type="UInt8" Name="types" format="appended" offset="160"/>
</Cells>
</Piece>
</UnstructuredGrid>
<AppendedData encoding="raw">
_"#
        .to_vec();
        let push = |f: &mut Vec<u8>, bytes: &[u8]| {
            f.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
            f.extend_from_slice(bytes);
        };
        let pts: Vec<u8> = [
            0.0f64,
            0.,
            0.,
            1.,
            0.,
            0.,
            0.,
            1.,
            0.,
            0.,
            0.,
            f64::from_bits(0x3FF000000000003C),
        ]
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
        assert!(pts.contains(&b'<'));
        push(&mut f, &pts);
        push(
            &mut f,
            &[0i64, 1, 2, 3]
                .iter()
                .flat_map(|x| x.to_le_bytes())
                .collect::<Vec<u8>>(),
        );
        push(&mut f, &4i64.to_le_bytes());
        push(&mut f, &[10u8]);
        f.extend_from_slice(b"\n</AppendedData>\n</VTKFile>\n");
        let m = parse_vtk(&f, Path::new("raw.vtu")).unwrap();
        assert_eq!(m.mesh.num_cells(), 1);
        assert_eq!(m.mesh.nodes[3].z.to_bits(), 0x3FF000000000003C);
        // A truncated appended block is an error, not a panic.
        let cut = &f[..f.len() - 40];
        assert!(parse_vtk(cut, Path::new("raw.vtu")).is_err());
    }

    #[test]
    fn garbage_never_panics() {
        let files: Vec<(Vec<u8>, &str)> = [
            "cyl.vtu",
            "cyl.vtk",
            "box_hex_b64.vtu",
            "box_hex_bin.vtk",
            "box_hex_v51_bin.vtk",
            "box_hex_zlib_u64.vtu",
            "box_hex_meshio_b64.vtu",
        ]
        .iter()
        .map(|n| (std::fs::read(data("vtk", n)).unwrap(), *n))
        .collect();
        let iters: usize = std::env::var("HYTLED_FUZZ_ITERS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(30);
        let mut s: u64 = 0x2545f4914f6cdd1d;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        for (f, name) in &files {
            for _ in 0..iters {
                let mut b = f.clone();
                for _ in 0..(1 + next() % 4) {
                    let i = (next() as usize) % b.len();
                    match next() % 3 {
                        0 => b[i] = next() as u8,
                        1 => b.truncate(i.max(1)),
                        _ => b.insert(i, b"0123456789 \n<>\"=-.e"[(next() % 19) as usize]),
                    }
                }
                let _ = parse_vtk(&b, Path::new(name));
            }
        }
    }

    /// Issue 22: an ASCII legacy file's parse error names the line and the token, not vtkio's
    /// "Parse error: Alt".
    #[test]
    fn legacy_parse_errors_name_the_line() {
        let good = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0 1 0 0\n0 1 0 0 0 1\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n";
        assert!(locate_ascii_problem(good.as_bytes()).is_none());
        let e = locate_ascii_problem(good.replace("0 0 0 1\n", "0 0 x 1\n").as_bytes()).unwrap();
        assert!(e.contains("line 7: 'x' is not a number"), "{e}");
        let e = locate_ascii_problem(good.replace("CELL_TYPES", "CELL_TYPOS").as_bytes()).unwrap();
        assert!(e.contains("line 10: 'CELL_TYPOS'"), "{e}");
        let e = locate_ascii_problem(good.replace("4 0 1 2 3", "4 0 1.5 2 3").as_bytes()).unwrap();
        assert!(e.contains("not an integer") && e.contains("CELLS"), "{e}");
        let e = locate_ascii_problem(
            good.replace("CELL_TYPES 1\n10\n", "CELL_TYPES 2\n10\n")
                .as_bytes(),
        )
        .unwrap();
        assert!(e.contains("ends after 1 of the 2 values CELL_TYPES"), "{e}");
    }
}
