//! Run summaries: the JSON object of `hytled run --json` and the readable table.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::solver::integrate::RelaxationRecord;

/// What a warning is about. Callers (the Python package, re-solves, sweeps) tell warnings
/// apart by their kind, never by their text; summary.json lists the kinds beside the messages
/// (`warning_kinds`, in the same order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WarningKind {
    /// The input: a mesh file's content and quality, its units, the model's volume against
    /// the geometry's.
    Input,
    /// The discretization: volumetric locking, nodes removed or reached by few points,
    /// combinations not verified.
    Discretization,
    /// Boundary conditions: parts no boundary holds, initial motion against held nodes,
    /// drives under-integrated, conditions imposed by EBCIEM or SEBCIEM.
    Boundary,
    /// Rigid contact: a tool that starts inside the body, points left inside a tool.
    Contact,
    /// `output.frames` in a steady-state run, which writes its load stages instead.
    SteadyFrames,
    /// The solve: restarts, cut load steps, out-of-balance forces, the energy balance.
    Solve,
    /// A re-solve of a prepared model: a tool moved far, a warm start that failed.
    Resolve,
}

impl WarningKind {
    /// The kind's name in summary.json and Python (`"input"`, `"steady_frames"`, ...).
    pub fn name(self) -> &'static str {
        match self {
            WarningKind::Input => "input",
            WarningKind::Discretization => "discretization",
            WarningKind::Boundary => "boundary",
            WarningKind::Contact => "contact",
            WarningKind::SteadyFrames => "steady_frames",
            WarningKind::Solve => "solve",
            WarningKind::Resolve => "resolve",
        }
    }
}

/// Something the user should know that does not stop the run: its kind and its message.
/// It reads as its message (`Display`, and as a `str`).
#[derive(Debug, Clone, PartialEq)]
pub struct Warning {
    pub kind: WarningKind,
    pub message: String,
}

impl Warning {
    pub fn new(kind: WarningKind, message: impl Into<String>) -> Self {
        Warning {
            kind,
            message: message.into(),
        }
    }

    /// Messages of one kind, as warnings.
    pub fn all(kind: WarningKind, messages: impl IntoIterator<Item = String>) -> Vec<Warning> {
        messages
            .into_iter()
            .map(|m| Warning::new(kind, m))
            .collect()
    }
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::ops::Deref for Warning {
    type Target = str;
    fn deref(&self) -> &str {
        &self.message
    }
}

impl std::borrow::Borrow<str> for Warning {
    fn borrow(&self) -> &str {
        &self.message
    }
}

/// summary.json's `warnings` (the messages) and `warning_kinds` (their kinds, in order);
/// nothing without warnings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Warnings(pub Vec<Warning>);

impl Serialize for Warnings {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = s.serialize_map(None)?;
        if !self.0.is_empty() {
            let messages: Vec<&str> = self.0.iter().map(|w| w.message.as_str()).collect();
            let kinds: Vec<&str> = self.0.iter().map(|w| w.kind.name()).collect();
            m.serialize_entry("warnings", &messages)?;
            m.serialize_entry("warning_kinds", &kinds)?;
        }
        m.end()
    }
}

impl<'de> Deserialize<'de> for Warnings {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        struct Parts {
            #[serde(default)]
            warnings: Vec<String>,
            #[serde(default)]
            warning_kinds: Vec<WarningKind>,
        }
        let p = Parts::deserialize(d)?;
        if p.warnings.len() != p.warning_kinds.len() {
            return Err(serde::de::Error::custom(format!(
                "{} warnings but {} warning_kinds",
                p.warnings.len(),
                p.warning_kinds.len()
            )));
        }
        Ok(Warnings(
            p.warnings
                .into_iter()
                .zip(p.warning_kinds)
                .map(|(m, k)| Warning::new(k, m))
                .collect(),
        ))
    }
}

impl std::ops::Deref for Warnings {
    type Target = Vec<Warning>;
    fn deref(&self) -> &Vec<Warning> {
        &self.0
    }
}

impl<'a> IntoIterator for &'a Warnings {
    type Item = &'a Warning;
    type IntoIter = std::slice::Iter<'a, Warning>;
    fn into_iter(self) -> Self::IntoIter {
        self.0.iter()
    }
}

