//! What a run writes: VTU frames as the run produces them (FE meshes, meshless background
//! tets with interpolated displacements, coupled meshes), the `.pvd` series, integration
//! points of adaptive runs, the time history (CSV and SVG plots), relaxation records and
//! `summary.json`. Units SI.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use super::fields::ResultPoints;
use super::{Discretization, Prepared};
use crate::geometry::Mesh;
use crate::io::vtu::{self, DataArray, VtuFormat};
use crate::material::Solid;
use crate::report::Summary;
use crate::scene::Scene;
use crate::solver::{Model, RunOutput};
use crate::{Error, InputKind, Result};

/// VTU cells making each of `n` points a VTK vertex (type 1), so ParaView draws them:
/// (connectivity, offsets, types).
fn vertex_cells(n: usize) -> (Vec<usize>, Vec<usize>, Vec<u8>) {
    ((0..n).collect(), (1..=n).collect(), vec![1u8; n])
}

/// Integration points as VTK vertices with their weight (m^3), refinement level (adaptive
/// integration) and background tet (-1 for none), for inspection.
fn write_integration_points(
    path: &Path,
    positions: &[Vector3<f64>],
    weights: &[f64],
    levels: &[u8],
    owner: &[Option<usize>],
    format: VtuFormat,
) -> Result<()> {
    let n = positions.len();
    let (conn, offsets, types) = vertex_cells(n);
    let level: Vec<f64> = (0..n)
        .map(|p| levels.get(p).map_or(0.0, |&l| l as f64))
        .collect();
    let owner: Vec<f64> = (0..n)
        .map(|p| owner.get(p).copied().flatten().map_or(-1.0, |e| e as f64))
        .collect();
    let piece = vtu::Piece {
        points: positions,
        connectivity: &conn,
        offsets: &offsets,
        types: &types,
        point_data: vec![
            DataArray {
                name: "weight_m3",
                components: 1,
                values: weights,
            },
            DataArray {
                name: "level",
                components: 1,
                values: &level,
            },
            DataArray {
                name: "background_tet",
                components: 1,
                values: &owner,
            },
        ],
        cell_data: Vec::new(),
    };
    vtu::write_vtu(path, &piece, format)
}

/// `reaction.svg` (every constrained component of every boundary against time) and
/// `energy.svg` (external work, strain and kinetic energy against time).
fn write_history_plots(dir: &Path, model: &Model<Solid>, out: &RunOutput) -> Result<()> {
    use crate::io::plot::{line_plot, Series};
    // Per reaction: the components a boundary prescribes; all three of a rigid body's.
    let shown: Vec<(String, Vec<usize>)> = model
        .reaction_names()
        .into_iter()
        .enumerate()
        .map(|(bi, name)| {
            let comps = match model.boundaries().get(bi) {
                Some(b) => (0..3).filter(|&k| b.components[k].is_some()).collect(),
                None => vec![0, 1, 2],
            };
            (name, comps)
        })
        .collect();
    let names: Vec<String> = shown
        .iter()
        .flat_map(|(name, comps)| {
            comps
                .iter()
                .map(move |&k| format!("{name} {}", ["x", "y", "z"][k]))
        })
        .collect();
    // Relaxation's time is a device of the solver, not a history of the body.
    let axis = if out.load_steps.is_some() {
        "pseudo-time of the relaxation (s)"
    } else {
        "time (s)"
    };
    let mut series = Vec::new();
    let mut at = 0;
    for (bi, (_, comps)) in shown.iter().enumerate() {
        for &k in comps {
            series.push(Series {
                name: &names[at],
                points: out
                    .history
                    .iter()
                    .filter_map(|h| Some((h.time, h.reactions.get(bi)?[k])))
                    .collect(),
            });
            at += 1;
        }
    }
    line_plot(
        &dir.join("reaction.svg"),
        "Reaction forces",
        axis,
        "force (N)",
        &series,
    )?;
    let e = |f: fn(&crate::solver::integrate::HistoryRow) -> f64| -> Vec<(f64, f64)> {
        out.history.iter().map(|h| (h.time, f(h))).collect()
    };
    let energies = [
        Series {
            name: "external work",
            points: e(|h| h.external_work),
        },
        Series {
            name: "strain energy",
            points: e(|h| h.strain_energy),
        },
        Series {
            name: "kinetic energy",
            points: e(|h| h.kinetic_energy),
        },
    ];
    line_plot(
        &dir.join("energy.svg"),
        "Energies",
        axis,
        "energy (J)",
        &energies,
    )
}

