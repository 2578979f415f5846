//! TLED finite elements (Miller et al. 2007): reference-configuration derivatives, volumes and
//! hourglass matrices, turned into quadrature points for the shared force kernel.

pub mod hex8;
pub mod tet10;
pub mod tet4;

use crate::geometry::{ElementShape, Mesh};
use crate::quadrature::{PointKind, QuadraturePoints};
use crate::{Error, InputKind, Result};

/// Finite-element formulations hytled offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ElementKind {
    /// One-point uniform-strain hexahedron with Joldes et al. hourglass control.
    Hex8,
    /// Linear tetrahedron, one point.
    Tet4,
    /// Average-nodal-pressure tetrahedron (Bonet & Burton 1998) for near-incompressible solids.
    Tet4Anp,
    /// Quadratic 10-node tetrahedron, four points with mean dilatation ([`tet10`]), made from
    /// a linear tet mesh.
    Tet10,
}

impl ElementKind {
    /// The mesh shape this formulation needs.
    pub fn shape(self) -> ElementShape {
        match self {
            ElementKind::Hex8 => ElementShape::Hex8,
            ElementKind::Tet4 | ElementKind::Tet4Anp | ElementKind::Tet10 => ElementShape::Tet4,
        }
    }

    /// Name as written in scene files.
    pub fn name(self) -> &'static str {
        match self {
            ElementKind::Hex8 => "hex8",
            ElementKind::Tet4 => "tet4",
            ElementKind::Tet4Anp => "tet4-anp",
            ElementKind::Tet10 => "tet10",
        }
    }
}

/// Bytes a one-point hexahedron holds beyond its eight slots ([`crate::memory::BYTES_PER_SLOT`]):
/// hourglass shape vectors and forces, stress and strain buffers. A 512,000-element hex8 cube
/// (531,441 nodes) measured 730 MiB peak, 1,460 bytes per element.
pub const HEX8_POINT_BYTES: f64 = 600.0;

/// Refuses a model of `cells` elements of `kind` (a mesh's, or the fewest a mesher will make)
/// that would not fit in memory, before its element points are built:
/// [`crate::memory::BYTES_PER_SLOT`] per element node, and [`HEX8_POINT_BYTES`] more per
/// hexahedron. `what` names the mesh in the message. A lower bound for the coupled model too,
/// whose meshless points on the same cells hold more slots than the elements.
pub fn check_model_memory(cells: f64, kind: ElementKind, what: &str) -> Result<()> {
    let per_cell = match kind {
        ElementKind::Hex8 => 8.0 * crate::memory::BYTES_PER_SLOT + HEX8_POINT_BYTES,
        ElementKind::Tet4 | ElementKind::Tet4Anp => 4.0 * crate::memory::BYTES_PER_SLOT,
        // Four points of ten slots, and about 1.2 edge nodes per element.
        ElementKind::Tet10 => 40.0 * crate::memory::BYTES_PER_SLOT + 200.0,
    };
    crate::memory::check(
        cells * per_cell,
        &format!("the model of {what}"),
        "raise discretization.size, lower discretization.divisions or use a coarser mesh",
    )
}

/// Builds one quadrature point per element. `hourglass_coefficient` is kappa_hg (hex8 only) and
/// `modulus` the elastic modulus (Pa) that scales it (mu or lambda + 2 mu). Rejects inverted or degenerate
/// elements with an error naming the element and its volume.
pub fn element_points(
    mesh: &Mesh,
    kind: ElementKind,
    hourglass_coefficient: f64,
    modulus: f64,
) -> Result<QuadraturePoints> {
    if mesh.shape != kind.shape() {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
                "element '{}' needs a {:?} mesh but the mesh holds {:?} cells",
                kind.name(),
                kind.shape(),
                mesh.shape
            ),
        ));
    }
    if kind == ElementKind::Tet10 {
        return tet10::Tet10Mesh::from_tet4(mesh)?.points();
    }
    let mut qp = QuadraturePoints::with_capacity(mesh.num_cells(), mesh.cells.len());
    for e in 0..mesh.num_cells() {
        let ids = mesh.cell(e);
        match kind {
            ElementKind::Hex8 => {
                let x: [_; 8] = std::array::from_fn(|a| mesh.nodes[ids[a]]);
                let h = hex8::Hex8Reference::new(&x)
                    .map_err(|volume| Error::InvalidElement { element: e, volume })?;
                let hg = h.hourglass_vectors(&x, hourglass_coefficient, modulus);
                qp.push_hourglass(ids, &h.b, h.volume, hg);
            }
            ElementKind::Tet10 => unreachable!("tet10 returned above"),
            ElementKind::Tet4 | ElementKind::Tet4Anp => {
                let x: [_; 4] = std::array::from_fn(|a| mesh.nodes[ids[a]]);
                let (b, volume) = tet4::derivatives(&x)
                    .map_err(|volume| Error::InvalidElement { element: e, volume })?;
                let pk = if kind == ElementKind::Tet4Anp {
                    PointKind::Anp
                } else {
                    PointKind::Standard
                };
                qp.push(ids, &b, volume, pk);
            }
        }
    }
    Ok(qp)
}
