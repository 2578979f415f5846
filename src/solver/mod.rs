//! The one explicit integrator shared by every discretization: central differences for dynamics,
//! adaptive dynamic relaxation for steady state, the stable step, energies and reactions.

pub mod chunks;
pub mod forces;
pub mod gpu;
pub mod integrate;
#[cfg(target_arch = "x86_64")]
mod lanes_avx2;
pub mod order;
pub mod spectrum;
pub mod statics;
pub mod timestep;
mod two_ended;

use nalgebra::{Matrix3, Vector3};

use crate::bc::contact::Contact;
use crate::bc::loads::{Load, Loads};
use crate::bc::{Boundary, Constraints};
use crate::material::Material;
use crate::quadrature::{NodeSlots, QuadraturePoints};
use crate::{InputKind, Result};
pub use forces::{Fields, Forces};
pub use integrate::{
    keep_warm, run, run_streaming, Device, FrameSink, Mode, RunOutput, Settings, StepEstimate,
    WarmStart,
};
pub use statics::Variant as StaticVariant;

/// A raw pointer that may cross threads: each parallel task writes a disjoint index range.
#[derive(Clone, Copy)]
pub(crate) struct SharedMut<T>(pub(crate) *mut T);
unsafe impl<T> Send for SharedMut<T> {}
unsafe impl<T> Sync for SharedMut<T> {}

impl<T> SharedMut<T> {
    /// The pointer; a method so closures capture the whole (Send + Sync) wrapper.
    #[inline(always)]
    pub(crate) fn get(self) -> *mut T {
        self.0
    }
}

/// Essential conditions imposed by correcting the explicit predictor each step (meshless
/// EBCIEM / SEBCIEM, thesis eq. 4.21-4.24), for boundaries whose shape functions are not
/// interpolating.
pub trait Corrector: Send {
    /// Corrects the predicted displacements `u` (nodal parameters of all nodes, m) so that
    /// the interpolated field takes the prescribed values at load fraction `tau` (0..1, each
    /// boundary's curve applied to it). `alpha` is the force coefficient of the update
    /// u = alpha M^-1 F + ..., s^2 (central differences: dt^2 / (1 + c dt / 2)). Called on
    /// the time loop's thread pool: parallel where its work splits, and serial parts through
    /// [`keep_warm`] so the other workers do not fall asleep.
    fn correct(&mut self, u: &mut [Vector3<f64>], tau: f64, alpha: f64);
    /// Force (N) that model boundary `b` applied to the body in the last correction.
    fn reaction(&self, b: usize) -> Vector3<f64>;
    /// Work (J) of the last correction's constraint forces over the increment
    /// (u_next - u_prev) / 2 (central difference, as for directly prescribed DOFs).
    fn work(&self, u_next: &[Vector3<f64>], u_prev: &[Vector3<f64>]) -> f64;
    /// Takes the prescribed values and curves of `boundaries` (the model's, whose nodes and
    /// prescribed components are those the corrector was built for) for the next runs.
    fn set_values(&mut self, boundaries: &[Boundary]) -> Result<()>;
    /// The nodes whose displacements [`Self::correct`] may change, ascending. The time loop
    /// measures the step's change on these after the correction and on all others during
    /// its update, so it needs no second pass over every node.
    fn touched(&self) -> &[u32];
    /// The nodes whose displacements [`Self::correct`] reads or writes, ascending (None: any
    /// node). The GPU loop copies only these between the device and the host each step.
    fn window(&self) -> Option<Vec<u32>> {
        None
    }
    /// The conditions the corrector imposes as linear constraints on the nodal parameters, for
    /// the static solve ([`statics`]): one per constrained node and component,
    /// sum_j w_j u_j(axis) = target (m) at load fraction `tau`. None where the corrector has
    /// none to give (the static solve then refuses the model).
    fn linear_constraints(&self, _tau: f64) -> Option<Vec<LinearConstraint>> {
        None
    }
    /// Takes the force (N) each model boundary applied to the body as found by the static
    /// solve, reported by [`Self::reaction`] until the next correction.
    fn set_reactions(&mut self, _per_boundary: &[Vector3<f64>]) {}
}

