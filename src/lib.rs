//! hytled: hybrid TLED finite-element / MTLED meshless solver for large deformation of soft tissue.
//!
//! Units are SI throughout: metres, kilograms, seconds, newtons, pascals, joules.
//!
//! Data flows one way: scene file -> geometry -> discretization (a flat list of quadrature
//! points) -> explicit solver -> outputs.

// `!(x > 0.0)` is deliberate throughout: it also rejects NaN, which `x <= 0.0` would let through.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

pub mod error;
pub mod geometry;
pub mod io;

pub use error::{Error, Result};
pub mod bc;
pub mod bench;
pub mod comparison;
pub mod coupling;
pub mod fe;
pub mod material;
pub mod memory;
pub mod meshless;
pub mod probe;
pub mod quadrature;
pub mod report;
pub mod scene;
pub mod simulation;
pub mod solver;
pub mod sweep;
