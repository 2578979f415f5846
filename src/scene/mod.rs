//! Scene files: the TOML schema, `--set` overrides by dotted path, and validation.
//!
//! All values are SI: metres, kilograms, seconds, pascals.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::geometry::select::Selection;
use crate::solver::Mode;
use crate::{Error, Result};

/// A complete scene.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Short name used in reports; defaults to the file stem.
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub description: Option<String>,
    pub geometry: Geometry,
    #[serde(default)]
    pub discretization: Discretization,
    pub material: MaterialSpec,
    #[serde(default)]
    pub boundaries: BTreeMap<String, BoundarySpec>,
    /// `[regions.NAME]`: tissue regions with their own material.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub regions: BTreeMap<String, RegionSpec>,
    /// `[loads.NAME]`: gravity, point forces, tractions and pressures.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub loads: BTreeMap<String, LoadSpec>,
    /// `[measured.NAME]`: displacements prescribed node by node from a file.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub measured: BTreeMap<String, MeasuredSpec>,
    /// `[contact.NAME]`: rigid bodies the body's surface touches without friction.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub contact: BTreeMap<String, ContactSpec>,
    /// `[curves.NAME]`: tabulated load curves that boundaries and loads name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub curves: BTreeMap<String, CurveSpec>,
    #[serde(default)]
    pub solver: SolverSpec,
    #[serde(default)]
    pub probes: BTreeMap<String, ProbeSpec>,
    #[serde(default)]
    pub references: BTreeMap<String, ReferenceSpec>,
    #[serde(default)]
    pub output: OutputSpec,
    /// `[initial]`: rigid initial motion (dynamic runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial: Option<InitialSpec>,
    /// Directory of the scene file: relative input paths are resolved against it.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// The body: a built-in shape, or a mesh file. Lengths in m.
///
/// Written `[geometry] shape = "box"` with `min`, `max`; `shape = "cylinder"` with `radius`,
/// `height`; `shape = "half_ellipsoid"` with `semi_axes = [a, b, c]`; or `mesh = "meshes/part.inp"` (any of .inp, .msh, .vtk, .vtu, by extension or
/// `format`) with `units` (the factor that turns the file's lengths into m, e.g. 0.001 for mm).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "GeometryToml", into = "GeometryToml")]
pub enum Geometry {
    /// Axis-aligned box [min, max].
    Box { min: [f64; 3], max: [f64; 3] },
    /// Circular cylinder along z, base at z = 0, centred on x = y = 0.
    Cylinder { radius: f64, height: f64 },
    /// Half-ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0, with `semi_axes` = [a, b, c]:
    /// flat elliptical base (semi-axes a along x, b along y) on z = 0 centred on x = y = 0,
    /// apex at (0, 0, c). Meshed by TetGen only (`mesher = "tetgen"`).
    HalfEllipsoid { semi_axes: [f64; 3] },
    /// A mesh file (relative paths are resolved against the scene file's directory).
    Mesh {
        file: PathBuf,
        format: Option<MeshFormat>,
        /// File length unit in m (1 for m, 0.001 for mm).
        units: f64,
        /// Merge coincident nodes (within 1e-9 x the bounding-box diagonal) on load.
        merge_duplicates: bool,
    },
}

pub use crate::io::mesh_file::MeshFormat;

/// `[geometry]` as written.
#[derive(Debug, Clone, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct GeometryToml {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shape: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    min: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    max: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    height: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    semi_axes: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mesh: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    format: Option<MeshFormat>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    units: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    merge_duplicates: Option<bool>,
}

impl TryFrom<GeometryToml> for Geometry {
    type Error = String;
    fn try_from(g: GeometryToml) -> std::result::Result<Self, String> {
        let only = |allowed: &[&str]| -> std::result::Result<(), String> {
            let given = [
                ("min", g.min.is_some()),
                ("max", g.max.is_some()),
                ("radius", g.radius.is_some()),
                ("height", g.height.is_some()),
                ("semi_axes", g.semi_axes.is_some()),
                ("format", g.format.is_some()),
                ("units", g.units.is_some()),
                ("merge_duplicates", g.merge_duplicates.is_some()),
            ];
            match given.iter().find(|(k, set)| *set && !allowed.contains(k)) {
                Some((k, _)) => Err(format!(
                    "geometry: `{k}` does not apply here (allowed: {})",
                    allowed.join(", ")
                )),
                None => Ok(()),
            }
        };
        match (g.mesh.clone(), g.shape.as_deref()) {
            (Some(file), None) | (Some(file), Some("mesh")) => {
                only(&["format", "units", "merge_duplicates"])?;
                Ok(Geometry::Mesh {
                    file,
                    format: g.format,
                    units: g.units.unwrap_or(1.0),
                    merge_duplicates: g.merge_duplicates.unwrap_or(false),
                })
            }
            (None, Some("box")) => {
                only(&["min", "max"])?;
                match (g.min, g.max) {
                    (Some(min), Some(max)) => Ok(Geometry::Box { min, max }),
                    _ => Err("geometry: a box needs `min` and `max` (m)".into()),
                }
            }
            (None, Some("cylinder")) => {
                only(&["radius", "height"])?;
                match (g.radius, g.height) {
                    (Some(radius), Some(height)) => Ok(Geometry::Cylinder { radius, height }),
                    _ => Err("geometry: a cylinder needs `radius` and `height` (m)".into()),
                }
            }
            (None, Some("half_ellipsoid")) => {
                only(&["semi_axes"])?;
                match g.semi_axes {
                    Some(semi_axes) => Ok(Geometry::HalfEllipsoid { semi_axes }),
                    None => Err("geometry: a half_ellipsoid needs `semi_axes = [a, b, c]` (m; base semi-axes a along x, b along y, height c along z)".into()),
                }
            }
            (Some(_), Some(s)) => Err(format!("geometry: give either `mesh = \"file\"` or `shape = \"{s}\"`, not both")),
            (None, Some(s)) => Err(format!("geometry: unknown shape '{s}'; use \"box\", \"cylinder\", \"half_ellipsoid\" or `mesh = \"file.inp|.msh|.vtk|.vtu\"`")),
            (None, None) => Err("geometry: give `shape = \"box\" | \"cylinder\" | \"half_ellipsoid\"` or `mesh = \"file\"`".into()),
        }
    }
}

impl From<Geometry> for GeometryToml {
    fn from(g: Geometry) -> Self {
        match g {
            Geometry::Box { min, max } => GeometryToml {
                shape: Some("box".into()),
                min: Some(min),
                max: Some(max),
                ..Default::default()
            },
            Geometry::Cylinder { radius, height } => GeometryToml {
                shape: Some("cylinder".into()),
                radius: Some(radius),
                height: Some(height),
                ..Default::default()
            },
            Geometry::HalfEllipsoid { semi_axes } => GeometryToml {
                shape: Some("half_ellipsoid".into()),
                semi_axes: Some(semi_axes),
                ..Default::default()
            },
            Geometry::Mesh {
                file,
                format,
                units,
                merge_duplicates,
            } => GeometryToml {
                mesh: Some(file),
                format,
                units: Some(units),
                merge_duplicates: Some(merge_duplicates),
                ..Default::default()
            },
        }
    }
}

/// Discretization method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// TLED finite elements.
    #[default]
    Fe,
    /// MTLED meshless: node cloud, integration points, MLS / MMLS shape functions.
    Meshless,
    /// Finite elements on the boundary (`fe_layers` cell layers), meshless nodes inside, FE and
    /// MLS shape functions blended by a ramp in the transition layer.
    Coupled,
}

/// The modulus that scales the hex8 hourglass stiffness.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum HourglassModulus {
    /// The shear modulus mu: hourglass modes are resisted like shear, so the stiffness stays
    /// bounded as nu -> 0.5.
    #[default]
    Shear,
    /// The P-wave modulus lambda + 2 mu (NiftySim, Joldes et al. 2008).
    PWave,
}

/// Points of a coupled scene's transition cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum TransitionRuleKind {
    /// Full Gauss rule: 2x2x2 (hexahedra), four points (tets).
    #[default]
    Full,
    /// Tets: the interior's `tet_rule`; hexahedra keep 2x2x2.
    Interior,
}

/// Where the FE layer of a coupled scene lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum FeRegionKind {
    /// `fe_layers` cell layers along the whole boundary surface.
    #[default]
    Surface,
    /// `fe_layers` cell layers around the nodes of the essential boundaries (fixed or driven
    /// components) only; free surfaces are meshless (coupled paper sect. 3.2).
    Essential,
}

