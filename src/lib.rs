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

pub use error::{Error, InputKind, Result};
pub mod bc;
pub mod bench;
pub mod comparison;
pub mod coupling;
pub mod fe;
pub mod interrupt;
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

/// The examples of the Rust API guide (docs/rust-api.md), compiled and run as doc tests.
#[doc = include_str!("../docs/rust-api.md")]
#[cfg(doctest)]
pub struct RustApiGuide;

/// Whether the kernels (force lanes, sparse solves) may use AVX2 (`HYTLED_NO_AVX2` set in the environment turns it
/// off, e.g. to compare the two paths).
pub(crate) fn simd_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::env::var_os("HYTLED_NO_AVX2").is_none() && std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
