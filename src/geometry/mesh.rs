//! A volume mesh of one element shape: node coordinates (m) and flat connectivity.

use nalgebra::Vector3;

/// Element shapes hytled meshes with. Node order follows VTK/ABAQUS: hex8 bottom face
/// 0-1-2-3 counter-clockwise seen from +z then top face 4-5-6-7 above them; tet4 with
/// positive volume (x1-x0).((x2-x0)x(x3-x0)) > 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ElementShape {
    Hex8,
    Tet4,
}

impl ElementShape {
    /// Nodes per element.
    pub fn nodes_per_cell(self) -> usize {
        match self {
            ElementShape::Hex8 => 8,
            ElementShape::Tet4 => 4,
        }
    }

    /// VTK cell type id (12 hexahedron, 10 tetrahedron).
    pub fn vtk_type(self) -> u8 {
        match self {
            ElementShape::Hex8 => 12,
            ElementShape::Tet4 => 10,
        }
    }
}

/// Refuses to make a mesh of about `nodes` nodes and `cells` elements of `shape` that would
/// not fit in memory ([`crate::memory::check`]): 24 bytes a node position and 8 a node index
/// of the connectivity. Counts are f64 so that any divisions a scene gives can be judged
/// without overflow.
pub fn check_mesh_memory(nodes: f64, cells: f64, shape: ElementShape) -> crate::Result<()> {
    let bytes = 24.0 * nodes + 8.0 * shape.nodes_per_cell() as f64 * cells;
    crate::memory::check(
        bytes,
        &format!(
            "the mesh ({} nodes, {} {} elements)",
            count(nodes),
            count(cells),
            match shape {
                ElementShape::Hex8 => "hex8",
                ElementShape::Tet4 => "tet4",
            }
        ),
        "raise discretization.size or lower discretization.divisions",
    )
}

/// A count for messages: exact below a trillion, else in scientific notation.
fn count(n: f64) -> String {
    if n < 1e12 {
        format!("{n:.0}")
    } else {
        format!("{n:.2e}")
    }
}

/// A single-shape volume mesh. Coordinates in metres.
#[derive(Debug, Clone)]
pub struct Mesh {
    pub nodes: Vec<Vector3<f64>>,
    pub shape: ElementShape,
    /// Flat connectivity, `shape.nodes_per_cell()` node indices per element.
    pub cells: Vec<usize>,
}

impl Mesh {
    /// Number of elements.
    pub fn num_cells(&self) -> usize {
        self.cells.len() / self.shape.nodes_per_cell()
    }

    /// Node indices of element `e`.
    pub fn cell(&self, e: usize) -> &[usize] {
        let n = self.shape.nodes_per_cell();
        &self.cells[e * n..(e + 1) * n]
    }

    /// Axis-aligned bounding box (min, max) of the nodes.
    pub fn bounding_box(&self) -> (Vector3<f64>, Vector3<f64>) {
        super::select::bounds(&self.nodes)
    }
}

/// Hexahedra split into six tets around the 0-6 diagonal (they tile each hex exactly, which is
/// all integration and the boundary triangles need; tets of neighbouring hexes need not match).
pub fn hex_to_tets(mesh: Mesh) -> Mesh {
    if mesh.shape == ElementShape::Tet4 {
        return mesh;
    }
    const SPLIT: [[usize; 4]; 6] = [
        [0, 1, 2, 6],
        [0, 2, 3, 6],
        [0, 3, 7, 6],
        [0, 7, 4, 6],
        [0, 4, 5, 6],
        [0, 5, 1, 6],
    ];
    let mut cells = Vec::with_capacity(mesh.num_cells() * 24);
    for e in 0..mesh.num_cells() {
        let c = mesh.cell(e);
        for t in SPLIT {
            let mut q = t.map(|a| c[a]);
            let p = |i: usize| mesh.nodes[q[i]];
            if super::quality::tet_signed_volume(&p(0), &p(1), &p(2), &p(3)) < 0.0 {
                q.swap(2, 3);
            }
            cells.extend(q);
        }
    }
    Mesh {
        nodes: mesh.nodes,
        shape: ElementShape::Tet4,
        cells,
    }
}
