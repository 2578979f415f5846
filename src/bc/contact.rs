//! Frictionless contact between the body's surface and rigid analytic surfaces (plane, sphere,
//! cylinder) moved along a load curve, imposed kinematically inside the explicit loop.
//!
//! After each step's update, every candidate surface point whose position x = X + sum_j
//! phi_j u_j lies inside a rigid body is pushed back to its surface along the surface normal
//! by a force lambda n spread over the nodes with the same row: u_j += (a / m_j) phi_j lambda n,
//! with a the update's force coefficient (central differences: dt^2 / (1 + c dt / 2)). That
//! closes the gap exactly when lambda = depth / (a sum_j phi_j^2 / m_j): for a finite-element
//! node (phi = 1 at the node) the node moves onto the surface, as the defence-node method of
//! explicit codes does (NiftySim's contact plates); for meshless points, whose shape functions
//! do not interpolate, the correction acts on the nodal parameters through the shape functions,
//! as the EBCIEM / SEBCIEM corrections do for essential conditions (thesis chapter 4).
//! Neighbouring points share nodes, so the corrections run as Gauss-Seidel sweeps until the
//! deepest remaining penetration is below the tolerance. The contact only pushes (unilateral)
//! and leaves the tangential components free (frictionless). The force the rigid body applies
//! is the sum of lambda n over its points; no penalty stiffness enters the stable step.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::LoadCurve;
use crate::quadrature::SparseRow;
use crate::{Error, InputKind, Result};

/// A rigid surface in its reference position; the body stays outside the solid it bounds.
#[derive(Debug, Clone)]
pub enum RigidShape {
    /// The half-space behind the plane through `point` whose unit `normal` points to the body.
    Plane {
        point: Vector3<f64>,
        normal: Vector3<f64>,
    },
    /// A solid ball.
    Sphere { center: Vector3<f64>, radius: f64 },
    /// A solid cylinder of `radius` about the line through `center` along the unit `axis`,
    /// between `min` and `max` along it (from `center`; None: unbounded), with flat ends whose
    /// rims are rounded to `edge_radius` (m; 0: sharp): the points within `edge_radius` of the
    /// cylinder of radius `radius - edge_radius` between `min + edge_radius` and
    /// `max - edge_radius`.
    Cylinder {
        center: Vector3<f64>,
        axis: Vector3<f64>,
        radius: f64,
        min: Option<f64>,
        max: Option<f64>,
        edge_radius: f64,
    },
    /// The solid a closed surface encloses (a tool or the skull from a file), its depth the
    /// signed distance to the surface.
    Surface(std::sync::Arc<crate::geometry::surface_distance::SurfaceDistance>),
}

impl RigidShape {
    /// For a point `x` (m) inside the solid displaced by `d` (m): how deep it is (m) and the
    /// outward unit normal of the nearest surface. None outside.
    pub fn penetration(&self, x: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
        let (depth, n) = self.signed_depth(x, d);
        (depth > 0.0).then_some((depth, n))
    }

    /// Points of the solid in its reference position (m) that it cannot hold without holding
    /// its neighbourhood: a ball's centre, a bounded cylinder's axis at its ends and middle;
    /// none for a half-space or an unbounded cylinder (which no closed body can hold).
    pub fn core_points(&self) -> Vec<Vector3<f64>> {
        match self {
            RigidShape::Plane { .. } => Vec::new(),
            RigidShape::Sphere { center, .. } => vec![*center],
            RigidShape::Cylinder {
                center,
                axis,
                min: Some(lo),
                max: Some(hi),
                ..
            } => [*lo, 0.5 * (lo + hi), *hi]
                .iter()
                .map(|t| center + axis * *t)
                .collect(),
            RigidShape::Cylinder { .. } => Vec::new(),
            // Its vertices (up to 64, spread over the list): a tool wholly inside the tissue has
            // them all inside.
            RigidShape::Surface(tool) => {
                let p = &tool.surface().points;
                let step = p.len().div_ceil(64).max(1);
                p.iter().step_by(step).copied().collect()
            }
        }
    }

    /// Signed depth of `x` (m) in the solid displaced by `d` (m): positive inside, minus the
    /// distance to the surface outside; with the outward unit normal of the nearest surface.
    pub fn signed_depth(&self, x: &Vector3<f64>, d: &Vector3<f64>) -> (f64, Vector3<f64>) {
        self.signed_depth_hinted(x, d, None)
    }

