//! Prepare once, solve many times: the intra-operative loop, where a model built before
//! surgery is solved again each time new displacements are measured or a tool moves.
//!
//! A [`Session`] holds a prepared scene. Between solves, boundary displacements, measured
//! displacements, rigid-body (tool) positions and load factors change on the model; each
//! relaxation after the first starts from the last equilibrium ([`Settings::warm_start`]),
//! so it relaxes only the change.
//!
//! ```no_run
//! use hytled::simulation::Session;
//!
//! let scene = hytled::scene::load("cases/brain-shift.toml".as_ref(), &[])?;
//! let mut session = Session::new(scene)?;
//! let first = session.solve()?; // from the unloaded state
//! println!("{} steps", first.output.steps);
//! // New measurements at the same points: 10 % more displacement.
//! let points = session.measured_points("exposed")?.len();
//! let mut u = session.measured_displacements("exposed")?;
//! u.iter_mut().flatten().for_each(|c| *c *= 1.1);
//! assert_eq!(u.len(), points);
//! session.set_measured("exposed", &u)?;
//! let next = session.solve()?; // from the first equilibrium
//! println!("{} steps (warm: {})", next.output.steps, next.warm);
//! # Ok::<(), hytled::Error>(())
//! ```

use std::time::Instant;

use nalgebra::Vector3;

use super::{prepare, settings, summarize, PointFields, Prepared, ResultPoints};
use crate::material::Solid;
use crate::report::{Summary, Warning, WarningKind};
use crate::scene::Scene;
use crate::solver::{MassState, Mode, Model, RunOutput, Settings, WarmStart};
use crate::{Error, InputKind, Result};

/// A prepared scene solved as often as its inputs change.
pub struct Session {
    scene: Scene,
    prep: Prepared,
    settings: Settings,
    /// The last converged relaxation's state: where the next solve starts.
    warm: Option<WarmStart>,
    /// Seconds the preparation took.
    prepare_seconds: f64,
    /// Warm starts of a model that keeps its physical masses: the scaled ones they relax with
    /// ([`Model::scale_masses`]), made at the first warm start.
    warm_masses: Option<Vec<f64>>,
    /// The state in `warm` came from a run with `warm_masses`.
    warm_from_swapped: bool,
    /// The rigid bodies' final displacements (m) the state in `warm` was relaxed with.
    warm_tools: Vec<Vector3<f64>>,
}

/// What a solve changes in a [`Session`] (where the next solve starts), kept by
/// [`Session::checkpoint`] and put back by [`Session::restore`]: an interrupted solve leaves the
/// model as it was.
#[derive(Clone)]
pub struct Checkpoint {
    warm: Option<WarmStart>,
    warm_masses: Option<Vec<f64>>,
    warm_from_swapped: bool,
    warm_tools: Vec<Vector3<f64>>,
}

/// What one solve produced.
pub struct Solution {
    /// The run's summary (reactions, probes, steps, times, warnings), as `hytled run` prints.
    pub summary: Summary,
    /// The time loop's output: displacements `u` (m, nodal parameters), internal forces, history.
    pub output: RunOutput,
    /// Whether the solve started from the previous equilibrium.
    pub warm: bool,
}

impl Session {
    /// Meshes the scene and builds its model ([`prepare`]): the expensive part, done once.
    pub fn new(scene: Scene) -> Result<Self> {
        let t0 = Instant::now();
        let prep = prepare(&scene)?;
        let mut settings = settings(&scene, false);
        settings.refresh_factor = true;
        Ok(Session {
            scene,
            prep,
            settings,
            warm: None,
            prepare_seconds: t0.elapsed().as_secs_f64(),
            warm_masses: None,
            warm_from_swapped: false,
            warm_tools: Vec::new(),
        })
    }

    /// The scene the session was prepared from.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The prepared discretization (mesh, model, probes, warnings).
    pub fn prepared(&self) -> &Prepared {
        &self.prep
    }

    /// The model, for changes the setters below do not cover. Boundary values changed on
    /// `model.boundaries()` are taken by the next solve ([`Model::apply_boundary_changes`]).
    pub fn model_mut(&mut self) -> &mut Model<Solid> {
        &mut self.prep.model
    }

