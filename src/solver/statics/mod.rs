//! Static equilibrium, F_int(u) = F_ext(u), by Newton's method with load stepping, a line
//! search and automatic step cuts: the steady state without a pseudo-dynamic path.
//!
//! The tangent comes from the same quadrature points as the forces ([`tangent`]); the reduced
//! stiffness K_ff is factored by faer's supernodal Cholesky on a pattern and symbolic
//! factorization built once ([`factor`]). Three variants ([`Variant`]): full Newton (a
//! factorization per iteration), modified Newton (one kept factor, no reassembly) and the
//! default Newton-Krylov (the current tangent each iteration, solved by conjugate gradients
//! preconditioned by a kept factor, refactored only when the iterations slow down): a
//! factorization costs tens to hundreds of force evaluations on quadratic meshes, an
//! assembly about ten, a CG iteration one sparse product.
//!
//! Prescribed displacements are imposed exactly (their DOFs eliminated); each load step starts
//! from the linear predictor u_f += K_ff^-1 (r_f - K_fp du_p), so the nodes beside a moved
//! boundary follow it instead of being torn from it in the first evaluation. Follower pressure
//! enters the residual but not the tangent (its load stiffness is left out: convergence is
//! then linear where pressure dominates).
//!
//! Where things are: this file holds the load stepping ([`Newton::run`]: stages, step
//! growth, cuts, the stop) and a load step's Newton iterations with their line search;
//! [`predictor`] starts each load step; [`linear`] solves K_ff du = r (factorizations, the
//! kept factor, preconditioned CG); [`contact`] and [`constraints`] hold rigid contact and
//! linear constraints (augmented Lagrangians); [`record`] the residual history, frames,
//! stages, the work and the output; [`checks`] what is refused before the start;
//! [`tangent`], [`factor`], [`trisolve`] and [`krylov`] the sparse tangent, its
//! factorization, the triangular solves on the threads and GMRES.

mod checks;
mod constraints;
mod contact;
pub mod factor;
mod krylov;
mod linear;
mod predictor;
mod record;
pub mod tangent;
mod trisolve;

use std::time::Instant;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::integrate::{FrameSink, HistoryRow, RunOutput, Settings, Stage};
use super::Model;
use crate::bc::LoadCurve;
use crate::material::Material;
use crate::{Error, InputKind, Result};
use checks::check_supported;
pub use checks::free_rigid_motions;
use constraints::{violation, CONSTRAINT_SHARE};
use factor::{Dofs, Factor, Kind};
pub use tangent::Tangent;

/// How each Newton iteration solves K du = r ([`crate::solver::Settings::static_variant`];
/// scene `solver.static_variant`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    /// The current tangent, solved by conjugate gradients preconditioned by a kept
    /// factorization, refactored when CG takes more than [`CG_LIMIT`] iterations.
    #[default]
    NewtonKrylov,
    /// A factorization of the current tangent at every iteration.
    Newton,
    /// The kept factorization alone (no assembly between factorizations), refactored when an
    /// iteration reduces the residual by less than half.
    Modified,
}

impl Variant {
    /// The scene's name of the variant.
    pub fn name(self) -> &'static str {
        match self {
            Variant::NewtonKrylov => "newton-krylov",
            Variant::Newton => "newton",
            Variant::Modified => "modified",
        }
    }
}

/// CG iterations after which the kept factor is replaced by one of the current tangent.
pub const CG_LIMIT: usize = 40;
/// CG stops when the residual of the linear system is at most this fraction of its
/// right-hand side.
const CG_TOLERANCE: f64 = 1e-4;
/// ... and at most this fraction, less where the Newton iterations already contract fast:
/// the forcing term eta = 0.9 (r_k / r_k-1)^2 of Eisenstat and Walker (1996, choice 2), kept
/// within [CG_TOLERANCE, ETA_MAX]. An early iteration's direction need not be exact to the
/// fourth digit where the residual is still of the order of the load.
const ETA_MAX: f64 = 0.1;
/// Newton iterations per load step (after its last multiplier update) before the step is cut.
const MAX_ITERATIONS: usize = 25;
/// ... where rigid bodies that do not move hold the body ([`CONTACT_STALL_ITERATIONS`]):
/// the MNI brain's full-load step from 98.4 % of gravity went from a residual of 4.8e-2 to
/// 2.1e-6 of the largest force in 24 iterations, rising and falling as points came into
/// contact, and was cut at 25 (three such cuts; 277 Newton iterations and 55 s in all, with
/// 40: 216 and 40-42 s, the same with 60 and 100, where the stall window decides).
const CONTACT_MAX_ITERATIONS: usize = 40;
/// Multiplier updates (constraints and contact, augmented Lagrangian rounds) per load step
/// before the step is cut.
const MAX_ROUNDS: usize = 20;
/// A round of multiplier updates after the first ends once the Newton iterations have cut the
/// residual the last update left by this factor, not at convergence (the inner solves of
/// an augmented Lagrangian need not be exact while the multipliers are still moving: Nocedal
/// and Wright 2006, sect. 17.4); the last round converges fully. The MNI brain's polish
/// after its relaxed start: 50 -> 35 Newton iterations, 13.9 -> 12.0 s (0.1: 37, 0.3: 36);
/// from the unloaded state 216 -> 194 iterations, the reactions the same to the digits
/// printed.
const ROUND_CONTRACTION: f64 = 0.5;
/// The line search ends where the slope along the direction is within this fraction of its
/// start's.
const LINE_SEARCH: f64 = 0.5;
/// At most this many force evaluations in one line search.
const LINE_SEARCH_EVALUATIONS: usize = 8;
/// A load step that did not converge is tried once more with every node's diagonal block
/// raised by this share of itself times the relative residual (pseudo-transient
/// continuation with switched evolution relaxation, Kelley and Keyes 1998: the shift damps
/// the directions as a pseudo-mass would and fades as the residual falls, so the iterations
/// end as Newton's). A near-singular tangent otherwise sends the iterates wandering: the
/// coupled tet cube under the plate moved 5-35 mm per Newton update at 93 % of the load and
/// stopped there after 70 factorizations; with the shift from the start it converged in one
/// load step (42 Newton iterations, 4 factorizations, 1.0 s, relaxation's force to 1e-6).
/// Not on every step: the tet cylinders took 46-57 Newton iterations with it against 5-6.
const SHIFT: f64 = 1.0;
/// A load step whose predictor (linear, or the load path extrapolated) takes the smallest
/// volume ratio J of the model below this share of its value at the step's start is cut
/// before any Newton iteration. The driven tet10 plug (2 cores), for the linear predictor:
/// brain-indentation 3.43 -> 1.99 s (12 -> 5 factorizations; its full-load predictor reached
/// J = 0.29 from 1, its tangents after it 474 negative pivots), the benchmark's c2 2.04 ->
/// 1.74 s, c3 5.97 -> 5.48 s; for the extrapolated path too, c1 0.77 -> 0.59 s (no tangent
/// not positive definite, 2 of 15 factorizations before); at 0.9, brain-shift's
/// gravity step was cut twice for nothing (0.25 -> 0.34 s); at 0.7, brain-indentation 2.21 s.
/// Not applied to average-nodal-pressure elements, whose points' J is not held near 1 (their
/// nodes' is): the tet4-anp cylinder 75-80 % compressed settles with point J down to 0.12 at
/// nu = 0.49, and with the cut it stopped at 96-99.9 % of the load, where it had converged.
const PREDICTOR_J: f64 = 0.8;
/// The shortest share of an inverting linear predictor tried with rigid contact.
const PREDICTOR_SHORTEST: f64 = 1e-3;
/// Cuts in a row after which a stalled load step is retried with the shift: a step still
/// stalling when halved this often is not too long, its tangent is near-singular. Retried
/// from the first stall, cylinder-mixed's full-load step stalled shifted too and its solve
/// took 80 s against 20 s.
const SHIFT_AFTER_CUTS: usize = 2;
/// Newton iterations within which a load step's residual must halve, or the step has
/// stalled (it is cut, or retried with the shift).
const STALL_ITERATIONS: usize = 3;
/// ... with rigid bodies that do not move (a body settling onto them under its load), whose
/// residual rises and falls while points come into contact and the line search holds the
/// body against the surface: the cube hanging from a post onto a floor 0.5 mm below it under
/// gravity (`tests/contact.rs`) stalled at 0.96 % of the load with a window of 3, took 174
/// load steps with 6, and converged in 4 with 10; the MNI brain settling into its skull
/// stopped at 0.78 % of gravity with 3 and converged with 10. Not where a tool moves: a
/// shorter step is then a shorter travel of the tool, and with 10 the brain's flat punch
/// took its full travel in one step and settled with a rim point on the punch's side
/// (-43.76 mN, 41 points, against relaxation's -43.12 mN, 42).
const CONTACT_STALL_ITERATIONS: usize = 10;
/// Cuts in a row (each halving the load step) before the solve gives up.
const MAX_CUTS: usize = 12;
/// A load step's first Newton step shorter than this (from the line search), its residual
/// still half the largest force, cuts the step at once.
const EARLY_CUT_ALPHA: f64 = 0.25;
/// A point pressed into a rigid body is held against the push (an error naming the contact and
/// the boundary) when the components its nodes may move along carry less than this share of
/// the push. Relaxation's correction tests at the first touch, where a prescribed component
/// carries all of it ([`crate::bc::contact::Conflict`]); a static load step meets the body
/// deformed: a sphere pushed 10 mm through the cube's fixed base met the node on its axis
/// already 5.8 mm sideways (the cube's lateral stretch), the push 0.11 free, and slid it out.
const STATIC_HELD_SHARE: f64 = 0.5;
/// The solve also gives up when a cut would make the load step shorter than this fraction of
/// the load. Steps that short converge only to the sub-step tolerance and carry their
/// residual on: on the benchmark's c5 (71,607 nodes) steps of 1e-4 crawled from 93.5 % for
/// minutes, a cut, a sub-step and a cut again, never MAX_CUTS in a row.
const MIN_STEP: f64 = 1e-3;

