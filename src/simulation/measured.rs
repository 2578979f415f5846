//! `[measured]` displacements matched to surface nodes: the image-driven brain-shift workflow.

use nalgebra::Vector3;

use super::{load_curve, scene_path};
use crate::bc::{Boundary, MeasuredMap};
use crate::io::measured::{parse_measured, MeasuredAt};
use crate::io::model::MeshInput;
use crate::scene::{MeasuredSpec, Scene};
use crate::{Error, InputKind, Result};

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
    let place = Place { name, path: &path };
    let points = without_repeats(points, input, &place)?;
    let (lo, hi) = crate::geometry::select::bounds(nodes);
    let tolerance = spec
        .tolerance
        .unwrap_or(DEFAULT_TOLERANCE * (hi - lo).norm());
    if candidates.is_empty() {
        return Err(Error::input(
            InputKind::Value,
            format!("measured '{name}': the body has no surface node to take the displacements"),
        ));
    }
    let tree = {
        let pts: Vec<[f64; 3]> = candidates
            .iter()
            .map(|&i| [nodes[i].x, nodes[i].y, nodes[i].z])
            .collect();
        kiddo::ImmutableKdTree::<f64, 3>::new_from_slice(&pts).map_err(|e| {
            Error::input(
                InputKind::Value,
                format!("measured '{name}': cannot index the surface nodes: {e:?}"),
            )
        })?
    };
    if spec.interpolate {
        let mut xs = Vec::with_capacity(points.len());
        for m in &points {
            xs.push(position(m, input, &place)?);
        }
        let us: Vec<[f64; 3]> = points.iter().map(|m| [m.u.x, m.u.y, m.u.z]).collect();
        let (taken, rows) = interpolated(
            name,
            &path,
            &xs,
            (nodes, candidates),
            (spec.tolerance, DEFAULT_TOLERANCE * (hi - lo).norm()),
        )?;
        let map = MeasuredMap {
            points: xs.iter().map(|x| [x.x, x.y, x.z]).collect(),
            rows,
            values: us,
        };
        return Ok(Boundary {
            name: name.into(),
            nodes: taken,
            components: [Some(0.0); 3],
            node_values: Some(map.node_values(&map.values)),
            curve: load_curve(scene, &spec.curve)?,
            measured: Some(std::sync::Arc::new(map)),
        });
    }
    let mut xs = Vec::with_capacity(points.len());
    let mut taken: Vec<(usize, usize)> = Vec::new(); // (node, line)
    let mut line_of = vec![0usize; nodes.len()]; // 0: not taken
    let mut values = Vec::new();
    let mut rows = Vec::new();
    for (j, m) in points.iter().enumerate() {
        let x = position(m, input, &place)?;
        xs.push([x.x, x.y, x.z]);
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
            return Err(place.error(InputKind::Value, m.line, format!(
                "the point ({:.6e}, {:.6e}, {:.6e}) m is {sci_dist:.3e} m from the nearest surface \
                 node ({node}, at ({:.6e}, {:.6e}, {:.6e}) m), beyond the tolerance {sci_tolerance:.3e} m: \
                 check the file's units (m) and frame, or raise measured.{name}.tolerance",
                crate::error::Sci(x.x),
                crate::error::Sci(x.y),
                crate::error::Sci(x.z),
                crate::error::Sci(y.x),
                crate::error::Sci(y.y),
                crate::error::Sci(y.z), sci_dist = crate::error::Sci(dist), sci_tolerance = crate::error::Sci(tolerance))));
        }
        let other = line_of[node];
        if other != 0 {
            return Err(place.error(
                InputKind::Value,
                m.line,
                format!(
                    "the point takes surface node {node}, which line {other} already took: two \
                 measured points closer to each other than to any other node; thin the \
                 measurements or refine the surface",
                ),
            ));
        }
        line_of[node] = m.line;
        taken.push((node, m.line));
        values.push([m.u.x, m.u.y, m.u.z]);
        rows.push(vec![(j as u32, 1.0)]);
    }
    Ok(Boundary {
        name: name.into(),
        nodes: taken.iter().map(|t| t.0).collect(),
        components: [Some(0.0); 3],
        node_values: Some(values.clone()),
        curve: load_curve(scene, &spec.curve)?,
        measured: Some(std::sync::Arc::new(MeasuredMap {
            points: xs,
            rows,
            values,
        })),
    })
}

/// Where a measured point was given: its boundary's name and file.
struct Place<'a> {
    name: &'a str,
    path: &'a std::path::Path,
}

