//! The writer: a mesh and its sets as an `.inp` deck.

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;
use std::path::Path;

use crate::geometry::ElementShape;
use crate::io::model::MeshInput;
use crate::{Error, InputKind, Result};

use super::elements::shape_name;
use super::lines::upper;

/// A name as a parameter value: quoted when it has blanks; error when `.inp` cannot carry it.
fn name_value(kind: &str, name: &str, path: &Path) -> Result<String> {
    if name.is_empty() {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "{}: a {kind} with an empty name cannot be written to .inp",
                path.display()
            ),
        ));
    }
    if name
        .chars()
        .any(|c| matches!(c, ',' | '"' | '=') || c.is_control())
    {
        return Err(Error::input(InputKind::Value, format!(
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
                return Err(Error::input(InputKind::Value, format!(
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

pub(super) fn format_inp(m: &MeshInput, path: &Path) -> Result<String> {
    let bad = |msg: String| Error::input(InputKind::Value, format!("{}: {msg}", path.display()));
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