/// Why the static solve stops after a failed load step of `span` (a load fraction), the
/// `cuts` in a row counting it: None while the step may still be halved.
fn give_up(cuts: usize, span: f64) -> Option<String> {
    if cuts > MAX_CUTS {
        Some(format!("after {MAX_CUTS} cuts in a row"))
    } else if 0.5 * span < MIN_STEP {
        Some(format!(
            "and half of it would be under the shortest load step, {} % of the load",
            100.0 * MIN_STEP
        ))
    } else {
        None
    }
}
/// The residual (largest out-of-balance force at a free DOF) must also fall below this
/// fraction of the largest nodal force.
const RESIDUAL_TOLERANCE: f64 = 1e-6;
/// A load step that ends short of a stage or the full load (a cut's sub-step) converges
/// when its residual is below this fraction of the largest nodal force: its error is carried
/// into the next step, which converges fully. 1e-3 until the scale came from accepted states
/// only (before, a rejected full-load attempt's forces had loosened it): the benchmark's c3
/// then took 10.4 s and brain-indentation 4.15 s, at 1e-2 8.25 s and 3.47 s, the forces at
/// every stage the same.
const SUBSTEP_TOLERANCE: f64 = 1e-2;

/// A modified-Newton step with the kept factor is repeated while it cuts the residual at
/// least this much (2x); otherwise the tangent is assembled for the rest of the load step.
const CHEAP_CONTRACTION: f64 = 0.5;

/// One Newton iteration of the residual history.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct ResidualRow {
    /// The share of the final load at the step's end ([`StaticReport::load_reached`]).
    pub load: f64,
    /// Iteration within the load step (0: after the predictor).
    pub iteration: usize,
    /// Largest out-of-balance force at a free DOF over the largest nodal force.
    pub residual: f64,
    /// Largest displacement change of the iteration, m.
    pub update: f64,
}

/// What a static solve did ([`RunOutput::statics`]; summary.json `static`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct StaticReport {
    pub variant: String,
    /// Load steps converged, and cuts (halvings) of steps that did not.
    pub load_steps: usize,
    pub cuts: usize,
    pub newton_iterations: usize,
    /// Conjugate-gradient iterations (Newton-Krylov).
    pub linear_iterations: usize,
    /// GMRES products (pairs of triangular solves) of EBCIEM's multiplier updates.
    pub multiplier_iterations: usize,
    /// Relaxation steps of the relaxed start ([`crate::solver::Settings::relaxed_start`]),
    /// and their wall time, s; 0 where the solve started from the unloaded state.
    #[serde(default)]
    pub relaxed_start_steps: usize,
    #[serde(default)]
    pub relaxed_start_seconds: f64,
    /// Where the load steps stopped short of the full load and the run relaxed instead
    /// ([`crate::solver::Settings::relaxation_fallback`]): the load share they reached, and
    /// the relaxation's steps and wall time, s (None, 0, 0 otherwise).
    #[serde(default)]
    pub fallback_from: Option<f64>,
    #[serde(default)]
    pub fallback_steps: usize,
    #[serde(default)]
    pub fallback_seconds: f64,
    /// Why the load steps stopped short of the full load (None where they did not): the
    /// caller says it in the notes.
    #[serde(skip)]
    pub stop: Option<String>,
    /// A warm start's step failed and the load steps went on from the unloaded state: the
    /// work along the path is theirs alone.
    #[serde(skip)]
    pub from_unloaded: bool,
    pub assemblies: usize,
    pub factorizations: usize,
    /// Of the factorizations, those in single precision (mixed precision: refined by CG on
    /// the double-precision tangent).
    #[serde(default)]
    pub single_factorizations: usize,
    /// Of the factorizations, those of a tangent not positive definite, made so (a modified
    /// LDL^T, L |D| L^T: its direction descends the energy).
    #[serde(default)]
    pub modified_factorizations: usize,
    /// Modified-Newton steps solved with a kept factor, no assembly (Newton-Krylov).
    pub kept_solves: usize,
    /// Load steps tried again with the diagonal shift after they did not converge
    /// ([`SHIFT`]), and how many of those then converged.
    pub shifted_retries: usize,
    pub shifted_converged: usize,
    /// Free DOFs, nonzeros of the upper triangle of K_ff and of its Cholesky factor, and the
    /// fill-reducing order.
    pub dofs: usize,
    pub ordering: String,
    pub matrix_nonzeros: usize,
    pub factor_nonzeros: usize,
    /// Bytes of the tangent, the matrix and the factor.
    pub factor_bytes: usize,
    /// Wall seconds: symbolic analysis, numeric factorizations, assemblies, linear solves.
    pub symbolic_seconds: f64,
    pub factor_seconds: f64,
    pub assembly_seconds: f64,
    pub solve_seconds: f64,
    /// The share of the final load reached at equilibrium: the load fraction, or where every
    /// changing input follows one rising curve, that curve's factor there (the solve steps
    /// in it).
    pub load_reached: f64,
    pub residual_history: Vec<ResidualRow>,
}

