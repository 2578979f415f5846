//! A scene's meshless discretization: nodes, background integration, supports, shape
//! functions, and removal of nodes that too few supports reach (Horton 2010 sect. 2.5).

use nalgebra::Vector3;

use super::adaptive::{self, AdaptiveSettings};
use super::integration::{self, TetRule};
use super::mls::{self, MlsSettings};
use super::points::{build_points, shape_at, support_counts, support_statistics};
use super::support::{Support, SupportRule};
use super::{cloud, points::ShapeAt};
use crate::geometry::domain::Domain;
use crate::geometry::{ElementShape, Mesh};
use crate::quadrature::QuadraturePoints;
use crate::report::AdaptiveInfo;
use crate::scene::{self, CloudKind, ElementName, Geometry, IntegrationKind, Scene, SupportKind};
use crate::{Error, Result};

/// The built meshless discretization of a scene.
pub struct MeshlessBuild {
    /// Field nodes, m (after removing nodes reached by fewer than two supports).
    pub nodes: Vec<Vector3<f64>>,
    /// Background tetrahedra over `background.nodes` (no cells for grid integration of a
    /// cloud without tets): the geometry written to VTU and triangulating the boundary.
    pub background: Mesh,
    /// For each background vertex, its field node (usize::MAX when removed).
    pub background_node: Vec<usize>,
    pub points: QuadraturePoints,
    /// Integration point positions, m.
    pub positions: Vec<Vector3<f64>>,
    /// Background tet of each integration point (usize::MAX for grid points).
    pub owner: Vec<usize>,
    pub support: Support,
    pub mls: MlsSettings,
    pub removed_nodes: usize,
    /// Exact volume of the scene's shape, m^3.
    pub exact_volume: f64,
    /// How the nodes and points were made, for reports.
    pub cloud: String,
    pub integration: String,
    pub warnings: Vec<String>,
    /// What adaptive integration did (None for other integration kinds).
    pub adaptive: Option<AdaptiveInfo>,
    /// Refinement level of each integration point (adaptive integration; empty otherwise).
    pub point_level: Vec<u8>,
}

impl MeshlessBuild {
    /// Shape functions (values only) at `x` (m).
    pub fn shape_values(&self, x: &Vector3<f64>, what: &dyn Fn() -> String) -> Result<ShapeAt> {
        shape_at(&self.support, &self.mls, x, false, what)
    }

    /// (mean, min, max) support nodes per integration point.
    pub fn support_statistics(&self) -> (f64, usize, usize) {
        support_statistics(&self.points)
    }
}

/// The scene's shape as a meshless domain (None for a mesh file, whose shape is its cells).
pub fn domain(scene: &Scene) -> Option<Domain> {
    match &scene.geometry {
        Geometry::Box { min, max } => Some(Domain::Box {
            min: Vector3::from(*min),
            max: Vector3::from(*max),
        }),
        Geometry::Cylinder { radius, height } => Some(Domain::Cylinder {
            radius: *radius,
            height: *height,
        }),
        Geometry::HalfEllipsoid { semi_axes } => Some(Domain::HalfEllipsoid {
            semi_axes: Vector3::from(*semi_axes),
        }),
        Geometry::Mesh { .. } => None,
    }
}

fn need_domain(scene: &Scene, what: &str) -> Result<Domain> {
    domain(scene).ok_or_else(|| {
        Error::Input(format!(
            "{what} needs a built-in shape (box or cylinder); with geometry.mesh use cloud = 'mesh' or 'file' and integration = 'tets'"
        ))
    })
}

/// Node spacing (m) the scene's sizing asks for: `size`, or the smallest division length.
pub fn spacing(scene: &Scene) -> Result<f64> {
    let d = &scene.discretization;
    if let Some(h) = d.size {
        return Ok(h);
    }
    let div = d.divisions.ok_or_else(|| {
        Error::Input("discretization: give `size` (node spacing, m) or `divisions`".into())
    })?;
    Ok(match &scene.geometry {
        Geometry::Box { min, max } => (0..3)
            .map(|k| (max[k] - min[k]) / div[k].max(1) as f64)
            .fold(f64::INFINITY, f64::min),
        Geometry::Cylinder { radius, height } => {
            (radius / div[0].max(1) as f64 * 2.0).min(height / div[2].max(1) as f64)
        }
        // As the box: the bounding box [2a, 2b, c] divided by [nx, ny, nz].
        Geometry::HalfEllipsoid { semi_axes: s } => [2.0 * s[0], 2.0 * s[1], s[2]]
            .iter()
            .zip(div)
            .map(|(len, n)| len / n.max(1) as f64)
            .fold(f64::INFINITY, f64::min),
        Geometry::Mesh { .. } => {
            return Err(Error::Input(
                "a node spacing from `divisions` needs a built-in shape; give discretization.size"
                    .into(),
            ))
        }
    })
}

