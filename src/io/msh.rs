//! Gmsh MSH reader: format 4.1 (ASCII or binary, parsed by the `mshio` crate) and format 2.2
//! (ASCII, parsed here).
//!
//! What is read:
//! - **Volume cells**: 4-node tetrahedra (Gmsh type 4) become [`ElementShape::Tet4`], 8-node
//!   hexahedra (type 5) [`ElementShape::Hex8`]. Gmsh numbers the nodes of both as VTK does
//!   (hex: bottom 0-1-2-3, top 4-5-6-7), so connectivity is taken as written. A file with both
//!   is an error (hytled meshes have one shape), as is a file with neither.
//! - **Boundary faces**: 3-node triangles (type 2) and 4-node quadrangles (type 3).
//! - **Points and lines** (types 15, 1 and the higher-order lines 8, 26-28) only contribute
//!   their nodes to node sets.
//! - Every other type (prisms, pyramids, second-order volumes and faces such as 11 tet10,
//!   17 hex20, 12 hex27, 9 tri6...) is an error naming the type, where it is, and the fix
//!   (re-mesh with `Mesh.ElementOrder = 1`).
//!
//! **Sets** come from physical groups; a group's name is its `$PhysicalNames` entry, or
//! `physical_<dim>_<tag>` when it has none:
//! - a 3-D group gives an element set (its cells) and a node set (their nodes);
//! - a 2-D group gives a face set (its triangles/quadrangles as node-index lists, in the
//!   file's node order) and a node set (their nodes);
//! - a 0-D or 1-D group gives a node set.
//!
//! In MSH 4.1 physical tags belong to the geometric entities of `$Entities`; each element
//! block takes the tags of its entity. In MSH 2.2 they are the first tag of each element
//! (an element written once per group it belongs to is merged back into one).
//!
//! Node ids may be sparse and in any order: nodes are indexed 0.. in file order and
//! [`MeshInput::node_ids`] keeps the ids. Coordinates are returned as written in the file; the
//! scene applies its units factor afterwards.
//!
//! Errors name the file and where the problem is (line for 2.2; element/node block, byte
//! offset and, for ASCII, line for 4.1). No input makes the reader panic: the parts of
//! `mshio` that can panic on malformed headers are checked first and the parse runs under
//! `super::guard_parser` as a last resort (no mutated file in the fuzz tests reaches it).

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use nalgebra::Vector3;

use super::model::MeshInput;
use super::{clip, file_error as input_err, line_err};
use crate::geometry::{ElementShape, Mesh};
use crate::{Error, Result};

/// Reads a Gmsh `.msh` file, format 4.1 (ASCII or binary) or 2.2 (ASCII), chosen from its
/// `$MeshFormat` header. See the module documentation for what becomes cells, faces and sets.
/// Coordinates are as written in the file (no unit conversion).
pub fn read_msh(path: &Path) -> Result<MeshInput> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_msh(&bytes, path)
}

/// [`read_msh`] on the bytes of a file already in memory; `path` only names the file in
/// messages.
pub fn parse_msh(bytes: &[u8], path: &Path) -> Result<MeshInput> {
    let header = read_header(bytes, path)?;
    match header.version.as_str() {
        "2.2" => {
            if header.file_type != 0 {
                return Err(line_err(
                    path,
                    header.line,
                    "binary MSH 2.2 is not supported; save the mesh as ASCII MSH 2.2 \
                     (Mesh.Binary = 0) or as MSH 4.1 (binary or ASCII)",
                ));
            }
            parse_msh22(&String::from_utf8_lossy(bytes), path)
        }
        "4.1" => parse_msh41(bytes, &header, path),
        _ => unreachable!("read_header only accepts 2.2 and 4.1"),
    }
}

/// Parses the text of an ASCII MSH 2.2 file (what [`read_msh`] does for version 2.2); `path`
/// only names the file in messages, which give the line of each problem.
pub fn parse_msh22(text: &str, path: &Path) -> Result<MeshInput> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut cur = Cursor::new(text, path, 1);
    let fail = |m: String| input_err(path, m);

    match cur.next() {
        Some((_, "$MeshFormat")) => {}
        Some((l, other)) => {
            return Err(line_err(
                path,
                l,
                format!(
                    "expected $MeshFormat, found '{}': not a Gmsh MSH file",
                    clip(other)
                ),
            ))
        }
        None => return Err(fail("the file is empty: not a Gmsh MSH file".into())),
    }
    let (l, fmt) = cur
        .next()
        .ok_or_else(|| fail("the file ends inside $MeshFormat; it is truncated".into()))?;
    let f: Vec<&str> = fmt.split_whitespace().collect();
    if f.first().and_then(|v| v.parse::<f64>().ok()) != Some(2.2) {
        return Err(line_err(
            path,
            l,
            format!(
                "MSH format version '{}' is not 2.2 (this parser reads ASCII MSH 2.2 only; \
             use read_msh for 4.1)",
                clip(f.first().copied().unwrap_or(""))
            ),
        ));
    }
    if f.get(1) != Some(&"0") {
        return Err(line_err(
            path,
            l,
            format!(
                "MSH 2.2 file type '{}' is not 0 (ASCII); binary MSH 2.2 is not supported: \
             save as ASCII (Mesh.Binary = 0) or as MSH 4.1",
                clip(f.get(1).copied().unwrap_or(""))
            ),
        ));
    }
    cur.expect_end("$EndMeshFormat", "$MeshFormat", l)?;

    let mut raw = Raw::default();
    let mut seen_nodes: Option<usize> = None;
    let mut seen_elements: Option<usize> = None;
    while let Some((l, line)) = cur.next() {
        match line {
            "$PhysicalNames" => parse_physical_names(&mut cur, l, &mut raw.names)?,
            "$Nodes" => {
                if let Some(first) = seen_nodes {
                    return Err(line_err(
                        path,
                        l,
                        format!(
                            "a second $Nodes section (the first is at line {first}); \
                         hytled reads one"
                        ),
                    ));
                }
                seen_nodes = Some(l);
                parse_nodes22(&mut cur, l, &mut raw)?;
            }
            "$Elements" => {
                if let Some(first) = seen_elements {
                    return Err(line_err(
                        path,
                        l,
                        format!(
                            "a second $Elements section (the first is at line {first}); \
                         hytled reads one"
                        ),
                    ));
                }
                seen_elements = Some(l);
                parse_elements22(&mut cur, l, &mut raw)?;
            }
            s if s.starts_with("$End") => {
                return Err(line_err(
                    path,
                    l,
                    format!("'{}' closes a section that was not opened", clip(s)),
                ))
            }
            s if s.starts_with('$') => cur.skip_section(s, l)?,
            s => {
                return Err(line_err(
                    path,
                    l,
                    format!("unexpected text outside any section: '{}'", clip(s)),
                ))
            }
        }
    }
    if seen_nodes.is_none() {
        return Err(fail("no $Nodes section".into()));
    }
    if seen_elements.is_none() {
        return Err(fail("no $Elements section".into()));
    }
    assemble(raw, path)
}

// ---------------------------------------------------------------------------------------------
// Shared model: what both format parsers produce before assembly.

/// Where a node or element was read, for messages.
#[derive(Debug, Clone, Copy)]
enum Loc {
    /// Line number (MSH 2.2).
    Line(usize),
    /// 0-based element block and position in it (MSH 4.1).
    ElementBlock { block: usize, index: usize },
    /// 0-based node block and position in it (MSH 4.1).
    NodeBlock { block: usize, index: usize },
}

impl std::fmt::Display for Loc {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Loc::Line(l) => write!(f, "line {l}"),
            Loc::ElementBlock { block, index } => {
                write!(f, "element block {}, element {}", block + 1, index + 1)
            }
            Loc::NodeBlock { block, index } => {
                write!(f, "node block {}, node {}", block + 1, index + 1)
            }
        }
    }
}

/// What an element type is to this reader.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Volume(ElementShape),
    Face,
    /// Points and lines: their nodes go to node sets only.
    Lower,
}