/// The kept tangent, factorization and numbering of a model: built by the first static solve
/// and reused by later ones while the prescribed DOFs stay the same.
pub struct Cache {
    tangent: Tangent,
    factor: Factor,
    dofs: Dofs,
}

impl Cache {
    /// Bytes held.
    pub fn bytes(&self, points: usize) -> usize {
        self.tangent.bytes(points) + self.factor.bytes()
    }

    /// Bytes held at the most, over the factorizations made.
    pub fn peak_bytes(&self, points: usize) -> usize {
        self.tangent.bytes(points) + self.factor.peak_bytes
    }
}

/// Solves the model's steady state statically; the output has the fields a relaxation's
/// has (no pseudo-time: `steps` counts Newton iterations, `dt` is 0).
pub fn solve<M: Material>(
    model: &mut Model<M>,
    s: &Settings,
    mut sink: Option<&mut FrameSink<'_, M>>,
    cache: &mut Option<Cache>,
) -> Result<RunOutput> {
    let start = Instant::now();
    check_supported(model)?;
    let free = free_rigid_motions(model);
    if !free.is_empty() {
        return Err(Error::input(InputKind::Value, format!(
            "the boundaries leave the body free to move as a rigid body ({}): a static solve has no \
             unique answer; prescribe components that hold these motions (e.g. fix one face, or a \
             node in each direction)",
            free.join("; ")
        )));
    }
    let dofs = Dofs::new(&model.constraints.mask);
    if dofs.len == 0 {
        return Err(Error::input(
            InputKind::Value,
            format!(
            "every degree of freedom of the {} nodes is prescribed by the boundaries: nothing to \
             solve; constrain fewer components",
            model.nodes.len()
        ),
        ));
    }
    let rows: Vec<crate::solver::LinearConstraint> = model
        .corrector
        .as_ref()
        .and_then(|c| c.linear_constraints(1.0))
        .unwrap_or_default();
    let reuse = cache.as_ref().is_some_and(|c| {
        c.dofs.index == dofs.index && c.tangent.offsets.len() == model.nodes.len() + 1
    });
    let mut c = match cache.take() {
        Some(c) if reuse => c,
        _ => {
            let mut cliques: Vec<Vec<u32>> = rows
                .iter()
                .map(|r| r.row.iter().map(|&(j, _)| j).collect())
                .collect();
            if let Some(ct) = model.contact.as_ref() {
                for b in 0..ct.len() {
                    for p in ct.points_of(b) {
                        if p.row.len() > 1 {
                            cliques.push(p.row.iter().map(|&(j, _)| j).collect());
                        }
                    }
                }
            }
            let tangent = Tangent::new(model, &cliques, true);
            let est = Factor::estimate_bytes(&tangent, &dofs, 25.0);
            crate::memory::check(
                (est + tangent.bytes(model.points.len())) as f64,
                "the static solve's tangent and factor",
                "use solver.mode = \"relaxation\", which needs no factor, or a coarser discretization",
            )?;
            let factor = Factor::new(&tangent, &dofs, &model.nodes)?;
            Cache {
                tangent,
                factor,
                dofs,
            }
        }
    };
    c.factor.factorizations = 0;
    c.factor.single_factorizations = 0;
    c.factor.modified_factorizations = 0;
    c.factor.peak_bytes = c.factor.bytes();
    c.factor.factor_seconds = 0.0;
    let mut st = Newton::new(model, s, &mut c, start);
    st.rows = rows;
    st.lambda = vec![0.0; st.rows.len()];
    if let Some(ct) = st.model.contact.as_ref() {
        for b in 0..ct.len() {
            for i in 0..ct.points_of(b).len() {
                st.touch.push((b as u32, i as u32));
            }
        }
    }
    st.t_lambda = vec![0.0; st.touch.len()];
    st.t_state = vec![(0.0, Vector3::zeros(), 0.0); st.touch.len()];
    st.t_hint = vec![None; st.touch.len()];
    let mut result = st.run(&mut sink);
    if result.is_ok() && s.refresh_factor && st.converged && !st.kept_contracting {
        st.assemble();
        result = st.refactor(false).map(|_| ());
    }
    let out = result.map(|()| st.finish());
    *cache = Some(c);
    out
}

