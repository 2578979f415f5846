//! Hybrid FE + meshless discretization: finite elements on the boundary, MLS nodes inside,
//! FE and MLS shape functions blended by a ramp in the transition layer (Horton et al. 2010
//! conclusions; coupled paper `mtled-fe-coupled-ebc-cylinder.txt` sect. 3.2, after Krongauz &
//! Belytschko 1996).
//!
//! In a transition cell the ramp R(X) = sum of the cell's FE shape functions N_I over its
//! interface nodes (R = 0 on the FE side, 1 on the meshless side) and the shape functions are
//! phi_I = (1 - R) N_I + R phi_I^MLS, dphi_I = (1 - R) dN_I + R dphi_I^MLS + (phi_I^MLS - N_I) dR.
//! They reproduce linear fields exactly (both families do), so the patch test holds through
//! the transition layer. Every point, FE, blended or meshless, ends up in the one
//! [`QuadraturePoints`] list the solver uses.

pub mod mixed;
pub mod quadratic;
pub mod regions;

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::fe::{self, hex8, tet4, ElementKind};
use crate::geometry::cell_grid::CellGrid;
use crate::geometry::{ElementShape, Mesh};
use crate::meshless::discretize::hex_to_tets;
use crate::meshless::mls::MlsSettings;
use crate::meshless::points::{build_points, shape_at};
use crate::meshless::support::{Support, SupportRule};
use crate::probe::locate_in_grid;
use crate::quadrature::{PointKind, QuadraturePoints, SparseRow};
use crate::{Error, InputKind, Result};
pub use regions::{CellRole, FeRegion, NodeRole, Regions};

/// Settings of a coupled build.
#[derive(Debug, Clone)]
pub struct CoupledSettings {
    /// Cell layers of finite elements from the boundary inwards (>= 1).
    pub fe_layers: usize,
    /// Where the FE layer lies: the whole surface or around the essential boundaries.
    pub fe_region: FeRegion,
    /// Element formulation of the pure FE cells (hex8 needs a hex mesh).
    pub element: ElementKind,
    /// Hex8 hourglass coefficient kappa_hg and the modulus that scales it (Pa).
    pub hourglass: f64,
    pub hourglass_modulus: f64,
    pub mls: MlsSettings,
    pub rule: SupportRule,
    /// Influence-radius factor of the interface nodes (radius rule): their supports must
    /// reach across the transition layer, where only one side has MLS nodes.
    pub interface_scale: f64,
    /// Mean dilatation over each transition cell's Gauss points (no volumetric locking).
    pub mean_dilatation: bool,
    /// Tet interiors: face-connected interior tets per mean-dilatation patch
    /// ([`crate::meshless::integration::tet_patches`]); 1 = each point its own J.
    pub mean_dilatation_patch: usize,
    /// Points of the transition cells.
    pub transition_rule: TransitionRule,
    /// Nodes of loads concentrated on a few nodes (a small driven footprint): transition
    /// cells within two cells of them take the full rule whatever `transition_rule` says.
    pub full_rule_near: Vec<usize>,
    /// Integration points per interior background tet (1, 4 or 5).
    pub tet_rule: crate::meshless::integration::TetRule,
    /// Adaptive integration of the interior tets (thesis chapter 5) instead of `tet_rule`
    /// alone; its base rule is `tet_rule`.
    pub adaptive: Option<crate::meshless::adaptive::AdaptiveSettings>,
    /// Interior tets merged per integration point (1: `tet_rule` in every tet; see
    /// [`crate::meshless::integration::cluster_tets`]).
    pub tets_per_point: f64,
}