/// One linear condition on the nodal parameters ([`Corrector::linear_constraints`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearConstraint {
    /// (node, weight) pairs: the shape functions at a constrained point.
    pub row: Vec<(u32, f64)>,
    /// (node, weight) pairs that carry the constraint's multiplier as nodal force: EBCIEM's
    /// boundary-force column of V (m^2, thesis eq. 4.12); `None`: the row itself (SEBCIEM,
    /// V = Phi^T, eq. 4.30).
    pub spread: Option<Vec<(u32, f64)>>,
    /// The displacement component it prescribes (0 x, 1 y, 2 z).
    pub axis: usize,
    /// The prescribed value, m.
    pub target: f64,
    /// The model boundary it belongs to.
    pub boundary: usize,
}

/// A model's lumped masses and their flags, kept to be put back
/// ([`Model::mass_state`], [`Model::restore_masses`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MassState {
    mass: Vec<f64>,
    uneven: bool,
    scaled: bool,
}

/// Everything the time loop needs: reference nodes, quadrature points, lumped masses,
/// constraints and the force evaluator. Its state is private and changed only through
/// methods that keep it consistent (masses with their flags, boundaries with the constraints
/// built on them).
pub struct Model<M: Material> {
    /// Reference node coordinates, m.
    pub(in crate::solver) nodes: Vec<Vector3<f64>>,
    /// The discretization's points in Morton order ([`order::spatial_order`]).
    pub(in crate::solver) points: QuadraturePoints,
    /// Per point of `points`: its id in the discretization (element or integration point id,
    /// as messages and outputs give it).
    pub(in crate::solver) point_ids: Vec<u32>,
    pub(in crate::solver) slots: NodeSlots,
    /// Lumped nodal masses, kg ([`Self::mass`]; changed only through the methods that keep
    /// `masses_uneven` and `mass_scaled` with them).
    mass: Vec<f64>,
    pub(in crate::solver) boundaries: Vec<Boundary>,
    pub(in crate::solver) constraints: Constraints,
    pub(in crate::solver) forces: Forces<M>,
    /// Imposes the boundaries marked in `corrected` (meshless EBCIEM / SEBCIEM).
    pub(in crate::solver) corrector: Option<Box<dyn Corrector>>,
    /// Per boundary: imposed by `corrector` instead of directly on nodes.
    pub(in crate::solver) corrected: Vec<bool>,
    /// Gravity, point forces, tractions and pressures ([`Self::set_loads`]).
    pub(in crate::solver) loads: Loads,
    /// External nodal forces of the last step, N (empty without loads).
    pub(in crate::solver) f_ext: Vec<Vector3<f64>>,
    /// Frictionless contact with rigid bodies, corrected after each update.
    pub(in crate::solver) contact: Option<Contact>,
    /// `mass` is not each point's mass split evenly over its nodes (set by
    /// [`Self::set_lumped_masses`] and [`Self::scale_masses`]): the per-point step bounds,
    /// which assume that split, are then not used.
    masses_uneven: bool,
    /// `mass` holds the fictitious masses of [`Self::scale_masses`] (relaxation only).
    mass_scaled: bool,
    /// The static solve's tangent pattern, numbering and factorization, kept between solves
    /// ([`statics::solve`]).
    pub(in crate::solver) static_cache: Option<statics::Cache>,
    /// What the constraints and the corrector were built on: per boundary, its name, nodes
    /// and prescribed components ([`Self::apply_boundary_changes`]).
    layout: Vec<BoundaryLayout>,
}

/// The part of a [`Boundary`] that the model's constraints and corrections are built on (its
/// values and curve may change between runs; these may not).
#[derive(Debug, Clone, PartialEq)]
struct BoundaryLayout {
    name: String,
    nodes: Vec<usize>,
    prescribed: [bool; 3],
    per_node: bool,
}

impl BoundaryLayout {
    fn of(b: &Boundary) -> Self {
        BoundaryLayout {
            name: b.name.clone(),
            nodes: b.nodes.clone(),
            prescribed: b.components.map(|c| c.is_some()),
            per_node: b.node_values.is_some(),
        }
    }
}

/// Checks what a boundary's values may hold: `node_values` one entry per node, and every
/// prescribed value finite.
fn check_boundary_values(b: &Boundary) -> Result<()> {
    if let Some(v) = &b.node_values {
        if v.len() != b.nodes.len() {
            return Err(crate::Error::input(
                InputKind::Value,
                format!(
                "boundary '{}': {} node values for its {} nodes; give one [x, y, z] per node, in \
                 the order of its nodes",
                b.name,
                v.len(),
                b.nodes.len()
            ),
            ));
        }
    }
    // Per-node values replace the uniform ones on the prescribed components.
    let entries = b.node_values.as_ref().map_or(1, Vec::len);
    for k in 0..entries {
        for c in 0..3 {
            if let Some(x) = b.value(k, c).filter(|x| !x.is_finite()) {
                return Err(crate::Error::input(
                    InputKind::Value,
                    format!(
                    "boundary '{}': prescribed {} displacement {x} m (its entry {k}) is not finite",
                    b.name,
                    ["x", "y", "z"][c]
                ),
                ));
            }
        }
    }
    Ok(())
}

