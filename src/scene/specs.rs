//! The other tables of a scene: materials and regions, boundaries, loads, measured
//! displacements, contact, curves, solver, probes, references, initial motion and output.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::geometry::select::Selection;
use crate::solver::Mode;

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
/// the mesh file) take `[material]` with the keys given here in place of its own.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub select: Option<Selection>,
    /// An element set of the mesh file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elements: Option<String>,
    /// Labels of the geometry's image (`geometry.image`): the points whose nearest voxel has
    /// one of them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labels: Option<Vec<i64>>,
    /// A closed surface file (STL, OBJ, VTK poly data; relative to the scene file) nested in
    /// the body: the points inside it. A body TetGen fills from a surface or an image is
    /// meshed with this surface as an internal boundary (its elements conform).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surface: Option<PathBuf>,
    /// The region surface file's length unit in m (1; 0.001 for mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units: Option<f64>,
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
    /// Interpolate scattered measurements onto the surface nodes within `tolerance` of them
    /// (default: the measurements' own spacing) instead of matching one point per node.
    #[serde(default)]
    pub interpolate: bool,
}

/// `[contact.NAME]`: a rigid body moved by `motion` along `curve`, which the body's surface
/// points touch without friction (the body stays outside it): `shape = "plane"` with `point`
/// and `normal` (pointing to the body), `"sphere"` with `center` and `radius`, or
/// `"cylinder"` with `center`, `axis`, `radius` and optional `min` / `max` (the extent along
/// the axis from `center`, flat ends) and `edge_radius` (the ends' rims rounded). `select`
/// limits the surface points that may touch it.
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
    /// `shape = "cylinder"`: the radius its flat ends' rims are rounded to, m (default 0: a
    /// sharp rim); less than `radius`, and than half of `max - min` when both are given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub edge_radius: Option<f64>,
    /// `shape = "surface"`: a closed surface file (STL, OBJ, VTK poly data; relative to the
    /// scene file), the rigid solid it encloses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<std::path::PathBuf>,
    /// The surface file's length unit in m (1; 0.001 for mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units: Option<f64>,
    /// `file` a labelled image: the labels whose surface is the rigid surface (every nonzero
    /// label when not given), extracted as `geometry.image`'s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labels: Option<Vec<i64>>,
    /// Moves the surface along its normals by this much, m (positive outward: a gap).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset: Option<f64>,
    /// The tissue lies inside the closed surface (the skull around the brain); false: the
    /// rigid solid is inside it (a tool).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inside: Option<bool>,
    /// The rigid body's displacement at the end of its curve, m.
    #[serde(default)]
    pub motion: [f64; 3],
    #[serde(default = "default_curve")]
    pub curve: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub select: Option<Selection>,
}

impl ContactSpec {
    /// The rigid surface these keys describe (validated: every key its shape needs is there),
    /// for the analytic shapes; a `"surface"` tool is read by the pipeline (it has the scene's
    /// folder), and here is a placeholder plane that nothing touches.
    pub fn rigid_shape(&self) -> crate::bc::contact::RigidShape {
        use crate::bc::contact::RigidShape;
        let v = |a: Option<[f64; 3]>| nalgebra::Vector3::from(a.unwrap_or_default());
        // A direction of any length: scaled by its largest component first, so that a squared
        // length that overflows (1e200) or underflows (1e-300) does not make it NaN or zero,
        // which switched the tool off without a word (issue 41).
        let unit = |a: Option<[f64; 3]>| {
            let d = v(a);
            let m = d.amax();
            if m > 0.0 {
                (d / m).normalize()
            } else {
                d
            }
        };
        match self.shape.as_str() {
            "plane" => RigidShape::Plane {
                point: v(self.point),
                normal: unit(self.normal),
            },
            "sphere" => RigidShape::Sphere {
                center: v(self.center),
                radius: self.radius.unwrap_or(0.0),
            },
            _ => RigidShape::Cylinder {
                center: v(self.center),
                axis: unit(self.axis),
                radius: self.radius.unwrap_or(0.0),
                min: self.min,
                max: self.max,
                edge_radius: self.edge_radius.unwrap_or(0.0),
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
    /// step when deformation has raised the frequencies (default true): dynamic runs and
    /// mass-scaled relaxation from the start, relaxation with physical masses after a restart.
    #[serde(default = "default_true")]
    pub step_update: bool,
    /// Relaxation: replace the masses by fictitious ones proportional to each node's stiffness
    /// (mass scaling; the steady state does not depend on the masses, gravity keeps the
    /// physical ones). Graded meshes and quadratic elements then converge in several times
    /// fewer steps. Default: on in relaxation, except for models of tet4-anp elements only
    /// (their elements' own J collapsed at a driven rim under it). Not allowed in dynamic runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_scaling: Option<bool>,
    /// Where the time loop runs: `"cpu"` (default) or `"gpu"` (NVIDIA GPU 0, the same answers
    /// bitwise; see README "GPU"). `--device` overrides it.
    #[serde(default)]
    pub device: crate::solver::Device,
    /// Static: how each Newton iteration solves its linear system: `"newton-krylov"`
    /// (default: the current tangent by conjugate gradients preconditioned by a kept
    /// factorization), `"newton"` (a factorization per iteration) or `"modified"` (the kept
    /// factorization alone). See docs/methods.md.
    #[serde(default)]
    pub static_variant: crate::solver::StaticVariant,
    /// Static, with rigid contact that no rigid body moves and no load stages: relax to 100 x
    /// `tolerance` first and solve statically from there (default true; false: Newton's load
    /// steps from the unloaded state). See docs/methods.md "Static solve".
    #[serde(default = "default_true")]
    pub relaxed_start: bool,
    /// Static, where the load steps stop short of the full load after the last stage (a
    /// bifurcation, an element squeezed flat): relax from the unloaded state instead, the
    /// static stages kept, unless that relaxation inverts a point and restarts (default true;
    /// false: the run stops there, exit 4). See
    /// docs/methods.md "Static solve".
    #[serde(default = "default_true")]
    pub relaxation_fallback: bool,
}

pub(super) fn default_true() -> bool {
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
            mass_scaling: None,
            device: Default::default(),
            static_variant: Default::default(),
            relaxed_start: true,
            relaxation_fallback: true,
        }
    }
}

/// `[probes.NAME]`: a material point whose displacement is reported, or (`select`) the mean
/// displacement of a selection of nodes (e.g. `select = { set = "tip" }`). Exactly one of the
/// two keys is given; the file is refused otherwise, where it is read.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "ProbeKeys", into = "ProbeKeys")]
pub enum ProbeSpec {
    /// `position = [x, y, z]`: the material point at this reference position, m.
    Position([f64; 3]),
    /// `select = { ... }`: the mean of the selected nodes' displacements.
    Select(Selection),
}

impl ProbeSpec {
    /// The reference position of a point probe, m.
    pub fn position(&self) -> Option<[f64; 3]> {
        match self {
            ProbeSpec::Position(x) => Some(*x),
            ProbeSpec::Select(_) => None,
        }
    }