/// A built coupled discretization over a mesh whose vertices are all nodes.
pub struct CoupledBuild {
    /// Nodes, m: the mesh vertices (FE, interface and meshless nodes).
    pub nodes: Vec<Vector3<f64>>,
    /// The FE layer's cells (pure FE and transition) over `nodes`.
    pub fe_mesh: Mesh,
    /// The interior's background cells over `nodes`: hexahedra (2x2x2 Gauss points each) when
    /// the coupled mesh is hexahedral, else tets (`tet_rule` points each).
    pub interior: Mesh,
    /// Roles: `cell` has one entry per FE-layer cell (Fe or Transition), `node` one per node.
    pub regions: Regions,
    pub points: QuadraturePoints,
    /// Cell of each quadrature point: FE-layer cells first, then interior cells
    /// (index `fe_mesh.num_cells() + cell`).
    pub owner: Vec<usize>,
    /// For each cell in `owner`'s numbering, the cell of the input mesh it is (None for
    /// interior cells made from a node cloud).
    pub source_cell: Vec<Option<usize>>,
    /// Global ids of the MLS nodes (interface + meshless), ascending; `support` indexes them.
    pub mls_nodes: Vec<usize>,
    pub support: Support,
    pub mls: MlsSettings,
    /// Lumped volume of each node (m^3; [`Self::lumped_masses`] at unit density).
    pub lumped_volume: Vec<f64>,
    /// |phi| of every slot of the blended points, in point and slot order: their lumping.
    blend_phi_abs: Vec<f64>,
    /// Points per family: pure FE, blended (transition), meshless.
    pub fe_points: usize,
    pub transition_points: usize,
    pub meshless_points: usize,
    /// Transition cells given the full rule near a concentrated drive
    /// ([`CoupledSettings::full_rule_near`]) under [`TransitionRule::Interior`].
    pub full_rule_cells: usize,
    pub warnings: Vec<String>,
    /// What adaptive integration of the interior did (None without it).
    pub adaptive: Option<crate::report::AdaptiveInfo>,
    /// Adaptive integration: the interior points' positions (m) and refinement levels, in the
    /// order of the last `meshless_points` quadrature points.
    pub adaptive_points: Option<(Vec<Vector3<f64>>, Vec<u8>)>,
    /// `element = "tet10"`: the FE layer's edge nodes (after the mesh's vertices in `nodes`)
    /// and each FE-layer cell's ten nodes.
    pub quadratic: Option<quadratic::Quadratic>,
    /// Point location in `fe_mesh` and `interior` ([`Self::shape_values`]).
    fe_grid: CellGrid,
    interior_grid: CellGrid,
}

impl CoupledBuild {
    /// (mean, min, max) support nodes per meshless and transition point.
    pub fn support_statistics(&self) -> (f64, usize, usize) {
        let sizes: Vec<usize> = (self.fe_points..self.points.len())
            .map(|p| self.points.slots(p).len())
            .collect();
        match (sizes.iter().min(), sizes.iter().max()) {
            (Some(&lo), Some(&hi)) => (
                sizes.iter().sum::<usize>() as f64 / sizes.len() as f64,
                lo,
                hi,
            ),
            _ => (0.0, 0, 0),
        }
    }

    /// Lumped nodal masses, kg, with `density(p)` (kg/m^3) at point `p` (this build's order):
    /// a blended point's mass goes to its nodes in proportion to |phi_I| (the row sums of its
    /// consistent mass), the others' evenly. An even split starves the FE nodes of a
    /// transition cell next to an essential boundary: each blended point has 30-50 nodes, so
    /// a face node got a few percent of its cells' volume and set a stable step 3x shorter
    /// than the pure methods' (4,208-node Gmsh cylinder, fe_layers = 1 around the driven
    /// faces: 5.4e-5 s against 2.2e-4 s for MMLS on the same nodes). Sums run over the FE,
    /// the meshless, then the blended points.
    pub fn lumped_masses(&self, density: &dyn Fn(usize) -> f64) -> Vec<f64> {
        let qp = &self.points;
        let mut mass = vec![0.0; self.nodes.len()];
        let blended = self.fe_points..self.fe_points + self.transition_points;
        let (corner, edge) = crate::fe::tet10::MASS_SHARES;
        for p in (0..self.fe_points).chain(blended.end..qp.len()) {
            let r = qp.slots(p);
            let m = density(p) * qp.weights[p];
            if p < self.fe_points && self.quadratic.is_some() {
                // HRZ: each of an element's four points carries a quarter of its mass.
                for (a, &i) in qp.nodes[r].iter().enumerate() {
                    mass[i as usize] += m * if a < 4 { corner } else { edge };
                }
                continue;
            }
            let share = m / r.len() as f64;
            for &i in &qp.nodes[r] {
                mass[i as usize] += share;
            }
        }
        let mut at = 0;
        for p in blended {
            let r = qp.slots(p);
            let phi = &self.blend_phi_abs[at..at + r.len()];
            at += r.len();
            let sum: f64 = phi.iter().sum();
            let w = density(p) * qp.weights[p];
            for (&i, ph) in qp.nodes[r].iter().zip(phi) {
                mass[i as usize] += w * ph / sum;
            }
        }
        mass
    }

    /// MLS values at `x` (m) in global node ids.
    fn mls_values(&self, x: &Vector3<f64>, what: &dyn Fn() -> String) -> Result<SparseRow> {
        let s = shape_at(&self.support, &self.mls, x, false, what)?;
        Ok(s.ids
            .iter()
            .zip(&s.phi)
            .map(|(&i, &p)| (self.mls_nodes[i] as u32, p))
            .collect())
    }

