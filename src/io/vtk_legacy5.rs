//! Binary legacy VTK files of version 5.x (what VTK 9, ParaView and meshio write with
//! `binary=True`): cells as `OFFSETS` / `CONNECTIVITY` arrays of any integer type (usually
//! `vtktypeint64`), data big-endian. vtkio reads binary legacy files up to version 4.2 only,
//! so this module reads the unstructured grid itself into vtkio's model, which the VTK reader
//! then converts like any other file.
//!
//! Every section is read with its announced size checked against the bytes left before
//! anything is allocated; errors name the byte offset of the line or block at fault.

use std::path::Path;

use vtkio::model::{
    Attribute, Attributes, ByteOrder, CellType, Cells, DataArray, DataSet, ElementType, FieldArray,
    IOBuffer, Piece, UnstructuredGridPiece, Version, VertexNumbers,
};

use super::{clip, file_error as fail};
use crate::Result;

/// A scalar type of a legacy binary array.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ty {
    Bit,
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    U64,
    I64,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Option<Ty> {
        Some(match s.to_ascii_lowercase().as_str() {
            "bit" => Ty::Bit,
            "unsigned_char" | "vtktypeuint8" => Ty::U8,
            "char" | "signed_char" | "vtktypeint8" => Ty::I8,
            "unsigned_short" | "vtktypeuint16" => Ty::U16,
            "short" | "vtktypeint16" => Ty::I16,
            "unsigned_int" | "vtktypeuint32" => Ty::U32,
            "int" | "vtktypeint32" => Ty::I32,
            "unsigned_long" | "unsigned_long_long" | "unsigned___int64" | "vtktypeuint64" => {
                Ty::U64
            }
            "long" | "long_long" | "__int64" | "vtktypeint64" | "vtkidtype" => Ty::I64,
            "float" | "vtktypefloat32" => Ty::F32,
            "double" | "vtktypefloat64" => Ty::F64,
            _ => return None,
        })
    }

    /// Bytes of `n` values.
    fn bytes(self, n: usize) -> Option<usize> {
        match self {
            Ty::Bit => Some(n.div_ceil(8)),
            Ty::U8 | Ty::I8 => Some(n),
            Ty::U16 | Ty::I16 => n.checked_mul(2),
            Ty::U32 | Ty::I32 | Ty::F32 => n.checked_mul(4),
            Ty::U64 | Ty::I64 | Ty::F64 => n.checked_mul(8),
        }
    }
}

/// Big-endian values of type `ty` as an IOBuffer.
fn buffer(ty: Ty, b: &[u8]) -> IOBuffer {
    fn be<const N: usize, T>(b: &[u8], f: fn([u8; N]) -> T) -> Vec<T> {
        b.chunks_exact(N)
            .map(|c| {
                let mut a = [0u8; N];
                a.copy_from_slice(c);
                f(a)
            })
            .collect()
    }
    match ty {
        Ty::Bit => IOBuffer::Bit(b.to_vec()),
        Ty::U8 => IOBuffer::U8(b.to_vec()),
        Ty::I8 => IOBuffer::I8(b.iter().map(|&x| x as i8).collect()),
        Ty::U16 => IOBuffer::U16(be(b, u16::from_be_bytes)),
        Ty::I16 => IOBuffer::I16(be(b, i16::from_be_bytes)),
        Ty::U32 => IOBuffer::U32(be(b, u32::from_be_bytes)),
        Ty::I32 => IOBuffer::I32(be(b, i32::from_be_bytes)),
        Ty::U64 => IOBuffer::U64(be(b, u64::from_be_bytes)),
        Ty::I64 => IOBuffer::I64(be(b, i64::from_be_bytes)),
        Ty::F32 => IOBuffer::F32(be(b, f32::from_be_bytes)),
        Ty::F64 => IOBuffer::F64(be(b, f64::from_be_bytes)),
    }
}

