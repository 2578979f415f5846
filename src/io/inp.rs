//! ABAQUS `.inp` volume meshes with their named sets: reader ([`read_inp`], [`parse_inp`]) and
//! writer ([`write_inp`]).
//!
//! Coordinates are returned as written in the file (no unit conversion: the scene's `units`
//! factor is applied by the caller). Node and element ids may be sparse and unordered; they are
//! kept in [`MeshInput::node_ids`] / [`MeshInput::element_ids`] and everything else refers to
//! 0-based positions in order of appearance.
//!
//! # Keywords read
//!
//! Keywords and parameter names are case-insensitive and blanks in them are ignored
//! (`*End Part` = `*ENDPART`); `**` starts a comment line; a keyword line ending with a comma
//! continues on the next line; blank lines are ignored; trailing commas on data lines are
//! tolerated.
//!
//! * `*HEADING`: its text lines are ignored.
//! * `*NODE` (`NSET=` optional, `SYSTEM=R` only): `id, x, y, z`. Two-coordinate (2-D) nodes
//!   are an error; a blank coordinate between others is 0 (as in ABAQUS); further fields
//!   (nodal normals) are ignored with a warning.
//! * `*ELEMENT, TYPE=..` (`ELSET=` optional). `C3D8`, `C3D8R`, `C3D8H`, `C3D8I`, `C3D8RH`, ...
//!   read as hex8, `C3D4`, `C3D4H`, `C3D4T` as tet4; all volume elements of a file must have
//!   one shape. Linear triangles and quadrilaterals (`CPS3`, `CPE3`, `S3`, `S3R`, `STRI3`,
//!   `R3D3`, `M3D3`, `SFM3D3`, `CPS4`, `CPS4R`, `CPE4`, `S4`, `S4R`, `R3D4`, `M3D4`, `M3D4R`,
//!   `SFM3D4`, `SFM3D4R`, ...) are boundary faces: they become the face set named by `ELSET=`
//!   (or `TYPE_<type>`), and any element set listing them contributes them as a face set too.
//!   Line, point, spring and mass elements (`T3D2`, `B31`, `MASS`, ...) are ignored with a
//!   warning. Any other type (`C3D10`, `C3D20R`, `C3D6`, ...) is an error. An element line
//!   ending with a comma continues on the next line.
//! * `*NSET, NSET=..` and `*ELSET, ELSET=..`, with id lists, names of other sets of the same
//!   kind, or `GENERATE` (`start, end[, step]`); `*NSET, NSET=a, ELSET=b` adds the nodes of
//!   element set `b`. Repeated definitions with one name append.
//! * `*SURFACE, NAME=s[, TYPE=ELEMENT]`: lines `elset-or-element-id[, label]`. Labels
//!   `S1`..`S6` (C3D8) / `S1`..`S4` (C3D4) give element faces (ABAQUS numbering), oriented
//!   outward (right-hand normal pointing out of the element, as
//!   [`crate::geometry::quality::boundary_faces`]); without a label the free faces of the
//!   listed volume elements are taken; surface elements are taken as written (`SNEG`: reversed).
//!   Other surface types (`TYPE=NODE`, ...) are skipped with a warning.
//! * `*INCLUDE, INPUT=file` (relative to the including file, nested up to 10 deep, cycles are
//!   an error) and `INPUT=file` on `*NODE`, `*ELEMENT`, `*NSET`, `*ELSET`, `*SURFACE`.
//! * `*PART` / `*END PART` / `*ASSEMBLY` / `*INSTANCE` / `*END INSTANCE` / `*END ASSEMBLY`
//!   (ABAQUS/CAE's layout). Every `*INSTANCE, NAME=i, PART=p` is a copy of part `p`'s nodes,
//!   elements and sets (plus any `*NODE`/`*NSET`/... between `*INSTANCE` and `*END INSTANCE`),
//!   placed by its optional data lines as ABAQUS does: a translation `dx, dy, dz`, then a
//!   rotation `xa, ya, za, xb, yb, zb, angle` by `angle` degrees about the axis through a and b
//!   (right-hand rule about a -> b), applied after the translation. The instances are merged
//!   in file order; node and element ids stay the part's (they repeat across instances; a
//!   warning lists each instance's node and element positions, and errors in a part's lines
//!   name the instance being read). A part-level set `s` becomes `i.s` for each instance
//!   (and also `s` when a single instance has a set of that name and the assembly defines
//!   none). Assembly-level `*NSET` / `*ELSET` with `INSTANCE=i` take ids (and set names) of
//!   instance `i` and keep their plain names; without `INSTANCE=`, sets of set names are read
//!   and sets of ids (assembly nodes: reference points) are skipped with a warning, as are
//!   assembly `*NODE`/`*ELEMENT` lines. Instances without volume elements (rigid or analytic
//!   parts) or of another element shape than the first instance read are skipped with a
//!   warning, with the assembly sets on them. Mesh data outside `*PART` in such a file is read
//!   as one more body with plain set names.
//! * Everything else (`*MATERIAL`, `*SOLID SECTION`, `*STEP` .. `*END STEP`, `*BOUNDARY`, ...)
//!   is skipped with its data lines; one warning lists the skipped keywords.
//!
//! Errors are [`Error::Input`] messages `file:line: problem`, where `file` is the file
//! (included or not) the line is in.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use super::model::MeshInput;
use crate::geometry::quality::tet_signed_volume;
use crate::geometry::{ElementShape, Mesh};
use crate::{Error, Result};

/// Deepest `*INCLUDE` nesting read.
const MAX_INCLUDE_DEPTH: usize = 10;

/// Reads an ABAQUS input file (volume mesh + named sets). See the [module docs](self) for the
/// keywords read. Coordinates are as written in the file (the scene applies its units factor).
pub fn read_inp(path: &Path) -> Result<MeshInput> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8_lossy(&bytes);
    parse_inp(&text, path)
}

/// Parses the text of an ABAQUS input file; `path` names the file in errors and resolves
/// `*INCLUDE, INPUT=...` relative to its directory. Coordinates are as written in the text.
pub fn parse_inp(text: &str, path: &Path) -> Result<MeshInput> {
    let mut flat = Flattener {
        files: vec![path.to_path_buf()],
        stack: vec![canonical(path)],
    };
    let mut lines = Vec::new();
    flat.flatten(text, 0, 0, &mut lines)?;
    let files = Files(flat.files);
    if has_parts(&lines) {
        return parse_assembly(&lines, &files);
    }
    let mut p = Parser::new(&files);
    p.run(&lines)?;
    p.finish()
}

/// Writes a [`MeshInput`] as an ABAQUS input file: `*HEADING`, `*NODE`, one `*ELEMENT` block
/// (`TYPE=C3D8` or `C3D4`, `ELSET=ALL_ELEMENTS`, or `ALL_ELEMENTS_<k>` when that name holds
/// another element set), the face sets as surface elements (`CPS3` / `CPS4`, `ELSET=<name>`,
/// numbered after the volume elements) so that [`read_inp`] reads them back as face sets, then
/// `*NSET` / `*ELSET` for the node and element sets (16 ids per line).
///
/// The file's ids are `node_ids` / `element_ids` when they are positive, unique and one per
/// node / element, otherwise 1, 2, ... Coordinates are written in their shortest exact decimal
/// form, so reading the file back gives the same bits. Reading it back also gives the extra
/// element set of all elements; empty face sets are not written. Names with blanks are
/// quoted; names with `,`, `"`, `=` or control characters, names that differ only in case
/// (ABAQUS names are case-insensitive), non-finite coordinates, out-of-range indices and faces
/// that are not triangles or quadrilaterals are errors.
pub fn write_inp(path: &Path, m: &MeshInput) -> Result<()> {
    let text = format_inp(m, path)?;
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

// ---------------------------------------------------------------------------------------------
// Lines, files and keyword lines
// ---------------------------------------------------------------------------------------------

/// Where a line is: index into the file list and 1-based line number.
#[derive(Debug, Clone, Copy)]
struct Loc {
    file: usize,
    line: usize,
}

/// A significant (non-blank, non-comment) line, trimmed, includes expanded.
struct Line<'a> {
    loc: Loc,
    text: Cow<'a, str>,
    keyword: bool,
}

/// The files lines come from, for messages.
struct Files(Vec<PathBuf>);

impl Files {
    fn name(&self, file: usize) -> String {
        self.0
            .get(file)
            .map(|p| p.display().to_string())
            .unwrap_or_default()
    }

    fn at(&self, loc: Loc) -> String {
        format!("{}:{}", self.name(loc.file), loc.line)
    }

    fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
        Error::Input(format!("{}: {msg}", self.at(loc)))
    }
}

fn canonical(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
}

/// A parsed keyword line: normalized name (upper case, no blanks), the name as written, and
/// its parameters (normalized key, value as written without quotes; flags have "").
struct Keyword {
    name: String,
    shown: String,
    params: Vec<(String, String)>,
}

