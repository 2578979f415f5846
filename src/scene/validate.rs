//! Checks of a parsed scene that serde cannot express, and the exact references it implies.

use super::{
    BoundarySpec, CloudKind, Displacement, Geometry, IntegrationKind, MaterialSpec, MeshFormat,
    Method, Scene, MAX_ELEMENTS,
};
use crate::geometry::select::Selection;
use crate::solver::Mode;

/// The Ogden exponents accepted, |alpha| from .0 to .1: below, the energy's rounding error
/// (about 3 eps / alpha^2 of mu) exceeds 1e-11 mu, and at 1e-300 alpha^2 underflows to 0 (a NaN
/// energy); above, lbar^alpha overflows f64 at moderate stretches (5^1000 at |alpha| = 1000),
/// while 100 still holds stretches from 1e-3 to 1e3.
const OGDEN_ALPHA: (f64, f64) = (0.01, 100.0);

/// Computes the value of every `exact = "uniaxial"` reference: a box with one face (a plane
/// selection at the box's min or max along axis k) driven by d along k stretches by
/// lambda = 1 + d / L_k; the lateral stretch a and sigma_kk come from
/// [`crate::material::uniaxial_stretch`]. Reactions along k on either end face are
/// +-sigma_kk times the deformed cross-section; probe displacements are (stretch - 1) times
/// the probe's distance from the box's min corner.
pub(super) fn resolve_exact(s: &mut Scene) -> std::result::Result<(), Invalid> {
    let names: Vec<String> = s
        .references
        .iter()
        .filter(|(_, r)| r.exact.is_some())
        .map(|(n, _)| n.clone())
        .collect();
    for name in names {
        let r = &s.references[&name];
        let kind = r.exact.clone().unwrap_or_default();
        let fail = |why: String| {
            Invalid::at(
                format!("references.{name}.exact"),
                format!("references.{name}: exact = '{kind}': {why}"),
            )
        };
        if kind != "uniaxial" {
            return Err(fail("the known exact solution is 'uniaxial'".into()));
        }
        let Geometry::Box { min, max } = s.geometry else {
            return Err(fail("needs geometry.shape = 'box'".into()));
        };
        // The driven face: the one boundary with a prescribed displacement on a face of the box
        // (conditions inside the box, such as a plane held at the exact field, are ignored).
        let on_face = |b: &BoundarySpec| match &b.select {
            Selection::Plane { axis, value, .. } => {
                let k = axis.index();
                let tol = 1e-9 * (max[k] - min[k]);
                ((value - max[k]).abs() <= tol)
                    .then_some((k, true))
                    .or_else(|| ((value - min[k]).abs() <= tol).then_some((k, false)))
            }
            _ => None,
        };
        let driven: Vec<(&String, &BoundarySpec, usize, bool)> = s
            .boundaries
            .iter()
            .filter(|(_, b)| b.displacement.is_some())
            .filter_map(|(n, b)| on_face(b).map(|(k, at_max)| (n, b, k, at_max)))
            .collect();
        let [(bname, b, k, at_max)] = driven[..] else {
            return Err(fail(format!(
                "needs exactly one boundary with a displacement on a face of the box (found {})",
                driven.len()
            )));
        };
        let d = b.displacement.clone().unwrap_or(Displacement {
            x: None,
            y: None,
            z: None,
        });
        let comps = [d.x, d.y, d.z];
        if (0..3).any(|c| c != k && comps[c].is_some_and(|v| v != 0.0)) {
            return Err(fail(format!(
                "boundary '{bname}' must be driven along its normal only"
            )));
        }
        let len = max[k] - min[k];
        let dk = comps[k].unwrap_or(0.0);
        let stretch = 1.0 + if at_max { dk } else { -dk } / len;
        if !(stretch > 0.0) {
            return Err(fail(format!(
                "the stretch 1 + d / L = {num_stretch} must be positive",
                num_stretch = crate::error::Num(stretch)
            )));
        }
        if !s.regions.is_empty() {
            return Err(fail(
                "the exact uniaxial solution holds for one material; this scene has regions".into(),
            ));
        }
        let (a, _, sigma) = match s.material.solid() {
            crate::material::Solid::NeoHookean(m) => crate::material::uniaxial_stretch(&m, stretch),
            crate::material::Solid::Ogden(m) => m.uniaxial(stretch),
        };
        let parts: Vec<&str> = r.quantity.split('.').collect();
        let c = match parts[2] {
            "x" => 0,
            "y" => 1,
            _ => 2,
        };
        let value = match parts[0] {
            "reaction" if c == k => {
                let Some(Selection::Plane { axis, value, .. }) =
                    s.boundaries.get(parts[1]).map(|b| &b.select)
                else {
                    return Err(fail(format!("boundary '{}' must select a face", parts[1])));
                };
                if axis.index() != k {
                    return Err(fail(format!(
                        "boundary '{}' is not an end face along {}",
                        parts[1],
                        ["x", "y", "z"][k]
                    )));
                }
                let area: f64 = (0..3)
                    .filter(|&i| i != k)
                    .map(|i| a * (max[i] - min[i]))
                    .product();
                let sign = if (value - max[k]).abs() < (value - min[k]).abs() {
                    1.0
                } else {
                    -1.0
                };
                sign * sigma * area
            }
            "reaction" => {
                return Err(fail(
                    "lateral reactions vanish exactly; a relative error against 0 is undefined"
                        .into(),
                ))
            }
            _ => {
                let Some(pos) = s.probes.get(parts[1]).and_then(|p| p.position()) else {
                    return Err(fail(format!("probe '{}' needs a `position`", parts[1])));
                };
                let st = if c == k { stretch } else { a };
                (st - 1.0) * (pos[c] - min[c])
            }
        };
        if let Some(r) = s.references.get_mut(&name) {
            r.value = Some(value);
        }
    }
    Ok(())
}