impl<M: Material> Model<M> {
    /// Where point `p` (Morton order) is, as messages give it: the centroid of its supporting
    /// nodes in the reference configuration, m.
    pub(in crate::solver) fn point_centroid(&self, p: usize) -> Vector3<f64> {
        let sl = self.points.slots(p);
        let count = sl.len().max(1) as f64;
        sl.map(|k| self.nodes[self.points.nodes[k] as usize])
            .sum::<Vector3<f64>>()
            / count
    }

    /// Assembles the model; the points are stored in Morton order (see [`order`]). Masses: each point's mass rho w is split evenly among its support
    /// nodes (for FE elements this is the usual element-mass lumping). A node that carries no
    /// mass is an error naming it.
    pub fn new(
        nodes: Vec<Vector3<f64>>,
        points: QuadraturePoints,
        material: M,
        boundaries: Vec<Boundary>,
    ) -> Result<Self> {
        Self::with_materials(nodes, points, vec![material], Vec::new(), boundaries)
    }

    /// As [`Self::new`] with one material per region: point `p` (in the discretization's
    /// order) has `materials[point_material[p]]`; `point_material` empty gives every point the
    /// first. Masses take each point's density. Errors when the lists do not match.
    pub fn with_materials(
        nodes: Vec<Vector3<f64>>,
        points: QuadraturePoints,
        materials: Vec<M>,
        point_material: Vec<u16>,
        boundaries: Vec<Boundary>,
    ) -> Result<Self> {
        let n = nodes.len();
        if materials.is_empty()
            || !(point_material.is_empty() || point_material.len() == points.len())
            || point_material
                .iter()
                .any(|&m| m as usize >= materials.len())
        {
            return Err(crate::Error::input(
                InputKind::Value,
                format!(
                    "{} point materials for {} points and {} materials",
                    point_material.len(),
                    points.len(),
                    materials.len()
                ),
            ));
        }
        let (points, point_ids) = order::spatial_order(points, &nodes);
        // The materials follow their points into the spatial order.
        let point_material: Vec<u16> = if point_material.is_empty() {
            Vec::new()
        } else {
            point_ids
                .iter()
                .map(|&q| point_material[q as usize])
                .collect()
        };
        let slots = NodeSlots::new(&points, n);
        let rho =
            |p: usize| materials[point_material.get(p).copied().unwrap_or(0) as usize].density();
        let mass: Vec<f64> = (0..n)
            .map(|i| {
                slots
                    .range(i)
                    .map(|k| {
                        let p = slots.points[k] as usize;
                        rho(p) * points.weights[p] / points.slots(p).len() as f64
                    })
                    .sum()
            })
            .collect();
        if let Some(i) = mass.iter().position(|&m| !(m > 0.0)) {
            return Err(crate::Error::input(InputKind::Mesh, format!(
                "node {i} at {:?} m belongs to no element and lies in no integration point's support, so it \
                 has no mass: remove unused nodes from the mesh, or, for a meshless node, give the \
                 points larger supports (discretization.dilatation, support_nodes) or more points \
                 (a smaller tets_per_point, a larger point_ratio)",
                nodes[i].as_slice()
            )).node(i));
        }
        for b in &boundaries {
            check_boundary_values(b)?;
        }
        let constraints = Constraints::new(&boundaries, n)?;
        let layout = boundaries.iter().map(BoundaryLayout::of).collect();
        let forces = Forces::with_materials(materials, point_material, &points, &slots, n);
        let corrected = vec![false; boundaries.len()];
        Ok(Model {
            nodes,
            points,
            point_ids,
            slots,
            mass,
            boundaries,
            constraints,
            forces,
            corrector: None,
            corrected,
            loads: Loads::default(),
            f_ext: Vec::new(),
            contact: None,
            masses_uneven: false,
            mass_scaled: false,
            static_cache: None,
            layout,
        })
    }