struct RawElement {
    id: u64,
    gmsh_type: i64,
    role: Role,
    /// Dimension of the element (and of its physical groups).
    dim: u8,
    nodes: Vec<u64>,
    /// Physical group tags (of dimension `dim`).
    physical: Vec<i64>,
    loc: Loc,
}

#[derive(Default)]
struct Raw {
    nodes: Vec<(u64, Vector3<f64>, Loc)>,
    elements: Vec<RawElement>,
    /// Physical names by (dimension, tag).
    names: HashMap<(u8, i64), String>,
    warnings: Vec<String>,
}

/// Name, node count and dimension of the Gmsh element types this reader knows by name.
fn gmsh_type_info(t: i64) -> Option<(&'static str, usize, u8)> {
    Some(match t {
        1 => ("2-node line", 2, 1),
        2 => ("3-node triangle", 3, 2),
        3 => ("4-node quadrangle", 4, 2),
        4 => ("4-node tetrahedron", 4, 3),
        5 => ("8-node hexahedron", 8, 3),
        6 => ("6-node prism", 6, 3),
        7 => ("5-node pyramid", 5, 3),
        8 => ("3-node second-order line", 3, 1),
        9 => ("6-node second-order triangle", 6, 2),
        10 => ("9-node second-order quadrangle", 9, 2),
        11 => ("10-node second-order tetrahedron", 10, 3),
        12 => ("27-node second-order hexahedron", 27, 3),
        13 => ("18-node second-order prism", 18, 3),
        14 => ("14-node second-order pyramid", 14, 3),
        15 => ("1-node point", 1, 0),
        16 => ("8-node second-order quadrangle", 8, 2),
        17 => ("20-node second-order hexahedron", 20, 3),
        18 => ("15-node second-order prism", 15, 3),
        19 => ("13-node second-order pyramid", 13, 3),
        20 => ("9-node third-order incomplete triangle", 9, 2),
        21 => ("10-node third-order triangle", 10, 2),
        22 => ("12-node fourth-order incomplete triangle", 12, 2),
        23 => ("15-node fourth-order triangle", 15, 2),
        24 => ("15-node fifth-order incomplete triangle", 15, 2),
        25 => ("21-node fifth-order triangle", 21, 2),
        26 => ("4-node third-order line", 4, 1),
        27 => ("5-node fourth-order line", 5, 1),
        28 => ("6-node fifth-order line", 6, 1),
        29 => ("20-node third-order tetrahedron", 20, 3),
        30 => ("35-node fourth-order tetrahedron", 35, 3),
        31 => ("56-node fifth-order tetrahedron", 56, 3),
        92 => ("64-node third-order hexahedron", 64, 3),
        93 => ("125-node fourth-order hexahedron", 125, 3),
        _ => return None,
    })
}

/// The role, node count and dimension of a supported type, or the message for an
/// unsupported one (`at` says where it is).
fn classify(t: i64, at: &str) -> std::result::Result<(Role, usize, u8), String> {
    let role = match t {
        4 => Some(Role::Volume(ElementShape::Tet4)),
        5 => Some(Role::Volume(ElementShape::Hex8)),
        2 | 3 => Some(Role::Face),
        1 | 8 | 15 | 26 | 27 | 28 => Some(Role::Lower),
        _ => None,
    };
    match (role, gmsh_type_info(t)) {
        (Some(r), Some((_, n, d))) => Ok((r, n, d)),
        (_, info) => {
            let name = info.map_or("unknown type", |i| i.0);
            Err(format!(
                "unsupported Gmsh element type {t} ({name}) {at}; hytled reads 4-node tetrahedra \
                 (type 4) or 8-node hexahedra (type 5), with 3-node triangles or 4-node \
                 quadrangles as boundary faces: re-mesh with Mesh.ElementOrder = 1 and without \
                 prisms or pyramids"
            ))
        }
    }
}

/// The name of physical group (`dim`, `tag`).
fn group_name(names: &HashMap<(u8, i64), String>, dim: u8, tag: i64) -> String {
    names
        .get(&(dim, tag))
        .cloned()
        .unwrap_or_else(|| format!("physical_{dim}_{tag}"))
}

