//! Set resolution: node, element and surface sets from the recorded events, by name or id.

use std::collections::{HashMap, HashSet};

use crate::geometry::Mesh;
use crate::{Error, Result};

use super::elements::{element_face, num_faces, shape_name};
use super::events::{ElemRef, Item, Label, SetEvent, Target};
use super::lines::{upper, Files, Loc};

/// An element set being resolved: volume cells, surface elements, and whether it listed
/// ignored (line/point) elements.
#[derive(Default, Clone)]
pub(super) struct ElsetAcc {
    pub(super) name: String,
    pub(super) vol: Vec<usize>,
    pub(super) faces: Vec<usize>,
    pub(super) ignored: bool,
}

pub(super) struct Resolver<'a> {
    pub(super) files: &'a Files,
    pub(super) node_index: &'a HashMap<u64, usize>,
    pub(super) elem_index: &'a HashMap<u64, (ElemRef, Loc)>,
    pub(super) mesh: &'a Mesh,
    pub(super) faces: &'a [Vec<usize>],
    /// Keyed by upper-case name: (name as first written, node indices).
    pub(super) nsets: HashMap<String, (String, Vec<usize>)>,
    pub(super) elsets: HashMap<String, ElsetAcc>,
    pub(super) surfaces: HashMap<String, (String, Vec<Vec<usize>>)>,
    /// Upper-case instance name whose sets are looked up first (assembly sets with INSTANCE=).
    pub(super) prefix: Option<String>,
    /// Added to error messages (the instance).
    pub(super) ctx: String,
}

/// Finds a set by name, case-insensitively, also as `instance.name`.
pub(super) fn find<'m, T>(map: &'m HashMap<String, T>, name: &str) -> Option<&'m T> {
    let key = upper(name);
    map.get(&key)
        .or_else(|| key.rsplit_once('.').and_then(|(_, short)| map.get(short)))
}

impl<'a> Resolver<'a> {
    pub(super) fn new(
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

    pub(super) fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
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

    pub(super) fn event(&mut self, ev: &SetEvent) -> Result<()> {
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
