//! The parser state: one body's nodes, elements, sets and surfaces read keyword by keyword.

use std::collections::HashMap;

use nalgebra::Vector3;

use crate::geometry::{ElementShape, Mesh};
use crate::io::model::MeshInput;
use crate::{Error, InputKind, Result};

use super::build::{build_input, Body};
use super::elements::{classify, shape_name, ElemKind};
use super::events::{ElemRef, Item, Label, Mode, Notes, SetEvent, SurfElem, Target};
use super::lines::{blocks, fields, upper, Files, Keyword, Line, Loc};
use super::sets::Resolver;
use super::values::{parse_coord, parse_id};

/// Reads the nodes, elements and sets of one mesh body: a whole file without parts, or one
/// part (with its instance's own lines) of an assembly.
pub(super) struct Parser<'f> {
    pub(super) files: &'f Files,
    pub(super) nodes: Vec<Vector3<f64>>,
    pub(super) node_ids: Vec<u64>,
    pub(super) node_locs: Vec<Loc>,
    pub(super) node_index: HashMap<u64, usize>,
    /// Shape of the first volume element, its id and line.
    pub(super) shape: Option<(ElementShape, u64, Loc)>,
    pub(super) vol_ids: Vec<u64>,
    pub(super) vol_conn: Vec<u64>,
    pub(super) vol_locs: Vec<Loc>,
    pub(super) surf: Vec<SurfElem>,
    pub(super) elem_index: HashMap<u64, (ElemRef, Loc)>,
    pub(super) events: Vec<SetEvent>,
    pub(super) notes: Notes,
    pub(super) mode: Mode,
}

impl<'f> Parser<'f> {
    pub(super) fn new(files: &'f Files) -> Self {
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

    pub(super) fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
        self.files.err(loc, msg)
    }

    pub(super) fn run(&mut self, lines: &[Line]) -> Result<()> {
        let (pre, blocks) = blocks(lines);
        self.notes.pre_keyword_lines += pre;
        for b in &blocks {
            self.keyword(&b.kw, b.loc, b.data)?;
        }
        Ok(())
    }

    pub(super) fn keyword(&mut self, kw: &Keyword, loc: Loc, data: &[Line]) -> Result<()> {
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
    pub(super) fn surface_name(&mut self, kw: &Keyword, loc: Loc) -> Result<Option<String>> {
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
                    None => Error::input(InputKind::Format, msg),
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

    pub(super) fn set_block(
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

    pub(super) fn surface_block(&mut self, name: String, data: &[Line]) -> Result<()> {
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
    pub(super) fn resolve(self) -> Result<(Body, Notes)> {
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

    pub(super) fn finish(self) -> Result<MeshInput> {
        if self.shape.is_none() {
            return Err(Error::input(InputKind::Format, format!(
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