    /// [`RigidShape::signed_depth`], but a point within a flat-ended cylinder's radius whose
    /// push direction `hint` (from the last equilibrium) is within 0.9 of an end's normal
    /// stays on that end, however deep: a static Newton step can carry a point under a punch
    /// deeper than its distance to the side wall, which would push it out sideways.
    pub fn signed_depth_hinted(
        &self,
        x: &Vector3<f64>,
        d: &Vector3<f64>,
        hint: Option<Vector3<f64>>,
    ) -> (f64, Vector3<f64>) {
        match self {
            RigidShape::Plane { point, normal } => (-(x - point - d).dot(normal), *normal),
            RigidShape::Surface(tool) => tool.contact_depth(&(x - d)),
            RigidShape::Sphere { center, radius } => {
                let r = x - center - d;
                let dist = r.norm();
                // At the centre any direction will do.
                let n = if dist > 0.0 { r / dist } else { Vector3::z() };
                (radius - dist, n)
            }
            RigidShape::Cylinder {
                center,
                axis,
                radius,
                min,
                max,
                edge_radius,
            } => {
                // A rounded rim is the sharp cylinder shrunk by the edge radius and offset by
                // it: the offset adds the radius to the exact signed distance.
                let e = *edge_radius;
                let radius = radius - e;
                let r = x - center - d;
                let s = r.dot(axis);
                let lo = min.map_or(f64::NEG_INFINITY, |m| m + e);
                let hi = max.map_or(f64::INFINITY, |m| m - e);
                let radial = r - axis * s;
                let dist = radial.norm();
                let out = if dist > 0.0 {
                    radial / dist
                } else {
                    axis.cross(&Vector3::x())
                        .try_normalize(0.0)
                        .unwrap_or(Vector3::y())
                };
                // Depths to the side and the nearer end (negative: beyond it).
                let side = radius - dist;
                if let Some(h) = hint.filter(|_| side > 0.0) {
                    let a = h.dot(axis);
                    if a > 0.9 && hi.is_finite() {
                        return (hi - s + e, *axis);
                    }
                    if a < -0.9 && lo.is_finite() {
                        return (s - lo + e, -axis);
                    }
                }
                let (end, end_n) = if s - lo < hi - s {
                    (s - lo, -axis)
                } else {
                    (hi - s, *axis)
                };
                let (depth, n) = match (side > 0.0, end > 0.0) {
                    (true, true) if side <= end => (side, out),
                    (true, true) => (end, end_n),
                    (false, true) => (side, out),
                    (true, false) => (end, end_n),
                    (false, false) => {
                        // Beyond the rim: distance to the circular edge.
                        let v = out * (-side) + end_n * (-end);
                        let l = v.norm();
                        (-l, v / l)
                    }
                };
                (depth + e, n)
            }
        }
    }
}

/// A rigid body: its surface, and its displacement `motion` (m) at curve factor 1.
#[derive(Debug, Clone)]
pub struct RigidBody {
    pub name: String,
    pub shape: RigidShape,
    pub motion: Vector3<f64>,
    pub curve: LoadCurve,
}

/// A candidate surface point: its reference position (m) and the row of nodal values that
/// gives its displacement.
#[derive(Debug, Clone)]
pub struct ContactPoint {
    pub x: Vector3<f64>,
    pub row: SparseRow,
    /// Components a boundary prescribes at the point itself (a meshless or blended boundary
    /// node there, whose correction the contact would undo); FE nodes' prescribed components
    /// are the `fixed` mask of [`Contact::correct`].
    pub held: [bool; 3],
}

/// A surface point a rigid body pushed into although the boundary conditions hold its nodes
/// along the push: the contact cannot move it, so the body would pass through the tissue.
#[derive(Debug, Clone, PartialEq)]
pub struct Conflict {
    /// The rigid body ([`Contact::names`] order).
    pub body: usize,
    /// The point's reference position, m.
    pub x: Vector3<f64>,
    /// How deep it is inside the rigid body, m.
    pub depth: f64,
    /// The node of its row with the largest weight (the prescribed one).
    pub node: u32,
    /// The direction of the push (the rigid surface's outward unit normal).
    pub normal: Vector3<f64>,
}

/// A point is held against the push when the components its nodes may move along carry less
/// than this share of the push (0 for a finite-element node prescribed along the normal).
const HELD_SHARE: f64 = 1e-6;

impl ContactPoint {
    /// Its position at nodal displacements `u`, m: x + the row's weighted displacements.
    pub fn position(&self, u: &[Vector3<f64>]) -> Vector3<f64> {
        self.row
            .iter()
            .fold(self.x, |acc, &(j, f)| acc + u[j as usize] * f)
    }

    /// The node of its row with the largest weight (the one a conflict names).
    pub fn main_node(&self) -> u32 {
        self.row
            .iter()
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
            .map_or(0, |r| r.0)
    }

    /// Whether the boundary conditions hold this point against a push along `n` (unit): the
    /// components its nodes may move along (`fixed`, per node, true where prescribed) carry
    /// less than `share` of it, weighting each node by its shape function squared, or a
    /// boundary prescribes the point itself along it. The static solve's form of the test
    /// relaxation's correction makes with the masses and [`HELD_SHARE`] ([`Conflict`]).
    pub fn held_along(&self, n: &Vector3<f64>, fixed: &[[bool; 3]], share: f64) -> bool {
        let (mut den, mut full) = (0.0, 0.0);
        for &(j, f) in &self.row {
            let free: f64 = (0..3)
                .filter(|&c| !fixed.get(j as usize).is_some_and(|m| m[c]))
                .map(|c| n[c] * n[c])
                .sum();
            den += f * f * free;
            full += f * f;
        }
        let free_at_point: f64 = (0..3).filter(|&c| !self.held[c]).map(|c| n[c] * n[c]).sum();
        let held_here = self.held.iter().any(|&h| h) && !(free_at_point > share);
        held_here || !(den > share * full)
    }
}