/// The model name, moduli and density of a material (`key` names it in errors).
fn check_material(m: &MaterialSpec, key: &str) -> std::result::Result<(), Invalid> {
    match m.model.as_str() {
        "neo-hookean" => {
            if m.alpha.is_some() && key == "material" {
                return Err(Invalid::at(format!("{key}.alpha"), format!("{key}.alpha is the Ogden exponent; set model = 'ogden' or remove it")));
            }
        }
        "ogden" => match m.alpha {
            Some(a) if (OGDEN_ALPHA.0..=OGDEN_ALPHA.1).contains(&a.abs()) => {}
            Some(a) if a != 0.0 => {
                return Err(Invalid::at(format!("{key}.alpha"), format!(
                    "{key}.alpha = {num_a}: the Ogden exponent must lie within {} <= |alpha| <= {} \
                     (W = 2 mu / alpha^2 (sum lbar_i^alpha - 3) keeps no digits below: rounding / alpha^2; \
                     and overflows above it at moderate stretches); tissue exponents lie within \
                     |alpha| <= 30 (-4.7 for brain, Miller and Chinzei 2002)",
                    OGDEN_ALPHA.0,
                    OGDEN_ALPHA.1
                , num_a = crate::error::Num(a))))
            }
            _ => {
                return Err(Invalid::at(format!("{key}"), format!(
                    "{key}: model = 'ogden' needs `alpha`, a non-zero exponent (-4.7 for brain tissue, \
                     Miller and Chinzei 2002)"
                )))
            }
        },
        other => {
            return Err(Invalid::at(format!("{key}.model"), format!(
                "{key}.model = '{other}': the available models are 'neo-hookean' and 'ogden'"
            )))
        }
    }
    if !(m.density > 0.0) {
        return Err(Invalid::at(
            format!("{key}.density"),
            format!(
                "{key}.density = {}: must be positive (kg/m^3)",
                crate::error::Num(m.density)
            ),
        ));
    }
    match (m.youngs_modulus, m.poisson_ratio, m.shear_modulus, m.bulk_modulus) {
        (Some(e), Some(nu), None, None) => {
            if !(e > 0.0) || !(nu > -1.0 && nu < 0.5) {
                return Err(Invalid::at(format!("{key}"), format!("{key}: need youngs_modulus > 0 (got {num_e}) and -1 < poisson_ratio < 0.5 (got {num_nu})", num_e = crate::error::Num(e), num_nu = crate::error::Num(nu))));
            }
        }
        (None, None, Some(mu), Some(k)) => {
            if !(mu > 0.0 && k > 0.0) {
                return Err(Invalid::at(format!("{key}"), format!("{key}: shear_modulus ({num_mu}) and bulk_modulus ({num_k}) must be positive (Pa)", num_mu = crate::error::Num(mu), num_k = crate::error::Num(k))));
            }
        }
        _ => return Err(Invalid::at(format!("{key}"), format!("{key}: give either youngs_modulus and poisson_ratio, or shear_modulus and bulk_modulus"))),
    }
    Ok(())
}

/// A curve name must be built in or a `[curves.NAME]` table.
fn check_curve(s: &Scene, key: &str, name: &str) -> std::result::Result<(), Invalid> {
    if crate::bc::LoadCurve::builtin(name).is_some() || s.curves.contains_key(name) {
        return Ok(());
    }
    let mut known: Vec<&str> = crate::bc::LoadCurve::BUILTIN.to_vec();
    known.extend(s.curves.keys().map(String::as_str));
    Err(Invalid::at(
        format!("{key}"),
        format!(
            "{key} = '{name}': no such curve; use one of {} or add a [curves.{name}] table",
            known.join(", ")
        ),
    ))
}

/// A scene value refused: its dotted key and the sentence that says what is wrong (which
/// names the key too, as the message is read alone).
pub(super) struct Invalid {
    pub key: String,
    pub message: String,
}

impl Invalid {
    pub(super) fn at(key: impl Into<String>, message: impl Into<String>) -> Self {
        Invalid {
            key: key.into(),
            message: message.into(),
        }
    }
}

/// Physical and structural checks that serde cannot express.
pub(super) fn validate(s: &Scene) -> std::result::Result<(), Invalid> {
    check_geometry(s)?;
    check_discretization(s)?;
    check_materials_and_curves(s)?;
    check_conditions(s)?;
    check_solver(s)?;
    check_outputs(s)?;
    Ok(())
}