/// Integer values of an array (indices, offsets): None for a float or bit array or a
/// negative value.
fn indices(ty: Ty, b: &[u8]) -> Option<Vec<u64>> {
    match buffer(ty, b) {
        IOBuffer::U8(v) => Some(v.into_iter().map(u64::from).collect()),
        IOBuffer::U16(v) => Some(v.into_iter().map(u64::from).collect()),
        IOBuffer::U32(v) => Some(v.into_iter().map(u64::from).collect()),
        IOBuffer::U64(v) => Some(v),
        IOBuffer::I8(v) => v.into_iter().map(|x| u64::try_from(x).ok()).collect(),
        IOBuffer::I16(v) => v.into_iter().map(|x| u64::try_from(x).ok()).collect(),
        IOBuffer::I32(v) => v.into_iter().map(|x| u64::try_from(x).ok()).collect(),
        IOBuffer::I64(v) => v.into_iter().map(|x| u64::try_from(x).ok()).collect(),
        _ => None,
    }
}

/// VTK cell type numbers vtkio knows.
fn cell_type(t: i32) -> Option<CellType> {
    use CellType::*;
    Some(match t {
        1 => Vertex,
        2 => PolyVertex,
        3 => Line,
        4 => PolyLine,
        5 => Triangle,
        6 => TriangleStrip,
        7 => Polygon,
        8 => Pixel,
        9 => Quad,
        10 => Tetra,
        11 => Voxel,
        12 => Hexahedron,
        13 => Wedge,
        14 => Pyramid,
        21 => QuadraticEdge,
        22 => QuadraticTriangle,
        23 => QuadraticQuad,
        24 => QuadraticTetra,
        25 => QuadraticHexahedron,
        26 => QuadraticWedge,
        27 => QuadraticPyramid,
        28 => BiquadraticQuad,
        29 => TriquadraticHexahedron,
        30 => QuadraticLinearQuad,
        31 => QuadraticLinearWedge,
        32 => BiquadraticQuadraticWedge,
        33 => BiquadraticQuadraticHexahedron,
        34 => BiquadraticTriangle,
        35 => CubicLine,
        41 => ConvexPointSet,
        42 => Polyhedron,
        _ => return None,
    })
}

/// A reading position in the file.
struct Cur<'a> {
    b: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Cur<'a> {
    fn err(&self, at: usize, m: impl std::fmt::Display) -> crate::Error {
        fail(self.path, format!("byte {at}: {m}"))
    }

    /// Skips blanks and line breaks (between a binary block and the next keyword).
    fn skip_blank(&mut self) {
        while self.b.get(self.pos).is_some_and(u8::is_ascii_whitespace) {
            self.pos += 1;
        }
    }

    /// The next text line (without its line break) and its byte offset; None at the end.
    fn raw_line(&mut self) -> Result<Option<(usize, &'a str)>> {
        if self.pos >= self.b.len() {
            return Ok(None);
        }
        let at = self.pos;
        let rest = &self.b[at..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos = at + end + 1;
        let line = &rest[..end];
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if line.len() > 4096 {
            return Err(self.err(at, "expected a keyword line, found a very long line"));
        }
        let control = line.iter().any(|&c| c < 0x20 && c != b'\t');
        match std::str::from_utf8(line) {
            Ok(s) if !control => Ok(Some((at, s))),
            _ => Err(self.err(
                at,
                "expected a keyword line, found binary data: a count before it does not match \
                 the data (wrong count or corrupt file)",
            )),
        }
    }

    /// The next keyword line after blanks, split into words.
    fn keyword_line(&mut self) -> Result<Option<(usize, &'a str, Vec<&'a str>)>> {
        self.skip_blank();
        Ok(self
            .raw_line()?
            .map(|(at, l)| (at, l, l.split_whitespace().collect())))
    }

    /// `n` values of `ty` right after the keyword line.
    fn take(&mut self, ty: Ty, n: usize, what: &str, at: usize) -> Result<&'a [u8]> {
        let len = ty
            .bytes(n)
            .ok_or_else(|| self.err(at, format!("{what}: count {n} too large")))?;
        let left = self.b.len().saturating_sub(self.pos);
        if len > left {
            return Err(self.err(
                self.pos,
                format!(
                    "{what}: the file ends inside the data ({len} bytes announced, {left} left): \
                     truncated file or wrong count"
                ),
            ));
        }
        let s = &self.b[self.pos..self.pos + len];
        self.pos += len;
        Ok(s)
    }
}

