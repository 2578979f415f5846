//! Shapes, their structured and TetGen meshes, and node selections.

pub mod mesh;
pub mod shapes;

pub use mesh::{ElementShape, Mesh};