impl Place<'_> {
    /// "measured 'NAME' (FILE line N)", the start of every message about a point.
    fn text(&self, line: usize) -> String {
        format!(
            "measured '{}' ({} line {line})",
            self.name,
            self.path.display()
        )
    }

    /// An error about the point on `line`: the sentence after [`Self::text`], with the file,
    /// line and key (`measured.NAME`) as facts.
    fn error(&self, kind: InputKind, line: usize, sentence: String) -> Error {
        Error::input(kind, format!("{}: {sentence}", self.text(line)))
            .placed(self.path, line)
            .key(format!("measured.{}", self.name))
    }
}

/// The measured points with each position given once: a point repeated with the same
/// displacement is kept once (and said); one repeated with another displacement is an error
/// naming both lines (which value holds there is the user's to say, not a blend of the two).
fn without_repeats(
    points: Vec<crate::io::measured::Measured>,
    input: Option<&MeshInput>,
    place: &Place,
) -> Result<Vec<crate::io::measured::Measured>> {
    let key = |x: Vector3<f64>| x.map(|v| if v == 0.0 { 0u64 } else { v.to_bits() });
    let mut first: std::collections::HashMap<Vector3<u64>, usize> = Default::default();
    let mut kept: Vec<crate::io::measured::Measured> = Vec::with_capacity(points.len());
    let mut repeats = Vec::new();
    for m in points {
        let x = position(&m, input, place)?;
        match first.get(&key(x)) {
            None => {
                first.insert(key(x), kept.len());
                kept.push(m);
            }
            Some(&k) if kept[k].u == m.u => repeats.push((m.line, kept[k].line)),
            Some(&k) => {
                return Err(place.error(InputKind::Value, m.line, format!(
                    "the point ({:.6e}, {:.6e}, {:.6e}) m is given again with another displacement                      ({:.6e}, {:.6e}, {:.6e}) m; line {} gives ({:.6e}, {:.6e}, {:.6e}) m there: keep one of them",
                    crate::error::Sci(x.x),
                    crate::error::Sci(x.y),
                    crate::error::Sci(x.z),
                    crate::error::Sci(m.u.x),
                    crate::error::Sci(m.u.y),
                    crate::error::Sci(m.u.z),
                    kept[k].line,
                    crate::error::Sci(kept[k].u.x),
                    crate::error::Sci(kept[k].u.y),
                    crate::error::Sci(kept[k].u.z))))
            }
        }
    }
    if let Some((line, of)) = repeats.first() {
        log::warn!(
            "{}: {} point(s) repeat an earlier line with the same displacement (line {line} repeats line {of}); each is used once",
            place.text(*line),
            repeats.len()
        );
    }
    Ok(kept)
}

/// A measured point's position: as written, or the mesh file's node it names.
fn position(
    m: &crate::io::measured::Measured,
    input: Option<&MeshInput>,
    place: &Place,
) -> Result<Vector3<f64>> {
    match m.at {
        MeasuredAt::Position(x) => Ok(x),
        MeasuredAt::Node(id) => {
            let file = input.ok_or_else(|| {
                place.error(
                    InputKind::Value,
                    m.line,
                    format!(
                        "node id {id} needs a mesh file (geometry.mesh); give positions \
                     x, y, z, ux, uy, uz instead",
                    ),
                )
            })?;
            let k = file.node_ids.iter().position(|&n| n == id).ok_or_else(|| {
                place.error(
                    InputKind::Selection,
                    m.line,
                    format!("the mesh file has no node {id}",),
                )
            })?;
            Ok(file.mesh.nodes[k])
        }
    }
}

/// Measured points each node's value is fitted to.
const FIT_POINTS: usize = 12;