/// The state of one static solve.
struct Newton<'a, M: Material> {
    model: &'a mut Model<M>,
    s: &'a Settings,
    c: &'a mut Cache,
    start: Instant,
    u: Vec<Vector3<f64>>,
    f: Vec<Vector3<f64>>,
    /// The internal forces alone where `f` also holds constraint or contact forces (empty
    /// otherwise): the work done on the body is theirs.
    f_int: Vec<Vector3<f64>>,
    fe: Vec<Vector3<f64>>,
    /// Scratch nodal vectors.
    t0: Vec<Vector3<f64>>,
    t1: Vec<Vector3<f64>>,
    report: StaticReport,
    force_evaluations: usize,
    history: Vec<HistoryRow>,
    stages: Vec<Stage>,
    frames: Vec<(f64, Vec<Vector3<f64>>)>,
    external_work: f64,
    peak_force: f64,
    converged: bool,
    notes: Vec<String>,
    min_j: (f64, usize),
    /// The kept factor is of a tangent this many assemblies old (Modified: refactor policy).
    fresh: bool,
    /// CG's last iterate where it did not converge ([`Self::pcg`]).
    cg_partial: Vec<f64>,
    /// The tangent held is of a state given up (a rejected load step's), not near u.
    tangent_stale: bool,
    /// So is the kept factor: neither a modified-Newton step nor a preconditioner from it.
    factor_stale: bool,
    /// Factorizations made up to the end of the load step's predictor (a factor of its
    /// start): one made after it is of a state a rejected step gives up.
    predictor_factorizations: usize,
    /// Newton iterations of the last load step.
    last_iterations: usize,
    /// The load step under way is a retry with the diagonal shift ([`SHIFT`]).
    shifted: bool,
    /// The last load step failed by stalling (its residual no longer falling, its
    /// iterations or multiplier rounds used up, no descent along the direction), not by
    /// inverting an element or diverging: the failures the shift can mend.
    stalled: bool,
    /// The load step under way ends short of a stage or the full load.
    loose: bool,
    /// The last (at most three) converged states on the load path: (load fraction, u).
    path: Vec<(f64, Vec<Vector3<f64>>)>,
    /// The smallest volume ratio J at the last of them.
    path_j: f64,
    /// (chord length along the path, u, F_int) at the last (at most three) history rows, for
    /// the work's quadrature ([`work_on_parabola`](record::work_on_parabola)); and the work
    /// of the first interval as taken by a trapezoid, until a third row lets the parabola
    /// take it.
    work_state: Vec<(f64, Vec<Vector3<f64>>, Vec<Vector3<f64>>)>,
    first_trapezoid: Option<f64>,
    peak_work: f64,
    sink_seconds: f64,
    last_progress: Instant,
    /// Linear constraints (meshless essential boundaries) by an augmented Lagrangian: the
    /// rows with their targets at the load step's end, multipliers (N) and penalties (N/m).
    rows: Vec<crate::solver::LinearConstraint>,
    lambda: Vec<f64>,
    penalty: Vec<f64>,
    /// Rigid contact by an augmented Lagrangian with an active set: per candidate point
    /// (body, point), its multiplier (N), penalty (N/m), and at the last evaluation its depth
    /// (m), push direction and force g = max(0, lambda + k depth) (N).
    touch: Vec<(u32, u32)>,
    t_lambda: Vec<f64>,
    t_penalty: Vec<f64>,
    t_state: Vec<(f64, Vector3<f64>, f64)>,
    /// Per candidate point, the push direction it had in contact at the last equilibrium: a
    /// Newton step may carry a point under a flat punch deeper than its distance to the
    /// punch's side, which would push it out sideways onto another branch.
    t_hint: Vec<Option<Vector3<f64>>>,
    /// Per candidate point, whether it pushed at the last tangent.
    t_pushing: Vec<bool>,
    tau_now: f64,
    /// The curve every changing input follows, where they share one that rises and is not
    /// the ramp ([`path_curve`]): the load steps are then taken in its factor, the share of
    /// the final load, and mapped back to load fractions.
    path_curve: Option<LoadCurve>,
    /// The last load step ended on modified-Newton steps with the kept factor that still
    /// contracted ([`CHEAP_CONTRACTION`]).
    kept_contracting: bool,
    /// Iterations within which a load step's residual must halve, and in all: with rigid
    /// contact whose bodies all stay where they are, [`CONTACT_STALL_ITERATIONS`] and
    /// [`CONTACT_MAX_ITERATIONS`]; otherwise [`STALL_ITERATIONS`] and [`MAX_ITERATIONS`].
    stall_window: usize,
    iteration_limit: usize,
}

impl<'a, M: Material> Newton<'a, M> {
    fn new(model: &'a mut Model<M>, s: &'a Settings, c: &'a mut Cache, start: Instant) -> Self {
        let n = model.nodes.len();
        let u = match &s.warm_start {
            Some(w) if w.u.len() == n => w.u.clone(),
            _ => vec![Vector3::zeros(); n],
        };
        let report = StaticReport {
            variant: s.static_variant.name().into(),
            dofs: c.dofs.len,
            ordering: c.factor.ordering.into(),
            matrix_nonzeros: c.factor.matrix_nonzeros(),
            factor_nonzeros: c.factor.factor_nonzeros(),
            factor_bytes: c.bytes(model.points.len()),
            symbolic_seconds: c.factor.symbolic_seconds,
            ..Default::default()
        };
        let path_curve = path_curve(model);
        let resting_contact = model
            .contact
            .as_ref()
            .is_some_and(|ct| ct.motion_curves().next().is_none());
        let (stall_window, iteration_limit) = if resting_contact {
            (CONTACT_STALL_ITERATIONS, CONTACT_MAX_ITERATIONS)
        } else {
            (STALL_ITERATIONS, MAX_ITERATIONS)
        };
        Newton {
            model,
            s,
            c,
            start,
            u,
            f: vec![Vector3::zeros(); n],
            f_int: Vec::new(),
            fe: vec![Vector3::zeros(); n],
            t0: vec![Vector3::zeros(); n],
            t1: vec![Vector3::zeros(); n],
            report,
            force_evaluations: 0,
            history: Vec::new(),
            stages: Vec::new(),
            frames: Vec::new(),
            external_work: 0.0,
            peak_force: 0.0,
            converged: false,
            notes: Vec::new(),
            min_j: (1.0, 0),
            fresh: false,
            shifted: false,
            stalled: false,
            last_iterations: 0,
            loose: false,
            path: Vec::new(),
            path_j: 1.0,
            work_state: Vec::new(),
            first_trapezoid: None,
            peak_work: 0.0,
            sink_seconds: 0.0,
            last_progress: Instant::now(),
            rows: Vec::new(),
            lambda: Vec::new(),
            penalty: Vec::new(),
            touch: Vec::new(),
            t_lambda: Vec::new(),
            t_penalty: Vec::new(),
            t_state: Vec::new(),
            t_hint: Vec::new(),
            t_pushing: Vec::new(),
            tau_now: 0.0,
            path_curve,
            kept_contracting: false,
            cg_partial: Vec::new(),
            tangent_stale: false,
            // A cold solve of a session starts from the unloaded state's own tangent, as a
            // fresh one does: the kept factor of the last equilibrium (a ball pressed 24 mm into
            // the cube) sent the first steps of the cube at 25 mm down another path, which
            // stopped unconverged at -1.07 N against 0.84 N.
            factor_stale: s.warm_start.is_none(),
            predictor_factorizations: 0,
            stall_window,
            iteration_limit,
        }
    }

    /// The load fraction tau (the curves' argument) at which the loads reach the share
    /// `lam` of their final values along the path ([`Self::path_curve`]); `lam` itself
    /// without one.
    fn tau_of(&self, lam: f64) -> f64 {
        match &self.path_curve {
            Some(c) => c.fraction_at(lam),
            None => lam,
        }
    }

    /// The share of the final load at load fraction `tau` (the inverse of [`Self::tau_of`]).
    fn lam_of(&self, tau: f64) -> f64 {
        match &self.path_curve {
            Some(c) => (c.value(tau) / c.value(1.0)).clamp(0.0, 1.0),
            None => tau,
        }
    }