impl Keyword {
    fn get(&self, key: &str) -> Option<&str> {
        self.params
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    fn has(&self, key: &str) -> bool {
        self.params.iter().any(|(k, _)| k == key)
    }
}

/// Upper case without blanks.
fn norm_key(s: &str) -> String {
    s.chars()
        .filter(|c| !c.is_whitespace())
        .collect::<String>()
        .to_ascii_uppercase()
}

/// Splits on commas outside double quotes.
fn split_quoted(s: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut start = 0;
    let mut quoted = false;
    for (i, c) in s.char_indices() {
        match c {
            '"' => quoted = !quoted,
            ',' if !quoted => {
                out.push(s.get(start..i).unwrap_or(""));
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(s.get(start..).unwrap_or(""));
    out
}

/// Trims and removes surrounding double quotes.
fn unquote(s: &str) -> &str {
    let t = s.trim();
    if t.len() >= 2 && t.starts_with('"') && t.ends_with('"') {
        t.get(1..t.len() - 1).unwrap_or(t)
    } else {
        t
    }
}

/// Data fields, trimmed and unquoted, trailing empty fields dropped.
fn fields(s: &str) -> Vec<&str> {
    let mut f: Vec<&str> = split_quoted(s).into_iter().map(unquote).collect();
    while f.last().is_some_and(|x| x.is_empty()) {
        f.pop();
    }
    f
}

fn parse_keyword(text: &str) -> Keyword {
    let body = text.strip_prefix('*').unwrap_or(text);
    let parts = split_quoted(body);
    let first = parts.first().copied().unwrap_or("");
    let mut params = Vec::new();
    for p in parts.iter().skip(1) {
        if p.trim().is_empty() {
            continue;
        }
        match p.split_once('=') {
            Some((k, v)) => params.push((norm_key(k), unquote(v).to_string())),
            None => params.push((norm_key(p), String::new())),
        }
    }
    Keyword {
        name: norm_key(first),
        shown: format!("*{}", first.trim()),
        params,
    }
}

fn is_keyword(t: &str) -> bool {
    t.starts_with('*') && !t.starts_with("**")
}

/// Keywords whose data lines may come from an `INPUT=` file.
fn takes_input_file(name: &str) -> bool {
    matches!(name, "NODE" | "ELEMENT" | "NSET" | "ELSET" | "SURFACE")
}

/// Expands `*INCLUDE` and `INPUT=` into one list of significant lines.
struct Flattener {
    files: Vec<PathBuf>,
    /// Canonical paths of the files being read, outermost first (cycle detection).
    stack: Vec<PathBuf>,
}

impl Flattener {
    fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
        let name = self
            .files
            .get(loc.file)
            .map(|p| p.display().to_string())
            .unwrap_or_default();
        Error::Input(format!("{name}:{}: {msg}", loc.line))
    }

    /// Non-blank, non-comment lines of a text, trimmed, with 1-based line numbers.
    fn significant(text: &str) -> Vec<(usize, &str)> {
        text.lines()
            .enumerate()
            .map(|(i, l)| {
                let l = if i == 0 {
                    l.trim_start_matches('\u{feff}')
                } else {
                    l
                };
                (i + 1, l.trim())
            })
            .filter(|(_, t)| !t.is_empty() && !t.starts_with("**"))
            .collect()
    }

    /// Resolves, checks and reads a file named by `INPUT=` on the line at `loc`.
    fn open(&mut self, name: &str, loc: Loc, depth: usize) -> Result<(usize, PathBuf, String)> {
        if name.is_empty() {
            return Err(self.err(loc, "INPUT= names no file"));
        }
        let including = self.files.get(loc.file).cloned().unwrap_or_default();
        let rel = Path::new(name);
        let p = if rel.is_absolute() {
            rel.to_path_buf()
        } else {
            including
                .parent()
                .unwrap_or_else(|| Path::new(""))
                .join(rel)
        };
        let c = canonical(&p);
        if self.stack.contains(&c) {
            let mut chain: Vec<String> =
                self.stack.iter().map(|s| s.display().to_string()).collect();
            chain.push(c.display().to_string());
            return Err(self.err(
                loc,
                format!(
                    "*INCLUDE cycle: {}; remove the include that loops back",
                    chain.join(" -> ")
                ),
            ));
        }
        if depth + 1 > MAX_INCLUDE_DEPTH {
            return Err(self.err(
                loc,
                format!(
                    "*INCLUDE of {} nests deeper than {MAX_INCLUDE_DEPTH} levels",
                    p.display()
                ),
            ));
        }
        // Regular files only: a device (/dev/zero, a pipe) could be read forever.
        if let Ok(md) = std::fs::metadata(&p) {
            if !md.is_file() {
                return Err(self.err(
                    loc,
                    format!("{} named by INPUT= is not a regular file", p.display()),
                ));
            }
        }
        let bytes = std::fs::read(&p).map_err(|e| {
            self.err(
                loc,
                format!("cannot read the file {} named by INPUT=: {e}", p.display()),
            )
        })?;
        let text = String::from_utf8_lossy(&bytes).into_owned();
        self.files.push(p);
        Ok((self.files.len() - 1, c, text))
    }

    fn flatten<'t>(
        &mut self,
        text: &'t str,
        file: usize,
        depth: usize,
        out: &mut Vec<Line<'t>>,
    ) -> Result<()> {
        let sig = Self::significant(text);
        let mut i = 0;
        while let Some(&(no, t)) = sig.get(i) {
            let loc = Loc { file, line: no };
            i += 1;
            if !is_keyword(t) {
                out.push(Line {
                    loc,
                    text: Cow::Borrowed(t),
                    keyword: false,
                });
                continue;
            }
            // A keyword line ending with a comma continues on the next line.
            let mut kt: Cow<'t, str> = Cow::Borrowed(t);
            while kt.ends_with(',') {
                match sig.get(i) {
                    Some(&(_, next)) if !next.starts_with('*') => {
                        let mut s = kt.into_owned();
                        s.push_str(next);
                        kt = Cow::Owned(s);
                        i += 1;
                    }
                    _ => break,
                }
            }
            let kw = parse_keyword(&kt);
            if kw.name == "INCLUDE" {
                let Some(name) = kw.get("INPUT") else {
                    return Err(self.err(loc, "*INCLUDE without INPUT=<file>"));
                };
                let (sub_file, c, sub_text) = self.open(name, loc, depth)?;
                self.stack.push(c);
                let mut sub = Vec::new();
                let r = self.flatten(&sub_text, sub_file, depth + 1, &mut sub);
                self.stack.pop();
                r?;
                out.extend(sub.into_iter().map(|l| Line {
                    loc: l.loc,
                    text: Cow::Owned(l.text.into_owned()),
                    keyword: l.keyword,
                }));
                continue;
            }
            let input = kw.get("INPUT").map(str::to_string);
            out.push(Line {
                loc,
                text: kt,
                keyword: true,
            });
            if let (Some(name), true) = (input, takes_input_file(&kw.name)) {
                let (sub_file, _, sub_text) = self.open(&name, loc, depth)?;
                for (no, t) in Self::significant(&sub_text) {
                    let l = Loc {
                        file: sub_file,
                        line: no,
                    };
                    if is_keyword(t) {
                        return Err(self.err(
                            l,
                            format!(
                                "keyword line in a data file read by {} INPUT=; it may hold data lines only",
                                kw.shown
                            ),
                        ));
                    }
                    out.push(Line {
                        loc: l,
                        text: Cow::Owned(t.to_string()),
                        keyword: false,
                    });
                }
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Element types
// ---------------------------------------------------------------------------------------------

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ElemKind {
    Volume(ElementShape),
    /// Boundary face with this many nodes.
    Surface(usize),
    /// Line / point / connector element: ignored; node count when known.
    Ignored(Option<usize>),
    Unsupported,
}

fn classify(ty: &str) -> ElemKind {
    if let Some(rest) = ty.strip_prefix("C3D8") {
        if rest.len() <= 3 && rest.chars().all(|c| "RHITS".contains(c)) {
            return ElemKind::Volume(ElementShape::Hex8);
        }
    }
    if let Some(rest) = ty.strip_prefix("C3D4") {
        if rest.len() <= 2 && rest.chars().all(|c| "HT".contains(c)) {
            return ElemKind::Volume(ElementShape::Tet4);
        }
    }
    match ty {
        "CPS3" | "CPE3" | "S3" | "S3R" | "S3RS" | "STRI3" | "R3D3" | "M3D3" | "SFM3D3" | "DS3"
        | "CPS3T" | "CPE3T" => ElemKind::Surface(3),
        "CPS4" | "CPS4R" | "CPS4I" | "CPE4" | "CPE4R" | "CPE4I" | "CPE4H" | "CPE4RH" | "S4"
        | "S4R" | "S4RS" | "S4R5" | "R3D4" | "M3D4" | "M3D4R" | "SFM3D4" | "SFM3D4R" | "DS4" => {
            ElemKind::Surface(4)
        }
        "T2D2" | "T3D2" | "T2D2H" | "T3D2H" | "B21" | "B21H" | "B31" | "B31H" | "B33" | "B33H"
        | "CONN3D2" | "CONN2D2" | "SPRING2" | "SPRINGA" | "DASHPOT2" | "DASHPOTA" | "GAPUNI"
        | "RB3D2" | "RB2D2" | "R2D2" | "R3D2" => ElemKind::Ignored(Some(2)),
        "T2D3" | "T3D3" | "B22" | "B32" | "B22H" | "B32H" => ElemKind::Ignored(Some(3)),
        "SPRING1" | "DASHPOT1" | "MASS" | "ROTARYI" | "HEATCAP" => ElemKind::Ignored(Some(1)),
        _ => ElemKind::Unsupported,
    }
}

fn shape_name(s: ElementShape) -> &'static str {
    match s {
        ElementShape::Hex8 => "hex8",
        ElementShape::Tet4 => "tet4",
    }
}

/// ABAQUS faces S1.. of each shape as 0-based local nodes, outward oriented (the ABAQUS node
/// list of the face reversed, keeping its first node).
fn element_face(shape: ElementShape, k: usize) -> Option<&'static [usize]> {
    const HEX: [[usize; 4]; 6] = [
        [0, 3, 2, 1],
        [4, 5, 6, 7],
        [0, 1, 5, 4],
        [1, 2, 6, 5],
        [2, 3, 7, 6],
        [3, 0, 4, 7],
    ];
    const TET: [[usize; 3]; 4] = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]];
    match shape {
        ElementShape::Hex8 => HEX.get(k).map(|f| &f[..]),
        ElementShape::Tet4 => TET.get(k).map(|f| &f[..]),
    }
}

fn num_faces(shape: ElementShape) -> usize {
    match shape {
        ElementShape::Hex8 => 6,
        ElementShape::Tet4 => 4,
    }
}

// ---------------------------------------------------------------------------------------------
// Parser state
// ---------------------------------------------------------------------------------------------

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ElemRef {
    Vol(usize),
    Face(usize),
    Ignored,
}

#[derive(Debug, Clone)]
enum Item {
    Id(u64),
    Gen(u64, u64, u64),
    Name(String),
}

#[derive(Debug, Clone, Copy)]
enum Label {
    S(usize),
    Pos,
    Neg,
}

#[derive(Debug, Clone)]
enum Target {
    Id(u64),
    Name(String),
}

/// Set definitions, resolved in file order once every node and element is known.
enum SetEvent {
    NodeBlock {
        name: String,
        start: usize,
        end: usize,
    },
    ElemBlock {
        name: String,
        refs: Vec<ElemRef>,
    },
    Nset {
        name: String,
        loc: Loc,
        items: Vec<(Item, Loc)>,
        elset: Option<String>,
    },
    Elset {
        name: String,
        items: Vec<(Item, Loc)>,
    },
    Surface {
        name: String,
        entries: Vec<(Target, Option<Label>, Loc)>,
    },
}

struct SurfElem {
    id: u64,
    nodes: Vec<u64>,
    loc: Loc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Top,
    Step,
}

/// What the reader tells the user besides the mesh, gathered over every part read.
#[derive(Default)]
struct Notes {
    warnings: Vec<String>,
    /// Skipped keywords: (normalized name, name as written), first occurrence of each.
    skipped: Vec<(String, String)>,
    ignored_types: BTreeMap<String, usize>,
    extra_node_fields: usize,
    pre_keyword_lines: usize,
    assembly_nodes_skipped: usize,
    assembly_sets_skipped: Vec<String>,
}

impl Notes {
    fn skip_keyword(&mut self, kw: &Keyword) {
        if !self.skipped.iter().any(|(n, _)| *n == kw.name) {
            self.skipped.push((kw.name.clone(), kw.shown.clone()));
        }
    }

    /// Adds the notes of another part read (each warning once).
    fn absorb(&mut self, o: Notes) {
        for w in o.warnings {
            if !self.warnings.contains(&w) {
                self.warnings.push(w);
            }
        }
        for (n, shown) in o.skipped {
            if !self.skipped.iter().any(|(m, _)| *m == n) {
                self.skipped.push((n, shown));
            }
        }
        for (ty, n) in o.ignored_types {
            *self.ignored_types.entry(ty).or_insert(0) += n;
        }
        self.extra_node_fields += o.extra_node_fields;
        self.pre_keyword_lines += o.pre_keyword_lines;
        self.assembly_nodes_skipped += o.assembly_nodes_skipped;
        self.assembly_sets_skipped.extend(o.assembly_sets_skipped);
    }

    fn into_warnings(self) -> Vec<String> {
        let mut warnings = self.warnings;
        if self.pre_keyword_lines > 0 {
            warnings.push(format!(
                "{} data line(s) before the first keyword were ignored",
                self.pre_keyword_lines
            ));
        }
        if self.extra_node_fields > 0 {
            warnings.push(format!(
                "{} *NODE line(s) have more than 3 coordinates; the extra fields were ignored",
                self.extra_node_fields
            ));
        }
        for (ty, n) in &self.ignored_types {
            warnings.push(format!(
                "ignored {n} element(s) of type {ty} (line/point elements are not part of a volume mesh)"
            ));
        }
        if self.assembly_nodes_skipped > 0 {
            warnings.push(format!(
                "{} node/element line(s) defined in the assembly (reference points?) were skipped",
                self.assembly_nodes_skipped
            ));
        }
        if !self.assembly_sets_skipped.is_empty() {
            warnings.push(format!(
                "assembly-level set(s) of assembly nodes (no INSTANCE=) or of skipped instances were skipped: {}",
                self.assembly_sets_skipped.join(", ")
            ));
        }
        if !self.skipped.is_empty() {
            let names: Vec<&str> = self.skipped.iter().map(|(_, s)| s.as_str()).collect();
            warnings.push(format!("skipped keywords: {}", names.join(", ")));
        }
        warnings
    }
}

/// Reads the nodes, elements and sets of one mesh body: a whole file without parts, or one
/// part (with its instance's own lines) of an assembly.
struct Parser<'f> {
    files: &'f Files,
    nodes: Vec<Vector3<f64>>,
    node_ids: Vec<u64>,
    node_locs: Vec<Loc>,
    node_index: HashMap<u64, usize>,
    /// Shape of the first volume element, its id and line.
    shape: Option<(ElementShape, u64, Loc)>,
    vol_ids: Vec<u64>,
    vol_conn: Vec<u64>,
    vol_locs: Vec<Loc>,
    surf: Vec<SurfElem>,
    elem_index: HashMap<u64, (ElemRef, Loc)>,
    events: Vec<SetEvent>,
    notes: Notes,
    mode: Mode,
}

fn upper(s: &str) -> String {
    s.to_ascii_uppercase()
}

/// A keyword line with its data lines.
struct Block<'l, 'a> {
    kw: Keyword,
    loc: Loc,
    data: &'l [Line<'a>],
}

/// The keyword blocks of a list of lines, and the number of data lines before the first
/// keyword.
fn blocks<'l, 'a>(lines: &'l [Line<'a>]) -> (usize, Vec<Block<'l, 'a>>) {
    let mut out = Vec::new();
    let mut pre = 0;
    let mut i = 0;
    while let Some(l) = lines.get(i) {
        i += 1;
        if !l.keyword {
            pre += 1;
            continue;
        }
        let start = i;
        while lines.get(i).is_some_and(|d| !d.keyword) {
            i += 1;
        }
        out.push(Block {
            kw: parse_keyword(&l.text),
            loc: l.loc,
            data: lines.get(start..i).unwrap_or(&[]),
        });
    }
    (pre, out)
}

impl<'f> Parser<'f> {
    fn new(files: &'f Files) -> Self {
        Parser {
            files,
            nodes: Vec::new(),
            node_ids: Vec::new(),
            node_locs: Vec::new(),
            node_index: HashMap::new(),
            shape: None,
            vol_ids: Vec::new(),
            vol_conn: Vec::new(),
            vol_locs: Vec::new(),
            surf: Vec::new(),
            elem_index: HashMap::new(),
            events: Vec::new(),
            notes: Notes::default(),
            mode: Mode::Top,
        }
    }

    fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
        self.files.err(loc, msg)
    }

    fn run(&mut self, lines: &[Line]) -> Result<()> {
        let (pre, blocks) = blocks(lines);
        self.notes.pre_keyword_lines += pre;
        for b in &blocks {
            self.keyword(&b.kw, b.loc, b.data)?;
        }
        Ok(())
    }

    fn keyword(&mut self, kw: &Keyword, loc: Loc, data: &[Line]) -> Result<()> {
        if self.mode == Mode::Step {
            self.notes.skip_keyword(kw);
            if kw.name == "ENDSTEP" {
                self.mode = Mode::Top;
            }
            return Ok(());
        }
        match kw.name.as_str() {
            "HEADING" => {}
            "STEP" => {
                self.notes.skip_keyword(kw);
                self.mode = Mode::Step;
            }
            "NODE" => self.node_block(kw, data)?,
            "ELEMENT" => self.element_block(kw, loc, data)?,
            "NSET" | "ELSET" => {
                let key = if kw.name == "NSET" { "NSET" } else { "ELSET" };
                let name = kw.get(key).unwrap_or("").to_string();
                if name.is_empty() {
                    return Err(self.err(loc, format!("{} without {key}=<name>", kw.shown)));
                }
                self.set_block(kw, key == "NSET", name, loc, data)?;
            }
            "SURFACE" => {
                if let Some(name) = self.surface_name(kw, loc)? {
                    self.surface_block(name, data)?;
                }
            }
            _ => self.notes.skip_keyword(kw),
        }
        Ok(())
    }

    /// The name of an element-face *SURFACE, or None (with a warning) for other types.
    fn surface_name(&mut self, kw: &Keyword, loc: Loc) -> Result<Option<String>> {
        let name = kw.get("NAME").unwrap_or("").to_string();
        if name.is_empty() {
            return Err(self.err(loc, format!("{} without NAME=<name>", kw.shown)));
        }
        let ty = kw
            .get("TYPE")
            .map(upper)
            .unwrap_or_else(|| "ELEMENT".into());
        if ty != "ELEMENT" {
            self.notes.warnings.push(format!(
                "{}: surface '{name}' of TYPE={ty} is not a set of element faces; skipped",
                self.files.at(loc)
            ));
            return Ok(None);
        }
        Ok(Some(name))
    }

    // -- *NODE ---------------------------------------------------------------------------------

    fn node_block(&mut self, kw: &Keyword, data: &[Line]) -> Result<()> {
        if let Some(sys) = kw.get("SYSTEM") {
            if !sys.eq_ignore_ascii_case("R") {
                let loc = data.first().map(|l| l.loc);
                let msg = format!(
                    "*NODE with SYSTEM={sys} (cylindrical/spherical coordinates) is not supported; write Cartesian coordinates"
                );
                return Err(match loc {
                    Some(l) => self.err(l, msg),
                    None => Error::Input(msg),
                });
            }
        }
        let start = self.nodes.len();
        for l in data {
            let f = fields(&l.text);
            let id_field = f.first().copied().unwrap_or("");
            let id = parse_id(id_field, "node id").map_err(|m| self.err(l.loc, m))?;
            let coords = f.get(1..).unwrap_or(&[]);
            if coords.len() < 3 {
                return Err(self.err(
                    l.loc,
                    format!(
                        "node {id} has {} coordinate(s); hytled reads 3-D nodes 'id, x, y, z' (2-D models are not supported)",
                        coords.len()
                    ),
                ));
            }
            if coords.len() > 3 {
                self.notes.extra_node_fields += 1;
            }
            let mut x = [0.0; 3];
            for (k, c) in coords.iter().take(3).enumerate() {
                x[k] = parse_coord(c).map_err(|m| self.err(l.loc, format!("node {id}: {m}")))?;
            }
            if let Some(&first) = self.node_index.get(&id) {
                let prev = self.node_locs.get(first).copied().unwrap_or(l.loc);
                return Err(self.err(
                    l.loc,
                    format!(
                        "duplicate node id {id} (first defined at {}); node ids must be unique",
                        self.files.at(prev)
                    ),
                ));
            }
            self.node_index.insert(id, self.nodes.len());
            self.nodes.push(Vector3::new(x[0], x[1], x[2]));
            self.node_ids.push(id);
            self.node_locs.push(l.loc);
        }
        if let Some(name) = kw.get("NSET") {
            if !name.is_empty() {
                self.events.push(SetEvent::NodeBlock {
                    name: name.to_string(),
                    start,
                    end: self.nodes.len(),
                });
            }
        }
        Ok(())
    }

    // -- *ELEMENT ------------------------------------------------------------------------------

    fn element_block(&mut self, kw: &Keyword, loc: Loc, data: &[Line]) -> Result<()> {
        let Some(ty) = kw.get("TYPE") else {
            return Err(self.err(
                loc,
                format!("{} without TYPE= (hytled reads TYPE=C3D8*/C3D4*)", kw.shown),
            ));
        };
        let ty = upper(ty.trim());
        let kind = classify(&ty);
        let npe = match kind {
            ElemKind::Volume(s) => Some(s.nodes_per_cell()),
            ElemKind::Surface(n) => Some(n),
            ElemKind::Ignored(n) => n,
            ElemKind::Unsupported => {
                return Err(self.err(
                    loc,
                    format!(
                        "unsupported element type {ty} at line {} (hytled reads C3D8*/C3D4*; convert or re-mesh)",
                        loc.line
                    ),
                ))
            }
        };
        let elset = match kw.get("ELSET") {
            Some(e) if !e.is_empty() => Some(e.to_string()),
            _ => matches!(kind, ElemKind::Surface(_)).then(|| format!("TYPE_{ty}")),
        };
        let mut refs = Vec::new();
        let mut pend: Vec<&str> = Vec::new();
        let mut pend_loc = loc;
        for l in data {
            let cont = l.text.ends_with(',');
            if pend.is_empty() {
                pend_loc = l.loc;
            }
            pend.extend(fields(&l.text));
            let done = match npe {
                Some(n) => pend.len() > n || !cont,
                None => true,
            };
            if done && !pend.is_empty() {
                refs.push(self.element(&ty, kind, npe, &pend, pend_loc)?);
                pend.clear();
            }
        }
        if !pend.is_empty() {
            let id = pend.first().copied().unwrap_or("?");
            let found = pend.len().saturating_sub(1);
            let n = npe.unwrap_or(0);
            return Err(self.err(
                pend_loc,
                format!(
                    "element {id} is truncated: type {ty} expects {n} nodes, found {found} (its line ends with a comma but the element data ends there)"
                ),
            ));
        }
        if matches!(kind, ElemKind::Ignored(_)) {
            *self.notes.ignored_types.entry(ty.clone()).or_insert(0) += refs.len();
        }
        if let Some(name) = elset {
            self.events.push(SetEvent::ElemBlock { name, refs });
        }
        Ok(())
    }

    fn element(
        &mut self,
        ty: &str,
        kind: ElemKind,
        npe: Option<usize>,
        f: &[&str],
        loc: Loc,
    ) -> Result<ElemRef> {
        let id = parse_id(f.first().copied().unwrap_or(""), "element id")
            .map_err(|m| self.err(loc, m))?;
        let nodes = f.get(1..).unwrap_or(&[]);
        if let Some(n) = npe {
            if nodes.len() != n {
                return Err(self.err(
                    loc,
                    format!(
                        "element {id}: type {ty} expects {n} nodes, found {}",
                        nodes.len()
                    ),
                ));
            }
        }
        if let Some((_, prev)) = self.elem_index.get(&id) {
            return Err(self.err(
                loc,
                format!(
                    "duplicate element id {id} (first defined at {}); element ids must be unique",
                    self.files.at(*prev)
                ),
            ));
        }
        let r = match kind {
            ElemKind::Volume(s) => {
                match self.shape {
                    None => self.shape = Some((s, id, loc)),
                    Some((s0, id0, loc0)) if s0 != s => {
                        return Err(self.err(
                            loc,
                            format!(
                                "element {id} is {} ({ty}) but element {id0} at {} is {}; mixed hex/tet meshes are not supported (mesh with one element shape)",
                                shape_name(s),
                                self.files.at(loc0),
                                shape_name(s0)
                            ),
                        ))
                    }
                    Some(_) => {}
                }
                for n in nodes {
                    let nid = parse_id(n, "node id")
                        .map_err(|m| self.err(loc, format!("element {id}: {m}")))?;
                    self.vol_conn.push(nid);
                }
                self.vol_ids.push(id);
                self.vol_locs.push(loc);
                ElemRef::Vol(self.vol_ids.len() - 1)
            }
            ElemKind::Surface(_) => {
                let mut v = Vec::with_capacity(nodes.len());
                for n in nodes {
                    v.push(
                        parse_id(n, "node id")
                            .map_err(|m| self.err(loc, format!("element {id}: {m}")))?,
                    );
                }
                self.surf.push(SurfElem { id, nodes: v, loc });
                ElemRef::Face(self.surf.len() - 1)
            }
            ElemKind::Ignored(_) | ElemKind::Unsupported => ElemRef::Ignored,
        };
        self.elem_index.insert(id, (r, loc));
        Ok(r)
    }

    // -- *NSET / *ELSET ------------------------------------------------------------------------

    fn set_block(
        &mut self,
        kw: &Keyword,
        nodes: bool,
        name: String,
        loc: Loc,
        data: &[Line],
    ) -> Result<()> {
        let generate = kw.has("GENERATE");
        let what = if nodes { "node" } else { "element" };
        let mut items = Vec::new();
        for l in data {
            let f = fields(&l.text);
            if generate {
                if f.len() < 2 || f.len() > 3 {
                    return Err(self.err(
                        l.loc,
                        format!(
                            "{} GENERATE line expects 'start, end[, step]', found {} field(s)",
                            kw.shown,
                            f.len()
                        ),
                    ));
                }
                let mut v = [0u64, 0, 1];
                for (k, s) in f.iter().enumerate() {
                    let what = ["GENERATE start", "GENERATE end", "GENERATE step"];
                    if let (Some(slot), Some(what)) = (v.get_mut(k), what.get(k)) {
                        *slot = parse_id(s, what).map_err(|m| self.err(l.loc, m))?;
                    }
                }
                if v[0] > v[1] {
                    return Err(self.err(
                        l.loc,
                        format!("{} GENERATE start {} is after end {}", kw.shown, v[0], v[1]),
                    ));
                }
                items.push((Item::Gen(v[0], v[1], v[2]), l.loc));
            } else {
                for s in f {
                    if s.is_empty() {
                        continue;
                    }
                    let numeric = s
                        .chars()
                        .next()
                        .is_some_and(|c| c.is_ascii_digit() || matches!(c, '+' | '-' | '.'));
                    if numeric {
                        let id = parse_id(s, &format!("{what} id"))
                            .map_err(|m| self.err(l.loc, format!("{} {name}: {m}", kw.shown)))?;
                        items.push((Item::Id(id), l.loc));
                    } else {
                        items.push((Item::Name(s.to_string()), l.loc));
                    }
                }
            }
        }
        if nodes {
            let elset = kw
                .get("ELSET")
                .filter(|e| !e.is_empty())
                .map(str::to_string);
            self.events.push(SetEvent::Nset {
                name,
                loc,
                items,
                elset,
            });
        } else {
            self.events.push(SetEvent::Elset { name, items });
        }
        Ok(())
    }

    // -- *SURFACE ------------------------------------------------------------------------------

    fn surface_block(&mut self, name: String, data: &[Line]) -> Result<()> {
        let mut entries = Vec::new();
        for l in data {
            let f = fields(&l.text);
            let Some(&t) = f.first() else { continue };
            if t.is_empty() {
                return Err(self.err(
                    l.loc,
                    format!("*SURFACE {name}: empty element or set field"),
                ));
            }
            let target = if t.chars().next().is_some_and(|c| c.is_ascii_digit()) {
                Target::Id(
                    parse_id(t, "element id")
                        .map_err(|m| self.err(l.loc, format!("*SURFACE {name}: {m}")))?,
                )
            } else {
                Target::Name(t.to_string())
            };
            let label = match f.get(1).map(|s| upper(s)) {
                None => None,
                Some(s) if s.is_empty() => None,
                Some(s) if s == "SPOS" => Some(Label::Pos),
                Some(s) if s == "SNEG" => Some(Label::Neg),
                Some(s) => match s.strip_prefix('S').and_then(|k| k.parse::<usize>().ok()) {
                    Some(k) if (1..=6).contains(&k) => Some(Label::S(k - 1)),
                    _ => {
                        return Err(self.err(
                            l.loc,
                            format!(
                                "*SURFACE {name}: unsupported face label '{s}' (use S1..S6 for C3D8, S1..S4 for C3D4, SPOS/SNEG for surface elements)"
                            ),
                        ))
                    }
                },
            };
            entries.push((target, label, l.loc));
        }
        self.events.push(SetEvent::Surface { name, entries });
        Ok(())
    }

    // -- Resolution ----------------------------------------------------------------------------

    /// Resolves node references and set definitions: the body's mesh (cells empty and a
    /// placeholder shape when it has no volume elements), ids and sets by upper-case name.
    fn resolve(self) -> Result<(Body, Notes)> {
        let files = self.files;
        let shape = self.shape.map(|s| s.0);
        let npe = shape.map_or(8, |s| s.nodes_per_cell());
        let lookup_node = |nid: u64, eid: u64, loc: Loc| -> Result<usize> {
            self.node_index.get(&nid).copied().ok_or_else(|| {
                files.err(
                    loc,
                    format!("element {eid} references node {nid}, which no *NODE line defines"),
                )
            })
        };
        let mut cells = Vec::with_capacity(self.vol_conn.len());
        for ((chunk, &eid), &loc) in self
            .vol_conn
            .chunks(npe)
            .zip(&self.vol_ids)
            .zip(&self.vol_locs)
        {
            for &nid in chunk {
                cells.push(lookup_node(nid, eid, loc)?);
            }
        }
        let mut faces: Vec<Vec<usize>> = Vec::with_capacity(self.surf.len());
        for s in &self.surf {
            let mut f = Vec::with_capacity(s.nodes.len());
            for &nid in &s.nodes {
                f.push(lookup_node(nid, s.id, s.loc)?);
            }
            faces.push(f);
        }
        let mesh = Mesh {
            nodes: self.nodes,
            shape: shape.unwrap_or(ElementShape::Hex8),
            cells,
        };
        let mut r = Resolver::new(files, &self.node_index, &self.elem_index, &mesh, &faces);
        for ev in &self.events {
            r.event(ev)?;
        }
        let (nsets, elsets, surfaces) = (r.nsets, r.elsets, r.surfaces);
        Ok((
            Body {
                mesh,
                shape,
                node_ids: self.node_ids,
                node_index: self.node_index,
                vol_ids: self.vol_ids,
                elem_index: self.elem_index,
                faces,
                nsets,
                elsets,
                surfaces,
            },
            self.notes,
        ))
    }

    fn finish(self) -> Result<MeshInput> {
        if self.shape.is_none() {
            return Err(Error::Input(format!(
                "{}: no volume elements (C3D8*/C3D4*) found; hytled needs a hexahedral or tetrahedral volume mesh",
                self.files.name(0)
            )));
        }
        let (body, notes) = self.resolve()?;
        let ids = body.vol_ids.clone();
        Ok(build_input(body, notes, |e| {
            format!("element {}", ids.get(e).copied().unwrap_or(0))
        }))
    }
}

/// A mesh body with its sets, resolved.
struct Body {
    mesh: Mesh,
    shape: Option<ElementShape>,
    node_ids: Vec<u64>,
    node_index: HashMap<u64, usize>,
    vol_ids: Vec<u64>,
    elem_index: HashMap<u64, (ElemRef, Loc)>,
    faces: Vec<Vec<usize>>,
    nsets: HashMap<String, (String, Vec<usize>)>,
    elsets: HashMap<String, ElsetAcc>,
    surfaces: HashMap<String, (String, Vec<Vec<usize>>)>,
}

