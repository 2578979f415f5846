//! Readers and writers: VTU/PVD for ParaView, CSV time histories.

pub mod csv;
pub mod vtu;
pub mod model;
pub mod inp;
pub mod msh;
pub mod vtk;
pub mod plot;