pub fn mls_settings(scene: &Scene) -> MlsSettings {
    let d = &scene.discretization;
    MlsSettings {
        basis: match d.basis {
            scene::Basis::Linear => mls::Basis::Linear,
            scene::Basis::Quadratic => mls::Basis::Quadratic,
        },
        mu: d.mu,
        min_rcond: d.min_rcond,
    }
}

pub fn support_rule(scene: &Scene) -> SupportRule {
    let d = &scene.discretization;
    let quadratic = d.basis == scene::Basis::Quadratic;
    match d.support {
        SupportKind::Radius => SupportRule::Radius {
            dilatation: d.dilatation.unwrap_or(if quadratic { 2.0 } else { 1.6 }),
        },
        SupportKind::Nearest => SupportRule::Nearest {
            n: d.support_nodes.unwrap_or(if quadratic { 16 } else { 8 }),
            alpha: d.alpha,
        },
    }
}

/// The nodes (m) of a generated cloud (`cloud = "lattice"` or `"halton"`) over the scene's
/// built-in shape, a description of it, and its spacing h (m).
pub fn generated_cloud(scene: &Scene) -> Result<(Vec<Vector3<f64>>, String, f64)> {
    let d = &scene.discretization;
    let h = spacing(scene)?;
    match d.cloud {
        CloudKind::Lattice => Ok((
            cloud::jittered_lattice(
                &need_domain(scene, "cloud = 'lattice'")?,
                h,
                d.jitter,
                d.seed,
            )?,
            format!(
                "lattice h = {h:.4e} m, jitter {}, seed {}",
                d.jitter, d.seed
            ),
            h,
        )),
        CloudKind::Halton => {
            let domain = &need_domain(scene, "cloud = 'halton'")?;
            // Fill to saturation (random sequential packing at 0.85 h is about as dense as the
            // lattice of spacing h); the cap only bounds the work.
            let count = 3 * cloud::jittered_lattice(domain, h, 0.0, 0)?.len();
            Ok((
                cloud::halton_fill(domain, count, d.min_spacing * h, d.seed)?,
                format!(
                    "Halton fill, min spacing {:.4e} m, seed {}",
                    d.min_spacing * h,
                    d.seed
                ),
                h,
            ))
        }
        other => Err(Error::Input(format!(
            "cloud = '{other:?}' is not a generated cloud (use 'lattice' or 'halton')"
        ))),
    }
}

/// Nodes (and background tets when the nodes come from a tet mesh or Delaunay) of the scene.
fn nodes_and_tets(scene: &Scene) -> Result<(Mesh, String)> {
    let d = &scene.discretization;
    // Tets integrate, and their boundary faces carry the EBCIEM boundary integrals.
    let tets_wanted =
        d.integration.uses_tets() || d.bc_method.resolve(d.support) == scene::BcMethod::Ebciem;
    let (nodes, name) = match d.cloud {
        CloudKind::Mesh => {
            let mut s = scene.clone();
            if s.discretization.element == ElementName::Hex8 {
                s.discretization.element = ElementName::Tet4;
            }
            let mesh = hex_to_tets(crate::simulation::build_mesh(&s)?);
            let (nodes, map) = cloud::mesh_vertices(&mesh);
            let cells: Vec<usize> = mesh.cells.iter().map(|&i| map[i]).collect();
            let name = format!(
                "vertices of a {} tet mesh",
                if d.mesher == scene::Mesher::Tetgen {
                    "TetGen"
                } else {
                    "structured"
                }
            );
            let bg = Mesh {
                nodes,
                shape: ElementShape::Tet4,
                cells,
            };
            return Ok((bg, name));
        }
        CloudKind::Lattice | CloudKind::Halton => {
            let (nodes, name, _) = generated_cloud(scene)?;
            (nodes, name)
        }
        CloudKind::File => {
            let rel = d.cloud_file.clone().unwrap_or_default();
            let path = if rel.is_absolute() {
                rel
            } else {
                scene.base_dir.join(rel)
            };
            let nodes = cloud::read_cloud(&path)?;
            (nodes, format!("file {}", path.display()))
        }
    };
    let cells = if tets_wanted {
        delaunay(&nodes)?
    } else {
        Vec::new()
    };
    Ok((
        Mesh {
            nodes,
            shape: ElementShape::Tet4,
            cells,
        },
        name,
    ))
}