/// The [`MeshInput`] of a resolved body: sets by their names, the notes as warnings, and the
/// unused-node and inverted-element checks (`label` names an element by its index).
fn build_input(body: Body, notes: Notes, label: impl Fn(usize) -> String) -> MeshInput {
    let Body {
        mesh,
        node_ids,
        vol_ids,
        faces,
        nsets,
        elsets,
        surfaces,
        ..
    } = body;
    let mut node_sets = BTreeMap::new();
    for (_, (name, mut v)) in nsets {
        v.sort_unstable();
        v.dedup();
        node_sets.insert(name, v);
    }
    let mut element_sets = BTreeMap::new();
    let mut face_acc: HashMap<String, (String, Vec<Vec<usize>>)> = HashMap::new();
    for (key, acc) in elsets {
        if !acc.vol.is_empty() || (acc.faces.is_empty() && !acc.ignored) {
            let mut v = acc.vol;
            v.sort_unstable();
            v.dedup();
            element_sets.insert(acc.name.clone(), v);
        }
        if !acc.faces.is_empty() {
            let mut seen = HashSet::new();
            let fs: Vec<Vec<usize>> = acc
                .faces
                .iter()
                .filter(|&&i| seen.insert(i))
                .filter_map(|&i| faces.get(i).cloned())
                .collect();
            face_acc.insert(key, (acc.name, fs));
        }
    }
    for (key, (name, fs)) in surfaces {
        face_acc
            .entry(key)
            .or_insert_with(|| (name, Vec::new()))
            .1
            .extend(fs);
    }
    let face_sets: BTreeMap<String, Vec<Vec<usize>>> = face_acc.into_values().collect();

    let mut warnings = notes.into_warnings();
    let mut used = vec![false; mesh.nodes.len()];
    for &c in &mesh.cells {
        if let Some(u) = used.get_mut(c) {
            *u = true;
        }
    }
    let unused = used.iter().filter(|u| !**u).count();
    if unused > 0 {
        warnings.push(format!(
            "{unused} node(s) are used by no volume element (kept)"
        ));
    }
    let shape = mesh.shape;
    let mut inverted = 0usize;
    let mut first_inverted = None;
    for e in 0..vol_ids.len().min(mesh.num_cells()) {
        let c = mesh.cell(e);
        let corner = match shape {
            ElementShape::Tet4 => [c[0], c[1], c[2], c[3]],
            ElementShape::Hex8 => [c[0], c[1], c[3], c[4]],
        };
        let p = corner.map(|i| mesh.nodes.get(i).copied().unwrap_or_default());
        if tet_signed_volume(&p[0], &p[1], &p[2], &p[3]) <= 0.0 {
            inverted += 1;
            first_inverted.get_or_insert(e);
        }
    }
    if let Some(e) = first_inverted {
        warnings.push(format!(
            "{inverted} element(s) have non-positive volume at their first corner (first: {}); check their node order",
            label(e)
        ));
    }

    MeshInput {
        mesh,
        node_ids,
        element_ids: vol_ids,
        node_sets,
        element_sets,
        face_sets,
        warnings,
    }
}

// ---------------------------------------------------------------------------------------------
// Parts, instances and the assembly
// ---------------------------------------------------------------------------------------------

/// Whether the file uses parts and an assembly.
fn has_parts(lines: &[Line]) -> bool {
    lines.iter().any(|l| {
        l.keyword
            && matches!(
                parse_keyword(&l.text).name.as_str(),
                "PART" | "ASSEMBLY" | "INSTANCE"
            )
    })
}

struct PartDef<'l, 'a> {
    name: String,
    loc: Loc,
    body: Vec<Block<'l, 'a>>,
}

struct InstanceDef<'l, 'a> {
    name: String,
    part: String,
    loc: Loc,
    /// The positioning lines (translation, rotation).
    place: &'l [Line<'a>],
    /// Keywords between *Instance and *End Instance (reference points, sets).
    body: Vec<Block<'l, 'a>>,
}

/// Where the keyword blocks of an assembly file go.
#[derive(Clone, Copy)]
enum Region {
    Top,
    Part(usize),
    Assembly,
    Instance(usize),
    Step,
}

/// An instance's placement: translation, then rotation about the axis through points a and b
/// by an angle in degrees (right-hand rule about a -> b), as ABAQUS applies them.
struct Placement {
    translation: Vector3<f64>,
    rotation: Option<(Vector3<f64>, nalgebra::Rotation3<f64>)>,
}

impl Placement {
    fn parse(inst: &InstanceDef, files: &Files) -> Result<Placement> {
        let what = format!("*Instance {}", inst.name);
        let numbers = |l: &Line, n: usize, meaning: &str| -> Result<Vec<f64>> {
            let f = fields(&l.text);
            if f.len() > n {
                return Err(files.err(
                    l.loc,
                    format!(
                        "{what}: {} fields on the {meaning} line; it has {n}",
                        f.len()
                    ),
                ));
            }
            let mut v = vec![0.0; n];
            for (k, s) in f.iter().enumerate() {
                if !s.is_empty() {
                    v[k] = parse_coord(s)
                        .map_err(|m| files.err(l.loc, format!("{what} {meaning} line: {m}")))?;
                }
            }
            Ok(v)
        };
        let mut p = Placement {
            translation: Vector3::zeros(),
            rotation: None,
        };
        if let Some(l) = inst.place.first() {
            let t = numbers(l, 3, "translation (dx, dy, dz)")?;
            p.translation = Vector3::new(t[0], t[1], t[2]);
        }
        if let Some(l) = inst.place.get(1) {
            let r = numbers(l, 7, "rotation (xa, ya, za, xb, yb, zb, angle)")?;
            let a = Vector3::new(r[0], r[1], r[2]);
            let b = Vector3::new(r[3], r[4], r[5]);
            if r[6] != 0.0 {
                let axis = nalgebra::Unit::try_new(b - a, 0.0).ok_or_else(|| {
                    files.err(
                        l.loc,
                        format!("{what}: the rotation axis points a and b coincide"),
                    )
                })?;
                p.rotation = Some((
                    a,
                    nalgebra::Rotation3::from_axis_angle(&axis, r[6].to_radians()),
                ));
            }
        }
        if let Some(l) = inst.place.get(2) {
            return Err(files.err(
                l.loc,
                format!(
                    "{what}: more than two positioning lines (translation, rotation); hytled reads those two"
                ),
            ));
        }
        Ok(p)
    }

    fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        let y = x + self.translation;
        match &self.rotation {
            Some((a, r)) => a + r * (y - a),
            None => y,
        }
    }
}

/// Adds "[instance 'I' of part 'P']" to an input error.
fn in_instance(e: Error, inst: &InstanceDef) -> Error {
    match e {
        Error::Input(m) => Error::Input(format!(
            "{m} [instance '{}' of part '{}']",
            inst.name, inst.part
        )),
        other => other,
    }
}

/// Node and element ids of one instance read, with their positions in the merged mesh.
struct InstanceMaps {
    node_index: HashMap<u64, usize>,
    elem_index: HashMap<u64, (ElemRef, Loc)>,
}

/// Reads a file with `*Part`s and an `*Assembly`: every instance is a copy of its part's
/// nodes, elements and sets, placed by its translation/rotation lines; see the module docs.
fn parse_assembly(lines: &[Line], files: &Files) -> Result<MeshInput> {
    let (pre, all) = blocks(lines);
    let mut top: Vec<Block> = Vec::new();
    let mut parts: Vec<PartDef> = Vec::new();
    let mut instances: Vec<InstanceDef> = Vec::new();
    let mut assembly: Vec<Block> = Vec::new();
    let mut region = Region::Top;
    for b in all {
        match (region, b.kw.name.as_str()) {
            (Region::Step, "ENDSTEP") => {
                top.push(b);
                region = Region::Top;
            }
            (Region::Step, _) => top.push(b),
            (_, "STEP") => {
                top.push(b);
                region = Region::Step;
            }
            (_, "PART") => {
                if let Region::Part(i) = region {
                    return Err(files.err(
                        b.loc,
                        format!(
                            "{} inside part '{}' (line {}): its *End Part is missing",
                            b.kw.shown, parts[i].name, parts[i].loc.line
                        ),
                    ));
                }
                let name = b.kw.get("NAME").unwrap_or("").to_string();
                if name.is_empty() {
                    return Err(files.err(b.loc, format!("{} without NAME=<name>", b.kw.shown)));
                }
                if let Some(p) = parts.iter().find(|p| p.name.eq_ignore_ascii_case(&name)) {
                    return Err(files.err(
                        b.loc,
                        format!(
                            "part '{name}' is defined twice (first at {})",
                            files.at(p.loc)
                        ),
                    ));
                }
                parts.push(PartDef {
                    name,
                    loc: b.loc,
                    body: Vec::new(),
                });
                region = Region::Part(parts.len() - 1);
            }
            (_, "ENDPART") | (_, "ENDASSEMBLY") => region = Region::Top,
            (_, "ASSEMBLY") | (_, "ENDINSTANCE") => region = Region::Assembly,
            (_, "INSTANCE") => {
                let name = b.kw.get("NAME").unwrap_or("").to_string();
                if name.is_empty() {
                    return Err(files.err(b.loc, format!("{} without NAME=<name>", b.kw.shown)));
                }
                if let Some(i) = instances
                    .iter()
                    .find(|i| i.name.eq_ignore_ascii_case(&name))
                {
                    return Err(files.err(
                        b.loc,
                        format!(
                            "instance '{name}' is defined twice (first at {})",
                            files.at(i.loc)
                        ),
                    ));
                }
                instances.push(InstanceDef {
                    name,
                    part: b.kw.get("PART").unwrap_or("").to_string(),
                    loc: b.loc,
                    place: b.data,
                    body: Vec::new(),
                });
                region = Region::Instance(instances.len() - 1);
            }
            (Region::Part(i), _) => parts[i].body.push(b),
            (Region::Instance(i), _) => instances[i].body.push(b),
            (Region::Assembly, _) => assembly.push(b),
            (Region::Top, _) => top.push(b),
        }
    }

    let mut notes = Notes {
        pre_keyword_lines: pre,
        ..Notes::default()
    };
    // Bodies to merge: mesh data outside parts (plain set names), then every instance.
    let mut bodies: Vec<(Option<&InstanceDef>, Body)> = Vec::new();
    let mut p = Parser::new(files);
    for b in &top {
        p.keyword(&b.kw, b.loc, b.data)?;
    }
    if !p.nodes.is_empty() || !p.vol_ids.is_empty() || !p.surf.is_empty() {
        let (body, n) = p.resolve()?;
        notes.absorb(n);
        bodies.push((None, body));
    } else {
        notes.absorb(p.notes);
    }
    for inst in &instances {
        let part = parts
            .iter()
            .find(|p| p.name.eq_ignore_ascii_case(&inst.part));
        let own_nodes = inst.body.iter().any(|b| b.kw.name == "NODE");
        if part.is_none() && !own_nodes {
            return Err(files.err(
                inst.loc,
                format!(
                    "*Instance {}: part '{}' is not defined (no *Part, name={} before the assembly)",
                    inst.name, inst.part, inst.part
                ),
            ));
        }
        let mut p = Parser::new(files);
        for b in part
            .map_or(&[][..], |p| &p.body[..])
            .iter()
            .chain(&inst.body)
        {
            p.keyword(&b.kw, b.loc, b.data)
                .map_err(|e| in_instance(e, inst))?;
        }
        let (mut body, n) = p.resolve().map_err(|e| in_instance(e, inst))?;
        notes.absorb(n);
        let place = Placement::parse(inst, files)?;
        for (k, x) in body.mesh.nodes.iter_mut().enumerate() {
            *x = place.apply(x);
            if !x.iter().all(|v| v.is_finite()) {
                return Err(files.err(
                    inst.loc,
                    format!(
                        "*Instance {}: node {} is not finite after the translation/rotation",
                        inst.name,
                        body.node_ids.get(k).copied().unwrap_or(0)
                    ),
                ));
            }
        }
        bodies.push((Some(inst), body));
    }

    // Merge the bodies of the first shape read.
    let mut shape: Option<(ElementShape, String)> = None;
    let mut skipped: HashSet<String> = HashSet::new();
    let mut nodes = Vec::new();
    let mut node_ids = Vec::new();
    let mut cells = Vec::new();
    let mut vol_ids = Vec::new();
    let mut faces: Vec<Vec<usize>> = Vec::new();
    let mut nsets: HashMap<String, (String, Vec<usize>)> = HashMap::new();
    let mut elsets: HashMap<String, ElsetAcc> = HashMap::new();
    let mut surfaces: HashMap<String, (String, Vec<Vec<usize>>)> = HashMap::new();
    let mut maps: HashMap<String, InstanceMaps> = HashMap::new();
    // Part-level set names (kind, upper-case name) -> (qualified key, name) for each instance.
    let mut local: BTreeMap<(u8, String), Vec<(String, String)>> = BTreeMap::new();
    // Element index ranges of the instances, for messages.
    let mut ranges: Vec<(usize, usize, String)> = Vec::new();
    let mut listing: Vec<String> = Vec::new();
    for (inst, body) in bodies {
        let who = inst.map_or_else(
            || "mesh data outside *Part".to_string(),
            |i| format!("instance '{}' (part '{}')", i.name, i.part),
        );
        match (body.shape, &shape) {
            (None, _) => {
                notes.warnings.push(format!(
                    "{who} has no volume elements (C3D8*/C3D4*); skipped"
                ));
                if let Some(i) = inst {
                    skipped.insert(upper(&i.name));
                }
                continue;
            }
            (Some(s), Some((s0, first))) if s != *s0 => {
                notes.warnings.push(format!(
                    "{who} is {} but {first} is {}; hytled reads one element shape, so it was skipped",
                    shape_name(s),
                    shape_name(*s0)
                ));
                if let Some(i) = inst {
                    skipped.insert(upper(&i.name));
                }
                continue;
            }
            (Some(s), None) => shape = Some((s, who.clone())),
            _ => {}
        }
        let (no, co, fo) = (nodes.len(), vol_ids.len(), faces.len());
        let shift = |r: ElemRef| match r {
            ElemRef::Vol(i) => ElemRef::Vol(i + co),
            ElemRef::Face(i) => ElemRef::Face(i + fo),
            ElemRef::Ignored => ElemRef::Ignored,
        };
        nodes.extend_from_slice(&body.mesh.nodes);
        node_ids.extend_from_slice(&body.node_ids);
        cells.extend(body.mesh.cells.iter().map(|&c| c + no));
        vol_ids.extend_from_slice(&body.vol_ids);
        faces.extend(
            body.faces
                .iter()
                .map(|f| f.iter().map(|&i| i + no).collect::<Vec<usize>>()),
        );
        let (prefix, shown) = match inst {
            Some(i) => (format!("{}.", upper(&i.name)), format!("{}.", i.name)),
            None => (String::new(), String::new()),
        };
        for (key, (name, v)) in body.nsets {
            let q = format!("{prefix}{key}");
            if inst.is_some() {
                local
                    .entry((0, key))
                    .or_default()
                    .push((q.clone(), name.clone()));
            }
            nsets.insert(
                q,
                (
                    format!("{shown}{name}"),
                    v.iter().map(|&i| i + no).collect(),
                ),
            );
        }
        for (key, acc) in body.elsets {
            let q = format!("{prefix}{key}");
            if inst.is_some() {
                local
                    .entry((1, key))
                    .or_default()
                    .push((q.clone(), acc.name.clone()));
            }
            elsets.insert(
                q,
                ElsetAcc {
                    name: format!("{shown}{}", acc.name),
                    vol: acc.vol.iter().map(|&i| i + co).collect(),
                    faces: acc.faces.iter().map(|&i| i + fo).collect(),
                    ignored: acc.ignored,
                },
            );
        }
        for (key, (name, fs)) in body.surfaces {
            let q = format!("{prefix}{key}");
            if inst.is_some() {
                local
                    .entry((2, key))
                    .or_default()
                    .push((q.clone(), name.clone()));
            }
            let fs = fs
                .iter()
                .map(|f| f.iter().map(|&i| i + no).collect())
                .collect();
            surfaces.insert(q, (format!("{shown}{name}"), fs));
        }
        let name = inst.map_or_else(String::new, |i| i.name.clone());
        listing.push(format!(
            "{who}: nodes {no}..{}, elements {co}..{}",
            nodes.len(),
            vol_ids.len()
        ));
        ranges.push((co, vol_ids.len(), name.clone()));
        if let Some(i) = inst {
            maps.insert(
                upper(&i.name),
                InstanceMaps {
                    node_index: body.node_index.iter().map(|(&k, &v)| (k, v + no)).collect(),
                    elem_index: body
                        .elem_index
                        .iter()
                        .map(|(&k, &(r, l))| (k, (shift(r), l)))
                        .collect(),
                },
            );
        }
    }
    let Some((shape, _)) = shape else {
        return Err(Error::Input(format!(
            "{}: no volume elements (C3D8*/C3D4*) found in any part instance; hytled needs a hexahedral or tetrahedral volume mesh",
            files.name(0)
        )));
    };
    let mesh = Mesh {
        nodes,
        shape,
        cells,
    };

    // Assembly-level sets and surfaces, in file order.
    let empty_nodes = HashMap::new();
    let empty_elems = HashMap::new();
    let single = (maps.len() == 1).then(|| maps.values().next()).flatten();
    let mut asm = Parser::new(files);
    for b in &assembly {
        let kw = &b.kw;
        let (instance, event) = match kw.name.as_str() {
            "NODE" | "ELEMENT" => {
                notes.assembly_nodes_skipped += b.data.len();
                continue;
            }
            "NSET" | "ELSET" => {
                let key = if kw.name == "NSET" { "NSET" } else { "ELSET" };
                let name = kw.get(key).unwrap_or("").to_string();
                if name.is_empty() {
                    return Err(files.err(b.loc, format!("{} without {key}=<name>", kw.shown)));
                }
                let instance = match kw.get("INSTANCE") {
                    Some(i) if skipped.contains(&upper(i)) => {
                        notes
                            .assembly_sets_skipped
                            .push(format!("{name} (instance {i})"));
                        continue;
                    }
                    Some(i) if !maps.contains_key(&upper(i)) => {
                        return Err(files.err(
                            b.loc,
                            format!(
                                "{} {name}: INSTANCE={i} is not an instance of the assembly",
                                kw.shown
                            ),
                        ))
                    }
                    Some(i) => Some(i.to_string()),
                    None => None,
                };
                asm.set_block(kw, key == "NSET", name.clone(), b.loc, b.data)?;
                let Some(ev) = asm.events.pop() else { continue };
                let ids = match &ev {
                    SetEvent::Nset { items, .. } | SetEvent::Elset { items, .. } => items
                        .iter()
                        .any(|(it, _)| matches!(it, Item::Id(_) | Item::Gen(..))),
                    _ => false,
                };
                if instance.is_none() && ids {
                    // Ids without INSTANCE= are assembly nodes/elements (reference points).
                    notes.assembly_sets_skipped.push(name);
                    continue;
                }
                (instance, ev)
            }
            "SURFACE" => {
                let Some(name) = asm.surface_name(kw, b.loc)? else {
                    continue;
                };
                asm.surface_block(name, b.data)?;
                let Some(ev) = asm.events.pop() else { continue };
                (None, ev)
            }
            _ => {
                asm.notes.skip_keyword(kw);
                continue;
            }
        };
        let (node_index, elem_index) = match (&instance, single) {
            (Some(i), _) => match maps.get(&upper(i)) {
                Some(m) => (&m.node_index, &m.elem_index),
                None => (&empty_nodes, &empty_elems),
            },
            // A surface listing element ids with a single instance: that instance's ids.
            (None, Some(m)) => (&m.node_index, &m.elem_index),
            (None, None) => (&empty_nodes, &empty_elems),
        };
        let mut r = Resolver::new(files, node_index, elem_index, &mesh, &faces);
        r.nsets = std::mem::take(&mut nsets);
        r.elsets = std::mem::take(&mut elsets);
        r.surfaces = std::mem::take(&mut surfaces);
        if let Some(i) = &instance {
            r.prefix = Some(upper(i));
            r.ctx = format!(" (in instance '{i}')");
        }
        let res = r.event(&event);
        nsets = r.nsets;
        elsets = r.elsets;
        surfaces = r.surfaces;
        res?;
    }
    notes.absorb(asm.notes);

    // Plain names for part-level sets that only one instance has and the assembly does not
    // define (so single-instance models keep the names of their part).
    for ((kind, key), defs) in local {
        let [(q, name)] = &defs[..] else { continue };
        match kind {
            0 if !nsets.contains_key(&key) => {
                if let Some((_, v)) = nsets.get(q).cloned() {
                    nsets.insert(key, (name.clone(), v));
                }
            }
            1 if !elsets.contains_key(&key) => {
                if let Some(mut acc) = elsets.get(q).cloned() {
                    acc.name = name.clone();
                    elsets.insert(key, acc);
                }
            }
            2 if !surfaces.contains_key(&key) => {
                if let Some((_, f)) = surfaces.get(q).cloned() {
                    surfaces.insert(key, (name.clone(), f));
                }
            }
            _ => {}
        }
    }
    if listing.len() > 1 {
        notes.warnings.push(format!(
            "{} part instances read (node ids repeat across instances; positions in the mesh): {}",
            listing.len(),
            listing.join("; ")
        ));
    }

    let body = Body {
        mesh,
        shape: Some(shape),
        node_ids,
        node_index: HashMap::new(),
        vol_ids,
        elem_index: HashMap::new(),
        faces,
        nsets,
        elsets,
        surfaces,
    };
    let ids = body.vol_ids.clone();
    Ok(build_input(body, notes, |e| {
        let id = ids.get(e).copied().unwrap_or(0);
        match ranges.iter().find(|(a, b, _)| (*a..*b).contains(&e)) {
            Some((_, _, n)) if !n.is_empty() => format!("element {id} of instance '{n}'"),
            _ => format!("element {id}"),
        }
    }))
}