/// The geometry: a box with positive extent, positive shape sizes, a mesh file with a positive
/// unit factor and a known format.
fn check_geometry(s: &Scene) -> std::result::Result<(), Invalid> {
    match &s.geometry {
        Geometry::Box { min, max } => {
            if (0..3).any(|k| !(max[k] > min[k])) {
                return Err(Invalid::at(
                    "geometry",
                    format!(
                        "geometry: box max {max:?} must exceed min {min:?} in every coordinate"
                    ),
                ));
            }
        }
        Geometry::Cylinder { radius, height } => {
            if !(*radius > 0.0 && *height > 0.0) {
                return Err(Invalid::at("geometry", format!("geometry: cylinder radius ({num_radius}) and height ({num_height}) must be positive (m)", num_radius = crate::error::Num(radius), num_height = crate::error::Num(height))));
            }
        }
        Geometry::HalfEllipsoid { semi_axes } => {
            if !semi_axes.iter().all(|v| v.is_finite() && *v > 0.0) {
                return Err(Invalid::at("geometry", format!("geometry: half_ellipsoid semi_axes {semi_axes:?} must be positive and finite (m)")));
            }
        }
        Geometry::Surface { file, units } => {
            if !(*units > 0.0 && units.is_finite()) {
                return Err(Invalid::at("geometry.units", format!("geometry.units = {num_units}: must be a positive factor to metres (0.001 for a surface in mm)", num_units = crate::error::Num(units))));
            }
            if crate::io::surface_file::SurfaceFormat::from_path(file).is_none() {
                return Err(Invalid::at("geometry.surface", format!(
                    "geometry.surface = '{}': unknown extension; use .stl (ASCII or binary), .obj, or VTK poly data (.vtk, .vtp)",
                    file.display()
                )));
            }
        }
        Geometry::Image { file, labels, .. } => {
            if crate::io::image::ImageFormat::from_path(file).is_none() {
                return Err(Invalid::at("geometry.image", format!(
                    "geometry.image = '{}': unknown extension; use a NIfTI-1 (.nii, .nii.gz) or NRRD (.nrrd, .nhdr) labelmap",
                    file.display()
                )));
            }
            if labels.contains(&0) {
                return Err(Invalid::at("geometry.labels", "geometry.labels: label 0 is background (holes stay holes); list the tissue labels"));
            }
            if s.discretization.size.is_none() {
                return Err(Invalid::at("geometry.image", "geometry.image needs discretization.size (the element edge, m; the image's voxels are grouped in blocks about that size)"));
            }
        }
        Geometry::Mesh {
            file,
            format,
            units,
            ..
        } => {
            if !(*units > 0.0 && units.is_finite()) {
                return Err(Invalid::at("geometry.units", format!("geometry.units = {num_units}: must be a positive factor to metres (0.001 for a mesh in mm)", num_units = crate::error::Num(units))));
            }
            if format.is_none() && MeshFormat::from_path(file).is_none() {
                return Err(Invalid::at("geometry.mesh", format!(
                    "geometry.mesh = '{}': unknown extension; use .inp, .msh, .vtk or .vtu, or set geometry.format",
                    file.display()
                )));
            }
        }
    }
    Ok(())
}