    /// Sets the model's loads. Gravity takes the lumped masses the model was built
    /// with (the points' volumes times their densities).
    pub fn set_loads(&mut self, loads: Vec<Load>) -> Result<()> {
        self.loads = Loads::new(loads, &self.mass)?;
        self.f_ext = if self.loads.is_empty() {
            Vec::new()
        } else {
            vec![Vector3::zeros(); self.nodes.len()]
        };
        Ok(())
    }

    /// Replaces the evenly split lumped masses by `mass` (kg, one per node; see
    /// [`crate::coupling::CoupledBuild::lumped_masses`]). Errors naming a node whose mass is
    /// not positive.
    pub fn set_lumped_masses(&mut self, mass: &[f64]) -> Result<()> {
        if mass.len() != self.mass.len() {
            return Err(crate::Error::input(
                InputKind::Value,
                format!("{} lumped masses for {} nodes", mass.len(), self.mass.len()),
            ));
        }
        if let Some(i) = mass.iter().position(|&v| !(v > 0.0)) {
            return Err(crate::Error::input(
                InputKind::Value,
                format!(
                    "node {i} at {:?} m has lumped mass {:.3e} kg; it needs a positive mass",
                    self.nodes[i].as_slice(),
                    crate::error::Sci(mass[i])
                ),
            )
            .node(i)
            .value(mass[i]));
        }
        self.mass.copy_from_slice(mass);
        self.masses_uneven = true;
        Ok(())
    }

    /// Reference node coordinates, m.
    pub fn nodes(&self) -> &[Vector3<f64>] {
        &self.nodes
    }

    /// The discretization's quadrature points, in the model's (Morton) order.
    pub fn points(&self) -> &QuadraturePoints {
        &self.points
    }

    /// The essential boundaries, in the order of the scene and of [`Self::reactions`].
    pub fn boundaries(&self) -> &[Boundary] {
        &self.boundaries
    }

    /// The boundaries, for new values between runs: a boundary's prescribed values,
    /// `node_values` and `curve` may change; the next run takes them
    /// ([`Self::apply_boundary_changes`]) and refuses any other change (its name, nodes, which
    /// components it prescribes) with an error, so the constraints cannot go stale.
    pub fn boundaries_mut(&mut self) -> &mut [Boundary] {
        &mut self.boundaries
    }

    /// The degrees of freedom the time loop prescribes directly.
    pub fn constraints(&self) -> &Constraints {
        &self.constraints
    }

    /// The force evaluator: materials, their points, the kernel's scratch.
    pub fn forces(&self) -> &Forces<M> {
        &self.forces
    }

    /// Gravity, point forces, tractions and pressures ([`Self::set_loads`]).
    pub fn loads(&self) -> &Loads {
        &self.loads
    }

    /// The loads, to scale them between runs ([`Loads::set_factor`]).
    pub fn loads_mut(&mut self) -> &mut Loads {
        &mut self.loads
    }

    /// Frictionless contact with rigid bodies, if the model has any.
    pub fn contact(&self) -> Option<&Contact> {
        self.contact.as_ref()
    }

    /// The rigid bodies, to move them between runs ([`Contact::set_motion`]).
    pub fn contact_mut(&mut self) -> Option<&mut Contact> {
        self.contact.as_mut()
    }

    /// Sets the rigid bodies the body may touch (None: none).
    pub fn set_contact(&mut self, contact: Option<Contact>) {
        self.contact = contact;
    }

    /// Lumped nodal masses, kg.
    pub fn mass(&self) -> &[f64] {
        &self.mass
    }

    /// The internal nodal forces (N) of displacements `u` (m) into `f`: the force kernel over
    /// the model's points.
    pub fn internal_forces(&mut self, u: &[Vector3<f64>], f: &mut [Vector3<f64>]) {
        self.forces.compute(&self.points, &self.slots, u, f);
    }

    /// The external nodal forces (N) of the last step: gravity, point forces, tractions and
    /// pressures at their load factors (empty without loads).
    pub fn external_forces(&self) -> &[Vector3<f64>] {
        &self.f_ext
    }

    /// Each node's slots in the point table (the gather order of the force kernel).
    pub fn slots(&self) -> &NodeSlots {
        &self.slots
    }

    /// The corrector that imposes the boundaries the model marks as corrected (meshless
    /// EBCIEM / SEBCIEM), if any.
    pub fn corrector(&self) -> Option<&dyn Corrector> {
        self.corrector.as_deref()
    }

    /// Whether the masses are not each point's mass split evenly over its nodes (lumped by
    /// [`Self::set_lumped_masses`] or scaled by [`Self::scale_masses`]).
    pub fn masses_uneven(&self) -> bool {
        self.masses_uneven
    }