/// The deformable body's closed surface, as [`Contact::check_tunnelled`] deforms it.
#[derive(Debug)]
pub struct BodySurface {
    /// Reference positions of the vertices, m.
    pub vertices: Vec<Vector3<f64>>,
    /// Each vertex's displacement as a combination of nodal parameters.
    pub rows: Vec<SparseRow>,
    /// Faces (vertex indices).
    pub faces: Vec<Vec<usize>>,
}

/// Contact of the candidate points with the rigid bodies.
#[derive(Debug, Clone)]
pub struct Contact {
    bodies: Vec<RigidBody>,
    /// Candidate points of each body.
    points: Vec<Vec<ContactPoint>>,
    /// Penetration left after the sweeps that counts as closed, m.
    tolerance: f64,
    /// Every node a candidate's row reaches, ascending.
    touched: Vec<u32>,
    /// Force each body applied to the body in the last correction, N.
    forces: Vec<Vector3<f64>>,
    /// Contact force on each node in the last correction, N (for the work), entries of
    /// `touched` only.
    nodal: Vec<Vector3<f64>>,
    /// Deepest penetration left after any correction so far, m; points in contact with each
    /// body.
    worst: f64,
    in_contact: Vec<usize>,
    /// The body's closed surface: each vertex's reference position (m) and its row over the
    /// nodal parameters, and the faces, for [`Contact::check_tunnelled`].
    body: Option<std::sync::Arc<BodySurface>>,
    /// Scratch of the sweeps: each point's multiplier (N), the points in contact and whether
    /// each point is among them.
    lambda: Vec<f64>,
    active: Vec<usize>,
    is_active: Vec<bool>,
    /// The first point found pushed into while its nodes are prescribed.
    conflict: Option<Conflict>,
    /// Surface tools (a distance query is a tree search): each point's position in the tool's
    /// frame at its last exact query and its depth there.
    clearance: Vec<Vec<(Vector3<f64>, f64)>>,
    /// Per point of the body being corrected: its (depth, normal) measured in parallel before
    /// a sweep that visits every point; a point whose nodes an earlier correction of the same
    /// sweep moved is measured again.
    measured: Vec<(f64, Vector3<f64>)>,
    /// Per node: the sweep (count of `sweep_stamp`) in which a correction last moved it.
    moved_in: Vec<u64>,
    sweep_stamp: u64,
}

/// The depth of `x` (m) in `shape` displaced by `d` (m), or for a surface tool an upper bound
/// that is still negative where the point cannot have reached it: the depth is
/// 1-Lipschitz in position, so a point that was `-c` deep at `y0` is at most `-c + |y - y0|`
/// deep now. Exact values refresh `cache`. The normal is meaningful only where the depth is
/// exact (a bound is negative, and negative depths of points not in contact are skipped).
fn depth_with_clearance(
    shape: &RigidShape,
    x: &Vector3<f64>,
    d: &Vector3<f64>,
    cache: Option<&mut (Vector3<f64>, f64)>,
) -> (f64, Vector3<f64>) {
    match (shape, cache) {
        (RigidShape::Surface(tool), Some(c)) => {
            let y = x - d;
            let bound = c.1 + (y - c.0).norm();
            if bound < 0.0 {
                return (bound, Vector3::z());
            }
            let (depth, n) = tool.contact_depth(&y);
            *c = (y, depth);
            (depth, n)
        }
        _ => shape.signed_depth(x, d),
    }
}

/// A raw pointer that parallel tasks share, each writing its own entry.
#[derive(Clone, Copy)]
struct Shared<T>(*mut T);
unsafe impl<T> Send for Shared<T> {}
unsafe impl<T> Sync for Shared<T> {}

impl<T> Shared<T> {
    /// The pointer; a method so closures capture the whole (Send + Sync) wrapper.
    fn get(self) -> *mut T {
        self.0
    }
}

/// Gauss-Seidel sweeps at most per step. Points near the edge of a flat-ended indenter switch
/// between its end and its side and converge slowly: the meshless brain indentation (3,520
/// nodes) left 9.4e-7 m with 50 sweeps and 1.1e-9 m with 400, in the same solve time (the
/// few steps that need them are few).
const SWEEPS: usize = 400;

/// Over-relaxation of the sweeps over points that share nodes (meshless rows): on the
/// meshless cube pressed by a plate (25 points, rows of about 20 nodes) the deepest
/// penetration left within 50 sweeps fell from 4.6e-9 m without to 2.0e-10 m with 1.5.
const OMEGA: f64 = 1.5;