    /// Internal and external forces at `u` and load fraction `tau` into `f`, `fe`; returns
    /// the smallest J over the points.
    fn forces(&mut self, tau: f64) -> f64 {
        let m = &mut *self.model;
        m.forces.compute(&m.points, &m.slots, &self.u, &mut self.f);
        self.force_evaluations += 1;
        if !self.rows.is_empty() || m.contact.is_some() {
            self.f_int.clone_from(&self.f);
        }
        self.fe.iter_mut().for_each(|x| *x = Vector3::zeros());
        m.loads.apply(&self.u, tau, &mut self.fe);
        self.min_j = m.forces.min_j();
        for (i, lc) in self.rows.iter().enumerate() {
            // The multiplier through the constraint's spread (EBCIEM's V), the penalty through
            // the row, as the tangent has it (k Phi^T Phi): at convergence the violation is
            // below the tolerance and the multipliers carry the whole constraint force.
            let (lam, pen) = (
                self.lambda[i],
                self.penalty.get(i).copied().unwrap_or(0.0) * violation(lc, &self.u),
            );
            match &lc.spread {
                Some(v) => {
                    for &(j, w) in v {
                        self.f[j as usize][lc.axis] += w * lam;
                    }
                    for &(j, w) in &lc.row {
                        self.f[j as usize][lc.axis] += w * pen;
                    }
                }
                None => {
                    for &(j, w) in &lc.row {
                        self.f[j as usize][lc.axis] += w * (lam + pen);
                    }
                }
            }
        }
        self.tau_now = tau;
        if let Some(ct) = self.model.contact.as_ref() {
            use rayon::prelude::*;
            let (u, touch, hint) = (&self.u, &self.touch, &self.t_hint);
            let (lam, pen) = (&self.t_lambda, &self.t_penalty);
            self.t_state
                .par_iter_mut()
                .enumerate()
                .with_min_len(256)
                .for_each(|(k, st)| {
                    let (b, i) = (touch[k].0 as usize, touch[k].1 as usize);
                    let (depth, n) = ct.depth_of_hinted(
                        b,
                        &ct.points_of(b)[i],
                        u,
                        tau,
                        hint.get(k).copied().flatten(),
                    );
                    let g = (lam[k] + pen.get(k).copied().unwrap_or(0.0) * depth).max(0.0);
                    *st = (depth, n, g);
                });
            // In point order: the sums do not depend on the thread count.
            for (k, &(b, i)) in self.touch.iter().enumerate() {
                let (_, n, g) = self.t_state[k];
                if g > 0.0 {
                    for &(j, w) in &ct.points_of(b as usize)[i as usize].row {
                        self.f[j as usize] -= n * (w * g);
                    }
                }
            }
        }
        self.min_j.0
    }

    /// The point of smallest J at the last force evaluation, as messages name it: "0.071 at
    /// integration point 84910 near (x, y, z) m" (one-point FE meshes number points as their
    /// elements).
    fn weakest_point(&self) -> String {
        let (j, p) = self.min_j;
        let m = &*self.model;
        if p >= m.point_ids.len() {
            return format!("{j:.3}");
        }
        let near = m.point_centroid(p);
        format!(
            "{j:.3} at integration point {} near ({:.4e}, {:.4e}, {:.4e}) m",
            m.point_ids[p], near.x, near.y, near.z
        )
    }

    /// Largest |F_ext - F_int| at a free DOF, and the largest nodal force (the scale).
    fn residual_norm(&self) -> (f64, f64) {
        let (mut r, mut scale) = (0.0f64, 0.0f64);
        for (i, ix) in self.c.dofs.index.iter().enumerate() {
            for k in 0..3 {
                scale = scale.max(self.f[i][k].abs()).max(self.fe[i][k].abs());
                if ix[k] != u32::MAX {
                    r = r.max((self.fe[i][k] - self.f[i][k]).abs());
                }
            }
        }
        (r, scale.max(self.peak_force))
    }

    fn assemble(&mut self) {
        let t0 = Instant::now();
        self.c.tangent.assemble(self.model, &self.u);
        self.tangent_stale = false;
        if !self.rows.is_empty() {
            self.set_penalties();
            self.add_constraint_stiffness();
        }
        if !self.touch.is_empty() {
            let fresh = self.t_penalty.is_empty();
            self.set_contact_penalties();
            if fresh {
                // The forces of this state with the penalties now known.
                let tau = self.tau_now;
                self.forces(tau);
                self.force_evaluations -= 1;
            }
            self.add_contact_stiffness();
        }
        // Where the contact's active set changed since the last tangent, this one is
        // shifted too: the penalty's kink makes the tangent of one set a poor model across
        // the change, and the points let go can slide along a near-singular direction (the
        // coupled tet cube under a plate, stepped along the smooth curve: 119 -> 82 -> 103
        // points pushing from one iteration to the next, and updates of 5 mm for a plate
        // 0.6 mm down, until the step shrank below the shortest). A settled set (every
        // point of the fe cube pushing from the first iteration) keeps Newton's tangent.
        let flipped = if self.touch.is_empty() {
            false
        } else {
            let n = self.t_state.len();
            let mut changed = self.t_pushing.len() != n;
            self.t_pushing.resize(n, false);
            for (was, st) in self.t_pushing.iter_mut().zip(&self.t_state) {
                changed |= *was != (st.2 > 0.0);
                *was = st.2 > 0.0;
            }
            changed
        };
        if self.shifted || flipped {
            let r = self
                .report
                .residual_history
                .last()
                .map_or(1.0, |h| h.residual);
            let share = SHIFT * r.min(1.0);
            for a in 0..self.u.len() {
                let d = self.c.tangent.diagonal(a).trace() / 3.0 * share;
                self.c.tangent.add(a, a, &(Matrix3::identity() * d));
            }
        }
        self.report.assemblies += 1;
        self.force_evaluations += 1;
        self.report.assembly_seconds += t0.elapsed().as_secs_f64();
    }

    /// The run: from a warm start one step at the full load, and where that does not converge
    /// (a change too large to take from there) the load steps from the unloaded state, said in
    /// the notes, as [`crate::simulation::Session`] does for relaxation; otherwise load steps
    /// to each stage and to the full load.
    fn run(&mut self, sink: &mut Option<&mut FrameSink<'_, M>>) -> Result<()> {
        if self.s.warm_start.is_none() {
            return self.run_from(false, sink);
        }
        match self.run_from(true, sink) {
            Err(Error::Unstable(msg)) => {
                self.notes.push(format!(
                    "static solve: the warm start from the last equilibrium failed ({msg}); \
                     solved from the unloaded state"
                ));
                self.u.iter_mut().for_each(|x| *x = Vector3::zeros());
                self.report.from_unloaded = true;
                self.tangent_stale = true;
                self.factor_stale = true;
                self.lambda.iter_mut().for_each(|x| *x = 0.0);
                self.t_lambda.iter_mut().for_each(|x| *x = 0.0);
                self.t_hint.iter_mut().for_each(|x| *x = None);
                self.path.clear();
                self.shifted = false;
                self.history.clear();
                self.work_state.clear();
                self.first_trapezoid = None;
                self.external_work = 0.0;
                self.peak_work = 0.0;
                self.run_from(false, sink)
            }
            r => r,
        }
    }

