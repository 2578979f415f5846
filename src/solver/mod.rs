//! The one explicit integrator shared by every discretization: central differences for dynamics,
//! adaptive dynamic relaxation for steady state, the stable step, energies and reactions.

pub mod forces;
pub mod integrate;
pub mod timestep;

use nalgebra::Vector3;

use crate::bc::{Boundary, Constraints};
use crate::material::Material;
use crate::quadrature::{NodeSlots, QuadraturePoints};
use crate::Result;
pub use forces::Forces;
pub use integrate::{run, Mode, RunOutput, Settings};

/// Everything the time loop needs: reference nodes, quadrature points, lumped masses,
/// constraints and the force evaluator.
pub struct Model<M: Material> {
    /// Reference node coordinates, m.
    pub nodes: Vec<Vector3<f64>>,
    pub points: QuadraturePoints,
    pub slots: NodeSlots,
    /// Lumped nodal masses, kg.
    pub mass: Vec<f64>,
    pub boundaries: Vec<Boundary>,
    pub constraints: Constraints,
    pub forces: Forces<M>,
}

impl<M: Material> Model<M> {
    /// Assembles the model. Masses: each point's mass rho w is split evenly among its support
    /// nodes (for FE elements this is the usual element-mass lumping). A node that carries no
    /// mass is an error naming it.
    pub fn new(
        nodes: Vec<Vector3<f64>>,
        points: QuadraturePoints,
        material: M,
        boundaries: Vec<Boundary>,
    ) -> Result<Self> {
        let n = nodes.len();
        let slots = NodeSlots::new(&points, n);
        let rho = material.density();
        let mass: Vec<f64> = (0..n)
            .map(|i| {
                slots
                    .range(i)
                    .map(|k| {
                        let p = slots.points[k] as usize;
                        rho * points.weights[p] / points.slots(p).len() as f64
                    })
                    .sum()
            })
            .collect();
        if let Some(i) = mass.iter().position(|&m| !(m > 0.0)) {
            return Err(crate::Error::Input(format!(
                "node {i} at {:?} m belongs to no element or integration point, so it has no mass; remove unused nodes",
                nodes[i].as_slice()
            )));
        }
        let constraints = Constraints::new(&boundaries, n)?;
        let forces = Forces::new(material, &points, &slots, n);
        Ok(Model {
            nodes,
            points,
            slots,
            mass,
            boundaries,
            constraints,
            forces,
        })
    }

    /// Sum of internal nodal forces over each boundary's nodes, N: the force each boundary
    /// applies to the body (negative along the axis in compression, as in REFERENCE.md).
    pub fn reactions(&self, f_int: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        self.boundaries
            .iter()
            .map(|b| {
                b.nodes
                    .iter()
                    .fold(Vector3::zeros(), |acc, &i| acc + f_int[i])
            })
            .collect()
    }
}