/// Builds the mesh and sets from what a parser read: node ids to indices, one volume shape,
/// physical groups to sets.
fn assemble(raw: Raw, path: &Path) -> Result<MeshInput> {
    let Raw {
        nodes: raw_nodes,
        elements: raw_elements,
        names,
        mut warnings,
    } = raw;
    let fail = |m: String| input_err(path, m);

    // Nodes: file order, ids to indices.
    let mut index_of: HashMap<u64, usize> = HashMap::with_capacity(raw_nodes.len());
    let mut node_locs = Vec::with_capacity(raw_nodes.len());
    let mut nodes = Vec::with_capacity(raw_nodes.len());
    let mut node_ids = Vec::with_capacity(raw_nodes.len());
    for (id, p, loc) in raw_nodes {
        if let Some(&first) = index_of.get(&id) {
            let first_loc: Loc = node_locs[first];
            return Err(fail(format!(
                "node {id} is defined twice ({first_loc} and {loc}); node ids must be unique"
            )));
        }
        index_of.insert(id, nodes.len());
        node_locs.push(loc);
        nodes.push(p);
        node_ids.push(id);
    }

    // Elements: merge repeats of one element (MSH 2.2 writes an element once per physical
    // group it is in).
    let mut elements: Vec<RawElement> = Vec::with_capacity(raw_elements.len());
    let mut element_at: HashMap<u64, usize> = HashMap::with_capacity(raw_elements.len());
    for e in raw_elements {
        if let Some(&k) = element_at.get(&e.id) {
            let first = &mut elements[k];
            if first.gmsh_type == e.gmsh_type && first.nodes == e.nodes {
                for p in e.physical {
                    if !first.physical.contains(&p) {
                        first.physical.push(p);
                    }
                }
                continue;
            }
            return Err(fail(format!(
                "element {} is defined twice with different types or nodes ({} and {}); \
                 element ids must be unique",
                e.id, first.loc, e.loc
            )));
        }
        element_at.insert(e.id, elements.len());
        elements.push(e);
    }

    // One volume shape.
    let first_of = |s: ElementShape| elements.iter().find(|e| e.role == Role::Volume(s));
    let shape = match (first_of(ElementShape::Tet4), first_of(ElementShape::Hex8)) {
        (Some(t), Some(h)) => {
            return Err(fail(format!(
                "mixed tetrahedra and hexahedra (e.g. tetrahedron {} at {}, hexahedron {} at \
                 {}) are not supported; mesh with one element shape",
                t.id, t.loc, h.id, h.loc
            )))
        }
        (Some(_), None) => ElementShape::Tet4,
        (None, Some(_)) => ElementShape::Hex8,
        (None, None) => {
            return Err(fail(
                "no volume elements: the file has no 4-node tetrahedra (type 4) or 8-node \
                 hexahedra (type 5); mesh the volume (gmsh -3) and, when physical groups are \
                 defined, put the volume in one (Gmsh then saves only elements of physical \
                 groups)"
                    .into(),
            ))
        }
    };

    let mut cells = Vec::new();
    let mut element_ids = Vec::new();
    let mut node_sets: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    let mut element_sets: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    let mut face_sets: BTreeMap<String, Vec<Vec<usize>>> = BTreeMap::new();
    let mut used_groups: BTreeMap<String, Vec<u8>> = BTreeMap::new();
    for e in &elements {
        let idx = e
            .nodes
            .iter()
            .map(|t| {
                index_of.get(t).copied().ok_or_else(|| {
                    fail(format!(
                        "element {} ({}) references node {t}, which is not defined in $Nodes",
                        e.id, e.loc
                    ))
                })
            })
            .collect::<Result<Vec<usize>>>()?;
        let set_names: Vec<String> = e
            .physical
            .iter()
            .map(|&p| {
                let n = group_name(&names, e.dim, p);
                let dims = used_groups.entry(n.clone()).or_default();
                if !dims.contains(&e.dim) {
                    dims.push(e.dim);
                }
                n
            })
            .collect();
        match e.role {
            Role::Volume(_) => {
                let c = element_ids.len();
                cells.extend_from_slice(&idx);
                element_ids.push(e.id);
                for n in &set_names {
                    element_sets.entry(n.clone()).or_default().push(c);
                }
            }
            Role::Face => {
                for n in &set_names {
                    face_sets.entry(n.clone()).or_default().push(idx.clone());
                }
            }
            Role::Lower => {}
        }
        for n in set_names {
            node_sets.entry(n).or_default().extend_from_slice(&idx);
        }
    }
    for v in node_sets.values_mut().chain(element_sets.values_mut()) {
        v.sort_unstable();
        v.dedup();
    }
    for (name, dims) in &used_groups {
        if dims.len() > 1 {
            warnings.push(format!(
                "physical groups of dimensions {dims:?} share the name '{name}'; its node set \
                 holds the nodes of all of them"
            ));
        }
    }
    let mut unused: Vec<(u8, i64, &String)> = names
        .iter()
        .filter(|(_, n)| !used_groups.contains_key(*n))
        .map(|(&(d, t), n)| (d, t, n))
        .collect();
    unused.sort();
    for (d, t, n) in unused {
        warnings.push(format!(
            "physical group '{n}' (dimension {d}, tag {t}) has no elements in the file"
        ));
    }

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

// ---------------------------------------------------------------------------------------------
// Header and MSH 2.2 text parsing.

struct Header {
    version: String,
    file_type: i32,
    data_size: usize,
    /// Line of the version line.
    line: usize,
    /// Byte offset of `$MeshFormat`.
    start: usize,
}

/// Finds `$MeshFormat` and checks the version line: 2.2 or 4.1, file type 0/1, a data size
/// `mshio` can handle (it panics on others).
fn read_header(bytes: &[u8], path: &Path) -> Result<Header> {
    let fail = |m: String| input_err(path, m);
    let mut start = 0;
    if bytes.starts_with(&[0xef, 0xbb, 0xbf]) {
        start = 3;
    }
    while start < bytes.len() && bytes[start].is_ascii_whitespace() {
        start += 1;
    }
    let line_no = 1 + bytes[..start].iter().filter(|&&b| b == b'\n').count();
    let rest = &bytes[start..];
    let first_end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
    let first = String::from_utf8_lossy(&rest[..first_end]);
    if first.trim() != "$MeshFormat" {
        if rest.is_empty() {
            return Err(fail("the file is empty: not a Gmsh MSH file".into()));
        }
        return Err(line_err(
            path,
            line_no,
            format!(
                "expected $MeshFormat, found '{}': not a Gmsh MSH file (MSH 1 files, \
             which start with $NOD, are not supported; save as MSH 4.1 or 2.2)",
                clip(first.trim())
            ),
        ));
    }
    let after = &rest[(first_end + 1).min(rest.len())..];
    let second_end = after
        .iter()
        .position(|&b| b == b'\n')
        .unwrap_or(after.len());
    let second = String::from_utf8_lossy(&after[..second_end]);
    let line = line_no + 1;
    let f: Vec<&str> = second.split_whitespace().collect();
    if f.len() < 3 {
        return Err(line_err(
            path,
            line,
            format!(
                "the $MeshFormat line '{}' should be 'version file-type data-size'{}",
                clip(second.trim()),
                if second_end == after.len() {
                    " (the file ends here: truncated?)"
                } else {
                    ""
                }
            ),
        ));
    }
    let version = match f[0].parse::<f64>() {
        Ok(2.2) => "2.2",
        Ok(4.1) => "4.1",
        _ => {
            return Err(line_err(
                path,
                line,
                format!(
                    "MSH format version '{}' is not supported; hytled reads MSH 4.1 \
                 (ASCII or binary) and MSH 2.2 (ASCII): save with Mesh.MshFileVersion = 4.1 \
                 (gmsh -format msh41)",
                    clip(f[0])
                ),
            ))
        }
    };
    let file_type = match f[1] {
        "0" => 0,
        "1" => 1,
        other => {
            return Err(line_err(
                path,
                line,
                format!(
                    "MSH file type '{}' is neither 0 (ASCII) nor 1 (binary)",
                    clip(other)
                ),
            ))
        }
    };
    let data_size = match f[2].parse::<usize>() {
        Ok(d) if d == 4 || d == 8 => d,
        Ok(d) if file_type == 0 && (1..=16).contains(&d) => d,
        _ => {
            return Err(line_err(
                path,
                line,
                format!(
                    "MSH data size '{}' is not supported (Gmsh writes 8)",
                    clip(f[2])
                ),
            ))
        }
    };
    Ok(Header {
        version: version.to_string(),
        file_type,
        data_size,
        line,
        start,
    })
}

/// Non-empty, trimmed lines with their 1-based numbers.
struct Cursor<'a> {
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
    path: &'a Path,
    first_line: usize,
    /// Number of the last line returned.
    last: usize,
}

impl<'a> Cursor<'a> {
    fn new(text: &'a str, path: &'a Path, first_line: usize) -> Self {
        Cursor {
            lines: text.lines().enumerate(),
            path,
            first_line,
            last: first_line.saturating_sub(1),
        }
    }

    fn next(&mut self) -> Option<(usize, &'a str)> {
        for (i, l) in self.lines.by_ref() {
            let t = l.trim();
            if !t.is_empty() {
                self.last = i + self.first_line;
                return Some((self.last, t));
            }
        }
        None
    }

    /// Whether the last line returned was the last non-empty line of the text.
    fn at_end(&self) -> bool {
        self.lines.clone().all(|(_, l)| l.trim().is_empty())
    }

    fn err(&self, m: String) -> Error {
        input_err(self.path, m)
    }

    fn err_at(&self, line: usize, m: String) -> Error {
        line_err(self.path, line, m)
    }

    /// Requires `end` as the next line (closing `section` opened at `opened`).
    fn expect_end(&mut self, end: &str, section: &str, opened: usize) -> Result<()> {
        match self.next() {
            Some((_, l)) if l == end => Ok(()),
            Some((l, other)) => Err(self.err_at(
                l,
                format!(
                    "expected {end} to close {section} (line {opened}), found '{}'",
                    clip(other)
                ),
            )),
            None => Err(self.err(format!(
                "missing {end}: the file ends inside {section} (line {opened}); it is truncated"
            ))),
        }
    }

    /// Skips a section this reader does not use, up to its `$End...` line.
    fn skip_section(&mut self, start: &str, opened: usize) -> Result<()> {
        let name = start.split_whitespace().next().unwrap_or(start);
        let end = format!("$End{}", &name[1..]);
        while let Some((_, l)) = self.next() {
            if l == end {
                return Ok(());
            }
        }
        Err(self.err(format!(
            "missing {end}: the file ends inside {} (line {opened}); it is truncated",
            clip(name)
        )))
    }

    /// The count line after a section header.
    fn count(&mut self, section: &str, opened: usize) -> Result<usize> {
        let (l, line) = self.next().ok_or_else(|| {
            self.err(format!(
                "the file ends right after {section} (line {opened}); it is truncated"
            ))
        })?;
        line.parse::<usize>().map_err(|_| {
            self.err_at(
                l,
                format!(
                    "the {section} count '{}' is not a non-negative integer (non-numeric \
                 field or wrong header)",
                    clip(line)
                ),
            )
        })
    }

    /// The next data line of a section that should have `n` of them, `k` read so far.
    fn data_line(
        &mut self,
        section: &str,
        what: &str,
        opened: usize,
        k: usize,
        n: usize,
    ) -> Result<(usize, &'a str)> {
        let end = format!("$End{}", &section[1..]);
        match self.next() {
            None => Err(self.err(format!(
                "the file ends inside {section} (line {opened}) after {k} of the {n} {what} its \
                 header announces; the file is truncated"
            ))),
            Some((l, s)) if s == end => Err(self.err_at(
                l,
                format!(
                    "{end} after {k} {what}, but the {section} header (line {opened}) \
                 announces {n}: wrong count in the header"
                ),
            )),
            Some((l, s)) if s.starts_with('$') => Err(self.err_at(
                l,
                format!(
                    "'{}' inside {section} (line {opened}) after {k} of {n} {what}; \
                 missing {end}?",
                    clip(s)
                ),
            )),
            Some(x) => Ok(x),
        }
    }

