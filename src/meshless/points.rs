//! Quadrature points of the meshless discretization and shape-function evaluation with support growth.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::mls::{self, MlsError, MlsSettings};
use super::support::{Support, SupportRule};
use crate::quadrature::{PointKind, QuadraturePoints};
use crate::{Error, InputKind, Result};

/// Support growth factors tried, in order, when a moment matrix is too ill-conditioned.
const GROWTH: [f64; 5] = [1.0, 1.25, 1.5, 1.75, 2.0];

/// The nearest-node rule goes on to 3x and 4x the node count: on a finely sampled flat face
/// (the bonded base of the 21,000-node brain) the 16 nearest nodes of a face node can all lie
/// in the face, and a few more nodes cost little, unlike 3x a support radius (27x the nodes).
const GROWTH_NEAREST: [f64; 7] = [1.0, 1.25, 1.5, 1.75, 2.0, 3.0, 4.0];

/// The growth factors for `support`'s rule.
fn growth(support: &Support) -> &'static [f64] {
    match support.rule {
        SupportRule::Nearest { .. } => &GROWTH_NEAREST,
        SupportRule::Radius { .. } => &GROWTH,
    }
}

/// Shape functions at one point: support node ids (ascending), phi and dphi/dX (1/m).
#[derive(Debug, Clone, Default)]
pub struct ShapeAt {
    pub ids: Vec<usize>,
    pub phi: Vec<f64>,
    pub dphi: Vec<Vector3<f64>>,
}

/// Scratch reused across evaluations so the preprocessing loop allocates little.
#[derive(Default)]
struct Scratch {
    ids: Vec<usize>,
    radii: Vec<f64>,
    pos: Vec<Vector3<f64>>,
}

/// Evaluates the shape functions (and with `derivatives`, dphi/dX) at `x` (m). An
/// ill-conditioned moment matrix grows the support up to 2x before it becomes an error that
/// names `what`, the position and the support (the nearest-node rule grows to 4x its node
/// count).
pub fn shape_at(
    support: &Support,
    s: &MlsSettings,
    x: &Vector3<f64>,
    derivatives: bool,
    what: &dyn Fn() -> String,
) -> Result<ShapeAt> {
    let mut out = ShapeAt::default();
    let mut sc = Scratch::default();
    shape_into(support, s, x, derivatives, &mut sc, &mut out, what)?;
    Ok(out)
}

fn shape_into(
    support: &Support,
    s: &MlsSettings,
    x: &Vector3<f64>,
    derivatives: bool,
    sc: &mut Scratch,
    out: &mut ShapeAt,
    what: &dyn Fn() -> String,
) -> Result<()> {
    let mut last: Option<MlsError> = None;
    let factors = growth(support);
    for &g in factors {
        support.find(x, g, &mut sc.ids, &mut sc.radii);
        sc.pos.clear();
        sc.pos.extend(sc.ids.iter().map(|&i| support.nodes[i]));
        let r = if derivatives {
            mls::shape_functions(x, &sc.pos, &sc.radii, s, &mut out.phi, &mut out.dphi)
        } else {
            out.dphi.clear();
            mls::shape_values(x, &sc.pos, &sc.radii, s, &mut out.phi)
        };
        match r {
            Ok(()) => {
                out.ids.clear();
                out.ids.extend_from_slice(&sc.ids);
                return Ok(());
            }
            Err(e) => last = Some(e),
        }
    }
    let shown: Vec<String> = sc.ids.iter().take(40).map(|i| i.to_string()).collect();
    Err(Error::input(InputKind::Discretization, format!(
        "{} at ({:.6e}, {:.6e}, {:.6e}) m: {} with its support of {} nodes [{}{}] even after growing the support to {}x. \
         The nodes around this point are too few or (nearly) coplanar: refine the cloud there, raise \
         discretization.dilatation / support_nodes, or use basis = 'quadratic' (MMLS)",
        what(),
        crate::error::Sci(x.x),
        crate::error::Sci(x.y),
        crate::error::Sci(x.z),
        last.map(|e| e.to_string()).unwrap_or_default(),
        sc.ids.len(),
        shown.join(", "),
        if sc.ids.len() > 40 { ", ..." } else { "" },
        factors.last().copied().unwrap_or(1.0),
)))
}

