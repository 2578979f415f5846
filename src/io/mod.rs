//! Files in and out. Every reader returns plain data (no scene, no model) and refuses a file it
//! cannot use with an [`InputKind::Format`] error naming the file (and the line, where the
//! format has lines); every writer writes atomically where a half-written file would mislead.
//!
//! | room | holds | formats |
//! |---|---|---|
//! | [`mesh_file`] | reading any volume mesh by extension or `geometry.format`, units, checks | dispatches below |
//! | [`model`] | [`model::MeshInput`], what every mesh reader produces | |
//! | [`vtk`] | VTK unstructured grids in, through vtkio | `.vtk` legacy up to 4.2, `.vtu` |
//! | `vtk_legacy5` | binary legacy VTK 5.x, which vtkio does not read, into vtkio's model | `.vtk` 5.x binary |
//! | `vtk_xml` | XML VTK rewritten into the one layout vtkio reads reliably (base64 inline) | `.vtu` appended, zlib, UInt32 headers |
//! | [`msh`] | Gmsh meshes: 4.1 through mshio, 2.2 parsed here | `.msh` |
//! | [`inp`] | ABAQUS meshes with their sets, parts and assemblies; and the writer | `.inp` |
//! | [`surface_file`] | closed surfaces for `geometry.surface`, regions and contact | `.stl`, `.obj`, `.vtk`/`.vtp` poly data |
//! | [`image`] | labelmaps and scalar images in, images and displacement fields out, RAS metres | `.nii`, `.nii.gz`, `.nrrd`, `.nhdr` |
//! | [`measured`] | measured displacements, by position or node id | `.csv`, text |
//! | [`vtu`] | the result writer for ParaView, with collections | `.vtu`, `.pvd` |
//! | [`csv`] | time histories and tables | `.csv` |
//! | [`plot`] | reaction and energy plots | `.svg` |
//! | [`out_dir`] | the `--out` folder: claimed, locked, one run, a truthful summary whatever stops it | |
//!
//! Third-party parsers (vtkio, mshio, nifti, stl_io) may panic on a malformed file; their calls
//! go through `catch_quietly`, which turns such a panic into an error without printing it.

use crate::InputKind;

pub mod csv;
pub mod image;
pub mod inp;
pub mod measured;
pub mod mesh_file;
pub mod model;
pub mod msh;
pub mod out_dir;
pub mod plot;
pub mod surface_file;
pub mod vtk;
mod vtk_legacy5;
mod vtk_xml;
pub mod vtu;

/// A format error in a file: "FILE: message", the file as a fact.
pub(crate) fn file_error(path: &std::path::Path, m: impl std::fmt::Display) -> crate::Error {
    crate::Error::input(InputKind::Format, m.to_string()).file(path)
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

std::thread_local! {
    static QUIET: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// `catch_unwind` without the panic message: where a third-party parser (vtkio, mshio) panics
/// on malformed input, the caller turns it into a clear input error and the user sees no
/// backtrace. Panics on other threads, or outside this call, are reported as before.
pub(crate) fn catch_quietly<T>(f: impl FnOnce() -> T) -> std::thread::Result<T> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(std::cell::Cell::get) {
                previous(info);
            }
        }));
    });
    let was = QUIET.with(|q| q.replace(true));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    QUIET.with(|q| q.set(was));
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn catch_quietly_catches_and_restores_the_reporting() {
        assert_eq!(catch_quietly(|| 7).ok(), Some(7));
        let caught = catch_quietly(|| -> u8 { panic!("a parser's panic") });
        let message = caught.err().and_then(|p| p.downcast_ref::<&str>().copied());
        assert_eq!(message, Some("a parser's panic"));
        // Outside the call, panics on this thread are reported again.
        assert!(!QUIET.with(std::cell::Cell::get));
        // Nested calls keep the outer call quiet until it returns.
        let _ = catch_quietly(|| {
            let _ = catch_quietly(|| 1);
            assert!(QUIET.with(std::cell::Cell::get));
        });
        assert!(!QUIET.with(std::cell::Cell::get));
    }
}