fn count(s: Option<&&str>, cur: &Cur, at: usize, line: &str) -> Result<usize> {
    s.and_then(|w| w.parse::<usize>().ok()).ok_or_else(|| {
        cur.err(
            at,
            format!(
                "'{}': expected a count (a non-negative integer)",
                clip(line)
            ),
        )
    })
}

fn data_type(s: Option<&&str>, cur: &Cur, at: usize, line: &str) -> Result<Ty> {
    let Some(w) = s else {
        return Err(cur.err(at, format!("'{}': the data type is missing", clip(line))));
    };
    Ty::parse(w).ok_or_else(|| {
        cur.err(
            at,
            format!(
                "'{}': unsupported data type '{}' (numeric types only)",
                clip(line),
                clip(w)
            ),
        )
    })
}

/// Reads a binary legacy VTK file of version 5.x holding an unstructured grid.
pub(crate) fn read(bytes: &[u8], path: &Path) -> Result<vtkio::Vtk> {
    let mut cur = Cur {
        b: bytes,
        pos: 0,
        path,
    };
    // Header: version line, title, BINARY, DATASET.
    let (_, first) = cur.raw_line()?.unwrap_or((0, ""));
    let version = first
        .rsplit(' ')
        .next()
        .and_then(|v| v.split_once('.'))
        .and_then(|(a, b)| Some((a.trim().parse().ok()?, b.trim().parse().ok()?)))
        .unwrap_or((5, 1));
    let title = cur.raw_line()?.map_or("", |l| l.1).trim().to_string();
    let fmt = cur.raw_line()?.map_or("", |l| l.1).trim();
    if !fmt.eq_ignore_ascii_case("BINARY") {
        return Err(fail(path, "line 3: expected BINARY"));
    }
    let mut points: Option<IOBuffer> = None;
    let mut cells: Option<CellArrays> = None;
    let mut types: Option<Vec<CellType>> = None;
    let mut attrs = Attributes::new();
    // Where attribute arrays go (0 dataset field, 1 point data, 2 cell data) and how many
    // tuples each has.
    let mut target = 0u8;
    let mut tuples = 0usize;
    let mut dataset_seen = false;

    while let Some((at, line, w)) = cur.keyword_line()? {
        let Some(head) = w.first() else { continue };
        let kw = head.to_ascii_uppercase();
        if !dataset_seen && kw != "DATASET" {
            return Err(cur.err(at, format!("expected DATASET, found '{}'", clip(line))));
        }
        match kw.as_str() {
            "DATASET" => {
                let kind = w.get(1).map(|s| s.to_ascii_uppercase()).unwrap_or_default();
                if kind != "UNSTRUCTURED_GRID" {
                    return Err(fail(
                        path,
                        format!(
                            "the file holds a {} data set, not an unstructured grid; hytled reads \
                             volume meshes from VTK unstructured grids (DATASET \
                             UNSTRUCTURED_GRID, or .vtu)",
                            clip(&kind)
                        ),
                    ));
                }
                dataset_seen = true;
            }
            "POINTS" => {
                let n = count(w.get(1), &cur, at, line)?;
                let ty = data_type(w.get(2), &cur, at, line)?;
                let n3 = n
                    .checked_mul(3)
                    .ok_or_else(|| cur.err(at, "POINTS: count too large"))?;
                let b = cur.take(ty, n3, "POINTS", at)?;
                if ty == Ty::Bit {
                    return Err(cur.err(at, "POINTS of type bit"));
                }
                points = Some(buffer(ty, b));
            }
            "METADATA" => {
                // INFORMATION / COMPONENT_NAMES lines up to a blank line.
                while let Some((_, l)) = cur.raw_line()? {
                    if l.trim().is_empty() {
                        break;
                    }
                }
            }
            "CELLS" => cells = Some(read_cells(&mut cur, &w, at, line)?),
            "CELL_TYPES" => types = Some(read_cell_types(&mut cur, &w, at, line)?),
            "POINT_DATA" | "CELL_DATA" => {
                tuples = count(w.get(1), &cur, at, line)?;
                target = if kw == "POINT_DATA" { 1 } else { 2 };
            }
            "FIELD" => {
                let field = read_field(&mut cur, &w, at, line)?;
                match target {
                    1 => attrs.point.push(field),
                    2 => attrs.cell.push(field),
                    _ => {}
                }
            }
            "SCALARS"
            | "VECTORS"
            | "NORMALS"
            | "TENSORS"
            | "TENSORS6"
            | "TEXTURE_COORDINATES"
            | "COLOR_SCALARS"
            | "LOOKUP_TABLE"
            | "GLOBAL_IDS"
            | "PEDIGREE_IDS" => {
                if target == 0 && kw != "LOOKUP_TABLE" {
                    return Err(cur.err(at, format!("{kw} before POINT_DATA or CELL_DATA")));
                }
                match read_attribute(&mut cur, &kw, &w, at, line, tuples)? {
                    Some(a) if target == 1 => attrs.point.push(a),
                    Some(a) => attrs.cell.push(a),
                    None => {}
                }
            }
            _ => {
                return Err(cur.err(
                    at,
                    format!(
                        "unknown keyword '{}' in a legacy VTK unstructured grid (or a count \
                         before it does not match the data)",
                        clip(head)
                    ),
                ))
            }
        }
    }
    if !dataset_seen {
        return Err(fail(
            path,
            "no DATASET line: not a complete legacy VTK file",
        ));
    }
    let points = points.ok_or_else(|| fail(path, "no POINTS section"))?;
    let CellArrays {
        connectivity,
        offsets,
    } = cells.ok_or_else(|| fail(path, "no CELLS section"))?;
    let types = types.ok_or_else(|| fail(path, "no CELL_TYPES section"))?;
    if types.len() != offsets.len() {
        return Err(fail(
            path,
            format!(
                "CELLS holds {} cells but CELL_TYPES {}",
                offsets.len(),
                types.len()
            ),
        ));
    }
    Ok(vtkio::Vtk {
        version: Version::new(version),
        title,
        byte_order: ByteOrder::BigEndian,
        data: DataSet::UnstructuredGrid {
            meta: None,
            pieces: vec![Piece::Inline(Box::new(UnstructuredGridPiece {
                points,
                cells: Cells {
                    cell_verts: VertexNumbers::XML {
                        connectivity,
                        offsets,
                    },
                    types,
                },
                data: attrs,
            }))],
        },
        file_path: None,
    })
}