/// An element set being resolved: volume cells, surface elements, and whether it listed
/// ignored (line/point) elements.
#[derive(Default, Clone)]
struct ElsetAcc {
    name: String,
    vol: Vec<usize>,
    faces: Vec<usize>,
    ignored: bool,
}

struct Resolver<'a> {
    files: &'a Files,
    node_index: &'a HashMap<u64, usize>,
    elem_index: &'a HashMap<u64, (ElemRef, Loc)>,
    mesh: &'a Mesh,
    faces: &'a [Vec<usize>],
    /// Keyed by upper-case name: (name as first written, node indices).
    nsets: HashMap<String, (String, Vec<usize>)>,
    elsets: HashMap<String, ElsetAcc>,
    surfaces: HashMap<String, (String, Vec<Vec<usize>>)>,
    /// Upper-case instance name whose sets are looked up first (assembly sets with INSTANCE=).
    prefix: Option<String>,
    /// Added to error messages (the instance).
    ctx: String,
}

/// Finds a set by name, case-insensitively, also as `instance.name`.
fn find<'m, T>(map: &'m HashMap<String, T>, name: &str) -> Option<&'m T> {
    let key = upper(name);
    map.get(&key)
        .or_else(|| key.rsplit_once('.').and_then(|(_, short)| map.get(short)))
}

impl<'a> Resolver<'a> {
    fn new(
        files: &'a Files,
        node_index: &'a HashMap<u64, usize>,
        elem_index: &'a HashMap<u64, (ElemRef, Loc)>,
        mesh: &'a Mesh,
        faces: &'a [Vec<usize>],
    ) -> Self {
        Resolver {
            files,
            node_index,
            elem_index,
            mesh,
            faces,
            nsets: HashMap::new(),
            elsets: HashMap::new(),
            surfaces: HashMap::new(),
            prefix: None,
            ctx: String::new(),
        }
    }

    fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
        self.files.err(loc, format!("{msg}{}", self.ctx))
    }

    /// A set by name: first as a set of the instance in `prefix`, then as [`find`] does.
    fn lookup<'m, T>(&self, map: &'m HashMap<String, T>, name: &str) -> Option<&'m T> {
        self.prefix
            .as_ref()
            .and_then(|p| map.get(&format!("{p}.{}", upper(name))))
            .or_else(|| find(map, name))
    }

    fn elset_entry(&mut self, name: &str) -> &mut ElsetAcc {
        self.elsets.entry(upper(name)).or_insert_with(|| ElsetAcc {
            name: name.to_string(),
            ..Default::default()
        })
    }

    fn node(&self, id: u64, set: &str, loc: Loc) -> Result<usize> {
        self.node_index
            .get(&id)
            .copied()
            .ok_or_else(|| self.err(loc, format!("*NSET {set}: node {id} is not defined")))
    }

    fn elem(&self, id: u64, what: &str, loc: Loc) -> Result<ElemRef> {
        self.elem_index
            .get(&id)
            .map(|(r, _)| *r)
            .ok_or_else(|| self.err(loc, format!("{what}: element {id} is not defined")))
    }

    fn event(&mut self, ev: &SetEvent) -> Result<()> {
        match ev {
            SetEvent::NodeBlock { name, start, end } => {
                let e = self
                    .nsets
                    .entry(upper(name))
                    .or_insert_with(|| (name.clone(), Vec::new()));
                e.1.extend(*start..*end);
            }
            SetEvent::ElemBlock { name, refs } => {
                let acc = self.elset_entry(name);
                for r in refs {
                    add_ref(acc, *r);
                }
            }
            SetEvent::Nset {
                name,
                loc,
                items,
                elset,
            } => {
                let mut v = Vec::new();
                for (item, iloc) in items {
                    match item {
                        Item::Id(id) => v.push(self.node(*id, name, *iloc)?),
                        Item::Gen(a, b, s) => {
                            let mut k = *a;
                            while k <= *b {
                                v.push(self.node(k, name, *iloc)?);
                                match k.checked_add(*s) {
                                    Some(n) => k = n,
                                    None => break,
                                }
                            }
                        }
                        Item::Name(other) => match self.lookup(&self.nsets, other) {
                            Some((_, nodes)) => v.extend(sorted_unique(nodes)),
                            None => {
                                return Err(self.err(
                                    *iloc,
                                    format!(
                                        "*NSET {name}: '{other}' is neither a node id nor a node set defined above"
                                    ),
                                ))
                            }
                        },
                    }
                }
                if let Some(es) = elset {
                    let Some(acc) = self.lookup(&self.elsets, es) else {
                        return Err(self.err(
                            *loc,
                            format!("*NSET {name}: ELSET={es} is not an element set defined above"),
                        ));
                    };
                    let acc = acc.deduped();
                    for &c in &acc.vol {
                        if c < self.mesh.num_cells() {
                            v.extend_from_slice(self.mesh.cell(c));
                        }
                    }
                    for &f in &acc.faces {
                        if let Some(face) = self.faces.get(f) {
                            v.extend_from_slice(face);
                        }
                    }
                }
                let e = self
                    .nsets
                    .entry(upper(name))
                    .or_insert_with(|| (name.clone(), Vec::new()));
                e.1.extend(v);
            }
            SetEvent::Elset { name, items } => {
                let mut add = ElsetAcc::default();
                let what = format!("*ELSET {name}");
                for (item, iloc) in items {
                    match item {
                        Item::Id(id) => add_ref(&mut add, self.elem(*id, &what, *iloc)?),
                        Item::Gen(a, b, s) => {
                            let mut k = *a;
                            while k <= *b {
                                add_ref(&mut add, self.elem(k, &what, *iloc)?);
                                match k.checked_add(*s) {
                                    Some(n) => k = n,
                                    None => break,
                                }
                            }
                        }
                        Item::Name(other) => match self.lookup(&self.elsets, other) {
                            Some(o) => {
                                let o = o.deduped();
                                add.vol.extend(o.vol);
                                add.faces.extend(o.faces);
                                add.ignored |= o.ignored;
                            }
                            None => {
                                return Err(self.err(
                                    *iloc,
                                    format!(
                                        "{what}: '{other}' is neither an element id nor an element set defined above"
                                    ),
                                ))
                            }
                        },
                    }
                }
                let acc = self.elset_entry(name);
                acc.vol.extend(add.vol);
                acc.faces.extend(add.faces);
                acc.ignored |= add.ignored;
            }
            SetEvent::Surface { name, entries } => {
                let mut out: Vec<Vec<usize>> = Vec::new();
                for (target, label, loc) in entries {
                    let members: ElsetAcc = match target {
                        Target::Id(id) => {
                            let mut a = ElsetAcc::default();
                            add_ref(&mut a, self.elem(*id, &format!("*SURFACE {name}"), *loc)?);
                            a
                        }
                        Target::Name(set) => match self.lookup(&self.elsets, set) {
                            Some(a) => a.deduped(),
                            None => {
                                return Err(self.err(
                                    *loc,
                                    format!(
                                    "*SURFACE {name}: '{set}' is not an element set defined above"
                                ),
                                ))
                            }
                        },
                    };
                    self.surface_faces(name, &members, *label, *loc, &mut out)?;
                }
                let e = self
                    .surfaces
                    .entry(upper(name))
                    .or_insert_with(|| (name.clone(), Vec::new()));
                e.1.extend(out);
            }
        }
        Ok(())
    }

    fn surface_faces(
        &self,
        name: &str,
        members: &ElsetAcc,
        label: Option<Label>,
        loc: Loc,
        out: &mut Vec<Vec<usize>>,
    ) -> Result<()> {
        let shape = self.mesh.shape;
        let ncells = self.mesh.num_cells();
        let cells: Vec<usize> = members
            .vol
            .iter()
            .copied()
            .filter(|&c| c < ncells)
            .collect();
        match label {
            Some(Label::S(k)) => {
                if !members.faces.is_empty() {
                    return Err(self.err(
                        loc,
                        format!(
                            "*SURFACE {name}: face label S{} given for surface (CPS/S/R3D/M3D) elements; use SPOS/SNEG or no label",
                            k + 1
                        ),
                    ));
                }
                let Some(local) = element_face(shape, k) else {
                    return Err(self.err(
                        loc,
                        format!(
                            "*SURFACE {name}: face S{} does not exist on {} elements (S1..S{})",
                            k + 1,
                            shape_name(shape),
                            num_faces(shape)
                        ),
                    ));
                };
                for c in cells {
                    let cell = self.mesh.cell(c);
                    out.push(local.iter().filter_map(|&i| cell.get(i).copied()).collect());
                }
            }
            Some(Label::Pos) | Some(Label::Neg) => {
                if !cells.is_empty() {
                    return Err(self.err(
                        loc,
                        format!(
                            "*SURFACE {name}: SPOS/SNEG apply to surface elements; use S1..S{} for {} elements",
                            num_faces(shape),
                            shape_name(shape)
                        ),
                    ));
                }
            }
            None => {
                // Free faces of the listed volume elements.
                let mut count: HashMap<Vec<usize>, usize> = HashMap::new();
                let mut all = Vec::new();
                for &c in &cells {
                    let cell = self.mesh.cell(c);
                    for k in 0..num_faces(shape) {
                        if let Some(local) = element_face(shape, k) {
                            let f: Vec<usize> =
                                local.iter().filter_map(|&i| cell.get(i).copied()).collect();
                            let mut key = f.clone();
                            key.sort_unstable();
                            *count.entry(key.clone()).or_insert(0) += 1;
                            all.push((key, f));
                        }
                    }
                }
                out.extend(
                    all.into_iter()
                        .filter(|(key, _)| count.get(key) == Some(&1))
                        .map(|(_, f)| f),
                );
            }
        }
        let reverse = matches!(label, Some(Label::Neg));
        for &f in &members.faces {
            if let Some(face) = self.faces.get(f) {
                let mut v = face.clone();
                if reverse {
                    if let Some(rest) = v.get_mut(1..) {
                        rest.reverse();
                    }
                }
                out.push(v);
            }
        }
        Ok(())
    }
}