    /// Whether the masses are the fictitious ones of [`Self::scale_masses`].
    pub fn mass_scaled(&self) -> bool {
        self.mass_scaled
    }

    /// The masses and how they were made, to put back with [`Self::restore_masses`].
    pub fn mass_state(&self) -> MassState {
        MassState {
            mass: self.mass.clone(),
            uneven: self.masses_uneven,
            scaled: self.mass_scaled,
        }
    }

    /// Puts back masses taken with [`Self::mass_state`] (of this model).
    pub fn restore_masses(&mut self, state: MassState) {
        debug_assert_eq!(state.mass.len(), self.mass.len());
        self.mass = state.mass;
        self.masses_uneven = state.uneven;
        self.mass_scaled = state.scaled;
    }

    /// Puts in fictitious masses `mass` (kg, one per node) that an earlier
    /// [`Self::scale_masses`] of this model gave.
    pub fn set_scaled_masses(&mut self, mass: &[f64]) -> Result<()> {
        if mass.len() != self.mass.len() {
            return Err(crate::Error::input(
                InputKind::Value,
                format!("{} scaled masses for {} nodes", mass.len(), self.mass.len()),
            ));
        }
        self.mass.copy_from_slice(mass);
        self.masses_uneven = true;
        self.mass_scaled = true;
        Ok(())
    }

    /// Replaces the masses by fictitious ones for dynamic relaxation (mass scaling; Underwood
    /// 1983): each node's mass proportional to its block-Gershgorin row sum of the reference
    /// stiffness ([`crate::solver::timestep::gershgorin_rows`]), their total the body's mass.
    /// Every node then has the same Gershgorin frequency bound, so the small elements of a
    /// graded mesh no longer set a step that the large ones do not need, and the steady state,
    /// which does not depend on the masses, is reached in fewer steps (the graded
    /// indentation benchmark with tet10 elements: 2,377 steps against 17,921). Call after
    /// [`Self::set_loads`] (gravity keeps the physical masses) and before building
    /// correctors, which must use the masses of the update. Not for dynamic runs: it changes
    /// the dynamics.
    pub fn scale_masses(&mut self) -> Result<()> {
        let moduli = |p: usize| self.point_moduli(p);
        let rows = timestep::gershgorin_rows(&self.points, &self.slots, &moduli);
        let total: f64 = self.mass.iter().sum();
        let sum: f64 = rows.iter().sum();
        if !(sum > 0.0 && sum.is_finite()) {
            // Moduli out of range: the physical masses stay, and the step estimate says
            // what is wrong ([`crate::solver::integrate::check_critical_step`]).
            return Ok(());
        }
        let scale = total / sum;
        // A node whose derivatives all vanish at its points (a meshless node at the edge of
        // its supports) keeps its physical mass rather than none.
        let scaled: Vec<f64> = rows
            .iter()
            .zip(&self.mass)
            .map(|(&r, &m)| if r > 0.0 { r * scale } else { m })
            .collect();
        self.mass = scaled;
        self.masses_uneven = true;
        self.mass_scaled = true;
        Ok(())
    }

    /// (P-wave modulus lambda + 2 mu, shear modulus mu, bulk modulus kappa in Pa, density in
    /// kg/m^3) of point `p` (model order), for the stable-step bounds.
    pub fn point_moduli(&self, p: usize) -> [f64; 4] {
        let m = self.forces.material_at(p);
        let (lambda, mu) = m.lame();
        [lambda + 2.0 * mu, mu, lambda + 2.0 * mu / 3.0, m.density()]
    }

    /// Hands the boundaries marked in `corrected` to `corrector`: they leave the directly
    /// prescribed DOFs, and their reactions come from the constraint forces.
    pub fn set_corrector(
        &mut self,
        corrector: Box<dyn Corrector>,
        corrected: Vec<bool>,
    ) -> Result<()> {
        let direct: Vec<Boundary> = self
            .boundaries
            .iter()
            .zip(&corrected)
            .map(|(b, &c)| {
                let mut b = b.clone();
                if c {
                    b.nodes.clear();
                }
                b
            })
            .collect();
        self.constraints = Constraints::new(&direct, self.nodes.len())?;
        self.corrector = Some(corrector);
        self.corrected = corrected;
        Ok(())
    }