    /// Shape-function values at `x` (m): FE inside pure FE cells, blended in transition
    /// cells, MLS in the interior. `what` names the point in errors.
    pub fn shape_values(&self, x: &Vector3<f64>, what: &dyn Fn() -> String) -> Result<SparseRow> {
        // Inside an interior cell (not just near one): MLS.
        let inner = locate_in_grid(x, &self.interior, &self.interior_grid, what).ok();
        if inner
            .as_ref()
            .is_some_and(|p| p.weights.iter().all(|&w| w >= -1e-12))
        {
            return self.mls_values(x, what);
        }
        let at = match (locate_in_grid(x, &self.fe_mesh, &self.fe_grid, what), inner) {
            (Ok(p), _) => p,
            (Err(_), Some(_)) => return self.mls_values(x, what),
            (Err(e), None) => return Err(e),
        };
        self.layer_values(at.element, &at.nodes, &at.weights, x, what)
    }

    /// Shape-function values at `x` (m) on FE-layer cell `e` (`Some(e)`), or in the interior
    /// (`None`), without searching for the cell: for points known to lie on a cell, such as
    /// the Gauss points of its boundary faces. `what` names the point in errors.
    pub fn shape_values_in(
        &self,
        cell: Option<usize>,
        x: &Vector3<f64>,
        what: &dyn Fn() -> String,
    ) -> Result<SparseRow> {
        let Some(e) = cell else {
            return self.mls_values(x, what);
        };
        let ids = self.fe_mesh.cell(e);
        let w: Vec<f64> = match self.fe_mesh.shape {
            ElementShape::Hex8 => {
                let c: [Vector3<f64>; 8] = std::array::from_fn(|a| self.nodes[ids[a]]);
                let xi = hex8::natural_coordinates(&c, x).ok_or_else(|| {
                    Error::input(
                        InputKind::Discretization,
                        format!("{}: not on FE-layer cell {e}", what()),
                    )
                })?;
                hex8::shape(xi).to_vec()
            }
            ElementShape::Tet4 => {
                let c: [Vector3<f64>; 4] = std::array::from_fn(|a| self.nodes[ids[a]]);
                tet4::barycentric(&c, x)
                    .ok_or_else(|| {
                        Error::input(
                            InputKind::Discretization,
                            format!("{}: not on FE-layer cell {e}", what()),
                        )
                    })?
                    .to_vec()
            }
        };
        self.layer_values(e, ids, &w, x, what)
    }

    /// Values at `x` on FE-layer cell `e` whose nodes `ids` have FE shape-function values
    /// `w` there: FE in pure FE cells, blended with MLS by the ramp r = sum of the interface
    /// nodes' FE values in transition cells.
    fn layer_values(
        &self,
        e: usize,
        ids: &[usize],
        w: &[f64],
        x: &Vector3<f64>,
        what: &dyn Fn() -> String,
    ) -> Result<SparseRow> {
        // The ramp: the interface vertices' linear (barycentric or trilinear) values.
        let r: f64 = ids
            .iter()
            .zip(w)
            .filter(|(&i, _)| self.regions.node[i] == NodeRole::Interface)
            .map(|(_, &w)| w)
            .sum();
        // A quadratic layer's own functions at the barycentric coordinates `w`.
        let quad: Option<Vec<(usize, f64)>> = self
            .quadratic
            .as_ref()
            .map(|q| q.values(e, [w[0], w[1], w[2], w[3]]));
        let (ids, w): (Vec<usize>, Vec<f64>) = match quad {
            Some(v) => v.into_iter().unzip(),
            None => (ids.to_vec(), w.to_vec()),
        };
        let (ids, w) = (&ids[..], &w[..]);
        match self.regions.cell[e] {
            CellRole::Fe => Ok(ids
                .iter()
                .map(|&i| i as u32)
                .zip(w.iter().copied())
                .collect()),
            CellRole::Meshless => self.mls_values(x, what),
            CellRole::Transition => {
                let mut acc: std::collections::BTreeMap<u32, f64> = Default::default();
                for (i, v) in self.mls_values(x, what)? {
                    *acc.entry(i).or_default() += r * v;
                }
                for (&i, &v) in ids.iter().zip(w) {
                    *acc.entry(i as u32).or_default() += (1.0 - r) * v;
                }
                Ok(acc.into_iter().collect())
            }
        }
    }

    /// VTU cells: the FE-layer cells then the interior tets, as (connectivity, offsets, VTK types).
    pub fn vtu_cells(&self) -> (Vec<usize>, Vec<usize>, Vec<u8>) {
        let mut conn = self.fe_mesh.cells.clone();
        conn.extend_from_slice(&self.interior.cells);
        let npc = self.fe_mesh.shape.nodes_per_cell();
        let nf = self.fe_mesh.num_cells();
        let ni = self.interior.num_cells();
        let npi = self.interior.shape.nodes_per_cell();
        let mut offsets: Vec<usize> = (1..=nf).map(|e| e * npc).collect();
        offsets.extend((1..=ni).map(|e| nf * npc + npi * e));
        let mut types = vec![self.fe_mesh.shape.vtk_type(); nf];
        types.extend(std::iter::repeat_n(self.interior.shape.vtk_type(), ni));
        (conn, offsets, types)
    }

