//! The pipeline the fe, meshless and coupled builds share (issue 58): each method turns the
//! scene into [`Parts`] (its nodes and points, where each point lies, its boundaries), and
//! [`assemble`] does the rest once for all: probes, regions, masses, the model, loads and
//! contact, the essential-boundary correction and [`Prepared`]. A new method (an element, a
//! point kind) gives its parts and a [`Discretized`] view; it copies no pipeline.

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::Vector3;

use crate::bc::Boundary;
use crate::coupling::CoupledBuild;
use crate::fe::tet10::Tet10Mesh;
use crate::fe::ElementKind;
use crate::geometry::Mesh;
use crate::io::model::MeshInput;
use crate::material::Material;
use crate::meshless::discretize::MeshlessBuild;
use crate::probe::Probe;
use crate::quadrature::QuadraturePoints;
use crate::report::Warning;
use crate::scene::{BcMethod, ProbeSpec, Scene};
use crate::solver::Model;
use crate::{Error, InputKind, Result};

use super::surface::{Discretized, QuadraticFe};
use super::{add_loads_and_contact, hourglass_modulus, regions, select_nodes, translate, Prepared};

/// The discretization a scene was built with: what the method keeps beside the model.
pub enum Discretization {
    /// Finite elements over [`Prepared::mesh`].
    Fe,
    /// Meshless: the node cloud, points and supports, and how essential conditions act.
    Meshless {
        build: Box<MeshlessBuild>,
        bc_method: BcMethod,
    },
    /// Coupled FE and meshless, and how conditions on its meshless nodes act (None where every
    /// condition holds FE nodes only).
    Coupled {
        build: Box<CoupledBuild>,
        bc_method: Option<BcMethod>,
    },
}

impl Discretization {
    /// The meshless build, for meshless scenes.
    pub fn meshless(&self) -> Option<&MeshlessBuild> {
        match self {
            Discretization::Meshless { build, .. } => Some(build),
            _ => None,
        }
    }

    /// The coupled build, for coupled scenes.
    pub fn coupled(&self) -> Option<&CoupledBuild> {
        match self {
            Discretization::Coupled { build, .. } => Some(build),
            _ => None,
        }
    }

    /// How essential conditions act on meshless nodes (None for FE, and for coupled scenes
    /// whose conditions hold FE nodes only).
    pub fn bc_method(&self) -> Option<BcMethod> {
        match self {
            Discretization::Fe => None,
            Discretization::Meshless { bc_method, .. } => Some(*bc_method),
            Discretization::Coupled { bc_method, .. } => *bc_method,
        }
    }

    /// The view loads, contact and probes are built on; `mesh` is [`Prepared::mesh`].
    pub(super) fn view<'a>(
        &'a self,
        mesh: &'a Mesh,
        quadratic: Option<QuadraticFe<'a>>,
    ) -> Discretized<'a> {
        match self {
            Discretization::Fe => Discretized::Fe(mesh, quadratic),
            Discretization::Meshless { build, .. } => Discretized::Meshless(build),
            Discretization::Coupled { build, .. } => Discretized::Coupled(build),
        }
    }
}

/// What the mesh-based builds (fe, coupled) start from: the clock, the scene's mesh file (if
/// any), the body's mesh (built-in shapes, images and surfaces meshed here), its element, the
/// material's Lame parameters and the warnings so far.
pub(super) struct MeshStart {
    pub t0: Instant,
    pub input: Option<MeshInput>,
    pub mesh: Mesh,
    pub kind: ElementKind,
    /// The material's Lame parameters (lambda, mu), Pa.
    pub lame: (f64, f64),
    pub warnings: Vec<Warning>,
}

impl MeshStart {
    pub fn of(scene: &Scene) -> Result<Self> {
        let t0 = Instant::now();
        let input = translate::load_mesh_input(scene)?;
        let mut warnings = Vec::new();
        let mesh = super::body_mesh(scene, input.as_ref(), &mut warnings)?;
        Ok(MeshStart {
            t0,
            input,
            mesh,
            lame: translate::material(scene).lame(),
            kind: scene.discretization.element.into(),
            warnings,
        })
    }
}

/// What one method's build gives the shared pipeline.
pub(super) struct Parts {
    /// The geometry outputs are written on: the FE mesh (tet10: its linear split over all
    /// nodes), the meshless background tets, the coupled FE layer.
    pub mesh: Mesh,
    pub method: Discretization,
    /// Quadratic tets (fe tet10): the elements and the linear mesh of their vertices.
    pub quadratic: Option<(Tet10Mesh, Mesh)>,
    /// The quadrature points, in the method's order (before the model's spatial order).
    pub points: QuadraturePoints,
    /// Where each point lies, for regions.
    pub places: regions::Places,
    pub boundaries: Vec<Boundary>,
    pub kind: ElementKind,
    pub min_dihedral: Option<super::MinDihedral>,
    pub warnings: Vec<Warning>,
}

