//! Readers and writers: VTU/PVD for ParaView, CSV time histories.

pub mod csv;
pub mod inp;
pub mod mesh_file;
pub mod model;
pub mod msh;
pub mod plot;
pub mod vtk;
pub mod vtu;
