//! Shapes, their structured and TetGen meshes, and node selections.

pub mod domain;
pub mod mesh;
pub mod quality;
pub mod select;
pub mod shapes;
#[cfg(feature = "tetgen")]
pub mod tetgen;

pub use mesh::{ElementShape, Mesh};