impl std::ops::DerefMut for Warnings {
    fn deref_mut(&mut self) -> &mut Vec<Warning> {
        &mut self.0
    }
}

/// Wall-clock times, s.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WallSeconds {
    pub preprocess: f64,
    pub solve: f64,
    pub total: f64,
}

/// A probe's result, m.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ProbeResult {
    pub position: [f64; 3],
    pub displacement: [f64; 3],
}

/// Energies at the end of the run, J.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Energy {
    pub external_work: f64,
    pub strain_energy: f64,
    pub kinetic: f64,
    /// Largest |W_ext| during the run, J.
    pub peak_external_work: f64,
    /// Work done against the mass-proportional damping (`solver.damping`) in a dynamic run, J;
    /// absent without damping.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping_dissipation: Option<f64>,
    /// |W_ext + K_0 - (U + K + D)| / max(|W_ext + K_0|, peak |W_ext| + K_0), with K_0 the
    /// initial kinetic energy and D the damping's dissipation: the peak scales it when a load
    /// comes back to zero; null for relaxation, whose damped path is fictitious.
    pub balance_error: Option<f64>,
}

/// A computed value against a reference.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Comparison {
    pub quantity: String,
    pub value: f64,
    pub computed: f64,
    pub relative_error: f64,
    /// The load fraction compared at (a relaxation load stage; absent: the end).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at: Option<f64>,
    /// Relative distance from the computed value to the reference's band (0 inside it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub band_error: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
}

/// Reactions and probes at one relaxation load stage (`references.NAME.at`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StageResult {
    /// Load fraction held.
    pub load: f64,
    /// Step at which the relaxation converged there.
    pub step: usize,
    pub reactions: BTreeMap<String, [f64; 3]>,
    pub probes: BTreeMap<String, [f64; 3]>,
}

/// Mesh facts that bear on accuracy and the stable step.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MeshInfo {
    pub elements: usize,
    /// Smallest dihedral angle of a tet mesh, degrees, and the element that has it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_dihedral_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_dihedral_element: Option<usize>,
    /// What sets the critical step: the per-point bound at a point or the nodal bound at a node.
    pub critical: crate::solver::integrate::Critical,
    /// Sum of the integration weights, m^3.
    pub volume: f64,
    /// The volume the geometry gives, m^3: a labelled image's chosen voxels, or what a surface
    /// file encloses (a difference over 2 % from `volume` is warned of).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry_volume: Option<f64>,
    /// What gives `geometry_volume`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry_volume_of: Option<String>,
}

/// Support sizes of the meshless integration points: nodes per point.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SupportNodes {
    pub mean: f64,
    pub min: usize,
    pub max: usize,
}

/// A rigid contact body at the end of a run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ContactInfo {
    /// Surface points it pressed at the last step.
    pub points_in_contact: usize,
    /// Deepest penetration any step left after its corrections, m (of every rigid body).
    pub max_penetration: f64,
    /// Penetration the corrections aim to leave at most, m.
    pub tolerance: f64,
}

/// How the meshless discretization was made.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MeshlessInfo {
    pub cloud: String,
    pub integration: String,
    pub basis: String,
    pub support_rule: String,
    /// Exact volume of the scene's shape, m^3 (compare with `mesh.volume`, the sum of weights);
    /// null for a mesh file, which has no shape to compare with.
    pub exact_volume: Option<f64>,
    /// What adaptive integration did (`integration = "adaptive"` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive: Option<AdaptiveInfo>,
}

/// What adaptive integration (thesis chapter 5) did to the background tets' points.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct AdaptiveInfo {
    /// Relative tolerance on the less-smooth integrand per cell.
    pub tolerance: f64,
    /// Children per split (2, 4 or 8).
    pub subdivision: usize,
    pub max_level: usize,
    /// Points of the base rule alone (cells x rule points) and after refinement.
    pub points_before: usize,
    pub points_after: usize,
    /// Deepest level reached.
    pub deepest_level: usize,
    /// Leaf cells per level 0..=max_level.
    pub leaves_per_level: Vec<usize>,
}

impl AdaptiveInfo {
    /// One line for text reports.
    pub fn line(&self) -> String {
        format!(
            "adaptive, tolerance {}, {} children per split, max level {}: {} -> {} points, deepest level {}, leaf cells per level {:?}",
            self.tolerance,
            self.subdivision,
            self.max_level,
            self.points_before,
            self.points_after,
            self.deepest_level,
            self.leaves_per_level
        )
    }
}

