//! `[discretization]`: the method, elements, meshless nodes, points and supports, and the
//! coupled layer.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::specs::default_true;

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
    /// components) and the surface a `[contact]` rigid body can reach; the other free surfaces
    /// are meshless (coupled paper sect. 3.2).
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
    /// Quadratic 10-node tetrahedron with one volume change per element (P2/P0), built from
    /// the tet mesh by adding edge nodes (`fe::tet10`).
    #[serde(rename = "tet10")]
    Tet10,
}

impl From<ElementName> for crate::fe::ElementKind {
    fn from(e: ElementName) -> Self {
        match e {
            ElementName::Hex8 => crate::fe::ElementKind::Hex8,
            ElementName::Tet4 => crate::fe::ElementKind::Tet4,
            ElementName::Tet4Anp => crate::fe::ElementKind::Tet4Anp,
            ElementName::Tet10 => crate::fe::ElementKind::Tet10,
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

/// One entry of `discretization.refine`: the TetGen mesh of a built-in shape graded near the
/// outline of a boundary's selection or a rigid tool, edge `size` (m) there growing by the
/// factor `growth` per element away from it (edge size + (growth - 1) x distance, up to
/// `discretization.size`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Refine {
    /// A `[boundaries.NAME]` or `[contact.NAME]` whose outline is a mesh feature.
    pub near: String,
    /// Edge length at the outline, m.
    pub size: f64,
    /// Ratio of neighbouring element sizes away from the outline (default 1.25).
    #[serde(default = "default_growth")]
    pub growth: f64,
}

fn default_growth() -> f64 {
    1.25
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
    /// TetGen meshes graded near what acts on the body: `[{ near = "indenter", size = 0.0005,
    /// growth = 1.25 }]`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub refine: Vec<Refine>,
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
    /// Coupled tet interiors: face-connected interior tets per mean-dilatation patch (the
    /// points of a patch share their weighted mean J, as a cell's points do under
    /// `mean_dilatation`; 1 = every point its own J). Read it through
    /// [`Discretization::mean_dilatation_patch`].
    #[serde(
        default,
        rename = "mean_dilatation_patch",
        skip_serializing_if = "Option::is_none"
    )]
    pub mean_dilatation_patch_given: Option<usize>,
}

/// Interior tets per mean-dilatation patch by default (studies/README.md, "mean-dilatation
/// patches"): 8 put the coupled defaults within 1.5 % of the indentation benchmark's band at
/// 4,507 nodes and the tet cylinders within docs/reference.md's tolerances.
pub const DEFAULT_MEAN_DILATATION_PATCH: usize = 8;

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
    /// Merging (face-connected clusters, [`crate::meshless::integration::cluster_tets`])
    /// softens: coupled defaults on the 1,982-17,917-node Gmsh cylinders, worst error over
    /// reaction and probe 0.17-0.81 % with 1, 0.50-2.59 % with 2, 1.39-4.02 % with 3
    /// (2026-11-28, with the mean-dilatation patches); with 5 relaxation found spurious modes.
    pub fn tets_per_point(&self) -> f64 {
        self.tets_per_point_given.unwrap_or(1.0)
    }

    /// Interior tets per mean-dilatation patch of a coupled tet interior: as given, else
    /// [`DEFAULT_MEAN_DILATATION_PATCH`]. Each MLS point with its own J makes the linear MLS
    /// interior lock at nu = 0.49 (one volumetric constraint per point, 4-6 per node): on the
    /// brain-indentation benchmark the coupled tet10 interior was 6.5 % stiff on level c3
    /// where fe tet10 is within 0.2 %, and within 0.9 % of fe tet10 at nu = 0.3.
    pub fn mean_dilatation_patch(&self) -> usize {
        self.mean_dilatation_patch_given
            .unwrap_or(DEFAULT_MEAN_DILATATION_PATCH)
    }

    /// Background tets per mean-dilatation patch of a pure meshless scene: as given, else 1
    /// (each point its own J). Given, the points of about that many face-connected background
    /// tets share their mean J. On the Gmsh tet cylinders (4,208 nodes, four points per tet) 8
    /// takes MLS from 3.08 / 2.50 % to 0.41 / 0.78 % in compression and the indentation
    /// benchmark from 8.12 % to 1.63 % (c4); but MLS integrated by tet rules is not
    /// integration-consistent and the softer volumetric response lets that error grow: the
    /// coarse TetGen cube read from an STL (513 nodes) misses the exact corner stretch by
    /// 3.7 % with 8 where each point its own J is within 0.5 %, and on the structured
    /// hexahedral cylinder the reactions move away from ABAQUS (compression 0.88 -> 2.77 %).
    /// So it is not a default.
    pub fn meshless_mean_dilatation_patch(&self) -> usize {
        self.mean_dilatation_patch_given.unwrap_or(1)
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
            refine: Vec::new(),
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
            mean_dilatation_patch_given: None,
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