/// Hexahedra split into six tets around the 0-6 diagonal (they tile each hex exactly, which is
/// all integration and the boundary triangles need; tets of neighbouring hexes need not match).
pub fn hex_to_tets(mesh: Mesh) -> Mesh {
    if mesh.shape == ElementShape::Tet4 {
        return mesh;
    }
    const SPLIT: [[usize; 4]; 6] = [
        [0, 1, 2, 6],
        [0, 2, 3, 6],
        [0, 3, 7, 6],
        [0, 7, 4, 6],
        [0, 4, 5, 6],
        [0, 5, 1, 6],
    ];
    let mut cells = Vec::with_capacity(mesh.num_cells() * 24);
    for e in 0..mesh.num_cells() {
        let c = mesh.cell(e);
        for t in SPLIT {
            let mut q = t.map(|a| c[a]);
            let p = |i: usize| mesh.nodes[q[i]];
            if crate::geometry::quality::tet_signed_volume(&p(0), &p(1), &p(2), &p(3)) < 0.0 {
                q.swap(2, 3);
            }
            cells.extend(q);
        }
    }
    Mesh {
        nodes: mesh.nodes,
        shape: ElementShape::Tet4,
        cells,
    }
}

/// Delaunay tetrahedralization of `nodes` (TetGen), as flat node-index quadruples.
#[cfg(feature = "tetgen")]
pub fn delaunay(nodes: &[Vector3<f64>]) -> Result<Vec<usize>> {
    Ok(crate::geometry::tetgen::delaunay(nodes)?
        .into_iter()
        .flatten()
        .collect())
}

/// Without TetGen: an error that says how to do without.
#[cfg(not(feature = "tetgen"))]
pub fn delaunay(_nodes: &[Vector3<f64>]) -> Result<Vec<usize>> {
    Err(Error::Input(
        "integration = 'tets' on a generated or file cloud needs a Delaunay tetrahedralization (feature `tetgen`); \
         use integration = 'grid' or cloud = 'mesh'"
            .into(),
    ))
}

/// Given the field nodes, the ones that carry a boundary condition or a probe.
pub type ProtectedNodes<'a> = dyn Fn(&[Vector3<f64>]) -> Result<Vec<usize>> + 'a;

/// The scene's rule per background tet (`tet_rule`: 1, 4 or 5 points).
pub fn tet_rule(scene: &Scene) -> Result<TetRule> {
    let n = scene.discretization.tet_rule();
    TetRule::from_points(n)
        .ok_or_else(|| Error::Input(format!("discretization.tet_rule = {n}: use 1, 4 or 5")))
}

/// The scene's adaptive-integration settings: `tolerance`, `tet_rule` (the base rule),
/// `subdivision`, `max_level`.
pub fn adaptive_settings(scene: &Scene) -> Result<AdaptiveSettings> {
    let d = &scene.discretization;
    Ok(AdaptiveSettings {
        tolerance: d.tolerance,
        rule: tet_rule(scene)?,
        subdivision: d.subdivision,
        max_level: d.max_level,
    })
}

/// Adaptive integration points (thesis chapter 5) of the tet mesh `tets` for the shape functions
/// of `support`, driven by the less-smooth integrand of thesis eq. 5.5, with the report of what
/// the refinement did. Serves meshless scenes and coupled interiors.
pub fn adaptive_tet_points(
    settings: &AdaptiveSettings,
    tets: &Mesh,
    support: &Support,
    mls: &MlsSettings,
) -> Result<(adaptive::AdaptivePoints, AdaptiveInfo)> {
    let a = adaptive::adaptive_points(tets, settings, |x| {
        let sh = shape_at(support, mls, x, true, &|| {
            "adaptive-integration trial point".to_string()
        })?;
        Ok(adaptive::less_smooth(&sh.dphi))
    })?;
    let info = AdaptiveInfo {
        tolerance: settings.tolerance,
        subdivision: settings.subdivision,
        max_level: settings.max_level,
        points_before: a.points_before,
        points_after: a.positions.len(),
        deepest_level: a.deepest_level(),
        leaves_per_level: a.leaves_per_level.clone(),
    };
    Ok((a, info))
}