    /// The integrator settings the solves use (from the scene's `[solver]`); change them here
    /// (device, tolerance, progress).
    pub fn settings_mut(&mut self) -> &mut Settings {
        &mut self.settings
    }

    /// Seconds the preparation (meshing, shape functions, masses) took.
    pub fn prepare_seconds(&self) -> f64 {
        self.prepare_seconds
    }

    /// Whether the next [`Self::solve`] starts from the last equilibrium.
    pub fn is_warm(&self) -> bool {
        self.warm.is_some()
    }

    /// The next solve starts from the unloaded state.
    pub fn forget(&mut self) {
        self.warm = None;
    }

    fn boundary_index(&self, name: &str) -> Result<usize> {
        let boundaries = self.prep.model.boundaries();
        boundaries
            .iter()
            .position(|b| b.name == name)
            .ok_or_else(|| {
                let names: Vec<&str> = boundaries.iter().map(|b| b.name.as_str()).collect();
                Error::input(
                    InputKind::Selection,
                    format!(
                        "no boundary named '{name}'; the model's boundaries: {}",
                        if names.is_empty() {
                            "none".to_string()
                        } else {
                            names.join(", ")
                        }
                    ),
                )
                .key(format!("boundaries.{name}"))
            })
    }

    fn boundary(&self, name: &str) -> Result<&crate::bc::Boundary> {
        let i = self.boundary_index(name)?;
        Ok(&self.prep.model.boundaries()[i])
    }

    fn boundary_mut(&mut self, name: &str) -> Result<&mut crate::bc::Boundary> {
        let i = self.boundary_index(name)?;
        Ok(&mut self.prep.model.boundaries_mut()[i])
    }