    /// Requires the `$End` line of `section` after its `n` data lines.
    fn end_after_count(
        &mut self,
        section: &str,
        what: &str,
        opened: usize,
        n: usize,
    ) -> Result<()> {
        let end = format!("$End{}", &section[1..]);
        match self.next() {
            Some((_, s)) if s == end => Ok(()),
            Some((l, s)) if s.starts_with('$') => Err(self.err_at(
                l,
                format!(
                    "expected {end} after the {n} {what} of {section} (line {opened}), \
                 found '{}': missing {end}",
                    clip(s)
                ),
            )),
            Some((l, s)) => Err(self.err_at(
                l,
                format!(
                    "expected {end} after the {n} {what} the {section} header (line \
                 {opened}) announces, found '{}': wrong count in the header",
                    clip(s)
                ),
            )),
            None => Err(self.err(format!(
                "missing {end}: the file ends after the {n} {what} of {section} (line {opened}); \
                 it is truncated"
            ))),
        }
    }

    /// Parses field `s` (line `l`) as a number, naming `what` on failure.
    fn num<T: std::str::FromStr>(&self, s: &str, what: &str, l: usize) -> Result<T> {
        s.parse::<T>().map_err(|_| {
            self.err_at(
                l,
                format!(
                    "{what} '{}' is not a valid number (non-numeric field)",
                    clip(s)
                ),
            )
        })
    }

    /// A hint for a short last line.
    fn truncated_hint(&self) -> &'static str {
        if self.at_end() {
            " (it is the last line of the file: truncated?)"
        } else {
            ""
        }
    }
}

/// Reads the entries of `$PhysicalNames` (header at line `opened`): `dim tag "name"`.
fn parse_physical_names(
    cur: &mut Cursor<'_>,
    opened: usize,
    names: &mut HashMap<(u8, i64), String>,
) -> Result<()> {
    const S: &str = "$PhysicalNames";
    let n = cur.count(S, opened)?;
    for k in 0..n {
        let (l, line) = cur.data_line(S, "names", opened, k, n)?;
        let (dim_s, rest) = split_token(line);
        let (tag_s, rest) = split_token(rest);
        if tag_s.is_empty() {
            return Err(cur.err_at(
                l,
                format!(
                    "a physical name should be 'dimension tag \"name\"', found '{}'{}",
                    clip(line),
                    cur.truncated_hint()
                ),
            ));
        }
        let dim: u8 = cur.num(dim_s, "physical group dimension", l)?;
        if dim > 3 {
            return Err(cur.err_at(
                l,
                format!("physical group dimension {dim} is not 0, 1, 2 or 3"),
            ));
        }
        let tag: i64 = cur.num(tag_s, "physical group tag", l)?;
        let rest = rest.trim();
        let name = match rest.strip_prefix('"') {
            Some(r) => r.split('"').next().unwrap_or(r),
            None => rest,
        };
        let name = if name.is_empty() {
            format!("physical_{dim}_{tag}")
        } else {
            name.to_string()
        };
        names.insert((dim, tag.abs()), name);
    }
    cur.end_after_count(S, "names", opened, n)
}

/// First whitespace-separated token of `s` and the rest.
fn split_token(s: &str) -> (&str, &str) {
    let s = s.trim_start();
    match s.find(char::is_whitespace) {
        Some(i) => (&s[..i], &s[i..]),
        None => (s, ""),
    }
}

fn parse_nodes22(cur: &mut Cursor<'_>, opened: usize, raw: &mut Raw) -> Result<()> {
    const S: &str = "$Nodes";
    let n = cur.count(S, opened)?;
    raw.nodes.reserve(n.min(1 << 20));
    for k in 0..n {
        let (l, line) = cur.data_line(S, "nodes", opened, k, n)?;
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.len() != 4 {
            return Err(cur.err_at(
                l,
                format!(
                    "a node line has {} fields, expected 4 (id x y z): '{}'{}",
                    f.len(),
                    clip(line),
                    cur.truncated_hint()
                ),
            ));
        }
        let id: u64 = cur.num(f[0], "node id", l)?;
        let mut p = [0.0f64; 3];
        for (c, s) in p.iter_mut().zip(&f[1..]) {
            *c = cur.num(s, "node coordinate", l)?;
            if !c.is_finite() {
                return Err(cur.err_at(
                    l,
                    format!("node {id} has a non-finite coordinate '{}'", clip(s)),
                ));
            }
        }
        raw.nodes
            .push((id, Vector3::new(p[0], p[1], p[2]), Loc::Line(l)));
    }
    cur.end_after_count(S, "nodes", opened, n)
}

fn parse_elements22(cur: &mut Cursor<'_>, opened: usize, raw: &mut Raw) -> Result<()> {
    const S: &str = "$Elements";
    let n = cur.count(S, opened)?;
    raw.elements.reserve(n.min(1 << 20));
    for k in 0..n {
        let (l, line) = cur.data_line(S, "elements", opened, k, n)?;
        let f: Vec<&str> = line.split_whitespace().collect();
        if f.len() < 3 {
            return Err(cur.err_at(
                l,
                format!(
                    "an element line has {} fields, expected 'id type ntags tags... \
                 nodes...': '{}'{}",
                    f.len(),
                    clip(line),
                    cur.truncated_hint()
                ),
            ));
        }
        let id: u64 = cur.num(f[0], "element id", l)?;
        let t: i64 = cur.num(f[1], "element type", l)?;
        let ntags: usize = cur.num(f[2], "element tag count", l)?;
        let (role, nn, dim) =
            classify(t, &format!("at line {l} (element {id})")).map_err(|m| cur.err(m))?;
        let expected = ntags.checked_add(3 + nn);
        if expected != Some(f.len()) {
            return Err(cur.err_at(
                l,
                format!(
                    "element {id} of type {t} with {ntags} tags needs {} fields, found {}{}",
                    expected.map_or("too many".to_string(), |e| e.to_string()),
                    f.len(),
                    cur.truncated_hint()
                ),
            ));
        }
        let mut physical = Vec::new();
        if ntags >= 1 {
            let p: i64 = cur.num(f[3], "physical tag", l)?;
            if p != 0 {
                physical.push(p.abs());
            }
        }
        for s in &f[4.min(3 + ntags)..3 + ntags] {
            let _: i64 = cur.num(s, "element tag", l)?;
        }
        let nodes = f[3 + ntags..]
            .iter()
            .map(|s| cur.num::<u64>(s, "node id", l))
            .collect::<Result<Vec<u64>>>()?;
        raw.elements.push(RawElement {
            id,
            gmsh_type: t,
            role,
            dim,
            nodes,
            physical,
            loc: Loc::Line(l),
        });
    }
    cur.end_after_count(S, "elements", opened, n)
}

// ---------------------------------------------------------------------------------------------
// MSH 4.1 through mshio.

/// Byte position of a section line `$Name` (at the start of a line) in `bytes`, and the
/// position just after its line end.
fn find_section(bytes: &[u8], name: &[u8]) -> Option<(usize, usize)> {
    let mut from = 0;
    while let Some(rel) = find_bytes(&bytes[from..], name) {
        let at = from + rel;
        let line_start = at == 0 || bytes[at - 1] == b'\n';
        let after = at + name.len();
        let end = if bytes[after..].starts_with(b"\r\n") {
            Some(after + 2)
        } else if bytes[after..].starts_with(b"\n") || after == bytes.len() {
            Some((after + 1).min(bytes.len()))
        } else {
            None
        };
        if let (true, Some(e)) = (line_start, end) {
            return Some((at, e));
        }
        from = at + 1;
    }
    None
}