/// A `CELLS` section's arrays: the connectivity and each cell's end in it.
struct CellArrays {
    connectivity: Vec<u64>,
    offsets: Vec<u64>,
}

/// The `OFFSETS` and `CONNECTIVITY` arrays after a `CELLS n_off n_conn` line (words `w`, at
/// byte `at`), checked: offsets from 0, never decreasing, ending at the connectivity's length.
fn read_cells(cur: &mut Cur, w: &[&str], at: usize, line: &str) -> Result<CellArrays> {
    let n_off = count(w.get(1), cur, at, line)?;
    let n_conn = count(w.get(2), cur, at, line)?;
    let mut arrays = Vec::with_capacity(2);
    for (name, n) in [("OFFSETS", n_off), ("CONNECTIVITY", n_conn)] {
        let Some((a, l, w)) = cur.keyword_line()? else {
            return Err(cur.err(cur.pos, format!("the file ends before {name}")));
        };
        if !w.first().is_some_and(|h| h.eq_ignore_ascii_case(name)) {
            return Err(cur.err(
                a,
                format!("expected '{name} <type>' after CELLS, found '{}'", clip(l)),
            ));
        }
        let ty = data_type(w.get(1), cur, a, l)?;
        let b = cur.take(ty, n, name, a)?;
        let v = indices(ty, b)
            .ok_or_else(|| cur.err(a, format!("{name} must hold non-negative integers")))?;
        arrays.push((a, v));
    }
    let (_, conn) = arrays.pop().unwrap_or_default();
    let (off_at, off) = arrays.pop().unwrap_or_default();
    // OFFSETS starts at 0, never decreases and ends at the connectivity's length.
    if n_off > 0 {
        if off.first() != Some(&0) {
            return Err(cur.err(off_at, "OFFSETS must start at 0"));
        }
        for (i, p) in off.windows(2).enumerate() {
            if p[1] < p[0] {
                return Err(cur.err(
                    off_at,
                    format!(
                        "OFFSETS decrease at entry {} ({} then {})",
                        i + 1,
                        p[0],
                        p[1]
                    ),
                ));
            }
        }
        let last = off.last().copied().unwrap_or(0);
        if last != n_conn as u64 {
            return Err(cur.err(
                off_at,
                format!(
                    "the last OFFSETS entry is {last}, but CONNECTIVITY has {n_conn} \
                     entries"
                ),
            ));
        }
    } else if n_conn > 0 {
        return Err(cur.err(at, "CELLS: CONNECTIVITY without OFFSETS"));
    }
    Ok(CellArrays {
        connectivity: conn,
        offsets: off.get(1..).unwrap_or(&[]).to_vec(),
    })
}