    /// The selection of a mean probe.
    pub fn select(&self) -> Option<&Selection> {
        match self {
            ProbeSpec::Select(s) => Some(s),
            ProbeSpec::Position(_) => None,
        }
    }
}

/// `[probes.NAME]` as written: its keys, of which exactly one is given.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ProbeKeys {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    position: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    select: Option<Selection>,
}

impl TryFrom<ProbeKeys> for ProbeSpec {
    type Error = String;
    fn try_from(k: ProbeKeys) -> std::result::Result<Self, String> {
        match (k.position, k.select) {
            (Some(x), None) => Ok(ProbeSpec::Position(x)),
            (None, Some(s)) => Ok(ProbeSpec::Select(s)),
            _ => Err(
                "a probe takes either `position = [x, y, z]` (m) or `select = { ... }`, \
                      exactly one of them"
                    .into(),
            ),
        }
    }
}

impl From<ProbeSpec> for ProbeKeys {
    fn from(p: ProbeSpec) -> Self {
        match p {
            ProbeSpec::Position(x) => ProbeKeys {
                position: Some(x),
                select: None,
            },
            ProbeSpec::Select(s) => ProbeKeys {
                position: None,
                select: Some(s),
            },
        }
    }
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
    /// axis with free lateral faces (docs/reference.md "Cube"), computed from the scene's material,
    /// box and prescribed displacement, so it follows `--set material.poisson_ratio=...`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exact: Option<String>,
    #[serde(default)]
    pub source: Option<String>,
    /// Relaxation: the load fraction (0 < at <= 1; default 1, the end) at which the quantity is
    /// compared. The load stops rising there until the relaxation has converged (a load
    /// stage), so one run gives a force-displacement curve at equilibrium.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at: Option<f64>,
    /// The interval [low, high] (N or m) in which the reference value may still lie (a
    /// reference not fully converged): the summary adds the relative distance to it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub band: Option<[f64; 2]>,
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
    /// VTU frames of a dynamic run, equally spaced in time (10 unless given). Relaxation writes
    /// the unloaded state, each load stage and the converged state whatever this says (its
    /// path in pseudo-time is not a physical history); a relaxation scene that sets it is
    /// told so.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<usize>,
    /// Rows in the time-history CSV (dynamic).
    #[serde(default = "default_history")]
    pub history_rows: usize,
    /// An image (NIfTI-1 or NRRD; relative to the scene file) to warp: on its grid the run
    /// writes the displacement field that ITK and 3D Slicer load as a displacement-field
    /// transform (`NAME_displacement`) and the image warped into the deformed configuration
    /// (`NAME_warped`), in its format.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<std::path::PathBuf>,
}

/// Frames of a dynamic run without `output.frames`.
pub const DEFAULT_FRAMES: usize = 10;
fn default_history() -> usize {
    200
}

impl Default for OutputSpec {
    fn default() -> Self {
        OutputSpec {
            frames: None,
            history_rows: default_history(),
            image: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bc::contact::RigidShape;

    /// Directions read as written whatever their length: a normal of 1e200 or 1e-300 is the
    /// unit normal, not NaN or zero (which disabled the tool).
    #[test]
    fn contact_directions_of_any_length_are_unit_directions() {
        for scale in [1.0, 1e200, 1e-300, 5e-324] {
            let plane: ContactSpec = toml::from_str(&format!(
                "shape = \"plane\"\npoint = [0.0, 0.0, 0.0]\nnormal = [0.0, {scale:e}, {scale:e}]\n"
            ))
            .unwrap();
            let cyl: ContactSpec = toml::from_str(&format!(
                "shape = \"cylinder\"\ncenter = [0.0, 0.0, 0.0]\naxis = [0.0, 0.0, {scale:e}]\nradius = 0.01\n"
            ))
            .unwrap();
            let h = 0.5f64.sqrt();
            match (plane.rigid_shape(), cyl.rigid_shape()) {
                (RigidShape::Plane { normal, .. }, RigidShape::Cylinder { axis, .. }) => {
                    assert!(
                        (normal - nalgebra::Vector3::new(0.0, h, h)).norm() < 1e-15,
                        "{scale}: {normal:?}"
                    );
                    assert_eq!(axis, nalgebra::Vector3::new(0.0, 0.0, 1.0), "{scale}");
                }
                other => panic!("{other:?}"),
            }
        }
    }
}