    /// New final displacement (m) of the components of boundary `name` given as Some; None
    /// leaves a component as it is. A component the boundary leaves free cannot become
    /// prescribed (its selection and components were prepared), nor a measured boundary take
    /// a uniform value ([`Self::set_measured`]).
    pub fn set_displacement(&mut self, name: &str, value: [Option<f64>; 3]) -> Result<()> {
        let b = self.boundary_mut(name)?;
        if b.measured.is_some() || b.node_values.is_some() {
            return Err(Error::input(
                InputKind::Value,
                format!(
                "boundary '{name}' prescribes a value per node (measured displacements); give new \
                 measurements with set_measured"
            ),
            )
            .key(format!("boundaries.{name}")));
        }
        for (c, v) in value.iter().enumerate() {
            let Some(v) = v else { continue };
            if !v.is_finite() {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                        "boundary '{name}': {} displacement {v} m is not finite",
                        ["x", "y", "z"][c]
                    ),
                )
                .key(format!("boundaries.{name}"))
                .value(*v));
            }
            if b.components[c].is_none() {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                    "boundary '{name}' leaves its {} component free, so it cannot prescribe one \
                     now; prescribe it in the scene ([boundaries.{name}] displacement or fix) and \
                     prepare again",
                    ["x", "y", "z"][c]
                ),
                )
                .key(format!("boundaries.{name}")));
            }
        }
        for (c, v) in value.iter().enumerate() {
            if let Some(v) = v {
                b.components[c] = Some(*v);
            }
        }
        Ok(())
    }

    /// The final displacement (m) of each component of boundary `name` (None: free); for a
    /// measured boundary, zeros on its prescribed components (its values are per node).
    pub fn displacement(&self, name: &str) -> Result<[Option<f64>; 3]> {
        Ok(self.boundary(name)?.components)
    }

    fn measured_map(&self, name: &str) -> Result<&crate::bc::MeasuredMap> {
        self.boundary(name)?.measured.as_deref().ok_or_else(|| {
            Error::input(
                InputKind::Value,
                format!("boundary '{name}' is not a [measured] boundary"),
            )
            .key(format!("boundaries.{name}"))
        })
    }

    /// The positions (m) of the measured points of `[measured.NAME]`, in its file's order.
    pub fn measured_points(&self, name: &str) -> Result<Vec<[f64; 3]>> {
        Ok(self.measured_map(name)?.points.clone())
    }

    /// The displacements (m) in force at the measured points of `[measured.NAME]`: those of
    /// its file, or of the last [`Self::set_measured`].
    pub fn measured_displacements(&self, name: &str) -> Result<Vec<[f64; 3]>> {
        Ok(self.measured_map(name)?.values.clone())
    }

    /// New displacements (m) measured at the points of `[measured.NAME]` (one per point, in
    /// its file's order): matched or interpolated onto the surface nodes as prepared.
    pub fn set_measured(&mut self, name: &str, u: &[[f64; 3]]) -> Result<()> {
        self.boundary_mut(name)?.set_measured(u)
    }

    /// New final displacement (m) of rigid body `[contact.NAME]` from its reference position.
    pub fn set_tool_motion(&mut self, name: &str, motion: [f64; 3]) -> Result<()> {
        self.contact_mut(name)?
            .set_motion(name, Vector3::from(motion))
    }

    /// The final displacement (m) of rigid body `[contact.NAME]`.
    pub fn tool_motion(&self, name: &str) -> Result<[f64; 3]> {
        let m = self.contact(name)?.motion(name)?;
        Ok([m.x, m.y, m.z])
    }

    fn no_contact(name: &str) -> Error {
        Error::input(
            InputKind::Selection,
            format!("no rigid body named '{name}': the scene has no [contact]"),
        )
        .key(format!("contact.{name}"))
    }

    fn contact(&self, name: &str) -> Result<&crate::bc::contact::Contact> {
        self.prep
            .model
            .contact()
            .ok_or_else(|| Self::no_contact(name))
    }

    fn contact_mut(&mut self, name: &str) -> Result<&mut crate::bc::contact::Contact> {
        self.prep
            .model
            .contact_mut()
            .ok_or_else(|| Self::no_contact(name))
    }

    /// Scales load `[loads.NAME]` by `factor` (1: as in the scene).
    pub fn set_load_factor(&mut self, name: &str, factor: f64) -> Result<()> {
        self.prep.model.loads_mut().set_factor(name, factor)
    }

    /// The factor of load `[loads.NAME]`.
    pub fn load_factor(&self, name: &str) -> Result<f64> {
        self.prep.model.loads().factor(name)
    }

    /// Solves with the inputs as they are now. A relaxation starts from the last converged
    /// equilibrium where there is one (warm); should that attempt fail (a change too large
    /// to take from there: an instability after the restarts), it solves again from the
    /// unloaded state and says so in the summary's warnings. Dynamic runs always start from
    /// the initial state.
    pub fn solve(&mut self) -> Result<Solution> {
        let warm = match (&self.warm, self.settings.mode) {
            (Some(w), Mode::Relaxation | Mode::Static) => Some(w.clone()),
            _ => None,
        };
        let Some(w) = warm else {
            return self.run(None);
        };
        // A warm start puts every rigid body at its final place from the first step: moved
        // further than the contact tolerance since the last equilibrium, a tool would jump past
        // the surface it should push (issue 56: reaction 0, "converged"). Such a change is
        // solved from the unloaded state, where the tool comes along its curve in small steps.
        if let Some(moved) = self.tool_jump() {
            let mut cold = self.run(None)?;
            cold.summary
                .warnings
                .push(Warning::new(WarningKind::Resolve, moved));
            return Ok(cold);
        }
        match self.run(Some(w)) {
            Err(Error::Unstable(msg)) => {
                let mut cold = self.run(None)?;
                cold.summary.warnings.push(Warning::new(
                    WarningKind::Resolve,
                    format!(
                    "the warm start from the last equilibrium failed ({msg}); solved again from \
                     the unloaded state"
                ),
                ));
                Ok(cold)
            }
            r => r,
        }
    }

    /// Where the next solve would start, to [`Session::restore`] after a solve that should
    /// not count (stopped by Ctrl-C).
    pub fn checkpoint(&self) -> Checkpoint {
        Checkpoint {
            warm: self.warm.clone(),
            warm_masses: self.warm_masses.clone(),
            warm_from_swapped: self.warm_from_swapped,
            warm_tools: self.warm_tools.clone(),
        }
    }

    /// Puts back the state of a [`Session::checkpoint`].
    pub fn restore(&mut self, c: Checkpoint) {
        self.warm = c.warm;
        self.warm_masses = c.warm_masses;
        self.warm_from_swapped = c.warm_from_swapped;
        self.warm_tools = c.warm_tools;
    }

    /// The rigid bodies' final displacements now, m.
    fn tool_motions(&self) -> Vec<Vector3<f64>> {
        let Some(c) = self.prep.model.contact() else {
            return Vec::new();
        };
        c.names()
            .map(|n| c.motion(n).unwrap_or_else(|_| Vector3::zeros()))
            .collect()
    }

    /// A message where a rigid body moved further than it may jump
    /// ([`crate::bc::contact::Contact::jump_limit`]) since the warm state was relaxed.
    fn tool_jump(&self) -> Option<String> {
        let c = self.prep.model.contact()?;
        let now = self.tool_motions();
        c.names()
            .enumerate()
            .zip(now.iter().zip(&self.warm_tools))
            .find_map(|((k, name), (a, b))| {
                let d = (a - b).norm();
                let limit = c.jump_limit(k);
                (d > limit).then(|| {
                    format!(
                        "contact '{name}' moved {d:.3e} m since the last equilibrium, more than the {limit:.3e} m \
                         it may jump at once (a warm start puts it at its new place from the first step, \
                         where it could pass through the surface it should push): solved from the unloaded \
                         state, the tool coming along its curve"
                    )
                })
            })
    }

    /// Solves from the unloaded state, whatever came before.
    pub fn solve_cold(&mut self) -> Result<Solution> {
        self.run(None)
    }

    /// Whether a warm start relaxes with scaled masses where the model keeps its physical
    /// ones: a model of tet4-anp elements alone keeps them in a cold relaxation (their
    /// rims collapsed under scaled masses while the load came on from zero), but a warm start begins loaded and moves only by
    /// the change. Not where the scene chose its masses (`solver.mass_scaling`), nor with a
    /// meshless correction, which was built with the model's masses.
    fn scales_warm_masses(&self) -> bool {
        let m = &self.prep.model;
        self.scene.solver.mass_scaling.is_none() && !m.mass_scaled() && m.corrector().is_none()
    }

    fn run(&mut self, warm: Option<WarmStart>) -> Result<Solution> {
        self.run_with(warm, super::solve)
    }

    /// [`Self::run`] with the solver passed in (a test's stands in for it).
    fn run_with(
        &mut self,
        warm: Option<WarmStart>,
        solve: impl FnOnce(&mut Prepared, &Settings) -> Result<RunOutput>,
    ) -> Result<Solution> {
        let t0 = Instant::now();
        let is_warm = warm.is_some();
        // The steady state does not depend on the masses; scaled ones make every node's
        // step bound alike, so the change relaxes in a fraction of the steps (brain-shift:
        // 305 against 1,804 with the physical masses).
        let swap = is_warm && self.settings.mode == Mode::Relaxation && self.scales_warm_masses();
        // The lowest frequency carried over holds for the masses it was estimated with.
        let warm = warm.map(|mut w| {
            if swap && !self.warm_from_swapped {
                w.omega_min = None;
            }
            w
        });
        self.settings.warm_start = warm;
        let out = if swap {
            let mut scaled = ScaledMasses::put_in(&mut self.prep, &mut self.warm_masses)?;
            solve(&mut scaled, &self.settings)
        } else {
            solve(&mut self.prep, &self.settings)
        };
        self.settings.warm_start = None;
        let out = out?;
        let mut summary = summarize(&self.scene, &self.prep, &out, t0.elapsed().as_secs_f64());
        // The preparation happened once, before the first solve (`prepare_seconds`).
        summary.wall_seconds.preprocess = 0.0;
        if is_warm {
            summary
                .warnings
                .retain(|w| w.kind != WarningKind::SteadyFrames);
        }
        self.warm_from_swapped = swap;
        // Only a converged relaxation is an equilibrium to start from.
        self.warm = (self.settings.mode.is_steady() && summary.converged).then(|| out.warm_start());
        self.warm_tools = self.tool_motions();
        Ok(Solution {
            summary,
            output: out,
            warm: is_warm,
        })
    }

    /// The fields of nodal values `u` (m) at the points of the VTU frames, with their cells
    /// ([`PointFields`]: FE nodes; meshless and coupled, their output points, displacements
    /// and stresses interpolated with the shape functions), as `run --out` writes them.
    pub fn point_fields(&mut self, u: &[Vector3<f64>]) -> Result<PointFields> {
        let Prepared {
            model,
            mesh,
            method,
            ..
        } = &mut self.prep;
        if u.len() != model.nodes().len() {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "{} displacements for the model's {} nodes",
                    u.len(),
                    model.nodes().len()
                ),
            ));
        }
        Ok(ResultPoints::new(mesh, method)?.point_fields(model, u))
    }
}

