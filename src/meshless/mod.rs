//! MTLED meshless discretization (Horton et al. 2010; thesis chapters 2-4): node clouds,
//! integration points, support domains, MLS / MMLS shape functions.
//!
//! The result is the same list of quadrature points the finite elements produce (supporting
//! node ids, dphi/dX, weight), so the force kernel, mass lumping, stable step and integrator
//! serve it unchanged.

pub mod adaptive;
pub mod cloud;
pub mod discretize;
pub mod essential;
pub mod integration;
pub mod mls;
pub mod points;
pub mod support;