/// Sorted, without repeats.
fn sorted_unique(v: &[usize]) -> Vec<usize> {
    let mut w = v.to_vec();
    w.sort_unstable();
    w.dedup();
    w
}

/// First occurrences, in order.
fn first_occurrences(v: &[usize]) -> Vec<usize> {
    let mut seen = HashSet::with_capacity(v.len());
    v.iter().copied().filter(|&i| seen.insert(i)).collect()
}

impl ElsetAcc {
    /// A copy without repeated members (a set referencing itself grows linearly, not
    /// exponentially).
    fn deduped(&self) -> ElsetAcc {
        ElsetAcc {
            name: self.name.clone(),
            vol: sorted_unique(&self.vol),
            faces: first_occurrences(&self.faces),
            ignored: self.ignored,
        }
    }
}

fn add_ref(acc: &mut ElsetAcc, r: ElemRef) {
    match r {
        ElemRef::Vol(i) => acc.vol.push(i),
        ElemRef::Face(i) => acc.faces.push(i),
        ElemRef::Ignored => acc.ignored = true,
    }
}

// ---------------------------------------------------------------------------------------------
// Numbers
// ---------------------------------------------------------------------------------------------

/// A positive integer id; the message quotes the field.
fn parse_id(s: &str, what: &str) -> std::result::Result<u64, String> {
    if s.is_empty() {
        return Err(format!("empty {what} field"));
    }
    match s.parse::<u64>() {
        Ok(0) => Err(format!("{what} '0' (ids must be positive)")),
        Ok(v) => Ok(v),
        Err(_) => {
            if s.parse::<f64>().is_ok() {
                Err(format!("{what} '{s}' is not a positive integer"))
            } else {
                Err(format!("non-numeric {what} '{s}'"))
            }
        }
    }
}

/// A finite coordinate; blank is 0; Fortran `D` exponents accepted.
fn parse_coord(s: &str) -> std::result::Result<f64, String> {
    if s.is_empty() {
        return Ok(0.0);
    }
    let v = if s.contains(['d', 'D']) {
        s.replace(['d', 'D'], "e").parse::<f64>()
    } else {
        s.parse::<f64>()
    };
    match v {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("non-finite coordinate '{s}'")),
        Err(_) => Err(format!("non-numeric coordinate '{s}'")),
    }
}

// ---------------------------------------------------------------------------------------------
// Writer
// ---------------------------------------------------------------------------------------------

/// A name as a parameter value: quoted when it has blanks; error when `.inp` cannot carry it.
fn name_value(kind: &str, name: &str, path: &Path) -> Result<String> {
    if name.is_empty() {
        return Err(Error::Input(format!(
            "{}: a {kind} with an empty name cannot be written to .inp",
            path.display()
        )));
    }
    if name
        .chars()
        .any(|c| matches!(c, ',' | '"' | '=') || c.is_control())
    {
        return Err(Error::Input(format!(
            "{}: {kind} '{name}' contains ',', '\"', '=' or a control character, which .inp cannot carry; rename it",
            path.display()
        )));
    }
    if name.chars().any(char::is_whitespace) {
        Ok(format!("\"{name}\""))
    } else {
        Ok(name.to_string())
    }
}

/// Errors on two names equal up to case (ABAQUS names are case-insensitive).
fn check_case_clash<'n>(names: impl Iterator<Item = &'n String>, path: &Path) -> Result<()> {
    let mut seen: HashMap<String, &String> = HashMap::new();
    for n in names {
        if let Some(prev) = seen.insert(upper(n), n) {
            if prev != n {
                return Err(Error::Input(format!(
                    "{}: set names '{prev}' and '{n}' differ only in case; ABAQUS names are case-insensitive, rename one",
                    path.display()
                )));
            }
        }
    }
    Ok(())
}

/// Ids from the file when usable (one per item, positive, unique), otherwise 1..=n.
fn usable_ids(ids: &[u64], n: usize) -> Vec<u64> {
    let mut seen = HashSet::with_capacity(ids.len());
    if ids.len() == n && ids.iter().all(|&i| i > 0 && seen.insert(i)) {
        ids.to_vec()
    } else {
        (1..=n as u64).collect()
    }
}

fn write_id_lines(s: &mut String, ids: impl Iterator<Item = u64>) {
    let mut k = 0;
    for id in ids {
        if k > 0 {
            s.push_str(if k % 16 == 0 { "\n" } else { ", " });
        }
        let _ = write!(s, "{id}");
        k += 1;
    }
    if k > 0 {
        s.push('\n');
    }
}

