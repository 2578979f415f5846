//! The meshless discretization: nodes, background integration, supports, shape
//! functions, and removal of nodes that too few supports reach (Horton 2010 sect. 2.5).

use nalgebra::Vector3;

use super::adaptive::{self, AdaptiveSettings};
use super::cloud;
use super::integration::{self, TetRule};
use super::mls::MlsSettings;
use super::points::{build_points, shape_at, support_counts, support_statistics};
use super::support::{Support, SupportRule};
use crate::geometry::domain::Domain;
use crate::geometry::{ElementShape, Mesh};
use crate::quadrature::{QuadraturePoints, SparseRow};
use crate::report::AdaptiveInfo;
use crate::{Error, InputKind, Result};

/// The built meshless discretization of a scene.
pub struct MeshlessBuild {
    /// Field nodes, m (after removing nodes reached by fewer than two supports).
    pub nodes: Vec<Vector3<f64>>,
    /// Background tetrahedra over `background.nodes` (no cells for grid integration of a
    /// cloud without tets): the geometry written to VTU and triangulating the boundary.
    pub background: Mesh,
    /// For each background vertex, its field node (None when it was removed as poorly
    /// supported).
    pub background_node: Vec<Option<usize>>,
    pub points: QuadraturePoints,
    /// Integration point positions, m.
    pub positions: Vec<Vector3<f64>>,
    /// Background tet of each integration point (None for grid points).
    pub owner: Vec<Option<usize>>,
    pub support: Support,
    pub mls: MlsSettings,
    pub removed_nodes: usize,
    /// Exact volume of the scene's shape, m^3 (None for a mesh file: no shape to compare with).
    pub exact_volume: Option<f64>,
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
    /// Shape-function values at `x` (m) in node ids; `what` names the point in errors.
    pub fn shape_values(&self, x: &Vector3<f64>, what: &dyn Fn() -> String) -> Result<SparseRow> {
        let s = shape_at(&self.support, &self.mls, x, false, what)?;
        Ok(s.ids.iter().map(|&i| i as u32).zip(s.phi).collect())
    }

    /// (mean, min, max) support nodes per integration point.
    pub fn support_statistics(&self) -> (f64, usize, usize) {
        support_statistics(&self.points)
    }
}

/// Where the meshless nodes come from.
pub enum CloudSource {
    /// The vertices of this mesh, whose cells (hexahedra split into six tets each) become the
    /// background tets.
    Mesh { mesh: Mesh, description: String },
    /// Nodes (m) generated over the shape or read from a file; background tets by Delaunay
    /// when the integration or EBCIEM needs them.
    Nodes {
        nodes: Vec<Vector3<f64>>,
        description: String,
    },
}

/// How the integration points are made (Horton 2010 sect. 3.2; thesis chapter 5).
#[derive(Debug, Clone, Copy)]
pub enum Integration {
    /// `rule` in every background tet, merged into about one point per `tets_per_point` tets
    /// (1: no merging).
    Tets { rule: TetRule, tets_per_point: f64 },
    /// A regular grid of `point_ratio` points per node over the domain.
    Grid { point_ratio: f64 },
    /// Adaptive subdivision of the background tets.
    Adaptive(AdaptiveSettings),
}

impl Integration {
    /// Background tets are needed to integrate.
    fn uses_tets(&self) -> bool {
        !matches!(self, Integration::Grid { .. })
    }
}

/// Everything the meshless discretization needs, translated from the scene by the caller.
pub struct MeshlessSettings {
    pub cloud: CloudSource,
    /// The body's shape where it is analytic (grid integration, reports); None for a mesh file.
    pub domain: Option<Domain>,
    pub integration: Integration,
    pub mls: MlsSettings,
    pub support: SupportRule,
    /// Background tets wanted even for grid integration: their boundary faces carry the
    /// EBCIEM boundary integrals.
    pub boundary_tets: bool,
    /// Face-connected background tets whose integration points share their mean J
    /// ([`integration::tet_patches`]; 1 = each point its own; grid points have no tet and
    /// keep their own).
    pub mean_dilatation_patch: usize,
}