/// Where meshless nodes come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum CloudKind {
    /// The vertices of the tet mesh the scene's sizing makes (structured or TetGen).
    #[default]
    Mesh,
    /// A regular lattice of spacing `size` with a random jitter of `jitter` x the spacing.
    Lattice,
    /// Quasi-random (Halton) fill with a minimum spacing of `min_spacing` x `size`.
    Halton,
    /// Nodes read from `cloud_file` (CSV or whitespace XYZ, m).
    File,
}

/// Where meshless integration points come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum IntegrationKind {
    /// Background tetrahedra (the mesh whose vertices are the nodes, or a Delaunay
    /// tetrahedralization of the cloud) with `tet_rule` points each.
    #[default]
    Tets,
    /// A regular background grid, one point per cell, `point_ratio` points per node (Horton 2010).
    Grid,
    /// Background tetrahedra refined adaptively (thesis chapter 5, Joldes et al. 2015): each
    /// tet's `tet_rule` estimate of the "less smooth" integrand (thesis eq. 5.5) is compared
    /// with the sum over its `subdivision` children; cells differing by more than `tolerance`
    /// are refined, to at most `max_level` levels.
    Adaptive,
}

impl IntegrationKind {
    /// True when the points come from background tetrahedra (plain or adaptive).
    pub fn uses_tets(self) -> bool {
        matches!(self, IntegrationKind::Tets | IntegrationKind::Adaptive)
    }
}

/// Support-domain rule of the meshless shape functions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum SupportKind {
    /// Nodes whose influence sphere (dilatation x mean neighbour distance) covers the point.
    #[default]
    Radius,
    /// The `support_nodes` nearest nodes, weight radius `alpha` x the farthest (Horton 2010).
    Nearest,
}

/// MLS polynomial basis as written in scenes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Basis {
    /// Linear MLS, m = 4.
    #[default]
    Linear,
    /// Modified MLS with quadratic basis, m = 10.
    Quadratic,
}

/// How essential boundary conditions act on meshless nodes (thesis chapter 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum BcMethod {
    /// EBCIEM with the radius support rule, SEBCIEM with the nearest-node rule: the nearest
    /// rule's shape functions jump where the set of nearest nodes changes, which makes the
    /// EBCIEM boundary integrals inconsistent with the nodal rows (cylinder runs diverged
    /// within 50 steps), while SEBCIEM only evaluates at the nodes.
    #[default]
    Auto,
    /// Exact imposition with the distributed boundary force interpolated linearly over the
    /// triangulated boundary (thesis sect. 4.3).
    Ebciem,
    /// Exact imposition with the boundary force lumped at the nodes (thesis sect. 4.3.1).
    Sebciem,
    /// Prescribe the nodal parameters (inexact: MLS is not interpolating).
    Correction,
}

impl BcMethod {
    /// The method `Auto` stands for under the given support rule.
    pub fn resolve(self, support: SupportKind) -> BcMethod {
        match (self, support) {
            (BcMethod::Auto, SupportKind::Radius) => BcMethod::Ebciem,
            (BcMethod::Auto, SupportKind::Nearest) => BcMethod::Sebciem,
            (m, _) => m,
        }
    }

    /// Name as written in scenes and summaries.
    pub fn name(self) -> &'static str {
        match self {
            BcMethod::Auto => "auto",
            BcMethod::Ebciem => "ebciem",
            BcMethod::Sebciem => "sebciem",
            BcMethod::Correction => "correction",
        }
    }
}

/// Element formulation names as written in scenes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum ElementName {
    #[default]
    #[serde(rename = "hex8")]
    Hex8,
    #[serde(rename = "tet4")]
    Tet4,
    #[serde(rename = "tet4-anp")]
    Tet4Anp,
}

impl From<ElementName> for crate::fe::ElementKind {
    fn from(e: ElementName) -> Self {
        match e {
            ElementName::Hex8 => crate::fe::ElementKind::Hex8,
            ElementName::Tet4 => crate::fe::ElementKind::Tet4,
            ElementName::Tet4Anp => crate::fe::ElementKind::Tet4Anp,
        }
    }
}

/// How tetrahedra are made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Mesher {
    /// Structured hexahedra, or tetrahedra from splitting their extruded prisms (no slivers).
    #[default]
    Structured,
    /// TetGen through tritet (feature `tetgen`; AGPL-3.0).
    Tetgen,
}

/// `[discretization]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Discretization {
    #[serde(default)]
    pub method: Method,
    #[serde(default)]
    pub element: ElementName,
    /// Target element edge length, m.
    #[serde(default)]
    pub size: Option<f64>,
    /// Explicit divisions: box [nx, ny, nz]; cylinder [n_inner, n_radial, n_axial].
    #[serde(default)]
    pub divisions: Option<[usize; 3]>,
    #[serde(default)]
    pub mesher: Mesher,
    /// Hourglass coefficient kappa_hg of hex8 (Joldes et al. 2008), dimensionless. Default
    /// 0.51 with `hourglass_modulus = "shear"` (0.51 mu = 0.01 (lambda + 2 mu) at nu = 0.49,
    /// the calibration of README "Hourglass coefficient"), 0.01 with `"p-wave"`.
    #[serde(default)]
    pub hourglass: Option<f64>,
    /// The modulus that scales the hourglass stiffness: `shear` (mu, default) or `p-wave`
    /// (lambda + 2 mu, NiftySim's; it grows without bound as nu -> 0.5 and locks hex8).
    #[serde(default)]
    pub hourglass_modulus: HourglassModulus,
    /// TetGen radius-edge ratio bound (quality), when `mesher = "tetgen"`.
    #[serde(default)]
    pub radius_edge_ratio: Option<f64>,
    /// Meshless: node source.
    #[serde(default)]
    pub cloud: CloudKind,
    /// Meshless: node file for `cloud = "file"` (relative to the scene file), m.
    #[serde(default)]
    pub cloud_file: Option<PathBuf>,
    /// Meshless lattice: random offset per component, as a fraction of the spacing, [0, 0.5).
    #[serde(default)]
    pub jitter: f64,
    /// Meshless Halton fill: minimum node spacing as a fraction of `size` (default 0.85, which
    /// fills to about the density of the lattice of spacing `size`).
    #[serde(default = "default_min_spacing")]
    pub min_spacing: f64,
    /// Seed of the random and quasi-random clouds.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Meshless: integration points on background tets or a regular grid.
    #[serde(default)]
    pub integration: IntegrationKind,
    /// Points per background tet: 1, 4 or 5 (default 4 meshless, 1 for the tets of a coupled
    /// interior; a hexahedral coupled interior uses 2x2x2 Gauss points per cell instead).
    /// Read it through [`Discretization::tet_rule`].
    #[serde(default, rename = "tet_rule", skip_serializing_if = "Option::is_none")]
    pub tet_rule_points: Option<usize>,
    /// Tet integration: background tets merged into one integration point (their total
    /// volume at their centroid, binned on a grid of about this many tets per cell; 1 = one
    /// rule per tet, the default).
    /// Read it through [`Discretization::tets_per_point`].
    #[serde(
        default,
        rename = "tets_per_point",
        skip_serializing_if = "Option::is_none"
    )]
    pub tets_per_point_given: Option<f64>,
    /// Grid integration: integration points per node (default 2, Horton 2010 sect. 3.2).
    #[serde(default = "default_point_ratio")]
    pub point_ratio: f64,
    /// Adaptive integration: relative accuracy of the less-smooth integrand per cell (default
    /// 0.001).
    #[serde(default = "default_adaptive_tolerance")]
    pub tolerance: f64,
    /// Adaptive integration: children per split, 2 (longest-edge bisection, default), 4 (three
    /// edge midpoints) or 8 (all six edge midpoints).
    #[serde(default = "default_subdivision")]
    pub subdivision: usize,
    /// Adaptive integration: deepest refinement level (default 3; at most 18, 9 or 6 for
    /// subdivision 2, 4 or 8).
    #[serde(default = "default_max_level")]
    pub max_level: usize,
    #[serde(default)]
    pub support: SupportKind,
    /// Radius rule: influence radius / mean neighbour distance (default 1.6 linear, 2.0 quadratic).
    #[serde(default)]
    pub dilatation: Option<f64>,
    /// Nearest rule: nodes per support (default 8 linear, 16 quadratic).
    #[serde(default)]
    pub support_nodes: Option<usize>,
    /// Nearest rule: weight radius / farthest support distance (default 10, Horton 2010).
    #[serde(default = "default_alpha")]
    pub alpha: f64,
    /// MLS basis: linear (m = 4) or quadratic (Modified MLS, m = 10).
    #[serde(default)]
    pub basis: Basis,
    /// MMLS weight of the second-order coefficients in support-scaled coordinates (default 1e-7).
    #[serde(default = "default_mu")]
    pub mu: f64,
    /// Smallest accepted reciprocal condition number of a moment matrix (default 1e-10).
    #[serde(default = "default_min_rcond")]
    pub min_rcond: f64,
    /// Essential boundary conditions on meshless nodes.
    #[serde(default)]
    pub bc_method: BcMethod,
    /// Coupled: cell layers of finite elements from the boundary inwards (default 2).
    #[serde(default, rename = "fe_layers")]
    pub fe_layers_given: Option<usize>,
    /// Coupled: where the FE layer lies, `surface` or `essential` (see [`FeRegionKind`];
    /// default: [`Discretization::fe_region`]).
    #[serde(default, rename = "fe_region")]
    pub fe_region_given: Option<FeRegionKind>,
    /// Coupled: points of the transition cells, `full` (2x2x2 / 4 per tet) or `interior`
    /// (tets: the interior's `tet_rule`; default: [`Discretization::transition_rule`]).
    #[serde(default, rename = "transition_rule")]
    pub transition_rule_given: Option<TransitionRuleKind>,
    /// Coupled: influence-radius factor of the interface nodes (radius rule; default 1.5).
    /// Their supports must reach across the transition layer, where only one side has MLS
    /// nodes (exact cube, fe_layers = 2: F_z 0.40 % off at 1.0, 0.016 % at 1.5).
    #[serde(default = "default_interface_scale")]
    pub interface_scale: f64,
    /// Coupled: mean dilatation (the cell's weighted mean J) at the Gauss points of each
    /// transition cell, so the fully integrated blended cells do not lock as nu -> 0.5
    /// (default true; false = plain full integration).
    #[serde(default = "default_true")]
    pub mean_dilatation: bool,
}

