//! The scene's `[loads]` and `[contact]` on a built discretization.

use nalgebra::Vector3;

use super::surface::{Discretized, Surface};
use super::{load_curve, select_nodes};
use crate::bc::contact::{Contact, ContactPoint, RigidBody};
use crate::bc::loads::{Load, LoadKind};
use crate::io::model::MeshInput;
use crate::report::{Warning, WarningKind};
use crate::scene::Scene;
use crate::{InputKind, Result};

/// Gravity as it is; point forces on the selected nodes (spread by the rows at their
/// positions); tractions and pressures on the boundary faces whose corners are all selected.
/// The body's surface is built only when a load acts on faces.
pub(super) fn scene_loads(
    scene: &Scene,
    d: Discretized<'_>,
    input: Option<&MeshInput>,
) -> Result<Vec<Load>> {
    let mut surface: Option<Surface> = None;
    let mut out = Vec::new();
    for (name, l) in &scene.loads {
        let what = format!("load '{name}'");
        let key = format!("loads.{name}.select");
        let curve = load_curve(scene, &l.curve)?;
        let kind = match (l.gravity, l.force, &l.select) {
            (Some(g), _, _) => LoadKind::Gravity(Vector3::from(g)),
            (None, Some(f), Some(sel)) => {
                let nodes = select_nodes(sel, d.nodes(), &what, &key, input)?;
                LoadKind::PointForce {
                    rows: nodes
                        .iter()
                        .map(|&i| d.node_row(i))
                        .collect::<Result<_>>()?,
                    force: Vector3::from(f),
                }
            }
            (None, None, Some(sel)) => {
                if surface.is_none() {
                    surface = Some(d.surface()?);
                }
                let s = surface.as_ref().expect("built above");
                let picked = select_nodes(sel, &s.vertices, &what, &key, input)?;
                let mut on = vec![false; s.vertices.len()];
                for i in picked {
                    on[i] = true;
                }
                let faces = (0..s.faces.len())
                    .filter(|&k| s.faces[k].0.iter().all(|&i| on[i]))
                    .map(|k| d.face(s, k))
                    .collect::<Result<Vec<_>>>()?;
                match (l.traction, l.pressure) {
                    (Some(t), _) => LoadKind::Traction {
                        faces,
                        traction: Vector3::from(t),
                    },
                    (None, Some(p)) => LoadKind::Pressure { faces, pressure: p },
                    (None, None) => unreachable!("validated: one kind per load"),
                }
            }
            (None, _, None) => unreachable!("validated: loads other than gravity select"),
        };
        out.push(Load {
            name: name.clone(),
            kind,
            curve,
        });
    }
    Ok(out)
}