/// What a frame labels its points and cells with, besides the fields: a 0/1 point array per
/// boundary (`boundary_NAME`: the nodes it holds, measured ones included) and the region of
/// each cell (`region`: 0 for `[material]`, k for the k-th region in name order), so that
/// ParaView users can colour and threshold by them.
pub struct FrameLabels {
    /// Per boundary: its name and, per model node, whether it holds the node.
    pub boundaries: Vec<BoundaryNodes>,
    /// Per quadrature point that lies in a frame cell (discretization order; a point of a
    /// split element once per cell of the split): the cell and its material. Empty without
    /// regions; a meshless grid point, in no cell, has none.
    pub point_cells: Vec<CellMaterial>,
    /// Frame cells per FE element: 8 for tet10 (written as the eight linear tets of
    /// [`crate::fe::tet10::Tet10Mesh::split`], element `e` as cells 8e..8e+7), else 1.
    pub element_cells: usize,
}

/// A boundary's name and, per model node, whether the boundary holds it.
pub struct BoundaryNodes {
    pub name: String,
    pub holds: Vec<bool>,
}

/// A frame cell and the material (0 for `[material]`, k for the k-th region) of a point in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CellMaterial {
    pub cell: usize,
    pub material: u16,
}

impl FrameLabels {
    /// The labels of a prepared run.
    pub fn of(prep: &Prepared) -> Self {
        let n = prep.model.nodes().len();
        let boundaries = prep
            .model
            .boundaries()
            .iter()
            .map(|b| {
                let mut holds = vec![false; n];
                for &i in &b.nodes {
                    holds[i] = true;
                }
                BoundaryNodes {
                    name: b.name.clone(),
                    holds,
                }
            })
            .collect();
        let fe = matches!(prep.method, Discretization::Fe);
        let element_cells = if fe && prep.kind == crate::fe::ElementKind::Tet10 {
            8
        } else {
            1
        };
        let point_cells = if prep.point_material.is_empty() {
            Vec::new()
        } else {
            match &prep.method {
                Discretization::Meshless { build: m, .. } => m
                    .owner
                    .iter()
                    .zip(&prep.point_material)
                    .filter_map(|(&cell, &material)| {
                        Some(CellMaterial {
                            cell: cell?,
                            material,
                        })
                    })
                    .collect(),
                Discretization::Coupled { build: c, .. } => c
                    .owner
                    .iter()
                    .zip(&prep.point_material)
                    .map(|(&cell, &material)| CellMaterial { cell, material })
                    .collect(),
                Discretization::Fe => {
                    let per_element = element_points(
                        prep.point_material.len(),
                        prep.mesh.num_cells(),
                        element_cells,
                    );
                    prep.point_material
                        .iter()
                        .enumerate()
                        .flat_map(|(p, &m)| {
                            let e = p / per_element;
                            (element_cells * e..element_cells * (e + 1))
                                .map(move |cell| CellMaterial { cell, material: m })
                        })
                        .collect()
                }
            }
        };
        FrameLabels {
            boundaries,
            point_cells,
            element_cells,
        }
    }
}

/// Quadrature points per FE element, for `points` points over `cells` frame cells of which
/// `element_cells` make one element (at least 1).
pub(super) fn element_points(points: usize, cells: usize, element_cells: usize) -> usize {
    let elements = (cells / element_cells.max(1)).max(1);
    (points / elements).max(1)
}

/// Writes the VTU frames of a run into a folder, one file per frame as the frames come, and
/// the `.pvd` series that lists them.
pub struct FrameWriter<'a> {
    dir: PathBuf,
    name: String,
    /// The frames' points and cells and the interpolation of nodal values to them.
    points: ResultPoints<'a>,
    labels: FrameLabels,
    format: VtuFormat,
    /// (time s, file name) of every frame written.
    series: Vec<(f64, String)>,
}

impl<'a> FrameWriter<'a> {
    /// A writer of `name_0000.vtu`, ... in `dir` (created when the first frame is written)
    /// for the discretization `method` over `mesh` ([`super::Prepared`]'s).
    pub fn new(
        dir: &Path,
        name: &str,
        mesh: &'a Mesh,
        method: &'a Discretization,
        labels: FrameLabels,
        format: VtuFormat,
    ) -> Result<Self> {
        Ok(FrameWriter {
            dir: dir.to_path_buf(),
            name: name.to_string(),
            points: ResultPoints::new(mesh, method)?,
            labels,
            format,
            series: Vec::new(),
        })
    }

