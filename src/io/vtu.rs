//! A small, dependency-free writer for VTK XML UnstructuredGrid (`.vtu`) files and ParaView
//! collections (`.pvd`).
//!
//! Files follow the VTK XML format version 1.0 with `header_type="UInt64"` and little-endian
//! binary data. Points and data arrays are `Float64`, connectivity and offsets `Int64`, cell
//! types `UInt8`. Three encodings are available (see [`VtuFormat`]); raw appended binary is the
//! smallest and fastest; the default, inline base64, is the one every reader accepts.
//!
//! Every file is written to a hidden temporary file in the target directory and renamed into
//! place once complete, so an interrupted run never leaves a truncated `.vtu` or `.pvd` behind.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use crate::{Error, InputKind, Result};

/// A named data array attached to points or cells.
///
/// `values` is flat: tuple `i` is `values[i * components..(i + 1) * components]`.
#[derive(Clone, Copy, Debug)]
pub struct DataArray<'a> {
    /// Name shown in ParaView. Must be unique among the arrays of the same association.
    pub name: &'a str,
    /// Components per tuple (1 for scalars, 3 for vectors, 9 for tensors, ...).
    pub components: usize,
    /// `count * components` values, tuple after tuple.
    pub values: &'a [f64],
}

/// One unstructured-grid piece: points, cells and their data.
///
/// A piece with no cells (empty `connectivity`, `offsets` and `types`) is a valid point cloud,
/// but ParaView draws nothing for points that no cell refers to; add one `VTK_VERTEX` (type 1)
/// cell per point to see them.
#[derive(Clone, Debug)]
pub struct Piece<'a> {
    /// Point coordinates, m.
    pub points: &'a [Vector3<f64>],
    /// The point indices of all cells, one cell after another.
    pub connectivity: &'a [usize],
    /// End offset of each cell in `connectivity` (VTK style: the first cell is
    /// `connectivity[0..offsets[0]]`).
    pub offsets: &'a [usize],
    /// VTK cell type of each cell (10 = tetra, 12 = hexahedron, 24 = quadratic tetra, ...).
    pub types: &'a [u8],
    /// Arrays with one tuple per point.
    pub point_data: Vec<DataArray<'a>>,
    /// Arrays with one tuple per cell.
    pub cell_data: Vec<DataArray<'a>>,
}

/// How array data is encoded in a `.vtu` file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VtuFormat {
    /// Human-readable text; numbers are written with the fewest digits that read back exactly.
    Ascii,
    /// Inline base64 inside each `DataArray` (header and data encoded together). The default:
    /// ParaView, VTK and XML-strict readers (vtkio, hytled's own mesh reader) all read it.
    #[default]
    Binary,
    /// Raw little-endian binary in one `AppendedData` block at the end of the file: a quarter
    /// smaller and faster, read by ParaView/VTK but not by strict XML parsers such as vtkio.
    Appended,
}

/// Writes `piece` to `path` as a VTK XML UnstructuredGrid file in the given format.
///
/// Returns [`Error::Input`] when array lengths, offsets, cell types or point indices are
/// inconsistent, naming the offending array, and [`Error::Io`] when the file cannot be written.
pub fn write_vtu(path: &Path, piece: &Piece, format: VtuFormat) -> Result<()> {
    validate(path, piece)?;
    let mut arrays: Vec<ArrayOut> =
        Vec::with_capacity(piece.point_data.len() + piece.cell_data.len() + 4);
    for a in &piece.point_data {
        arrays.push(ArrayOut::new(
            Some(a.name),
            a.components,
            Src::F64(a.values),
        ));
    }
    for a in &piece.cell_data {
        arrays.push(ArrayOut::new(
            Some(a.name),
            a.components,
            Src::F64(a.values),
        ));
    }
    arrays.push(ArrayOut::new(Some("Points"), 3, Src::Points(piece.points)));
    arrays.push(ArrayOut::new(
        Some("connectivity"),
        1,
        Src::Index(piece.connectivity),
    ));
    arrays.push(ArrayOut::new(Some("offsets"), 1, Src::Index(piece.offsets)));
    arrays.push(ArrayOut::new(Some("types"), 1, Src::U8(piece.types)));
    let (n_point_data, n_cell_data) = (piece.point_data.len(), piece.cell_data.len());

    write_atomically(path, |w| {
        w.write_all(
            b"<?xml version=\"1.0\"?>\n\
              <VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  \
              <UnstructuredGrid>\n",
        )?;
        writeln!(
            w,
            "    <Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
            piece.points.len(),
            piece.types.len()
        )?;
        let mut offset = 0u64;
        let mut emit = |w: &mut BufWriter<File>, a: &ArrayOut, indent: &str| {
            write_array(w, a, format, &mut offset, indent)
        };
        let (point_arrays, rest) = arrays.split_at(n_point_data);
        let (cell_arrays, geometry) = rest.split_at(n_cell_data);
        if !point_arrays.is_empty() {
            w.write_all(b"      <PointData>\n")?;
            for a in point_arrays {
                emit(w, a, "        ")?;
            }
            w.write_all(b"      </PointData>\n")?;
        }
        if !cell_arrays.is_empty() {
            w.write_all(b"      <CellData>\n")?;
            for a in cell_arrays {
                emit(w, a, "        ")?;
            }
            w.write_all(b"      </CellData>\n")?;
        }
        w.write_all(b"      <Points>\n")?;
        emit(w, &geometry[0], "        ")?;
        w.write_all(b"      </Points>\n      <Cells>\n")?;
        for a in &geometry[1..] {
            emit(w, a, "        ")?;
        }
        w.write_all(b"      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n")?;
        if format == VtuFormat::Appended {
            // Offsets in the headers count from the byte after '_'; each array is stored as
            // [u64 byte count][bytes], in the same order as the headers above.
            w.write_all(b"  <AppendedData encoding=\"raw\">\n   _")?;
            for a in &arrays {
                w.write_all(&(a.src.byte_len() as u64).to_le_bytes())?;
                a.src.write_le(w)?;
            }
            w.write_all(b"\n  </AppendedData>\n")?;
        }
        w.write_all(b"</VTKFile>\n")
    })
}