    /// Weights that give the displacement at each mesh vertex: the node itself for FE nodes
    /// (interpolating), the MLS values at interface and meshless nodes.
    pub fn vertex_weights(&self) -> Result<Vec<SparseRow>> {
        (0..self.nodes.len())
            .map(|v| self.vertex_weights_of(v, &|| format!("output vertex {v}")))
            .collect()
    }

    /// [`Self::vertex_weights`] of vertex `v` alone; `what` names it in errors.
    pub fn vertex_weights_of(&self, v: usize, what: &dyn Fn() -> String) -> Result<SparseRow> {
        match self.regions.node[v] {
            NodeRole::Fe => Ok(vec![(v as u32, 1.0)]),
            _ => self.mls_values(&self.nodes[v], what),
        }
    }
}

/// Points of the transition cells' rule in natural coordinates (xi, weight in the reference
/// cell): the full rule, or for tets the interior's `tet_rule` when `rule` is
/// [`TransitionRule::Interior`].
fn transition_gauss(shape: ElementShape, s: &CoupledSettings) -> Vec<([f64; 4], f64)> {
    match (shape, s.transition_rule) {
        (ElementShape::Tet4, TransitionRule::Interior) => s.tet_rule.table().to_vec(),
        _ => gauss(shape),
    }
}

/// Nodes of the cells that hold one of `nodes` (their first ring): a transition cell with
/// one of these is at most two cells from them and takes the full rule.
fn full_rule_nodes(mesh: &Mesh, nodes: &[usize]) -> Vec<bool> {
    let n = mesh.nodes.len();
    let mut seed = vec![false; n];
    for &i in nodes.iter().filter(|&&i| i < n) {
        seed[i] = true;
    }
    let mut ring = seed.clone();
    for e in 0..mesh.num_cells() {
        let c = mesh.cell(e);
        if c.iter().any(|&i| seed[i]) {
            for &i in c {
                ring[i] = true;
            }
        }
    }
    ring
}

/// How the blended points of a transition cell are placed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TransitionRule {
    /// Full Gauss rule: 2x2x2 (hexahedra), the degree-2 four-point rule (tets).
    #[default]
    Full,
    /// Tets: the interior's `tet_rule` (1 point by default), so the transition layer is
    /// integrated like the meshless cells next to it; hexahedra keep 2x2x2.
    Interior,
}

/// Gauss points of a full rule in the cell's natural coordinates: (xi, weight in the
/// reference cell). Hex: 2x2x2 Gauss-Legendre; tet: barycentric degree-2 four-point rule.
fn gauss(shape: ElementShape) -> Vec<([f64; 4], f64)> {
    match shape {
        ElementShape::Hex8 => {
            let g = 1.0 / 3f64.sqrt();
            let mut v = Vec::with_capacity(8);
            for k in [-g, g] {
                for j in [-g, g] {
                    for i in [-g, g] {
                        v.push(([i, j, k, 0.0], 1.0));
                    }
                }
            }
            v
        }
        ElementShape::Tet4 => {
            const A: f64 = 0.585_410_196_624_968_5;
            const B: f64 = 0.138_196_601_125_010_5;
            vec![
                ([A, B, B, B], 0.25),
                ([B, A, B, B], 0.25),
                ([B, B, A, B], 0.25),
                ([B, B, B, A], 0.25),
            ]
        }
    }
}

/// FE shape functions, their reference derivatives (1/m), the position (m) and the weight
/// (m^3) at Gauss point `g` of cell `x`.
type FePoint = (Vec<f64>, Vec<Vector3<f64>>, Vector3<f64>, f64);

fn fe_point(
    shape: ElementShape,
    x: &[Vector3<f64>],
    g: &([f64; 4], f64),
) -> std::result::Result<FePoint, f64> {
    match shape {
        ElementShape::Hex8 => {
            let xs: [Vector3<f64>; 8] = std::array::from_fn(|a| x[a]);
            let xi = [g.0[0], g.0[1], g.0[2]];
            let n = hex8::shape(xi);
            let dn = hex8::shape_derivatives(xi);
            let j: Matrix3<f64> = hex8::jacobian(&xs, xi);
            let det = j.determinant();
            let jinv_t = j.try_inverse().ok_or(det)?.transpose();
            if !(det > 0.0) {
                return Err(det);
            }
            let pos = xs
                .iter()
                .zip(&n)
                .fold(Vector3::zeros(), |a, (p, w)| a + p * *w);
            Ok((
                n.to_vec(),
                dn.iter().map(|d| jinv_t * d).collect(),
                pos,
                det * g.1,
            ))
        }
        ElementShape::Tet4 => {
            let xs: [Vector3<f64>; 4] = std::array::from_fn(|a| x[a]);
            let (d, v) = tet4::derivatives(&xs)?;
            let pos = (0..4).fold(Vector3::zeros(), |a, k| a + xs[k] * g.0[k]);
            Ok((g.0.to_vec(), d.to_vec(), pos, v * g.1))
        }
    }
}

