//! ABAQUS `.inp` volume meshes with their named sets: reader ([`read_inp`], [`parse_inp`]) and
//! writer ([`write_inp`]).
//!
//! Coordinates are returned as written in the file (no unit conversion: the scene's `units`
//! factor is applied by the caller). Node and element ids may be sparse and unordered; they are
//! kept in [`MeshInput::node_ids`] / [`MeshInput::element_ids`] and everything else refers to
//! 0-based positions in order of appearance.
//!
//! # Keywords read
//!
//! Keywords and parameter names are case-insensitive and blanks in them are ignored
//! (`*End Part` = `*ENDPART`); `**` starts a comment line; a keyword line ending with a comma
//! continues on the next line; blank lines are ignored; trailing commas on data lines are
//! tolerated.
//!
//! * `*HEADING`: its text lines are ignored.
//! * `*NODE` (`NSET=` optional, `SYSTEM=R` only): `id, x, y, z`. Two-coordinate (2-D) nodes
//!   are an error; a blank coordinate between others is 0 (as in ABAQUS); further fields
//!   (nodal normals) are ignored with a warning.
//! * `*ELEMENT, TYPE=..` (`ELSET=` optional). `C3D8`, `C3D8R`, `C3D8H`, `C3D8I`, `C3D8RH`, ...
//!   read as hex8, `C3D4`, `C3D4H`, `C3D4T` as tet4; all volume elements of a file must have
//!   one shape. Linear triangles and quadrilaterals (`CPS3`, `CPE3`, `S3`, `S3R`, `STRI3`,
//!   `R3D3`, `M3D3`, `SFM3D3`, `CPS4`, `CPS4R`, `CPE4`, `S4`, `S4R`, `R3D4`, `M3D4`, `M3D4R`,
//!   `SFM3D4`, `SFM3D4R`, ...) are boundary faces: they become the face set named by `ELSET=`
//!   (or `TYPE_<type>`), and any element set listing them contributes them as a face set too.
//!   Line, point, spring and mass elements (`T3D2`, `B31`, `MASS`, ...) are ignored with a
//!   warning. Any other type (`C3D10`, `C3D20R`, `C3D6`, ...) is an error. An element line
//!   ending with a comma continues on the next line.
//! * `*NSET, NSET=..` and `*ELSET, ELSET=..`, with id lists, names of other sets of the same
//!   kind, or `GENERATE` (`start, end[, step]`); `*NSET, NSET=a, ELSET=b` adds the nodes of
//!   element set `b`. Repeated definitions with one name append.
//! * `*SURFACE, NAME=s[, TYPE=ELEMENT]`: lines `elset-or-element-id[, label]`. Labels
//!   `S1`..`S6` (C3D8) / `S1`..`S4` (C3D4) give element faces (ABAQUS numbering), oriented
//!   outward (right-hand normal pointing out of the element, as
//!   [`crate::geometry::quality::boundary_faces`]); without a label the free faces of the
//!   listed volume elements are taken; surface elements are taken as written (`SNEG`: reversed).
//!   Other surface types (`TYPE=NODE`, ...) are skipped with a warning.
//! * `*INCLUDE, INPUT=file` (relative to the including file, nested up to 10 deep, cycles are
//!   an error) and `INPUT=file` on `*NODE`, `*ELEMENT`, `*NSET`, `*ELSET`, `*SURFACE`.
//! * `*PART` / `*END PART` / `*ASSEMBLY` / `*INSTANCE` / `*END INSTANCE` / `*END ASSEMBLY`
//!   (ABAQUS/CAE's layout). Every `*INSTANCE, NAME=i, PART=p` is a copy of part `p`'s nodes,
//!   elements and sets (plus any `*NODE`/`*NSET`/... between `*INSTANCE` and `*END INSTANCE`),
//!   placed by its optional data lines as ABAQUS does: a translation `dx, dy, dz`, then a
//!   rotation `xa, ya, za, xb, yb, zb, angle` by `angle` degrees about the axis through a and b
//!   (right-hand rule about a -> b), applied after the translation. The instances are merged
//!   in file order; node and element ids stay the part's (they repeat across instances; a
//!   warning lists each instance's node and element positions, and errors in a part's lines
//!   name the instance being read). A part-level set `s` becomes `i.s` for each instance
//!   (and also `s` when a single instance has a set of that name and the assembly defines
//!   none). Assembly-level `*NSET` / `*ELSET` with `INSTANCE=i` take ids (and set names) of
//!   instance `i` and keep their plain names; without `INSTANCE=`, sets of set names are read
//!   and sets of ids (assembly nodes: reference points) are skipped with a warning, as are
//!   assembly `*NODE`/`*ELEMENT` lines. Instances without volume elements (rigid or analytic
//!   parts) or of another element shape than the first instance read are skipped with a
//!   warning, with the assembly sets on them. Mesh data outside `*PART` in such a file is read
//!   as one more body with plain set names.
//! * Everything else (`*MATERIAL`, `*SOLID SECTION`, `*STEP` .. `*END STEP`, `*BOUNDARY`, ...)
//!   is skipped with its data lines; one warning lists the skipped keywords.
//!
//! Errors are [`Error::Input`] messages `file:line: problem`, where `file` is the file
//! (included or not) the line is in.