/// Mean dilatation over patches of about `size` face-connected background tets (issue 40): the
/// points of a patch form one group that shares its weighted mean J, the stress the exact
/// gradient of the patch's energy ([`crate::solver::forces`]), as in the coupled method's tet
/// interior. One J per point locks the linear MLS interior at nu = 0.49: four points per tet
/// make 4-6 volumetric constraints per node. The points are reordered group by group, their
/// positions, owners and levels with them; unchanged for `size` 1 or points without a tet
/// (grid integration).
fn patch_groups(
    points: QuadraturePoints,
    positions: Vec<Vector3<f64>>,
    owner: Vec<Option<usize>>,
    level: Vec<u8>,
    background: &Mesh,
    size: usize,
) -> (
    QuadraturePoints,
    Vec<Vector3<f64>>,
    Vec<Option<usize>>,
    Vec<u8>,
) {
    let tets = background.num_cells();
    let in_tets: Option<Vec<usize>> = owner.iter().map(|t| t.filter(|&t| t < tets)).collect();
    let Some(tet_of) =
        in_tets.filter(|_| size > 1 && tets > 0 && background.shape == ElementShape::Tet4)
    else {
        return (points, positions, owner, level);
    };
    let patch = integration::tet_patches(background, size);
    let order = integration::patch_point_groups(Some(&patch), &tet_of);
    let mut qp = QuadraturePoints::with_capacity(points.len(), points.nodes.len());
    let point = |p: usize| {
        let r = points.slots(p);
        (
            points.nodes[r.clone()]
                .iter()
                .map(|&i| i as usize)
                .collect::<Vec<_>>(),
            points.dphi[r].to_vec(),
            points.weights[p],
        )
    };
    for group in &order {
        if let [p] = group[..] {
            let (ids, dphi, w) = point(p);
            qp.push(&ids, &dphi, w, points.kinds[p]);
        } else {
            qp.push_group(&group.iter().map(|&p| point(p)).collect::<Vec<_>>());
        }
    }
    let flat: Vec<usize> = order.into_iter().flatten().collect();
    let level = if level.len() == flat.len() {
        flat.iter().map(|&p| level[p]).collect()
    } else {
        level
    };
    (
        qp,
        flat.iter().map(|&p| positions[p]).collect(),
        flat.iter().map(|&p| owner[p]).collect(),
        level,
    )
}

/// Nodes and background tets of the settings' cloud, with its description.
fn nodes_and_tets(s: MeshlessSettings) -> Result<(Mesh, String, MeshlessRest)> {
    let tets_wanted = s.integration.uses_tets() || s.boundary_tets;
    let rest = MeshlessRest {
        domain: s.domain,
        integration: s.integration,
        mls: s.mls,
        support: s.support,
        patch: s.mean_dilatation_patch,
    };
    let (nodes, name) = match s.cloud {
        CloudSource::Mesh { mesh, description } => {
            let mesh = hex_to_tets(mesh);
            let (nodes, map) = cloud::mesh_vertices(&mesh);
            // Every vertex a cell uses is kept.
            let cells: Vec<usize> = mesh.cells.iter().filter_map(|&i| map[i]).collect();
            let bg = Mesh {
                nodes,
                shape: ElementShape::Tet4,
                cells,
            };
            return Ok((bg, description, rest));
        }
        CloudSource::Nodes { nodes, description } => (nodes, description),
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
        rest,
    ))
}

/// The settings other than the cloud, once the cloud is consumed.
struct MeshlessRest {
    domain: Option<Domain>,
    integration: Integration,
    mls: MlsSettings,
    support: SupportRule,
    patch: usize,
}

pub use crate::geometry::mesh::hex_to_tets;

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
    Err(Error::input(InputKind::Unsupported,
        "integration = 'tets' on a generated or file cloud needs a Delaunay tetrahedralization (feature `tetgen`); \
         use integration = 'grid' or cloud = 'mesh'",
    ))
}

/// Given the field nodes, the ones that carry a boundary condition or a probe.
pub type ProtectedNodes<'a> = dyn Fn(&[Vector3<f64>]) -> Result<Vec<usize>> + 'a;

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

/// Refuses a meshless build that cannot fit in memory before its supports and points are
/// built: before its background mesh is made, from the mesh planned (`(nodes, tets, what it
/// is)`), and again once the cloud and tets exist. The fewest integration points the
/// integration makes (tets x rule points / tets per point, or nodes x point ratio; adaptive
/// integration is judged later, by [`build_points`]), each with at least the nearest rule's
/// node count (or [`super::support::MIN_NEAREST`]) at [`crate::memory::BYTES_PER_SLOT`].
pub fn check_build_memory(
    planned: &crate::memory::PlannedMesh,
    integration: &Integration,
    rule: SupportRule,
) -> Result<()> {
    let points = match integration {
        Integration::Tets {
            rule,
            tets_per_point,
        } => planned.elements * rule.points() as f64 / tets_per_point.max(1.0),
        Integration::Grid { point_ratio } => planned.nodes * point_ratio,
        Integration::Adaptive(_) => return Ok(()),
    };
    let support = match rule {
        SupportRule::Nearest { n, .. } => n,
        SupportRule::Radius { .. } => super::support::MIN_NEAREST,
    };
    crate::memory::check(
        points * support as f64 * crate::memory::BYTES_PER_SLOT,
        &format!(
            "the meshless point table (at least {points:.0} integration points x {support} support nodes, on {})", planned.what
        ),
        "use a coarser cloud (discretization.size), fewer integration points (discretization.tet_rule, \
         tets_per_point, point_ratio) or smaller supports (discretization.support_nodes, dilatation)",
    )
}