    /// Takes changes of the boundaries' values into the constraints and corrections the time
    /// loop imposes: `boundaries[k].components`' values, `node_values` and `curve` may change
    /// between runs of one model (a new measurement, a new tool position); every run calls
    /// this first ([`integrate::run`]), so a change made on `self.boundaries` is never
    /// ignored. A change the model cannot take is an error that says so: a boundary added,
    /// removed or renamed, its nodes, which components it prescribes, or whether its values
    /// are per node (the quadrature points, masses, meshless corrections and contact were
    /// built on them: prepare the model again).
    pub fn apply_boundary_changes(&mut self) -> Result<()> {
        if self.boundaries.len() != self.layout.len() {
            return Err(crate::Error::input(
                InputKind::Value,
                format!(
                "the model was built with {} boundaries and now has {}: boundaries cannot be added \
                 or removed after preparing; prepare the model again with them",
                self.layout.len(),
                self.boundaries.len()
            ),
            ));
        }
        for (b, was) in self.boundaries.iter().zip(&self.layout) {
            let now = BoundaryLayout::of(b);
            if now != *was {
                let what = if now.name != was.name {
                    format!("was renamed from '{}'", was.name)
                } else if now.nodes != was.nodes {
                    format!(
                        "its nodes changed ({} -> {})",
                        was.nodes.len(),
                        now.nodes.len()
                    )
                } else if now.prescribed != was.prescribed {
                    "the components it prescribes changed (a free component cannot become \
                     prescribed nor the reverse)"
                        .to_string()
                } else {
                    "its values changed between uniform and per node".to_string()
                };
                return Err(crate::Error::input(
                    InputKind::Value,
                    format!(
                        "boundary '{}' {what} after the model was prepared: the constraints and \
                     corrections were built on its nodes and components, so only its values and \
                     curve may change between runs; prepare the model again for a new selection",
                        b.name
                    ),
                ));
            }
            check_boundary_values(b)?;
        }
        let direct: Vec<Boundary> = self
            .boundaries
            .iter()
            .enumerate()
            .map(|(k, b)| {
                let mut b = b.clone();
                if self.corrected.get(k).copied().unwrap_or(false) {
                    b.nodes.clear();
                }
                b
            })
            .collect();
        self.constraints = Constraints::new(&direct, self.nodes.len())?;
        if let Some(c) = self.corrector.as_mut() {
            c.set_values(&self.boundaries)?;
        }
        Ok(())
    }

    /// Bytes of the arrays the time loop touches: the points and their slots, the node -> slot
    /// map, masses and positions, the force evaluator's scratch and the integrator's seven
    /// nodal vectors. Leaves out what a corrector holds.
    pub fn solver_bytes(&self) -> usize {
        use std::mem::size_of_val;
        let q = &self.points;
        let n = self.nodes.len();
        size_of_val(q.offsets.as_slice())
            + size_of_val(q.nodes.as_slice())
            + size_of_val(q.dphi.as_slice())
            + size_of_val(q.weights.as_slice())
            + size_of_val(q.kinds.as_slice())
            + size_of_val(q.hourglass.as_slice())
            + size_of_val(q.groups.as_slice())
            + size_of_val(self.point_ids.as_slice())
            + size_of_val(self.slots.offsets.as_slice())
            + size_of_val(self.slots.slots.as_slice())
            + size_of_val(self.slots.points.as_slice())
            + size_of_val(self.mass.as_slice())
            + size_of_val(self.nodes.as_slice())
            + self.forces.scratch_bytes()
            + 7 * n * std::mem::size_of::<Vector3<f64>>()
    }

    /// Per point in the discretization's order (element order for FE meshes): Cauchy stress
    /// (Pa), Green-Lagrange strain, von Mises stress (Pa) and J at displacements `u` (m).
    pub fn stress_fields(&mut self, u: &[Vector3<f64>]) -> Fields {
        let f = self.forces.stress_fields(&self.points, &self.slots, u);
        let mut out = Fields::zeros(f.len());
        for (q, &p) in self.point_ids.iter().enumerate() {
            let p = p as usize;
            out.cauchy[9 * p..9 * p + 9].copy_from_slice(&f.cauchy[9 * q..9 * q + 9]);
            out.green[9 * p..9 * p + 9].copy_from_slice(&f.green[9 * q..9 * q + 9]);
            out.von_mises[p] = f.von_mises[q];
            out.j[p] = f.j[q];
            out.j_own[p] = f.j_own[q];
        }
        out
    }