    /// Load steps from the unloaded state, or (`warm`) one step at the full load.
    /// The loop runs in the share of the final load (`lam`, [`Self::tau_of`]); the loads,
    /// the stages, the history and the frames take load fractions.
    fn run_from(&mut self, warm: bool, sink: &mut Option<&mut FrameSink<'_, M>>) -> Result<()> {
        let mut tau = if warm { 1.0 } else { 0.0 };
        self.forces(self.tau_of(tau));
        if warm {
            self.warm_contact_multipliers();
        }
        self.keep_faces();
        self.peak_force = self.residual_norm().1;
        self.record_row(self.tau_of(tau));
        if !warm {
            self.frame(0.0, sink)?;
        }
        // Stages in the load's share, each kept with its load fraction.
        let stages: Vec<(f64, f64)> = self
            .s
            .stages
            .iter()
            .copied()
            .filter(|&l| l > 0.0 && l < 1.0 && !warm)
            .map(|l| (self.lam_of(l), l))
            .collect();
        let mut targets: Vec<f64> = stages.iter().map(|s| s.0).collect();
        targets.push(1.0);
        if !warm {
            self.path = vec![(tau, self.u.clone())];
            self.path_j = self.min_j.0;
        }
        let longest = self.contact_step_limit();
        let mut dtau = longest;
        let mut failed_span = f64::INFINITY;
        let mut cuts_in_row = 0;
        for &target in &targets {
            let mut first = true;
            while tau < target || (first && warm) {
                first = false;
                crate::interrupt::check(|| {
                    format!("in the static solve at {:.1} % of the load", 100.0 * tau)
                })?;
                // The span left to the stage in equal steps no longer than dtau: a short
                // last step costs as many Newton iterations as a full one (c3: 0.5688 ->
                // 0.6 took 5).
                let left = target - tau;
                let steps = (left / dtau - 1e-9).ceil().max(1.0);
                let next = if steps <= 1.0 {
                    target
                } else {
                    tau + left / steps
                };
                let saved = self.u.clone();
                // The residual's scale from accepted states only: the MNI brain's first
                // attempt at 1.6 % of gravity pushed 1,367 points into the skull, and the
                // forces of that rejected predictor let the retry pass as converged (residual
                // 2.6e-4 of them) with the brain 1 um from where it started, its sag ~mm.
                let saved_peak = self.peak_force;
                self.loose = next < target;
                match self.load_step(tau, next)? {
                    true => {
                        if self.shifted {
                            self.report.shifted_converged += 1;
                            self.shifted = false;
                        }
                        if next > tau {
                            if self.path.len() == 3 {
                                self.path.remove(0);
                            }
                            self.path.push((next, self.u.clone()));
                            self.path_j = self.min_j.0;
                        }
                        tau = next;
                        cuts_in_row = 0;
                        self.keep_faces();
                        self.report.load_steps += 1;
                        self.report.load_reached = tau;
                        self.record_row(self.tau_of(tau));
                        self.progress(tau);
                    }
                    false => {
                        self.u = saved;
                        self.tangent_stale = true;
                        self.factor_stale |=
                            self.c.factor.factorizations != self.predictor_factorizations;
                        self.peak_force = saved_peak;
                        if self.stalled && !self.shifted && cuts_in_row >= SHIFT_AFTER_CUTS {
                            self.shifted = true;
                            self.report.shifted_retries += 1;
                            continue;
                        }
                        self.shifted = false;
                        // A warm start's one step has no shorter span to cut to (before
                        // this test came first, the stop rule reported it as the last
                        // equilibrium at 100 % of the load, not converged).
                        if warm {
                            return Err(Error::Unstable(
                                "its one step at the full load did not converge".into(),
                            ));
                        }
                        self.report.cuts += 1;
                        cuts_in_row += 1;
                        if let Some(why) = give_up(cuts_in_row, next - tau) {
                            self.forces(self.tau_of(tau));
                            let (r, scale) = self.residual_norm();
                            self.report.stop = Some(format!(
                                "static solve: a load step of {:.2e} of the load from {:.4} % did not converge \
                                 {why}; the last equilibrium is at {:.4} % of the load (residual \
                                 {:.2e} of the largest nodal force; smallest J {}), written as the result; \
                                 the body may buckle, an element may invert, or the load may exceed what \
                                 the material holds: refine or smooth the mesh there, or try \
                                 solver.mode = \"relaxation\"",
                                next - tau,
                                100.0 * tau,
                                100.0 * tau,
                                r / scale.max(f64::MIN_POSITIVE),
                                self.weakest_point()
                            ));
                            self.converged = false;
                            return Ok(());
                        }
                        failed_span = failed_span.min(next - tau);
                        dtau = (next - tau) * 0.5;
                        continue;
                    }
                }
                // Grow after an easy step, but not back to a span that failed.
                if self.last_iterations <= 3 {
                    dtau = (dtau * 2.0).min(failed_span * 0.75).min(longest);
                }
            }
            if target < 1.0 {
                let at = stages
                    .iter()
                    .find(|s| s.0 == target)
                    .map_or(target, |s| s.1);
                self.stage(at)?;
                self.frame(at, sink)?;
            }
        }
        self.converged = true;
        self.frame(1.0, sink)?;
        Ok(())
    }