/// Refuses a point table that would not fit in memory before it is built: the mean support
/// size of up to 64 evenly spaced points (found at the unit support, before any growth) times
/// the points and [`crate::memory::BYTES_PER_SLOT`].
fn check_memory(support: &Support, positions: &[Vector3<f64>]) -> Result<()> {
    let n = positions.len();
    if n == 0 {
        return Ok(());
    }
    let samples = n.min(64);
    let (mut ids, mut radii) = (Vec::new(), Vec::new());
    let mut total = 0usize;
    for k in 0..samples {
        support.find(&positions[k * n / samples], 1.0, &mut ids, &mut radii);
        total += ids.len();
    }
    let mean = total as f64 / samples as f64;
    crate::memory::check(
        n as f64 * mean * crate::memory::BYTES_PER_SLOT,
        &format!(
            "the meshless point table ({n} integration points x about {mean:.0} support nodes)"
        ),
        "use fewer integration points (discretization.point_ratio, tet_rule, tets_per_point) or \
         smaller supports (discretization.support_nodes, dilatation), or a coarser cloud",
    )
}

/// Quadrature points of the meshless discretization: for every integration point (positions
/// m, weights m^3) its support and dphi/dX. Built in parallel in fixed chunks and concatenated
/// in point order, so the result does not depend on the number of threads.
pub fn build_points(
    support: &Support,
    s: &MlsSettings,
    positions: &[Vector3<f64>],
    weights: &[f64],
) -> Result<QuadraturePoints> {
    const CHUNK: usize = 512;
    check_memory(support, positions)?;
    // Per chunk: support sizes, node ids, dphi.
    type Chunk = (Vec<usize>, Vec<u32>, Vec<Vector3<f64>>);
    let chunks: Vec<Result<Chunk>> = positions
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, xs)| {
            // A stop request (Ctrl-C, SIGTERM) ends the build within a chunk (512 points).
            crate::interrupt::check(|| "while building the meshless shape functions".into())?;
            let mut sc = Scratch::default();
            let mut sh = ShapeAt::default();
            let mut counts = Vec::with_capacity(xs.len());
            let mut ids = Vec::new();
            let mut dphi = Vec::new();
            for (k, x) in xs.iter().enumerate() {
                let p = c * CHUNK + k;
                shape_into(support, s, x, true, &mut sc, &mut sh, &|| {
                    format!("integration point {p}")
                })?;
                counts.push(sh.ids.len());
                ids.extend(sh.ids.iter().map(|&i| i as u32));
                dphi.extend_from_slice(&sh.dphi);
            }
            Ok((counts, ids, dphi))
        })
        .collect();
    let slots: usize = chunks
        .iter()
        .map(|c| c.as_ref().map_or(0, |c| c.1.len()))
        .sum();
    let mut qp = QuadraturePoints::with_capacity(positions.len(), slots);
    let mut p = 0;
    for chunk in chunks {
        let (counts, ids, dphi) = chunk?;
        let mut at = 0;
        for n in counts {
            qp.nodes.extend_from_slice(&ids[at..at + n]);
            qp.dphi.extend_from_slice(&dphi[at..at + n]);
            qp.weights.push(weights[p]);
            qp.kinds.push(PointKind::Standard);
            qp.offsets.push(qp.nodes.len());
            at += n;
            p += 1;
        }
    }
    Ok(qp)
}

/// Number of integration points whose support contains each node.
pub fn support_counts(qp: &QuadraturePoints, num_nodes: usize) -> Vec<usize> {
    let mut c = vec![0usize; num_nodes];
    for &n in &qp.nodes {
        c[n as usize] += 1;
    }
    c
}