    /// Per node: the points' Cauchy stress, strain and J averaged with each point's share of
    /// its volume at the node (w_p / n_p, the lumped-mass weights), von Mises stress from the
    /// averaged Cauchy stress. The smoothed nodal fields ParaView colours by; a node's own
    /// points are those that support it.
    pub fn nodal_fields(&mut self, u: &[Vector3<f64>]) -> Fields {
        let f = self.forces.stress_fields(&self.points, &self.slots, u);
        let n = self.nodes.len();
        let mut out = Fields::zeros(n);
        for i in 0..n {
            let (mut c, mut e, mut j, mut w) = (Matrix3::zeros(), Matrix3::zeros(), 0.0, 0.0);
            for k in self.slots.range(i) {
                let p = self.slots.points[k] as usize;
                let wp = self.points.weights[p] / self.points.slots(p).len() as f64;
                c += f.cauchy_at(p) * wp;
                e += f.green_at(p) * wp;
                // tet4-anp: the volume-weighted mean of the elements' own J around the node
                // is the nodal J_n their pressures come from.
                let jp = if self.points.kinds[p] == crate::quadrature::PointKind::Anp {
                    f.j_own[p]
                } else {
                    f.j[p]
                };
                j += jp * wp;
                w += wp;
            }
            if w != 0.0 {
                out.set(i, &(c / w), &(e / w), j / w);
            }
        }
        out
    }

    /// Nodes a corrector (EBCIEM / SEBCIEM) or a contact moves after the update, sorted and
    /// without repeats: their forces at the end include constraint forces.
    pub fn corrected_nodes(&self) -> Vec<u32> {
        let mut l: Vec<u32> = Vec::new();
        if let Some(corr) = self.corrector.as_ref() {
            l.extend_from_slice(corr.touched());
        }
        if let Some(ct) = self.contact.as_ref() {
            l.extend_from_slice(ct.touched());
        }
        l.sort_unstable();
        l.dedup();
        l
    }

    /// The force each boundary applies to the body, N: the sum over its nodes of the internal
    /// minus the external nodal forces (`self.f_ext`, the last step's loads; at equilibrium
    /// F_int = F_ext + R), negative along the axis in compression as in docs/reference.md.
    /// Boundaries imposed by a corrector report its constraint force instead.
    /// Rigid contact bodies follow the boundaries with the force they applied in the last
    /// correction ([`Self::reaction_names`]).
    pub fn reactions(&self, f_int: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let ext = |i: usize| self.f_ext.get(i).copied().unwrap_or_else(Vector3::zeros);
        let mut r: Vec<Vector3<f64>> = self
            .boundaries
            .iter()
            .enumerate()
            .map(|(k, b)| match (&self.corrector, self.corrected.get(k)) {
                (Some(c), Some(true)) => c.reaction(k),
                _ => b
                    .nodes
                    .iter()
                    .fold(Vector3::zeros(), |acc, &i| acc + (f_int[i] - ext(i))),
            })
            .collect();
        if let Some(c) = &self.contact {
            r.extend_from_slice(c.forces());
        }
        r
    }

    /// [`Self::reactions`] as [x, y, z] rows, N: what history rows and load stages keep.
    pub fn reaction_rows(&self, f_int: &[Vector3<f64>]) -> Vec<[f64; 3]> {
        self.reactions(f_int)
            .iter()
            .map(|v| [v.x, v.y, v.z])
            .collect()
    }