/// How the coupled FE + meshless discretization was made.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CoupledInfo {
    pub fe_layers: usize,
    /// Cells: pure FE (TLED kernels), transition (blended), meshless interior.
    pub fe_cells: usize,
    pub transition_cells: usize,
    pub meshless_cells: usize,
    /// Nodes: FE only (interpolating), interface (FE and MLS), meshless only.
    pub fe_nodes: usize,
    pub interface_nodes: usize,
    pub meshless_nodes: usize,
    /// Quadrature points per family.
    pub fe_points: usize,
    pub transition_points: usize,
    pub meshless_points: usize,
    /// Transition cells on the full rule near a load concentrated on a few driven nodes,
    /// where `transition_rule = "interior"` would give them one point.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub full_rule_cells: usize,
    pub basis: String,
    pub support_rule: String,
    /// What adaptive integration of the interior tets did (`integration = "adaptive"` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive: Option<AdaptiveInfo>,
}

/// The reaction component tables show for `boundary`: the one a reference of the run names
/// (`reaction.BOUNDARY.x|y|z`), else z. Returns (index, "x" | "y" | "z").
pub fn reaction_component(summary: Option<&Summary>, boundary: &str) -> (usize, &'static str) {
    summary
        .and_then(|s| {
            s.reference.values().find_map(|c| {
                let p: Vec<&str> = c.quantity.split('.').collect();
                (p.len() == 3 && p[0] == "reaction" && p[1] == boundary).then(|| match p[2] {
                    "x" => (0, "x"),
                    "y" => (1, "y"),
                    _ => (2, "z"),
                })
            })
        })
        .unwrap_or((2, "z"))
}

/// Per boundary name: the reaction component tables show ([`reaction_component`] of `first`,
/// the first successful run) and its column header, "reaction NAME x|y|z (N)".
pub fn reaction_columns(first: Option<&Summary>, boundaries: &[String]) -> Vec<(usize, String)> {
    boundaries
        .iter()
        .map(|r| {
            let (k, a) = reaction_component(first, r);
            (k, format!("reaction {r} {a} (N)"))
        })
        .collect()
}

/// Everything a run reports. Units: SI (m, kg, s, N, Pa, J).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Summary {
    pub scene: String,
    pub units: String,
    pub method: String,
    pub element: String,
    pub mode: String,
    pub nodes: usize,
    pub integration_points: usize,
    pub dt: f64,
    pub dt_critical: f64,
    pub dt_factor: f64,
    pub steps: usize,
    /// Every evaluation of the internal forces the run made: steps, Lanczos iterations, and in
    /// a static solve its force evaluations, tangent assemblies and products with the tangent
    /// (one each): the cost measure that compares the modes.
    pub force_evaluations: usize,
    /// Static solve: load steps, Newton and linear iterations, factorizations, factor memory
    /// and the residual history (None in the other modes).
    #[serde(rename = "static", default, skip_serializing_if = "Option::is_none")]
    pub statics: Option<crate::solver::statics::StaticReport>,
    /// Relaxation: steps of the attempts abandoned after an instability (`solver.retries`;
    /// their time is in `wall_seconds.solve`).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub failed_steps: usize,
    /// Relaxation: restarts after an instability (`solver.retries`).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub restarts: usize,
    /// Estimates of the critical step at the deformed state (`solver.step_update`; relaxation
    /// only after a restart); `dt` above is the step the run started with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub step_updates: Option<crate::solver::integrate::StepUpdates>,
    /// Relaxation: pseudo-steps over which the load was applied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_steps: Option<usize>,
    /// Dynamic runs: linear and angular momentum at the start and the end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub momentum: Option<crate::solver::integrate::Momentum>,
    pub simulated_time: f64,
    /// `"completed"` (dynamic run to its end), `"converged"` (relaxation) or `"not converged"`
    /// (relaxation stopped by `solver.max_steps`; `hytled run` exits with code 4).
    pub status: String,
    pub converged: bool,
    /// Relaxation: the largest out-of-balance force |F_int - F_ext| at a free DOF at the end,
    /// relative to the largest nodal force component |F_int| at the end or at any recorded row (nodes a corrector or contact
    /// moves are left out: their constraint forces are not residuals). Converged runs of the
    /// committed cases end at 2e-8 to 1.2e-5 (brain-shift, the largest); the cube stopped
    /// after 100 / 400 of its 747 steps, at 0.12 / 1.6e-3. Absent for dynamic runs, whose
    /// residual is the inertia.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub equilibrium_residual: Option<f64>,
    pub threads: usize,
    /// Where the time loop ran: "cpu", or the GPU's name.
    pub device: String,
    pub wall_seconds: WallSeconds,
    pub reactions: BTreeMap<String, [f64; 3]>,
    /// Rigid contact bodies: points in contact at the end and the deepest penetration any
    /// step left (their forces are among `reactions`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub contact: BTreeMap<String, ContactInfo>,
    /// Total force of each load at the end of the run, N (`[loads.NAME]`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub loads: BTreeMap<String, [f64; 3]>,
    pub probes: BTreeMap<String, ProbeResult>,
    /// Relaxation load stages (the `at` of the references) before the full load.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub stages: Vec<StageResult>,
    pub energy: Energy,
    pub reference: BTreeMap<String, Comparison>,
    pub mesh: MeshInfo,
    /// Meshless runs: nodes per support (mean/min/max).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub support_nodes: Option<SupportNodes>,
    /// Meshless runs: nodes removed because fewer than two integration points reach them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub removed_nodes: Option<usize>,
    /// Meshless runs: ebciem, sebciem or correction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bc_method: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meshless: Option<MeshlessInfo>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coupled: Option<CoupledInfo>,
    #[serde(flatten)]
    pub warnings: Warnings,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub relaxation: Vec<RelaxationRecord>,
}