/// The prepared model with fictitious masses ([`Model::scale_masses`]) put in for one warm
/// relaxation; the physical masses come back when it is dropped, so a solve that returns an
/// error or panics (a Python caller goes on after a panic) leaves the model as it was.
struct ScaledMasses<'a> {
    prep: &'a mut Prepared,
    /// The model's masses and their flags as they were (taken when `None` after the drop).
    physical: Option<MassState>,
}

impl<'a> ScaledMasses<'a> {
    /// Puts in the masses `cached` (those of an earlier warm start), or scales them and keeps
    /// a copy there.
    fn put_in(prep: &'a mut Prepared, cached: &mut Option<Vec<f64>>) -> Result<Self> {
        let model = &mut prep.model;
        let physical = model.mass_state();
        let put = match cached {
            Some(m) => model.set_scaled_masses(m),
            None => model.scale_masses().map(|()| {
                if model.mass_scaled() {
                    *cached = Some(model.mass().to_vec());
                }
            }),
        };
        if let Err(e) = put {
            model.restore_masses(physical);
            return Err(e);
        }
        Ok(ScaledMasses {
            prep,
            physical: Some(physical),
        })
    }
}

impl std::ops::Deref for ScaledMasses<'_> {
    type Target = Prepared;
    fn deref(&self) -> &Prepared {
        self.prep
    }
}

