//! ABAQUS/CAE's parts, assembly and instances: placed copies merged into one body.

use std::collections::{BTreeMap, HashMap, HashSet};

use nalgebra::Vector3;

use crate::geometry::{ElementShape, Mesh};
use crate::io::model::MeshInput;
use crate::{Error, InputKind, Result};

use super::build::{build_input, Body};
use super::elements::shape_name;
use super::events::{ElemRef, Item, Notes, SetEvent};
use super::lines::{blocks, fields, parse_keyword, upper, Block, Files, Line, Loc};
use super::parser::Parser;
use super::sets::{ElsetAcc, Resolver};
use super::values::parse_coord;

/// Whether the file uses parts and an assembly.
pub(super) fn has_parts(lines: &[Line]) -> bool {
    lines.iter().any(|l| {
        l.keyword
            && matches!(
                parse_keyword(&l.text).name.as_str(),
                "PART" | "ASSEMBLY" | "INSTANCE"
            )
    })
}

struct PartDef<'l, 'a> {
    pub(super) name: String,
    pub(super) loc: Loc,
    pub(super) body: Vec<Block<'l, 'a>>,
}

struct InstanceDef<'l, 'a> {
    pub(super) name: String,
    pub(super) part: String,
    pub(super) loc: Loc,
    /// The positioning lines (translation, rotation).
    pub(super) place: &'l [Line<'a>],
    /// Keywords between *Instance and *End Instance (reference points, sets).
    pub(super) body: Vec<Block<'l, 'a>>,
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
    pub(super) translation: Vector3<f64>,
    pub(super) rotation: Option<(Vector3<f64>, nalgebra::Rotation3<f64>)>,
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
    e.append(&format!(
        " [instance '{}' of part '{}']",
        inst.name, inst.part
    ))
}

/// Node and element ids of one instance read, with their positions in the merged mesh.
struct InstanceMaps {
    pub(super) node_index: HashMap<u64, usize>,
    pub(super) elem_index: HashMap<u64, (ElemRef, Loc)>,
}