fn default_adaptive_tolerance() -> f64 {
    0.001
}

fn default_subdivision() -> usize {
    2
}

fn default_max_level() -> usize {
    3
}

fn default_interface_scale() -> f64 {
    1.5
}

fn default_min_spacing() -> f64 {
    0.85
}
fn default_seed() -> u64 {
    1
}
impl Discretization {
    /// (kappa_hg, modulus in Pa) of the hex8 hourglass stiffness for a material with Lame
    /// parameters `lambda`, `mu` (Pa).
    pub fn hourglass_scale(&self, lambda: f64, mu: f64) -> (f64, f64) {
        match self.hourglass_modulus {
            HourglassModulus::Shear => (self.hourglass.unwrap_or(0.51), mu),
            HourglassModulus::PWave => (self.hourglass.unwrap_or(0.01), lambda + 2.0 * mu),
        }
    }

    /// A coupled scene on an unstructured tetrahedral mesh whose vertices are the nodes
    /// (element tet4 / tet4-anp, cloud = "mesh"): the FE layer goes around the essential
    /// boundaries only. Measured on the 4,208-node Gmsh cylinder: errors (reaction / probe)
    /// compression 1.89 / 0.98 %, extension 0.38 / 0.07 %, shear 0.81 / 0.01 % against 3.30 /
    /// 2.52, 1.40 / 1.42 and 1.98 / 0.01 % with two tet4-anp layers along the whole surface.
    fn unstructured_tets(&self) -> bool {
        self.element != ElementName::Hex8 && self.cloud == CloudKind::Mesh
    }

    /// Coupled FE layer depth in cells: as given, else 1 on unstructured tets (a second
    /// tet4-anp layer stiffens the bonded rim: compression reaction 2.83 % off against 1.46 %
    /// on the 4,208-node Gmsh cylinder, FE around the driven faces, MMLS interior) and 2 on
    /// hexahedra.
    pub fn fe_layers(&self) -> usize {
        self.fe_layers_given
            .unwrap_or(if self.unstructured_tets() { 1 } else { 2 })
    }

    /// Where the coupled FE layer lies: as given, else around the essential boundaries on
    /// unstructured tets and along the whole surface otherwise.
    pub fn fe_region(&self) -> FeRegionKind {
        self.fe_region_given.unwrap_or(if self.unstructured_tets() {
            FeRegionKind::Essential
        } else {
            FeRegionKind::Surface
        })
    }

    /// Points of the coupled transition cells: as given, else the interior's rule on
    /// unstructured tets and the full rule otherwise. On the 4,208-node Gmsh cylinder the one
    /// point per transition tet is both the more accurate (worst error 1.43 % against 1.89 %
    /// with four points) and cheaper per step (19,374 against 28,914 points of about 29
    /// support nodes). It under-integrates a load concentrated on a few driven nodes: the
    /// brain indentation force fell to 0.0431 N (3,520 nodes) against 0.0496 N with the full
    /// rule and about 0.051 N refined; such scenes set `transition_rule = "full"`.
    pub fn transition_rule(&self) -> TransitionRuleKind {
        self.transition_rule_given
            .unwrap_or(if self.unstructured_tets() {
                TransitionRuleKind::Interior
            } else {
                TransitionRuleKind::Full
            })
    }

    /// Background tets per integration point: as given, else 1 (one `tet_rule` per tet).
    /// Merging trades a quadrature error that does not vanish under refinement for fewer
    /// points. Coupled, 4,208-node Gmsh cylinder (one point per transition tet): worst error
    /// over compression, extension and shear 1.43 % with 1 (16,194 interior points), 0.90 %
    /// with 3 (5,555 points, 1.1-1.4x fe tet4-anp's solve against 1.5-1.9x); at 17,917 nodes
    /// 0.59 % with 1 and 1.61 % with 3 (reactions 0.5-0.8 % softer at every resolution); with
    /// 5 relaxation finds spurious modes (12,120 steps in compression, 4.7 % off).
    pub fn tets_per_point(&self) -> f64 {
        self.tets_per_point_given.unwrap_or(1.0)
    }

    /// Points per background tet: `tet_rule` as given, else 4 (meshless) or 1 (coupled).
    pub fn tet_rule(&self) -> usize {
        self.tet_rule_points
            .unwrap_or(if self.method == Method::Coupled { 1 } else { 4 })
    }
}
fn default_point_ratio() -> f64 {
    2.0
}
fn default_alpha() -> f64 {
    10.0
}
fn default_mu() -> f64 {
    1e-7
}
fn default_min_rcond() -> f64 {
    1e-10
}

impl Default for Discretization {
    fn default() -> Self {
        Discretization {
            method: Method::Fe,
            element: ElementName::Hex8,
            size: None,
            divisions: None,
            mesher: Mesher::Structured,
            hourglass: None,
            hourglass_modulus: HourglassModulus::default(),
            radius_edge_ratio: None,
            cloud: CloudKind::Mesh,
            cloud_file: None,
            jitter: 0.0,
            min_spacing: default_min_spacing(),
            seed: default_seed(),
            integration: IntegrationKind::Tets,
            tet_rule_points: None,
            tets_per_point_given: None,
            interface_scale: default_interface_scale(),
            mean_dilatation: true,
            point_ratio: default_point_ratio(),
            tolerance: default_adaptive_tolerance(),
            subdivision: default_subdivision(),
            max_level: default_max_level(),
            support: SupportKind::Radius,
            dilatation: None,
            support_nodes: None,
            alpha: default_alpha(),
            basis: Basis::Linear,
            mu: default_mu(),
            min_rcond: default_min_rcond(),
            bc_method: BcMethod::Auto,
            fe_layers_given: None,
            fe_region_given: None,
            transition_rule_given: None,
        }
    }
}

/// `[material]`: neo-Hookean or one-term Ogden from (E, nu) or (mu, kappa), plus density.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    /// "neo-hookean" (default) or "ogden".
    #[serde(default = "default_model")]
    pub model: String,
    /// Young's modulus E, Pa (small strain).
    #[serde(default)]
    pub youngs_modulus: Option<f64>,
    /// Poisson's ratio nu (small strain).
    #[serde(default)]
    pub poisson_ratio: Option<f64>,
    /// Shear modulus mu, Pa.
    #[serde(default)]
    pub shear_modulus: Option<f64>,
    /// Bulk modulus kappa, Pa.
    #[serde(default)]
    pub bulk_modulus: Option<f64>,
    /// Ogden exponent alpha (non-zero; -4.7 for brain, Miller and Chinzei 2002).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha: Option<f64>,
    /// Density, kg/m^3.
    pub density: f64,
}

