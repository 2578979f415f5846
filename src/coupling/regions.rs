//! Splitting a mesh into the FE layer that covers the boundary, the meshless interior and the
//! transition layer between them (coupled paper sect. 3.2; Krongauz & Belytschko 1996).

use crate::geometry::quality::boundary_faces;
use crate::geometry::Mesh;
use crate::{Error, InputKind, Result};

/// What a cell is in the coupled discretization.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellRole {
    /// FE layer, no node on the meshless side: TLED element kernel.
    Fe,
    /// FE layer with at least one interface node: blended shape functions, full Gauss rule.
    Transition,
    /// Interior: background cell of the meshless integration points.
    Meshless,
}

/// What a node is in the coupled discretization.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeRole {
    /// Node of FE cells only: interpolating (Kronecker delta), conditions imposed directly.
    Fe,
    /// Node shared by FE and meshless cells: ramp R = 1, an MLS node.
    Interface,
    /// Node of meshless cells only: an MLS node.
    Meshless,
}

/// Cell and node roles.
#[derive(Debug, Clone)]
pub struct Regions {
    pub cell: Vec<CellRole>,
    pub node: Vec<NodeRole>,
    /// Largest node depth (layers of cells between a node and the boundary).
    pub max_depth: usize,
}

impl Regions {
    /// Number of cells with role `r`.
    pub fn cells(&self, r: CellRole) -> usize {
        self.cell.iter().filter(|&&c| c == r).count()
    }

    /// Number of nodes with role `r`.
    pub fn nodes(&self, r: NodeRole) -> usize {
        self.node.iter().filter(|&&c| c == r).count()
    }
}

/// Where the FE layer of a coupled discretization lies.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum FeRegion {
    /// Along the whole boundary surface (free surfaces included).
    #[default]
    Surface,
    /// Around these nodes only (those of the essential boundaries: coupled paper sect. 3.2,
    /// "coupling MLS with FE in the close region of the essential boundary"); the rest of the
    /// surface is meshless.
    Around(Vec<usize>),
}