/// `[discretization]`: sizes, divisions and the element count they give, rules, supports and the meshless and coupled settings.
fn check_discretization(s: &Scene) -> std::result::Result<(), Invalid> {
    let d = &s.discretization;
    if let Some(h) = d.size {
        if !(h > 0.0) {
            return Err(Invalid::at(
                "discretization.size",
                format!(
                    "discretization.size = {num_h}: must be a positive length in m",
                    num_h = crate::error::Num(h)
                ),
            ));
        }
    }
    if let Some(div) = d.divisions {
        if div.contains(&0) {
            return Err(Invalid::at(
                "discretization.divisions",
                format!("discretization.divisions = {div:?}: every division must be at least 1"),
            ));
        }
        let [a, b, c] = div.map(|k| k as f64);
        // The cylinder's O-grid has n_inner^2 + 4 n_inner n_radial cells per layer, the box
        // nx ny nz (tets: 6 per hex, checked at the hex count as the element limit is).
        let n = match &s.geometry {
            Geometry::Cylinder { .. } => (a * a + 4.0 * a * b) * c,
            _ => a * b * c,
        };
        if n > MAX_ELEMENTS {
            return Err(Invalid::at("discretization.divisions", format!(
                "discretization.divisions = {div:?} gives {sci_n:.3e} cells, more than the limit of \
                 {sci_MAX_ELEMENTS:.0e}; use fewer divisions", sci_n = crate::error::Sci(n), sci_MAX_ELEMENTS = crate::error::Sci(MAX_ELEMENTS))));
        }
    }
    let extent = match &s.geometry {
        Geometry::Box { min, max } => Some([max[0] - min[0], max[1] - min[1], max[2] - min[2]]),
        Geometry::Cylinder { radius, height } => Some([2.0 * radius, 2.0 * radius, *height]),
        Geometry::HalfEllipsoid { semi_axes: a } => Some([2.0 * a[0], 2.0 * a[1], a[2]]),
        Geometry::Mesh { .. } | Geometry::Surface { .. } | Geometry::Image { .. } => None,
    };
    if let (Some(e), Some(h), None) = (extent, d.size, d.divisions) {
        let n: f64 = e.iter().map(|l| (l / h).max(1.0)).product();
        if n > MAX_ELEMENTS {
            return Err(Invalid::at("discretization.size", format!(
                "discretization.size = {num_h} m gives about {sci_n:.3e} cells over the {:.3} x {:.3} x \
                 {:.3} m shape, more than the limit of {sci_MAX_ELEMENTS:.0e}; lengths are in metres \
                 (is the size given in mm?)",
                e[0], e[1], e[2]
            , sci_n = crate::error::Sci(n), sci_MAX_ELEMENTS = crate::error::Sci(MAX_ELEMENTS), num_h = crate::error::Num(h))));
        }
    }
    if let Some(k) = d.mean_dilatation_patch_given {
        if !(1..=1000).contains(&k) {
            return Err(Invalid::at(
                "discretization.mean_dilatation_patch",
                format!(
                "discretization.mean_dilatation_patch = {k}: must be between 1 (each point its \
                 own J) and 1000 interior tets"
            ),
            ));
        }
    }
    if let Some(k) = d.tets_per_point_given {
        if !(1.0..=1000.0).contains(&k) {
            return Err(Invalid::at(
                "discretization.tets_per_point",
                format!(
                "discretization.tets_per_point = {k}: must be between 1 (one rule per tet) and 1000"
            ),
            ));
        }
        if d.integration != IntegrationKind::Tets {
            return Err(Invalid::at(
                "discretization.tets_per_point",
                format!(
                    "discretization.tets_per_point = {k} merges background-tet points; it needs \
                 integration = 'tets' (this scene has {:?})",
                    d.integration
                ),
            ));
        }
    }
    if ![1, 4, 5].contains(&d.tet_rule()) {
        return Err(Invalid::at(
            "discretization.tet_rule",
            format!(
                "discretization.tet_rule = {}: the tetrahedron rules have 1, 4 or 5 points",
                d.tet_rule()
            ),
        ));
    }
    if d.method == Method::Coupled && !(d.interface_scale >= 1.0 && d.interface_scale <= 4.0) {
        return Err(Invalid::at(
            "discretization.interface_scale",
            format!(
                "discretization.interface_scale = {}: use a factor in [1, 4] (default 1.5)",
                crate::error::Num(d.interface_scale)
            ),
        ));
    }
    let file_cloud = d.method != Method::Fe && d.cloud == CloudKind::File;
    let mesh_geometry = matches!(s.geometry, Geometry::Mesh { .. });
    if d.size.is_none() && d.divisions.is_none() && !file_cloud && !mesh_geometry {
        return Err(Invalid::at(
            "discretization",
            "discretization: give `size` (target element length, m) or `divisions`",
        ));
    }
    if !(d.jitter >= 0.0 && d.jitter < 0.5) {
        return Err(Invalid::at(
            "discretization.jitter",
            format!(
                "discretization.jitter = {}: must lie in [0, 0.5) (fraction of the node spacing)",
                crate::error::Num(d.jitter)
            ),
        ));
    }
    if !(d.point_ratio > 0.0) {
        return Err(Invalid::at(
            "discretization.point_ratio",
            format!(
                "discretization.point_ratio = {}: must be positive (integration points per node)",
                crate::error::Num(d.point_ratio)
            ),
        ));
    }
    if !(d.tolerance > 0.0 && d.tolerance.is_finite()) {
        return Err(Invalid::at(
            "discretization.tolerance",
            format!(
                "discretization.tolerance = {}: must be a positive relative accuracy (e.g. 0.001)",
                crate::error::Num(d.tolerance)
            ),
        ));
    }
    if ![2, 4, 8].contains(&d.subdivision) {
        return Err(Invalid::at("discretization.subdivision", format!(
            "discretization.subdivision = {}: use 2 (longest-edge bisection), 4 (three edge midpoints) or 8 (all six)",
            d.subdivision
        )));
    }
    let deepest = crate::meshless::adaptive::max_level_for(d.subdivision);
    if d.max_level > deepest {
        return Err(Invalid::at("discretization.max_level", format!(
            "discretization.max_level = {}: at most {deepest} with subdivision = {} (a cell may split into at most 2^18 leaves)",
            d.max_level, d.subdivision
        )));
    }
    if !(d.mu >= 0.0) || !(d.min_rcond > 0.0 && d.min_rcond < 1.0) {
        return Err(Invalid::at(
            "discretization",
            format!(
                "discretization: mu ({}) must be >= 0 and min_rcond ({}) in (0, 1)",
                crate::error::Num(d.mu),
                crate::error::Num(d.min_rcond)
            ),
        ));
    }
    if d.cloud == CloudKind::File && d.cloud_file.is_none() {
        return Err(Invalid::at(
            "discretization.cloud",
            "discretization.cloud = 'file' needs cloud_file = \"path/to/nodes.csv\"",
        ));
    }
    if !(d.min_spacing > 0.0) {
        return Err(Invalid::at(
            "discretization.min_spacing",
            format!(
                "discretization.min_spacing = {}: must be positive (fraction of size)",
                crate::error::Num(d.min_spacing)
            ),
        ));
    }
    // The bounds the supports are built with, named here by their keys.
    use crate::meshless::support::{DILATATION, MIN_ALPHA, MIN_NEAREST};
    if let Some(x) = d
        .dilatation
        .filter(|x| !(*x > DILATATION.0 && *x < DILATATION.1))
    {
        return Err(Invalid::at(
            "discretization.dilatation",
            format!(
                "discretization.dilatation = {num_x}: must lie in ({}, {}) (influence radius / mean \
             neighbour distance; 1.6 linear, 2.0 quadratic by default)",
                DILATATION.0, DILATATION.1
            , num_x = crate::error::Num(x)),
        ));
    }
    if let Some(n) = d.support_nodes.filter(|&n| n < MIN_NEAREST) {
        return Err(Invalid::at(
            "discretization.support_nodes",
            format!(
                "discretization.support_nodes = {n}: at least {MIN_NEAREST} nodes (8 linear, 16 \
             quadratic by default)"
            ),
        ));
    }
    if !(d.alpha >= MIN_ALPHA) {
        return Err(Invalid::at(
            "discretization.alpha",
            format!(
            "discretization.alpha = {}: must be at least {MIN_ALPHA} (weight radius / distance of \
             the farthest support node; default 10)",
            crate::error::Num(d.alpha)),
        ));
    }
    if let Some(h) = d.hourglass.filter(|h| !(*h >= 0.0)) {
        return Err(Invalid::at("discretization.hourglass", format!(
            "discretization.hourglass = {num_h}: must be >= 0 (default 0.51 with hourglass_modulus = 'shear', 0.01 with 'p-wave')"
        , num_h = crate::error::Num(h))));
    }
    if !d.refine.is_empty()
        && !(d.mesher == crate::scene::Mesher::Tetgen
            && matches!(s.geometry, Geometry::HalfEllipsoid { .. }))
    {
        return Err(Invalid::at(
            "discretization.refine",
            "discretization.refine grades the TetGen mesh of the half-ellipsoid (geometry.shape = \
             'half_ellipsoid', discretization.mesher = 'tetgen'); a mesh file carries its own \
             grading (meshes/make_gmsh_brain_indentation.py shows one)",
        ));
    }
    for (k, r) in d.refine.iter().enumerate() {
        let h = d.size.unwrap_or(f64::INFINITY);
        if !(r.size > 0.0 && r.size.is_finite() && r.size <= h) {
            return Err(Invalid::at(
                format!("discretization.refine[{k}].size"),
                format!(
                "discretization.refine[{k}].size = {}: must be a positive length in m, at most \
                 discretization.size",
                crate::error::Num(r.size)),
            ));
        }
        if !(r.size >= 1e-4 * h.min(1.0)) {
            return Err(Invalid::at(
                format!("discretization.refine[{k}].size"),
                format!(
                    "discretization.refine[{k}].size = {} m: below 1e-4 x discretization.size \
                 (millions of surface points); lengths are in metres",
                    crate::error::Num(r.size)
                ),
            ));
        }
        if !(r.growth > 1.0 && r.growth <= 3.0) {
            return Err(Invalid::at(
                format!("discretization.refine[{k}].growth"),
                format!(
                    "discretization.refine[{k}].growth = {}: must lie in (1, 3] (the ratio of \
                 neighbouring element sizes away from the outline; 1.25 by default)",
                    crate::error::Num(r.growth)
                ),
            ));
        }
    }
    Ok(())
}