/// The cell types after a `CELL_TYPES n` line: big-endian i32, hytled's volume and face cells.
fn read_cell_types(cur: &mut Cur, w: &[&str], at: usize, line: &str) -> Result<Vec<CellType>> {
    let path = cur.path;
    let n = count(w.get(1), cur, at, line)?;
    let b = cur.take(Ty::I32, n, "CELL_TYPES", at)?;
    let mut v = Vec::with_capacity(n);
    for (i, c) in b.chunks_exact(4).enumerate() {
        let t = i32::from_be_bytes([c[0], c[1], c[2], c[3]]);
        v.push(cell_type(t).ok_or_else(|| {
            fail(
                path,
                format!(
                    "unsupported VTK cell type {t} at cell {i}; hytled reads VTK_TETRA \
                     (10) or VTK_HEXAHEDRON (12) volume cells, with VTK_TRIANGLE (5) \
                     or VTK_QUAD (9) boundary faces"
                ),
            )
        })?);
    }
    Ok(v)
}

/// The arrays after a `FIELD name k` line, as one field attribute.
fn read_field(cur: &mut Cur, w: &[&str], at: usize, line: &str) -> Result<Attribute> {
    let k = count(w.get(2), cur, at, line)?;
    let mut data_array = Vec::new();
    let mut got = 0;
    while got < k {
        let Some((a, l, w)) = cur.keyword_line()? else {
            return Err(cur.err(
                cur.pos,
                format!("the file ends after {got} of the {k} FIELD arrays"),
            ));
        };
        got += 1;
        if w.first()
            .is_some_and(|h| h.eq_ignore_ascii_case("NULL_ARRAY"))
        {
            continue;
        }
        if w.len() != 4 {
            return Err(cur.err(
                a,
                format!(
                    "FIELD array line '{}': expected 'name components tuples type'",
                    clip(l)
                ),
            ));
        }
        let comps = count(w.get(1), cur, a, l)?;
        let nt = count(w.get(2), cur, a, l)?;
        let ty = data_type(w.get(3), cur, a, l)?;
        let n = comps
            .checked_mul(nt)
            .ok_or_else(|| cur.err(a, "FIELD array: count too large"))?;
        let b = cur.take(ty, n, &format!("FIELD array '{}'", clip(w[0])), a)?;
        data_array.push(FieldArray {
            name: w[0].to_string(),
            elem: u32::try_from(comps).unwrap_or(u32::MAX),
            data: buffer(ty, b),
        });
    }
    let field = Attribute::Field {
        name: w.get(1).unwrap_or(&"FieldData").to_string(),
        data_array,
    };
    Ok(field)
}