/// Builds the meshless discretization. `protected(nodes)` returns the nodes that carry a
/// boundary condition or a probe: removing one of those is an error.
pub fn build(scene: &Scene, protected: &ProtectedNodes) -> Result<MeshlessBuild> {
    let d = &scene.discretization;
    let (background, cloud_name) = nodes_and_tets(scene)?;
    let mls = mls_settings(scene);
    let rule = support_rule(scene);

    let tets: Vec<[usize; 4]> = background
        .cells
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    let full = Support::new(
        background.nodes.clone(),
        rule,
        (!tets.is_empty()).then_some(tets.as_slice()),
    )?;
    let mut adaptive_info = None;
    let mut point_level = Vec::new();
    let (positions, weights, owner, integration_name) = match d.integration {
        IntegrationKind::Adaptive => {
            let (a, info) =
                adaptive_tet_points(&adaptive_settings(scene)?, &background, &full, &mls)?;
            let name = format!(
                "{} background tets, {}",
                background.num_cells(),
                info.line()
            );
            adaptive_info = Some(info);
            point_level = a.level;
            (a.positions, a.weights, a.owner, name)
        }
        IntegrationKind::Tets => {
            let (p, w, o) = integration::tet_points(&background, tet_rule(scene)?)?;
            match integration::cluster_bin(&background, &w, d.tets_per_point()) {
                Some(bin) => {
                    let (p, w, o) = integration::cluster_points(&p, &w, &o, bin);
                    let name = format!(
                        "{} background tets x {} points merged into {} (about {} tets per point)",
                        background.num_cells(),
                        d.tet_rule(),
                        p.len(),
                        d.tets_per_point()
                    );
                    (p, w, o, name)
                }
                None => {
                    let name = format!(
                        "{} background tets x {} points",
                        background.num_cells(),
                        d.tet_rule()
                    );
                    (p, w, o, name)
                }
            }
        }
        IntegrationKind::Grid => {
            let dom = need_domain(scene, "integration = 'grid'")?;
            let (p, w) = integration::grid_points(&dom, background.nodes.len(), d.point_ratio)?;
            let o = vec![usize::MAX; p.len()];
            let name = format!("regular grid, {} points per node", d.point_ratio);
            (p, w, o, name)
        }
    };
    if positions.is_empty() {
        return Err(Error::Input("the meshless discretization has no integration points; refine the grid (point_ratio) or check the cloud".into()));
    }

    // Field nodes: the background vertices, less those reached by fewer than two supports.
    let mut keep: Vec<usize> = (0..background.nodes.len()).collect();
    let mut removed_total = 0usize;
    let mut warnings = Vec::new();
    for _round in 0..4 {
        let nodes: Vec<Vector3<f64>> = keep.iter().map(|&i| background.nodes[i]).collect();
        let support = full.subset(&keep)?;
        let points = build_points(&support, &mls, &positions, &weights)?;
        let counts = support_counts(&points, nodes.len());
        let low: Vec<usize> = (0..nodes.len()).filter(|&i| counts[i] < 2).collect();
        if low.is_empty() {
            if removed_total > 0 {
                warnings.push(format!(
                    "removed {removed_total} meshless node(s) that fewer than two integration points reach (Horton 2010 sect. 2.5); \
                     add integration points (tet_rule, point_ratio) or enlarge the supports to keep them"
                ));
            }
            let background_node = {
                let mut m = vec![usize::MAX; background.nodes.len()];
                for (new, &old) in keep.iter().enumerate() {
                    m[old] = new;
                }
                m
            };
            return Ok(MeshlessBuild {
                nodes,
                background,
                background_node,
                points,
                positions,
                owner,
                support,
                mls,
                removed_nodes: removed_total,
                exact_volume: domain(scene).map_or(f64::NAN, |d| d.volume()),
                cloud: cloud_name,
                integration: integration_name,
                warnings,
                adaptive: adaptive_info,
                point_level,
            });
        }
        let guarded = protected(&nodes)?;
        if let Some(&g) = guarded.iter().find(|g| low.binary_search(g).is_ok()) {
            return Err(Error::Input(format!(
                "meshless node {} at {:?} m carries a boundary condition or a probe but only {} integration point(s) reach it, \
                 so it would have to be removed; add integration points (tet_rule, point_ratio) or enlarge the supports \
                 (dilatation, support_nodes)",
                keep[g],
                nodes[g].as_slice(),
                counts[g]
            )));
        }
        removed_total += low.len();
        let drop: std::collections::BTreeSet<usize> = low.into_iter().collect();
        keep = keep
            .into_iter()
            .enumerate()
            .filter(|(i, _)| !drop.contains(i))
            .map(|(_, k)| k)
            .collect();
    }
    Err(Error::Input(
        "removing meshless nodes that fewer than two integration points reach did not settle after 4 rounds; \
         the cloud is much coarser than the integration (or the reverse): add integration points or enlarge the supports"
            .into(),
    ))
}
