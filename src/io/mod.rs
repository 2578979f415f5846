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
//! Third-party parsers (vtkio, mshio, nifti, stl_io) are called only on input checked for what
//! they are known to panic on, through `guard_parser`, which turns a panic that still happens
//! into an error; there is no panic hook (see `guard_parser` for the evidence).

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

/// A format error at a line of a file: "FILE: line N: message", the file and line as facts
/// (the wording the line-based readers have always used; see [`crate::Error::placed`]).
pub(crate) fn line_err(
    path: &std::path::Path,
    line: usize,
    m: impl std::fmt::Display,
) -> crate::Error {
    crate::Error::input(
        InputKind::Format,
        format!("{}: line {line}: {m}", path.display()),
    )
    .placed(path, line)
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

/// A third-party parser panicked: [`guard_parser`]'s error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ParserPanicked {
    /// The crate whose parser it was.
    pub parser: &'static str,
}

impl std::fmt::Display for ParserPanicked {
    /// The one wording of every reader's message for it (the fuzz tests look for it).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the parser ({}) failed on malformed data; the file is corrupt or truncated",
            self.parser
        )
    }
}

/// Runs a third-party parser (vtkio, mshio, nifti, stl_io) and turns a panic into an error:
/// a last resort only. The readers check what these parsers are known to panic on before
/// calling them, and `tests/fuzz_readers.rs` fails on any mutated file whose error is a
/// [`ParserPanicked`]: 20,000 mutations of each VTK and MSH sample and 1,500 of STL and NIfTI
/// headers reached none. So no process-wide panic hook silences them: should an input the
/// checks missed reach a panic, Rust's usual panic line is printed before the clean error.
pub(crate) fn guard_parser<T>(
    parser: &'static str,
    f: impl FnOnce() -> T,
) -> std::result::Result<T, ParserPanicked> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|_| ParserPanicked { parser })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guard_parser_turns_a_panic_into_its_error() {
        assert_eq!(guard_parser("p", || 7), Ok(7));
        let caught = guard_parser("vtkio", || -> u8 { panic!("a parser's panic") });
        assert_eq!(caught, Err(ParserPanicked { parser: "vtkio" }));
        let text = caught.unwrap_err().to_string();
        assert!(
            text.starts_with("the parser (vtkio) failed on malformed data"),
            "{text}"
        );
    }
}