/// A point or cell attribute (`SCALARS`, `VECTORS`, ...) of `tuples` tuples after its line;
/// None for what carries no data hytled keeps (lookup tables, ids).
fn read_attribute(
    cur: &mut Cur,
    kw: &str,
    w: &[&str],
    at: usize,
    line: &str,
    tuples: usize,
) -> Result<Option<Attribute>> {
    let name = w.get(1).unwrap_or(&"").to_string();
    let (ty, comps, elem) = match kw {
        "SCALARS" => {
            let c = match w.get(3) {
                Some(_) => count(w.get(3), cur, at, line)?,
                None => 1,
            };
            if !(1..=4).contains(&c) {
                return Err(cur.err(at, "SCALARS: 1 to 4 components"));
            }
            let ty = data_type(w.get(2), cur, at, line)?;
            // An optional LOOKUP_TABLE line follows.
            let save = cur.pos;
            let mut table = None;
            match cur.keyword_line()? {
                Some((_, _, lw))
                    if lw
                        .first()
                        .is_some_and(|h| h.eq_ignore_ascii_case("LOOKUP_TABLE")) =>
                {
                    table = lw.get(1).map(|s| s.to_string());
                }
                _ => cur.pos = save,
            }
            (
                ty,
                c,
                ElementType::Scalars {
                    num_comp: c as u32,
                    lookup_table: table,
                },
            )
        }
        "VECTORS" | "NORMALS" => (
            data_type(w.get(2), cur, at, line)?,
            3,
            if kw == "VECTORS" {
                ElementType::Vectors
            } else {
                ElementType::Normals
            },
        ),
        "TENSORS" => (data_type(w.get(2), cur, at, line)?, 9, ElementType::Tensors),
        "TENSORS6" => (
            data_type(w.get(2), cur, at, line)?,
            6,
            ElementType::Generic(6),
        ),
        "TEXTURE_COORDINATES" => {
            let d = count(w.get(2), cur, at, line)?;
            if !(1..=3).contains(&d) {
                return Err(cur.err(at, "TEXTURE_COORDINATES: 1 to 3 dimensions"));
            }
            (
                data_type(w.get(3), cur, at, line)?,
                d,
                ElementType::TCoords(d as u32),
            )
        }
        "COLOR_SCALARS" => {
            let c = count(w.get(2), cur, at, line)?;
            (
                Ty::U8,
                c,
                ElementType::ColorScalars(c.min(u32::MAX as usize) as u32),
            )
        }
        "LOOKUP_TABLE" => {
            // A table of `size` RGBA colours (unsigned char in binary files).
            let size = count(w.get(2), cur, at, line)?;
            let n = size
                .checked_mul(4)
                .ok_or_else(|| cur.err(at, "LOOKUP_TABLE: count too large"))?;
            cur.take(Ty::U8, n, "LOOKUP_TABLE", at)?;
            return Ok(None);
        }
        // GLOBAL_IDS / PEDIGREE_IDS name type: one value per tuple.
        _ => (
            data_type(w.get(2), cur, at, line)?,
            1,
            ElementType::Generic(1),
        ),
    };
    let n = tuples
        .checked_mul(comps)
        .ok_or_else(|| cur.err(at, format!("{kw}: count too large")))?;
    let b = cur.take(ty, n, &format!("{kw} {}", clip(&name)), at)?;
    if matches!(kw, "GLOBAL_IDS" | "PEDIGREE_IDS") {
        return Ok(None);
    }
    Ok(Some(Attribute::DataArray(DataArray {
        name,
        elem,
        data: buffer(ty, b),
    })))
}