    /// The frames' points (see [`ResultPoints`]).
    pub fn points(&self) -> &ResultPoints<'a> {
        &self.points
    }

    /// Writes the next frame at displacements `u` (m) and time `t` (s). Point data:
    /// displacement (m); the nodal Cauchy stress (Pa), Green-Lagrange strain, principal
    /// stretches (largest first), von Mises stress (Pa) and J, averaged from the points
    /// ([`Model::nodal_fields`]; meshless: interpolated to the background vertices with the
    /// shape functions); `boundary_NAME` (1 on the nodes a boundary holds). Cell data: the
    /// points' Cauchy stress, von Mises stress and J (meshless and coupled: the mean over the
    /// cell's points) and, with regions, `region`.
    pub fn write(&mut self, model: &mut Model<Solid>, t: f64, u: &[Vector3<f64>]) -> Result<()> {
        let points = model.stress_fields(u);
        let file = format!("{}_{:04}.vtu", self.name, self.series.len());
        if self.series.is_empty() {
            std::fs::create_dir_all(&self.dir).map_err(|e| Error::io(&self.dir, e))?;
        }
        let path = self.dir.join(&file);
        let g = self.points.geometry();
        let (xs, conn, offsets, types, owner) =
            (g.points, g.connectivity, g.offsets, g.types, g.owner);
        let ncell = types.len();
        let (disp, at_points) = self.points.at_points(model, u);
        let stretches: Vec<f64> = (0..at_points.len())
            .flat_map(|v| at_points.principal_stretches(v))
            .collect();
        // Cell values: per element, or the mean of each cell's points (a split element's
        // cells each take the mean of the element's points).
        let element_cells = self.labels.element_cells.max(1);
        let cells_of = |values: &[f64], width: usize| -> Vec<f64> {
            let Some(owner) = &owner else {
                if element_cells == 1 {
                    return values.to_vec();
                }
                let per_element = element_points(values.len() / width, ncell, element_cells);
                let mut out = vec![0.0; ncell * width];
                for (e, pts) in values.chunks(per_element * width).enumerate() {
                    let n = (pts.len() / width).max(1) as f64;
                    for c in 0..width {
                        let mean = pts.iter().skip(c).step_by(width).sum::<f64>() / n;
                        for k in element_cells * e..(element_cells * (e + 1)).min(ncell) {
                            out[k * width + c] = mean;
                        }
                    }
                }
                return out;
            };
            let mut sum = vec![0.0; ncell * width];
            let mut count = vec![0usize; ncell];
            for (p, e) in owner.iter().enumerate() {
                if let Some(e) = e.filter(|&e| e < ncell) {
                    count[e] += 1;
                    for c in 0..width {
                        sum[e * width + c] += values[p * width + c];
                    }
                }
            }
            for e in 0..ncell {
                let w = 1.0 / count[e].max(1) as f64;
                sum[e * width..(e + 1) * width]
                    .iter_mut()
                    .for_each(|x| *x *= w);
            }
            sum
        };
        let (cell_sig, cell_vm, cell_j) = (
            cells_of(&points.cauchy, 9),
            cells_of(&points.von_mises, 1),
            cells_of(&points.j, 1),
        );
        let cell_j_own = cells_of(&points.j_own, 1);
        let region: Vec<f64> = if self.labels.point_cells.is_empty() {
            Vec::new()
        } else {
            let mut r = vec![0.0; ncell];
            for c in &self.labels.point_cells {
                if let Some(x) = r.get_mut(c.cell) {
                    *x = c.material as f64;
                }
            }
            r
        };
        // Boundary labels at the frame's points (meshless: at the field node of a vertex).
        let node_of = |v: usize| self.points.node(v);
        let labels: Vec<(String, Vec<f64>)> = self
            .labels
            .boundaries
            .iter()
            .map(|b| {
                let v: Vec<f64> = (0..xs.len())
                    .map(|k| match node_of(k) {
                        Some(i) if b.holds.get(i) == Some(&true) => 1.0,
                        _ => 0.0,
                    })
                    .collect();
                (format!("boundary_{}", b.name), v)
            })
            .collect();
        let mut point_data = vec![
            DataArray {
                name: "displacement",
                components: 3,
                values: &disp,
            },
            DataArray {
                name: "cauchy_stress",
                components: 9,
                values: &at_points.cauchy,
            },
            DataArray {
                name: "green_lagrange_strain",
                components: 9,
                values: &at_points.green,
            },
            DataArray {
                name: "principal_stretches",
                components: 3,
                values: &stretches,
            },
            DataArray {
                name: "von_mises",
                components: 1,
                values: &at_points.von_mises,
            },
            DataArray {
                name: "J",
                components: 1,
                values: &at_points.j,
            },
        ];
        for (name, v) in &labels {
            point_data.push(DataArray {
                name,
                components: 1,
                values: v,
            });
        }
        let mut cell_data = Vec::new();
        if types.iter().all(|&t| t != 1) {
            cell_data.extend([
                DataArray {
                    name: "cauchy_stress",
                    components: 9,
                    values: &cell_sig,
                },
                DataArray {
                    name: "von_mises",
                    components: 1,
                    values: &cell_vm,
                },
                DataArray {
                    name: "J",
                    components: 1,
                    values: &cell_j,
                },
                DataArray {
                    name: "J_element",
                    components: 1,
                    values: &cell_j_own,
                },
            ]);
            if !region.is_empty() {
                cell_data.push(DataArray {
                    name: "region",
                    components: 1,
                    values: &region,
                });
            }
        }
        let piece = vtu::Piece {
            points: xs,
            connectivity: &conn,
            offsets: &offsets,
            types: &types,
            point_data,
            cell_data,
        };
        vtu::write_vtu(&path, &piece, self.format)?;
        self.series.push((t, file));
        Ok(())
    }

    /// Writes `name.pvd` listing the frames written so far.
    pub fn write_series(&self) -> Result<()> {
        vtu::write_pvd(&self.dir.join(format!("{}.pvd", self.name)), &self.series)
    }
}