/// `output.image`: a NIfTI-1 or NRRD file by its extension.
fn check_output_image(s: &Scene) -> std::result::Result<(), Invalid> {
    match &s.output.image {
        Some(f) if crate::io::image::ImageFormat::from_path(f).is_none() => Err(Invalid::at("output.image", format!(
            "output.image = '{}': unknown extension; give a NIfTI-1 (.nii, .nii.gz) or NRRD (.nrrd, .nhdr) image to warp",
            f.display()
        ))),
        _ => Ok(()),
    }
}

/// The material, each region's material and selection, and the tabulated curves.
fn check_materials_and_curves(s: &Scene) -> std::result::Result<(), Invalid> {
    check_output_image(s)?;
    check_material(&s.material, "material")?;
    for (name, r) in &s.regions {
        let key = format!("regions.{name}");
        if let Some(f) = &r.surface {
            if r.select.is_some() || r.elements.is_some() || r.labels.is_some() {
                return Err(Invalid::at(
                    format!("{key}"),
                    format!("{key}: give one of `select`, `elements`, `labels` or `surface`"),
                ));
            }
            if crate::io::surface_file::SurfaceFormat::from_path(f).is_none() {
                return Err(Invalid::at(
                    format!("{key}.surface"),
                    format!(
                        "{key}.surface = '{}': unknown extension; use .stl, .obj, .vtk or .vtp",
                        f.display()
                    ),
                ));
            }
            if r.units.is_some_and(|u| !(u > 0.0 && u.is_finite())) {
                return Err(Invalid::at(
                    format!("{key}.units"),
                    format!("{key}.units: a positive factor to metres"),
                ));
            }
            check_material(&s.material.with(r), &key)?;
            continue;
        }
        if r.units.is_some() {
            return Err(Invalid::at(
                format!("{key}.units"),
                format!("{key}.units applies to `surface = \"FILE\"`"),
            ));
        }
        match (&r.select, &r.elements, &r.labels) {
            (Some(Selection::Plane { .. }), _, _) | (Some(Selection::Set(_)), _, _) => {
                return Err(Invalid::at(format!("{key}.select"), format!(
                    "{key}.select: a region is a volume; use a box, sphere or cylinder (or \
                     `elements = \"SET\"` for an element set of the mesh file)"
                )))
            }
            (Some(_), None, None) | (None, Some(_), None) => {}
            (None, None, Some(labels)) => {
                if !matches!(s.geometry, Geometry::Image { .. }) {
                    return Err(Invalid::at(format!("{key}.labels"), format!(
                        "{key}.labels selects voxels of the geometry's image: it needs `geometry.image`"
                    )));
                }
                if labels.is_empty() || labels.contains(&0) {
                    return Err(Invalid::at(format!("{key}.labels"), format!(
                        "{key}.labels = {labels:?}: list one or more nonzero labels of the image"
                    )));
                }
            }
            _ => {
                return Err(Invalid::at(format!("{key}"), format!(
                    "{key}: give one of `select = {{ box | sphere | cylinder = ... }}`, `elements = \"SET\"`, `labels = [N, ...]` or `surface = \"FILE\"`"
                )))
            }
        }
        check_material(&s.material.with(r), &key)?;
    }
    for (name, c) in &s.curves {
        if crate::bc::LoadCurve::builtin(name).is_some() {
            return Err(Invalid::at(
                format!("curves.{name}"),
                format!("curves.{name}: '{name}' is a built-in curve; give the table another name"),
            ));
        }
        if c.points.is_some() == c.file.is_some() {
            return Err(Invalid::at(format!("curves.{name}"), format!(
                "curves.{name}: give either `points = [[t, factor], ...]` (t in s) or `file = \"curve.csv\"`"
            )));
        }
    }
    Ok(())
}

