//! ABAQUS element types: which are volumes, faces or ignored, and their faces.

use crate::geometry::ElementShape;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum ElemKind {
    Volume(ElementShape),
    /// Boundary face with this many nodes.
    Surface(usize),
    /// Line / point / connector element: ignored; node count when known.
    Ignored(Option<usize>),
    Unsupported,
}

pub(super) fn classify(ty: &str) -> ElemKind {
    if let Some(rest) = ty.strip_prefix("C3D8") {
        if rest.len() <= 3 && rest.chars().all(|c| "RHITS".contains(c)) {
            return ElemKind::Volume(ElementShape::Hex8);
        }
    }
    if let Some(rest) = ty.strip_prefix("C3D4") {
        if rest.len() <= 2 && rest.chars().all(|c| "HT".contains(c)) {
            return ElemKind::Volume(ElementShape::Tet4);
        }
    }
    match ty {
        "CPS3" | "CPE3" | "S3" | "S3R" | "S3RS" | "STRI3" | "R3D3" | "M3D3" | "SFM3D3" | "DS3"
        | "CPS3T" | "CPE3T" => ElemKind::Surface(3),
        "CPS4" | "CPS4R" | "CPS4I" | "CPE4" | "CPE4R" | "CPE4I" | "CPE4H" | "CPE4RH" | "S4"
        | "S4R" | "S4RS" | "S4R5" | "R3D4" | "M3D4" | "M3D4R" | "SFM3D4" | "SFM3D4R" | "DS4" => {
            ElemKind::Surface(4)
        }
        "T2D2" | "T3D2" | "T2D2H" | "T3D2H" | "B21" | "B21H" | "B31" | "B31H" | "B33" | "B33H"
        | "CONN3D2" | "CONN2D2" | "SPRING2" | "SPRINGA" | "DASHPOT2" | "DASHPOTA" | "GAPUNI"
        | "RB3D2" | "RB2D2" | "R2D2" | "R3D2" => ElemKind::Ignored(Some(2)),
        "T2D3" | "T3D3" | "B22" | "B32" | "B22H" | "B32H" => ElemKind::Ignored(Some(3)),
        "SPRING1" | "DASHPOT1" | "MASS" | "ROTARYI" | "HEATCAP" => ElemKind::Ignored(Some(1)),
        _ => ElemKind::Unsupported,
    }
}

pub(super) fn shape_name(s: ElementShape) -> &'static str {
    match s {
        ElementShape::Hex8 => "hex8",
        ElementShape::Tet4 => "tet4",
    }
}

/// ABAQUS faces S1.. of each shape as 0-based local nodes, outward oriented (the ABAQUS node
/// list of the face reversed, keeping its first node).
pub(super) fn element_face(shape: ElementShape, k: usize) -> Option<&'static [usize]> {
    const HEX: [[usize; 4]; 6] = [
        [0, 3, 2, 1],
        [4, 5, 6, 7],
        [0, 1, 5, 4],
        [1, 2, 6, 5],
        [2, 3, 7, 6],
        [3, 0, 4, 7],
    ];
    const TET: [[usize; 3]; 4] = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]];
    match shape {
        ElementShape::Hex8 => HEX.get(k).map(|f| &f[..]),
        ElementShape::Tet4 => TET.get(k).map(|f| &f[..]),
    }
}

pub(super) fn num_faces(shape: ElementShape) -> usize {
    match shape {
        ElementShape::Hex8 => 6,
        ElementShape::Tet4 => 4,
    }
}