fn default_model() -> String {
    "neo-hookean".into()
}

impl MaterialSpec {
    /// (mu, kappa) in Pa from (E, nu) or (mu, kappa).
    fn moduli(&self) -> (f64, f64) {
        match (self.youngs_modulus, self.poisson_ratio) {
            (Some(e), Some(nu)) => (e / (2.0 * (1.0 + nu)), e / (3.0 * (1.0 - 2.0 * nu))),
            _ => (
                self.shear_modulus.unwrap_or(0.0),
                self.bulk_modulus.unwrap_or(0.0),
            ),
        }
    }

    /// The neo-Hookean material these keys describe: from (E, nu) or (mu, kappa).
    pub fn neo_hookean(&self) -> crate::material::NeoHookean {
        match (self.youngs_modulus, self.poisson_ratio) {
            (Some(e), Some(nu)) => {
                crate::material::NeoHookean::from_young_poisson(e, nu, self.density)
            }
            _ => {
                let (mu, kappa) = self.moduli();
                crate::material::NeoHookean {
                    mu,
                    kappa,
                    density: self.density,
                }
            }
        }
    }

    /// The material these keys describe.
    pub fn solid(&self) -> crate::material::Solid {
        use crate::material::{Ogden, Solid};
        match self.model.as_str() {
            "ogden" => {
                let (mu, kappa) = self.moduli();
                Solid::Ogden(Ogden {
                    mu,
                    alpha: self.alpha.unwrap_or(2.0),
                    kappa,
                    density: self.density,
                })
            }
            _ => Solid::NeoHookean(self.neo_hookean()),
        }
    }

    /// These keys with a region's given keys in their place. A region that gives E or nu
    /// takes the other of the pair from here (likewise mu and kappa); giving both pairs is an
    /// error the validation reports.
    pub fn with(&self, r: &RegionSpec) -> MaterialSpec {
        let mut m = self.clone();
        if let Some(model) = &r.model {
            m.model = model.clone();
        }
        let e_nu = r.youngs_modulus.is_some() || r.poisson_ratio.is_some();
        let mu_kappa = r.shear_modulus.is_some() || r.bulk_modulus.is_some();
        if e_nu {
            m.youngs_modulus = r.youngs_modulus.or(self.youngs_modulus);
            m.poisson_ratio = r.poisson_ratio.or(self.poisson_ratio);
            if !mu_kappa {
                (m.shear_modulus, m.bulk_modulus) = (None, None);
            }
        }
        if mu_kappa {
            m.shear_modulus = r.shear_modulus.or(self.shear_modulus);
            m.bulk_modulus = r.bulk_modulus.or(self.bulk_modulus);
            if !e_nu {
                (m.youngs_modulus, m.poisson_ratio) = (None, None);
            }
        }
        m.alpha = r.alpha.or(m.alpha);
        m.density = r.density.unwrap_or(m.density);
        m
    }
}

/// `[regions.NAME]`: a tissue region with its own material. Points of the region (by
/// `select`, a box, sphere or cylinder tested at the point, or `elements`, an element set of
/// the mesh file) take [material] with the keys given here in place of its own.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub select: Option<Selection>,
    /// An element set of the mesh file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elements: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub youngs_modulus: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poisson_ratio: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shear_modulus: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bulk_modulus: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density: Option<f64>,
}

/// A displacement component name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Component {
    X,
    Y,
    Z,
    All,
}

/// Prescribed final displacement per component, m.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Displacement {
    pub x: Option<f64>,
    pub y: Option<f64>,
    pub z: Option<f64>,
}

/// `[boundaries.NAME]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoundarySpec {
    pub select: Selection,
    /// Components held at zero.
    #[serde(default)]
    pub fix: Vec<Component>,
    /// Components driven to these values along `curve`.
    #[serde(default)]
    pub displacement: Option<Displacement>,
    /// A built-in curve ("smooth", "ramp", "constant", "smooth-return") or the name of a
    /// `[curves.NAME]` table.
    #[serde(default = "default_curve")]
    pub curve: String,
}

fn default_curve() -> String {
    "smooth".into()
}

/// `[loads.NAME]`: one load, scaled by its curve. Exactly one of `gravity`, `force`,
/// `traction` or `pressure`; the last three act on `select` (nodes for `force`, the boundary
/// faces whose corners are all selected for `traction` and `pressure`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadSpec {
    /// Body force: the acceleration of gravity, m/s^2 (e.g. [0, 0, -9.81]); every node gets
    /// its lumped mass times it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gravity: Option<[f64; 3]>,
    /// Force on each selected node, N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force: Option<[f64; 3]>,
    /// Dead traction on the selected faces, Pa (force per reference area, fixed direction).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub traction: Option<[f64; 3]>,
    /// Follower pressure on the selected faces, Pa, along the deformed inward normal
    /// (positive pushes into the body).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pressure: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub select: Option<Selection>,
    /// As a boundary's `curve` (default "smooth").
    #[serde(default = "default_curve")]
    pub curve: String,
}

impl LoadSpec {
    /// The load acts on faces (traction, pressure).
    pub fn on_faces(&self) -> bool {
        self.traction.is_some() || self.pressure.is_some()
    }
}

/// `[measured.NAME]`: displacements measured on the surface (e.g. registered from
/// intra-operative images), prescribed node by node along `curve`: `file` holds `x, y, z, ux,
/// uy, uz` per line (each point taken by the nearest surface node within `tolerance`) or `id,
/// ux, uy, uz` (node ids of the mesh file), in m. An essential boundary named NAME.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasuredSpec {
    /// The file, relative to the scene file.
    pub file: PathBuf,
    /// Largest distance from a measured point to the surface node that takes it, m (default
    /// 1e-3 x the body's bounding-box diagonal).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<f64>,
    #[serde(default = "default_curve")]
    pub curve: String,
}

/// `[contact.NAME]`: a rigid body moved by `motion` along `curve`, which the body's surface
/// points touch without friction (the body stays outside it): `shape = "plane"` with `point`
/// and `normal` (pointing to the body), `"sphere"` with `center` and `radius`, or
/// `"cylinder"` with `center`, `axis`, `radius` and optional `min` / `max` (the extent along
/// the axis from `center`, flat ends). `select` limits the surface points that may touch it.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactSpec {
    pub shape: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normal: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<f64>,
    /// The rigid body's displacement at the end of its curve, m.
    #[serde(default)]
    pub motion: [f64; 3],
    #[serde(default = "default_curve")]
    pub curve: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub select: Option<Selection>,
}

impl ContactSpec {
    /// The rigid surface these keys describe (validated: every key its shape needs is there).
    pub fn rigid_shape(&self) -> crate::bc::contact::RigidShape {
        use crate::bc::contact::RigidShape;
        let v = |a: Option<[f64; 3]>| nalgebra::Vector3::from(a.unwrap_or_default());
        match self.shape.as_str() {
            "plane" => RigidShape::Plane {
                point: v(self.point),
                normal: v(self.normal).normalize(),
            },
            "sphere" => RigidShape::Sphere {
                center: v(self.center),
                radius: self.radius.unwrap_or(0.0),
            },
            _ => RigidShape::Cylinder {
                center: v(self.center),
                axis: v(self.axis).normalize(),
                radius: self.radius.unwrap_or(0.0),
                min: self.min,
                max: self.max,
            },
        }
    }
}

/// `[curves.NAME]`: a tabulated load curve, (time s, factor of the final value) pairs, linear
/// between them and held beyond them, given inline (`points`) or in a CSV file (`file`, two
/// columns; relative to the scene file). Relaxation maps `solver.load_time` onto its load steps.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CurveSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<Vec<[f64; 2]>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
}