impl Contact {
    /// Contact of `points[b]` with `bodies[b]` on a model of `num_nodes` nodes; `tolerance`
    /// (m) is the penetration left once the corrections converge.
    pub fn new(
        bodies: Vec<RigidBody>,
        points: Vec<Vec<ContactPoint>>,
        num_nodes: usize,
        tolerance: f64,
    ) -> Result<Self> {
        if bodies.len() != points.len() {
            return Err(Error::input(
                InputKind::Value,
                "contact: one point list per rigid body",
            ));
        }
        let mut hit = vec![false; num_nodes];
        for (b, pts) in bodies.iter().zip(&points) {
            if pts.is_empty() {
                return Err(Error::input(
                    InputKind::Selection,
                    format!(
                        "contact '{}': no surface point to touch (check its select)",
                        b.name
                    ),
                )
                .key(format!("contact.{}", b.name)));
            }
            for p in pts {
                for &(j, _) in &p.row {
                    let j = j as usize;
                    if j >= num_nodes {
                        return Err(Error::input(
                            InputKind::Value,
                            format!(
                                "contact '{}': node {j} beyond the model's {num_nodes}",
                                b.name
                            ),
                        )
                        .node(j));
                    }
                    hit[j] = true;
                }
            }
        }
        let n = bodies.len();
        let clearance = points
            .iter()
            .map(|p| vec![(Vector3::repeat(f64::NAN), f64::INFINITY); p.len()])
            .collect();
        Ok(Contact {
            bodies,
            points,
            tolerance,
            touched: (0..num_nodes as u32).filter(|&j| hit[j as usize]).collect(),
            forces: vec![Vector3::zeros(); n],
            nodal: vec![Vector3::zeros(); num_nodes],
            worst: 0.0,
            in_contact: vec![0; n],
            body: None,
            lambda: Vec::new(),
            active: Vec::new(),
            is_active: Vec::new(),
            conflict: None,
            clearance,
            measured: Vec::new(),
            moved_in: vec![0; num_nodes],
            sweep_stamp: 0,
        })
    }