/// (mean, min, max) number of support nodes per integration point.
pub fn support_statistics(qp: &QuadraturePoints) -> (f64, usize, usize) {
    let sizes = (0..qp.len()).map(|p| qp.slots(p).len());
    let (mut min, mut max, mut sum) = (usize::MAX, 0usize, 0usize);
    for n in sizes {
        min = min.min(n);
        max = max.max(n);
        sum += n;
    }
    if qp.is_empty() {
        return (0.0, 0, 0);
    }
    (sum as f64 / qp.len() as f64, min, max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::meshless::support::SupportRule;

    #[test]
    fn coplanar_support_is_an_error_naming_point_position_and_support() {
        // All nodes in the plane z = 0: a linear basis cannot be determined, at any growth.
        let mut nodes = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                nodes.push(Vector3::new(i as f64 * 0.01, j as f64 * 0.01, 0.0));
            }
        }
        let sup = Support::new(nodes, SupportRule::Radius { dilatation: 1.6 }, None).unwrap();
        let x = Vector3::new(0.021, 0.022, 0.0);
        let err = shape_at(&sup, &MlsSettings::default(), &x, true, &|| {
            "integration point 7".into()
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains("integration point 7"), "{err}");
        assert!(err.contains("2.1"), "position missing: {err}");
        assert!(err.contains("support of"), "{err}");
        assert!(err.contains("coplanar"), "{err}");
    }

    /// A 9 x 9 face of nodes at spacing 1 on z = 0 and a sparse layer at z = 2.5 above it: the
    /// 21 nearest nodes of the face centre lie in the face, so 8 nearest grown to 2x (16) are
    /// coplanar; the nearest rule grows on to 4x, takes in the layer above, and reproduces
    /// linear fields. The radius rule still stops at 2x.
    #[test]
    fn nearest_support_grows_past_a_finely_sampled_face() {
        let mut nodes = Vec::new();
        for i in 0..9 {
            for j in 0..9 {
                nodes.push(Vector3::new(i as f64, j as f64, 0.0));
            }
        }
        for i in 0..3 {
            for j in 0..3 {
                nodes.push(Vector3::new(
                    2.0 + 2.0 * i as f64,
                    2.0 + 2.0 * j as f64,
                    2.5,
                ));
            }
        }
        let x = Vector3::new(4.0, 4.0, 0.0);
        let sup = Support::new(
            nodes.clone(),
            SupportRule::Nearest { n: 8, alpha: 10.0 },
            None,
        )
        .unwrap();
        let sh = shape_at(&sup, &MlsSettings::default(), &x, true, &|| {
            "face node".into()
        })
        .unwrap();
        assert!(
            sh.ids.len() > 16 && sh.ids.len() <= 32,
            "{} nodes",
            sh.ids.len()
        );
        assert!(sh.ids.iter().any(|&i| nodes[i].z > 0.0));
        let lin = |p: &Vector3<f64>| 0.3 + 1.5 * p.x - 0.7 * p.y + 2.0 * p.z;
        let (mut v, mut g) = (0.0, Vector3::zeros());
        for (k, &i) in sh.ids.iter().enumerate() {
            v += sh.phi[k] * lin(&nodes[i]);
            g += sh.dphi[k] * lin(&nodes[i]);
        }
        assert!((v - lin(&x)).abs() < 1e-10, "value {v} vs {}", lin(&x));
        assert!(
            (g - Vector3::new(1.5, -0.7, 2.0)).norm() < 1e-8,
            "gradient {g}"
        );

        let sup = Support::new(nodes, SupportRule::Radius { dilatation: 1.6 }, None).unwrap();
        if let Err(e) = shape_at(&sup, &MlsSettings::default(), &x, true, &|| {
            "face node".into()
        }) {
            assert!(e.to_string().contains("growing the support to 2x"), "{e}");
        }
    }
}