/// Node depth: 0 on the boundary surface (or, with [`FeRegion::Around`], at its nodes), else
/// 1 + the smallest depth of a node sharing a cell with it (cell-graph distance); usize::MAX
/// where no seed is reachable.
fn node_depth(mesh: &Mesh, region: &FeRegion) -> Result<Vec<usize>> {
    let mut depth = vec![usize::MAX; mesh.nodes.len()];
    match region {
        FeRegion::Surface => {
            let faces = boundary_faces(mesh)
                .map_err(|e| Error::input(InputKind::Discretization, format!("coupled: {e}")))?;
            for f in &faces {
                for &i in f {
                    depth[i] = 0;
                }
            }
        }
        FeRegion::Around(nodes) => {
            for &i in nodes {
                if let Some(d) = depth.get_mut(i) {
                    *d = 0;
                }
            }
        }
    }
    // Relaxation sweeps; the number of sweeps is the depth of the mesh (tens at most).
    loop {
        let mut changed = false;
        for e in 0..mesh.num_cells() {
            let c = mesh.cell(e);
            let d = c.iter().map(|&i| depth[i]).min().unwrap_or(usize::MAX);
            if d == usize::MAX {
                continue;
            }
            for &i in c {
                if depth[i] > d + 1 {
                    depth[i] = d + 1;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    Ok(depth)
}

/// The cells with a node within `fe_layers - 1` cell layers of the boundary (or of the
/// region's nodes) form the FE layer (so `fe_layers` = 1 is the cells touching it); the others
/// are meshless. Errors when the FE layer covers everything or nothing.
pub fn split(mesh: &Mesh, fe_layers: usize, region: &FeRegion) -> Result<Regions> {
    if fe_layers == 0 {
        return Err(Error::input(InputKind::Value,
            "discretization.fe_layers = 0: the coupled method needs at least one layer of finite elements on the boundary \
             (use method = 'meshless' for none)",
        ));
    }
    if let FeRegion::Around(nodes) = region {
        if nodes.is_empty() {
            return Err(Error::input(InputKind::Value,
                "discretization.fe_region = 'essential' but no boundary prescribes a displacement component: \
                 there is no essential boundary to put finite elements on (use fe_region = 'surface')",
            ));
        }
    }
    let depth = node_depth(mesh, region)?;
    let max_depth = depth
        .iter()
        .cloned()
        .filter(|&d| d != usize::MAX)
        .max()
        .unwrap_or(0);
    let mut cell: Vec<CellRole> = (0..mesh.num_cells())
        .map(|e| {
            let d = mesh.cell(e).iter().map(|&i| depth[i]).min().unwrap_or(0);
            if d < fe_layers {
                CellRole::Fe
            } else {
                CellRole::Meshless
            }
        })
        .collect();
    if !cell.contains(&CellRole::Meshless) {
        return Err(Error::input(InputKind::Value, format!(
            "discretization.fe_layers = {fe_layers} leaves no meshless interior: the mesh is only {} cell layer(s) deep; \
             lower fe_layers or refine the mesh (divisions / size)",
            max_depth
        )));
    }
    let mut in_fe = vec![false; mesh.nodes.len()];
    let mut in_ml = vec![false; mesh.nodes.len()];
    for (e, r) in cell.iter().enumerate() {
        for &i in mesh.cell(e) {
            match r {
                CellRole::Meshless => in_ml[i] = true,
                _ => in_fe[i] = true,
            }
        }
    }
    let node: Vec<NodeRole> = (0..mesh.nodes.len())
        .map(|i| match (in_fe[i], in_ml[i]) {
            (true, true) => NodeRole::Interface,
            (false, true) => NodeRole::Meshless,
            _ => NodeRole::Fe,
        })
        .collect();
    for (e, r) in cell.iter_mut().enumerate() {
        if *r == CellRole::Fe && mesh.cell(e).iter().any(|&i| node[i] == NodeRole::Interface) {
            *r = CellRole::Transition;
        }
    }
    Ok(Regions {
        cell,
        node,
        max_depth,
    })
}

/// Writes [`split_inputs`] of `mesh` as an ABAQUS file (`fe_path`) and a CSV cloud with an
/// `x,y,z` header (`cloud_path`, m). Returns (FE-layer nodes, cloud nodes).
pub fn write_split_inputs(
    mesh: &Mesh,
    fe_layers: usize,
    fe_path: &std::path::Path,
    cloud_path: &std::path::Path,
) -> Result<(usize, usize)> {
    let (fe, cloud) = split_inputs(mesh, fe_layers)?;
    let input = crate::io::model::MeshInput {
        node_ids: (1..=fe.nodes.len() as u64).collect(),
        element_ids: (1..=fe.num_cells() as u64).collect(),
        mesh: fe,
        node_sets: Default::default(),
        element_sets: Default::default(),
        face_sets: Default::default(),
        warnings: Vec::new(),
    };
    crate::io::inp::write_inp(fe_path, &input)?;
    let mut text = String::from("x,y,z\n");
    for p in &cloud {
        text.push_str(&format!("{:.17e},{:.17e},{:.17e}\n", p.x, p.y, p.z));
    }
    std::fs::write(cloud_path, text).map_err(|e| Error::io(cloud_path, e))?;
    Ok((input.mesh.nodes.len(), cloud.len()))
}

/// The FE layer of `mesh` as a mesh of its own (unused nodes dropped) and the positions (m) of
/// the meshless-only nodes: the two inputs of a mixed coupled scene, made from one mesh.
pub fn split_inputs(mesh: &Mesh, fe_layers: usize) -> Result<(Mesh, Vec<nalgebra::Vector3<f64>>)> {
    let r = split(mesh, fe_layers, &FeRegion::Surface)?;
    let mut map = vec![usize::MAX; mesh.nodes.len()];
    let mut nodes = Vec::new();
    let mut cells = Vec::new();
    for e in 0..mesh.num_cells() {
        if r.cell[e] == CellRole::Meshless {
            continue;
        }
        for &i in mesh.cell(e) {
            if map[i] == usize::MAX {
                map[i] = nodes.len();
                nodes.push(mesh.nodes[i]);
            }
            cells.push(map[i]);
        }
    }
    let cloud = (0..mesh.nodes.len())
        .filter(|&i| r.node[i] == NodeRole::Meshless)
        .map(|i| mesh.nodes[i])
        .collect();
    Ok((
        Mesh {
            nodes,
            shape: mesh.shape,
            cells,
        },
        cloud,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes;

    #[test]
    fn box_layers() {
        let mesh = shapes::box_hex(
            nalgebra::Vector3::zeros(),
            nalgebra::Vector3::new(1.0, 1.0, 1.0),
            [6, 6, 6],
        )
        .unwrap();
        let r = split(&mesh, 1, &FeRegion::Surface).unwrap();
        // 6^3 cells: the outer shell (6^3 - 4^3) is FE, all of it touching the 4^3 core.
        assert_eq!(r.cells(CellRole::Meshless), 64);
        assert_eq!(r.cells(CellRole::Transition), 216 - 64);
        assert_eq!(r.cells(CellRole::Fe), 0);
        // Interface: the 5^3 - 3^3 shell of nodes at depth 1.
        assert_eq!(r.nodes(NodeRole::Interface), 125 - 27);
        assert_eq!(r.nodes(NodeRole::Meshless), 27);
        let r = split(&mesh, 2, &FeRegion::Surface).unwrap();
        assert_eq!(r.cells(CellRole::Meshless), 8);
        assert_eq!(r.cells(CellRole::Transition), 64 - 8);
        assert_eq!(r.cells(CellRole::Fe), 216 - 64);
        assert!(split(&mesh, 3, &FeRegion::Surface).is_err());
        assert!(split(&mesh, 0, &FeRegion::Surface).is_err());
    }
}