/// `[solver]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    #[serde(default)]
    pub mode: Mode,
    /// Dynamic: simulated time, s.
    #[serde(default = "default_duration")]
    pub duration: f64,
    /// Dynamic: time over which the load curves run, s (default: the duration).
    #[serde(default)]
    pub load_time: Option<f64>,
    /// Relaxation: pseudo-steps over which the load curves run (default: the larger of 400 and
    /// the steps a shear wave takes to cross the body, so near-incompressible bodies are not
    /// loaded faster than they can shear).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_steps: Option<usize>,
    #[serde(default = "default_dt_factor")]
    pub dt_factor: f64,
    /// `"global"` (default: Lanczos on the reference stiffness) or `"bounds"` (the per-point
    /// and nodal bounds, 1.3-2.5x more conservative).
    #[serde(default)]
    pub time_step: crate::solver::StepEstimate,
    /// Mass-proportional damping, 1/s (dynamic).
    #[serde(default)]
    pub damping: f64,
    /// Relaxation convergence tolerance on the estimated displacement error, m.
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    #[serde(default = "default_max_steps")]
    pub max_steps: usize,
    /// Relaxation: steps between lowest-frequency estimates.
    #[serde(default = "default_interval")]
    pub estimate_interval: usize,
    /// Relaxation: restarts from the unloaded state with a 0.75x shorter step after an
    /// instability, at most this many (None: the solver's default, 2; 0 stops at the first
    /// instability).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retries: Option<usize>,
    /// Estimate the critical step again at the deformed state during the run and shorten the
    /// step when deformation has raised the frequencies (default true): dynamic runs from the
    /// start, relaxation after a restart.
    #[serde(default = "default_true")]
    pub step_update: bool,
}

fn default_true() -> bool {
    true
}

fn default_duration() -> f64 {
    3.0
}
fn default_dt_factor() -> f64 {
    0.9
}
fn default_tolerance() -> f64 {
    1e-7
}
fn default_max_steps() -> usize {
    1_000_000
}
fn default_interval() -> usize {
    50
}

impl Default for SolverSpec {
    fn default() -> Self {
        SolverSpec {
            mode: Mode::Dynamic,
            duration: default_duration(),
            load_time: None,
            load_steps: None,
            dt_factor: default_dt_factor(),
            time_step: Default::default(),
            damping: 0.0,
            tolerance: default_tolerance(),
            max_steps: default_max_steps(),
            estimate_interval: default_interval(),
            retries: None,
            step_update: true,
        }
    }
}

/// `[probes.NAME]`: a material point whose displacement is reported, or (`select`) the mean
/// displacement of a selection of nodes (e.g. `select = { set = "tip" }`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSpec {
    /// Reference position, m.
    #[serde(default)]
    pub position: Option<[f64; 3]>,
    /// Nodes whose displacements are averaged.
    #[serde(default)]
    pub select: Option<Selection>,
}

/// `[references.NAME]`: a published or exact value to compare with.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSpec {
    /// `reaction.BOUNDARY.x|y|z` (N) or `probe.NAME.x|y|z` (m).
    pub quantity: String,
    /// The reference value (N or m). Filled in from `exact` when that is given.
    #[serde(default)]
    pub value: Option<f64>,
    /// `"uniaxial"`: the exact homogeneous solution of a box stretched or compressed along one
    /// axis with free lateral faces (REFERENCE.md "Cube"), computed from the scene's material,
    /// box and prescribed displacement, so it follows `--set material.poisson_ratio=...`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exact: Option<String>,
    #[serde(default)]
    pub source: Option<String>,
}

/// `[initial]`: the body starts with the rigid velocity field v(X) = velocity +
/// angular_velocity x (X - center) on its free DOFs (dynamic runs only).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialSpec {
    /// Translational velocity, m/s.
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Angular velocity, rad/s (e.g. [0, 0, 6.283185307179586] spins at 1 Hz about z).
    #[serde(default)]
    pub angular_velocity: [f64; 3],
    /// Centre of the rotation, m.
    #[serde(default)]
    pub center: [f64; 3],
}

/// `[output]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// VTU frames (dynamic: equally spaced in time).
    #[serde(default = "default_frames")]
    pub frames: usize,
    /// Rows in the time-history CSV (dynamic).
    #[serde(default = "default_history")]
    pub history_rows: usize,
}

fn default_frames() -> usize {
    10
}
fn default_history() -> usize {
    200
}

impl Default for OutputSpec {
    fn default() -> Self {
        OutputSpec {
            frames: default_frames(),
            history_rows: default_history(),
        }
    }
}

impl Scene {
    /// True for `solver.mode = "dynamic"`.
    pub fn mode_is_dynamic(&self) -> bool {
        self.solver.mode == Mode::Dynamic
    }
}

/// Loads a scene file, applies `--set key.path=value` overrides and validates it.
pub fn load(path: &Path, overrides: &[String]) -> Result<Scene> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse(&text, path, overrides)
}

/// Parses scene text (see [`load`]); `path` names the source in errors.
pub fn parse(text: &str, path: &Path, overrides: &[String]) -> Result<Scene> {
    let err = |message: String| Error::Scene {
        file: PathBuf::from(path),
        message,
    };
    // Deserialise the file as written first, so schema errors carry its line numbers.
    let mut scene: Scene = toml::from_str(text).map_err(|e| {
        let hint = toml::from_str::<toml::Table>(text)
            .ok()
            .and_then(|t| name_hint(&t))
            .map_or(String::new(), |h| format!("\n  {h}"));
        err(format!(
            "{}{hint}",
            with_suggestion(&e.to_string()).trim_end()
        ))
    })?;
    let mut value: toml::Table = toml::from_str(text).map_err(|e| err(e.to_string()))?;
    for o in overrides {
        apply_override(&mut value, o).map_err(|m| err(format!("--set {o}: {m}")))?;
    }
    check_finite(&toml::Value::Table(value.clone()), "").map_err(err)?;
    if !overrides.is_empty() {
        if let Some(h) = name_hint(&value) {
            return Err(err(format!("after --set overrides: {h}")));
        }
        // The merged table has no source lines to point at; name the key path instead.
        scene = serde_path_to_error::deserialize(toml::Value::Table(value)).map_err(
            |e: serde_path_to_error::Error<toml::de::Error>| {
                let (at, message) = (e.path().to_string(), e.inner().message());
                // Custom checks (geometry, ...) already start with their key.
                let key = if at == "." || message.starts_with(&format!("{at}:")) {
                    String::new()
                } else {
                    format!("{at}: ")
                };
                err(format!(
                    "after --set overrides: {key}{}",
                    with_suggestion(message)
                ))
            },
        )?;
    }
    scene.base_dir = path.parent().map(PathBuf::from).unwrap_or_default();
    if scene.name.is_none() {
        scene.name = path.file_stem().map(|s| s.to_string_lossy().into_owned());
    }
    validate(&scene).map_err(err)?;
    resolve_exact(&mut scene).map_err(err)?;
    Ok(scene)
}

/// For a key that takes a name but got a number, array or bool (`support = 8` meant as
/// `support_nodes = 8`), "KEY: expected a name in quotes, one of `a`, `b`": serde says only
/// "wanted string or table". The names come from deserialising again with "?" at that key.
fn name_hint(table: &toml::Table) -> Option<String> {
    let e =
        serde_path_to_error::deserialize::<_, Scene>(toml::Value::Table(table.clone())).err()?;
    let message = e.inner().message();
    if !(message.contains("unit variant") || message.contains("wanted string or table")) {
        return None;
    }
    let mut probe = table.clone();
    let mut segments = e.path().iter().peekable();
    let mut cur = &mut probe;
    while let Some(seg) = segments.next() {
        let serde_path_to_error::Segment::Map { key } = seg else {
            return None;
        };
        if segments.peek().is_none() {
            cur.insert(key.clone(), toml::Value::String("?".into()));
            break;
        }
        cur = cur.get_mut(key)?.as_table_mut()?;
    }
    let again = serde_path_to_error::deserialize::<_, Scene>(toml::Value::Table(probe)).err()?;
    let m = again.inner().message();
    let marker = "unknown variant `?`, expected ";
    let names = &m[m.find(marker)? + marker.len()..];
    Some(format!("{}: expected a name in quotes, {names}", e.path()))
}

