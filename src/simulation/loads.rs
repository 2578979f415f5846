//! The scene's `[loads]` on a built discretization.

use nalgebra::Vector3;

use super::surface::{Discretized, Surface};
use super::{load_curve, select_nodes};
use crate::bc::loads::{Load, LoadKind};
use crate::io::model::MeshInput;
use crate::scene::Scene;
use crate::Result;

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
        let curve = load_curve(scene, &l.curve)?;
        let kind = match (l.gravity, l.force, &l.select) {
            (Some(g), _, _) => LoadKind::Gravity(Vector3::from(g)),
            (None, Some(f), Some(sel)) => {
                let nodes = select_nodes(sel, d.nodes(), &what, input)?;
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
                let picked = select_nodes(sel, &s.vertices, &what, input)?;
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