fn find_bytes(hay: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() || hay.len() < needle.len() {
        return None;
    }
    let first = needle[0];
    let mut i = 0;
    while i + needle.len() <= hay.len() {
        match hay[i..=hay.len() - needle.len()]
            .iter()
            .position(|&b| b == first)
        {
            None => return None,
            Some(p) => {
                i += p;
                if hay[i..].starts_with(needle) {
                    return Some(i);
                }
                i += 1;
            }
        }
    }
    None
}

/// How the bytes given to mshio differ from the file's: `delta` bytes inserted at `at`.
#[derive(Default, Clone, Copy)]
struct Patch {
    at: usize,
    delta: usize,
}

impl Patch {
    /// The file offset of `off` in the patched bytes.
    fn original(self, off: usize) -> usize {
        if off > self.at {
            off.saturating_sub(self.delta).max(self.at)
        } else {
            off
        }
    }
}

/// mshio keeps node tags only when they look sparse (max - min >= count); otherwise it drops
/// them and the order of dense but shuffled tags would be lost. Setting the `$Nodes` header's
/// largest tag to the maximum makes every file look sparse, so each block comes back with its
/// tags.
fn patch_max_node_tag(bytes: &[u8], header: &Header) -> (Vec<u8>, Patch) {
    let mut out = bytes.to_vec();
    let Some((_, data)) = find_section(bytes, b"$Nodes") else {
        return (out, Patch::default());
    };
    if header.file_type == 1 {
        let ds = header.data_size;
        if data + 4 * ds <= out.len() {
            out[data + 3 * ds..data + 4 * ds].fill(0xff);
        }
        return (out, Patch::default());
    }
    // ASCII: the 4th token of the header line.
    let line_end = bytes[data..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |p| data + p);
    let mut tokens = Vec::new();
    let mut i = data;
    while i < line_end {
        while i < line_end && bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        let s = i;
        while i < line_end && !bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        if i > s {
            tokens.push((s, i));
        }
    }
    if tokens.len() != 4
        || !bytes[tokens[3].0..tokens[3].1]
            .iter()
            .all(u8::is_ascii_digit)
    {
        return (out, Patch::default());
    }
    let (s, e) = tokens[3];
    let max = u64::MAX.to_string();
    let mut patched = Vec::with_capacity(bytes.len() + max.len());
    patched.extend_from_slice(&bytes[..s]);
    patched.extend_from_slice(max.as_bytes());
    patched.extend_from_slice(&bytes[e..]);
    out = patched;
    let delta = (s + max.len()).saturating_sub(e);
    (out, Patch { at: s, delta })
}

/// A readable message from mshio's error backtrace: what went wrong, in which part, where.
fn describe_mshio_error(
    e: &mshio::MshParserError<&[u8]>,
    buf: &[u8],
    original: &[u8],
    patch: Patch,
    ascii: bool,
) -> String {
    // Outermost first: contexts make the path, other kinds say what is wrong.
    let mut chain: Vec<String> = Vec::new();
    let mut problems: Vec<String> = Vec::new();
    for (_, k) in e.filtered_backtrace().iter().rev() {
        match k.context() {
            Some(c) => chain.push(c.to_string()),
            None => problems.push(k.to_string()),
        }
    }
    chain.dedup();
    problems.dedup();
    let what = if problems.is_empty() {
        "unexpected text: a section is malformed or its $End line is missing".to_string()
    } else {
        problems.join("; ")
    };
    let offset = e
        .backtrace
        .first()
        .map(|(s, _)| s.as_ptr() as usize)
        .and_then(|p| p.checked_sub(buf.as_ptr() as usize))
        .filter(|&o| o <= buf.len())
        .map(|o| patch.original(o).min(original.len()));
    let mut m = String::from("MSH 4.1 parse error");
    if let Some(o) = offset {
        m.push_str(&format!(" at byte offset {o}"));
        if ascii {
            let line = 1 + original[..o].iter().filter(|&&b| b == b'\n').count();
            let end = original[o..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(original.len(), |p| o + p);
            let text = String::from_utf8_lossy(&original[o..end]);
            let text = text.trim();
            if text.is_empty() {
                m.push_str(&format!(" (line {line})"));
            } else {
                m.push_str(&format!(" (line {line}, at '{}')", clip(text)));
            }
        }
    }
    if !chain.is_empty() {
        m.push_str(&format!(" in {}", chain.join(" > ")));
    }
    m.push_str(&format!(": {what}"));
    if offset == Some(original.len()) {
        m.push_str(" (at the end of the file: truncated?)");
    }
    m
}

/// Node tags and coordinates of one node block.
type NodeBlock = Vec<(u64, Vector3<f64>)>;

/// Node tags and coordinates of each node block of an ASCII MSH 4.1 `$Nodes` section, parsed
/// with Rust's exact float parsing.
fn ascii41_nodes(file: &[u8], path: &Path) -> Result<Vec<NodeBlock>> {
    let fail = |m: &str| input_err(path, format!("$Nodes: {m}"));
    let (_, start) = find_section(file, b"$Nodes").ok_or_else(|| fail("section not found"))?;
    let end = find_section(&file[start..], b"$EndNodes").map_or(file.len(), |(e, _)| start + e);
    let text = std::str::from_utf8(&file[start..end])
        .map_err(|_| fail("the section holds bytes that are not text"))?;
    let mut tok = text.split_ascii_whitespace();
    fn take<'a, T: std::str::FromStr>(
        it: &mut impl Iterator<Item = &'a str>,
        fail: &dyn Fn(&str) -> Error,
    ) -> Result<T> {
        it.next()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| fail("a number is missing or malformed"))
    }
    let num_blocks: usize = take(&mut tok, &fail)?;
    for _ in 0..3 {
        let _: u64 = take(&mut tok, &fail)?;
    }
    let bound = text.len() / 2 + 1;
    let mut blocks = Vec::with_capacity(num_blocks.min(bound));
    for _ in 0..num_blocks {
        let _: i64 = take(&mut tok, &fail)?;
        let _: i64 = take(&mut tok, &fail)?;
        let parametric: i64 = take(&mut tok, &fail)?;
        if parametric != 0 {
            return Err(fail("parametric node coordinates are not supported"));
        }
        let n: usize = take(&mut tok, &fail)?;
        let tags = (0..n)
            .map(|_| take::<u64>(&mut tok, &fail))
            .collect::<Result<Vec<u64>>>()?;
        let mut block = Vec::with_capacity(n.min(bound));
        for id in tags {
            let mut p = [0.0f64; 3];
            for c in p.iter_mut() {
                *c = take(&mut tok, &fail)?;
            }
            if !p.iter().all(|c| c.is_finite()) {
                return Err(input_err(
                    path,
                    format!("node {id} has a non-finite coordinate"),
                ));
            }
            block.push((id, Vector3::new(p[0], p[1], p[2])));
        }
        blocks.push(block);
    }
    Ok(blocks)
}