    /// Names of the entries of [`Self::reactions`]: the boundaries, then the rigid bodies.
    pub fn reaction_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self.boundaries.iter().map(|b| b.name.clone()).collect();
        if let Some(c) = &self.contact {
            v.extend(c.names().map(String::from));
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fe::{element_points, ElementKind};
    use crate::geometry::shapes::box_hex;
    use crate::material::NeoHookean;

    /// The model stores its points in Morton order but reports per-point results under the
    /// discretization's ids: each element's stress equals that of its own point evaluated in
    /// the mesh's order, and the masses are those of the unsorted points.
    #[test]
    fn sorted_points_report_under_the_discretizations_ids() {
        let mesh = box_hex(Vector3::zeros(), Vector3::new(0.1, 0.06, 0.04), [5, 3, 2]).unwrap();
        let mat = NeoHookean::from_young_poisson(3000.0, 0.45, 1000.0);
        let qp = element_points(&mesh, ElementKind::Hex8, 0.05, 1e5).unwrap();
        let mut model = Model::new(mesh.nodes.clone(), qp.clone(), mat, Vec::new()).unwrap();
        assert_ne!(
            model.point_ids,
            (0..qp.len() as u32).collect::<Vec<_>>(),
            "the mesher's order should differ from the Morton order"
        );
        // A field whose strain varies from element to element.
        let u: Vec<Vector3<f64>> = mesh
            .nodes
            .iter()
            .map(|x| Vector3::new(0.3 * x.x * x.x, 0.1 * x.x * x.y, -0.2 * x.z * (x.x + 0.05)))
            .collect();
        let fields = model.stress_fields(&u);
        let slots = NodeSlots::new(&qp, mesh.nodes.len());
        let mut plain = Forces::new(mat, &qp, &slots, mesh.nodes.len());
        let fields0 = plain.stress_fields(&qp, &slots, &u);
        assert!(fields == fields0, "per-point results moved");
        let distinct = fields0.j.windows(2).filter(|w| w[0] != w[1]).count();
        assert!(
            distinct > qp.len() / 2,
            "the test field must tell elements apart"
        );
        let m0: f64 = qp.weights.iter().sum::<f64>() * 1000.0;
        let m: f64 = model.mass.iter().sum();
        assert!((m - m0).abs() < 1e-12 * m0);
    }

    /// Issue 40: tet4-anp reports as its cell J the volume change its pressure comes from,
    /// the mean of its nodes' J_n (each the volume-weighted mean of the own J's around the
    /// node: the nodal J output), and its own det F apart (`j_own`). A field that alternates
    /// the elements' own J (a checkerboard the averaging does not see) leaves the reported J
    /// smooth.
    #[test]
    fn tet4_anp_reports_the_averaged_volume_change() {
        let mesh = crate::geometry::shapes::box_tet(
            Vector3::zeros(),
            Vector3::new(0.04, 0.04, 0.04),
            [4, 4, 4],
        )
        .unwrap();
        let mat = NeoHookean::from_young_poisson(3000.0, 0.49, 1000.0);
        let qp = element_points(&mesh, ElementKind::Tet4Anp, 0.0, 1.0).unwrap();
        let mut model = Model::new(mesh.nodes.clone(), qp, mat, Vec::new()).unwrap();
        // Interior nodes moved in a pattern that changes the elements' volumes unevenly.
        let u: Vec<Vector3<f64>> = mesh
            .nodes
            .iter()
            .enumerate()
            .map(|(i, x)| {
                let s = if i % 2 == 0 { 1.0 } else { -1.0 };
                Vector3::new(0.02 * x.x, 0.0, 0.0) + Vector3::new(1.0, 0.7, -0.4) * (8e-4 * s)
            })
            .collect();
        let cells = model.stress_fields(&u);
        let nodal = model.nodal_fields(&u);
        let (mut own_lo, mut own_hi, mut lo, mut hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for e in 0..mesh.num_cells() {
            let ids = mesh.cell(e);
            let x: [Vector3<f64>; 4] = std::array::from_fn(|a| mesh.nodes[ids[a]]);
            let y: [Vector3<f64>; 4] = std::array::from_fn(|a| x[a] + u[ids[a]]);
            let v0 = crate::fe::tet4::derivatives(&x).unwrap().1;
            let v1 = crate::fe::tet4::derivatives(&y).map_or(-1.0, |d| d.1);
            assert!((cells.j_own[e] - v1 / v0).abs() < 1e-12, "own J of {e}");
            let mean: f64 = ids.iter().map(|&i| nodal.j[i]).sum::<f64>() / 4.0;
            assert!((cells.j[e] - mean).abs() < 1e-12, "averaged J of {e}");
            own_lo = own_lo.min(cells.j_own[e]);
            own_hi = own_hi.max(cells.j_own[e]);
            lo = lo.min(cells.j[e]);
            hi = hi.max(cells.j[e]);
        }
        // The nodal J is J_n: the volume-weighted mean of the own J's around the node.
        for n in 0..mesh.nodes.len() {
            let (mut acc, mut w) = (0.0, 0.0);
            for e in 0..mesh.num_cells() {
                if mesh.cell(e).contains(&n) {
                    acc += cells.j_own[e];
                    w += 1.0;
                }
            }
            // Every tet of this mesh has the same volume.
            assert!((nodal.j[n] - acc / w).abs() < 1e-12, "J_n of node {n}");
        }
        assert!(
            own_hi - own_lo > 3.0 * (hi - lo),
            "own {own_lo}..{own_hi}, used {lo}..{hi}"
        );
    }
}