    /// One load step from the load's share `lam0` to `lam1` (equal for a warm start): the predictor, then
    /// Newton iterations with a line search. Ok(false) when it does not converge (the caller
    /// restores u and cuts the step).
    fn load_step(&mut self, lam0: f64, lam1: f64) -> Result<bool> {
        self.stalled = false;
        let tau1 = self.tau_of(lam1);
        let n = self.u.len();
        self.set_targets(tau1);
        if (!self.rows.is_empty() && self.penalty.is_empty())
            || (!self.touch.is_empty() && self.t_penalty.is_empty())
        {
            self.forces(tau1);
            self.assemble();
        }
        // A kept factor of an earlier state (a warm start's, the previous load step's) often
        // still contracts: modified-Newton steps with it cost a force evaluation and two
        // triangular solves, no assembly. The first that does not cut the residual by
        // CHEAP_CONTRACTION ends them for this load step (brain-shift's warm re-solve: 0.61 s
        // with a tangent per iteration).
        let mut cheap = self.s.static_variant == Variant::NewtonKrylov
            && !self.factor_stale
            && self.c.factor.kind().is_some_and(|k| k != Kind::Modified);
        let Some(mut last_update) = self.predict(lam0, lam1, cheap)? else {
            return Ok(false);
        };
        let mut rhs = vec![0.0; self.c.dofs.len];
        let (r0, scale0) = self.residual_norm();
        self.peak_force = self.peak_force.max(scale0);
        self.push_residual(lam1, 0, r0, scale0, last_update);
        let mut r_prev = r0;
        let mut trail = vec![r0];
        // Newton iterations count from the last multiplier update: the rounds converge
        // linearly (the meshless cube under a plate: the residual after each 2.2e-5, 7.4e-6,
        // 3.6e-8, 5.5e-9, ...) and used up the step's iterations at 25 in all.
        let (mut round_start, mut rounds) = (0, 0);
        // The residual at the first iteration of the current round.
        let mut round_r0: Option<f64> = None;
        'newton: for it in 1.. {
            // Ctrl-C within a Newton iteration, not only between load steps: the exact cube
            // at 5 mm solves in one load step of over a second (the Python test's 1.3 s).
            crate::interrupt::check(|| {
                format!(
                    "in the static solve at {:.1} % of the load, Newton iteration {it}",
                    100.0 * lam1
                )
            })?;
            self.last_iterations = it;
            let (r, scale) = self.residual_norm();
            if !r.is_finite() {
                return Ok(false);
            }
            // Not converging: no halving of the residual over a window of iterations.
            let window = self.stall_window;
            if trail.len() >= window + 1
                && r > 0.5 * trail[trail.len() - window - 1]
                && !self.is_converged(r, scale, last_update)
            {
                self.report.newton_iterations += it;
                self.stalled = true;
                return Ok(false);
            }
            trail.push(r);
            // As relaxation's correction refuses it at the first penetration: a sphere pushed
            // through a fixed face otherwise converged with the held node outside it, a slide
            // of about 22 mm at that depth.
            if let Some(e) = self.contact_conflict(tau1) {
                return Err(e);
            }
            let round_r = *round_r0.get_or_insert(r);
            let converged = self.is_converged(r, scale, last_update);
            // After the first round, the multipliers are updated once the iterations have cut
            // the residual the last update left by ROUND_CONTRACTION, not at convergence.
            if converged || (rounds >= 1 && r <= ROUND_CONTRACTION * round_r) {
                // The constraints met to the tolerance, or their multipliers updated
                // (lambda += k c) and the iterations go on.
                let contact_tol = self
                    .model
                    .contact
                    .as_ref()
                    .map_or(f64::INFINITY, |c| c.tolerance());
                let pushing = self.contact_unsettled(contact_tol);
                // The constraints to a hundredth of the tolerance: relaxation's corrector
                // meets them to rounding, and a violation of the tolerance itself moved the
                // meshless cube's corner by as much.
                let violated = self.worst_violation() > CONSTRAINT_SHARE * self.s.tolerance;
                if (violated || pushing) && !self.loose {
                    rounds += 1;
                    if rounds > MAX_ROUNDS {
                        self.report.newton_iterations += it;
                        self.stalled = true;
                        return Ok(false);
                    }
                    round_start = it;
                    self.update_multipliers();
                    for k in 0..self.touch.len() {
                        self.t_lambda[k] = self.t_state[k].2;
                    }
                    self.forces(tau1);
                    trail.clear();
                    trail.extend(std::iter::repeat_n(f64::INFINITY, it + 1));
                    last_update = f64::INFINITY;
                    round_r0 = None;
                    continue;
                }
                if converged {
                    self.report.newton_iterations += it - 1;
                    self.last_iterations = it - 1;
                    self.kept_contracting = cheap;
                    return Ok(true);
                }
            }
            if it - round_start >= self.iteration_limit {
                self.report.newton_iterations += it;
                self.stalled = true;
                return Ok(false);
            }
            // The direction.
            let cheap_step = cheap;
            match self.s.static_variant {
                _ if cheap_step => {}
                Variant::Modified => {
                    if self.fresh && r > 0.5 * r_prev && it > 1 {
                        self.fresh = false;
                    }
                    if !self.fresh {
                        self.assemble();
                        self.refactor(false)?;
                    }
                }
                _ => self.assemble(),
            }
            for i in 0..n {
                self.t0[i] = self.fe[i] - self.f[i];
            }
            self.c.dofs.gather(&self.t0, &mut rhs);
            let r_free = rhs.clone();
            let eta = (0.9 * (r / r_prev).powi(2)).clamp(CG_TOLERANCE, ETA_MAX);
            // The first iteration of a load step with the kept factor of its start: where CG
            // does not converge with it, its last iterate is tried before a new factor, so
            // that a step the early cut rejects keeps the start's factor for the shorter
            // retry's predictor (cylinder-mixed: 3 factorizations of 480 MB to 1).
            let mut probing = false;
            if cheap_step {
                self.kept_solve(&mut rhs);
            } else if it == 1
                && lam1 > lam0
                && self.s.static_variant == Variant::NewtonKrylov
                && matches!(self.c.factor.kind(), Some(Kind::Llt | Kind::Ldlt))
            {
                let t0 = Instant::now();
                let mut x = rhs.clone();
                if self.pcg(&mut x, eta, linear::Cg::Probe) {
                    rhs = x;
                } else {
                    rhs = std::mem::take(&mut self.cg_partial);
                    probing = true;
                }
                self.report.solve_seconds += t0.elapsed().as_secs_f64();
            } else {
                self.linear_solve(&mut rhs, eta)?;
            }
            let du = rhs.clone();
            // Line search on g(a) = du . r(u + a du): zero at the minimum along du.
            let g0: f64 = du.iter().zip(&r_free).map(|(a, b)| a * b).sum();
            let base = self.u.clone();
            let mut alpha = 1.0;
            let mut tries = 0;
            loop {
                self.c.dofs.scatter(&du, &mut self.t0);
                for i in 0..n {
                    self.u[i] = base[i] + self.t0[i] * alpha;
                }
                let j = self.forces(tau1);
                if j > 0.0 {
                    break;
                }
                tries += 1;
                if cheap_step && tries > 2 {
                    // The kept factor's direction inverts elements: back to the start of the
                    // iteration, with the tangent from here on.
                    self.undo(&base, tau1, &mut trail);
                    cheap = false;
                    continue 'newton;
                }
                // Early in a load step, a direction that still inverts an element when cut
                // to an eighth says the step is too long: cut the step now rather than
                // after three iterations of crawling (brain-indentation: five failed load
                // steps took 8 s of 18.8).
                if tries > 8 || (tries > 3 && it <= 2 && lam1 > lam0) {
                    self.report.newton_iterations += it;
                    return Ok(false);
                }
                alpha *= 0.5;
            }
            if probing && !(g0 > 0.0) {
                // CG's iterate is no descent direction: the full solve instead (the next
                // iteration is not the first, so it does not probe again).
                self.undo(&base, tau1, &mut trail);
                continue 'newton;
            }
            if g0 > 0.0 {
                match self.line_search(&base, &du, g0, alpha, tau1) {
                    Some(a) => alpha = a,
                    None if probing => {
                        self.undo(&base, tau1, &mut trail);
                        continue 'newton;
                    }
                    None => {
                        self.report.newton_iterations += it;
                        self.stalled = true;
                        return Ok(false);
                    }
                }
            }
            last_update = alpha * du.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            {
                log::debug!(
                    "    alpha {alpha:.3e} g0 {g0:.3e} min J {:.4} at point {}",
                    self.min_j.0,
                    self.min_j.1
                );
            }
            let (r_new, scale_new) = self.residual_norm();
            self.push_residual(lam1, it, r_new, scale_new, last_update);
            // A first Newton iteration of a load step (with the current tangent, not the
            // kept factor's modified step) that the line search cut to a short step and that
            // left the residual as large as the largest force says the step is too long: cut
            // it now, before more factorizations (cylinder-mixed's full-load first step: 4
            // factorizations of 480 MB over 3 iterations, steps 0.06-0.13).
            if it == 1
                && lam1 > lam0
                && !cheap_step
                && alpha < EARLY_CUT_ALPHA
                && r_new > 0.5 * scale_new
            {
                log::debug!(
                    "    early cut: step {alpha:.3e}, residual {:.3e}",
                    r_new / scale_new
                );
                self.report.newton_iterations += it;
                return Ok(false);
            }
            if cheap_step && r_new > CHEAP_CONTRACTION * r {
                cheap = false;
                if r_new > r {
                    // Worse than where it started (a factor of a state far from this one,
                    // as the load step's start): undone, and the tangent from here on.
                    self.undo(&base, tau1, &mut trail);
                    continue 'newton;
                }
            }
            if !(r_new < 1e8 * r0.max(1e-300)) {
                self.report.newton_iterations += it;
                return Ok(false);
            }
            r_prev = r;
        }
        Ok(false)
    }

    /// Back to `base` (the iteration's start) at load fraction `tau`, its residual taken off
    /// `trail`: a kept-factor step that did not pay is undone.
    fn undo(&mut self, base: &[Vector3<f64>], tau: f64, trail: &mut Vec<f64>) {
        self.u.copy_from_slice(base);
        self.forces(tau);
        trail.pop();
    }

    /// The step length along `du` from `base`, u left there with its forces: `alpha` (the
    /// longest that inverts no element) where the slope g(a) = du . r(base + a du) has not
    /// turned below -LINE_SEARCH g(0); otherwise a root of g bracketed in [0, alpha] by
    /// regula falsi (Illinois), to |g| <= LINE_SEARCH g(0) in at most LINE_SEARCH_EVALUATIONS
    /// force evaluations. The energy is a potential along du (g its derivative), so this is a
    /// minimisation along the direction; a force evaluation costs little against the
    /// factorization that made du (MNI: 20 ms against 2.3 s), and one secant step clamped to
    /// a tenth of the step left contact runs creeping at 10 % a Newton iteration. None when a
    /// trial point inverts an element.
    fn line_search(
        &mut self,
        base: &[Vector3<f64>],
        du: &[f64],
        g0: f64,
        alpha: f64,
        tau: f64,
    ) -> Option<f64> {
        let g1 = self.slope(du);
        if g1 >= -LINE_SEARCH * g0 {
            return Some(alpha);
        }
        self.c.dofs.scatter(du, &mut self.t0);
        let (mut lo, mut g_lo, mut hi, mut g_hi) = (0.0, g0, alpha, g1);
        let mut side = 0i8;
        let mut a = alpha;
        for _ in 0..LINE_SEARCH_EVALUATIONS {
            let span = hi - lo;
            a = (lo + span * g_lo / (g_lo - g_hi)).clamp(lo + 1e-3 * span, hi - 1e-3 * span);
            for i in 0..base.len() {
                self.u[i] = base[i] + self.t0[i] * a;
            }
            if !(self.forces(tau) > 0.0) {
                return None;
            }
            let g = self.slope(du);
            if g.abs() <= LINE_SEARCH * g0 {
                return Some(a);
            }
            // Illinois: the end kept twice in a row has its slope halved.
            if g > 0.0 {
                (lo, g_lo) = (a, g);
                if side == 1 {
                    g_hi *= 0.5;
                }
                side = 1;
            } else {
                (hi, g_hi) = (a, g);
                if side == -1 {
                    g_lo *= 0.5;
                }
                side = -1;
            }
        }
        Some(a)
    }

    /// du . (F_ext - F_int) over the free DOFs at the current forces: the energy's slope
    /// along du (in DOF order).
    fn slope(&self, du: &[f64]) -> f64 {
        let mut g = 0.0;
        for (i, ix) in self.c.dofs.index.iter().enumerate() {
            for k in 0..3 {
                if ix[k] != u32::MAX {
                    g += (self.fe[i][k] - self.f[i][k]) * du[ix[k] as usize];
                }
            }
        }
        g
    }

    /// Converged: the last update below solver.tolerance and the residual below
    /// [`RESIDUAL_TOLERANCE`] of the force scale, or the residual at rounding level.
    fn is_converged(&self, r: f64, scale: f64, update: f64) -> bool {
        let scale = scale.max(self.peak_force).max(f64::MIN_POSITIVE);
        (update <= self.s.tolerance && r <= RESIDUAL_TOLERANCE * scale)
            || r <= 1e-13 * scale
            || (self.loose && r <= SUBSTEP_TOLERANCE * scale)
    }
}

