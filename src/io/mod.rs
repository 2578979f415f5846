//! Readers and writers: VTU/PVD for ParaView, CSV time histories.

pub mod csv;
pub mod inp;
pub mod measured;
pub mod mesh_file;
pub mod model;
pub mod msh;
pub mod out_dir;
pub mod plot;
pub mod vtk;
mod vtk_legacy5;
mod vtk_xml;
pub mod vtu;

/// An input error naming the file: "FILE: message".
pub(crate) fn file_error(path: &std::path::Path, m: impl std::fmt::Display) -> crate::Error {
    crate::Error::Input(format!("{}: {m}", path.display()))
}

/// A line shortened to 60 characters for messages.
pub(crate) fn clip(s: &str) -> String {
    const MAX: usize = 60;
    if s.chars().count() <= MAX {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(MAX).collect();
        t.push_str("...");
        t
    }
}
