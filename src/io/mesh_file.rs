//! Reading any supported mesh file by format, with the scene's unit factor and the checks a
//! mesh needs before it is used.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::model::MeshInput;
use crate::{Error, InputKind, Result};

/// Mesh file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// ABAQUS input file.
    Inp,
    /// Gmsh 2.2 or 4.1.
    Msh,
    /// VTK legacy.
    Vtk,
    /// VTK XML unstructured grid.
    Vtu,
}

impl MeshFormat {
    /// From a file extension (case-insensitive).
    pub fn from_path(path: &Path) -> Option<Self> {
        let e = path.extension()?.to_string_lossy().to_lowercase();
        match e.as_str() {
            "inp" => Some(MeshFormat::Inp),
            "msh" => Some(MeshFormat::Msh),
            "vtk" => Some(MeshFormat::Vtk),
            "vtu" => Some(MeshFormat::Vtu),
            _ => None,
        }
    }
}

/// Reads `path` in `format` (default: from the extension) and scales its coordinates by
/// `units` (file length unit in m).
pub fn read_mesh(path: &Path, format: Option<MeshFormat>, units: f64) -> Result<MeshInput> {
    let format = format
        .or_else(|| MeshFormat::from_path(path))
        .ok_or_else(|| {
            Error::input(
                InputKind::Format,
                format!(
                    "{}: unknown mesh format; use .inp, .msh, .vtk or .vtu, or set geometry.format",
                    path.display()
                ),
            )
        })?;
    let mut m = read_raw(path, format)?;
    drop_unused_nodes(&mut m);
    if units != 1.0 {
        for p in m.mesh.nodes.iter_mut() {
            *p *= units;
        }
    }
    Ok(m)
}

fn read_raw(path: &Path, format: MeshFormat) -> Result<MeshInput> {
    match format {
        MeshFormat::Inp => super::inp::read_inp(path),
        MeshFormat::Msh => super::msh::read_msh(path),
        MeshFormat::Vtk | MeshFormat::Vtu => super::vtk::read_vtk(path),
    }
}

/// Removes nodes no volume cell uses (mesh generators keep geometry points and surface-only
/// nodes), renumbering cells and sets, with a warning that counts them.
fn drop_unused_nodes(m: &mut MeshInput) {
    let n = m.mesh.nodes.len();
    let mut used = vec![false; n];
    for &c in &m.mesh.cells {
        if c < n {
            used[c] = true;
        }
    }
    let unused = used.iter().filter(|u| !**u).count();
    if unused == 0 {
        return;
    }
    let mut map = vec![usize::MAX; n];
    let mut k = 0;
    for i in 0..n {
        if used[i] {
            map[i] = k;
            k += 1;
        }
    }
    let keep = |v: &[usize]| -> Vec<usize> {
        v.iter()
            .filter_map(|&i| map.get(i).copied().filter(|&j| j != usize::MAX))
            .collect()
    };
    m.mesh.nodes = (0..n)
        .filter(|&i| used[i])
        .map(|i| m.mesh.nodes[i])
        .collect();
    m.node_ids = (0..n.min(m.node_ids.len()))
        .filter(|&i| used[i])
        .map(|i| m.node_ids[i])
        .collect();
    m.mesh.cells = m.mesh.cells.iter().map(|&c| map[c]).collect();
    for v in m.node_sets.values_mut() {
        *v = keep(v);
    }
    for faces in m.face_sets.values_mut() {
        faces.retain(|f| {
            f.iter()
                .all(|&i| map.get(i).is_some_and(|&j| j != usize::MAX))
        });
        for f in faces.iter_mut() {
            *f = keep(f);
        }
    }
    m.warnings.push(format!(
        "{unused} node(s) belong to no volume cell and were dropped"
    ));
}

/// Writes a mesh with its node and element sets as VTU: each node set becomes a point array
/// (1 on its nodes, 0 elsewhere) and each element set a cell array, named after the set, which
/// the VTK reader turns back into sets of the same name. Face sets are not written (a VTU piece
/// here holds the volume cells only).
pub fn write_mesh_vtu(path: &Path, m: &MeshInput, format: super::vtu::VtuFormat) -> Result<()> {
    let n = m.mesh.nodes.len();
    let ne = m.mesh.num_cells();
    // 1 on the set's members, 0 elsewhere.
    let indicator = |len: usize, v: &[usize]| -> Vec<f64> {
        let mut a = vec![0.0; len];
        for &i in v {
            if let Some(x) = a.get_mut(i) {
                *x = 1.0;
            }
        }
        a
    };
    let node_arrays: Vec<(String, Vec<f64>)> = m
        .node_sets
        .iter()
        .map(|(name, v)| (name.clone(), indicator(n, v)))
        .collect();
    let cell_arrays: Vec<(String, Vec<f64>)> = m
        .element_sets
        .iter()
        .map(|(name, v)| (name.clone(), indicator(ne, v)))
        .collect();
    let pd = node_arrays
        .iter()
        .map(|(name, a)| super::vtu::DataArray {
            name,
            components: 1,
            values: a,
        })
        .collect();
    let cd = cell_arrays
        .iter()
        .map(|(name, a)| super::vtu::DataArray {
            name,
            components: 1,
            values: a,
        })
        .collect();
    super::vtu::write_mesh(path, &m.mesh, pd, cd, format)
}