/// A dynamic run whose energy balance (`Energy::balance_error`, scaled by the work put in) is
/// off by more than this fraction at the end gets a warning: every term the integrator moves
/// energy through is counted (external and correction work, strain, kinetic, damping), so a
/// larger gap is an instability that grew without tripping the divergence checks. Measured:
/// completed runs of the studies stay below 0.1 % (80 % compression and back: 0.08 % at
/// most), while fe hex8 at dt_factor 1.1 on the \[4,2,8\] cylinder (20 %, dynamic; the step
/// past the critical one once the compression raises the frequencies) ends 47 % off with a
/// reaction 25 % too large.
pub const ENERGY_WARNING: f64 = 0.01;

/// A relaxation that ends with an [`Summary::equilibrium_residual`] above this gets a warning,
/// converged or not: its displacements are not those of equilibrium to the digits shown.
pub const RESIDUAL_WARNING: f64 = 1e-3;

/// A relaxation that meets its displacement criterion with an
/// [`Summary::equilibrium_residual`] above this is "not converged" (exit code 4).
pub const RESIDUAL_NOT_CONVERGED: f64 = 1e-2;

/// The status cell of a sweep or comparison row: the error of a failed run, "not converged",
/// or "ok" (with the restarts after an instability, or how far step updates shortened the
/// step, if any, and the energy balance or the equilibrium residual where they are off by more
/// than [`ENERGY_WARNING`] / [`RESIDUAL_WARNING`]).
pub fn row_status(error: Option<&String>, summary: Option<&Summary>) -> String {
    match (error, summary) {
        (Some(e), _) => format!("failed: {e}"),
        (None, Some(s)) if !s.converged => "not converged".into(),
        (None, Some(s)) if s.restarts > 0 => format!(
            "ok after {} restart(s), {} steps abandoned",
            s.restarts, s.failed_steps
        ),
        (None, Some(s)) => {
            let mut st = match s.step_updates.filter(|u| u.reductions > 0) {
                Some(u) => format!("ok, step shortened to {:.3}x", u.dt_min / u.dt_initial),
                None => "ok".into(),
            };
            if let Some(b) = s.energy.balance_error.filter(|&b| b > ENERGY_WARNING) {
                st.push_str(&format!(
                    ", but {:.2} % of the energy unaccounted for (unstable?)",
                    100.0 * b
                ));
            }
            if let Some(r) = s.equilibrium_residual.filter(|&r| r > RESIDUAL_WARNING) {
                st.push_str(&format!(", but {r:.1e} from equilibrium"));
            }
            st
        }
        _ => "ok".into(),
    }
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

impl Summary {
    /// Solve wall time per step, ms, counting the steps of attempts a restart abandoned
    /// (their time is in the solve time).
    pub fn ms_per_step(&self) -> f64 {
        1e3 * self.wall_seconds.solve / (self.steps + self.failed_steps).max(1) as f64
    }

    /// Human-readable summary table.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "scene            {}", self.scene);
        let _ = writeln!(
            s,
            "method           {} / {} ({})",
            self.method, self.element, self.mode
        );
        let _ = writeln!(s, "nodes            {}", self.nodes);
        let _ = writeln!(
            s,
            "points           {} (elements {})",
            self.integration_points, self.mesh.elements
        );
        if let (Some(sn), Some(m)) = (&self.support_nodes, &self.meshless) {
            let _ = writeln!(s, "cloud            {}", m.cloud);
            let exact = m.exact_volume.map_or(String::new(), |v| {
                format!(
                    " vs exact volume {v:.6e} m^3 ({:+.3} %)",
                    100.0 * (self.mesh.volume / v - 1.0)
                )
            });
            let _ = writeln!(
                s,
                "integration      {}; weights {:.6e} m^3{exact}",
                m.integration, self.mesh.volume
            );
            let _ = writeln!(
                s,
                "shape functions  {} basis, {} support: {:.1} nodes per point (min {}, max {}); {} node(s) removed; boundary conditions by {}",
                m.basis,
                m.support_rule,
                sn.mean,
                sn.min,
                sn.max,
                self.removed_nodes.unwrap_or(0),
                self.bc_method.as_deref().unwrap_or("-")
            );
        }
        if let Some(a) = self.coupled.as_ref().and_then(|c| c.adaptive.as_ref()) {
            let _ = writeln!(s, "interior points  {}", a.line());
        }
        if let Some(a) = self.mesh.min_dihedral_deg {
            let _ = writeln!(
                s,
                "min dihedral     {a:.2} deg (element {})",
                self.mesh.min_dihedral_element.unwrap_or(0)
            );
        }
        if let Some(st) = &self.statics {
            let _ = writeln!(
                s,
                "static solve     {}: {} load steps ({} cuts{}), {} Newton iterations, {} CG iterations, \
                 {} assemblies, {} kept-factor steps, {} factorizations ({} in single precision{}) of {} DOFs ({:.1} MB factor, {:.2} s), \
                 {} force evaluations",
                st.variant,
                st.load_steps,
                st.cuts,
                if st.shifted_retries > 0 {
                    format!(
                        ", {} stalled steps retried shifted, {} converged",
                        st.shifted_retries, st.shifted_converged
                    )
                } else {
                    String::new()
                },
                st.newton_iterations,
                st.linear_iterations,
                st.assemblies,
                st.kept_solves,
                st.factorizations,
                st.single_factorizations,
                if st.modified_factorizations > 0 {
                    format!(
                        ", {} of a tangent not positive definite",
                        st.modified_factorizations
                    )
                } else {
                    String::new()
                },
                st.dofs,
                st.factor_bytes as f64 / 1e6,
                st.factor_seconds,
                self.force_evaluations
            );
            if st.relaxed_start_steps > 0 {
                let _ = writeln!(
                    s,
                    "relaxed start    {} relaxation steps to {} x the tolerance ({:.2} s; contact at rest, \
                     solver.relaxed_start), then the static solve from there; the force evaluations \
                     above count both",
                    st.relaxed_start_steps,
                    crate::solver::integrate::RELAXED_START_SHARE,
                    st.relaxed_start_seconds
                );
            }
            if let Some(from) = st.fallback_from {
                let _ = writeln!(
                    s,
                    "fallback         the load steps stopped at {:.4} % of the load; {} relaxation \
                     steps from the unloaded state ({:.2} s, solver.relaxation_fallback) gave the \
                     result; the force evaluations above count both",
                    100.0 * from,
                    st.fallback_steps,
                    st.fallback_seconds
                );
            }
        } else {
            let _ = writeln!(
                s,
                "time step        {:.4e} s = {:.3} x critical {:.4e} s (set by {})",
                self.dt, self.dt_factor, self.dt_critical, self.mesh.critical
            );
        }
        if let Some(u) = self.step_updates.filter(|u| u.estimates > 0) {
            let what = if u.reductions > 0 {
                format!(
                    "step shortened {} time(s), to {:.4e} s ({:.3} x the initial; the last at t = {:.4} s)",
                    u.reductions,
                    u.dt_min,
                    u.dt_min / u.dt_initial,
                    u.last_reduction_time
                )
            } else {
                "step kept".to_string()
            };
            let _ = writeln!(
                s,
                "step updates     {} estimate(s) at the deformed state ({} force evaluations): {what}",
                u.estimates, u.iterations
            );
        }
        if let Some(d) = self.momentum.as_ref().and_then(|m| m.angular_drift()) {
            let m = self
                .momentum
                .as_ref()
                .map(|m| m.angular_end)
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "momentum         angular at the end ({:.6e}, {:.6e}, {:.6e}) kg m^2/s, drift {:.3e} of the start",
                m[0], m[1], m[2], d
            );
        }
        if self.statics.is_none() {
            let _ = writeln!(
                s,
                "steps            {} ({} = {:.4} s){}{}",
                self.steps,
                if self.load_steps.is_some() {
                    "pseudo-time t"
                } else {
                    "t"
                },
                self.simulated_time,
                self.load_steps
                    .map_or(String::new(), |n| format!(", load over the first {n}"))
                    + &if self.failed_steps > 0 {
                        format!(
                            "; {} more in attempts abandoned after an instability",
                            self.failed_steps
                        )
                    } else {
                        String::new()
                    },
                if self.converged {
                    ""
                } else {
                    "  NOT CONVERGED"
                }
            );
        } else if !self.converged {
            let _ = writeln!(s, "steps            NOT CONVERGED (see the warnings)");
        }
        let residual = self.equilibrium_residual.map_or(String::new(), |r| {
            format!(" (largest free-node residual {r:.2e} of the largest nodal force in the run)")
        });
        let _ = writeln!(s, "status           {}{residual}", self.status);
        let _ = writeln!(
            s,
            "wall time        {:.3} s (preprocess {:.3} s, solve {:.3} s; {:.3} ms/step, {})",
            self.wall_seconds.total,
            self.wall_seconds.preprocess,
            self.wall_seconds.solve,
            self.ms_per_step(),
            if self.device == "cpu" {
                format!("{} threads", self.threads)
            } else {
                format!("on {}", self.device)
            }
        );
        if let Some(r) = self.relaxation.last() {
            let _ = writeln!(
                s,
                "relaxation       {} estimates of omega_min, last {:.4e} rad/s, r = {:.6}, error estimate {:.3e} m (relaxation.csv has the history)",
                self.relaxation.len(),
                r.omega_min,
                r.r,
                r.error_estimate
            );
        }
        let _ = writeln!(s, "reactions (N)    {:>13} {:>13} {:>13}", "x", "y", "z");
        for (k, v) in &self.reactions {
            let _ = writeln!(
                s,
                "  {k:<14} {:>13.6e} {:>13.6e} {:>13.6e}",
                v[0], v[1], v[2]
            );
        }
        for (k, c) in &self.contact {
            let _ = writeln!(
                s,
                "contact          {k}: {} surface point(s) in contact, deepest penetration {:.3e} m (tolerance {:.1e} m)",
                c.points_in_contact, c.max_penetration, c.tolerance
            );
        }
        if !self.loads.is_empty() {
            let _ = writeln!(s, "loads (N)        {:>13} {:>13} {:>13}", "x", "y", "z");
            for (k, v) in &self.loads {
                let _ = writeln!(
                    s,
                    "  {k:<14} {:>13.6e} {:>13.6e} {:>13.6e}",
                    v[0], v[1], v[2]
                );
            }
        }
        if !self.probes.is_empty() {
            let _ = writeln!(
                s,
                "probes (m)       {:>13} {:>13} {:>13}",
                "u_x", "u_y", "u_z"
            );
            for (k, p) in &self.probes {
                let d = p.displacement;
                let _ = writeln!(
                    s,
                    "  {k:<14} {:>13.6e} {:>13.6e} {:>13.6e}  at {:?}",
                    d[0], d[1], d[2], p.position
                );
            }
        }
        let e = &self.energy;
        let balance = match (e.balance_error, self.load_steps.is_some()) {
            (Some(b), _) => format!(", balance error {:.4} %", 100.0 * b),
            (None, true) if self.statics.is_some() => {
                ", the work of the internal forces along the load path (parabolas through the equilibria; Simpson for one load step)".into()
            }
            // Relaxation's damping takes the rest of the external work: no balance to check.
            (None, true) => ", the difference is what relaxation's damping absorbed".into(),
            (None, false) => String::new(),
        };
        let damping = e
            .damping_dissipation
            .map_or(String::new(), |d| format!(", damping {d:.6e}"));
        let _ = writeln!(
            s,
            "energy (J)       external work {:.6e}, strain {:.6e}, kinetic {:.6e}{damping}{balance}",
            e.external_work, e.strain_energy, e.kinetic
        );
        if !self.reference.is_empty() {
            let _ = writeln!(s, "vs reference");
            for (k, c) in &self.reference {
                let at = c.at.map_or(String::new(), |a| format!(" at load {a}"));
                let band = c.band_error.map_or(String::new(), |b| {
                    format!(", {:.3} % from its band", 100.0 * b)
                });
                let _ = writeln!(
                    s,
                    "  {k:<14} {:<22} computed {:>12.6e}  reference {:>12.6e}  error {:>7.3} %{band}{at}",
                    c.quantity,
                    c.computed,
                    c.value,
                    100.0 * c.relative_error
                );
            }
        }
        crate::error::tidy_exponents(&s)
    }
}