/// `interpolate = true`: the surface nodes within `reach` of a measured point (default: the
/// measurements' spacing, the median distance from a point to its nearest neighbour) and on
/// their patch (within 1e-3 x the body's diagonal, plus three times the neighbours' spread
/// across it, of the plane the nearest measured points span) take the
/// displacement of a linear moving least-squares fit to the [`FIT_POINTS`] nearest measured
/// points (weights (1 - (d / r)^2)^2 with r 1.5 x the farthest of them; the moment matrix
/// pseudo-inverted, so points on a plane or a line fit in their own span). It reproduces any
/// linear field exactly at any spacing; for a smooth field its error is of the order of the
/// spacing squared times the field's second derivatives. Returns the nodes and, per node, the
/// fit's weights on the measured points (its value is their weighted sum).
#[allow(clippy::type_complexity)]
fn interpolated(
    name: &str,
    path: &std::path::Path,
    xs: &[Vector3<f64>],
    (nodes, candidates): (&[Vector3<f64>], &[usize]),
    (reach, off_patch): (Option<f64>, f64),
) -> Result<(Vec<usize>, Vec<Vec<(u32, f64)>>)> {
    use kiddo::{ImmutableKdTree, SquaredEuclidean};
    use nalgebra::{Matrix4, Vector4};
    let what = || format!("measured '{name}' ({})", path.display());
    if xs.len() < 3 {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "{}: {} point(s); interpolation needs at least 3 (or set interpolate = false to \
             match points to nodes)",
                what(),
                xs.len()
            ),
        ));
    }
    let pts: Vec<[f64; 3]> = xs.iter().map(|x| [x.x, x.y, x.z]).collect();
    let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&pts).map_err(|e| {
        Error::input(
            InputKind::Value,
            format!("{}: cannot index the points: {e:?}", what()),
        )
    })?;
    let two = std::num::NonZero::new(2).expect("2 > 0");
    let mut gaps: Vec<f64> = pts
        .iter()
        .filter_map(|q| {
            let nn = tree
                .query(q)
                .nearest_n::<SquaredEuclidean<f64>>(two)
                .execute();
            nn.get(1).map(|n| n.distance.sqrt())
        })
        .collect();
    gaps.sort_by(f64::total_cmp);
    let spacing = gaps[gaps.len() / 2];
    let reach = reach.unwrap_or(spacing);
    let k = std::num::NonZero::new(FIT_POINTS.min(xs.len())).expect("at least 3");
    let (mut taken, mut rows) = (Vec::new(), Vec::new());
    for &i in candidates {
        let y = nodes[i];
        let q = [y.x, y.y, y.z];
        let near = tree
            .query(&q)
            .nearest_n::<SquaredEuclidean<f64>>(k)
            .execute();
        if near.first().is_none_or(|n| n.distance.sqrt() > reach) {
            continue;
        }
        // Only nodes on the measured patch: measurements on a surface say nothing about the
        // nodes below it (a side node 12.5 mm under a measured top face would take the top's
        // value). The patch's normal is its neighbours' direction of least spread.
        let c: Vector3<f64> = near
            .iter()
            .map(|n| xs[n.item as usize])
            .sum::<Vector3<f64>>()
            / near.len() as f64;
        let cov = near.iter().fold(nalgebra::Matrix3::zeros(), |m, n| {
            let d = xs[n.item as usize] - c;
            m + d * d.transpose()
        }) / near.len() as f64;
        let eig = cov.symmetric_eigen();
        let (kmin, lmin) =
            eig.eigenvalues
                .iter()
                .enumerate()
                .fold(
                    (0, f64::INFINITY),
                    |b, (k, &l)| if l < b.1 { (k, l) } else { b },
                );
        let normal = eig.eigenvectors.column(kmin).into_owned();
        if (y - c).dot(&normal).abs() > off_patch + 3.0 * lmin.max(0.0).sqrt() {
            continue;
        }
        let r = 1.5 * near.last().map_or(0.0, |n| n.distance.sqrt()).max(1e-300);
        let mut a = Matrix4::<f64>::zeros();
        let mut pw: Vec<(u32, Vector4<f64>)> = Vec::with_capacity(near.len());
        for n in &near {
            let j = n.item as usize;
            let d = (xs[j] - y) / r;
            let w = (1.0 - d.norm_squared()).max(0.0).powi(2);
            let p = Vector4::new(1.0, d.x, d.y, d.z);
            a += p * p.transpose() * w;
            pw.push((j as u32, p * w));
        }
        let inv = a.pseudo_inverse(1e-10 * a.norm()).map_err(|e| {
            Error::input(
                InputKind::Value,
                format!("{}: fit at node {i}: {e}", what()),
            )
        })?;
        // The fit's value at the node is the first coefficient, row 0 of the inverse applied
        // to sum_j p_j w_j u_j: linear in the measurements, with these weights.
        let row0 = inv.row(0);
        rows.push(
            pw.iter()
                .map(|(j, p)| (*j, row0.dot(&p.transpose())))
                .collect::<Vec<_>>(),
        );
        taken.push(i);
    }
    if taken.is_empty() {
        return Err(Error::input(InputKind::Value, format!(
            "{}: no surface node lies within {sci_reach:.3e} m of the {} measured points: check the \
             file's units (m) and frame, or raise measured.{name}.tolerance",
            what(),
            xs.len()
        , sci_reach = crate::error::Sci(reach))));
    }
    log::info!(
        "measured '{name}': {} points (spacing {spacing:.3e} m) interpolated onto {} surface nodes",
        xs.len(),
        taken.len()
    );
    Ok((taken, rows))
}