/// The curve the static solve steps along: the one every changing input (a boundary with
/// a prescribed value other than 0, a load, a moving rigid body) follows, where they share
/// one that rises from 0 ([`LoadCurve::is_rising`]) other than the ramp. The static answer
/// at the full load does not depend on the path, but the steps do: equal steps in the load
/// fraction along the smooth curve are 1.9x the mean share of the load at mid-path and next
/// to none at its ends, and the load path extrapolated over them ran ahead of the tissue (the
/// meshless cube under a plate read from a file: the predictor at 75 % of the load put the
/// cube's top 6 mm below the plate, which the next Newton update carried up past the middle
/// of the plate).
fn path_curve<M: Material>(model: &Model<M>) -> Option<LoadCurve> {
    let moving = |b: &crate::bc::Boundary| {
        b.components.iter().flatten().any(|&v| v != 0.0)
            || b.node_values
                .as_ref()
                .is_some_and(|v| v.iter().flatten().any(|&x| x != 0.0))
    };
    let mut curves = model
        .boundaries
        .iter()
        .filter(|b| moving(b))
        .map(|b| &b.curve)
        .chain(model.loads.curves())
        .chain(model.contact.iter().flat_map(|c| c.motion_curves()));
    let first = curves.next()?;
    (first.is_rising() && *first != LoadCurve::Ramp && curves.all(|c| c == first))
        .then(|| first.clone())
}

#[cfg(test)]
mod tests {
    use super::predictor::lagrange_weights;
    use super::{give_up, MAX_CUTS, MIN_STEP};

    /// The solve stops after MAX_CUTS cuts in a row, or when a cut would take the load step
    /// under MIN_STEP; each reason is said.
    #[test]
    fn the_solve_gives_up_before_the_load_step_crawls() {
        assert!(give_up(1, 0.2).is_none());
        assert!(give_up(MAX_CUTS, 4.0 * MIN_STEP).is_none());
        assert!(give_up(MAX_CUTS + 1, 0.2)
            .unwrap()
            .contains("cuts in a row"));
        // c5's crawl: a step of 1.8e-3 failed, and 9e-4 would have followed.
        let why = give_up(1, 1.8e-3).unwrap();
        assert!(why.contains("0.1 % of the load"), "{why}");
    }

    /// The predictor's weights reproduce any parabola through three unequally spaced load
    /// fractions at a fraction beyond them, and a line through two; they sum to one.
    #[test]
    fn the_predictor_extrapolates_a_parabola_exactly() {
        let p = |t: f64| 0.3 - 1.7 * t + 2.9 * t * t;
        let at = [0.1, 0.25, 0.32];
        let w = lagrange_weights(at.iter().copied(), 0.41);
        let got: f64 = at.iter().zip(&w).map(|(t, w)| w * p(*t)).sum();
        assert!((got - p(0.41)).abs() < 1e-14, "{got} {}", p(0.41));
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-14);
        let w = lagrange_weights([0.2, 0.4].into_iter(), 0.5);
        assert!(
            (w[0] + 0.5).abs() < 1e-15 && (w[1] - 1.5).abs() < 1e-15,
            "{w:?}"
        );
    }
}