/// Builds the meshless discretization. `protected(nodes)` returns the nodes that carry a
/// boundary condition or a probe: removing one of those is an error.
pub fn build(settings: MeshlessSettings, protected: &ProtectedNodes) -> Result<MeshlessBuild> {
    let (background, cloud_name, rest) = nodes_and_tets(settings)?;
    log::info!(
        "meshless cloud: {} nodes, {} background tets; integration points",
        background.nodes.len(),
        background.num_cells()
    );
    let MeshlessRest {
        domain,
        integration,
        mls,
        support: rule,
        patch,
    } = rest;
    check_build_memory(
        &crate::memory::PlannedMesh {
            nodes: background.nodes.len() as f64,
            elements: background.num_cells() as f64,
            what: format!(
                "{} nodes and {} background tets",
                background.nodes.len(),
                background.num_cells()
            ),
        },
        &integration,
        rule,
    )?;

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
    let (positions, weights, owner, integration_name) = match integration {
        Integration::Adaptive(a) => {
            let (a, info) = adaptive_tet_points(&a, &background, &full, &mls)?;
            let name = format!(
                "{} background tets, {}",
                background.num_cells(),
                info.line()
            );
            adaptive_info = Some(info);
            point_level = a.level;
            (
                a.positions,
                a.weights,
                a.owner.into_iter().map(Some).collect(),
                name,
            )
        }
        Integration::Tets {
            rule,
            tets_per_point,
        } => {
            let (p, w, o) = integration::tet_points(&background, rule)?;
            match integration::cluster_tets(&background, &p, &w, &o, tets_per_point) {
                Some((p, w, o)) => {
                    let name = format!(
                        "{} background tets x {} points merged into {} (about {} tets per point)",
                        background.num_cells(),
                        rule.points(),
                        p.len(),
                        tets_per_point
                    );
                    (p, w, o.into_iter().map(Some).collect(), name)
                }
                None => {
                    let name = format!(
                        "{} background tets x {} points",
                        background.num_cells(),
                        rule.points()
                    );
                    (p, w, o.into_iter().map(Some).collect(), name)
                }
            }
        }
        Integration::Grid { point_ratio } => {
            let dom = domain.as_ref().ok_or_else(|| {
                Error::input(InputKind::Unsupported,
                    "integration = 'grid' needs a built-in shape (box or cylinder); with geometry.mesh \
                     use cloud = 'mesh' or 'file' and integration = 'tets'",
                )
            })?;
            let (p, w) = integration::grid_points(dom, background.nodes.len(), point_ratio)?;
            let o = vec![None; p.len()];
            let name = format!("regular grid, {point_ratio} points per node");
            (p, w, o, name)
        }
    };
    if positions.is_empty() {
        return Err(Error::input(InputKind::Discretization, "the meshless discretization has no integration points; refine the grid (point_ratio) or check the cloud"));
    }

    // Field nodes: the background vertices, less those reached by fewer than two supports.
    let mut keep: Vec<usize> = (0..background.nodes.len()).collect();
    let mut removed_total = 0usize;
    let mut warnings = Vec::new();
    for _round in 0..4 {
        let nodes: Vec<Vector3<f64>> = keep.iter().map(|&i| background.nodes[i]).collect();
        let support = full.subset(&keep)?;
        log::info!(
            "supports and MLS shape functions at {} points",
            positions.len()
        );
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
                let mut m = vec![None; background.nodes.len()];
                for (new, &old) in keep.iter().enumerate() {
                    m[old] = Some(new);
                }
                m
            };
            let (points, positions, owner, point_level) =
                patch_groups(points, positions, owner, point_level, &background, patch);
            let integration_name = if points.groups.is_empty() {
                integration_name
            } else {
                format!(
                    "{integration_name}; mean J shared over {} patches of about {patch} tets",
                    points.groups.len()
                )
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
                exact_volume: domain.as_ref().map(|d| d.volume()),
                cloud: cloud_name,
                integration: integration_name,
                warnings,
                adaptive: adaptive_info,
                point_level,
            });
        }
        let guarded = protected(&nodes)?;
        if let Some(&g) = guarded.iter().find(|g| low.binary_search(g).is_ok()) {
            return Err(Error::input(InputKind::Discretization, format!(
                "meshless node {} at {:?} m carries a boundary condition or a probe but only {} integration point(s) reach it, \
                 so it would have to be removed; add integration points (tet_rule, point_ratio) or enlarge the supports \
                 (dilatation, support_nodes)",
                keep[g],
                nodes[g].as_slice(),
                counts[g]
            )).node(keep[g]));
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
    Err(Error::input(InputKind::Discretization,
        "removing meshless nodes that fewer than two integration points reach did not settle after 4 rounds; \
         the cloud is much coarser than the integration (or the reverse): add integration points or enlarge the supports",
    ))
}