/// Writes a ParaView collection (`.pvd`) listing one file per time step.
///
/// `frames` holds `(time in s, file name)` pairs; file names are usually relative to the
/// directory of the `.pvd` file.
pub fn write_pvd(path: &Path, frames: &[(f64, String)]) -> Result<()> {
    if let Some((t, f)) = frames.iter().find(|(t, _)| !t.is_finite()) {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "{}: time {t} of frame \"{f}\" is not finite; give every frame a finite time in s",
                path.display()
            ),
        ));
    }
    write_atomically(path, |w| {
        w.write_all(
            b"<?xml version=\"1.0\"?>\n\
              <VTKFile type=\"Collection\" version=\"1.0\" byte_order=\"LittleEndian\">\n  \
              <Collection>\n",
        )?;
        for (t, file) in frames {
            w.write_all(b"    <DataSet timestep=\"")?;
            write_f64(w, *t)?;
            writeln!(w, "\" group=\"\" part=\"0\" file=\"{}\"/>", XmlEscape(file))?;
        }
        w.write_all(b"  </Collection>\n</VTKFile>\n")
    })
}

/// Writes a file through a buffered hidden temporary file next to `path`, renamed onto `path`
/// only once everything was written and flushed. The temporary file is removed on failure.
pub(crate) fn write_atomically<F>(path: &Path, body: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> io::Result<()>,
{
    let name = path.file_name().ok_or_else(|| {
        Error::input(
            InputKind::Value,
            format!("{}: output path has no file name", path.display()),
        )
    })?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".{}.tmp", std::process::id()));
    let tmp: PathBuf = path.with_file_name(tmp_name);

    let result = (|| {
        let file = File::create(&tmp)?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        body(&mut w)?;
        w.into_inner().map_err(|e| e.into_error())?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    Ok(())
}

/// Writes `x` in text with the fewest digits that parse back to exactly `x`: plain decimal for
/// moderate magnitudes, scientific notation (`1.5e-7`) otherwise. Non-finite values are written
/// as `NaN`, `inf` and `-inf`.
pub(crate) fn write_f64<W: Write + ?Sized>(w: &mut W, x: f64) -> io::Result<()> {
    let a = x.abs();
    if a == 0.0 || !a.is_finite() || (1e-4..1e15).contains(&a) {
        write!(w, "{x}")
    } else {
        write!(w, "{x:e}")
    }
}

/// Fixed number of points of the VTK cell types with a fixed size; `None` for variable-size
/// types (poly-vertex, polyline, polygon, ...), which are accepted with any count.
fn points_per_cell(t: u8) -> Option<usize> {
    Some(match t {
        1 => 1,       // vertex
        3 => 2,       // line
        5 => 3,       // triangle
        8 | 9 => 4,   // pixel, quad
        10 => 4,      // tetra
        11 | 12 => 8, // voxel, hexahedron
        13 => 6,      // wedge
        14 => 5,      // pyramid
        21 => 3,      // quadratic edge
        22 => 6,      // quadratic triangle
        23 => 8,      // quadratic quad
        24 => 10,     // quadratic tetra
        25 => 20,     // quadratic hexahedron
        26 => 15,     // quadratic wedge
        27 => 13,     // quadratic pyramid
        _ => return None,
    })
}

fn validate(path: &Path, piece: &Piece) -> Result<()> {
    let p = path.display();
    let err = |m: String| Err(Error::input(InputKind::Format, format!("{p}: {m}")));
    let n_cells = piece.types.len();
    if piece.offsets.len() != n_cells {
        return err(format!(
            "array \"offsets\" has {} entries but \"types\" has {n_cells}; give one end offset and one type per cell",
            piece.offsets.len()
        ));
    }
    let mut start = 0usize;
    for (c, (&end, &t)) in piece.offsets.iter().zip(piece.types).enumerate() {
        if end < start || end > piece.connectivity.len() {
            return err(format!(
                "array \"offsets\" entry {c} is {end}, outside {start}..={} (offsets are cell end positions in \"connectivity\", non-decreasing)",
                piece.connectivity.len()
            ));
        }
        if t == 42 {
            return err(format!(
                "cell {c} has type 42 (polyhedron), which needs face arrays this writer does not write"
            ));
        }
        if let Some(n) = points_per_cell(t) {
            if end - start != n {
                return err(format!(
                    "cell {c} of VTK type {t} has {} points in \"connectivity\", expected {n}",
                    end - start
                ));
            }
        }
        start = end;
    }
    if start != piece.connectivity.len() {
        return err(format!(
            "array \"connectivity\" has {} entries but the last offset is {start}; the last entry of \"offsets\" must equal the length of \"connectivity\"",
            piece.connectivity.len()
        ));
    }
    if let Some((i, &v)) = piece
        .connectivity
        .iter()
        .enumerate()
        .find(|(_, &v)| v >= piece.points.len())
    {
        return err(format!(
            "array \"connectivity\" entry {i} is point {v}, but there are only {} points",
            piece.points.len()
        ));
    }
    for (kind, arrays, count) in [
        ("point", &piece.point_data, piece.points.len()),
        ("cell", &piece.cell_data, n_cells),
    ] {
        for (i, a) in arrays.iter().enumerate() {
            if a.name.is_empty() {
                return err(format!("{kind} data array {i} has an empty name"));
            }
            if arrays[..i].iter().any(|b| b.name == a.name) {
                return err(format!(
                    "{kind} data array \"{}\" appears twice; give arrays distinct names",
                    a.name
                ));
            }
            if a.components == 0 {
                return err(format!(
                    "{kind} data array \"{}\" has 0 components; give at least 1",
                    a.name
                ));
            }
            if a.values.len() != count * a.components {
                return err(format!(
                    "{kind} data array \"{}\" has {} values, expected {count} {kind}s x {} components = {}",
                    a.name,
                    a.values.len(),
                    a.components,
                    count * a.components
                ));
            }
        }
    }
    Ok(())
}

/// Where the values of one output array come from.
enum Src<'a> {
    /// Float64 values.
    F64(&'a [f64]),
    /// Float64 values, three per point.
    Points(&'a [Vector3<f64>]),
    /// Int64 values (connectivity, offsets). Validation keeps them far below `i64::MAX`.
    Index(&'a [usize]),
    /// UInt8 values (cell types).
    U8(&'a [u8]),
}

impl Src<'_> {
    fn vtk_type(&self) -> &'static str {
        match self {
            Src::F64(_) | Src::Points(_) => "Float64",
            Src::Index(_) => "Int64",
            Src::U8(_) => "UInt8",
        }
    }

    fn byte_len(&self) -> usize {
        match self {
            Src::F64(v) => 8 * v.len(),
            Src::Points(v) => 24 * v.len(),
            Src::Index(v) => 8 * v.len(),
            Src::U8(v) => v.len(),
        }
    }

    /// Writes the values as little-endian bytes, through a stack buffer so that the writer sees
    /// few large writes.
    fn write_le<W: Write + ?Sized>(&self, w: &mut W) -> io::Result<()> {
        fn chunked<W: Write + ?Sized, const N: usize>(
            w: &mut W,
            items: impl Iterator<Item = [u8; N]>,
        ) -> io::Result<()> {
            let mut buf = [0u8; 8192];
            let mut n = 0;
            for b in items {
                if n + N > buf.len() {
                    w.write_all(&buf[..n])?;
                    n = 0;
                }
                buf[n..n + N].copy_from_slice(&b);
                n += N;
            }
            w.write_all(&buf[..n])
        }
        match self {
            Src::F64(v) => chunked(w, v.iter().map(|x| x.to_le_bytes())),
            Src::Points(v) => chunked(
                w,
                v.iter().flat_map(|p| [p.x, p.y, p.z]).map(f64::to_le_bytes),
            ),
            Src::Index(v) => chunked(w, v.iter().map(|&i| (i as i64).to_le_bytes())),
            Src::U8(v) => w.write_all(v),
        }
    }

    /// Writes the values as text, one tuple of `components` values per line.
    fn write_ascii<W: Write + ?Sized>(
        &self,
        w: &mut W,
        components: usize,
        indent: &str,
    ) -> io::Result<()> {
        fn lines<W: Write + ?Sized, T: Copy>(
            w: &mut W,
            v: &[T],
            components: usize,
            indent: &str,
            mut put: impl FnMut(&mut W, T) -> io::Result<()>,
        ) -> io::Result<()> {
            for tuple in v.chunks(components) {
                w.write_all(indent.as_bytes())?;
                for (k, &x) in tuple.iter().enumerate() {
                    if k > 0 {
                        w.write_all(b" ")?;
                    }
                    put(w, x)?;
                }
                w.write_all(b"\n")?;
            }
            Ok(())
        }
        match self {
            Src::F64(v) => lines(w, v, components, indent, |w, x| write_f64(w, x)),
            Src::Points(v) => {
                for p in v.iter() {
                    w.write_all(indent.as_bytes())?;
                    write_f64(w, p.x)?;
                    w.write_all(b" ")?;
                    write_f64(w, p.y)?;
                    w.write_all(b" ")?;
                    write_f64(w, p.z)?;
                    w.write_all(b"\n")?;
                }
                Ok(())
            }
            // Cells on one line each would need the offsets; a fixed width reads just as well.
            Src::Index(v) => lines(w, v, 16, indent, |w, x| write!(w, "{x}")),
            Src::U8(v) => lines(w, v, 32, indent, |w, x| write!(w, "{x}")),
        }
    }
}

struct ArrayOut<'a> {
    name: Option<&'a str>,
    components: usize,
    src: Src<'a>,
}

impl<'a> ArrayOut<'a> {
    fn new(name: Option<&'a str>, components: usize, src: Src<'a>) -> Self {
        ArrayOut {
            name,
            components,
            src,
        }
    }
}

/// Writes one `<DataArray>` element; in appended format only the header, advancing `offset` by
/// the size the array will take in the appended block.
fn write_array<W: Write>(
    w: &mut W,
    a: &ArrayOut,
    format: VtuFormat,
    offset: &mut u64,
    indent: &str,
) -> io::Result<()> {
    write!(w, "{indent}<DataArray type=\"{}\"", a.src.vtk_type())?;
    if let Some(name) = a.name {
        write!(w, " Name=\"{}\"", XmlEscape(name))?;
    }
    if a.components != 1 {
        write!(w, " NumberOfComponents=\"{}\"", a.components)?;
    }
    match format {
        VtuFormat::Ascii => {
            w.write_all(b" format=\"ascii\">\n")?;
            a.src.write_ascii(w, a.components, &format!("{indent}  "))?;
            writeln!(w, "{indent}</DataArray>")
        }
        VtuFormat::Binary => {
            // Uncompressed inline binary: the UInt64 byte count and the data are base64
            // encoded together as one stream.
            write!(w, " format=\"binary\">\n{indent}  ")?;
            let mut b64 = Base64Writer::new(&mut *w);
            b64.write_all(&(a.src.byte_len() as u64).to_le_bytes())?;
            a.src.write_le(&mut b64)?;
            b64.finish()?;
            write!(w, "\n{indent}</DataArray>\n")
        }
        VtuFormat::Appended => {
            writeln!(w, " format=\"appended\" offset=\"{offset}\"/>")?;
            *offset += 8 + a.src.byte_len() as u64;
            Ok(())
        }
    }
}

/// Streaming standard base64 (RFC 4648, with padding) encoder.
struct Base64Writer<W: Write> {
    inner: W,
    pending: [u8; 3],
    n_pending: usize,
    out: Vec<u8>,
}

const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

impl<W: Write> Base64Writer<W> {
    fn new(inner: W) -> Self {
        Base64Writer {
            inner,
            pending: [0; 3],
            n_pending: 0,
            out: Vec::with_capacity(8192 + 4),
        }
    }

    fn encode_group(out: &mut Vec<u8>, b: [u8; 3], n: usize) {
        let v = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        out.push(B64[(v >> 18) as usize & 63]);
        out.push(B64[(v >> 12) as usize & 63]);
        out.push(if n > 1 {
            B64[(v >> 6) as usize & 63]
        } else {
            b'='
        });
        out.push(if n > 2 { B64[v as usize & 63] } else { b'=' });
    }

    /// Encodes the last partial group with padding and flushes everything to the inner writer.
    fn finish(mut self) -> io::Result<()> {
        if self.n_pending > 0 {
            let mut b = [0u8; 3];
            b[..self.n_pending].copy_from_slice(&self.pending[..self.n_pending]);
            Self::encode_group(&mut self.out, b, self.n_pending);
        }
        self.inner.write_all(&self.out)
    }
}

impl<W: Write> Write for Base64Writer<W> {
    fn write(&mut self, mut data: &[u8]) -> io::Result<usize> {
        let len = data.len();
        while self.n_pending > 0 && self.n_pending < 3 && !data.is_empty() {
            self.pending[self.n_pending] = data[0];
            self.n_pending += 1;
            data = &data[1..];
        }
        if self.n_pending > 0 {
            if self.n_pending < 3 {
                return Ok(len); // `data` ran out before the group was complete
            }
            Self::encode_group(&mut self.out, self.pending, 3);
            self.n_pending = 0;
        }
        let mut groups = data.chunks_exact(3);
        for g in &mut groups {
            Self::encode_group(&mut self.out, [g[0], g[1], g[2]], 3);
            if self.out.len() >= 8192 {
                self.inner.write_all(&self.out)?;
                self.out.clear();
            }
        }
        let rest = groups.remainder();
        self.pending[..rest.len()].copy_from_slice(rest);
        self.n_pending = rest.len();
        Ok(len)
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Displays a string with the XML special characters escaped, for attribute values.
struct XmlEscape<'a>(&'a str);

impl std::fmt::Display for XmlEscape<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut last = 0;
        for (i, c) in self.0.char_indices() {
            let rep = match c {
                '&' => "&amp;",
                '<' => "&lt;",
                '>' => "&gt;",
                '"' => "&quot;",
                '\'' => "&apos;",
                _ => continue,
            };
            f.write_str(&self.0[last..i])?;
            f.write_str(rep)?;
            last = i + 1;
        }
        f.write_str(&self.0[last..])
    }
}