/// Blended points of one transition cell: (node ids ascending, dphi/dX, weight, phi).
type Blended = Vec<(Vec<usize>, Vec<Vector3<f64>>, f64, Vec<f64>)>;

/// The blended points of transition cell `e` of the FE layer `mesh`: its FE functions (linear,
/// or with `quad` the cell's quadratic ones over all the build's `nodes`), the ramp of its
/// interface vertices' linear functions, and the MLS functions at each point.
#[allow(clippy::too_many_arguments)]
fn transition_cell(
    mesh: &Mesh,
    e: usize,
    node_role: &[NodeRole],
    support: &Support,
    mls_nodes: &[usize],
    s: &CoupledSettings,
    full: bool,
    quad: Option<(&quadratic::Quadratic, &[Vector3<f64>])>,
) -> Result<Blended> {
    let mls = &s.mls;
    // Quadratic cells take the four-point rule, which integrates their stiffness.
    let rule = if full || quad.is_some() {
        gauss(mesh.shape)
    } else {
        transition_gauss(mesh.shape, s)
    };
    let c = mesh.cell(e);
    let x: Vec<Vector3<f64>> = c.iter().map(|&i| mesh.nodes[i]).collect();
    let interface: Vec<bool> = c
        .iter()
        .map(|&i| node_role[i] == NodeRole::Interface)
        .collect();
    let mut out = Vec::new();
    for g in rule {
        let (n, dn, pos, w) = fe_point(mesh.shape, &x, &g)
            .map_err(|volume| Error::InvalidElement { element: e, volume })?;
        let (mut r, mut dr) = (0.0, Vector3::zeros());
        for a in 0..c.len() {
            if interface[a] {
                r += n[a];
                dr += dn[a];
            }
        }
        let (ids, n, dn) = match quad {
            Some((q, nodes)) => {
                let p = q
                    .point(e, nodes, g.0)
                    .map_err(|det| Error::InvalidElement {
                        element: e,
                        volume: det / 6.0,
                    })?;
                (p.ids, p.n, p.dn)
            }
            None => (c.to_vec(), n, dn),
        };
        let s = shape_at(support, mls, &pos, true, &|| {
            format!("transition point of element {e}")
        })?;
        // Union of the MLS support and the cell's nodes, ascending.
        let mut acc: Vec<(usize, Vector3<f64>, f64)> = s
            .ids
            .iter()
            .zip(&s.phi)
            .zip(&s.dphi)
            .map(|((&i, &p), d)| (mls_nodes[i], d * r + dr * p, r * p))
            .collect();
        for a in 0..ids.len() {
            let d = dn[a] * (1.0 - r) - dr * n[a];
            match acc.iter_mut().find(|(i, _, _)| *i == ids[a]) {
                Some(slot) => {
                    slot.1 += d;
                    slot.2 += (1.0 - r) * n[a];
                }
                None => acc.push((ids[a], d, (1.0 - r) * n[a])),
            }
        }
        acc.sort_unstable_by_key(|a| a.0);
        out.push((
            acc.iter().map(|a| a.0).collect(),
            acc.iter().map(|a| a.1).collect(),
            w,
            acc.iter().map(|a| a.2).collect(),
        ));
    }
    Ok(out)
}

/// Builds the coupled discretization of `mesh` (hex8 or tet4 cells; every vertex a node):
/// the outer `fe_layers` cell layers are the FE layer, the rest is split into background
/// tets of the meshless interior.
pub fn build(mesh: Mesh, s: &CoupledSettings) -> Result<CoupledBuild> {
    check_shape(s, mesh.shape)?;
    log::info!(
        "coupled build on {} nodes, {} cells: FE layers, transition, meshless interior",
        mesh.nodes.len(),
        mesh.num_cells()
    );
    let regions = regions::split(&mesh, s.fe_layers, &s.fe_region)?;
    let pick = |keep: &dyn Fn(CellRole) -> bool| Mesh {
        nodes: mesh.nodes.clone(),
        shape: mesh.shape,
        cells: (0..mesh.num_cells())
            .filter(|&e| keep(regions.cell[e]))
            .flat_map(|e| mesh.cell(e).iter().cloned())
            .collect(),
    };
    let fe_mesh = pick(&|r| r != CellRole::Meshless);
    let interior = pick(&|r| r == CellRole::Meshless);
    let source_cell: Vec<Option<usize>> = (0..mesh.num_cells())
        .filter(|&e| regions.cell[e] != CellRole::Meshless)
        .chain((0..mesh.num_cells()).filter(|&e| regions.cell[e] == CellRole::Meshless))
        .map(Some)
        .collect();
    let fe_roles: Vec<CellRole> = regions
        .cell
        .iter()
        .cloned()
        .filter(|&r| r != CellRole::Meshless)
        .collect();
    let mut b = assemble(
        mesh.nodes,
        fe_mesh,
        interior,
        Regions {
            cell: fe_roles,
            node: regions.node,
            max_depth: regions.max_depth,
        },
        s,
        Vec::new(),
    )?;
    b.source_cell = source_cell;
    Ok(b)
}