/// Writes one VTU per frame of `out.frames` (see [`FrameWriter`]) and then
/// [`write_results`]: the `.pvd` series, `history.csv`, `relaxation.csv` and `summary.json`.
pub fn write_outputs(
    dir: &Path,
    scene: &Scene,
    prep: &mut Prepared,
    out: &RunOutput,
    summary: &Summary,
    format: VtuFormat,
) -> Result<()> {
    let name = scene.name.clone().unwrap_or_else(|| "run".into());
    let labels = FrameLabels::of(prep);
    let mut frames = FrameWriter::new(dir, &name, &prep.mesh, &prep.method, labels, format)?;
    for (t, u) in &out.frames {
        frames.write(&mut prep.model, *t, u)?;
    }
    frames.write_series()?;
    let image = output_image(scene)?;
    write_image_outputs(dir, &name, image.as_ref(), &frames, &out.u)?;
    write_results(dir, &name, prep, out, summary, format)
}

/// `output.image`, read (None without it): read before the solve, so that a file that
/// cannot be used stops the run before its time is spent.
pub fn output_image(
    scene: &Scene,
) -> Result<Option<(crate::io::image::Image, std::path::PathBuf)>> {
    let Some(file) = &scene.output.image else {
        return Ok(None);
    };
    let path = super::translate::scene_path(scene, file);
    Ok(Some((crate::io::image::read_image(&path)?, path)))
}

/// `output.image`: on that image's grid, the displacement field that warps it into the
/// deformed configuration (`NAME_displacement`, ITK's resampling convention, see
/// [`crate::geometry::warp`]) and the image so warped (`NAME_warped`), in the image's format
/// (NIfTI `.nii.gz` or NRRD `.nrrd`). Nothing without `output.image`.
pub fn write_image_outputs(
    dir: &Path,
    name: &str,
    image: Option<&(crate::io::image::Image, std::path::PathBuf)>,
    frames: &FrameWriter,
    u: &[Vector3<f64>],
) -> Result<()> {
    let Some((image, path)) = image else {
        return Ok(());
    };
    let (mesh, disp) = frames.points().deformation(u)?;
    let (d, covered) = crate::geometry::warp::pull_back(image, &mesh, &disp)?;
    if covered == 0 {
        let (lo, hi) = crate::geometry::select::bounds(&mesh.nodes);
        let corners: Vec<Vector3<f64>> = (0..8)
            .map(|c| {
                image.world(&Vector3::new(
                    if c & 1 == 0 {
                        -0.5
                    } else {
                        image.dims[0] as f64 - 0.5
                    },
                    if c & 2 == 0 {
                        -0.5
                    } else {
                        image.dims[1] as f64 - 0.5
                    },
                    if c & 4 == 0 {
                        -0.5
                    } else {
                        image.dims[2] as f64 - 0.5
                    },
                ))
            })
            .collect();
        let (ilo, ihi) = crate::geometry::select::bounds(&corners);
        return Err(Error::input(InputKind::Value, format!(
            "output.image {}: none of its {} voxels lies in the deformed body: the image spans \
             [{:.4e}, {:.4e}, {:.4e}] to [{:.4e}, {:.4e}, {:.4e}] m, the body [{:.4e}, {:.4e}, {:.4e}] to \
             [{:.4e}, {:.4e}, {:.4e}] m (RAS); give an image of the same scene (check its origin, units and orientation)",
            path.display(),
            image.len(),
            crate::error::Sci(ilo.x), crate::error::Sci(ilo.y), crate::error::Sci(ilo.z), crate::error::Sci(ihi.x), crate::error::Sci(ihi.y), crate::error::Sci(ihi.z), crate::error::Sci(lo.x), crate::error::Sci(lo.y), crate::error::Sci(lo.z), crate::error::Sci(hi.x), crate::error::Sci(hi.y), crate::error::Sci(hi.z))));
    }
    let warped = crate::geometry::warp::warp(image, &d);
    let ext = match crate::io::image::ImageFormat::from_path(path) {
        Some(crate::io::image::ImageFormat::Nrrd) => "nrrd",
        _ => "nii.gz",
    };
    crate::io::image::write_displacement_field(
        &dir.join(format!("{name}_displacement.{ext}")),
        image,
        &d,
    )?;
    crate::io::image::write_image(&dir.join(format!("{name}_warped.{ext}")), &warped)?;
    let largest = d.iter().map(|v| v.norm()).fold(0.0, f64::max);
    log::info!(
        "output.image {}: {covered} of {} voxels in the deformed body, largest displacement {largest:.4e} m; wrote {name}_displacement.{ext} and {name}_warped.{ext}",
        path.display(),
        image.len()
    );
    Ok(())
}