/// Reads a file with `*Part`s and an `*Assembly`: every instance is a copy of its part's
/// nodes, elements and sets, placed by its translation/rotation lines; see the module docs.
pub(super) fn parse_assembly(lines: &[Line], files: &Files) -> Result<MeshInput> {
    let (pre, all) = blocks(lines);
    let layout = Layout::split(all, files)?;
    let mut notes = Notes {
        pre_keyword_lines: pre,
        ..Notes::default()
    };
    let bodies = read_bodies(&layout, files, &mut notes)?;
    let mut m = Merged::new(bodies, &mut notes, files)?;
    m.assembly_sets(&layout.assembly, files, &mut notes)?;
    m.plain_part_names();
    if m.listing.len() > 1 {
        notes.warnings.push(format!(
            "{} part instances read (node ids repeat across instances; positions in the mesh): {}",
            m.listing.len(),
            m.listing.join("; ")
        ));
    }
    let Merged {
        mesh,
        node_ids,
        vol_ids,
        faces,
        nsets,
        elsets,
        surfaces,
        ranges,
        ..
    } = m;
    let shape = mesh.shape;
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

/// The keyword blocks of an assembly file by where they stand.
struct Layout<'l, 'a> {
    /// Outside parts and the assembly, and everything in steps.
    top: Vec<Block<'l, 'a>>,
    parts: Vec<PartDef<'l, 'a>>,
    instances: Vec<InstanceDef<'l, 'a>>,
    /// Between *Assembly and *End Assembly, outside instances.
    assembly: Vec<Block<'l, 'a>>,
}

impl<'l, 'a> Layout<'l, 'a> {
    fn split(all: Vec<Block<'l, 'a>>, files: &Files) -> Result<Self> {
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
                    let name =
                        unique_name(&b, files, "part", parts.iter().map(|p| (&p.name, p.loc)))?;
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
                    let name = unique_name(
                        &b,
                        files,
                        "instance",
                        instances.iter().map(|i| (&i.name, i.loc)),
                    )?;
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
        Ok(Layout {
            top,
            parts,
            instances,
            assembly,
        })
    }
}

/// The NAME= of a `*Part` or `*Instance` block, refused when missing or when `taken` (the
/// names so far, with where they stand) has it already, ignoring case as ABAQUS does.
fn unique_name<'n>(
    b: &Block,
    files: &Files,
    what: &str,
    mut taken: impl Iterator<Item = (&'n String, Loc)>,
) -> Result<String> {
    let name = b.kw.get("NAME").unwrap_or("").to_string();
    if name.is_empty() {
        return Err(files.err(b.loc, format!("{} without NAME=<name>", b.kw.shown)));
    }
    if let Some((_, first)) = taken.find(|(n, _)| n.eq_ignore_ascii_case(&name)) {
        return Err(files.err(
            b.loc,
            format!(
                "{what} '{name}' is defined twice (first at {})",
                files.at(first)
            ),
        ));
    }
    Ok(name)
}

/// The bodies to merge, each read and placed: mesh data outside parts (plain set names), then
/// every instance (its part's keywords, then its own).
fn read_bodies<'d, 'l, 'a>(
    layout: &'d Layout<'l, 'a>,
    files: &Files,
    notes: &mut Notes,
) -> Result<Vec<(Option<&'d InstanceDef<'l, 'a>>, Body)>> {
    let mut bodies = Vec::new();
    let mut p = Parser::new(files);
    for b in &layout.top {
        p.keyword(&b.kw, b.loc, b.data)?;
    }
    if !p.nodes.is_empty() || !p.vol_ids.is_empty() || !p.surf.is_empty() {
        let (body, n) = p.resolve()?;
        notes.absorb(n);
        bodies.push((None, body));
    } else {
        notes.absorb(p.notes);
    }
    for inst in &layout.instances {
        let part = layout
            .parts
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
    Ok(bodies)
}

/// The bodies of the first element shape read, merged into one mesh: sets named
/// `INSTANCE.SET`, with what the assembly's sets and the messages need to find them.
struct Merged {
    mesh: Mesh,
    node_ids: Vec<u64>,
    vol_ids: Vec<u64>,
    faces: Vec<Vec<usize>>,
    nsets: HashMap<String, (String, Vec<usize>)>,
    elsets: HashMap<String, ElsetAcc>,
    surfaces: HashMap<String, (String, Vec<Vec<usize>>)>,
    /// Each merged instance's ids, by upper-case instance name.
    maps: HashMap<String, InstanceMaps>,
    /// Instances left out (no volume elements, or another shape), by upper-case name.
    skipped: HashSet<String>,
    /// Part-level set names (kind, upper-case name) -> (qualified key, name) for each instance.
    local: BTreeMap<(u8, String), Vec<(String, String)>>,
    /// Element index ranges of the instances, for messages.
    ranges: Vec<(usize, usize, String)>,
    listing: Vec<String>,
}

impl Merged {
    fn new(
        bodies: Vec<(Option<&InstanceDef>, Body)>,
        notes: &mut Notes,
        files: &Files,
    ) -> Result<Merged> {
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
        let mut local: BTreeMap<(u8, String), Vec<(String, String)>> = BTreeMap::new();
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
            // A set's qualified key; an instance's sets are also listed under their local
            // key (kind 0 node, 1 element, 2 surface) for references inside the part.
            let mut qualify = |kind: u8, key: String, name: &str| {
                let q = format!("{prefix}{key}");
                if inst.is_some() {
                    local
                        .entry((kind, key))
                        .or_default()
                        .push((q.clone(), name.to_string()));
                }
                q
            };
            for (key, (name, v)) in body.nsets {
                let q = qualify(0, key, &name);
                nsets.insert(
                    q,
                    (
                        format!("{shown}{name}"),
                        v.iter().map(|&i| i + no).collect(),
                    ),
                );
            }
            for (key, acc) in body.elsets {
                let q = qualify(1, key, &acc.name);
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
                let q = qualify(2, key, &name);
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
            return Err(Error::input(InputKind::Format, format!(
                "{}: no volume elements (C3D8*/C3D4*) found in any part instance; hytled needs a hexahedral or tetrahedral volume mesh",
                files.name(0)
            )));
        };
        Ok(Merged {
            mesh: Mesh {
                nodes,
                shape,
                cells,
            },
            node_ids,
            vol_ids,
            faces,
            nsets,
            elsets,
            surfaces,
            maps,
            skipped,
            local,
            ranges,
            listing,
        })
    }

    /// Adds the assembly-level sets and surfaces, in file order: an `INSTANCE=` set resolves
    /// that instance's ids; ids without it are assembly nodes (reference points), skipped.
    fn assembly_sets(&mut self, blocks: &[Block], files: &Files, notes: &mut Notes) -> Result<()> {
        let empty_nodes = HashMap::new();
        let empty_elems = HashMap::new();
        let single = (self.maps.len() == 1)
            .then(|| self.maps.values().next())
            .flatten();
        let mut asm = Parser::new(files);
        for b in blocks {
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
                        Some(i) if self.skipped.contains(&upper(i)) => {
                            notes
                                .assembly_sets_skipped
                                .push(format!("{name} (instance {i})"));
                            continue;
                        }
                        Some(i) if !self.maps.contains_key(&upper(i)) => {
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
                (Some(i), _) => match self.maps.get(&upper(i)) {
                    Some(m) => (&m.node_index, &m.elem_index),
                    None => (&empty_nodes, &empty_elems),
                },
                // A surface listing element ids with a single instance: that instance's ids.
                (None, Some(m)) => (&m.node_index, &m.elem_index),
                (None, None) => (&empty_nodes, &empty_elems),
            };
            let mut r = Resolver::new(files, node_index, elem_index, &self.mesh, &self.faces);
            r.nsets = std::mem::take(&mut self.nsets);
            r.elsets = std::mem::take(&mut self.elsets);
            r.surfaces = std::mem::take(&mut self.surfaces);
            if let Some(i) = &instance {
                r.prefix = Some(upper(i));
                r.ctx = format!(" (in instance '{i}')");
            }
            let res = r.event(&event);
            self.nsets = r.nsets;
            self.elsets = r.elsets;
            self.surfaces = r.surfaces;
            res?;
        }
        notes.absorb(asm.notes);
        Ok(())
    }

    /// Plain names for part-level sets that only one instance has and the assembly does not
    /// define (so single-instance models keep the names of their part).
    fn plain_part_names(&mut self) {
        let (nsets, elsets, surfaces) = (&mut self.nsets, &mut self.elsets, &mut self.surfaces);
        for ((kind, key), defs) in std::mem::take(&mut self.local) {
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
    }
}