/// Markdown table of run summaries (the JSON written by `run --json` or `summary.json`): one row
/// per run with the first reference comparison of each, for README and study reports.
pub fn markdown_table(summaries: &[serde_json::Value]) -> String {
    use std::fmt::Write;
    let mut s = String::from(
        "| scene | method | element | mode | nodes | elements | points | reaction (N) | reference (N) | error | probe error | dt (s) | steps | solve (s) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for v in summaries {
        let refs = v["reference"].as_object();
        let pick = |q: &str| {
            refs.and_then(|r| {
                r.values()
                    .find(|c| c["quantity"].as_str().is_some_and(|x| x.starts_with(q)))
            })
        };
        // A scene without a reaction reference shows "-", not NaN.
        let num = |c: Option<&serde_json::Value>, key: &str, f: &dyn Fn(f64) -> String| {
            c.and_then(|c| c[key].as_f64())
                .map(f)
                .unwrap_or_else(|| "-".into())
        };
        let r = pick("reaction");
        // Without a reaction reference: the largest reaction component of any boundary, named.
        let largest = || {
            let reactions = v["reactions"].as_object()?;
            let mut best: Option<(f64, String)> = None;
            for (name, comps) in reactions {
                for (k, c) in comps.as_array()?.iter().enumerate().take(3) {
                    let x = c.as_f64()?;
                    if best.as_ref().is_none_or(|b| x.abs() > b.0.abs()) {
                        best = Some((x, format!("{name}.{}", ["x", "y", "z"][k])));
                    }
                }
            }
            best.map(|(x, at)| format!("{x:.4} ({at})"))
        };
        let computed = match r {
            Some(_) => num(r, "computed", &|x| format!("{x:.4}")),
            None => largest().unwrap_or_else(|| "-".into()),
        };
        let value = num(r, "value", &|x| format!("{x:.4}"));
        let err = num(r, "relative_error", &|x| format!("{:.2} %", 100.0 * x));
        let perr = pick("probe")
            .and_then(|c| c["relative_error"].as_f64())
            .map(|e| format!("{:.2} %", 100.0 * e))
            .unwrap_or_else(|| "-".into());
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.3e} | {} | {:.2} |",
            v["scene"].as_str().unwrap_or("?"),
            v["method"].as_str().unwrap_or("?"),
            v["element"].as_str().unwrap_or("?"),
            v["mode"].as_str().unwrap_or("?"),
            v["nodes"],
            v["mesh"]["elements"],
            v["integration_points"],
            computed,
            value,
            err,
            perr,
            v["dt"].as_f64().unwrap_or(f64::NAN),
            v["steps"],
            v["wall_seconds"]["solve"].as_f64().unwrap_or(f64::NAN),
        );
    }
    crate::error::tidy_exponents(&s)
}