/// The shared pipeline after a method's build: probes, regions (each point's material and
/// hourglass scale), lumped masses, the model, loads and contact (after the masses, which
/// gravity takes), the essential-boundary correction (after mass scaling, which it reads),
/// and [`Prepared`].
pub(super) fn assemble(
    scene: &Scene,
    input: Option<&MeshInput>,
    parts: Parts,
    t0: Instant,
) -> Result<Prepared> {
    let Parts {
        mesh,
        method,
        quadratic,
        mut points,
        places,
        boundaries,
        kind,
        min_dihedral,
        mut warnings,
    } = parts;
    let q = QuadraticFe::of(&quadratic);
    let view = method.view(&mesh, q);
    let probes = probes(scene, view, input)?;
    let (materials, point_material, region_counts) =
        regions::point_materials(scene, input, &places)?;
    regions::scale_hourglass(
        &mut points,
        &point_material,
        &|m| hourglass_modulus(scene, m),
        &materials,
    );
    let density =
        |p: usize| materials[point_material.get(p).copied().unwrap_or(0) as usize].density();
    // Lumping that is not the points' volumes split evenly: HRZ for quadratic tets (from the
    // points in element order, four per element), the blended shape functions' for coupled.
    let masses = match (&method, &quadratic) {
        (Discretization::Fe, Some((t, _))) => Some(t.lumped_masses(&points, &|e| density(4 * e))),
        (Discretization::Coupled { build, .. }, _) => Some(build.lumped_masses(&density)),
        _ => None,
    };
    let mut model = Model::with_materials(
        view.nodes().to_vec(),
        points,
        materials,
        point_material.clone(),
        boundaries,
    )?;
    if let Some(m) = &masses {
        model.set_lumped_masses(m)?;
    }
    add_loads_and_contact(&mut model, scene, view, input, &mut warnings)?;
    match &method {
        Discretization::Fe => {}
        Discretization::Meshless { build, bc_method } => {
            super::build_meshless::impose(build, *bc_method, &mut model, &mut warnings)?
        }
        Discretization::Coupled { build, bc_method } => {
            if let Some(m) = bc_method {
                super::build_coupled::impose(build, *m, &mut model, &mut warnings)?
            }
        }
    }
    Ok(Prepared {
        mesh,
        method,
        warnings,
        model,
        point_material,
        regions: region_counts,
        probes,
        kind,
        min_dihedral,
        preprocess_seconds: t0.elapsed().as_secs_f64(),
        source_volume: None,
    })
}

/// The scene's probes on discretization `d`: a position's row from the shape functions of
/// the cell that holds it, a selection's mean of the rows at its nodes (with the nodes it
/// implies, [`Discretized::extend_selection`]).
fn probes(scene: &Scene, d: Discretized<'_>, input: Option<&MeshInput>) -> Result<Vec<Probe>> {
    // A meshless body has no cells to find a point in: its domain tells what is inside.
    let domain = match d {
        Discretized::Meshless(_) => translate::domain(scene).map(|dom| {
            (
                dom,
                0.05 * translate::spacing(scene).unwrap_or(0.0).max(1e-12),
            )
        }),
        _ => None,
    };
    let mut out = Vec::with_capacity(scene.probes.len());
    for (name, spec) in &scene.probes {
        let what = || format!("probe '{name}'");
        let probe = match spec {
            ProbeSpec::Select(sel) => {
                let mut ids = select_nodes(
                    sel,
                    d.nodes(),
                    &what(),
                    &format!("probes.{name}.select"),
                    input,
                )?;
                d.extend_selection(&mut ids);
                mean_probe(name, &ids, d)?
            }
            ProbeSpec::Position(p) => {
                let x = Vector3::from(*p);
                if domain
                    .as_ref()
                    .is_some_and(|(dom, tolerance)| !dom.contains(&x, *tolerance))
                {
                    return Err(Error::input(
                        InputKind::Selection,
                        format!("probe '{name}' at {p:?} m lies outside the body; move it inside"),
                    ));
                }
                let (row, element) = d.point_row(&x, &what)?;
                Probe {
                    name: name.clone(),
                    position: x,
                    nodes: row.iter().map(|e| e.0 as usize).collect(),
                    weights: row.iter().map(|e| e.1).collect(),
                    element,
                }
            }
        };
        out.push(probe);
    }
    Ok(out)
}

/// A probe that averages the displacements at nodes `ids` (each interpolated by its row,
/// [`Discretized::node_row`]); its position is the nodes' centroid.
fn mean_probe(name: &str, ids: &[usize], d: Discretized<'_>) -> Result<Probe> {
    let mut acc: BTreeMap<u32, f64> = BTreeMap::new();
    for &i in ids {
        for (j, w) in d.node_row(i)? {
            *acc.entry(j).or_default() += w / ids.len() as f64;
        }
    }
    let nodes = d.nodes();
    Ok(Probe {
        name: name.into(),
        position: ids.iter().fold(Vector3::zeros(), |a, &i| a + nodes[i]) / ids.len() as f64,
        nodes: acc.keys().map(|&i| i as usize).collect(),
        weights: acc.into_values().collect(),
        element: None,
    })
}