/// Computes the value of every `exact = "uniaxial"` reference: a box with one face (a plane
/// selection at the box's min or max along axis k) driven by d along k stretches by
/// lambda = 1 + d / L_k; the lateral stretch a and sigma_kk come from
/// [`crate::material::uniaxial_stretch`]. Reactions along k on either end face are
/// +-sigma_kk times the deformed cross-section; probe displacements are (stretch - 1) times
/// the probe's distance from the box's min corner.
fn resolve_exact(s: &mut Scene) -> std::result::Result<(), String> {
    let names: Vec<String> = s
        .references
        .iter()
        .filter(|(_, r)| r.exact.is_some())
        .map(|(n, _)| n.clone())
        .collect();
    for name in names {
        let r = &s.references[&name];
        let kind = r.exact.clone().unwrap_or_default();
        let fail = |why: String| format!("references.{name}: exact = '{kind}': {why}");
        if kind != "uniaxial" {
            return Err(fail("the known exact solution is 'uniaxial'".into()));
        }
        let Geometry::Box { min, max } = s.geometry else {
            return Err(fail("needs geometry.shape = 'box'".into()));
        };
        // The driven face: the one boundary with a prescribed displacement on a face of the box
        // (conditions inside the box, such as a plane held at the exact field, are ignored).
        let on_face = |b: &BoundarySpec| match &b.select {
            Selection::Plane { axis, value, .. } => {
                let k = axis.index();
                let tol = 1e-9 * (max[k] - min[k]);
                ((value - max[k]).abs() <= tol)
                    .then_some((k, true))
                    .or_else(|| ((value - min[k]).abs() <= tol).then_some((k, false)))
            }
            _ => None,
        };
        let driven: Vec<(&String, &BoundarySpec, usize, bool)> = s
            .boundaries
            .iter()
            .filter(|(_, b)| b.displacement.is_some())
            .filter_map(|(n, b)| on_face(b).map(|(k, at_max)| (n, b, k, at_max)))
            .collect();
        let [(bname, b, k, at_max)] = driven[..] else {
            return Err(fail(format!(
                "needs exactly one boundary with a displacement on a face of the box (found {})",
                driven.len()
            )));
        };
        let d = b.displacement.clone().unwrap_or(Displacement {
            x: None,
            y: None,
            z: None,
        });
        let comps = [d.x, d.y, d.z];
        if (0..3).any(|c| c != k && comps[c].is_some_and(|v| v != 0.0)) {
            return Err(fail(format!(
                "boundary '{bname}' must be driven along its normal only"
            )));
        }
        let len = max[k] - min[k];
        let dk = comps[k].unwrap_or(0.0);
        let stretch = 1.0 + if at_max { dk } else { -dk } / len;
        if !(stretch > 0.0) {
            return Err(fail(format!(
                "the stretch 1 + d / L = {stretch} must be positive"
            )));
        }
        if !s.regions.is_empty() {
            return Err(fail(
                "the exact uniaxial solution holds for one material; this scene has regions".into(),
            ));
        }
        let (a, _, sigma) = match s.material.solid() {
            crate::material::Solid::NeoHookean(m) => crate::material::uniaxial_stretch(&m, stretch),
            crate::material::Solid::Ogden(m) => m.uniaxial(stretch),
        };
        let parts: Vec<&str> = r.quantity.split('.').collect();
        let c = match parts[2] {
            "x" => 0,
            "y" => 1,
            _ => 2,
        };
        let value = match parts[0] {
            "reaction" if c == k => {
                let Some(Selection::Plane { axis, value, .. }) =
                    s.boundaries.get(parts[1]).map(|b| &b.select)
                else {
                    return Err(fail(format!("boundary '{}' must select a face", parts[1])));
                };
                if axis.index() != k {
                    return Err(fail(format!(
                        "boundary '{}' is not an end face along {}",
                        parts[1],
                        ["x", "y", "z"][k]
                    )));
                }
                let area: f64 = (0..3)
                    .filter(|&i| i != k)
                    .map(|i| a * (max[i] - min[i]))
                    .product();
                let sign = if (value - max[k]).abs() < (value - min[k]).abs() {
                    1.0
                } else {
                    -1.0
                };
                sign * sigma * area
            }
            "reaction" => {
                return Err(fail(
                    "lateral reactions vanish exactly; a relative error against 0 is undefined"
                        .into(),
                ))
            }
            _ => {
                let Some(pos) = s.probes.get(parts[1]).and_then(|p| p.position) else {
                    return Err(fail(format!("probe '{}' needs a `position`", parts[1])));
                };
                let st = if c == k { stretch } else { a };
                (st - 1.0) * (pos[c] - min[c])
            }
        };
        if let Some(r) = s.references.get_mut(&name) {
            r.value = Some(value);
        }
    }
    Ok(())
}

/// Refuses nan and inf anywhere in the scene (TOML allows them; no scene value means them).
fn check_finite(v: &toml::Value, key: &str) -> std::result::Result<(), String> {
    match v {
        toml::Value::Float(x) if !x.is_finite() => Err(format!(
            "{key} = {x}: numbers must be finite (nan and inf are not scene values)"
        )),
        toml::Value::Array(a) => a
            .iter()
            .enumerate()
            .try_for_each(|(i, x)| check_finite(x, &format!("{key}[{i}]"))),
        toml::Value::Table(t) => t.iter().try_for_each(|(k, x)| {
            let key = if key.is_empty() {
                k.clone()
            } else {
                format!("{key}.{k}")
            };
            check_finite(x, &key)
        }),
        _ => Ok(()),
    }
}

/// Built-in meshes larger than this many elements are refused before any memory is taken
/// (about 1 kB per element and its points: 20 GB).
pub const MAX_ELEMENTS: f64 = 2e7;

/// Sets `a.b.c = value` in a TOML table; the value is parsed as TOML (number, bool, array,
/// inline table) or else taken as a string.
pub fn apply_override(
    table: &mut toml::Table,
    assignment: &str,
) -> std::result::Result<(), String> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or("expected key.path=value")?;
    let key = key.trim();
    let raw = raw.trim();
    if key.is_empty() {
        return Err("empty key".into());
    }
    let value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
        Ok(mut t) => t.remove("v").unwrap_or(toml::Value::String(raw.into())),
        // TOML refuses numbers past f64 (1e400); taken as a string they would read "expected f64".
        Err(_) if raw.parse::<f64>().is_ok() => {
            return Err(format!(
                "{raw} is not a finite number (f64 spans about 1e-308 to 1e308)"
            ))
        }
        Err(_) => toml::Value::String(raw.into()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for (i, part) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            cur.insert(part.to_string(), value);
            return Ok(());
        }
        let entry = cur
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = match entry {
            toml::Value::Table(t) => t,
            _ => return Err(format!("'{}' is not a table", parts[..=i].join("."))),
        };
    }
    Ok(())
}

/// Appends "did you mean ...?" to serde's unknown-field / unknown-variant messages, and says
/// "a table" where serde names an internal type ("expected struct SolverSpec").
fn with_suggestion(msg: &str) -> String {
    if let Some(start) = msg.find("expected struct ") {
        let rest = &msg[start + "expected struct ".len()..];
        let end = rest
            .find(|c: char| !c.is_alphanumeric() && c != '_')
            .unwrap_or(rest.len());
        return format!(
            "{}expected a table (a [section] or {{ key = value, ... }}){}",
            &msg[..start],
            &rest[end..]
        );
    }
    for marker in ["unknown field `", "unknown variant `"] {
        if let Some(start) = msg.find(marker) {
            let rest = &msg[start + marker.len()..];
            let Some(end) = rest.find('`') else { break };
            let bad = &rest[..end];
            // rest[end..] = "`, expected one of `a`, `b`": the names are every other piece.
            let candidates: Vec<&str> = rest[end..].split('`').skip(2).step_by(2).collect();
            let best = candidates
                .iter()
                .map(|c| (strsim::jaro_winkler(bad, c), *c))
                .max_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((score, c)) = best {
                if score > 0.7 {
                    return format!("{}\n  did you mean `{c}`?", msg.trim_end());
                }
            }
        }
    }
    // toml's own wording for inline tables: "unexpected keys in table: a, available keys: b, c".
    if let Some(start) = msg.find("unexpected keys in table: ") {
        let rest = &msg[start + "unexpected keys in table: ".len()..];
        if let Some((bad, avail)) = rest.split_once(", available keys: ") {
            let avail: Vec<&str> = avail.lines().next().unwrap_or("").split(", ").collect();
            let hints: Vec<String> = bad
                .split(", ")
                .filter_map(|b| {
                    let best = avail
                        .iter()
                        .map(|c| (strsim::jaro_winkler(b, c), *c))
                        .max_by(|x, y| x.0.total_cmp(&y.0))?;
                    (best.0 > 0.7).then(|| format!("`{b}` -> did you mean `{}`?", best.1))
                })
                .collect();
            if !hints.is_empty() {
                return format!("{}\n  {}", msg.trim_end(), hints.join("\n  "));
            }
        }
    }
    msg.to_string()
}