    /// Rigid-body names, in the order of [`Self::forces`].
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.bodies.iter().map(|b| b.name.as_str())
    }

    /// Surface points that may touch rigid body `b`.
    pub fn candidates(&self, b: usize) -> usize {
        self.points.get(b).map_or(0, Vec::len)
    }

    /// Number of rigid bodies.
    pub fn len(&self) -> usize {
        self.bodies.len()
    }

    /// The candidate surface points of rigid body `b`.
    pub fn points_of(&self, b: usize) -> &[ContactPoint] {
        &self.points[b]
    }

    /// The depth (m, positive inside the rigid body) of point `p` (of body `b`) at nodal
    /// displacements `u` (m) and load fraction `tau`, and the direction that pushes it out.
    pub fn depth_of(
        &self,
        b: usize,
        p: &ContactPoint,
        u: &[Vector3<f64>],
        tau: f64,
    ) -> (f64, Vector3<f64>) {
        self.depth_of_hinted(b, p, u, tau, None)
    }

    /// [`Contact::depth_of`] with the point's push direction at the last equilibrium
    /// ([`RigidShape::signed_depth_hinted`]; static solve).
    pub fn depth_of_hinted(
        &self,
        b: usize,
        p: &ContactPoint,
        u: &[Vector3<f64>],
        tau: f64,
        hint: Option<Vector3<f64>>,
    ) -> (f64, Vector3<f64>) {
        let x = p.position(u);
        self.bodies[b]
            .shape
            .signed_depth_hinted(&x, &self.body_displacement(b, tau), hint)
    }

    /// The derivative of the push direction of point `p` (as [`Contact::depth_of_hinted`]
    /// gives it) with respect to the point's position, 1/m, by central differences of 1e-7 m:
    /// the normal's turning, which the static solve's contact tangent takes times the force.
    /// A sphere's is (I - n n^T) / r; a plane's and a flat end's 0; a surface from a file
    /// that of its interpolated normal.
    pub fn normal_gradient(
        &self,
        b: usize,
        p: &ContactPoint,
        u: &[Vector3<f64>],
        tau: f64,
        hint: Option<Vector3<f64>>,
    ) -> Matrix3<f64> {
        const H: f64 = 1e-7;
        let x = p.position(u);
        let d = self.body_displacement(b, tau);
        let shape = &self.bodies[b].shape;
        let mut g = Matrix3::zeros();
        for i in 0..3 {
            let mut e = Vector3::zeros();
            e[i] = H;
            let up = shape.signed_depth_hinted(&(x + e), &d, hint).1;
            let down = shape.signed_depth_hinted(&(x - e), &d, hint).1;
            g.set_column(i, &((up - down) / (2.0 * H)));
        }
        g
    }

    /// Takes the state a static solve ended in: each body's force on the body (N), its points
    /// in contact and the deepest penetration left (m), reported as a correction's are.
    pub fn set_static_state(
        &mut self,
        forces: Vec<Vector3<f64>>,
        in_contact: Vec<usize>,
        worst: f64,
    ) {
        self.forces = forces;
        self.in_contact = in_contact;
        self.worst = worst;
    }

    /// No rigid body.
    pub fn is_empty(&self) -> bool {
        self.bodies.is_empty()
    }

    /// The nodes a correction may move, ascending.
    pub fn touched(&self) -> &[u32] {
        &self.touched
    }

    /// Force each rigid body applied to the body in the last correction, N.
    pub fn forces(&self) -> &[Vector3<f64>] {
        &self.forces
    }

    /// Penetration the corrections aim to leave at most, m.
    pub fn tolerance(&self) -> f64 {
        self.tolerance
    }

    /// Deepest penetration any correction left, m.
    pub fn worst_penetration(&self) -> f64 {
        self.worst
    }

    /// The body's closed surface, which [`Contact::check_tunnelled`] tests the rigid bodies'
    /// end positions against.
    pub fn set_body_surface(&mut self, surface: BodySurface) {
        self.body = Some(std::sync::Arc::new(surface));
    }

    /// An error naming the first rigid body that ends the run inside the deformed body (its
    /// core point, or for a closed surface tool all of its sampled vertices, inside the surface
    /// moved by `u`, the nodal parameters, m) while pressing no surface point: it passed through
    /// the surface between its nodes (issue 56), and its answer (no force) is wrong.
    pub fn check_tunnelled(&self, u: &[Vector3<f64>]) -> Result<()> {
        let Some(surface) = &self.body else {
            return Ok(());
        };
        let moved: Vec<Vector3<f64>> = surface
            .vertices
            .iter()
            .zip(&surface.rows)
            .map(|(x, row)| {
                x + row
                    .iter()
                    .map(|&(j, w)| u.get(j as usize).map_or(Vector3::zeros(), |v| v * w))
                    .sum::<Vector3<f64>>()
            })
            .collect();
        let inside = |q: &Vector3<f64>| {
            crate::geometry::winding::winding_number(
                q,
                &moved,
                surface.faces.iter().map(|f| f.as_slice()),
            )
            .abs()
                > 0.5
        };
        for (b, body) in self.bodies.iter().enumerate() {
            if self.in_contact[b] > 0 {
                continue;
            }
            let d = self.body_displacement(b, 1.0);
            let cores: Vec<Vector3<f64>> = body.shape.core_points().iter().map(|c| c + d).collect();
            let end = if self.is_surface(b) {
                (!cores.is_empty() && cores.iter().all(inside)).then(|| cores[0])
            } else {
                cores.into_iter().find(inside)
            };
            if let Some(q) = end {
                return Err(Error::input(InputKind::Value, format!(
                    "contact '{}' ends inside the body (its point ({:.4e}, {:.4e}, {:.4e}) m) pressing no \
                     surface point: it passed through the surface between the surface's nodes \
                     (contact acts on them), so its answer (no force) is wrong. Refine the surface where the \
                     tool acts (discretization.size, refine), use a larger tool, or a smaller motion",
                    body.name, crate::error::Sci(q.x), crate::error::Sci(q.y), crate::error::Sci(q.z))));
            }
        }
        Ok(())
    }

    /// Forgets what earlier corrections left (deepest penetration, forces, points in
    /// contact): a relaxation that restarts after an instability begins afresh.
    pub fn reset_statistics(&mut self) {
        self.worst = 0.0;
        self.forces.iter_mut().for_each(|f| *f = Vector3::zeros());
        self.in_contact.iter_mut().for_each(|k| *k = 0);
        self.conflict = None;
    }

    /// The first surface point a rigid body pushed deeper than the tolerance although the
    /// prescribed components of its nodes hold it along the push ([`Conflict`]).
    pub fn conflict(&self) -> Option<&Conflict> {
        self.conflict.as_ref()
    }

    /// Points in contact with each body after the last correction.
    pub fn points_in_contact(&self) -> &[usize] {
        &self.in_contact
    }

    /// [`RigidShape::core_points`] of body `b` in its reference position.
    pub fn core_points(&self, b: usize) -> Vec<Vector3<f64>> {
        self.bodies[b].shape.core_points()
    }

    /// How far rigid body `b` may jump in one go (m) without carrying a surface point past its
    /// middle, where the correction would push it out on the far side: a plane, any distance;
    /// a ball or a cylinder, half its radius; a closed surface, a quarter of the smallest side
    /// of its bounding box.
    pub fn jump_limit(&self, b: usize) -> f64 {
        match &self.bodies[b].shape {
            RigidShape::Plane { .. } => f64::INFINITY,
            RigidShape::Sphere { radius, .. } | RigidShape::Cylinder { radius, .. } => 0.5 * radius,
            RigidShape::Surface(tool) => {
                let (lo, hi) = crate::geometry::select::bounds(&tool.surface().points);
                0.25 * (hi - lo).min()
            }
        }
    }

    /// Whether rigid body `b` is a closed surface (its core points are its vertices: inside the
    /// tissue means all of them inside, where an analytic tool's one core point suffices).
    pub fn is_surface(&self, b: usize) -> bool {
        matches!(self.bodies[b].shape, RigidShape::Surface(_))
    }

    /// The final displacement (m, at curve factor 1) of rigid body `name`.
    pub fn motion(&self, name: &str) -> Result<Vector3<f64>> {
        Ok(self.bodies[self.index(name)?].motion)
    }

    /// Moves rigid body `name` to a new final displacement `motion` (m, from its reference
    /// position, reached along its curve): a tool's new position between runs of one model.
    /// Errors naming the bodies there are, or a motion that is not finite.
    pub fn set_motion(&mut self, name: &str, motion: Vector3<f64>) -> Result<()> {
        let k = self.index(name)?;
        if !motion.iter().all(|c| c.is_finite()) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "contact '{name}': motion {:?} m is not finite",
                    motion.as_slice()
                ),
            )
            .key(format!("contact.{name}")));
        }
        self.bodies[k].motion = motion;
        Ok(())
    }

    fn index(&self, name: &str) -> Result<usize> {
        self.bodies
            .iter()
            .position(|b| b.name == name)
            .ok_or_else(|| {
                let names: Vec<&str> = self.names().collect();
                Error::input(
                    InputKind::Selection,
                    format!(
                        "no rigid body named '{name}'; the model's contact bodies: {}",
                        names.join(", ")
                    ),
                )
                .key(format!("contact.{name}"))
            })
    }

    /// The curves of the bodies that move.
    pub fn motion_curves(&self) -> impl Iterator<Item = &LoadCurve> {
        self.bodies
            .iter()
            .filter(|b| b.motion != Vector3::zeros())
            .map(|b| &b.curve)
    }

    /// Each body's displacement at load fraction `tau`, m.
    pub fn body_displacement(&self, b: usize, tau: f64) -> Vector3<f64> {
        let body = &self.bodies[b];
        body.motion * body.curve.value(tau)
    }

    /// The deepest point of the undeformed body inside rigid body `b` displaced to load
    /// fraction `tau`: (depth m, reference position m); None where none is inside.
    pub fn deepest_at_rest(&self, b: usize, tau: f64) -> Option<(f64, Vector3<f64>)> {
        let d = self.body_displacement(b, tau);
        let mut best: Option<(f64, Vector3<f64>)> = None;
        for p in &self.points[b] {
            let depth = self.bodies[b].shape.signed_depth(&p.x, &d).0;
            if depth > best.map_or(0.0, |x| x.0) {
                best = Some((depth, p.x));
            }
        }
        best
    }

    /// Pushes the points inside a rigid body (displaced to load fraction `tau`) back to its
    /// surface by correcting `u` (m), with masses `mass` (kg) and the update's force
    /// coefficient `a` (s^2). Components in `fixed` (prescribed DOFs) are not moved.
    ///
    /// Projected Gauss-Seidel (over-relaxed by `OMEGA` where rows share nodes): each point's
    /// multiplier lambda >= 0 changes by depth / (a
    /// sum_j phi_j^2 |n_free|^2 / m_j), clipped at zero, so a point that a neighbour's
    /// correction pushed too far gets its own push back; the first sweep visits every point,
    /// the later ones those it found in contact, until no point is deeper than the tolerance
    /// nor held while apart by more than it.
    pub fn correct(
        &mut self,
        u: &mut [Vector3<f64>],
        tau: f64,
        a: f64,
        mass: &[f64],
        fixed: &[[bool; 3]],
    ) {
        for &j in &self.touched {
            self.nodal[j as usize] = Vector3::zeros();
        }
        let position = |p: &ContactPoint, u: &[Vector3<f64>]| p.position(u);
        let mut worst = 0.0f64;
        for b in 0..self.bodies.len() {
            let d = self.body_displacement(b, tau);
            let shape = &self.bodies[b].shape;
            let mut force = Vector3::zeros();
            self.active.clear();
            self.lambda.clear();
            self.lambda.resize(self.points[b].len(), 0.0);
            self.is_active.clear();
            self.is_active.resize(self.points[b].len(), false);
            // Deepest penetration at the last full check (infinite until one is made).
            let mut after = f64::INFINITY;
            for sweep in 0..SWEEPS {
                let mut left = 0.0f64;
                let count = if sweep == 0 {
                    self.points[b].len()
                } else {
                    self.active.len()
                };
                self.sweep_stamp += 1;
                // The queries (a tree search for surface tools) of every point the sweep
                // visits, at once: the sweep below takes each point's from here unless an
                // earlier correction of this sweep moved one of its nodes (then it measures
                // again, as a serial sweep would). Each goes through the clearance cache where
                // the point's multiplier is zero, as the sweep's own query would.
                self.measured.resize(count, (0.0, Vector3::zeros()));
                {
                    let uu = &*u;
                    let (lambda, active) = (&self.lambda, &self.active);
                    let clear = Shared(self.clearance[b].as_mut_ptr());
                    let pts = &self.points[b];
                    self.measured
                        .par_iter_mut()
                        .enumerate()
                        .with_min_len(256)
                        .for_each(|(k, m)| {
                            let i = if sweep == 0 { k } else { active[k] };
                            // SAFETY: the visited points are distinct (active holds each once),
                            // so each task touches its own cache entry.
                            let c = unsafe { &mut *clear.get().add(i) };
                            let cache = (lambda[i] == 0.0).then_some(c);
                            *m = depth_with_clearance(shape, &position(&pts[i], uu), &d, cache);
                        });
                }
                for k in 0..count {
                    let i = if sweep == 0 { k } else { self.active[k] };
                    let p = &self.points[b][i];
                    let stamp = self.sweep_stamp;
                    let fresh = p
                        .row
                        .iter()
                        .all(|&(j, _)| self.moved_in[j as usize] != stamp);
                    let (depth, n) = if fresh {
                        self.measured[k]
                    } else {
                        let cache = (self.lambda[i] == 0.0).then(|| &mut self.clearance[b][i]);
                        depth_with_clearance(shape, &position(p, u), &d, cache)
                    };
                    if depth <= 0.0 && self.lambda[i] == 0.0 {
                        continue;
                    }
                    if sweep == 0 {
                        self.active.push(i);
                        self.is_active[i] = true;
                    }
                    let (mut den, mut full) = (0.0, 0.0);
                    for &(j, f) in &p.row {
                        let j = j as usize;
                        let free: f64 = (0..3).filter(|&c| !fixed[j][c]).map(|c| n[c] * n[c]).sum();
                        den += f * f * free / mass[j];
                        full += f * f / mass[j];
                    }
                    let free_at_point: f64 =
                        (0..3).filter(|&c| !p.held[c]).map(|c| n[c] * n[c]).sum();
                    let held_here = p.held.iter().any(|&h| h) && !(free_at_point > HELD_SHARE);
                    let blocked = !(den > HELD_SHARE * full);
                    if (held_here || blocked) && depth > self.tolerance && self.conflict.is_none() {
                        let node = p.main_node();
                        self.conflict = Some(Conflict {
                            body: b,
                            x: p.x,
                            depth,
                            node,
                            normal: n,
                        });
                    }
                    if blocked {
                        left = left.max(depth);
                        continue;
                    }
                    // A point alone on its node closes exactly; coupled points over-relax.
                    let omega = if p.row.len() == 1 { 1.0 } else { OMEGA };
                    let new = (self.lambda[i] + omega * depth / (a * den)).max(0.0);
                    let dl = new - self.lambda[i];
                    self.lambda[i] = new;
                    // Deeper than the tolerance, or held while apart by more than it.
                    left = left.max(if new > 0.0 { depth.abs() } else { depth });
                    for &(j, f) in &p.row {
                        let j = j as usize;
                        let step = n * (a * f * dl / mass[j]);
                        for c in 0..3 {
                            if !fixed[j][c] {
                                u[j][c] += step[c];
                            }
                        }
                        self.nodal[j] += n * (f * dl);
                        self.moved_in[j] = stamp;
                    }
                    force += n * dl;
                }
                if left > self.tolerance {
                    continue;
                }
                // The sweep's own measure sees each point before the later corrections: check
                // them all after it (a neighbour's push can also drive a point the sweeps did
                // not visit into the body, which then joins them).
                // In parallel (nothing moves during the check), then in point order.
                let uu = &*u;
                let lambda = &self.lambda;
                self.measured
                    .resize(self.points[b].len(), (0.0, Vector3::zeros()));
                self.measured
                    .par_iter_mut()
                    .zip(self.clearance[b].par_iter_mut())
                    .zip(self.points[b].par_iter())
                    .enumerate()
                    .with_min_len(256)
                    .for_each(|(i, ((m, c), p))| {
                        let cache = (lambda[i] == 0.0).then_some(c);
                        *m = depth_with_clearance(shape, &position(p, uu), &d, cache);
                    });
                after = 0.0;
                for i in 0..self.points[b].len() {
                    let depth = self.measured[i].0;
                    after = after.max(depth);
                    if depth > self.tolerance && !self.is_active[i] {
                        self.active.push(i);
                        self.is_active[i] = true;
                    }
                }
                if after <= self.tolerance {
                    break;
                }
            }
            if after == f64::INFINITY {
                // The sweeps ran out before a full check: measure what they left.
                after = self.points[b]
                    .iter()
                    .map(|p| shape.signed_depth(&position(p, u), &d).0)
                    .fold(0.0, f64::max);
            }
            worst = worst.max(after);
            self.forces[b] = force;
            self.in_contact[b] = self.lambda.iter().filter(|&&l| l > 0.0).count();
        }
        self.worst = self.worst.max(worst);
    }

    /// Work (J) of the last correction's contact forces over the increment (u_next - u_prev) / 2.
    pub fn work(&self, u_next: &[Vector3<f64>], u_prev: &[Vector3<f64>]) -> f64 {
        self.touched
            .iter()
            .map(|&j| {
                let j = j as usize;
                self.nodal[j].dot(&(u_next[j] - u_prev[j])) * 0.5
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn penetration_of_each_shape() {
        let plane = RigidShape::Plane {
            point: Vector3::new(0.0, 0.0, 1.0),
            normal: Vector3::new(0.0, 0.0, -1.0),
        };
        let d = Vector3::new(0.0, 0.0, -0.1);
        let (depth, n) = plane
            .penetration(&Vector3::new(0.3, 0.0, 0.95), &d)
            .unwrap();
        assert!((depth - 0.05).abs() < 1e-15 && n == Vector3::new(0.0, 0.0, -1.0));
        assert!(plane
            .penetration(&Vector3::new(0.0, 0.0, 0.85), &d)
            .is_none());
        let ball = RigidShape::Sphere {
            center: Vector3::zeros(),
            radius: 1.0,
        };
        let (depth, n) = ball
            .penetration(&Vector3::new(0.6, 0.0, 0.0), &Vector3::zeros())
            .unwrap();
        assert!((depth - 0.4).abs() < 1e-15 && n == Vector3::x());
        let punch = RigidShape::Cylinder {
            center: Vector3::zeros(),
            axis: Vector3::z(),
            radius: 1.0,
            min: Some(0.0),
            max: None,
            edge_radius: 0.0,
        };
        // Near the flat end: pushed down; near the side: pushed out.
        let (depth, n) = punch
            .penetration(&Vector3::new(0.1, 0.0, 0.05), &Vector3::zeros())
            .unwrap();
        assert!((depth - 0.05).abs() < 1e-15 && n == -Vector3::z());
        let (depth, n) = punch
            .penetration(&Vector3::new(0.0, 0.95, 3.0), &Vector3::zeros())
            .unwrap();
        assert!((depth - 0.05).abs() < 1e-12 && (n - Vector3::y()).norm() < 1e-15);
        assert!(punch
            .penetration(&Vector3::new(0.0, 0.0, -0.01), &Vector3::zeros())
            .is_none());
    }

    /// A rounded rim: the depth is the exact signed distance to the rounded surface (known
    /// at points on the flat end, the side and the torus of the rim), and its normal is the
    /// outward gradient of the distance (central differences along it give -1).
    #[test]
    fn a_rounded_rim_is_the_offset_of_the_shrunk_cylinder() {
        let (r, e) = (1.0, 0.2);
        let punch = RigidShape::Cylinder {
            center: Vector3::zeros(),
            axis: Vector3::z(),
            radius: r,
            min: Some(0.0),
            max: Some(2.0),
            edge_radius: e,
        };
        let zero = Vector3::zeros();
        // On the flat end and on the side, as the sharp cylinder.
        let (d, n) = punch.signed_depth(&Vector3::new(0.5, 0.0, 0.05), &zero);
        assert!((d - 0.05).abs() < 1e-15 && n == -Vector3::z(), "{d} {n:?}");
        let (d, n) = punch.signed_depth(&Vector3::new(0.0, 0.95, 1.0), &zero);
        assert!((d - 0.05).abs() < 1e-15 && (n - Vector3::y()).norm() < 1e-15);
        // Inside the sharp corner but outside the rounded rim: the torus about the circle
        // of radius r - e at height e, tube radius e.
        let x = Vector3::new(0.95, 0.0, 0.05);
        let torus = e - ((x.x - (r - e)).powi(2) + (x.z - e).powi(2)).sqrt();
        let (d, _) = punch.signed_depth(&x, &zero);
        assert!(d < 0.0 && (d - torus).abs() < 1e-15, "{d} vs {torus}");
        assert!(punch.penetration(&x, &zero).is_none());
        // Inside the rim: pushed out along the torus' normal, at 45 degrees here.
        let (d, n) = punch
            .penetration(&Vector3::new(0.9, 0.0, 0.1), &zero)
            .unwrap();
        let want = Vector3::new(1.0, 0.0, -1.0).normalize();
        assert!((d - (e - 0.1 * 2f64.sqrt())).abs() < 1e-15 && (n - want).norm() < 1e-12);
        // The normal is the outward gradient of the distance, moved by the motion `d`.
        let shift = Vector3::new(0.01, -0.02, 0.3);
        let h = 1e-7;
        for x in [
            Vector3::new(0.93, 0.1, 0.04),
            Vector3::new(0.7, -0.5, 0.12),
            Vector3::new(-0.99, 0.05, 1.95),
            Vector3::new(1.1, 0.0, -0.05),
        ] {
            let x = x + shift;
            let (_, n) = punch.signed_depth(&x, &shift);
            let slope = (punch.signed_depth(&(x + n * h), &shift).0
                - punch.signed_depth(&(x - n * h), &shift).0)
                / (2.0 * h);
            assert!((slope + 1.0).abs() < 1e-6, "{x:?}: slope {slope}");
        }
    }

    /// Two points sharing nodes through their rows are pushed out together: the sweeps
    /// leave less than the tolerance, and the body's force is what moved them.
    #[test]
    fn shared_rows_converge_below_the_tolerance() {
        let plate = RigidBody {
            name: "plate".into(),
            shape: RigidShape::Plane {
                point: Vector3::new(0.0, 0.0, 1.0),
                normal: -Vector3::z(),
            },
            motion: Vector3::new(0.0, 0.0, -0.1),
            curve: LoadCurve::Constant,
        };
        let pts = vec![
            ContactPoint {
                x: Vector3::new(0.0, 0.0, 1.0),
                row: vec![(0, 0.6), (1, 0.4)],
                held: [false; 3],
            },
            ContactPoint {
                x: Vector3::new(1.0, 0.0, 1.0),
                row: vec![(0, 0.3), (1, 0.7)],
                held: [false; 3],
            },
        ];
        let mut c = Contact::new(vec![plate], vec![pts], 2, 1e-9).unwrap();
        let mut u = vec![Vector3::zeros(); 2];
        let mass = [1.0, 2.0];
        c.correct(&mut u, 1.0, 1e-4, &mass, &[[false; 3]; 2]);
        assert!(c.worst_penetration() <= 1e-9, "{}", c.worst_penetration());
        for (x0, row) in [(1.0, [0.6, 0.4]), (1.0, [0.3, 0.7])] {
            let z = x0 + row[0] * u[0].z + row[1] * u[1].z;
            assert!((z - 0.9).abs() <= 1e-9, "{z}");
        }
        // The force moved the masses: m u / a summed.
        let f = c.forces()[0];
        let moved = (u[0] * mass[0] + u[1] * mass[1]) / 1e-4;
        assert!((f - moved).norm() < 1e-9 * f.norm(), "{f} vs {moved}");
        assert_eq!(c.points_in_contact(), &[2]);
    }
}
