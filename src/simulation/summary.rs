//! The summary of a finished run: what was solved, its results against the references, its
//! energy balance and cost.

use crate::report::StageResult;
use std::collections::BTreeMap;

use crate::report::{
    Comparison, CoupledInfo, Energy, MeshInfo, MeshlessInfo, ProbeResult, Summary, SupportNodes,
    WallSeconds, Warning, WarningKind, Warnings,
};
use crate::scene::Scene;
use crate::solver::{Mode, RunOutput};

use super::{Discretization, Prepared};

/// "fe", "coupled" or "meshless".
pub fn method_name(prep: &Prepared) -> &'static str {
    match prep.method {
        Discretization::Meshless { .. } => "meshless",
        Discretization::Coupled { .. } => "coupled",
        Discretization::Fe => "fe",
    }
}

/// The element or basis of a prepared scene: "hex8", "mls", "hex8+mls", ...
pub fn element_label(scene: &Scene, prep: &Prepared) -> String {
    match prep.method {
        Discretization::Meshless { .. } => basis_name(scene).into(),
        Discretization::Coupled { .. } => format!("{}+{}", prep.kind.name(), basis_name(scene)),
        Discretization::Fe => prep.kind.name().into(),
    }
}

/// The largest |F_int - F_ext| at a free DOF over the largest |F_int| component at any node,
/// now or at any recorded row of the run (`peak`, N: a load that ends at zero leaves forces of
/// rounding size, which are no scale) ([`crate::report::Summary::equilibrium_residual`]).
/// Nodes a corrector or contact moves after the update carry constraint forces, not
/// residuals, and are left out.
fn equilibrium_residual<M: crate::material::Material>(
    model: &crate::solver::Model<M>,
    f_int: &[nalgebra::Vector3<f64>],
    peak: f64,
) -> f64 {
    let n = f_int.len().min(model.constraints().mask.len());
    let mut moved = vec![false; n];
    for i in model.corrected_nodes() {
        if let Some(m) = moved.get_mut(i as usize) {
            *m = true;
        }
    }
    let (mut residual, mut scale) = (0.0f64, 0.0f64);
    for i in 0..n {
        let fe = model
            .external_forces()
            .get(i)
            .copied()
            .unwrap_or_else(nalgebra::Vector3::zeros);
        for k in 0..3 {
            scale = scale.max(f_int[i][k].abs());
            if !moved[i] && !model.constraints().mask[i][k] {
                residual = residual.max((f_int[i][k] - fe[k]).abs());
            }
        }
    }
    relative(residual, scale.max(peak), 0.0)
}

/// `value / scale`, with `floor` as the least scale: a quantity whose scale is zero or below
/// the floor (an unloaded run, forces or energies of rounding size) is measured against the
/// floor, not divided by nearly nothing; 0 when both are zero.
fn relative(value: f64, scale: f64, floor: f64) -> f64 {
    let s = scale.max(floor);
    if s > 0.0 {
        value / s
    } else {
        0.0
    }
}

/// The least energy scale of a balance (J): the strain energy of a uniform strain of 1e-6
/// in the body, mu V 1e-12 (shear modulus of the scene's material, volume of the points).
fn energy_floor(scene: &Scene, model: &crate::solver::Model<crate::material::Solid>) -> f64 {
    use crate::material::Material;
    let mu = scene.material.solid().lame().1;
    let volume: f64 = model.points().weights.iter().sum();
    1e-12 * mu.abs() * volume.abs()
}

