//! `[measured]` displacements matched to surface nodes: the image-driven brain-shift workflow.

use nalgebra::Vector3;

use super::{load_curve, scene_path};
use crate::bc::Boundary;
use crate::io::measured::{parse_measured, MeasuredAt};
use crate::io::model::MeshInput;
use crate::scene::{MeasuredSpec, Scene};
use crate::{Error, Result};

/// Default matching distance, as a fraction of the body's bounding-box diagonal.
pub const DEFAULT_TOLERANCE: f64 = 1e-3;

/// The boundary `[measured.NAME]` prescribes: each measured point (a position, or a node id of
/// the mesh file turned into its position) taken by the nearest of the `candidates` (surface
/// nodes of `nodes`) within the tolerance, with its displacement as that node's final value on
/// all three components. A point farther than the tolerance from every candidate, or two points
/// on one node, is an error naming the file, the line and the distances.
pub(super) fn boundary(
    scene: &Scene,
    name: &str,
    spec: &MeasuredSpec,
    nodes: &[Vector3<f64>],
    candidates: &[usize],
    input: Option<&MeshInput>,
) -> Result<Boundary> {
    let path = scene_path(scene, &spec.file);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| Error::io(format!("{} (measured.{name}.file)", path.display()), e))?;
    let points = parse_measured(&text, &path)?;
    let (lo, hi) = crate::geometry::select::bounds(nodes);
    let tolerance = spec
        .tolerance
        .unwrap_or(DEFAULT_TOLERANCE * (hi - lo).norm());
    if candidates.is_empty() {
        return Err(Error::Input(format!(
            "measured '{name}': the body has no surface node to take the displacements"
        )));
    }
    let tree = {
        let pts: Vec<[f64; 3]> = candidates
            .iter()
            .map(|&i| [nodes[i].x, nodes[i].y, nodes[i].z])
            .collect();
        kiddo::ImmutableKdTree::<f64, 3>::new_from_slice(&pts).map_err(|e| {
            Error::Input(format!(
                "measured '{name}': cannot index the surface nodes: {e:?}"
            ))
        })?
    };
    let where_ = |line: usize| format!("measured '{name}' ({} line {line})", path.display());
    let mut taken: Vec<(usize, usize)> = Vec::new(); // (node, line)
    let mut line_of = vec![0usize; nodes.len()]; // 0: not taken
    let mut values = Vec::new();
    for m in &points {
        let x = match m.at {
            MeasuredAt::Position(x) => x,
            MeasuredAt::Node(id) => {
                let file = input.ok_or_else(|| {
                    Error::Input(format!(
                        "{}: node id {id} needs a mesh file (geometry.mesh); give positions \
                         x, y, z, ux, uy, uz instead",
                        where_(m.line)
                    ))
                })?;
                let k = file.node_ids.iter().position(|&n| n == id).ok_or_else(|| {
                    Error::Input(format!(
                        "{}: the mesh file has no node {id}",
                        where_(m.line)
                    ))
                })?;
                file.mesh.nodes[k]
            }
        };
        let nn = tree
            .query(&[x.x, x.y, x.z])
            .nearest_n::<kiddo::SquaredEuclidean<f64>>(std::num::NonZero::<usize>::MIN)
            .execute();
        let Some(best) = nn.first() else {
            continue;
        };
        let node = candidates[best.item as usize];
        let dist = best.distance.sqrt();
        if dist > tolerance {
            let y = nodes[node];
            return Err(Error::Input(format!(
                "{}: the point ({:.6e}, {:.6e}, {:.6e}) m is {dist:.3e} m from the nearest surface \
                 node ({node}, at ({:.6e}, {:.6e}, {:.6e}) m), beyond the tolerance {tolerance:.3e} m: \
                 check the file's units (m) and frame, or raise measured.{name}.tolerance",
                where_(m.line),
                x.x,
                x.y,
                x.z,
                y.x,
                y.y,
                y.z
            )));
        }
        let other = line_of[node];
        if other != 0 {
            return Err(Error::Input(format!(
                "{}: the point takes surface node {node}, which line {other} already took: two \
                 measured points closer to each other than to any other node; thin the \
                 measurements or refine the surface",
                where_(m.line)
            )));
        }
        line_of[node] = m.line;
        taken.push((node, m.line));
        values.push([m.u.x, m.u.y, m.u.z]);
    }
    Ok(Boundary {
        name: name.into(),
        nodes: taken.iter().map(|t| t.0).collect(),
        components: [Some(0.0); 3],
        node_values: Some(values),
        curve: load_curve(scene, &spec.curve)?,
    })
}