fn format_inp(m: &MeshInput, path: &Path) -> Result<String> {
    let bad = |msg: String| Error::Input(format!("{}: {msg}", path.display()));
    let mesh = &m.mesh;
    let n = mesh.nodes.len();
    let npe = mesh.shape.nodes_per_cell();
    if !mesh.cells.len().is_multiple_of(npe) {
        return Err(bad(format!(
            "connectivity length {} is not a multiple of {npe}",
            mesh.cells.len()
        )));
    }
    if let Some(&c) = mesh.cells.iter().find(|&&c| c >= n) {
        return Err(bad(format!("a cell references node index {c} of {n}")));
    }
    if let Some(i) = mesh
        .nodes
        .iter()
        .position(|p| !p.iter().all(|v| v.is_finite()))
    {
        return Err(bad(format!("node {i} has a non-finite coordinate")));
    }
    let ncells = mesh.num_cells();
    let nid = usable_ids(&m.node_ids, n);
    let eid = usable_ids(&m.element_ids, ncells);
    for (name, v) in &m.node_sets {
        if let Some(&i) = v.iter().find(|&&i| i >= n) {
            return Err(bad(format!(
                "node set '{name}' holds node index {i} of {n}"
            )));
        }
    }
    for (name, v) in &m.element_sets {
        if let Some(&i) = v.iter().find(|&&i| i >= ncells) {
            return Err(bad(format!(
                "element set '{name}' holds cell index {i} of {ncells}"
            )));
        }
    }
    for (name, fs) in &m.face_sets {
        for f in fs {
            if f.len() != 3 && f.len() != 4 {
                return Err(bad(format!(
                    "face set '{name}' holds a face with {} nodes; .inp surface elements are triangles or quadrilaterals",
                    f.len()
                )));
            }
            if let Some(&i) = f.iter().find(|&&i| i >= n) {
                return Err(bad(format!(
                    "face set '{name}' holds node index {i} of {n}"
                )));
            }
        }
    }
    check_case_clash(m.node_sets.keys(), path)?;
    {
        let mut el: Vec<&String> = m.element_sets.keys().collect();
        el.extend(
            m.face_sets
                .keys()
                .filter(|k| !m.element_sets.contains_key(*k)),
        );
        check_case_clash(el.into_iter(), path)?;
    }
    // Name of the set of all elements: one that holds no other element set.
    let all: Vec<usize> = (0..ncells).collect();
    let mut all_name = "ALL_ELEMENTS".to_string();
    let mut k = 0;
    while m
        .element_sets
        .iter()
        .any(|(name, v)| name.eq_ignore_ascii_case(&all_name) && *v != all)
    {
        k += 1;
        all_name = format!("ALL_ELEMENTS_{k}");
    }

    let mut s = String::with_capacity(64 * (n + ncells) + 256);
    let _ = writeln!(s, "*HEADING");
    let _ = writeln!(
        s,
        "hytled mesh: {n} nodes, {ncells} {} elements",
        shape_name(mesh.shape)
    );
    s.push_str("** written by hytled; coordinates in the mesh's length unit\n");
    s.push_str("*NODE\n");
    for (p, id) in mesh.nodes.iter().zip(&nid) {
        let _ = writeln!(s, "{id}, {:?}, {:?}, {:?}", p.x, p.y, p.z);
    }
    let ty = match mesh.shape {
        ElementShape::Hex8 => "C3D8",
        ElementShape::Tet4 => "C3D4",
    };
    let _ = writeln!(s, "*ELEMENT, TYPE={ty}, ELSET={all_name}");
    for (e, id) in eid.iter().enumerate() {
        let _ = write!(s, "{id}");
        for &c in mesh.cell(e) {
            let _ = write!(s, ", {}", nid.get(c).copied().unwrap_or(0));
        }
        s.push('\n');
    }
    // Face sets: runs of triangles / quadrilaterals, numbered after the volume elements.
    let mut next = eid.iter().copied().max().unwrap_or(0);
    for (name, fs) in &m.face_sets {
        let value = name_value("face set", name, path)?;
        let mut i = 0;
        while let Some(first) = fs.get(i) {
            let len = first.len();
            let run = fs
                .get(i..)
                .unwrap_or(&[])
                .iter()
                .take_while(|f| f.len() == len)
                .count();
            let ty = if len == 3 { "CPS3" } else { "CPS4" };
            let _ = writeln!(s, "*ELEMENT, TYPE={ty}, ELSET={value}");
            for f in fs.get(i..i + run).unwrap_or(&[]) {
                next = next
                    .checked_add(1)
                    .ok_or_else(|| bad("element ids overflow".into()))?;
                let _ = write!(s, "{next}");
                for &c in f {
                    let _ = write!(s, ", {}", nid.get(c).copied().unwrap_or(0));
                }
                s.push('\n');
            }
            i += run;
        }
    }
    for (name, v) in &m.node_sets {
        let _ = writeln!(s, "*NSET, NSET={}", name_value("node set", name, path)?);
        write_id_lines(&mut s, v.iter().map(|&i| nid.get(i).copied().unwrap_or(0)));
    }
    for (name, v) in &m.element_sets {
        let _ = writeln!(
            s,
            "*ELSET, ELSET={}",
            name_value("element set", name, path)?
        );
        write_id_lines(&mut s, v.iter().map(|&i| eid.get(i).copied().unwrap_or(0)));
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<MeshInput> {
        parse_inp(text, Path::new("test.inp"))
    }

    fn err(text: &str) -> String {
        match parse(text) {
            Ok(_) => panic!("expected an error for:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    fn temp_dir(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("hytled-inp-{test}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Two unit hexes along x, sparse unordered node ids, mixed-case keywords, a continued
    /// element line, GENERATE sets, *SURFACE, skipped keywords.
    const TWO_HEX: &str = "\
*Heading
 two hexes ** not a comment, heading text
** a comment
*node, nset=AllNodes
101, 0.0, 0.0, 0.0
7,   1.0, 0.0, 0.0
55,  1.0, 1.0, 0.0
3,   0.0, 1.0, 0.0
12,  0.0, 0.0, 1.0
9,   1.0, 0.0, 1.0
40,  1.0, 1.0, 1.0
41,  0.0, 1.0, 1.0

*NODE
200, 2., 0., 0.
201, 2., 1., 0.
202, 2., 0., 1.
203, 2.D0, 1.0e0, 1.,
*Element, TYPE=c3d8r, ElSet=Tissue
10, 101, 7, 55, 3,
    12, 9, 40, 41
20, 7, 200, 201, 55, 9, 202, 203, 40,
*Nset, NSET=left
101, 3, 12, 41,
*NSET, nset=gen, GENERATE
200, 203, 1
*nset, nset=left
101
*Elset, elset=second, generate
20, 20
*Elset, elset=both
second, 10
*Surface, name=TopFaces, type=ELEMENT
Tissue, S2
*SURFACE, NAME=right
20, s4
*Nset, nset=fromEl, elset=second
*Material, name=Tissue
*Hyperelastic, neo hooke
0.001, 0.1
*Step, name=Load
*Static
1., 1.
*Boundary
left, ENCASTRE
*End Step
";

    #[test]
    fn two_hex_sparse_ids_sets_and_surfaces() {
        let m = parse(TWO_HEX).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Hex8);
        assert_eq!(
            m.node_ids,
            vec![101, 7, 55, 3, 12, 9, 40, 41, 200, 201, 202, 203]
        );
        assert_eq!(m.element_ids, vec![10, 20]);
        assert_eq!(m.mesh.nodes[1], Vector3::new(1.0, 0.0, 0.0));
        assert_eq!(m.mesh.nodes[11], Vector3::new(2.0, 1.0, 1.0));
        assert_eq!(
            m.mesh.cells,
            vec![0, 1, 2, 3, 4, 5, 6, 7, 1, 8, 9, 2, 5, 10, 11, 6]
        );
        assert_eq!(m.node_sets["AllNodes"], (0..8).collect::<Vec<_>>());
        assert_eq!(m.node_sets["left"], vec![0, 3, 4, 7]);
        assert_eq!(m.node_sets["gen"], vec![8, 9, 10, 11]);
        assert_eq!(m.node_sets["fromEl"], vec![1, 2, 5, 6, 8, 9, 10, 11]);
        assert_eq!(m.element_sets["Tissue"], vec![0, 1]);
        assert_eq!(m.element_sets["second"], vec![1]);
        assert_eq!(m.element_sets["both"], vec![0, 1]);
        // S2 = 5-8-7-6, outward: 4, 5, 6, 7 of each hex.
        assert_eq!(
            m.face_sets["TopFaces"],
            vec![vec![4, 5, 6, 7], vec![5, 10, 11, 6]]
        );
        // S4 of the second hex = local 2-6-7-3, outward 1, 2, 6, 5.
        assert_eq!(m.face_sets["right"], vec![vec![8, 9, 11, 10]]);
        let w = m.warnings.join("\n");
        assert!(
            w.contains(
                "skipped keywords: *Material, *Hyperelastic, *Step, *Static, *Boundary, *End Step"
            ),
            "{w}"
        );
        // Outward normals: +z for the top faces, +x for the right face.
        let normal = |f: &Vec<usize>| {
            let x = |i: usize| m.mesh.nodes[f[i]];
            (x(2) - x(0)).cross(&(x(3) - x(1)))
        };
        for f in &m.face_sets["TopFaces"] {
            assert!(normal(f).z > 0.0, "{f:?}");
        }
        assert!(normal(&m.face_sets["right"][0]).x > 0.0);
    }

    #[test]
    fn free_faces_instance_names_and_surface_elements() {
        let text = "\
*NODE
1,0,0,0
2,1,0,0
3,0,1,0
4,0,0,1
5,1,1,1
*ELEMENT,TYPE=C3D4,ELSET=V
1,1,2,3,4
2,2,3,4,5
*ELEMENT,TYPE=S3,ELSET=skin
3,1,3,2
*ELEMENT,TYPE=T3D2
4,1,2
*ELSET,ELSET=mix
1,3,4
*SURFACE,NAME=free
V
*SURFACE,NAME=neg
skin,SNEG
*NSET,NSET=one
Part-1-1.skinnodes
";
        // Unknown name in the nset -> error naming it.
        let e = err(text);
        assert!(
            e.contains("test.inp:21") && e.contains("'Part-1-1.skinnodes'"),
            "{e}"
        );
        let text = text.replace("Part-1-1.skinnodes", "4\n*NSET,NSET=two\nPart-1-1.one");
        let m = parse(&text).unwrap();
        assert_eq!(m.face_sets["free"].len(), 6);
        assert_eq!(m.face_sets["neg"], vec![vec![0, 1, 2]]);
        assert_eq!(m.face_sets["skin"], vec![vec![0, 2, 1]]);
        assert_eq!(m.face_sets["mix"], vec![vec![0, 2, 1]]);
        assert_eq!(m.element_sets["mix"], vec![0]);
        assert_eq!(m.node_sets["two"], vec![3]);
        assert!(!m.face_sets.contains_key("TYPE_T3D2"));
        assert!(m
            .warnings
            .iter()
            .any(|w| w.contains("1 element(s) of type T3D2")));
    }

    #[test]
    fn include_files_relative_and_errors_name_the_included_file() {
        let dir = temp_dir("include");
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(
            dir.join("sub/nodes.inp"),
            "** nodes\n*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n*include, input=more.inp\n",
        )
        .unwrap();
        std::fs::write(dir.join("sub/more.inp"), "*Node\n4,0,0,1\n").unwrap();
        std::fs::write(dir.join("elems.dat"), "1, 1, 2, 3, 4\n").unwrap();
        let main = dir.join("main.inp");
        std::fs::write(
            &main,
            "*HEADING\nx\n*INCLUDE, INPUT=sub/nodes.inp\n*ELEMENT, TYPE=C3D4, INPUT=elems.dat\n",
        )
        .unwrap();
        let m = read_inp(&main).unwrap();
        assert_eq!(m.mesh.nodes.len(), 4);
        assert_eq!(m.mesh.cells, vec![0, 1, 2, 3]);

        // An error inside an included file names that file and its line.
        std::fs::write(dir.join("sub/more.inp"), "*Node\n4,0,zero,1\n").unwrap();
        let e = read_inp(&main).unwrap_err().to_string();
        assert!(e.contains("more.inp:2:") && e.contains("'zero'"), "{e}");

        // A missing include names the including line.
        std::fs::write(&main, "*INCLUDE, INPUT=nothere.inp\n").unwrap();
        let e = read_inp(&main).unwrap_err().to_string();
        assert!(
            e.contains("main.inp:1:") && e.contains("nothere.inp"),
            "{e}"
        );
        std::fs::write(&main, "*INCLUDE, INPUT=sub\n").unwrap();
        let e = read_inp(&main).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");

        // A cycle.
        std::fs::write(dir.join("a.inp"), "*INCLUDE, INPUT=b.inp\n").unwrap();
        std::fs::write(dir.join("b.inp"), "*NODE\n1,0,0,0\n*INCLUDE, INPUT=a.inp\n").unwrap();
        let e = read_inp(&dir.join("a.inp")).unwrap_err().to_string();
        assert!(
            e.contains("b.inp:3:") && e.contains("*INCLUDE cycle"),
            "{e}"
        );

        // Self include with a depth chain of distinct files beyond the limit.
        for k in 0..12 {
            std::fs::write(
                dir.join(format!("d{k}.inp")),
                format!("*INCLUDE, INPUT=d{}.inp\n", k + 1),
            )
            .unwrap();
        }
        let e = read_inp(&dir.join("d0.inp")).unwrap_err().to_string();
        assert!(e.contains("deeper than 10"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    const TET_HEAD: &str = "*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n";

    #[test]
    fn malformed_inputs_give_clear_errors() {
        // Truncated file in the middle of a continued element.
        let e = err("*NODE\n1,0,0,0\n*ELEMENT,TYPE=C3D8\n1, 1, 2, 3, 4,\n");
        assert!(
            e.contains("test.inp:4:") && e.contains("expects 8 nodes, found 4"),
            "{e}"
        );
        // Wrong node count on an element line.
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1, 1, 2, 3\n"));
        assert!(
            e.contains("test.inp:7:")
                && e.contains("element 1: type C3D4 expects 4 nodes, found 3"),
            "{e}"
        );
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1, 1, 2, 3, 4, 4\n"));
        assert!(e.contains("expects 4 nodes, found 5"), "{e}");
        // Non-numeric fields.
        let e = err("*NODE\n1, 0.0, abc, 0.0\n");
        assert!(e.contains("test.inp:2:") && e.contains("'abc'"), "{e}");
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1, 1, 2, x3, 4\n"));
        assert!(e.contains("test.inp:7:") && e.contains("'x3'"), "{e}");
        // Missing referenced node, with *NODE after *ELEMENT still fine otherwise.
        let e =
            err("*ELEMENT,TYPE=C3D4\n7, 1, 2, 3, 9\n*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n");
        assert!(
            e.contains("test.inp:2:") && e.contains("element 7 references node 9"),
            "{e}"
        );
        assert!(parse(
            "*ELEMENT,TYPE=C3D4\n7, 1, 2, 3, 4\n*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n"
        )
        .is_ok());
        // Unsupported types.
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT, type=C3D10\n1,1,2,3,4,1,2,3,4,1,2\n"
        ));
        assert!(
            e.contains("test.inp:6: unsupported element type C3D10 at line 6 (hytled reads C3D8*/C3D4*; convert or re-mesh)"),
            "{e}"
        );
        let e = err(&format!("{TET_HEAD}*ELEMENT, type=FOO12\n1,1\n"));
        assert!(e.contains("unsupported element type FOO12"), "{e}");
        let e = err(&format!("{TET_HEAD}*ELEMENT\n1,1,2,3,4\n"));
        assert!(e.contains("without TYPE="), "{e}");
        // Duplicate node id names both lines.
        let e = err("*NODE\n1,0,0,0\n2,1,0,0\n*NODE\n1,5,5,5\n");
        assert!(
            e.contains("test.inp:5:")
                && e.contains("duplicate node id 1")
                && e.contains("test.inp:2"),
            "{e}"
        );
        // Duplicate element id.
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n1,1,2,3,4\n"
        ));
        assert!(e.contains("duplicate element id 1"), "{e}");
        // 2-D nodes.
        let e = err("*NODE\n1, 0.0, 1.0\n");
        assert!(e.contains("node 1 has 2 coordinate(s)"), "{e}");
        // Mixed mesh.
        let e = err("*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n5,1,1,0\n6,1,0,1\n7,1,1,1\n8,0,1,1\n*ELEMENT,TYPE=C3D8\n1,1,2,5,3,4,6,7,8\n*ELEMENT,TYPE=C3D4\n2,1,2,3,4\n");
        assert!(
            e.contains("test.inp:13:") && e.contains("element 2 is tet4") && e.contains("mixed"),
            "{e}"
        );
        // Unknown ids in sets.
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n*NSET,NSET=a\n1, 77\n"
        ));
        assert!(
            e.contains("test.inp:9:") && e.contains("node 77 is not defined"),
            "{e}"
        );
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n*ELSET,ELSET=a,GENERATE\n1,3\n"
        ));
        assert!(
            e.contains("test.inp:9:") && e.contains("element 2 is not defined"),
            "{e}"
        );
        let e = err("*NODE\n1,2,3,4\n*NSET,NSET=a,GENERATE\n1,5,0\n");
        assert!(e.contains("test.inp:4: GENERATE step '0'"), "{e}");
        let e = err("*NODE\n1,2,3,4\n*NSET,NSET=a,GENERATE\n5,1\n");
        assert!(e.contains("start 5 is after end 1"), "{e}");
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,1.5\n"));
        assert!(e.contains("node id '1.5' is not a positive integer"), "{e}");
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n*SURFACE,NAME=s\n1,S5\n"
        ));
        assert!(
            e.contains("test.inp:9:") && e.contains("S5 does not exist on tet4"),
            "{e}"
        );
        // No volume elements.
        let e = err(TET_HEAD);
        assert!(e.contains("no volume elements"), "{e}");
        // Non-finite coordinates.
        let e = err("*NODE\n1, 0, nan, 0\n");
        assert!(e.contains("non-finite coordinate 'nan'"), "{e}");
    }

    fn sample_input() -> MeshInput {
        // 2x1x1 hexes with awkward coordinates.
        let mut nodes = Vec::new();
        for k in 0..2 {
            for j in 0..2 {
                for i in 0..3 {
                    let x = i as f64 * (1.0 / 3.0) + 1e-17 * (j as f64);
                    let y = j as f64 * 0.1 + 7.0e-300;
                    let z = if k == 0 { -0.0 } else { 123456.789e-5 };
                    nodes.push(Vector3::new(x, y, z));
                }
            }
        }
        let id = |i: usize, j: usize, k: usize| i + 3 * j + 6 * k;
        let mut cells = Vec::new();
        for i in 0..2 {
            cells.extend([
                id(i, 0, 0),
                id(i + 1, 0, 0),
                id(i + 1, 1, 0),
                id(i, 1, 0),
                id(i, 0, 1),
                id(i + 1, 0, 1),
                id(i + 1, 1, 1),
                id(i, 1, 1),
            ]);
        }
        let mut m = MeshInput {
            mesh: Mesh {
                nodes,
                shape: ElementShape::Hex8,
                cells,
            },
            node_ids: vec![9, 8, 7, 6, 5, 4, 300, 2, 1, 10, 11, 12],
            element_ids: vec![5, 3],
            node_sets: BTreeMap::new(),
            element_sets: BTreeMap::new(),
            face_sets: BTreeMap::new(),
            warnings: Vec::new(),
        };
        m.node_sets.insert("bottom".into(), (0..6).collect());
        m.node_sets.insert("with space".into(), vec![3]);
        m.node_sets.insert("empty".into(), vec![]);
        m.node_sets.insert("many".into(), (0..12).collect());
        m.element_sets.insert("first".into(), vec![0]);
        m.element_sets.insert("load".into(), vec![1]);
        m.face_sets.insert("load".into(), vec![vec![2, 8, 11, 5]]);
        m.face_sets.insert(
            "mixed".into(),
            vec![
                vec![0, 1, 2],
                vec![0, 3, 4, 1],
                vec![6, 7, 8],
                vec![2, 1, 0],
            ],
        );
        m
    }

    #[test]
    fn write_then_read_round_trip_is_exact() {
        let m = sample_input();
        let dir = temp_dir("roundtrip");
        let path = dir.join("out.inp");
        write_inp(&path, &m).unwrap();
        let r = read_inp(&path).unwrap();
        assert_eq!(r.mesh.shape, m.mesh.shape);
        assert_eq!(r.mesh.nodes.len(), m.mesh.nodes.len());
        for (a, b) in r.mesh.nodes.iter().zip(&m.mesh.nodes) {
            for k in 0..3 {
                assert_eq!(a[k].to_bits(), b[k].to_bits(), "{a:?} vs {b:?}");
            }
        }
        assert_eq!(r.mesh.cells, m.mesh.cells);
        assert_eq!(r.node_ids, m.node_ids);
        assert_eq!(r.element_ids, m.element_ids);
        assert_eq!(r.node_sets, m.node_sets);
        let mut expected = m.element_sets.clone();
        expected.insert("ALL_ELEMENTS".into(), vec![0, 1]);
        assert_eq!(r.element_sets, expected);
        assert_eq!(r.face_sets, m.face_sets);
        assert!(r.warnings.is_empty(), "{:?}", r.warnings);
        // Writing again is stable, and a conflicting ALL_ELEMENTS gets another name.
        let text = format_inp(&r, &path).unwrap();
        let r2 = parse_inp(&text, &path).unwrap();
        assert_eq!(r2.element_sets, r.element_sets);
        let mut m3 = m.clone();
        m3.element_sets.insert("all_elements".into(), vec![1]);
        let r3 = parse_inp(&format_inp(&m3, &path).unwrap(), &path).unwrap();
        assert_eq!(r3.element_sets["all_elements"], vec![1]);
        assert_eq!(r3.element_sets["ALL_ELEMENTS_1"], vec![0, 1]);
        // Tet meshes, and unusable ids replaced by 1..n.
        let t = MeshInput {
            mesh: Mesh {
                nodes: vec![
                    Vector3::new(0.0, 0.0, 0.0),
                    Vector3::new(1.0, 0.0, 0.0),
                    Vector3::new(0.0, 1.0, 0.0),
                    Vector3::new(0.0, 0.0, 1.0),
                ],
                shape: ElementShape::Tet4,
                cells: vec![0, 1, 2, 3],
            },
            node_ids: vec![],
            element_ids: vec![0],
            node_sets: BTreeMap::new(),
            element_sets: BTreeMap::new(),
            face_sets: BTreeMap::new(),
            warnings: vec![],
        };
        let rt = parse_inp(&format_inp(&t, &path).unwrap(), &path).unwrap();
        assert_eq!(rt.mesh.cells, t.mesh.cells);
        assert_eq!(rt.node_ids, vec![1, 2, 3, 4]);
        assert_eq!(rt.element_ids, vec![1]);
        // Names .inp cannot carry.
        let mut bad = t.clone();
        bad.node_sets.insert("a,b".into(), vec![0]);
        assert!(format_inp(&bad, &path)
            .unwrap_err()
            .to_string()
            .contains("'a,b'"));
        let mut bad = t.clone();
        bad.node_sets.insert("Top".into(), vec![0]);
        bad.node_sets.insert("TOP".into(), vec![1]);
        assert!(format_inp(&bad, &path)
            .unwrap_err()
            .to_string()
            .contains("differ only in case"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn data_file(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/inp")
            .join(name)
    }

    #[test]
    fn gmsh_style_file() {
        let m = read_inp(&data_file("gmsh_cube_tet4.inp")).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Tet4);
        assert_eq!(m.mesh.nodes.len(), 8);
        assert_eq!(m.mesh.num_cells(), 6);
        assert_eq!(m.element_ids, vec![25, 26, 27, 28, 29, 30]);
        for e in 0..6 {
            let c = m.mesh.cell(e);
            let v = tet_signed_volume(
                &m.mesh.nodes[c[0]],
                &m.mesh.nodes[c[1]],
                &m.mesh.nodes[c[2]],
                &m.mesh.nodes[c[3]],
            );
            assert!((v - 1.0 / 6.0).abs() < 1e-12, "element {e}: {v}");
        }
        assert_eq!(m.element_sets["Volume1"], (0..6).collect::<Vec<_>>());
        assert_eq!(m.element_sets["tissue"], (0..6).collect::<Vec<_>>());
        assert_eq!(m.face_sets["Surface1"], vec![vec![0, 2, 1], vec![0, 3, 2]]);
        assert_eq!(m.face_sets["bottom"], m.face_sets["Surface1"]);
        assert_eq!(m.face_sets["top"].len(), 2);
        assert_eq!(m.node_sets["bottom"], vec![0, 1, 2, 3]);
        assert_eq!(m.node_sets["top"], vec![4, 5, 6, 7]);
        assert!(!m.element_sets.contains_key("Line1") && !m.face_sets.contains_key("Line1"));
        assert!(
            m.warnings.iter().any(|w| w.contains("T3D2")),
            "{:?}",
            m.warnings
        );
        // The boundary faces from the file are outward.
        for f in m.face_sets["Surface1"].iter().chain(&m.face_sets["top"]) {
            let x = |i: usize| m.mesh.nodes[f[i]];
            let n = (x(1) - x(0)).cross(&(x(2) - x(0)));
            let c = (x(0) + x(1) + x(2)) / 3.0 - Vector3::repeat(0.5);
            assert!(n.dot(&c) > 0.0);
        }
    }

    #[test]
    fn abaqus_cae_style_file() {
        let m = read_inp(&data_file("abaqus_cae_block_hex8.inp")).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Hex8);
        assert_eq!(m.mesh.nodes.len(), 12);
        assert_eq!(
            m.mesh.cells,
            vec![0, 1, 4, 3, 6, 7, 10, 9, 1, 2, 5, 4, 7, 8, 11, 10]
        );
        assert_eq!(m.node_sets["Set-1"], (0..12).collect::<Vec<_>>());
        assert_eq!(m.element_sets["Set-1"], vec![0, 1]);
        assert_eq!(m.node_sets["Fixed"], vec![0, 3, 6, 9]);
        assert_eq!(
            m.face_sets["Top"],
            vec![vec![6, 7, 10, 9], vec![7, 8, 11, 10]]
        );
        assert_eq!(m.face_sets["Load"], vec![vec![2, 5, 11, 8]]);
        // The part's sets also under the instance's name.
        assert_eq!(m.node_sets["Block-1.Set-1"], m.node_sets["Set-1"]);
        assert_eq!(m.face_sets["Block-1.Top"], m.face_sets["Top"]);
        assert_eq!(m.node_ids, (1..=12).collect::<Vec<u64>>());
        // The tet instance (another shape) and the reference point are skipped, not read.
        let w = m.warnings.join("\n");
        assert!(
            w.contains("instance 'Indenter-1' (part 'Indenter') is tet4 but instance 'Block-1' (part 'Block') is hex8"),
            "{w}"
        );
        assert!(w.contains("IndTip (instance Indenter-1)"), "{w}");
        assert!(
            w.contains("skipped keywords:") && w.contains("*Material") && w.contains("*Step"),
            "{w}"
        );
        assert!(w.contains("reference points"), "{w}");
        assert!(!w.contains("Fixed"), "{w}");
    }

    /// ABAQUS/CAE assembly: two placed instances of one part and one of another, part-level
    /// sets per instance, assembly sets with INSTANCE=.
    #[test]
    fn assembly_instances_are_placed_copies() {
        let m = read_inp(&data_file("abaqus_cae_two_instances.inp")).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Hex8);
        assert_eq!(m.mesh.nodes.len(), 32);
        assert_eq!(m.mesh.num_cells(), 5);
        let ids: Vec<u64> = (1..=12).chain(1..=12).chain(1..=8).collect();
        assert_eq!(m.node_ids, ids);
        assert_eq!(m.element_ids, vec![1, 2, 1, 2, 1]);
        let near = |i: usize, x: [f64; 3]| {
            let d = (m.mesh.nodes[i] - Vector3::from(x)).amax();
            assert!(d < 1e-12, "node {i}: {:?} vs {x:?}", m.mesh.nodes[i]);
        };
        // Beam-1 as written.
        near(2, [1.0, 0.0, 0.0]);
        near(11, [1.0, 0.5, 0.5]);
        // Beam-2: translated by (0, 0, 2), then turned 90 degrees about the z axis through
        // (0, 0, 2): (x, y, z) -> (-y, x, z + 2).
        near(12, [0.0, 0.0, 2.0]);
        near(14, [0.0, 1.0, 2.0]);
        near(23, [-0.5, 1.0, 2.5]);
        // Pad-1: translated by (2, 0, 0).
        near(31, [2.5, 0.5, 0.1]);
        // Cells point into their own instance's nodes.
        assert_eq!(&m.mesh.cells[16..24], &[12, 13, 16, 15, 18, 19, 22, 21]);
        assert_eq!(&m.mesh.cells[32..40], &[24, 25, 27, 26, 28, 29, 31, 30]);
        // Part-level sets, once per instance.
        assert_eq!(m.node_sets["Beam-1.Set-All"], (0..12).collect::<Vec<_>>());
        assert_eq!(m.node_sets["Beam-2.Set-All"], (12..24).collect::<Vec<_>>());
        assert_eq!(m.element_sets["Beam-2.Set-All"], vec![2, 3]);
        assert_eq!(m.node_sets["Beam-2.End"], vec![14, 17, 20, 23]);
        assert_eq!(m.face_sets["Beam-2.Top"].len(), 2);
        // A name only one instance has keeps its plain name too; shared ones do not.
        assert_eq!(m.node_sets["PadAll"], (24..32).collect::<Vec<_>>());
        assert_eq!(m.element_sets["Pad-1.PadAll"], vec![4]);
        assert!(!m.node_sets.contains_key("Set-All") && !m.node_sets.contains_key("End"));
        // Assembly sets: ids and set names resolved in their instance.
        assert_eq!(m.node_sets["Fixed"], vec![0, 3, 6, 9]);
        assert_eq!(m.node_sets["Ends"], vec![2, 5, 8, 11, 14, 17, 20, 23]);
        assert_eq!(m.node_sets["Clamp"], vec![24, 25, 26, 27]);
        // S4 of Beam-2's element 2 (the +x face in the part), outward: +y after the turn.
        assert_eq!(m.face_sets["Load"], vec![vec![14, 17, 23, 20]]);
        let f = &m.face_sets["Load"][0];
        let x = |i: usize| m.mesh.nodes[f[i]];
        let n = (x(2) - x(0)).cross(&(x(3) - x(1)));
        assert!(n.y > 0.0 && n.x.abs() < 1e-12, "{n:?}");
        // No inverted elements after the rotation; the instances are listed.
        let w = m.warnings.join("\n");
        assert!(!w.contains("non-positive"), "{w}");
        assert!(
            w.contains("3 part instances read")
                && w.contains("instance 'Beam-2' (part 'Beam'): nodes 12..24, elements 2..4"),
            "{w}"
        );
    }

    #[test]
    fn assembly_errors_name_the_instance_and_line() {
        let text = std::fs::read_to_string(data_file("abaqus_cae_two_instances.inp")).unwrap();
        let bad = |from: &str, to: &str| {
            assert!(text.contains(from), "{from}");
            err(&text.replacen(from, to, 1))
        };
        let e = bad("part=Pad\n", "part=Padx\n");
        assert!(
            e.contains("test.inp:74: *Instance Pad-1: part 'Padx' is not defined"),
            "{e}"
        );
        let e = bad("instance=Pad-1", "instance=Pad-2");
        assert!(
            e.contains(
                "test.inp:88: *Nset Clamp: INSTANCE=Pad-2 is not an instance of the assembly"
            ),
            "{e}"
        );
        // A missing node in an assembly set names the instance.
        let e = bad(" 1, 2, 3, 4\n*End Assembly", " 1, 2, 3, 9\n*End Assembly");
        assert!(
            e.contains("test.inp:89: *NSET Clamp: node 9 is not defined (in instance 'Pad-1')"),
            "{e}"
        );
        // A missing node in a part names the instance read.
        let e = bad("1, 1, 2, 4, 3, 5, 6, 8, 7", "1, 1, 2, 4, 3, 5, 6, 8, 70");
        assert!(
            e.contains("test.inp:51: element 1 references node 70")
                && e.contains("[instance 'Pad-1' of part 'Pad']"),
            "{e}"
        );
        // Positioning lines.
        let e = bad(
            "          2.,           0.,           0.\n",
            "          2., x, 0.\n",
        );
        assert!(
            e.contains("test.inp:75: *Instance Pad-1 translation") && e.contains("'x'"),
            "{e}"
        );
        let e = bad("          3.,          90.", "          2.,          90.");
        assert!(
            e.contains("test.inp:71: *Instance Beam-2: the rotation axis points a and b coincide"),
            "{e}"
        );
        let e = bad("          0.,           0.,           2.\n", "1, 2, 3, 4\n");
        assert!(
            e.contains("test.inp:70: *Instance Beam-2: 4 fields on the translation"),
            "{e}"
        );
        // Structure.
        let e = bad("*End Part\n**\n*Part, name=Pad", "**\n**\n*Part, name=Pad");
        assert!(
            e.contains("test.inp:40: *Part inside part 'Beam' (line 8)"),
            "{e}"
        );
        let e = bad("name=Pad-1", "name=Beam-1");
        assert!(e.contains("instance 'Beam-1' is defined twice"), "{e}");
    }

    /// Sets that reference themselves stay bounded (no doubling per line).
    #[test]
    fn self_referencing_sets_stay_small() {
        let mut text =
            format!("{TET_HEAD}*ELEMENT,TYPE=C3D4,ELSET=e\n1,1,2,3,4\n*NSET,NSET=a\n1,2\n");
        for _ in 0..200 {
            text.push_str(
                "*NSET,NSET=a\na, a, a, a\n*ELSET,ELSET=e\ne, e, e\n*NSET,NSET=a,ELSET=e\n",
            );
        }
        let m = parse(&text).unwrap();
        assert_eq!(m.node_sets["a"], vec![0, 1, 2, 3]);
        assert_eq!(m.element_sets["e"], vec![0]);
    }

    /// Random byte mutations of valid files never panic.
    #[test]
    fn mutations_never_panic() {
        let seeds = [
            TWO_HEX.to_string(),
            std::fs::read_to_string(data_file("gmsh_cube_tet4.inp")).unwrap(),
            std::fs::read_to_string(data_file("abaqus_cae_block_hex8.inp")).unwrap(),
            std::fs::read_to_string(data_file("abaqus_cae_two_instances.inp")).unwrap(),
        ];
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut rnd = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let alphabet = b"*,=\n 0123456789.-eEDSabcNODEgenratI\"";
        let mut ok = 0;
        for it in 0..3000 {
            let mut b = seeds[it % seeds.len()].clone().into_bytes();
            for _ in 0..(1 + rnd() % 6) {
                if b.is_empty() {
                    break;
                }
                let pos = (rnd() as usize) % b.len();
                match rnd() % 4 {
                    0 => b[pos] = alphabet[(rnd() as usize) % alphabet.len()],
                    1 => {
                        b.remove(pos);
                    }
                    2 => b.insert(pos, alphabet[(rnd() as usize) % alphabet.len()]),
                    _ => b.truncate(pos),
                }
            }
            let text = String::from_utf8_lossy(&b);
            if parse_inp(&text, Path::new("/nonexistent/fuzz.inp")).is_ok() {
                ok += 1;
            }
        }
        assert!(ok > 0);
    }
}