use std::path::Path;

use crate::{Error, Result};

use super::model::MeshInput;

mod assembly;
mod build;
mod elements;
mod events;
mod lines;
mod parser;
mod sets;
mod values;
mod write;

use assembly::{has_parts, parse_assembly};
use lines::{canonical, Files, Flattener};
use parser::Parser;
use write::format_inp;

/// Deepest `*INCLUDE` nesting read.
const MAX_INCLUDE_DEPTH: usize = 10;

/// Reads an ABAQUS input file (volume mesh + named sets). See the [module docs](self) for the
/// keywords read. Coordinates are as written in the file (the scene applies its units factor).
pub fn read_inp(path: &Path) -> Result<MeshInput> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8_lossy(&bytes);
    parse_inp(&text, path)
}

/// Parses the text of an ABAQUS input file; `path` names the file in errors and resolves
/// `*INCLUDE, INPUT=...` relative to its directory. Coordinates are as written in the text.
pub fn parse_inp(text: &str, path: &Path) -> Result<MeshInput> {
    let mut flat = Flattener {
        files: vec![path.to_path_buf()],
        stack: vec![canonical(path)],
    };
    let mut lines = Vec::new();
    flat.flatten(text, 0, 0, &mut lines)?;
    let files = Files(flat.files);
    if has_parts(&lines) {
        return parse_assembly(&lines, &files);
    }
    let mut p = Parser::new(&files);
    p.run(&lines)?;
    p.finish()
}