/// Builds the summary of a finished run.
pub fn summarize(scene: &Scene, prep: &Prepared, out: &RunOutput, total_seconds: f64) -> Summary {
    let model = &prep.model;
    let reactions: BTreeMap<String, [f64; 3]> = model
        .reaction_names()
        .into_iter()
        .zip(model.reactions(&out.f_int))
        .map(|(b, r)| (b, [r.x, r.y, r.z]))
        .collect();
    let mut warnings = prep.warnings.clone();
    warnings.extend(Warning::all(
        WarningKind::Solve,
        out.restarts.iter().cloned(),
    ));
    warnings.extend(Warning::all(WarningKind::Solve, out.notes.iter().cloned()));
    let equilibrium_residual = out
        .load_steps
        .is_some()
        .then(|| equilibrium_residual(model, &out.f_int, out.peak_nodal_force));
    // The relaxation's criterion watches the displacements; a body far from equilibrium by its
    // forces is not "converged" whatever they do (a scene in millimetres read as metres stopped
    // "converged" at a residual of 1.0).
    let out_of_balance =
        equilibrium_residual.is_some_and(|r| !(r <= crate::report::RESIDUAL_NOT_CONVERGED));
    let converged = out.converged && !out_of_balance;
    if out.converged && out_of_balance {
        warnings.push(Warning::new(
            WarningKind::Solve,
            format!(
            "not converged: the relaxation's displacement criterion (solver.tolerance = {:e} m) \
             was met, but the largest out-of-balance force is {:.2e} of the largest nodal force \
             (more than {:.0e}): the body is not at equilibrium; lower solver.tolerance, and \
             check the units of the geometry and the material",
            scene.solver.tolerance,
            equilibrium_residual.unwrap_or(f64::NAN),
            crate::report::RESIDUAL_NOT_CONVERGED
        ),
        ));
    } else if let Some(r) = equilibrium_residual.filter(|&r| r > crate::report::RESIDUAL_WARNING) {
        warnings.push(Warning::new(
            WarningKind::Solve,
            format!(
                "equilibrium: the largest out-of-balance force at a free node is {r:.2e} of the \
             largest nodal force at the end of this run (more than {:.0e}): the \
             displacements are not at equilibrium to the digits shown; lower solver.tolerance \
             or raise solver.max_steps",
                crate::report::RESIDUAL_WARNING
            ),
        ));
    }
    let balance_error = (scene.solver.mode == Mode::Dynamic).then(|| {
        let input = out.external_work + out.initial_kinetic;
        let scale = input
            .abs()
            .max(out.peak_external_work + out.initial_kinetic);
        relative(
            (input - out.strain_energy - out.kinetic_energy - out.damping_dissipation).abs(),
            scale,
            energy_floor(scene, model),
        )
    });
    if let Some(b) = balance_error.filter(|&b| b > crate::report::ENERGY_WARNING) {
        warnings.push(Warning::new(
            WarningKind::Solve,
            format!(
                "energy balance: {:.2} % of the work put in is unaccounted for at the end of this \
             dynamic run (more than {:.0} %): an instability that grew without diverging, most \
             likely; the step ended at {:.4e} s against a critical estimate of {:.4e} s at the \
             start (solver.dt_factor {:.3}). Rerun with a smaller solver.dt_factor and compare",
                100.0 * b,
                100.0 * crate::report::ENERGY_WARNING,
                out.dt,
                out.dt_critical,
                scene.solver.dt_factor,
            ),
        ));
    }
    if let Some(c) = model.contact() {
        if c.worst_penetration() > c.tolerance() {
            warnings.push(Warning::new(
                WarningKind::Contact,
                format!(
                "contact: a step left a surface point {:.3e} m inside a rigid body, more than the \
                 tolerance {:.1e} m (the corrections did not converge within their sweeps; a \
                 sharp edge of the rigid surface or a large step per load increment)",
                c.worst_penetration(),
                c.tolerance()
            ),
            ));
        }
    }
    let probes: BTreeMap<String, ProbeResult> = prep
        .probes
        .iter()
        .map(|p| {
            let d = p.displacement(&out.u);
            (
                p.name.clone(),
                ProbeResult {
                    position: [p.position.x, p.position.y, p.position.z],
                    displacement: [d.x, d.y, d.z],
                },
            )
        })
        .collect();
    let stages: Vec<StageResult> = out
        .stages
        .iter()
        .map(|st| StageResult {
            load: st.load,
            step: st.step,
            reactions: model
                .reaction_names()
                .into_iter()
                .zip(st.reactions.iter().copied())
                .collect(),
            probes: prep
                .probes
                .iter()
                .map(|p| {
                    let d = p.displacement(&st.u);
                    (p.name.clone(), [d.x, d.y, d.z])
                })
                .collect(),
        })
        .collect();
    let reference = scene
        .references
        .iter()
        .filter_map(|(name, r)| {
            let parts: Vec<&str> = r.quantity.split('.').collect();
            let k = match parts.get(2) {
                Some(&"x") => 0,
                Some(&"y") => 1,
                _ => 2,
            };
            let at = r.at.filter(|&a| a < 1.0);
            let computed = match at {
                None => match parts[0] {
                    "reaction" => reactions.get(parts[1])?[k],
                    _ => probes.get(parts[1])?.displacement[k],
                },
                Some(a) => {
                    let st = stages.iter().find(|s| s.load == a)?;
                    match parts[0] {
                        "reaction" => st.reactions.get(parts[1])?[k],
                        _ => st.probes.get(parts[1])?[k],
                    }
                }
            };
            let value = r.value?;
            let scale = value.abs().max(f64::MIN_POSITIVE);
            let relative_error = (computed - value).abs() / scale;
            let band_error = r
                .band
                .map(|[lo, hi]| (lo - computed).max(computed - hi).max(0.0) / scale);
            Some((
                name.clone(),
                Comparison {
                    quantity: r.quantity.clone(),
                    value,
                    computed,
                    relative_error,
                    at,
                    band_error,
                    source: r.source.clone(),
                },
            ))
        })
        .collect();
    let w = out.external_work;
    Summary {
        scene: scene.name.clone().unwrap_or_default(),
        units: "SI: m, kg, s, N, Pa, J".into(),
        method: method_name(prep).into(),
        element: element_label(scene, prep),
        mode: match scene.solver.mode {
            Mode::Dynamic => "dynamic".into(),
            Mode::Relaxation => "relaxation".into(),
            Mode::Static => "static".into(),
        },
        nodes: model.nodes().len(),
        integration_points: model.points().len(),
        // The step the run started with (step_updates has the shortest one).
        dt: out.step_updates.dt_initial,
        dt_critical: out.dt_critical,
        dt_factor: if out.dt_critical > 0.0 {
            out.step_updates.dt_initial / out.dt_critical
        } else {
            0.0
        },
        steps: out.steps,
        force_evaluations: out.force_evaluations,
        statics: out.statics.clone(),
        failed_steps: out.failed_steps,
        restarts: out.restarts.len(),
        step_updates: (out.step_updates.estimates > 0).then_some(out.step_updates),
        simulated_time: out.simulated_time,
        status: match (out.load_steps.is_some(), converged) {
            (false, _) => "completed",
            (true, true) => "converged",
            (true, false) => "not converged",
        }
        .into(),
        converged,
        equilibrium_residual,
        threads: rayon::current_num_threads(),
        device: out.device.clone(),
        wall_seconds: WallSeconds {
            preprocess: prep.preprocess_seconds,
            solve: out.solve_seconds,
            total: total_seconds,
        },
        reactions,
        contact: model
            .contact()
            .as_ref()
            .map(|c| {
                c.names()
                    .enumerate()
                    .map(|(b, name)| {
                        (
                            name.to_string(),
                            crate::report::ContactInfo {
                                points_in_contact: c.points_in_contact()[b],
                                max_penetration: c.worst_penetration(),
                                tolerance: c.tolerance(),
                            },
                        )
                    })
                    .collect()
            })
            .unwrap_or_default(),
        loads: model
            .loads()
            .names()
            .iter()
            .zip(model.loads().totals())
            .map(|(n, t)| (n.clone(), [t.x, t.y, t.z]))
            .collect(),
        probes,
        energy: Energy {
            external_work: w,
            strain_energy: out.strain_energy,
            kinetic: out.kinetic_energy,
            peak_external_work: out.peak_external_work,
            damping_dissipation: (out.damping_dissipation > 0.0).then_some(out.damping_dissipation),
            // Initial kinetic energy (initial velocities) is energy put in, like the work.
            balance_error,
        },
        reference,
        stages,
        mesh: MeshInfo {
            elements: prep.mesh.num_cells(),
            min_dihedral_deg: prep.min_dihedral.map(|m| m.degrees),
            min_dihedral_element: prep.min_dihedral.map(|m| m.element),
            critical: out.critical,
            volume: model.points().total_weight(),
            geometry_volume: prep.source_volume.as_ref().map(|v| v.volume),
            geometry_volume_of: prep.source_volume.as_ref().map(|v| v.of.clone()),
        },
        support_nodes: prep
            .meshless()
            .map(|m| m.support_statistics())
            .or_else(|| prep.coupled().map(|c| c.support_statistics()))
            .map(|(mean, min, max)| SupportNodes { mean, min, max }),
        removed_nodes: prep.meshless().map(|m| m.removed_nodes),
        bc_method: prep.bc_method().map(|b| b.name().to_string()),
        meshless: prep.meshless().map(|m| MeshlessInfo {
            cloud: m.cloud.clone(),
            integration: m.integration.clone(),
            basis: basis_long(scene),
            support_rule: m.support.describe(),
            exact_volume: m.exact_volume,
            adaptive: m.adaptive.clone(),
        }),
        coupled: prep.coupled().map(|c| {
            use crate::coupling::{CellRole, NodeRole};
            CoupledInfo {
                fe_layers: scene.discretization.fe_layers(),
                fe_cells: c.regions.cells(CellRole::Fe),
                transition_cells: c.regions.cells(CellRole::Transition),
                meshless_cells: c.interior.num_cells(),
                fe_nodes: c.regions.nodes(NodeRole::Fe),
                interface_nodes: c.regions.nodes(NodeRole::Interface),
                meshless_nodes: c.regions.nodes(NodeRole::Meshless),
                fe_points: c.fe_points,
                transition_points: c.transition_points,
                meshless_points: c.meshless_points,
                full_rule_cells: c.full_rule_cells,
                basis: basis_long(scene),
                support_rule: c.support.describe(),
                adaptive: c.adaptive.clone(),
            }
        }),
        warnings: Warnings(warnings),
        relaxation: out.relaxation.clone(),
        load_steps: out.load_steps,
        momentum: (scene.mode_is_dynamic()).then_some(out.momentum),
    }
}

fn basis_name(scene: &Scene) -> &'static str {
    match scene.discretization.basis {
        crate::scene::Basis::Linear => "mls",
        crate::scene::Basis::Quadratic => "mmls",
    }
}

fn basis_long(scene: &Scene) -> String {
    match scene.discretization.basis {
        crate::scene::Basis::Linear => "linear MLS".into(),
        crate::scene::Basis::Quadratic => {
            format!("quadratic MMLS (mu = {:e})", scene.discretization.mu)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::relative;

    /// A zero or rounding-size scale is no scale: an unloaded run whose energies are 1e-17 J of
    /// rounding was reported 4.4e291 % out of balance (divided by f64::MIN_POSITIVE).
    #[test]
    fn relative_measures_against_the_floor_not_nearly_nothing() {
        assert_eq!(relative(9.8e-17, 0.0, 1e-9), 9.8e-17 / 1e-9);
        assert!(relative(9.8e-17, 0.0, 1e-9) < 1e-6);
        assert_eq!(relative(0.0, 0.0, 0.0), 0.0);
        assert_eq!(relative(1.0, 4.0, 1e-9), 0.25);
    }
}