/// The model name, moduli and density of a material (`key` names it in errors).
fn check_material(m: &MaterialSpec, key: &str) -> std::result::Result<(), String> {
    match m.model.as_str() {
        "neo-hookean" => {
            if m.alpha.is_some() && key == "material" {
                return Err(format!("{key}.alpha is the Ogden exponent; set model = 'ogden' or remove it"));
            }
        }
        "ogden" => match m.alpha {
            Some(a) if a != 0.0 => {}
            _ => {
                return Err(format!(
                    "{key}: model = 'ogden' needs `alpha`, a non-zero exponent (-4.7 for brain tissue, \
                     Miller and Chinzei 2002)"
                ))
            }
        },
        other => {
            return Err(format!(
                "{key}.model = '{other}': the available models are 'neo-hookean' and 'ogden'"
            ))
        }
    }
    if !(m.density > 0.0) {
        return Err(format!(
            "{key}.density = {}: must be positive (kg/m^3)",
            m.density
        ));
    }
    match (m.youngs_modulus, m.poisson_ratio, m.shear_modulus, m.bulk_modulus) {
        (Some(e), Some(nu), None, None) => {
            if !(e > 0.0) || !(nu > -1.0 && nu < 0.5) {
                return Err(format!("{key}: need youngs_modulus > 0 (got {e}) and -1 < poisson_ratio < 0.5 (got {nu})"));
            }
        }
        (None, None, Some(mu), Some(k)) => {
            if !(mu > 0.0 && k > 0.0) {
                return Err(format!("{key}: shear_modulus ({mu}) and bulk_modulus ({k}) must be positive (Pa)"));
            }
        }
        _ => return Err(format!("{key}: give either youngs_modulus and poisson_ratio, or shear_modulus and bulk_modulus")),
    }
    Ok(())
}

/// A curve name must be built in or a `[curves.NAME]` table.
fn check_curve(s: &Scene, key: &str, name: &str) -> std::result::Result<(), String> {
    if crate::bc::LoadCurve::builtin(name).is_some() || s.curves.contains_key(name) {
        return Ok(());
    }
    let mut known: Vec<&str> = crate::bc::LoadCurve::BUILTIN.to_vec();
    known.extend(s.curves.keys().map(String::as_str));
    Err(format!(
        "{key} = '{name}': no such curve; use one of {} or add a [curves.{name}] table",
        known.join(", ")
    ))
}