/// Boundaries, measured displacements, contact and loads: selections, values and the curves they name.
fn check_conditions(s: &Scene) -> std::result::Result<(), Invalid> {
    let selections = s
        .boundaries
        .iter()
        .map(|(n, b)| (format!("boundaries.{n}"), Some(&b.select)))
        .chain(
            s.regions
                .iter()
                .map(|(n, r)| (format!("regions.{n}"), r.select.as_ref())),
        )
        .chain(
            s.loads
                .iter()
                .map(|(n, l)| (format!("loads.{n}"), l.select.as_ref())),
        )
        .chain(
            s.contact
                .iter()
                .map(|(n, c)| (format!("contact.{n}"), c.select.as_ref())),
        )
        .chain(
            s.probes
                .iter()
                .map(|(n, p)| (format!("probes.{n}"), p.select())),
        );
    for (key, sel) in selections {
        if let Some(sel) = sel {
            sel.check()
                .map_err(|m| Invalid::at(format!("{key}.select"), format!("{key}.select: {m}")))?;
        }
    }
    for (name, b) in &s.boundaries {
        check_curve(s, &format!("boundaries.{name}.curve"), &b.curve)?;
    }
    for (name, m) in &s.measured {
        let key = format!("measured.{name}");
        check_curve(s, &format!("{key}.curve"), &m.curve)?;
        if s.boundaries.contains_key(name) || s.contact.contains_key(name) {
            return Err(Invalid::at(format!("{key}"), format!(
                "{key}: a boundary or rigid body has the same name; reactions are reported by name, so give it another"
            )));
        }
        if let Some(t) = m.tolerance.filter(|t| !(*t > 0.0)) {
            return Err(Invalid::at(
                format!("{key}.tolerance"),
                format!(
                    "{key}.tolerance = {num_t}: must be a positive distance (m)",
                    num_t = crate::error::Num(t)
                ),
            ));
        }
    }
    for (name, c) in &s.contact {
        let key = format!("contact.{name}");
        check_curve(s, &format!("{key}.curve"), &c.curve)?;
        if s.boundaries.contains_key(name) {
            return Err(Invalid::at(format!("{key}"), format!(
                "{key}: a boundary has the same name; reactions are reported by name, so give the rigid body another"
            )));
        }
        let positive = |v: Option<f64>| v.is_some_and(|r| r > 0.0);
        let nonzero = |v: Option<[f64; 3]>| v.is_some_and(|a| a.iter().any(|&x| x != 0.0));
        let (need, ok, allowed): (&str, bool, &[&str]) = match c.shape.as_str() {
            "plane" => (
                "`point = [x, y, z]` and a non-zero `normal` (pointing to the body)",
                c.point.is_some() && nonzero(c.normal),
                &["point", "normal"],
            ),
            "sphere" => (
                "`center` and `radius` > 0 (m)",
                c.center.is_some() && positive(c.radius),
                &["center", "radius"],
            ),
            "cylinder" => {
                let e = c.edge_radius.unwrap_or(0.0);
                (
                    "`center`, a non-zero `axis` and `radius` > 0 (m); `min` < `max` along the axis when \
                     given; `edge_radius` >= 0 (m), less than `radius` and than half of `max - min`",
                    c.center.is_some()
                        && nonzero(c.axis)
                        && positive(c.radius)
                        && !matches!((c.min, c.max), (Some(a), Some(b)) if !(a < b))
                        && e >= 0.0
                        && c.radius.is_some_and(|r| e < r)
                        && !matches!((c.min, c.max), (Some(a), Some(b)) if !(2.0 * e < b - a)),
                    &["center", "axis", "radius", "min", "max", "edge_radius"],
                )
            }
            "surface" => {
                let image = c
                    .file
                    .as_ref()
                    .is_some_and(|f| crate::io::image::ImageFormat::from_path(f).is_some());
                if image {
                    (
                        "`file` (a labelled image: .nii, .nii.gz, .nrrd), `labels` nonzero when given, \
                         a finite `offset` (m) and discretization.size (the blocks of voxels)",
                        c.labels.as_ref().is_none_or(|l| !l.contains(&0))
                            && c.offset.is_none_or(f64::is_finite)
                            && s.discretization.size.is_some(),
                        &["file", "labels", "offset", "inside"],
                    )
                } else {
                    (
                        "`file` (a closed surface: .stl, .obj, .vtk, .vtp, or a labelled image: .nii, \
                         .nii.gz, .nrrd), `units` > 0 and a finite `offset` (m) when given",
                        c.file.as_ref().is_some_and(|f| {
                            crate::io::surface_file::SurfaceFormat::from_path(f).is_some()
                        }) && c.units.is_none_or(|u| u > 0.0 && u.is_finite())
                            && c.offset.is_none_or(f64::is_finite),
                        &["file", "units", "offset", "inside"],
                    )
                }
            }
            other => {
                let shapes = "\"plane\", \"sphere\", \"cylinder\" or \"surface\"";
                return Err(Invalid::at(
                    format!("{key}.shape"),
                    format!("{key}.shape = '{other}': use {shapes}"),
                ));
            }
        };
        if !ok {
            return Err(Invalid::at(
                format!("{key}"),
                format!("{key}: a {} needs {need}", c.shape),
            ));
        }
        let given = [
            ("point", c.point.is_some()),
            ("normal", c.normal.is_some()),
            ("center", c.center.is_some()),
            ("radius", c.radius.is_some()),
            ("axis", c.axis.is_some()),
            ("min", c.min.is_some()),
            ("max", c.max.is_some()),
            ("edge_radius", c.edge_radius.is_some()),
            ("file", c.file.is_some()),
            ("units", c.units.is_some()),
            ("labels", c.labels.is_some()),
            ("offset", c.offset.is_some()),
            ("inside", c.inside.is_some()),
        ];
        if let Some((k, _)) = given.iter().find(|(k, g)| *g && !allowed.contains(k)) {
            return Err(Invalid::at(
                format!("{key}.{k}"),
                format!("{key}.{k} does not apply to a {}", c.shape),
            ));
        }
    }
    for (name, l) in &s.loads {
        check_curve(s, &format!("loads.{name}.curve"), &l.curve)?;
        let given = [
            l.gravity.is_some(),
            l.force.is_some(),
            l.traction.is_some(),
            l.pressure.is_some(),
        ];
        if given.iter().filter(|&&g| g).count() != 1 {
            return Err(Invalid::at(format!("loads.{name}"), format!(
                "loads.{name}: give exactly one of `gravity = [gx, gy, gz]` (m/s^2), `force = [fx, fy, fz]` \
                 (N per node), `traction = [tx, ty, tz]` (Pa) or `pressure = p` (Pa)"
            )));
        }
        match (l.gravity.is_some(), l.select.is_some()) {
            (true, true) => {
                return Err(Invalid::at(
                    format!("loads.{name}"),
                    format!("loads.{name}: gravity acts on the whole body; remove `select`"),
                ))
            }
            (false, false) => {
                return Err(Invalid::at(
                    format!("loads.{name}"),
                    format!(
                "loads.{name}: needs `select = {{ ... }}` (the nodes or boundary faces it acts on)"
            ),
                ))
            }
            _ => {}
        }
    }
    for (name, b) in &s.boundaries {
        if b.fix.is_empty()
            && b.displacement
                .as_ref()
                .is_none_or(|d| d.x.is_none() && d.y.is_none() && d.z.is_none())
        {
            return Err(Invalid::at(format!("boundaries.{name}"), format!("boundaries.{name}: neither `fix` nor `displacement` is given, so it constrains nothing")));
        }
    }
    Ok(())
}

