//! What a run writes: VTU frames as the run produces them (FE meshes, meshless background
//! tets with interpolated displacements, coupled meshes), the `.pvd` series, integration
//! points of adaptive runs, the time history (CSV and SVG plots), relaxation records and
//! `summary.json`. Units SI.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use super::Prepared;
use crate::coupling::CoupledBuild;
use crate::geometry::Mesh;
use crate::io::vtu::{self, DataArray, VtuFormat};
use crate::material::Solid;
use crate::meshless::discretize::MeshlessBuild;
use crate::report::Summary;
use crate::scene::Scene;
use crate::solver::{Model, RunOutput};
use crate::{Error, Result};

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
    owner: &[usize],
    format: VtuFormat,
) -> Result<()> {
    let n = positions.len();
    let (conn, offsets, types) = vertex_cells(n);
    let level: Vec<f64> = (0..n)
        .map(|p| levels.get(p).map_or(0.0, |&l| l as f64))
        .collect();
    let owner: Vec<f64> = (0..n)
        .map(|p| match owner.get(p) {
            Some(&e) if e != usize::MAX => e as f64,
            _ => -1.0,
        })
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

/// One meshless VTU frame: the background vertices as points with the interpolated
/// displacement, and the background tets as cells carrying the mean stress, von Mises stress
/// and J of their integration points (one vertex cell per point when there are no tets).
fn write_meshless_frame(
    path: &Path,
    points: &[Vector3<f64>],
    (conn, offsets, types): (&[usize], &[usize], &[u8]),
    owner: &[usize],
    disp: &[f64],
    (sig, vm, jac): (&[f64], &[f64], &[f64]),
    format: VtuFormat,
) -> Result<()> {
    let ncell = types.len();
    if ncell == 0 {
        let (conn, offsets, types) = vertex_cells(points.len());
        let piece = vtu::Piece {
            points,
            connectivity: &conn,
            offsets: &offsets,
            types: &types,
            point_data: vec![DataArray {
                name: "displacement",
                components: 3,
                values: disp,
            }],
            cell_data: Vec::new(),
        };
        return vtu::write_vtu(path, &piece, format);
    }
    let mut count = vec![0usize; ncell];
    let (mut s9, mut v1, mut j1) = (vec![0.0; 9 * ncell], vec![0.0; ncell], vec![0.0; ncell]);
    for (p, &e) in owner.iter().enumerate() {
        if e >= ncell {
            continue;
        }
        count[e] += 1;
        for c in 0..9 {
            s9[9 * e + c] += sig[9 * p + c];
        }
        v1[e] += vm[p];
        j1[e] += jac[p];
    }
    for e in 0..ncell {
        let w = 1.0 / count[e].max(1) as f64;
        s9[9 * e..9 * e + 9].iter_mut().for_each(|x| *x *= w);
        v1[e] *= w;
        j1[e] *= w;
    }
    let cell_data = vec![
        DataArray {
            name: "cauchy_stress",
            components: 9,
            values: &s9,
        },
        DataArray {
            name: "von_mises",
            components: 1,
            values: &v1,
        },
        DataArray {
            name: "J",
            components: 1,
            values: &j1,
        },
    ];
    let point_data = vec![DataArray {
        name: "displacement",
        components: 3,
        values: disp,
    }];
    let piece = vtu::Piece {
        points,
        connectivity: conn,
        offsets,
        types,
        point_data,
        cell_data,
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
            let comps = match model.boundaries.get(bi) {
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
        "time (s)",
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
        "time (s)",
        "energy (J)",
        &energies,
    )
}

/// Writes the VTU frames of a run into a folder, one file per frame as the frames come, and
/// the `.pvd` series that lists them.
pub struct FrameWriter<'a> {
    dir: PathBuf,
    name: String,
    mesh: &'a Mesh,
    meshless: Option<&'a MeshlessBuild>,
    coupled: Option<&'a CoupledBuild>,
    /// Meshless and coupled: the nodes and shape-function values that give each VTU point's
    /// displacement (nodal parameters are not displacements).
    interp: Option<Vec<(Vec<usize>, Vec<f64>)>>,
    format: VtuFormat,
    /// (time s, file name) of every frame written.
    series: Vec<(f64, String)>,
}

impl<'a> FrameWriter<'a> {
    /// A writer of `name_0000.vtu`, ... in `dir` (created if missing).
    pub fn new(
        dir: &Path,
        name: &str,
        mesh: &'a Mesh,
        meshless: Option<&'a MeshlessBuild>,
        coupled: Option<&'a CoupledBuild>,
        format: VtuFormat,
    ) -> Result<Self> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let interp: Option<Vec<(Vec<usize>, Vec<f64>)>> = match (meshless, coupled) {
            (None, Some(c)) => Some(
                c.vertex_weights()?
                    .into_iter()
                    .map(|w| w.into_iter().unzip())
                    .collect(),
            ),
            (Some(m), _) => Some(
                m.background
                    .nodes
                    .iter()
                    .enumerate()
                    .map(|(v, x)| {
                        m.shape_values(x, &|| format!("output point {v}"))
                            .map(|s| (s.ids, s.phi))
                    })
                    .collect::<Result<Vec<_>>>()?,
            ),
            (None, None) => None,
        };
        Ok(FrameWriter {
            dir: dir.to_path_buf(),
            name: name.to_string(),
            mesh,
            meshless,
            coupled,
            interp,
            format,
            series: Vec::new(),
        })
    }

    /// Writes the next frame: displacement (m) per point; Cauchy and von Mises stress (Pa) and
    /// J per cell, from `model` at displacements `u` and time `t` (s).
    pub fn write(&mut self, model: &mut Model<Solid>, t: f64, u: &[Vector3<f64>]) -> Result<()> {
        let (sig, vm, jac) = model.stress_fields(u);
        let file = format!("{}_{:04}.vtu", self.name, self.series.len());
        let path = self.dir.join(&file);
        let format = self.format;
        let cells: Option<(&[Vector3<f64>], (Vec<usize>, Vec<usize>, Vec<u8>), &[usize])> =
            match (self.meshless, self.coupled) {
                (Some(m), _) => {
                    let b = &m.background;
                    let npc = b.shape.nodes_per_cell();
                    Some((
                        &b.nodes,
                        (
                            b.cells.clone(),
                            (1..=b.num_cells()).map(|e| e * npc).collect(),
                            vec![b.shape.vtk_type(); b.num_cells()],
                        ),
                        &m.owner,
                    ))
                }
                (None, Some(c)) => Some((&c.nodes, c.vtu_cells(), &c.owner)),
                (None, None) => None,
            };
        match (&self.interp, cells) {
            (Some(interp), Some((points, (conn, offsets, types), owner))) => {
                let disp: Vec<f64> = interp
                    .iter()
                    .flat_map(|(ids, phi)| {
                        let d = ids
                            .iter()
                            .zip(phi)
                            .fold(Vector3::zeros(), |a: Vector3<f64>, (&i, &p)| a + u[i] * p);
                        [d.x, d.y, d.z]
                    })
                    .collect();
                write_meshless_frame(
                    &path,
                    points,
                    (&conn, &offsets, &types),
                    owner,
                    &disp,
                    (&sig, &vm, &jac),
                    format,
                )?;
            }
            _ => {
                let disp: Vec<f64> = u.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
                let point_data = vec![DataArray {
                    name: "displacement",
                    components: 3,
                    values: &disp,
                }];
                let cell_data = vec![
                    DataArray {
                        name: "cauchy_stress",
                        components: 9,
                        values: &sig,
                    },
                    DataArray {
                        name: "von_mises",
                        components: 1,
                        values: &vm,
                    },
                    DataArray {
                        name: "J",
                        components: 1,
                        values: &jac,
                    },
                ];
                vtu::write_mesh(&path, self.mesh, point_data, cell_data, format)?;
            }
        }
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
    let mut frames = FrameWriter::new(
        dir,
        &name,
        &prep.mesh,
        prep.meshless.as_ref(),
        prep.coupled.as_ref(),
        format,
    )?;
    for (t, u) in &out.frames {
        frames.write(&mut prep.model, *t, u)?;
    }
    frames.write_series()?;
    write_results(dir, &name, prep, out, summary, format)
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
    if let Some(m) = prep.meshless.as_ref().filter(|m| m.adaptive.is_some()) {
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
        .coupled
        .as_ref()
        .and_then(|c| c.adaptive_points.as_ref().map(|a| (c, a)))
    {
        // The interior's points are the last ones; their owners are offset by the FE cells.
        let first = c.points.len() - pos.len();
        let fe_cells = c.fe_mesh.num_cells();
        let owner: Vec<usize> = c.owner[first..]
            .iter()
            .map(|&e| e.saturating_sub(fe_cells))
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
    let json = serde_json::to_string_pretty(summary)
        .map_err(|e| Error::Input(format!("cannot serialise the summary: {e}")))?;
    std::fs::write(dir.join("summary.json"), json)
        .map_err(|e| Error::io(dir.join("summary.json"), e))?;
    Ok(())
}
