//! Readers and writers: VTU/PVD for ParaView, CSV time histories.

pub mod csv;
pub mod vtu;