/// `[solver]`: step factor, duration, tolerance, retries and damping.
fn check_solver(s: &Scene) -> std::result::Result<(), Invalid> {
    let sv = &s.solver;
    if !(sv.dt_factor > 0.0) {
        return Err(Invalid::at(
            "solver.dt_factor",
            format!(
                "solver.dt_factor = {}: must be positive (default 0.9)",
                crate::error::Num(sv.dt_factor)
            ),
        ));
    }
    // The conservative bounds (tet4-anp's) leave a factor of 2-3 at most: 10 is past any
    // stable step, and a mistyped factor would otherwise run to a divergence in seconds of
    // simulated time per step.
    if sv.dt_factor > 10.0 {
        return Err(Invalid::at(
            "solver.dt_factor",
            format!(
                "solver.dt_factor = {}: at most 10 (the step as a fraction of the critical step \
             estimate; above 1 only conservative estimates stay stable; default 0.9)",
                crate::error::Num(sv.dt_factor)
            ),
        ));
    }
    if !(sv.duration > 0.0) {
        return Err(Invalid::at(
            "solver.duration",
            format!(
                "solver.duration = {}: must be positive (s)",
                crate::error::Num(sv.duration)
            ),
        ));
    }
    if !(sv.tolerance > 0.0) {
        return Err(Invalid::at(
            "solver.tolerance",
            format!(
                "solver.tolerance = {}: must be positive (m)",
                crate::error::Num(sv.tolerance)
            ),
        ));
    }
    if let Some(k) = sv.retries.filter(|&k| k > 10) {
        return Err(Invalid::at(
            "solver.retries",
            format!(
            "solver.retries = {k}: at most 10 (each restart shortens the step by 0.75x; default 2)"
        ),
        ));
    }
    if !(sv.damping >= 0.0) {
        return Err(Invalid::at(
            "solver.damping",
            format!(
                "solver.damping = {}: must be >= 0 (1/s)",
                crate::error::Num(sv.damping)
            ),
        ));
    }
    if sv.mass_scaling == Some(true) && sv.mode == crate::solver::Mode::Dynamic {
        return Err(Invalid::at("solver.mass_scaling", "solver.mass_scaling = true: mass scaling replaces the masses by fictitious                     ones, which changes the dynamics; it is for mode = \"relaxation\" only (remove                     the key, or set solver.mode = \"relaxation\")"
            ));
    }
    Ok(())
}

