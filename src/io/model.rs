//! What every mesh reader produces: a single-shape volume mesh with the file's named node sets,
//! element sets and boundary-face sets, in file order, coordinates as written (the scene's
//! `units` factor is applied later).

use std::collections::BTreeMap;

use crate::geometry::Mesh;

/// A mesh read from a file, with its named sets. Indices are 0-based positions in `mesh.nodes`
/// and in the mesh's cells (not the file's ids, which may be sparse and unordered).
#[derive(Debug, Clone)]
pub struct MeshInput {
    pub mesh: Mesh,
    /// The file's id of each node (ABAQUS / Gmsh node numbers; VTK: the index).
    pub node_ids: Vec<u64>,
    /// The file's id of each volume cell.
    pub element_ids: Vec<u64>,
    /// Named node sets (ABAQUS *NSET, Gmsh physical groups, VTK integer point arrays), node indices ascending.
    pub node_sets: BTreeMap<String, Vec<usize>>,
    /// Named element sets (volume cells), cell indices ascending.
    pub element_sets: BTreeMap<String, Vec<usize>>,
    /// Named boundary faces (surface elements written beside the volume, *SURFACE): node-index
    /// triangles or quadrilaterals.
    pub face_sets: BTreeMap<String, Vec<Vec<usize>>>,
    /// Things worth telling the user that do not stop the read.
    pub warnings: Vec<String>,
}

impl MeshInput {
    /// Node indices of a set by name: a node set, or the nodes of an element or face set.
    /// Unknown names are an error listing the available ones.
    pub fn set_nodes(&self, name: &str) -> std::result::Result<Vec<usize>, String> {
        let mut v: Vec<usize> = if let Some(n) = self.node_sets.get(name) {
            n.clone()
        } else if let Some(e) = self.element_sets.get(name) {
            e.iter().flat_map(|&c| self.mesh.cell(c).to_vec()).collect()
        } else if let Some(f) = self.face_sets.get(name) {
            f.iter().flatten().cloned().collect()
        } else {
            return Err(format!(
                "no set named '{name}' in the mesh; available: {}",
                self.set_names().join(", ")
            ));
        };
        v.sort_unstable();
        v.dedup();
        Ok(v)
    }

    /// All set names (node, element and face sets), sorted.
    pub fn set_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .node_sets
            .keys()
            .chain(self.element_sets.keys())
            .chain(self.face_sets.keys())
            .cloned()
            .collect();
        v.sort();
        v.dedup();
        if v.is_empty() {
            v.push("(none)".into());
        }
        v
    }
}