/// Writes a [`MeshInput`] as an ABAQUS input file: `*HEADING`, `*NODE`, one `*ELEMENT` block
/// (`TYPE=C3D8` or `C3D4`, `ELSET=ALL_ELEMENTS`, or `ALL_ELEMENTS_<k>` when that name holds
/// another element set), the face sets as surface elements (`CPS3` / `CPS4`, `ELSET=<name>`,
/// numbered after the volume elements) so that [`read_inp`] reads them back as face sets, then
/// `*NSET` / `*ELSET` for the node and element sets (16 ids per line).
///
/// The file's ids are `node_ids` / `element_ids` when they are positive, unique and one per
/// node / element, otherwise 1, 2, ... Coordinates are written in their shortest exact decimal
/// form, so reading the file back gives the same bits. Reading it back also gives the extra
/// element set of all elements; empty face sets are not written. Names with blanks are
/// quoted; names with `,`, `"`, `=` or control characters, names that differ only in case
/// (ABAQUS names are case-insensitive), non-finite coordinates, out-of-range indices and faces
/// that are not triangles or quadrilaterals are errors.
pub fn write_inp(path: &Path, m: &MeshInput) -> Result<()> {
    let text = format_inp(m, path)?;
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::path::PathBuf;

    use nalgebra::Vector3;

    use super::*;
    use crate::geometry::quality::tet_signed_volume;
    use crate::geometry::{ElementShape, Mesh};

    fn parse(text: &str) -> Result<MeshInput> {
        parse_inp(text, Path::new("test.inp"))
    }

    fn err(text: &str) -> String {
        match parse(text) {
            Ok(_) => panic!("expected an error for:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    fn temp_dir(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("hytled-inp-{test}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Two unit hexes along x, sparse unordered node ids, mixed-case keywords, a continued
    /// element line, GENERATE sets, *SURFACE, skipped keywords.
    const TWO_HEX: &str = "\
*Heading
 two hexes ** not a comment, heading text
** a comment
*node, nset=AllNodes
101, 0.0, 0.0, 0.0
7,   1.0, 0.0, 0.0
55,  1.0, 1.0, 0.0
3,   0.0, 1.0, 0.0
12,  0.0, 0.0, 1.0
9,   1.0, 0.0, 1.0
40,  1.0, 1.0, 1.0
41,  0.0, 1.0, 1.0

*NODE
200, 2., 0., 0.
201, 2., 1., 0.
202, 2., 0., 1.
203, 2.D0, 1.0e0, 1.,
*Element, TYPE=c3d8r, ElSet=Tissue
10, 101, 7, 55, 3,
    12, 9, 40, 41
20, 7, 200, 201, 55, 9, 202, 203, 40,
*Nset, NSET=left
101, 3, 12, 41,
*NSET, nset=gen, GENERATE
200, 203, 1
*nset, nset=left
101
*Elset, elset=second, generate
20, 20
*Elset, elset=both
second, 10
*Surface, name=TopFaces, type=ELEMENT
Tissue, S2
*SURFACE, NAME=right
20, s4
*Nset, nset=fromEl, elset=second
*Material, name=Tissue
*Hyperelastic, neo hooke
0.001, 0.1
*Step, name=Load
*Static
1., 1.
*Boundary
left, ENCASTRE
*End Step
";

    #[test]
    fn two_hex_sparse_ids_sets_and_surfaces() {
        let m = parse(TWO_HEX).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Hex8);
        assert_eq!(
            m.node_ids,
            vec![101, 7, 55, 3, 12, 9, 40, 41, 200, 201, 202, 203]
        );
        assert_eq!(m.element_ids, vec![10, 20]);
        assert_eq!(m.mesh.nodes[1], Vector3::new(1.0, 0.0, 0.0));
        assert_eq!(m.mesh.nodes[11], Vector3::new(2.0, 1.0, 1.0));
        assert_eq!(
            m.mesh.cells,
            vec![0, 1, 2, 3, 4, 5, 6, 7, 1, 8, 9, 2, 5, 10, 11, 6]
        );
        assert_eq!(m.node_sets["AllNodes"], (0..8).collect::<Vec<_>>());
        assert_eq!(m.node_sets["left"], vec![0, 3, 4, 7]);
        assert_eq!(m.node_sets["gen"], vec![8, 9, 10, 11]);
        assert_eq!(m.node_sets["fromEl"], vec![1, 2, 5, 6, 8, 9, 10, 11]);
        assert_eq!(m.element_sets["Tissue"], vec![0, 1]);
        assert_eq!(m.element_sets["second"], vec![1]);
        assert_eq!(m.element_sets["both"], vec![0, 1]);
        // S2 = 5-8-7-6, outward: 4, 5, 6, 7 of each hex.
        assert_eq!(
            m.face_sets["TopFaces"],
            vec![vec![4, 5, 6, 7], vec![5, 10, 11, 6]]
        );
        // S4 of the second hex = local 2-6-7-3, outward 1, 2, 6, 5.
        assert_eq!(m.face_sets["right"], vec![vec![8, 9, 11, 10]]);
        let w = m.warnings.join("\n");
        assert!(
            w.contains(
                "skipped keywords: *Material, *Hyperelastic, *Step, *Static, *Boundary, *End Step"
            ),
            "{w}"
        );
        // Outward normals: +z for the top faces, +x for the right face.
        let normal = |f: &Vec<usize>| {
            let x = |i: usize| m.mesh.nodes[f[i]];
            (x(2) - x(0)).cross(&(x(3) - x(1)))
        };
        for f in &m.face_sets["TopFaces"] {
            assert!(normal(f).z > 0.0, "{f:?}");
        }
        assert!(normal(&m.face_sets["right"][0]).x > 0.0);
    }

    #[test]
    fn free_faces_instance_names_and_surface_elements() {
        let text = "\
*NODE
1,0,0,0
2,1,0,0
3,0,1,0
4,0,0,1
5,1,1,1
*ELEMENT,TYPE=C3D4,ELSET=V
1,1,2,3,4
2,2,3,4,5
*ELEMENT,TYPE=S3,ELSET=skin
3,1,3,2
*ELEMENT,TYPE=T3D2
4,1,2
*ELSET,ELSET=mix
1,3,4
*SURFACE,NAME=free
V
*SURFACE,NAME=neg
skin,SNEG
*NSET,NSET=one
Part-1-1.skinnodes
";
        // Unknown name in the nset -> error naming it.
        let e = err(text);
        assert!(
            e.contains("test.inp:21") && e.contains("'Part-1-1.skinnodes'"),
            "{e}"
        );
        let text = text.replace("Part-1-1.skinnodes", "4\n*NSET,NSET=two\nPart-1-1.one");
        let m = parse(&text).unwrap();
        assert_eq!(m.face_sets["free"].len(), 6);
        assert_eq!(m.face_sets["neg"], vec![vec![0, 1, 2]]);
        assert_eq!(m.face_sets["skin"], vec![vec![0, 2, 1]]);
        assert_eq!(m.face_sets["mix"], vec![vec![0, 2, 1]]);
        assert_eq!(m.element_sets["mix"], vec![0]);
        assert_eq!(m.node_sets["two"], vec![3]);
        assert!(!m.face_sets.contains_key("TYPE_T3D2"));
        assert!(m
            .warnings
            .iter()
            .any(|w| w.contains("1 element(s) of type T3D2")));
    }

    #[test]
    fn include_files_relative_and_errors_name_the_included_file() {
        let dir = temp_dir("include");
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(
            dir.join("sub/nodes.inp"),
            "** nodes\n*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n*include, input=more.inp\n",
        )
        .unwrap();
        std::fs::write(dir.join("sub/more.inp"), "*Node\n4,0,0,1\n").unwrap();
        std::fs::write(dir.join("elems.dat"), "1, 1, 2, 3, 4\n").unwrap();
        let main = dir.join("main.inp");
        std::fs::write(
            &main,
            "*HEADING\nx\n*INCLUDE, INPUT=sub/nodes.inp\n*ELEMENT, TYPE=C3D4, INPUT=elems.dat\n",
        )
        .unwrap();
        let m = read_inp(&main).unwrap();
        assert_eq!(m.mesh.nodes.len(), 4);
        assert_eq!(m.mesh.cells, vec![0, 1, 2, 3]);

        // An error inside an included file names that file and its line.
        std::fs::write(dir.join("sub/more.inp"), "*Node\n4,0,zero,1\n").unwrap();
        let e = read_inp(&main).unwrap_err().to_string();
        assert!(e.contains("more.inp:2:") && e.contains("'zero'"), "{e}");

        // A missing include names the including line.
        std::fs::write(&main, "*INCLUDE, INPUT=nothere.inp\n").unwrap();
        let e = read_inp(&main).unwrap_err().to_string();
        assert!(
            e.contains("main.inp:1:") && e.contains("nothere.inp"),
            "{e}"
        );
        std::fs::write(&main, "*INCLUDE, INPUT=sub\n").unwrap();
        let e = read_inp(&main).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");

        // A cycle.
        std::fs::write(dir.join("a.inp"), "*INCLUDE, INPUT=b.inp\n").unwrap();
        std::fs::write(dir.join("b.inp"), "*NODE\n1,0,0,0\n*INCLUDE, INPUT=a.inp\n").unwrap();
        let e = read_inp(&dir.join("a.inp")).unwrap_err().to_string();
        assert!(
            e.contains("b.inp:3:") && e.contains("*INCLUDE cycle"),
            "{e}"
        );

        // Self include with a depth chain of distinct files beyond the limit.
        for k in 0..12 {
            std::fs::write(
                dir.join(format!("d{k}.inp")),
                format!("*INCLUDE, INPUT=d{}.inp\n", k + 1),
            )
            .unwrap();
        }
        let e = read_inp(&dir.join("d0.inp")).unwrap_err().to_string();
        assert!(e.contains("deeper than 10"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    const TET_HEAD: &str = "*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n";

    #[test]
    fn malformed_inputs_give_clear_errors() {
        // Truncated file in the middle of a continued element.
        let e = err("*NODE\n1,0,0,0\n*ELEMENT,TYPE=C3D8\n1, 1, 2, 3, 4,\n");
        assert!(
            e.contains("test.inp:4:") && e.contains("expects 8 nodes, found 4"),
            "{e}"
        );
        // Wrong node count on an element line.
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1, 1, 2, 3\n"));
        assert!(
            e.contains("test.inp:7:")
                && e.contains("element 1: type C3D4 expects 4 nodes, found 3"),
            "{e}"
        );
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1, 1, 2, 3, 4, 4\n"));
        assert!(e.contains("expects 4 nodes, found 5"), "{e}");
        // Non-numeric fields.
        let e = err("*NODE\n1, 0.0, abc, 0.0\n");
        assert!(e.contains("test.inp:2:") && e.contains("'abc'"), "{e}");
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1, 1, 2, x3, 4\n"));
        assert!(e.contains("test.inp:7:") && e.contains("'x3'"), "{e}");
        // Missing referenced node, with *NODE after *ELEMENT still fine otherwise.
        let e =
            err("*ELEMENT,TYPE=C3D4\n7, 1, 2, 3, 9\n*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n");
        assert!(
            e.contains("test.inp:2:") && e.contains("element 7 references node 9"),
            "{e}"
        );
        assert!(parse(
            "*ELEMENT,TYPE=C3D4\n7, 1, 2, 3, 4\n*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n"
        )
        .is_ok());
        // Unsupported types.
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT, type=C3D10\n1,1,2,3,4,1,2,3,4,1,2\n"
        ));
        assert!(
            e.contains("test.inp:6: unsupported element type C3D10 at line 6 (hytled reads C3D8*/C3D4*; convert or re-mesh)"),
            "{e}"
        );
        let e = err(&format!("{TET_HEAD}*ELEMENT, type=FOO12\n1,1\n"));
        assert!(e.contains("unsupported element type FOO12"), "{e}");
        let e = err(&format!("{TET_HEAD}*ELEMENT\n1,1,2,3,4\n"));
        assert!(e.contains("without TYPE="), "{e}");
        // Duplicate node id names both lines.
        let e = err("*NODE\n1,0,0,0\n2,1,0,0\n*NODE\n1,5,5,5\n");
        assert!(
            e.contains("test.inp:5:")
                && e.contains("duplicate node id 1")
                && e.contains("test.inp:2"),
            "{e}"
        );
        // Duplicate element id.
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n1,1,2,3,4\n"
        ));
        assert!(e.contains("duplicate element id 1"), "{e}");
        // 2-D nodes.
        let e = err("*NODE\n1, 0.0, 1.0\n");
        assert!(e.contains("node 1 has 2 coordinate(s)"), "{e}");
        // Mixed mesh.
        let e = err("*NODE\n1,0,0,0\n2,1,0,0\n3,0,1,0\n4,0,0,1\n5,1,1,0\n6,1,0,1\n7,1,1,1\n8,0,1,1\n*ELEMENT,TYPE=C3D8\n1,1,2,5,3,4,6,7,8\n*ELEMENT,TYPE=C3D4\n2,1,2,3,4\n");
        assert!(
            e.contains("test.inp:13:") && e.contains("element 2 is tet4") && e.contains("mixed"),
            "{e}"
        );
        // Unknown ids in sets.
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n*NSET,NSET=a\n1, 77\n"
        ));
        assert!(
            e.contains("test.inp:9:") && e.contains("node 77 is not defined"),
            "{e}"
        );
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n*ELSET,ELSET=a,GENERATE\n1,3\n"
        ));
        assert!(
            e.contains("test.inp:9:") && e.contains("element 2 is not defined"),
            "{e}"
        );
        let e = err("*NODE\n1,2,3,4\n*NSET,NSET=a,GENERATE\n1,5,0\n");
        assert!(e.contains("test.inp:4: GENERATE step '0'"), "{e}");
        let e = err("*NODE\n1,2,3,4\n*NSET,NSET=a,GENERATE\n5,1\n");
        assert!(e.contains("start 5 is after end 1"), "{e}");
        let e = err(&format!("{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,1.5\n"));
        assert!(e.contains("node id '1.5' is not a positive integer"), "{e}");
        let e = err(&format!(
            "{TET_HEAD}*ELEMENT,TYPE=C3D4\n1,1,2,3,4\n*SURFACE,NAME=s\n1,S5\n"
        ));
        assert!(
            e.contains("test.inp:9:") && e.contains("S5 does not exist on tet4"),
            "{e}"
        );
        // No volume elements.
        let e = err(TET_HEAD);
        assert!(e.contains("no volume elements"), "{e}");
        // Non-finite coordinates.
        let e = err("*NODE\n1, 0, nan, 0\n");
        assert!(e.contains("non-finite coordinate 'nan'"), "{e}");
    }

    fn sample_input() -> MeshInput {
        // 2x1x1 hexes with awkward coordinates.
        let mut nodes = Vec::new();
        for k in 0..2 {
            for j in 0..2 {
                for i in 0..3 {
                    let x = i as f64 * (1.0 / 3.0) + 1e-17 * (j as f64);
                    let y = j as f64 * 0.1 + 7.0e-300;
                    let z = if k == 0 { -0.0 } else { 123456.789e-5 };
                    nodes.push(Vector3::new(x, y, z));
                }
            }
        }
        let id = |i: usize, j: usize, k: usize| i + 3 * j + 6 * k;
        let mut cells = Vec::new();
        for i in 0..2 {
            cells.extend([
                id(i, 0, 0),
                id(i + 1, 0, 0),
                id(i + 1, 1, 0),
                id(i, 1, 0),
                id(i, 0, 1),
                id(i + 1, 0, 1),
                id(i + 1, 1, 1),
                id(i, 1, 1),
            ]);
        }
        let mut m = MeshInput {
            mesh: Mesh {
                nodes,
                shape: ElementShape::Hex8,
                cells,
            },
            node_ids: vec![9, 8, 7, 6, 5, 4, 300, 2, 1, 10, 11, 12],
            element_ids: vec![5, 3],
            node_sets: BTreeMap::new(),
            element_sets: BTreeMap::new(),
            face_sets: BTreeMap::new(),
            warnings: Vec::new(),
        };
        m.node_sets.insert("bottom".into(), (0..6).collect());
        m.node_sets.insert("with space".into(), vec![3]);
        m.node_sets.insert("empty".into(), vec![]);
        m.node_sets.insert("many".into(), (0..12).collect());
        m.element_sets.insert("first".into(), vec![0]);
        m.element_sets.insert("load".into(), vec![1]);
        m.face_sets.insert("load".into(), vec![vec![2, 8, 11, 5]]);
        m.face_sets.insert(
            "mixed".into(),
            vec![
                vec![0, 1, 2],
                vec![0, 3, 4, 1],
                vec![6, 7, 8],
                vec![2, 1, 0],
            ],
        );
        m
    }

    #[test]
    fn write_then_read_round_trip_is_exact() {
        let m = sample_input();
        let dir = temp_dir("roundtrip");
        let path = dir.join("out.inp");
        write_inp(&path, &m).unwrap();
        let r = read_inp(&path).unwrap();
        assert_eq!(r.mesh.shape, m.mesh.shape);
        assert_eq!(r.mesh.nodes.len(), m.mesh.nodes.len());
        for (a, b) in r.mesh.nodes.iter().zip(&m.mesh.nodes) {
            for k in 0..3 {
                assert_eq!(a[k].to_bits(), b[k].to_bits(), "{a:?} vs {b:?}");
            }
        }
        assert_eq!(r.mesh.cells, m.mesh.cells);
        assert_eq!(r.node_ids, m.node_ids);
        assert_eq!(r.element_ids, m.element_ids);
        assert_eq!(r.node_sets, m.node_sets);
        let mut expected = m.element_sets.clone();
        expected.insert("ALL_ELEMENTS".into(), vec![0, 1]);
        assert_eq!(r.element_sets, expected);
        assert_eq!(r.face_sets, m.face_sets);
        assert!(r.warnings.is_empty(), "{:?}", r.warnings);
        // Writing again is stable, and a conflicting ALL_ELEMENTS gets another name.
        let text = format_inp(&r, &path).unwrap();
        let r2 = parse_inp(&text, &path).unwrap();
        assert_eq!(r2.element_sets, r.element_sets);
        let mut m3 = m.clone();
        m3.element_sets.insert("all_elements".into(), vec![1]);
        let r3 = parse_inp(&format_inp(&m3, &path).unwrap(), &path).unwrap();
        assert_eq!(r3.element_sets["all_elements"], vec![1]);
        assert_eq!(r3.element_sets["ALL_ELEMENTS_1"], vec![0, 1]);
        // Tet meshes, and unusable ids replaced by 1..n.
        let t = MeshInput {
            mesh: Mesh {
                nodes: vec![
                    Vector3::new(0.0, 0.0, 0.0),
                    Vector3::new(1.0, 0.0, 0.0),
                    Vector3::new(0.0, 1.0, 0.0),
                    Vector3::new(0.0, 0.0, 1.0),
                ],
                shape: ElementShape::Tet4,
                cells: vec![0, 1, 2, 3],
            },
            node_ids: vec![],
            element_ids: vec![0],
            node_sets: BTreeMap::new(),
            element_sets: BTreeMap::new(),
            face_sets: BTreeMap::new(),
            warnings: vec![],
        };
        let rt = parse_inp(&format_inp(&t, &path).unwrap(), &path).unwrap();
        assert_eq!(rt.mesh.cells, t.mesh.cells);
        assert_eq!(rt.node_ids, vec![1, 2, 3, 4]);
        assert_eq!(rt.element_ids, vec![1]);
        // Names .inp cannot carry.
        let mut bad = t.clone();
        bad.node_sets.insert("a,b".into(), vec![0]);
        assert!(format_inp(&bad, &path)
            .unwrap_err()
            .to_string()
            .contains("'a,b'"));
        let mut bad = t.clone();
        bad.node_sets.insert("Top".into(), vec![0]);
        bad.node_sets.insert("TOP".into(), vec![1]);
        assert!(format_inp(&bad, &path)
            .unwrap_err()
            .to_string()
            .contains("differ only in case"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn data_file(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/inp")
            .join(name)
    }

    #[test]
    fn gmsh_style_file() {
        let m = read_inp(&data_file("gmsh_cube_tet4.inp")).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Tet4);
        assert_eq!(m.mesh.nodes.len(), 8);
        assert_eq!(m.mesh.num_cells(), 6);
        assert_eq!(m.element_ids, vec![25, 26, 27, 28, 29, 30]);
        for e in 0..6 {
            let c = m.mesh.cell(e);
            let v = tet_signed_volume(
                &m.mesh.nodes[c[0]],
                &m.mesh.nodes[c[1]],
                &m.mesh.nodes[c[2]],
                &m.mesh.nodes[c[3]],
            );
            assert!((v - 1.0 / 6.0).abs() < 1e-12, "element {e}: {v}");
        }
        assert_eq!(m.element_sets["Volume1"], (0..6).collect::<Vec<_>>());
        assert_eq!(m.element_sets["tissue"], (0..6).collect::<Vec<_>>());
        assert_eq!(m.face_sets["Surface1"], vec![vec![0, 2, 1], vec![0, 3, 2]]);
        assert_eq!(m.face_sets["bottom"], m.face_sets["Surface1"]);
        assert_eq!(m.face_sets["top"].len(), 2);
        assert_eq!(m.node_sets["bottom"], vec![0, 1, 2, 3]);
        assert_eq!(m.node_sets["top"], vec![4, 5, 6, 7]);
        assert!(!m.element_sets.contains_key("Line1") && !m.face_sets.contains_key("Line1"));
        assert!(
            m.warnings.iter().any(|w| w.contains("T3D2")),
            "{:?}",
            m.warnings
        );
        // The boundary faces from the file are outward.
        for f in m.face_sets["Surface1"].iter().chain(&m.face_sets["top"]) {
            let x = |i: usize| m.mesh.nodes[f[i]];
            let n = (x(1) - x(0)).cross(&(x(2) - x(0)));
            let c = (x(0) + x(1) + x(2)) / 3.0 - Vector3::repeat(0.5);
            assert!(n.dot(&c) > 0.0);
        }
    }

    #[test]
    fn abaqus_cae_style_file() {
        let m = read_inp(&data_file("abaqus_cae_block_hex8.inp")).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Hex8);
        assert_eq!(m.mesh.nodes.len(), 12);
        assert_eq!(
            m.mesh.cells,
            vec![0, 1, 4, 3, 6, 7, 10, 9, 1, 2, 5, 4, 7, 8, 11, 10]
        );
        assert_eq!(m.node_sets["Set-1"], (0..12).collect::<Vec<_>>());
        assert_eq!(m.element_sets["Set-1"], vec![0, 1]);
        assert_eq!(m.node_sets["Fixed"], vec![0, 3, 6, 9]);
        assert_eq!(
            m.face_sets["Top"],
            vec![vec![6, 7, 10, 9], vec![7, 8, 11, 10]]
        );
        assert_eq!(m.face_sets["Load"], vec![vec![2, 5, 11, 8]]);
        // The part's sets also under the instance's name.
        assert_eq!(m.node_sets["Block-1.Set-1"], m.node_sets["Set-1"]);
        assert_eq!(m.face_sets["Block-1.Top"], m.face_sets["Top"]);
        assert_eq!(m.node_ids, (1..=12).collect::<Vec<u64>>());
        // The tet instance (another shape) and the reference point are skipped, not read.
        let w = m.warnings.join("\n");
        assert!(
            w.contains("instance 'Indenter-1' (part 'Indenter') is tet4 but instance 'Block-1' (part 'Block') is hex8"),
            "{w}"
        );
        assert!(w.contains("IndTip (instance Indenter-1)"), "{w}");
        assert!(
            w.contains("skipped keywords:") && w.contains("*Material") && w.contains("*Step"),
            "{w}"
        );
        assert!(w.contains("reference points"), "{w}");
        assert!(!w.contains("Fixed"), "{w}");
    }

    /// ABAQUS/CAE assembly: two placed instances of one part and one of another, part-level
    /// sets per instance, assembly sets with INSTANCE=.
    #[test]
    fn assembly_instances_are_placed_copies() {
        let m = read_inp(&data_file("abaqus_cae_two_instances.inp")).unwrap();
        assert_eq!(m.mesh.shape, ElementShape::Hex8);
        assert_eq!(m.mesh.nodes.len(), 32);
        assert_eq!(m.mesh.num_cells(), 5);
        let ids: Vec<u64> = (1..=12).chain(1..=12).chain(1..=8).collect();
        assert_eq!(m.node_ids, ids);
        assert_eq!(m.element_ids, vec![1, 2, 1, 2, 1]);
        let near = |i: usize, x: [f64; 3]| {
            let d = (m.mesh.nodes[i] - Vector3::from(x)).amax();
            assert!(d < 1e-12, "node {i}: {:?} vs {x:?}", m.mesh.nodes[i]);
        };
        // Beam-1 as written.
        near(2, [1.0, 0.0, 0.0]);
        near(11, [1.0, 0.5, 0.5]);
        // Beam-2: translated by (0, 0, 2), then turned 90 degrees about the z axis through
        // (0, 0, 2): (x, y, z) -> (-y, x, z + 2).
        near(12, [0.0, 0.0, 2.0]);
        near(14, [0.0, 1.0, 2.0]);
        near(23, [-0.5, 1.0, 2.5]);
        // Pad-1: translated by (2, 0, 0).
        near(31, [2.5, 0.5, 0.1]);
        // Cells point into their own instance's nodes.
        assert_eq!(&m.mesh.cells[16..24], &[12, 13, 16, 15, 18, 19, 22, 21]);
        assert_eq!(&m.mesh.cells[32..40], &[24, 25, 27, 26, 28, 29, 31, 30]);
        // Part-level sets, once per instance.
        assert_eq!(m.node_sets["Beam-1.Set-All"], (0..12).collect::<Vec<_>>());
        assert_eq!(m.node_sets["Beam-2.Set-All"], (12..24).collect::<Vec<_>>());
        assert_eq!(m.element_sets["Beam-2.Set-All"], vec![2, 3]);
        assert_eq!(m.node_sets["Beam-2.End"], vec![14, 17, 20, 23]);
        assert_eq!(m.face_sets["Beam-2.Top"].len(), 2);
        // A name only one instance has keeps its plain name too; shared ones do not.
        assert_eq!(m.node_sets["PadAll"], (24..32).collect::<Vec<_>>());
        assert_eq!(m.element_sets["Pad-1.PadAll"], vec![4]);
        assert!(!m.node_sets.contains_key("Set-All") && !m.node_sets.contains_key("End"));
        // Assembly sets: ids and set names resolved in their instance.
        assert_eq!(m.node_sets["Fixed"], vec![0, 3, 6, 9]);
        assert_eq!(m.node_sets["Ends"], vec![2, 5, 8, 11, 14, 17, 20, 23]);
        assert_eq!(m.node_sets["Clamp"], vec![24, 25, 26, 27]);
        // S4 of Beam-2's element 2 (the +x face in the part), outward: +y after the turn.
        assert_eq!(m.face_sets["Load"], vec![vec![14, 17, 23, 20]]);
        let f = &m.face_sets["Load"][0];
        let x = |i: usize| m.mesh.nodes[f[i]];
        let n = (x(2) - x(0)).cross(&(x(3) - x(1)));
        assert!(n.y > 0.0 && n.x.abs() < 1e-12, "{n:?}");
        // No inverted elements after the rotation; the instances are listed.
        let w = m.warnings.join("\n");
        assert!(!w.contains("non-positive"), "{w}");
        assert!(
            w.contains("3 part instances read")
                && w.contains("instance 'Beam-2' (part 'Beam'): nodes 12..24, elements 2..4"),
            "{w}"
        );
    }

    #[test]
    fn assembly_errors_name_the_instance_and_line() {
        let text = std::fs::read_to_string(data_file("abaqus_cae_two_instances.inp")).unwrap();
        let bad = |from: &str, to: &str| {
            assert!(text.contains(from), "{from}");
            err(&text.replacen(from, to, 1))
        };
        let e = bad("part=Pad\n", "part=Padx\n");
        assert!(
            e.contains("test.inp:74: *Instance Pad-1: part 'Padx' is not defined"),
            "{e}"
        );
        let e = bad("instance=Pad-1", "instance=Pad-2");
        assert!(
            e.contains(
                "test.inp:88: *Nset Clamp: INSTANCE=Pad-2 is not an instance of the assembly"
            ),
            "{e}"
        );
        // A missing node in an assembly set names the instance.
        let e = bad(" 1, 2, 3, 4\n*End Assembly", " 1, 2, 3, 9\n*End Assembly");
        assert!(
            e.contains("test.inp:89: *NSET Clamp: node 9 is not defined (in instance 'Pad-1')"),
            "{e}"
        );
        // A missing node in a part names the instance read.
        let e = bad("1, 1, 2, 4, 3, 5, 6, 8, 7", "1, 1, 2, 4, 3, 5, 6, 8, 70");
        assert!(
            e.contains("test.inp:51: element 1 references node 70")
                && e.contains("[instance 'Pad-1' of part 'Pad']"),
            "{e}"
        );
        // Positioning lines.
        let e = bad(
            "          2.,           0.,           0.\n",
            "          2., x, 0.\n",
        );
        assert!(
            e.contains("test.inp:75: *Instance Pad-1 translation") && e.contains("'x'"),
            "{e}"
        );
        let e = bad("          3.,          90.", "          2.,          90.");
        assert!(
            e.contains("test.inp:71: *Instance Beam-2: the rotation axis points a and b coincide"),
            "{e}"
        );
        let e = bad("          0.,           0.,           2.\n", "1, 2, 3, 4\n");
        assert!(
            e.contains("test.inp:70: *Instance Beam-2: 4 fields on the translation"),
            "{e}"
        );
        // Structure.
        let e = bad("*End Part\n**\n*Part, name=Pad", "**\n**\n*Part, name=Pad");
        assert!(
            e.contains("test.inp:40: *Part inside part 'Beam' (line 8)"),
            "{e}"
        );
        let e = bad("name=Pad-1", "name=Beam-1");
        assert!(e.contains("instance 'Beam-1' is defined twice"), "{e}");
    }

    /// Sets that reference themselves stay bounded (no doubling per line).
    #[test]
    fn self_referencing_sets_stay_small() {
        let mut text =
            format!("{TET_HEAD}*ELEMENT,TYPE=C3D4,ELSET=e\n1,1,2,3,4\n*NSET,NSET=a\n1,2\n");
        for _ in 0..200 {
            text.push_str(
                "*NSET,NSET=a\na, a, a, a\n*ELSET,ELSET=e\ne, e, e\n*NSET,NSET=a,ELSET=e\n",
            );
        }
        let m = parse(&text).unwrap();
        assert_eq!(m.node_sets["a"], vec![0, 1, 2, 3]);
        assert_eq!(m.element_sets["e"], vec![0]);
    }

    /// Random byte mutations of valid files never panic.
    #[test]
    fn mutations_never_panic() {
        let seeds = [
            TWO_HEX.to_string(),
            std::fs::read_to_string(data_file("gmsh_cube_tet4.inp")).unwrap(),
            std::fs::read_to_string(data_file("abaqus_cae_block_hex8.inp")).unwrap(),
            std::fs::read_to_string(data_file("abaqus_cae_two_instances.inp")).unwrap(),
        ];
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut rnd = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let alphabet = b"*,=\n 0123456789.-eEDSabcNODEgenratI\"";
        let mut ok = 0;
        for it in 0..3000 {
            let mut b = seeds[it % seeds.len()].clone().into_bytes();
            for _ in 0..(1 + rnd() % 6) {
                if b.is_empty() {
                    break;
                }
                let pos = (rnd() as usize) % b.len();
                match rnd() % 4 {
                    0 => b[pos] = alphabet[(rnd() as usize) % alphabet.len()],
                    1 => {
                        b.remove(pos);
                    }
                    2 => b.insert(pos, alphabet[(rnd() as usize) % alphabet.len()]),
                    _ => b.truncate(pos),
                }
            }
            let text = String::from_utf8_lossy(&b);
            if parse_inp(&text, Path::new("/nonexistent/fuzz.inp")).is_ok() {
                ok += 1;
            }
        }
        assert!(ok > 0);
    }
}