/// Probes, initial motion and references.
fn check_outputs(s: &Scene) -> std::result::Result<(), Invalid> {
    if s.initial.is_some() && s.solver.mode != Mode::Dynamic {
        return Err(Invalid::at(
            "initial",
            "[initial] motion needs solver.mode = \"dynamic\" (relaxation seeks a steady state)",
        ));
    }
    for (name, r) in &s.references {
        if r.value.is_some() == r.exact.is_some() {
            return Err(Invalid::at(
                format!("references.{name}"),
                format!(
                    "references.{name}: give either `value` (N or m) or `exact = \"uniaxial\"`"
                ),
            ));
        }
        if r.value.is_some_and(|v| v == 0.0) {
            return Err(Invalid::at(
                format!("references.{name}.value"),
                format!(
                "references.{name}.value = 0: a relative error against 0 is undefined; compare a \
                 non-zero quantity"
            ),
            ));
        }
        if let Some(at) = r.at {
            if !(at > 0.0 && at <= 1.0) {
                return Err(Invalid::at(format!("references.{name}.at"), format!(
                    "references.{name}.at = {num_at}: the load fraction at which to compare must be in (0, 1] \
                     (1: the end of the run)"
                , num_at = crate::error::Num(at))));
            }
            if at < 1.0 && !s.solver.mode.is_steady() {
                return Err(Invalid::at(
                    format!("references.{name}.at"),
                    format!(
                        "references.{name}.at = {num_at}: comparing at a load fraction below 1 needs \
                     solver.mode = \"static\" or \"relaxation\" (the run converges at each such \
                     load stage); a dynamic run's path is in history.csv"
                    , num_at = crate::error::Num(at)),
                ));
            }
            if at < 1.0 && r.exact.is_some() {
                return Err(Invalid::at(format!("references.{name}"), format!(
                    "references.{name}: `exact` is the solution at the full load; give `value` for at = {num_at}"
                , num_at = crate::error::Num(at))));
            }
        }
        if let Some([lo, hi]) = r.band {
            let inside = r.value.is_none_or(|v| v >= lo && v <= hi);
            if !(lo <= hi) || !inside {
                return Err(Invalid::at(
                    format!("references.{name}.band"),
                    format!(
                    "references.{name}.band = [{lo}, {hi}]: expected [low, high] with low <= high \
                     around the value {}",
                    r.value.map_or("-".into(), |v| v.to_string())
                ),
                ));
            }
        }
        let parts: Vec<&str> = r.quantity.split('.').collect();
        let ok = parts.len() == 3
            && matches!(parts[2], "x" | "y" | "z")
            && match parts[0] {
                "reaction" => {
                    s.boundaries.contains_key(parts[1])
                        || s.contact.contains_key(parts[1])
                        || s.measured.contains_key(parts[1])
                }
                "probe" => s.probes.contains_key(parts[1]),
                _ => false,
            };
        if !ok {
            return Err(Invalid::at(format!("references.{name}.quantity"), format!(
                "references.{name}.quantity = '{}': expected reaction.BOUNDARY.x|y|z or probe.NAME.x|y|z naming a boundary ({}) or probe ({})",
                r.quantity,
                s.boundaries.keys().cloned().collect::<Vec<_>>().join(", "),
                s.probes.keys().cloned().collect::<Vec<_>>().join(", ")
            )));
        }
    }
    Ok(())
}