/// Writes a mesh with its sets in the format of `path`'s extension: `.vtu` (sets as arrays, see
/// [`write_mesh_vtu`]) or `.inp` (ABAQUS, sets as *NSET / *ELSET, face sets as surface elements).
pub fn write_mesh_file(
    path: &Path,
    m: &MeshInput,
    vtu_format: super::vtu::VtuFormat,
) -> Result<()> {
    match MeshFormat::from_path(path) {
        Some(MeshFormat::Vtu) => write_mesh_vtu(path, m, vtu_format),
        Some(MeshFormat::Inp) => super::inp::write_inp(path, m),
        _ => Err(Error::input(
            InputKind::Value,
            format!(
                "{}: hytled convert writes .vtu and .inp; choose one of those extensions",
                path.display()
            ),
        )),
    }
}

/// Groups nodes that coincide within 1e-9 x the bounding-box diagonal: for every node, the new
/// index of its group, and the first node (by index) of each group.
pub fn coincident_nodes(mesh: &crate::geometry::Mesh) -> (Vec<usize>, Vec<usize>) {
    let n = mesh.nodes.len();
    let (lo, hi) = mesh.bounding_box();
    let tol = (1e-9 * (hi - lo).norm()).max(f64::MIN_POSITIVE);
    let key = |p: &nalgebra::Vector3<f64>| {
        [
            (p.x / tol).round() as i64,
            (p.y / tol).round() as i64,
            (p.z / tol).round() as i64,
        ]
    };
    let mut first: std::collections::HashMap<[i64; 3], usize> = Default::default();
    let mut map = vec![0usize; n];
    let mut keep = Vec::with_capacity(n);
    for i in 0..n {
        match first.get(&key(&mesh.nodes[i])) {
            Some(&j) => map[i] = map[j],
            None => {
                first.insert(key(&mesh.nodes[i]), i);
                map[i] = keep.len();
                keep.push(i);
            }
        }
    }
    (map, keep)
}

/// Merges nodes closer than 1e-9 x the bounding-box diagonal into the first of them (by index),
/// renumbering cells and sets; returns how many were merged.
pub fn merge_duplicate_nodes(m: &mut MeshInput) -> usize {
    let n = m.mesh.nodes.len();
    if n == 0 {
        return 0;
    }
    let (map, keep) = coincident_nodes(&m.mesh);
    let merged = n - keep.len();
    if merged == 0 {
        return 0;
    }
    m.mesh.nodes = keep.iter().map(|&i| m.mesh.nodes[i]).collect();
    m.node_ids = keep
        .iter()
        .filter_map(|&i| m.node_ids.get(i).copied())
        .collect();
    for c in m.mesh.cells.iter_mut() {
        *c = map[*c];
    }
    let remap = |v: &mut Vec<usize>| {
        for x in v.iter_mut() {
            *x = map[*x];
        }
    };
    for v in m.node_sets.values_mut() {
        remap(v);
        v.sort_unstable();
        v.dedup();
    }
    for faces in m.face_sets.values_mut() {
        for f in faces.iter_mut() {
            remap(f);
        }
    }
    merged
}

/// Renames the sets whose names ABAQUS cannot carry (',', '"', '=' or control characters, e.g.
/// meshio's "gmsh:geometrical=1") by replacing those characters with '_' (and appending '_2',
/// '_3', ... on a clash). Returns one message per renamed set.
pub fn inp_safe_set_names(m: &mut MeshInput) -> Vec<String> {
    fn fix<T>(
        kind: &str,
        sets: &mut std::collections::BTreeMap<String, T>,
        msgs: &mut Vec<String>,
    ) {
        let bad: Vec<String> = sets
            .keys()
            .filter(|n| {
                n.chars()
                    .any(|c| matches!(c, ',' | '"' | '=') || c.is_control())
            })
            .cloned()
            .collect();
        for old in bad {
            let base: String = old
                .chars()
                .map(|c| {
                    if matches!(c, ',' | '"' | '=') || c.is_control() {
                        '_'
                    } else {
                        c
                    }
                })
                .collect();
            let mut new = base.clone();
            let mut k = 2;
            while sets.keys().any(|n| n.eq_ignore_ascii_case(&new)) {
                new = format!("{base}_{k}");
                k += 1;
            }
            if let Some(v) = sets.remove(&old) {
                sets.insert(new.clone(), v);
                msgs.push(format!("{kind} '{old}' renamed '{new}' for .inp"));
            }
        }
    }
    let mut msgs = Vec::new();
    fix("node set", &mut m.node_sets, &mut msgs);
    fix("element set", &mut m.element_sets, &mut msgs);
    fix("face set", &mut m.face_sets, &mut msgs);
    msgs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{ElementShape, Mesh};
    use nalgebra::Vector3;

    #[test]
    fn duplicate_nodes_merge_and_renumber_cells_and_sets() {
        // Two tets sharing a face, written with the shared nodes duplicated.
        let p = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(1.0, 1.0, 1.0),
        ];
        let mut m = MeshInput {
            mesh: Mesh {
                nodes: p.to_vec(),
                shape: ElementShape::Tet4,
                cells: vec![0, 1, 2, 3, 4, 6, 5, 7],
            },
            node_ids: (1..=8).collect(),
            element_ids: vec![1, 2],
            node_sets: [("s".to_string(), vec![4, 7])].into_iter().collect(),
            element_sets: Default::default(),
            face_sets: Default::default(),
            warnings: Vec::new(),
        };
        assert_eq!(merge_duplicate_nodes(&mut m), 3);
        assert_eq!(m.mesh.nodes.len(), 5);
        assert_eq!(m.mesh.cells, vec![0, 1, 2, 3, 1, 3, 2, 4]);
        assert_eq!(m.node_sets["s"], vec![1, 4]);
        assert_eq!(m.node_ids, vec![1, 2, 3, 4, 8]);
    }
}