impl std::ops::DerefMut for ScaledMasses<'_> {
    fn deref_mut(&mut self) -> &mut Prepared {
        self.prep
    }
}

impl Drop for ScaledMasses<'_> {
    fn drop(&mut self) {
        if let Some(m) = self.physical.take() {
            self.prep.model.restore_masses(m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact cube in relaxation (these tests are about its warm masses).
    fn cube() -> Session {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("cases/cube-compression.toml");
        let sets: Vec<String> = [
            "solver.mode=relaxation",
            "discretization.element=tet4-anp",
            "discretization.size=0.05",
            "references={}",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        Session::new(crate::scene::load(&path, &sets).expect("the cube scene"))
            .expect("the cube session")
    }

    /// Issue 58: a warm relaxation swaps in scaled masses; a solve that panics with them in
    /// leaves the physical masses behind, and the next solve's answer is bitwise the one of a
    /// session that never panicked.
    #[test]
    fn a_panic_inside_a_solve_leaves_the_physical_masses() {
        let mut a = cube();
        let mut b = cube();
        for s in [&mut a, &mut b] {
            s.solve().expect("cold solve");
            s.set_displacement("top", [None, None, Some(-0.021)])
                .expect("the top boundary");
        }
        let physical = a.prep.model.mass().to_vec();
        let warm = a.warm.clone();
        assert!(warm.is_some() && a.scales_warm_masses());
        let mut scaled_inside = false;
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let _ = a.run_with(warm, |prep, _| {
                scaled_inside = prep.model.mass_scaled() && prep.model.mass() != physical;
                panic!("a fault inside the solve");
            });
        }));
        assert!(caught.is_err() && scaled_inside);
        assert_eq!(a.prep.model.mass(), physical);
        assert!(!a.prep.model.mass_scaled());
        let (ra, rb) = (a.solve().expect("warm a"), b.solve().expect("warm b"));
        assert!(ra.warm && rb.warm);
        assert_eq!(ra.output.u, rb.output.u);
        assert_eq!(a.prep.model.mass(), physical);
    }
}