fn parse_msh41(bytes: &[u8], header: &Header, path: &Path) -> Result<MeshInput> {
    let fail = |m: String| input_err(path, m);
    let file = &bytes[header.start..];
    let (patched, patch) = patch_max_node_tag(file, header);
    let ascii = header.file_type == 0;
    let parsed = super::guard_parser("mshio", || {
        mshio::parse_msh_bytes(&patched)
            .map_err(|e| describe_mshio_error(&e, &patched, file, patch, ascii))
    });
    let msh = match parsed {
        Ok(Ok(m)) => m,
        Ok(Err(m)) => {
            // Offsets are relative to `$MeshFormat`; shift them for leading blank lines.
            let m = if header.start > 0 {
                format!(
                    "{m} (offsets counted from $MeshFormat at byte {})",
                    header.start
                )
            } else {
                m
            };
            return Err(fail(m));
        }
        Err(e) => {
            return Err(fail(format!(
                "MSH 4.1 parse error: {e}, or not a Gmsh MSH 4.1 file"
            )))
        }
    };

    let mut raw = Raw::default();
    if let Some((at, data)) = find_section(file, b"$PhysicalNames") {
        let end = find_section(&file[at..], b"$EndPhysicalNames")
            .map_or(file.len(), |(_, after)| at + after);
        let text = String::from_utf8_lossy(&file[data..end]);
        let opened = header.line - 1 + file[..at].iter().filter(|&&b| b == b'\n').count();
        let first_line = opened + 1;
        let mut cur = Cursor::new(&text, path, first_line);
        parse_physical_names(&mut cur, opened, &mut raw.names)?;
    }

    // Physical tags of each entity.
    let mut entity_groups: HashMap<(i32, i32), Vec<i64>> = HashMap::new();
    if let Some(ent) = &msh.data.entities {
        let tags = |v: &[i32]| v.iter().map(|&t| i64::from(t).abs()).collect::<Vec<i64>>();
        for p in &ent.points {
            entity_groups.insert((0, p.tag), tags(&p.physical_tags));
        }
        for c in &ent.curves {
            entity_groups.insert((1, c.tag), tags(&c.physical_tags));
        }
        for s in &ent.surfaces {
            entity_groups.insert((2, s.tag), tags(&s.physical_tags));
        }
        for v in &ent.volumes {
            entity_groups.insert((3, v.tag), tags(&v.physical_tags));
        }
    }

    let nodes = msh
        .data
        .nodes
        .as_ref()
        .ok_or_else(|| fail("no $Nodes section".into()))?;
    // mshio's ASCII float parsing can be off by a few ulps: take ASCII node tags and
    // coordinates from the text (mshio has checked its structure).
    let exact = if ascii {
        Some(ascii41_nodes(file, path)?)
    } else {
        None
    };
    if let Some(ex) = &exact {
        let ok = ex.len() == nodes.node_blocks.len()
            && ex
                .iter()
                .zip(&nodes.node_blocks)
                .all(|(e, b)| e.len() == b.nodes.len());
        if !ok {
            return Err(fail(
                "$Nodes: the node blocks could not be read consistently; the section is malformed"
                    .into(),
            ));
        }
    }
    for (b, block) in nodes.node_blocks.iter().enumerate() {
        let n = block.nodes.len();
        if let Some(ex) = &exact {
            for (i, &(id, v)) in ex[b].iter().enumerate() {
                raw.nodes
                    .push((id, v, Loc::NodeBlock { block: b, index: i }));
            }
            continue;
        }
        let tags: Vec<u64> = match &block.node_tags {
            Some(map) => {
                let mut t = vec![None; n];
                for (&tag, &i) in map {
                    if i < n {
                        t[i] = Some(tag);
                    }
                }
                match t.iter().position(Option::is_none) {
                    None => t.into_iter().flatten().collect(),
                    Some(_) => {
                        return Err(fail(format!(
                            "node block {} (entity dimension {}, tag {}) repeats a node tag; node \
                             ids must be unique",
                            b + 1,
                            block.entity_dim,
                            block.entity_tag
                        )))
                    }
                }
            }
            None => {
                // Not reached with the header patched; dense tags numbered in order.
                let first = nodes.min_node_tag + raw.nodes.len() as u64;
                (0..n as u64).map(|i| first + i).collect()
            }
        };
        for (i, (p, id)) in block.nodes.iter().zip(tags).enumerate() {
            let v = Vector3::new(p.x, p.y, p.z);
            if !v.iter().all(|c| c.is_finite()) {
                return Err(fail(format!(
                    "node {id} (node block {}, node {}) has a non-finite coordinate",
                    b + 1,
                    i + 1
                )));
            }
            raw.nodes
                .push((id, v, Loc::NodeBlock { block: b, index: i }));
        }
    }

    let elements = msh
        .data
        .elements
        .as_ref()
        .ok_or_else(|| fail("no $Elements section".into()))?;
    let nb = elements.element_blocks.len();
    for (b, block) in elements.element_blocks.iter().enumerate() {
        let t = block.element_type as i64;
        let at = format!(
            "in element block {} of {nb} (entity dimension {}, tag {})",
            b + 1,
            block.entity_dim,
            block.entity_tag
        );
        let (role, nn, dim) = classify(t, &at).map_err(fail)?;
        let physical = entity_groups
            .get(&(block.entity_dim, block.entity_tag))
            .cloned()
            .unwrap_or_default();
        for (i, e) in block.elements.iter().enumerate() {
            if e.nodes.len() != nn {
                return Err(fail(format!(
                    "element {} {at} has {} nodes; type {t} has {nn}",
                    e.element_tag,
                    e.nodes.len()
                )));
            }
            raw.elements.push(RawElement {
                id: e.element_tag,
                gmsh_type: t,
                role,
                dim,
                nodes: e.nodes.clone(),
                physical: physical.clone(),
                loc: Loc::ElementBlock { block: b, index: i },
            });
        }
    }
    assemble(raw, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::quality::tet_signed_volume;
    use std::path::PathBuf;

    fn data(name: &str) -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/msh")
            .join(name)
    }

    fn expected() -> serde_json::Value {
        let text = std::fs::read_to_string(data("expected.json")).unwrap();
        serde_json::from_str(&text).unwrap()
    }

    fn read(name: &str) -> MeshInput {
        read_msh(&data(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    fn err22(text: &str) -> String {
        match parse_msh22(text, Path::new("bad.msh")) {
            Ok(_) => panic!("expected an error"),
            Err(e) => {
                eprintln!("{e}");
                e.to_string()
            }
        }
    }

    fn err_bytes(bytes: &[u8]) -> String {
        match parse_msh(bytes, Path::new("bad.msh")) {
            Ok(_) => panic!("expected an error"),
            Err(e) => {
                eprintln!("{e}");
                e.to_string()
            }
        }
    }

    fn set_sizes(m: &MeshInput) -> Vec<(String, usize, usize, usize)> {
        m.set_names()
            .into_iter()
            .map(|n| {
                let len = |x: Option<usize>| x.unwrap_or(usize::MAX);
                (
                    n.clone(),
                    len(m.node_sets.get(&n).map(Vec::len)),
                    len(m.element_sets.get(&n).map(Vec::len)),
                    len(m.face_sets.get(&n).map(Vec::len)),
                )
            })
            .collect()
    }

    #[test]
    fn cylinder_variants_read_identically() {
        let exp = expected();
        let cyl = &exp["cylinder"];
        let a = read("cyl_v41.msh");
        let b = read("cyl_v41_bin.msh");
        let c = read("cyl_v22.msh");
        assert_eq!(a.mesh.nodes.len() as u64, cyl["nodes"].as_u64().unwrap());
        assert_eq!(a.mesh.shape, ElementShape::Tet4);
        assert_eq!(
            a.mesh.num_cells() as u64,
            cyl["element_types"]["4"]["count"].as_u64().unwrap()
        );
        let bits = |m: &MeshInput| {
            m.mesh
                .nodes
                .iter()
                .flat_map(|p| p.iter().map(|x| x.to_bits()).collect::<Vec<_>>())
                .collect::<Vec<u64>>()
        };
        // Both ASCII files hold Gmsh's 16-digit decimals: the same doubles, bit for bit.
        assert_eq!(bits(&a), bits(&c));
        // The binary file holds Gmsh's doubles themselves, which 16 digits do not always
        // round-trip: equal to within the rounding of the ASCII files.
        let mut max_ulps = 0.0f64;
        for (p, q) in a.mesh.nodes.iter().zip(&b.mesh.nodes) {
            for (x, y) in p.iter().zip(q.iter()) {
                let scale = x.abs().max(y.abs());
                if scale > 0.0 {
                    max_ulps = max_ulps.max((x - y).abs() / (scale * f64::EPSILON));
                } else {
                    assert_eq!(x, y);
                }
            }
        }
        assert!(max_ulps <= 4.0, "binary vs ASCII: {max_ulps} ulps");
        eprintln!("cylinder: binary vs ASCII coordinates differ by at most {max_ulps:.2} ulp");
        for other in [&b, &c] {
            assert_eq!(a.mesh.nodes.len(), other.mesh.nodes.len());
            assert_eq!(a.node_ids, other.node_ids);
            assert_eq!(a.mesh.cells, other.mesh.cells);
            assert_eq!(a.element_ids, other.element_ids);
            assert_eq!(a.node_sets, other.node_sets);
            assert_eq!(a.element_sets, other.element_sets);
            assert_eq!(a.face_sets, other.face_sets);
            assert_eq!(set_sizes(&a), set_sizes(other));
        }
        // Physical groups as gmsh reports them.
        for (name, g) in cyl["physical_groups"].as_object().unwrap() {
            let nodes = g["nodes"].as_u64().unwrap() as usize;
            let elems = g["elements"].as_u64().unwrap() as usize;
            assert_eq!(a.node_sets[name].len(), nodes, "{name}");
            match g["dim"].as_u64().unwrap() {
                3 => assert_eq!(a.element_sets[name].len(), elems, "{name}"),
                2 => assert_eq!(a.face_sets[name].len(), elems, "{name}"),
                _ => {}
            }
        }
        assert_eq!(a.set_names(), vec!["bottom", "lateral", "top", "volume"]);
        // Geometry of the sets: bottom at z = 0, top at z = 0.1, lateral at r = 0.05.
        for &i in &a.node_sets["bottom"] {
            assert!(a.mesh.nodes[i].z.abs() < 1e-12);
        }
        for &i in &a.node_sets["top"] {
            assert!((a.mesh.nodes[i].z - 0.1).abs() < 1e-12);
        }
        for &i in &a.node_sets["lateral"] {
            let p = a.mesh.nodes[i];
            assert!((p.x.hypot(p.y) - 0.05).abs() < 1e-9);
        }
        // Positive tetrahedra.
        let mut vmin = f64::INFINITY;
        let mut total = 0.0;
        for e in 0..a.mesh.num_cells() {
            let c = a.mesh.cell(e);
            let p = |k: usize| &a.mesh.nodes[c[k]];
            let v = tet_signed_volume(p(0), p(1), p(2), p(3));
            vmin = vmin.min(v);
            total += v;
        }
        assert!(vmin > 0.0, "smallest tet volume {vmin}");
        eprintln!("cylinder: smallest tet volume {vmin:.3e} m^3, total {total:.6e} m^3");
        // The polygonal cylinder is a little smaller than pi r^2 h.
        let exact = std::f64::consts::PI * 0.05 * 0.05 * 0.1;
        assert!(
            total < exact && total > 0.97 * exact,
            "volume {total} vs {exact}"
        );
        assert!(a.warnings.is_empty(), "{:?}", a.warnings);
    }

    #[test]
    fn hex_box_reads() {
        let exp = expected();
        let bx = &exp["box_hex"];
        let m = read("box_hex_v41.msh");
        assert_eq!(m.mesh.shape, ElementShape::Hex8);
        assert_eq!(m.mesh.nodes.len() as u64, bx["nodes"].as_u64().unwrap());
        assert_eq!(m.mesh.num_cells(), 24);
        assert_eq!(m.element_sets["tissue"].len(), 24);
        assert_eq!(m.node_sets["tissue"].len(), 60);
        assert_eq!(m.face_sets["fixed"].len(), 12);
        assert_eq!(m.node_sets["fixed"].len(), 20);
        for f in &m.face_sets["fixed"] {
            assert_eq!(f.len(), 4);
        }
        let (lo, hi) = m.mesh.bounding_box();
        assert!((hi - lo - Vector3::new(0.04, 0.03, 0.02)).norm() < 1e-12);
        // VTK hex order: the bottom face 0-1-2-3 seen from the top face is counter-clockwise,
        // so the volume from the corner tets is positive.
        for e in 0..m.mesh.num_cells() {
            let c = m.mesh.cell(e);
            let p = |k: usize| &m.mesh.nodes[c[k]];
            assert!(tet_signed_volume(p(0), p(1), p(3), p(4)) > 0.0);
            assert!(tet_signed_volume(p(6), p(5), p(7), p(2)) > 0.0);
        }
    }

    /// A small hand-written 2.2 file: sparse, unordered node ids, two groups on one element,
    /// unnamed group, a point group.
    const SMALL22: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n\
        $PhysicalNames\n2\n3 7 \"body part\"\n2 5 \"base\"\n$EndPhysicalNames\n\
        $Nodes\n5\n40 0 0 0\n10 1 0 0\n30 0 1 0\n20 0 0 1\n99 1 1 1\n$EndNodes\n\
        $Elements\n5\n\
        1 15 2 3 1 99\n\
        2 2 2 5 1 40 30 10\n\
        7 4 2 7 1 40 10 30 20\n\
        7 4 2 8 1 40 10 30 20\n\
        8 4 2 7 1 10 99 30 20\n\
        $EndElements\n";

    #[test]
    fn small_22_maps_ids_and_groups() {
        let m = parse_msh22(SMALL22, Path::new("small.msh")).unwrap();
        assert_eq!(m.node_ids, vec![40, 10, 30, 20, 99]);
        assert_eq!(m.element_ids, vec![7, 8]);
        assert_eq!(m.mesh.cells, vec![0, 1, 2, 3, 1, 4, 2, 3]);
        assert_eq!(m.element_sets["body part"], vec![0, 1]);
        assert_eq!(m.element_sets["physical_3_8"], vec![0]);
        assert_eq!(m.node_sets["physical_3_8"], vec![0, 1, 2, 3]);
        assert_eq!(m.face_sets["base"], vec![vec![0, 2, 1]]);
        assert_eq!(m.node_sets["base"], vec![0, 1, 2]);
        assert_eq!(m.node_sets["physical_0_3"], vec![4]);
        assert!(m.set_nodes("body part").unwrap().len() == 5);
    }

    fn cyl22() -> String {
        std::fs::read_to_string(data("cyl_v22.msh")).unwrap()
    }

    #[test]
    fn truncated_22_is_an_error() {
        let text = cyl22();
        let at = text.find("$Elements").unwrap();
        // Cut at a line end, halfway through the elements.
        let half = at + (text.len() - at) / 2;
        let cut = half + text[half..].find('\n').unwrap() + 1;
        let e = err22(&text[..cut]);
        assert!(e.contains("bad.msh") && e.contains("truncated"), "{e}");
        assert!(e.contains("$Elements") && e.contains("947"), "{e}");
        // Cut inside a line: the short last line is reported with its number.
        let e = err22(&text[..cut - 4]);
        assert!(e.contains("line ") && e.contains("truncated?"), "{e}");
        // Missing $EndNodes.
        let e = err22(&text.replace("$EndNodes\n", ""));
        assert!(e.contains("$EndNodes"), "{e}");
        // Through read_msh as bytes as well.
        let e = err_bytes(&text.as_bytes()[..cut]);
        assert!(e.contains("truncated"), "{e}");
    }

    #[test]
    fn wrong_node_count_is_an_error() {
        let text = cyl22();
        let e = err22(&text.replacen("$Nodes\n196\n", "$Nodes\n197\n", 1));
        assert!(e.contains("wrong count") && e.contains("$EndNodes"), "{e}");
        let e = err22(&text.replacen("$Nodes\n196\n", "$Nodes\n195\n", 1));
        assert!(e.contains("wrong count") && e.contains("line 208"), "{e}");
    }

    /// Issue 22: a header that announces more elements than the section holds is an error
    /// naming both lines, and a 1e6-digit node id is quoted in 60 characters, not 1 MB.
    #[test]
    fn wrong_element_count_and_huge_ids_give_short_located_errors() {
        let e = err22(&SMALL22.replacen("$Elements\n5\n", "$Elements\n9\n", 1));
        assert!(
            e.contains("wrong count") && e.contains("$EndElements") && e.contains("announces 9"),
            "{e}"
        );
        let huge = "1".repeat(1_000_000);
        let e = err22(&SMALL22.replacen("\n40 0 0 0\n", &format!("\n{huge} 0 0 0\n"), 1));
        assert!(
            e.contains("node id") && e.len() < 300,
            "{}",
            &e[..e.len().min(300)]
        );
    }

    #[test]
    fn non_numeric_field_is_an_error() {
        let text = cyl22();
        let bad = text.replacen("\n3 0.04619397662556436", "\n3 0.04619x97662556436", 1);
        assert_ne!(bad, text);
        let e = err22(&bad);
        assert!(
            e.contains("line 15") && e.contains("non-numeric") && e.contains("0.04619x"),
            "{e}"
        );
        let e = err22(&SMALL22.replace("8 4 2 7 1 10 99", "8 4 2 7 1 1O 99"));
        assert!(
            e.contains("non-numeric") && e.contains("node id '1O'"),
            "{e}"
        );
    }

    #[test]
    fn missing_node_is_an_error() {
        let e = err22(&SMALL22.replace("8 4 2 7 1 10 99 30 20", "8 4 2 7 1 10 98 30 20"));
        assert!(
            e.contains("element 8") && e.contains("node 98") && e.contains("line 23"),
            "{e}"
        );
    }

    #[test]
    fn unsupported_types_are_errors() {
        let tet10 = SMALL22.replace(
            "8 4 2 7 1 10 99 30 20",
            "8 11 2 7 1 10 99 30 20 40 40 40 40 40 40",
        );
        let e = err22(&tet10);
        assert!(
            e.contains("unsupported Gmsh element type 11 (10-node second-order tetrahedron)")
                && e.contains("line 23"),
            "{e}"
        );
        let e = err22(&SMALL22.replace("8 4 2 7 1 10 99 30 20", "8 6 2 7 1 10 99 30 20 40 10"));
        assert!(e.contains("type 6 (6-node prism)"), "{e}");
        let e = err22(&SMALL22.replace("8 4 2 7 1 10 99 30 20", "8 77 2 7 1 10"));
        assert!(e.contains("type 77 (unknown type)"), "{e}");
        let mixed = SMALL22.replace("8 4 2 7 1 10 99 30 20", "8 5 2 7 1 10 99 30 20 40 10 30 20");
        let e = err22(&mixed);
        assert!(e.contains("mixed tetrahedra and hexahedra"), "{e}");
    }

    #[test]
    fn unknown_version_is_an_error() {
        let e = err_bytes(b"$MeshFormat\n3.0 0 8\n$EndMeshFormat\n");
        assert!(e.contains("version '3.0' is not supported"), "{e}");
        let e = err_bytes(b"$MeshFormat\n4 0 8\n$EndMeshFormat\n");
        assert!(e.contains("version '4' is not supported"), "{e}");
        let e = err_bytes(b"$NOD\n1\n1 0 0 0\n$ENDNOD\n");
        assert!(e.contains("expected $MeshFormat"), "{e}");
        let e = err_bytes(b"$MeshFormat\n2.2 1 8\n$EndMeshFormat\n");
        assert!(e.contains("binary MSH 2.2 is not supported"), "{e}");
        let e = err_bytes(b"");
        assert!(e.contains("empty"), "{e}");
    }

    /// A small hand-written 4.1 file: dense node tags in shuffled order, a tet and a face.
    const SMALL41: &str = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n\
        $PhysicalNames\n2\n2 1 \"skin\"\n3 2 \"body\"\n$EndPhysicalNames\n\
        $Entities\n0 0 1 1\n\
        1 0 0 0 1 1 0 1 1 0\n\
        1 0 0 0 1 1 1 1 2 1 1\n$EndEntities\n\
        $Nodes\n2 4 1 4\n2 1 0 3\n3\n1\n2\n0 1 0\n0 0 0\n1 0 0\n\
        3 1 0 1\n4\n0 0 1\n$EndNodes\n\
        $Elements\n2 2 1 2\n2 1 2 1\n1 1 3 2\n3 1 4 1\n2 1 2 3 4\n$EndElements\n";

    #[test]
    fn small_41_keeps_shuffled_dense_ids() {
        let m = parse_msh(SMALL41.as_bytes(), Path::new("small41.msh")).unwrap();
        assert_eq!(m.node_ids, vec![3, 1, 2, 4]);
        assert_eq!(m.mesh.cells, vec![1, 2, 0, 3]);
        assert_eq!(m.element_ids, vec![2]);
        assert_eq!(m.element_sets["body"], vec![0]);
        assert_eq!(m.face_sets["skin"], vec![vec![1, 0, 2]]);
        assert_eq!(m.node_sets["skin"], vec![0, 1, 2]);
        let p = |k: usize| &m.mesh.nodes[m.mesh.cells[k]];
        assert!(tet_signed_volume(p(0), p(1), p(2), p(3)) > 0.0);
    }

    #[test]
    fn malformed_41_gives_located_errors() {
        // Unsupported element type, with its block.
        let e = err_bytes(
            SMALL41
                .replace("3 1 4 1\n2 1 2 3 4\n", "3 1 6 1\n2 1 2 3 4 1 2\n")
                .as_bytes(),
        );
        assert!(
            e.contains("unsupported Gmsh element type 6 (6-node prism) in element block 2 of 2"),
            "{e}"
        );
        // Element referencing a missing node.
        let e = err_bytes(SMALL41.replace("2 1 2 3 4\n", "2 1 2 3 9\n").as_bytes());
        assert!(e.contains("element 2") && e.contains("node 9"), "{e}");
        // Repeated node id.
        let e = err_bytes(SMALL41.replace("3 1 0 1\n4\n", "3 1 0 1\n3\n").as_bytes());
        assert!(e.contains("node 3 is defined twice"), "{e}");

        let text = std::fs::read_to_string(data("cyl_v41.msh")).unwrap();
        // Truncated inside $Elements.
        let at = text.find("$Elements").unwrap();
        let e = err_bytes(&text.as_bytes()[..at + 500]);
        assert!(
            e.contains("MSH 4.1 parse error") && e.contains("byte offset"),
            "{e}"
        );
        assert!(e.contains("element"), "{e}");
        // A non-numeric coordinate.
        let bad = text.replacen(
            "0.05 -1.224646799147353e-17 0.1\n0 2",
            "0.05 -1.2x4646799147353e-17 0.1\n0 2",
            1,
        );
        assert_ne!(bad, text);
        let e = err_bytes(bad.as_bytes());
        assert!(e.contains("line ") && e.contains("node"), "{e}");
        // Missing $EndNodes.
        let e = err_bytes(text.replacen("$EndNodes\n", "", 1).as_bytes());
        assert!(e.contains("MSH 4.1 parse error"), "{e}");
        // Binary, truncated.
        let bin = std::fs::read(data("cyl_v41_bin.msh")).unwrap();
        let e = err_bytes(&bin[..bin.len() * 2 / 3]);
        assert!(
            e.contains("MSH 4.1 parse error") && e.contains("byte offset"),
            "{e}"
        );
        // Bad data size (mshio would panic on it).
        let e = err_bytes(b"$MeshFormat\n4.1 1 3\n$EndMeshFormat\n");
        assert!(e.contains("data size '3'"), "{e}");
    }

    #[test]
    fn garbage_never_panics() {
        let files: Vec<Vec<u8>> = ["cyl_v41.msh", "cyl_v41_bin.msh", "cyl_v22.msh"]
            .iter()
            .map(|n| std::fs::read(data(n)).unwrap())
            .collect();
        // Deterministic pseudo-random mutations.
        let mut s: u64 = 0x9e3779b97f4a7c15;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        // HYTLED_FUZZ_ITERS=100000 for a longer run.
        let iters: usize = std::env::var("HYTLED_FUZZ_ITERS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(60);
        for f in &files {
            for _ in 0..iters {
                let mut b = f.clone();
                for _ in 0..(1 + next() % 4) {
                    let i = (next() as usize) % b.len();
                    match next() % 3 {
                        0 => b[i] = next() as u8,
                        1 => b.truncate(i.max(1)),
                        _ => {
                            b.insert(i, b"0123456789 \n$-.e"[(next() % 16) as usize]);
                        }
                    }
                }
                let _ = parse_msh(&b, Path::new("fuzz.msh"));
            }
        }
    }
}