/// Physical and structural checks that serde cannot express.
fn validate(s: &Scene) -> std::result::Result<(), String> {
    match &s.geometry {
        Geometry::Box { min, max } => {
            if (0..3).any(|k| !(max[k] > min[k])) {
                return Err(format!(
                    "geometry: box max {max:?} must exceed min {min:?} in every coordinate"
                ));
            }
        }
        Geometry::Cylinder { radius, height } => {
            if !(*radius > 0.0 && *height > 0.0) {
                return Err(format!("geometry: cylinder radius ({radius}) and height ({height}) must be positive (m)"));
            }
        }
        Geometry::HalfEllipsoid { semi_axes } => {
            if !semi_axes.iter().all(|v| v.is_finite() && *v > 0.0) {
                return Err(format!("geometry: half_ellipsoid semi_axes {semi_axes:?} must be positive and finite (m)"));
            }
        }
        Geometry::Mesh {
            file,
            format,
            units,
            ..
        } => {
            if !(*units > 0.0 && units.is_finite()) {
                return Err(format!("geometry.units = {units}: must be a positive factor to metres (0.001 for a mesh in mm)"));
            }
            if format.is_none() && MeshFormat::from_path(file).is_none() {
                return Err(format!(
                    "geometry.mesh = '{}': unknown extension; use .inp, .msh, .vtk or .vtu, or set geometry.format",
                    file.display()
                ));
            }
        }
    }
    let d = &s.discretization;
    if let Some(h) = d.size {
        if !(h > 0.0) {
            return Err(format!(
                "discretization.size = {h}: must be a positive length in m"
            ));
        }
    }
    if let Some(div) = d.divisions {
        if div.contains(&0) {
            return Err(format!(
                "discretization.divisions = {div:?}: every division must be at least 1"
            ));
        }
        let [a, b, c] = div.map(|k| k as f64);
        // The cylinder's O-grid has n_inner^2 + 4 n_inner n_radial cells per layer, the box
        // nx ny nz (tets: 6 per hex, checked at the hex count as the element limit is).
        let n = match &s.geometry {
            Geometry::Cylinder { .. } => (a * a + 4.0 * a * b) * c,
            _ => a * b * c,
        };
        if n > MAX_ELEMENTS {
            return Err(format!(
                "discretization.divisions = {div:?} gives {n:.3e} cells, more than the limit of \
                 {MAX_ELEMENTS:.0e}; use fewer divisions"
            ));
        }
    }
    let extent = match &s.geometry {
        Geometry::Box { min, max } => Some([max[0] - min[0], max[1] - min[1], max[2] - min[2]]),
        Geometry::Cylinder { radius, height } => Some([2.0 * radius, 2.0 * radius, *height]),
        Geometry::HalfEllipsoid { semi_axes: a } => Some([2.0 * a[0], 2.0 * a[1], a[2]]),
        Geometry::Mesh { .. } => None,
    };
    if let (Some(e), Some(h), None) = (extent, d.size, d.divisions) {
        let n: f64 = e.iter().map(|l| (l / h).max(1.0)).product();
        if n > MAX_ELEMENTS {
            return Err(format!(
                "discretization.size = {h} m gives about {n:.3e} cells over the {:.3} x {:.3} x \
                 {:.3} m shape, more than the limit of {MAX_ELEMENTS:.0e}; lengths are in metres \
                 (is the size given in mm?)",
                e[0], e[1], e[2]
            ));
        }
    }
    if let Some(k) = d.tets_per_point_given {
        if !(1.0..=1000.0).contains(&k) {
            return Err(format!(
                "discretization.tets_per_point = {k}: must be between 1 (one rule per tet) and 1000"
            ));
        }
        if d.integration != IntegrationKind::Tets {
            return Err(format!(
                "discretization.tets_per_point = {k} merges background-tet points; it needs \
                 integration = 'tets' (this scene has {:?})",
                d.integration
            ));
        }
    }
    if ![1, 4, 5].contains(&d.tet_rule()) {
        return Err(format!(
            "discretization.tet_rule = {}: the tetrahedron rules have 1, 4 or 5 points",
            d.tet_rule()
        ));
    }
    if d.method == Method::Coupled && !(d.interface_scale >= 1.0 && d.interface_scale <= 4.0) {
        return Err(format!(
            "discretization.interface_scale = {}: use a factor in [1, 4] (default 1.5)",
            d.interface_scale
        ));
    }
    let file_cloud = d.method != Method::Fe && d.cloud == CloudKind::File;
    let mesh_geometry = matches!(s.geometry, Geometry::Mesh { .. });
    if d.size.is_none() && d.divisions.is_none() && !file_cloud && !mesh_geometry {
        return Err("discretization: give `size` (target element length, m) or `divisions`".into());
    }
    if !(d.jitter >= 0.0 && d.jitter < 0.5) {
        return Err(format!(
            "discretization.jitter = {}: must lie in [0, 0.5) (fraction of the node spacing)",
            d.jitter
        ));
    }
    if !(d.point_ratio > 0.0) {
        return Err(format!(
            "discretization.point_ratio = {}: must be positive (integration points per node)",
            d.point_ratio
        ));
    }
    if !(d.tolerance > 0.0 && d.tolerance.is_finite()) {
        return Err(format!(
            "discretization.tolerance = {}: must be a positive relative accuracy (e.g. 0.001)",
            d.tolerance
        ));
    }
    if ![2, 4, 8].contains(&d.subdivision) {
        return Err(format!(
            "discretization.subdivision = {}: use 2 (longest-edge bisection), 4 (three edge midpoints) or 8 (all six)",
            d.subdivision
        ));
    }
    let deepest = crate::meshless::adaptive::max_level_for(d.subdivision);
    if d.max_level > deepest {
        return Err(format!(
            "discretization.max_level = {}: at most {deepest} with subdivision = {} (a cell may split into at most 2^18 leaves)",
            d.max_level, d.subdivision
        ));
    }
    if !(d.mu >= 0.0) || !(d.min_rcond > 0.0 && d.min_rcond < 1.0) {
        return Err(format!(
            "discretization: mu ({}) must be >= 0 and min_rcond ({}) in (0, 1)",
            d.mu, d.min_rcond
        ));
    }
    if d.cloud == CloudKind::File && d.cloud_file.is_none() {
        return Err(
            "discretization.cloud = 'file' needs cloud_file = \"path/to/nodes.csv\"".into(),
        );
    }
    if !(d.min_spacing > 0.0) {
        return Err(format!(
            "discretization.min_spacing = {}: must be positive (fraction of size)",
            d.min_spacing
        ));
    }
    if let Some(h) = d.hourglass.filter(|h| !(*h >= 0.0)) {
        return Err(format!(
            "discretization.hourglass = {h}: must be >= 0 (default 0.51 with hourglass_modulus = 'shear', 0.01 with 'p-wave')"
        ));
    }
    check_material(&s.material, "material")?;
    for (name, r) in &s.regions {
        let key = format!("regions.{name}");
        match (&r.select, &r.elements) {
            (Some(Selection::Plane { .. }), _) | (Some(Selection::Set(_)), _) => {
                return Err(format!(
                    "{key}.select: a region is a volume; use a box, sphere or cylinder (or \
                     `elements = \"SET\"` for an element set of the mesh file)"
                ))
            }
            (Some(_), None) | (None, Some(_)) => {}
            _ => {
                return Err(format!(
                    "{key}: give either `select = {{ box | sphere | cylinder = ... }}` or `elements = \"SET\"`"
                ))
            }
        }
        check_material(&s.material.with(r), &key)?;
    }
    for (name, c) in &s.curves {
        if crate::bc::LoadCurve::builtin(name).is_some() {
            return Err(format!(
                "curves.{name}: '{name}' is a built-in curve; give the table another name"
            ));
        }
        if c.points.is_some() == c.file.is_some() {
            return Err(format!(
                "curves.{name}: give either `points = [[t, factor], ...]` (t in s) or `file = \"curve.csv\"`"
            ));
        }
    }
    for (name, b) in &s.boundaries {
        check_curve(s, &format!("boundaries.{name}.curve"), &b.curve)?;
    }
    for (name, m) in &s.measured {
        let key = format!("measured.{name}");
        check_curve(s, &format!("{key}.curve"), &m.curve)?;
        if s.boundaries.contains_key(name) || s.contact.contains_key(name) {
            return Err(format!(
                "{key}: a boundary or rigid body has the same name; reactions are reported by name, so give it another"
            ));
        }
        if let Some(t) = m.tolerance.filter(|t| !(*t > 0.0)) {
            return Err(format!(
                "{key}.tolerance = {t}: must be a positive distance (m)"
            ));
        }
    }
    for (name, c) in &s.contact {
        let key = format!("contact.{name}");
        check_curve(s, &format!("{key}.curve"), &c.curve)?;
        if s.boundaries.contains_key(name) {
            return Err(format!(
                "{key}: a boundary has the same name; reactions are reported by name, so give the rigid body another"
            ));
        }
        let positive = |v: Option<f64>| v.is_some_and(|r| r > 0.0);
        let nonzero = |v: Option<[f64; 3]>| v.is_some_and(|a| a.iter().any(|&x| x != 0.0));
        let (need, ok, allowed): (&str, bool, &[&str]) = match c.shape.as_str() {
            "plane" => (
                "`point = [x, y, z]` and a non-zero `normal` (pointing to the body)",
                c.point.is_some() && nonzero(c.normal),
                &["point", "normal"],
            ),
            "sphere" => (
                "`center` and `radius` > 0 (m)",
                c.center.is_some() && positive(c.radius),
                &["center", "radius"],
            ),
            "cylinder" => (
                "`center`, a non-zero `axis` and `radius` > 0 (m); `min` < `max` along the axis when given",
                c.center.is_some()
                    && nonzero(c.axis)
                    && positive(c.radius)
                    && !matches!((c.min, c.max), (Some(a), Some(b)) if !(a < b)),
                &["center", "axis", "radius", "min", "max"],
            ),
            other => {
                return Err(format!(
                    "{key}.shape = '{other}': use \"plane\", \"sphere\" or \"cylinder\""
                ))
            }
        };
        if !ok {
            return Err(format!("{key}: a {} needs {need}", c.shape));
        }
        let given = [
            ("point", c.point.is_some()),
            ("normal", c.normal.is_some()),
            ("center", c.center.is_some()),
            ("radius", c.radius.is_some()),
            ("axis", c.axis.is_some()),
            ("min", c.min.is_some()),
            ("max", c.max.is_some()),
        ];
        if let Some((k, _)) = given.iter().find(|(k, g)| *g && !allowed.contains(k)) {
            return Err(format!("{key}.{k} does not apply to a {}", c.shape));
        }
    }
    for (name, l) in &s.loads {
        check_curve(s, &format!("loads.{name}.curve"), &l.curve)?;
        let given = [
            l.gravity.is_some(),
            l.force.is_some(),
            l.traction.is_some(),
            l.pressure.is_some(),
        ];
        if given.iter().filter(|&&g| g).count() != 1 {
            return Err(format!(
                "loads.{name}: give exactly one of `gravity = [gx, gy, gz]` (m/s^2), `force = [fx, fy, fz]` \
                 (N per node), `traction = [tx, ty, tz]` (Pa) or `pressure = p` (Pa)"
            ));
        }
        match (l.gravity.is_some(), l.select.is_some()) {
            (true, true) => {
                return Err(format!(
                    "loads.{name}: gravity acts on the whole body; remove `select`"
                ))
            }
            (false, false) => {
                return Err(format!(
                "loads.{name}: needs `select = {{ ... }}` (the nodes or boundary faces it acts on)"
            ))
            }
            _ => {}
        }
    }
    for (name, b) in &s.boundaries {
        if b.fix.is_empty()
            && b.displacement
                .as_ref()
                .is_none_or(|d| d.x.is_none() && d.y.is_none() && d.z.is_none())
        {
            return Err(format!("boundaries.{name}: neither `fix` nor `displacement` is given, so it constrains nothing"));
        }
    }
    let sv = &s.solver;
    if !(sv.dt_factor > 0.0) {
        return Err(format!(
            "solver.dt_factor = {}: must be positive (default 0.9)",
            sv.dt_factor
        ));
    }
    if !(sv.duration > 0.0) {
        return Err(format!(
            "solver.duration = {}: must be positive (s)",
            sv.duration
        ));
    }
    if !(sv.tolerance > 0.0) {
        return Err(format!(
            "solver.tolerance = {}: must be positive (m)",
            sv.tolerance
        ));
    }
    if let Some(k) = sv.retries.filter(|&k| k > 10) {
        return Err(format!(
            "solver.retries = {k}: at most 10 (each restart shortens the step by 0.75x; default 2)"
        ));
    }
    if !(sv.damping >= 0.0) {
        return Err(format!(
            "solver.damping = {}: must be >= 0 (1/s)",
            sv.damping
        ));
    }
    for (name, p) in &s.probes {
        if p.position.is_some() == p.select.is_some() {
            return Err(format!(
                "probes.{name}: give either `position = [x, y, z]` (m) or `select = {{ ... }}`"
            ));
        }
    }
    if s.initial.is_some() && s.solver.mode != Mode::Dynamic {
        return Err(
            "[initial] motion needs solver.mode = \"dynamic\" (relaxation seeks a steady state)"
                .into(),
        );
    }
    for (name, r) in &s.references {
        if r.value.is_some() == r.exact.is_some() {
            return Err(format!(
                "references.{name}: give either `value` (N or m) or `exact = \"uniaxial\"`"
            ));
        }
        if r.value.is_some_and(|v| v == 0.0) {
            return Err(format!(
                "references.{name}.value = 0: a relative error against 0 is undefined; compare a \
                 non-zero quantity"
            ));
        }
        let parts: Vec<&str> = r.quantity.split('.').collect();
        let ok = parts.len() == 3
            && matches!(parts[2], "x" | "y" | "z")
            && match parts[0] {
                "reaction" => {
                    s.boundaries.contains_key(parts[1])
                        || s.contact.contains_key(parts[1])
                        || s.measured.contains_key(parts[1])
                }
                "probe" => s.probes.contains_key(parts[1]),
                _ => false,
            };
        if !ok {
            return Err(format!(
                "references.{name}.quantity = '{}': expected reaction.BOUNDARY.x|y|z or probe.NAME.x|y|z naming a boundary ({}) or probe ({})",
                r.quantity,
                s.boundaries.keys().cloned().collect::<Vec<_>>().join(", "),
                s.probes.keys().cloned().collect::<Vec<_>>().join(", ")
            ));
        }
    }
    Ok(())
}