/// The FE formulation must match the mesh's cells.
fn check_shape(s: &CoupledSettings, shape: ElementShape) -> Result<()> {
    if s.element.shape() != shape {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "coupled: element '{}' needs a {:?} mesh but the (FE-layer) mesh holds {:?} cells",
                s.element.name(),
                s.element.shape(),
                shape
            ),
        ));
    }
    Ok(())
}

/// Quadrature points of the coupled discretization: TLED points of the pure FE cells,
/// blended full-Gauss points of the transition cells, MLS points of the interior tets.
fn assemble(
    mut nodes: Vec<Vector3<f64>>,
    fe_mesh: Mesh,
    interior: Mesh,
    mut regions: Regions,
    s: &CoupledSettings,
    mut warnings: Vec<String>,
) -> Result<CoupledBuild> {
    // A quadratic FE layer: its edge nodes come after the mesh's vertices.
    let quad = (s.element == ElementKind::Tet10)
        .then(|| quadratic::Quadratic::add_edge_nodes(&mut nodes, &mut regions.node, &fe_mesh));
    let n = nodes.len();
    // MLS nodes and the interior background tets in their local numbering.
    let mls_nodes: Vec<usize> = (0..n)
        .filter(|&i| regions.node[i] != NodeRole::Fe)
        .collect();
    let mut local = vec![usize::MAX; n];
    for (k, &i) in mls_nodes.iter().enumerate() {
        local[i] = k;
    }
    // Tets of the interior (hexahedra split) give each MLS node its neighbour distance.
    let tets = hex_to_tets(interior.clone());
    let local_tets: Vec<[usize; 4]> = tets
        .cells
        .chunks_exact(4)
        .map(|c| [local[c[0]], local[c[1]], local[c[2]], local[c[3]]])
        .collect();
    if let Some(t) = local_tets.iter().position(|t| t.contains(&usize::MAX)) {
        return Err(Error::input(
            InputKind::Discretization,
            format!(
                "coupled: interior tet {t} uses an FE-layer node that is not on the interface; \
             the FE layer and the interior overlap"
            ),
        )
        .element(t));
    }
    let mut support = Support::new(
        mls_nodes.iter().map(|&i| nodes[i]).collect(),
        s.rule,
        Some(&local_tets),
    )?;
    let iface: Vec<usize> = (0..mls_nodes.len())
        .filter(|&k| regions.node[mls_nodes[k]] == NodeRole::Interface)
        .collect();
    support.scale_radii(&iface, s.interface_scale);

    // Pure FE cells keep their TLED kernels.
    let fe_cells: Vec<usize> = (0..fe_mesh.num_cells())
        .filter(|&e| regions.cell[e] == CellRole::Fe)
        .collect();
    let pure = Mesh {
        nodes: nodes.clone(),
        shape: fe_mesh.shape,
        cells: fe_cells
            .iter()
            .flat_map(|&e| fe_mesh.cell(e).iter().cloned())
            .collect(),
    };
    let fe_qp =
        match &quad {
            // Four points of ten nodes per element, each element a mean-dilatation group.
            Some(q) => {
                let mut qp =
                    QuadraturePoints::with_capacity(4 * fe_cells.len(), 40 * fe_cells.len());
                for &e in &fe_cells {
                    let ids = q.full_cell(e).ok_or_else(|| {
                        Error::input(
                            InputKind::Discretization,
                            format!("coupled: FE-layer cell {e} has an edge without its node"),
                        )
                        .element(e)
                    })?;
                    let x: [Vector3<f64>; 10] = std::array::from_fn(|a| nodes[ids[a]]);
                    let pts = fe::tet10::cell_points(&x, &ids)
                        .map_err(|volume| Error::InvalidElement { element: e, volume })?;
                    qp.push_group(&pts);
                }
                qp
            }
            None => fe::element_points(&pure, s.element, s.hourglass, s.hourglass_modulus)
                .map_err(|e| match e {
                    Error::InvalidElement { element, volume } => Error::InvalidElement {
                        element: fe_cells[element],
                        volume,
                    },
                    e => e,
                })?,
        };
    // Points per pure FE cell (the owner of each).
    let per_cell = if quad.is_some() { 4 } else { 1 };

    // Transition cells: blended shape functions at full Gauss points.
    let transition_cells: Vec<usize> = (0..fe_mesh.num_cells())
        .filter(|&e| regions.cell[e] == CellRole::Transition)
        .collect();
    let near = full_rule_nodes(&fe_mesh, &s.full_rule_near);
    let full: Vec<bool> = transition_cells
        .iter()
        .map(|&e| fe_mesh.cell(e).iter().any(|&i| near[i]))
        .collect();
    let full_rule_cells =
        if fe_mesh.shape == ElementShape::Tet4 && s.transition_rule == TransitionRule::Interior {
            full.iter().filter(|&&f| f).count()
        } else {
            0
        };
    let blended: Vec<Blended> = transition_cells
        .par_iter()
        .zip(&full)
        .map(|(&e, &f)| {
            crate::interrupt::check(|| {
                "while building the transition layer's shape functions".into()
            })?;
            let q = quad.as_ref().map(|q| (q, &nodes[..]));
            transition_cell(&fe_mesh, e, &regions.node, &support, &mls_nodes, s, f, q)
        })
        .collect::<Result<_>>()?;

    let mut adaptive_info = None;
    let mut adaptive_points = None;
    // Interior: MLS at the background-tet points.
    // Interior hexahedra: 2x2x2 Gauss points; interior tets: the tet rule.
    if interior.shape == ElementShape::Hex8 && s.adaptive.is_some() {
        warnings.push(
            "integration = 'adaptive' refines background tetrahedra; this coupled interior is \
             hexahedral and keeps its 2x2x2 Gauss points (use element = 'tet4' or 'tet4-anp' \
             for an adaptive interior)"
                .into(),
        );
    }
    let (pos, w, tet_owner) = if interior.shape == ElementShape::Hex8 {
        let g = gauss(ElementShape::Hex8);
        let mut out = (Vec::new(), Vec::new(), Vec::new());
        for e in 0..interior.num_cells() {
            let x: Vec<Vector3<f64>> = interior.cell(e).iter().map(|&i| nodes[i]).collect();
            for q in &g {
                let (_, _, p, wq) = fe_point(ElementShape::Hex8, &x, q).map_err(|volume| {
                    Error::input(InputKind::Discretization, format!(
                        "coupled: interior cell {e} has a non-positive Jacobian {sci_volume:.6e} at a Gauss point", sci_volume = crate::error::Sci(volume))).element(e).value(volume)
                })?;
                out.0.push(p);
                out.1.push(wq);
                out.2.push(e);
            }
        }
        out
    } else {
        let bad_tet = |e| {
            match e {
            Error::InvalidElement { element, volume } => Error::input(InputKind::Discretization, format!(
                "coupled: interior background tet {element} has non-positive volume {sci_volume:.6e} m^3", sci_volume = crate::error::Sci(volume))).element(element).value(volume),
            e => e,
        }
        };
        match &s.adaptive {
            Some(a) => {
                let (pts, info) = crate::meshless::discretize::adaptive_tet_points(
                    a, &interior, &support, &s.mls,
                )
                .map_err(bad_tet)?;
                adaptive_info = Some(info);
                adaptive_points = Some((pts.positions.clone(), pts.level));
                (pts.positions, pts.weights, pts.owner)
            }
            None => {
                use crate::meshless::integration::{cluster_tets, tet_points};
                let (p, w, o) = tet_points(&interior, s.tet_rule).map_err(bad_tet)?;
                cluster_tets(&interior, &p, &w, &o, s.tets_per_point).unwrap_or((p, w, o))
            }
        }
    };
    let ml_qp = build_points(&support, &s.mls, &pos, &w)?;

    let slots = fe_qp.nodes.len()
        + blended.iter().flatten().map(|b| b.0.len()).sum::<usize>()
        + ml_qp.nodes.len();
    let n_blended: usize = blended.iter().map(|b| b.len()).sum();
    let total = fe_qp.len() + n_blended + ml_qp.len();
    // Lumped volumes: a blended point's weight goes to its nodes in proportion to |phi_I| (the
    // row sums of its consistent mass), the others' evenly. An even split starves the FE
    // nodes of a transition cell next to an essential boundary: each blended point has 30-50
    // nodes, so a face node got a few percent of its cells' volume and set a stable step 3x
    // shorter than the pure methods' (4,208-node Gmsh cylinder, fe_layers = 1 around the
    // driven faces: 5.4e-5 s against 2.2e-4 s for MMLS on the same nodes).
    let blend_phi_abs: Vec<f64> = blended
        .iter()
        .flatten()
        .flat_map(|(_, _, _, phi)| phi.iter().map(|p| p.abs()))
        .collect();
    let mut qp = QuadraturePoints::with_capacity(total, slots);
    let mut owner = Vec::with_capacity(total);
    let mut ids = Vec::new();
    #[allow(clippy::needless_range_loop)] // p indexes the point table and its owners alike
    for p in 0..fe_qp.len() {
        let r = fe_qp.slots(p);
        ids.clear();
        ids.extend(fe_qp.nodes[r.clone()].iter().map(|&i| i as usize));
        match fe_qp.kinds[p] {
            PointKind::Hourglass(h) => {
                let d: [Vector3<f64>; 8] = std::array::from_fn(|a| fe_qp.dphi[r.start + a]);
                qp.push_hourglass(&ids, &d, fe_qp.weights[p], fe_qp.hourglass[h as usize]);
            }
            // A quadratic element's four points: its group, pushed at its first point.
            PointKind::MeanDilatation(g) => {
                let [first, end] = fe_qp.groups[g as usize];
                if p == first as usize {
                    let pts: Vec<_> = (first as usize..end as usize)
                        .map(|q| {
                            let r = fe_qp.slots(q);
                            (
                                fe_qp.nodes[r.clone()].iter().map(|&i| i as usize).collect(),
                                fe_qp.dphi[r].to_vec(),
                                fe_qp.weights[q],
                            )
                        })
                        .collect();
                    qp.push_group(&pts);
                }
            }
            k => qp.push(&ids, &fe_qp.dphi[r], fe_qp.weights[p], k),
        }
        owner.push(fe_cells[p / per_cell]);
    }
    for (b, &e) in blended.iter().zip(&transition_cells) {
        // A one-point cell's mean J is its J: a group would only add a pass per step.
        if s.mean_dilatation && b.len() > 1 {
            let pts: Vec<_> = b
                .iter()
                .map(|(ids, dphi, w, _)| (ids.clone(), dphi.clone(), *w))
                .collect();
            qp.push_group(&pts);
        } else {
            for (ids, dphi, w, _) in b {
                qp.push(ids, dphi, *w, PointKind::Standard);
            }
        }
        owner.extend(std::iter::repeat_n(e, b.len()));
    }
    let nf = fe_mesh.num_cells();
    // Tet interiors: the points of a patch of about `mean_dilatation_patch` face-connected
    // tets form one mean-dilatation group (contiguous, in order of the patches' first tet).
    let patches = (interior.shape == ElementShape::Tet4 && s.mean_dilatation_patch > 1)
        .then(|| crate::meshless::integration::tet_patches(&interior, s.mean_dilatation_patch));
    let order = crate::meshless::integration::patch_point_groups(patches.as_deref(), &tet_owner);
    let global_ids = |p: usize| -> Vec<usize> {
        ml_qp.nodes[ml_qp.slots(p)]
            .iter()
            .map(|&i| mls_nodes[i as usize])
            .collect()
    };
    for group in &order {
        if group.len() > 1 {
            let pts: Vec<_> = group
                .iter()
                .map(|&p| {
                    (
                        global_ids(p),
                        ml_qp.dphi[ml_qp.slots(p)].to_vec(),
                        ml_qp.weights[p],
                    )
                })
                .collect();
            qp.push_group(&pts);
        } else {
            for &p in group {
                qp.push(
                    &global_ids(p),
                    &ml_qp.dphi[ml_qp.slots(p)],
                    ml_qp.weights[p],
                    PointKind::Standard,
                );
            }
        }
        owner.extend(group.iter().map(|&p| nf + tet_owner[p]));
    }
    let interior_order: Vec<usize> = order.into_iter().flatten().collect();
    let adaptive_points = adaptive_points.map(|(x, level): (Vec<Vector3<f64>>, Vec<u8>)| {
        (
            interior_order.iter().map(|&p| x[p]).collect(),
            interior_order.iter().map(|&p| level[p]).collect(),
        )
    });
    // Every MLS node must be reached by enough points to carry mass and stiffness (one-point
    // hexahedra reach their corner nodes once, so FE nodes are not checked).
    let mut count = vec![0usize; n];
    for &k in &qp.nodes {
        count[k as usize] += 1;
    }
    let low = mls_nodes.iter().filter(|&&i| count[i] < 2).count();
    if low > 0 {
        warnings.push(format!(
            "{low} meshless node(s) are reached by fewer than two quadrature points; raise tet_rule or the support size"
        ));
    }
    let source_cell = (0..fe_mesh.num_cells())
        .map(Some)
        .chain(std::iter::repeat_n(None, interior.num_cells()))
        .collect();
    let (fe_grid, interior_grid) = (CellGrid::new(&fe_mesh), CellGrid::new(&interior));
    let mut build = CoupledBuild {
        source_cell,
        lumped_volume: Vec::new(),
        blend_phi_abs,
        nodes,
        fe_points: fe_qp.len(),
        transition_points: n_blended,
        full_rule_cells,
        meshless_points: ml_qp.len(),
        fe_mesh,
        interior,
        regions,
        points: qp,
        owner,
        mls_nodes,
        support,
        mls: s.mls,
        warnings,
        adaptive: adaptive_info,
        adaptive_points,
        quadratic: quad,
        fe_grid,
        interior_grid,
    };
    build.lumped_volume = build.lumped_masses(&|_| 1.0);
    Ok(build)
}