/// Writes a single-shape mesh with optional point and cell arrays (one VTU piece).
pub fn write_mesh(
    path: &Path,
    mesh: &crate::geometry::Mesh,
    point_data: Vec<DataArray>,
    cell_data: Vec<DataArray>,
    format: VtuFormat,
) -> Result<()> {
    let npc = mesh.shape.nodes_per_cell();
    let offsets: Vec<usize> = (1..=mesh.num_cells()).map(|e| e * npc).collect();
    let types = vec![mesh.shape.vtk_type(); mesh.num_cells()];
    let piece = Piece {
        points: &mesh.nodes,
        connectivity: &mesh.cells,
        offsets: &offsets,
        types: &types,
        point_data,
        cell_data,
    };
    write_vtu(path, &piece, format)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vtkio::model::{Attribute, CellType, DataSet, IOBuffer, VertexNumbers};

    fn temp_dir(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("hytled-vtu-{test}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// One hexahedron (points 0..8) and one tetrahedron (points 8..12), sharing nothing.
    struct Mesh {
        points: Vec<Vector3<f64>>,
        connectivity: Vec<usize>,
        offsets: Vec<usize>,
        types: Vec<u8>,
        displacement: Vec<f64>,
        stress: Vec<f64>,
    }

    fn mesh() -> Mesh {
        let mut points: Vec<Vector3<f64>> = (0..12)
            .map(|i| {
                let t = i as f64;
                Vector3::new(
                    (t * 0.37).sin() / 3.0,
                    (t * 1.1).cos() * 1e-3,
                    t / 7.0 + 0.1,
                )
            })
            .collect();
        points[3] = Vector3::new(-0.0, 5e-324, 1e300);
        let displacement: Vec<f64> = (0..36)
            .map(|i| (i as f64).sqrt() * 1e-5 / 3.0 - 1e-5)
            .collect();
        let mut stress: Vec<f64> = (0..18)
            .map(|i| (i as f64 * 0.731).tan() * 1e6 / 7.0)
            .collect();
        stress[4] = f64::MAX;
        stress[5] = -f64::MIN_POSITIVE;
        Mesh {
            points,
            connectivity: vec![0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11],
            offsets: vec![8, 12],
            types: vec![12, 10],
            displacement,
            stress,
        }
    }

    fn piece(m: &Mesh) -> Piece<'_> {
        Piece {
            points: &m.points,
            connectivity: &m.connectivity,
            offsets: &m.offsets,
            types: &m.types,
            point_data: vec![DataArray {
                name: "displacement",
                components: 3,
                values: &m.displacement,
            }],
            cell_data: vec![DataArray {
                name: "stress",
                components: 9,
                values: &m.stress,
            }],
        }
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    fn f64s(buf: IOBuffer) -> Vec<f64> {
        match buf {
            IOBuffer::F64(v) => v,
            other => panic!("expected Float64 data, got {other:?}"),
        }
    }

    /// Reads `path` with vtkio and checks every array against `m` bit for bit.
    fn check_with_vtkio(path: &Path, m: &Mesh) {
        let vtk = vtkio::Vtk::import(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
            panic!("not an unstructured grid")
        };
        assert_eq!(pieces.len(), 1);
        let p = pieces
            .into_iter()
            .next()
            .unwrap()
            .into_loaded_piece_data(None)
            .unwrap();
        let flat: Vec<f64> = m.points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        assert_eq!(bits(&f64s(p.points)), bits(&flat));
        let VertexNumbers::XML {
            connectivity,
            offsets,
        } = p.cells.cell_verts
        else {
            panic!("expected XML cell numbering")
        };
        let as_u64 = |v: &[usize]| v.iter().map(|&x| x as u64).collect::<Vec<_>>();
        assert_eq!(connectivity, as_u64(&m.connectivity));
        assert_eq!(offsets, as_u64(&m.offsets));
        assert_eq!(p.cells.types, vec![CellType::Hexahedron, CellType::Tetra]);
        for (attrs, name, comps, want) in [
            (p.data.point, "displacement", 3, &m.displacement),
            (p.data.cell, "stress", 9, &m.stress),
        ] {
            assert_eq!(attrs.len(), 1);
            let Attribute::DataArray(a) = attrs.into_iter().next().unwrap() else {
                panic!("expected a data array")
            };
            assert_eq!(a.name, name);
            assert_eq!(a.elem.num_comp(), comps);
            assert_eq!(bits(&f64s(a.data)), bits(want));
        }
    }

    /// A mesh like [`mesh`] with values whose little-endian bytes never contain `<` (0x3C); see
    /// [`appended_raw_is_exact`] for why vtkio needs that.
    fn benign_mesh() -> Mesh {
        let mut m = mesh();
        let corners = [[0., 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]];
        for (i, p) in m.points.iter_mut().enumerate() {
            let c = corners[i % 4];
            *p = Vector3::new(c[0], c[1], c[2] + (i / 4) as f64);
        }
        for (i, v) in m.displacement.iter_mut().enumerate() {
            *v = i as f64 * 0.25 - 2.0;
        }
        for (i, v) in m.stress.iter_mut().enumerate() {
            *v = i as f64 * 1024.0 - 0.5;
        }
        m
    }

    /// Decodes the raw appended block of a file written in [`VtuFormat::Appended`] without any
    /// XML library: returns (Name, type, bytes) of each array in header order.
    fn decode_appended(path: &Path) -> Vec<(String, String, Vec<u8>)> {
        let data = std::fs::read(path).unwrap();
        let tag = b"<AppendedData encoding=\"raw\">";
        let at = data.windows(tag.len()).position(|w| w == tag).unwrap();
        let blob_start = at + data[at..].iter().position(|&b| b == b'_').unwrap() + 1;
        let head = std::str::from_utf8(&data[..at]).unwrap();
        let attr = |el: &str, key: &str| -> String {
            let k = format!(" {key}=\"");
            let i = el.find(&k).unwrap() + k.len();
            el[i..i + el[i..].find('"').unwrap()].to_string()
        };
        head.split("<DataArray")
            .skip(1)
            .map(|el| {
                let el = &el[..el.find('>').unwrap()];
                assert_eq!(attr(el, "format"), "appended");
                let off: usize = attr(el, "offset").parse().unwrap();
                let p = blob_start + off;
                let n = u64::from_le_bytes(data[p..p + 8].try_into().unwrap()) as usize;
                (
                    attr(el, "Name"),
                    attr(el, "type"),
                    data[p + 8..p + 8 + n].to_vec(),
                )
            })
            .collect()
    }

    /// The bytes between `_` and the closing `</AppendedData>` tag.
    fn raw_block(path: &Path) -> Vec<u8> {
        let data = std::fs::read(path).unwrap();
        let tail = b"\n  </AppendedData>\n</VTKFile>\n";
        let at = data
            .windows(15)
            .position(|w| w == b"encoding=\"raw\">")
            .unwrap();
        let blob = at + data[at..].iter().position(|&b| b == b'_').unwrap() + 1;
        data[blob..data.len() - tail.len()].to_vec()
    }

    fn le_f64(v: impl IntoIterator<Item = f64>) -> Vec<u8> {
        v.into_iter().flat_map(f64::to_le_bytes).collect()
    }

    fn le_i64(v: &[usize]) -> Vec<u8> {
        v.iter().flat_map(|&x| (x as i64).to_le_bytes()).collect()
    }

    #[test]
    fn vtu_round_trips_through_vtkio_in_every_format() {
        let dir = temp_dir("formats");
        let m = mesh();
        let benign = benign_mesh();
        for (format, name, m) in [
            (VtuFormat::Ascii, "ascii.vtu", &m),
            (VtuFormat::Binary, "binary.vtu", &m),
            // Raw appended data with arbitrary values is checked in `appended_raw_is_exact`.
            (VtuFormat::Appended, "appended.vtu", &benign),
        ] {
            let path = dir.join(name);
            write_vtu(&path, &piece(m), format).unwrap();
            let head = std::fs::read(&path).unwrap();
            let head = String::from_utf8_lossy(&head[..200]);
            assert!(head.contains(
                "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">"
            ));
            check_with_vtkio(&path, m);
        }
        // No temporary files are left behind.
        let mut names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["appended.vtu", "ascii.vtu", "binary.vtu"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// vtkio 0.6 reads `<AppendedData encoding="raw">` through quick-xml as element text, so the
    /// text ends at the first `<` (0x3C) byte of the binary data and the parse fails with
    /// `UnexpectedEof`. VTK, ParaView and meshio seek by offset and have no such limit. Here the
    /// appended block of the general mesh, which contains `<` bytes, is decoded by hand instead.
    #[test]
    fn appended_raw_is_exact() {
        let dir = temp_dir("appended");
        let path = dir.join("mesh.vtu");
        let m = mesh();
        write_vtu(&path, &piece(&m), VtuFormat::Appended).unwrap();
        let arrays = decode_appended(&path);
        let want: Vec<(&str, &str, Vec<u8>)> = vec![
            (
                "displacement",
                "Float64",
                le_f64(m.displacement.iter().copied()),
            ),
            ("stress", "Float64", le_f64(m.stress.iter().copied())),
            (
                "Points",
                "Float64",
                le_f64(m.points.iter().flat_map(|p| [p.x, p.y, p.z])),
            ),
            ("connectivity", "Int64", le_i64(&m.connectivity)),
            ("offsets", "Int64", le_i64(&m.offsets)),
            ("types", "UInt8", m.types.clone()),
        ];
        assert_eq!(arrays.len(), want.len());
        for ((name, ty, bytes), (wname, wty, wbytes)) in arrays.iter().zip(&want) {
            assert_eq!((name.as_str(), ty.as_str()), (*wname, *wty));
            assert_eq!(bytes, wbytes, "{name}");
        }
        assert!(std::fs::read(&path)
            .unwrap()
            .ends_with(b"\n  </AppendedData>\n</VTKFile>\n"));
        assert!(
            raw_block(&path).contains(&b'<'),
            "this data exercises the vtkio limitation"
        );
        assert!(
            vtkio::Vtk::import(&path).is_err(),
            "vtkio learned to read raw appended data"
        );
        // The benign mesh, with no `<` byte in its block, is read by vtkio in the test above.
        let benign = benign_mesh();
        write_vtu(&path, &piece(&benign), VtuFormat::Appended).unwrap();
        assert!(!raw_block(&path).contains(&b'<'));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn point_cloud_without_cells() {
        let dir = temp_dir("cloud");
        let points = vec![Vector3::new(1.0, 2.0, 3.0), Vector3::new(-0.5, 0.25, 1e-9)];
        let mass = [1.5, 2.5];
        for format in [VtuFormat::Ascii, VtuFormat::Binary, VtuFormat::Appended] {
            let path = dir.join(format!("{format:?}.vtu"));
            let piece = Piece {
                points: &points,
                connectivity: &[],
                offsets: &[],
                types: &[],
                point_data: vec![DataArray {
                    name: "mass",
                    components: 1,
                    values: &mass,
                }],
                cell_data: vec![],
            };
            write_vtu(&path, &piece, format).unwrap();
            if format == VtuFormat::Ascii {
                // vtkio 0.6 panics (index out of bounds in `DataArray::into_field_array`) on an
                // ASCII DataArray with no values, which VTK itself reads and writes; check the
                // text instead.
                let text = std::fs::read_to_string(&path).unwrap();
                assert!(text.contains("NumberOfPoints=\"2\" NumberOfCells=\"0\""));
                assert!(text.contains("1 2 3\n") && text.contains("-0.5 0.25 1e-9\n"));
                assert!(text.contains(
                    "<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n        </DataArray>"
                ));
                continue;
            }
            let vtk = vtkio::Vtk::import(&path).unwrap_or_else(|e| panic!("{format:?}: {e}"));
            let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
                panic!("not an unstructured grid")
            };
            let p = pieces
                .into_iter()
                .next()
                .unwrap()
                .into_loaded_piece_data(None)
                .unwrap();
            assert_eq!(f64s(p.points), vec![1.0, 2.0, 3.0, -0.5, 0.25, 1e-9]);
            assert!(p.cells.types.is_empty());
            let Attribute::DataArray(a) = &p.data.point[0] else {
                panic!()
            };
            assert_eq!(f64s(a.data.clone()), mass);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn inconsistent_input_is_rejected_and_writes_nothing() {
        let dir = temp_dir("errors");
        let path = dir.join("bad.vtu");
        let m = mesh();
        let short = &m.stress[..17];
        let mut p = piece(&m);
        p.cell_data[0].values = short;
        let e = write_vtu(&path, &p, VtuFormat::Appended).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, Error::Input(_)), "{e:?}");
        assert!(
            msg.contains("\"stress\"") && msg.contains("17") && msg.contains("18"),
            "{msg}"
        );

        let mut p = piece(&m);
        p.point_data[0].values = &m.displacement[..35];
        let msg = write_vtu(&path, &p, VtuFormat::Ascii)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("\"displacement\"") && msg.contains("35"),
            "{msg}"
        );

        let mut p = piece(&m);
        let offsets = [8, 11];
        p.offsets = &offsets;
        let msg = write_vtu(&path, &p, VtuFormat::Ascii)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("connectivity"), "{msg}");

        let mut p = piece(&m);
        let conn = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12];
        p.connectivity = &conn;
        let msg = write_vtu(&path, &p, VtuFormat::Ascii)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("point 12"), "{msg}");

        let mut p = piece(&m);
        let types = [12, 12];
        p.types = &types;
        let msg = write_vtu(&path, &p, VtuFormat::Ascii)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("cell 1") && msg.contains("expected 8"),
            "{msg}"
        );

        assert!(!path.exists());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn pvd_lists_every_frame() {
        let dir = temp_dir("pvd");
        let path = dir.join("run.pvd");
        let frames = vec![
            (0.0, "run_0000.vtu".to_string()),
            (1e-3 / 3.0, "run_0001.vtu".to_string()),
            (2.5e-3, "a&b.vtu".to_string()),
        ];
        write_pvd(&path, &frames).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text
            .starts_with("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"1.0\""));
        assert!(
            text.contains("<DataSet timestep=\"0\" group=\"\" part=\"0\" file=\"run_0000.vtu\"/>")
        );
        assert!(text.contains("file=\"a&amp;b.vtu\""));
        assert_eq!(text.matches("<DataSet ").count(), 3);
        // Times read back exactly.
        let times: Vec<f64> = text
            .split("timestep=\"")
            .skip(1)
            .map(|s| s[..s.find('"').unwrap()].parse().unwrap())
            .collect();
        assert_eq!(times, frames.iter().map(|f| f.0).collect::<Vec<_>>());
        assert!(text.trim_end().ends_with("</Collection>\n</VTKFile>"));
        assert!(matches!(
            write_pvd(&path, &[(f64::NAN, "x.vtu".into())]),
            Err(Error::Input(_))
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            // Feed one byte at a time and all at once: both must give the same text.
            for split in [false, true] {
                let mut out = Vec::new();
                let mut w = Base64Writer::new(&mut out);
                if split {
                    for b in input.as_bytes() {
                        w.write_all(std::slice::from_ref(b)).unwrap();
                    }
                } else {
                    w.write_all(input.as_bytes()).unwrap();
                }
                w.finish().unwrap();
                assert_eq!(String::from_utf8(out).unwrap(), want);
            }
        }
        // Long input crossing the internal flush threshold.
        let data: Vec<u8> = (0..30_000u32).map(|i| (i * 7919 % 251) as u8).collect();
        let mut out = Vec::new();
        let mut w = Base64Writer::new(&mut out);
        for chunk in data.chunks(1000) {
            w.write_all(chunk).unwrap();
        }
        w.finish().unwrap();
        assert_eq!(out.len(), 40_000);
        let mut alt = Vec::new();
        let mut w = Base64Writer::new(&mut alt);
        w.write_all(&data).unwrap();
        w.finish().unwrap();
        assert_eq!(out, alt);
    }
}