/// The scene's `[contact]` rigid bodies on a built discretization: their candidate points are
/// the body's surface vertices (FE: surface nodes; meshless: boundary vertices with the shape
/// functions there; coupled: surface vertices, FE nodes interpolating), limited by each body's
/// `select`. The contact tolerance (penetration left once the corrections converge) is
/// [`CONTACT_TOLERANCE`] times the body's bounding-box diagonal. Returns None without contact,
/// and warnings for bodies that start inside the surface.
pub(super) fn scene_contact(
    scene: &Scene,
    d: Discretized<'_>,
    input: Option<&MeshInput>,
    boundaries: &[crate::bc::Boundary],
    warnings: &mut Vec<Warning>,
) -> Result<Option<Contact>> {
    if scene.contact.is_empty() {
        return Ok(None);
    }
    let s = d.surface()?;
    let mut on_face = vec![false; s.vertices.len()];
    for (f, _) in &s.faces {
        for &i in f {
            on_face[i] = true;
        }
    }
    // A quadratic FE layer's surface faces are listed by their corners: their edge nodes are
    // on the surface too (without them a plate passed through the middles of the edges).
    if let Discretized::Coupled(b) = d {
        if let Some(q) = &b.quadratic {
            let mut face_edges = std::collections::HashSet::new();
            for (f, _) in &s.faces {
                for k in 0..f.len() {
                    let (a, c) = (f[k], f[(k + 1) % f.len()]);
                    face_edges.insert([a.min(c), a.max(c)]);
                }
            }
            for e in &q.edges {
                if face_edges.contains(&e.ends) {
                    on_face[e.node] = true;
                }
            }
        }
    }
    let (lo, hi) = crate::geometry::select::bounds(d.nodes());
    let diag = (hi - lo).norm();
    let tolerance = CONTACT_TOLERANCE * diag;
    let mut prescribed = vec![[false; 3]; d.nodes().len()];
    for b in boundaries {
        for &n in &b.nodes {
            if let Some(p) = prescribed.get_mut(n) {
                for (held, c) in p.iter_mut().zip(&b.components) {
                    *held |= c.is_some();
                }
            }
        }
    }
    let mut bodies = Vec::new();
    let mut points = Vec::new();
    for (name, c) in &scene.contact {
        let what = format!("contact '{name}'");
        let mut chosen: Vec<usize> = (0..s.vertices.len()).filter(|&i| on_face[i]).collect();
        if let Some(sel) = &c.select {
            let picked = select_nodes(
                sel,
                &s.vertices,
                &what,
                &format!("contact.{name}.select"),
                input,
            )?;
            let mut keep = vec![false; s.vertices.len()];
            for i in picked {
                keep[i] = true;
            }
            chosen.retain(|&i| keep[i]);
        }
        let pts = chosen
            .iter()
            .map(|&i| {
                let row = d.vertex_row(&s, i)?;
                // The prescribed components of a node at the point (meshless, blended).
                let mut held = [false; 3];
                for &(j, _) in &row {
                    if (d.nodes()[j as usize] - s.vertices[i]).norm() <= 1e-9 * diag {
                        for (h, p) in held.iter_mut().zip(prescribed[j as usize]) {
                            *h |= p;
                        }
                    }
                }
                Ok(ContactPoint {
                    x: s.vertices[i],
                    row,
                    held,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let body = RigidBody {
            name: name.clone(),
            shape: contact_shape(scene, c)?,
            motion: Vector3::from(c.motion),
            curve: load_curve(scene, &c.curve)?,
        };
        bodies.push(body);
        points.push(pts);
    }
    let mut contact = Contact::new(bodies, points, d.nodes().len(), tolerance)?;
    contact.set_body_surface(crate::bc::contact::BodySurface {
        vertices: s.vertices.clone(),
        rows: (0..s.vertices.len())
            .map(|i| d.vertex_row(&s, i))
            .collect::<Result<_>>()?,
        faces: s.faces.iter().map(|f| f.0.clone()).collect(),
    });
    // fe tet10 and a coupled tet10 layer alike take contact on their quadratic faces' nodes.
    let quadratic =
        crate::fe::ElementKind::from(scene.discretization.element) == crate::fe::ElementKind::Tet10;
    if quadratic && !matches!(d, Discretized::Meshless(_)) {
        warnings.push(Warning::new(
            WarningKind::Contact,
            TET10_CONTACT_WARNING.to_string(),
        ));
    }
    for (b, name) in contact.names().enumerate() {
        // Touching means deeper than the contact tolerance: a surface tool inside the tissue
        // "touched" it at 8.6e-10 m by rounding, and was never felt (issue 56).
        if contact
            .deepest_at_rest(b, 0.0)
            .is_some_and(|x| x.0 > tolerance)
        {
            continue;
        }
        let in_body = |q: &Vector3<f64>| {
            let w = crate::geometry::winding::winding_number(
                q,
                &s.vertices,
                s.faces.iter().map(|f| f.0.as_slice()),
            );
            w.abs() > 0.5
        };
        let cores = contact.core_points(b);
        let inside = if contact.is_surface(b) {
            // A closed tool: wholly inside, every sampled vertex inside the body.
            (!cores.is_empty() && cores.iter().all(in_body)).then(|| cores[0])
        } else {
            cores.into_iter().find(in_body)
        };
        if let Some(q) = inside {
            return Err(crate::Error::input(InputKind::Value, format!(
                "contact '{name}' starts inside the body without touching its surface (its point \
                 ({:.4e}, {:.4e}, {:.4e}) m is inside the body, and no surface point is inside it): \
                 contact acts on the body's surface, so a rigid body inside the tissue is never felt. \
                 Start it outside the body, or touching its surface",
                crate::error::Sci(q.x),
                crate::error::Sci(q.y),
                crate::error::Sci(q.z))));
        }
    }
    for (b, name) in contact.names().enumerate() {
        if let Some((deepest, _)) = contact.deepest_at_rest(b, 0.0).filter(|x| x.0 > tolerance) {
            warnings.push(Warning::new(WarningKind::Contact, format!(
                "contact '{name}' starts {deepest:.3e} m inside the body's surface; the first correction \
                 pushes the surface out in one step (deeper than half the distance a wave crosses in a \
                 step is refused; move the rigid body or its curve's start)"
            )));
        }
    }
    Ok(Some(contact))
}

/// A `[contact.NAME]` body's rigid surface: the analytic shape, or the closed surface of its
/// `file`.
fn contact_shape(
    scene: &Scene,
    c: &crate::scene::ContactSpec,
) -> Result<crate::bc::contact::RigidShape> {
    Ok(match (c.shape.as_str(), &c.file) {
        ("surface", Some(file)) => {
            let path = super::translate::scene_path(scene, file);
            let surface = super::translate::rigid_surface(scene, &path, c)?;
            crate::bc::contact::RigidShape::Surface(std::sync::Arc::new(
                crate::geometry::surface_distance::SurfaceDistance::new(surface)?,
            ))
        }
        _ => c.rigid_shape(),
    })
}

/// The surface nodes (of `faces`, on `nodes` in m) that the scene's rigid bodies may touch:
/// those within their faces' longest edge of a body anywhere along its straight path (motion
/// times the curve's factors, from the smallest to the largest, sampled at most half the
/// smallest such edge apart, 200 positions at most). A body's `select` is not applied (a
/// superset). The coupled method puts its FE layer around these nodes, as around the essential
/// boundaries, since contact holds them as a driven boundary holds its nodes.
pub(super) fn contact_reach(
    scene: &Scene,
    nodes: &[Vector3<f64>],
    faces: &[Vec<usize>],
) -> Result<Vec<usize>> {
    let mut margin = vec![0.0f64; nodes.len()];
    for f in faces {
        for k in 0..f.len() {
            let (a, b) = (f[k], f[(k + 1) % f.len()]);
            let l = (nodes[a] - nodes[b]).norm();
            margin[a] = margin[a].max(l);
            margin[b] = margin[b].max(l);
        }
    }
    let on: Vec<usize> = (0..nodes.len()).filter(|&i| margin[i] > 0.0).collect();
    let finest = on.iter().map(|&i| margin[i]).fold(f64::INFINITY, f64::min);
    let mut reached = vec![false; nodes.len()];
    for c in scene.contact.values() {
        let shape = contact_shape(scene, c)?;
        let (lo, hi) = load_curve(scene, &c.curve)?.factor_range();
        let motion = Vector3::from(c.motion);
        let travel = motion.norm() * (hi - lo);
        let positions = if travel > 0.0 && finest.is_finite() {
            (2.0 * travel / finest).ceil().clamp(1.0, 200.0) as usize
        } else {
            1
        };
        for k in 0..=positions {
            let d = motion * (lo + (hi - lo) * k as f64 / positions as f64);
            for &i in &on {
                if !reached[i] && shape.signed_depth(&nodes[i], &d).0 > -margin[i] {
                    reached[i] = true;
                }
            }
        }
    }
    Ok((0..nodes.len()).filter(|&i| reached[i]).collect())
}

/// Penetration a contact correction may leave, as a fraction of the body's bounding-box
/// diagonal.
pub const CONTACT_TOLERANCE: f64 = 1e-8;

/// Contact acts on nodes, and a quadratic face's corner nodes carry no share of a uniform
/// pressure: under a tool's flat end they are free to leave it (studies/README.md, issue 40,
/// contact). Exact with a flat plate on a flat face (tests/contact.rs), not verified beyond.
const TET10_CONTACT_WARNING: &str = "contact with element 'tet10' is not verified beyond a \
flat plate on a flat face: contact acts on the surface nodes, and a quadratic face's corner \
nodes carry no share of a uniform pressure, so under a tool they may leave its surface (on \
cases/brain-contact.toml 14 of the 33 corner nodes under the indenter's end stay 0.01-0.23 mm \
below it, and the force falls 8.5 % from the 8 / 2 mm mesh to the 6 / 1 mm one); linear \
elements (element = \"tet4-anp\") give every surface node its share";