/// The files of a run besides its frames: the integration points of adaptive runs,
/// `history.csv` and its plots, `relaxation.csv` (relaxation runs) and `summary.json`.
pub fn write_results(
    dir: &Path,
    name: &str,
    prep: &Prepared,
    out: &RunOutput,
    summary: &Summary,
    format: VtuFormat,
) -> Result<()> {
    let points_file = dir.join(format!("{name}_integration_points.vtu"));
    if let Some(m) = prep.meshless().filter(|m| m.adaptive.is_some()) {
        write_integration_points(
            &points_file,
            &m.positions,
            &m.points.weights,
            &m.point_level,
            &m.owner,
            format,
        )?;
    }
    if let Some((c, (pos, levels))) = prep
        .coupled()
        .and_then(|c| c.adaptive_points.as_ref().map(|a| (c, a)))
    {
        // The interior's points are the last ones; their owners are offset by the FE cells.
        let first = c.points.len() - pos.len();
        let fe_cells = c.fe_mesh.num_cells();
        let owner: Vec<Option<usize>> = c.owner[first..]
            .iter()
            .map(|&e| Some(e.saturating_sub(fe_cells)))
            .collect();
        write_integration_points(
            &points_file,
            pos,
            &c.points.weights[first..],
            levels,
            &owner,
            format,
        )?;
    }

    let mut header = vec!["step".to_string(), "time_s".to_string()];
    for b in prep.model.reaction_names() {
        for c in ["x", "y", "z"] {
            header.push(format!("reaction_{b}_{c}_N"));
        }
    }
    header.extend(["external_work_J", "strain_energy_J", "kinetic_energy_J"].map(String::from));
    let rows: Vec<Vec<f64>> = out
        .history
        .iter()
        .map(|h| {
            let mut r = vec![h.step as f64, h.time];
            r.extend(h.reactions.iter().flatten());
            r.extend([h.external_work, h.strain_energy, h.kinetic_energy]);
            r
        })
        .collect();
    crate::io::csv::write_csv(&dir.join("history.csv"), &header, &rows)?;
    write_history_plots(dir, &prep.model, out)?;
    if !out.relaxation.is_empty() {
        let header: Vec<String> = [
            "step",
            "omega_min_rad_s",
            "r",
            "accepted",
            "error_estimate_m",
        ]
        .map(String::from)
        .to_vec();
        let rows: Vec<Vec<f64>> = out
            .relaxation
            .iter()
            .map(|r| {
                vec![
                    r.step as f64,
                    r.omega_min,
                    r.r,
                    r.accepted as u8 as f64,
                    r.error_estimate,
                ]
            })
            .collect();
        crate::io::csv::write_csv(&dir.join("relaxation.csv"), &header, &rows)?;
    }
    let json = serde_json::to_string_pretty(summary).map_err(|e| {
        Error::input(
            InputKind::Value,
            format!("cannot serialise the summary: {e}"),
        )
    })?;
    std::fs::write(dir.join("summary.json"), json)
        .map_err(|e| Error::io(dir.join("summary.json"), e))?;
    Ok(())
}
