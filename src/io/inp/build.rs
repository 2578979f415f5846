//! The mesh and sets of a deck read as one body.

use std::collections::{BTreeMap, HashMap, HashSet};

use crate::geometry::quality::tet_signed_volume;
use crate::geometry::{ElementShape, Mesh};
use crate::io::model::MeshInput;

use super::events::{ElemRef, Notes};
use super::lines::Loc;
use super::sets::ElsetAcc;

/// A mesh body with its sets, resolved.
pub(super) struct Body {
    pub(super) mesh: Mesh,
    pub(super) shape: Option<ElementShape>,
    pub(super) node_ids: Vec<u64>,
    pub(super) node_index: HashMap<u64, usize>,
    pub(super) vol_ids: Vec<u64>,
    pub(super) elem_index: HashMap<u64, (ElemRef, Loc)>,
    pub(super) faces: Vec<Vec<usize>>,
    pub(super) nsets: HashMap<String, (String, Vec<usize>)>,
    pub(super) elsets: HashMap<String, ElsetAcc>,
    pub(super) surfaces: HashMap<String, (String, Vec<Vec<usize>>)>,
}

/// The [`MeshInput`] of a resolved body: sets by their names, the notes as warnings, and the
/// unused-node and inverted-element checks (`label` names an element by its index).
pub(super) fn build_input(body: Body, notes: Notes, label: impl Fn(usize) -> String) -> MeshInput {
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
