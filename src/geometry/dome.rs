//! The half-ellipsoid's surface made to follow the outlines of what acts on it: a driven
//! cylinder of tissue (an indenter's plug) or a rigid cylinder's rim, both circles about the
//! z axis, become rings of surface points, the plug's side and floor become inner facets, and
//! the rings and their points are spaced by a size that grows away from the outlines
//! ([`Grading`]). TetGen ([`super::tetgen::tetgen_half_ellipsoid_outlined`]) then meshes the
//! body with nodes on every outline, graded there.
//!
//! Without this the driven footprint is whichever nodes fall inside the cylinder (a faceted
//! 10 x 14 mm pit on the brain's 6 mm mesh for a 10 mm indenter) and changes with every mesh,
//! so the indentation force does not settle under refinement (issue 40).

use nalgebra::Vector3;

use crate::{Error, InputKind, Result};

/// Edge length that grows away from an outline: `size` (m) on it, `size + (growth - 1) d` at
/// a distance d (m) along the surface, up to the mesh's own size. `growth` is the ratio of
/// neighbouring element sizes (a geometric progression h_(k+1) = growth h_k has exactly this
/// size at the distance it has covered).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grading {
    /// Edge length on the outline (m).
    pub size: f64,
    /// Ratio of neighbouring element sizes, > 1.
    pub growth: f64,
}

/// A circle x^2 + y^2 = radius^2 on the dome, made a ring of surface points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outline {
    /// Radius about the z axis (m).
    pub radius: f64,
    /// The plug {x^2 + y^2 <= radius^2, z >= floor} (m) is a meshed sub-volume: its side and
    /// floor are inner facets, so a cylinder selection with `min = floor` selects it exactly.
    pub floor: Option<f64>,
    /// Element size near the outline; `None` keeps the mesh's size.
    pub grading: Option<Grading>,
}

/// The half-ellipsoid's piecewise linear complex: surface points and outward triangles (as
/// [`super::tetgen::half_ellipsoid_surface`]), the plug's inner facets (point-index polygons),
/// and for each plug a point inside it with the edge length wanted there.
#[derive(Debug, Clone, Default)]
pub struct DomePlc {
    pub points: Vec<Vector3<f64>>,
    pub triangles: Vec<[usize; 3]>,
    pub inner_facets: Vec<Vec<usize>>,
    pub plugs: Vec<(Vector3<f64>, f64)>,
}

/// Fine table of the ring family's parameter (see [`half_ellipsoid_outlined`]).
const NU: usize = 4096;
/// Meridians averaged in the family's arc length.
const NPHI: usize = 64;
/// Samples of a ring's arc length.
const NRING: usize = 2048;

/// The surface of the half-ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0 (`semi_axes`
/// = [a, b, c], m) with edges of about `h` (m) away from the `outlines`, each of which is a
/// ring of points, and with the plug of each outline that has a floor.
///
/// The dome's rings are the curves R(phi, u) (polar radius about the z axis, u in [0, 1],
/// apex 0, rim 1) lifted onto the ellipsoid: circles R = r_o u / u_o up to the largest
/// outline r_o (u_o = r_o / mean R_E), then R = r_o + (R_E(phi) - r_o)(u - u_o)/(1 - u_o)
/// out to the base ellipse R_E. The base has scaled copies of the rim ellipse to its centre,
/// as [`super::tetgen::half_ellipsoid_surface`]. Along the path apex - rim - centre (arc
/// length S, averaged over meridians), rings sit at the apex, every outline, the rim and the
/// centre, and between those at equal steps of the integral of dS / H(S), H being the
/// graded size; each ring has max(6, round(perimeter / H)) points equally spaced in arc
/// length, the first on the +x meridian. Consecutive rings are zipped into triangles.
pub fn half_ellipsoid_outlined(
    semi_axes: [f64; 3],
    h: f64,
    outlines: &[Outline],
) -> Result<DomePlc> {
    let [a, b, c] = semi_axes;
    check_half_ellipsoid(semi_axes, h)?;
    let mut outlines = outlines.to_vec();
    outlines.sort_by(|p, q| p.radius.total_cmp(&q.radius));
    outlines.dedup_by(|p, q| {
        // Two features on one circle: keep one, with the finer grading and any floor.
        if p.radius == q.radius {
            q.floor = q.floor.or(p.floor);
            q.grading = match (p.grading, q.grading) {
                (Some(x), Some(y)) if x.size < y.size => Some(x),
                (x, None) => x,
                (_, y) => y,
            };
            true
        } else {
            false
        }
    });
    let Some(r_o) = outlines.last().map(|o| o.radius) else {
        return Err(Error::input(InputKind::Mesh, "no outline to follow"));
    };
    let reach = 0.8 * a.min(b);
    for o in &outlines {
        if !(o.radius.is_finite() && o.radius > 0.0 && o.radius <= reach) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                    "an outline of radius {} m about the z axis cannot be a feature of the \
                 half-ellipsoid: it must lie within 0.8 x its smaller semi-axis ({reach} m)",
                    o.radius
                ),
            ));
        }
        if let Some(g) = o.grading {
            if !(g.size.is_finite() && g.size > 0.0 && g.growth.is_finite() && g.growth > 1.0) {
                return Err(Error::input(
                    InputKind::Value,
                    format!(
                        "refinement size {} m must be positive and growth {} above 1",
                        g.size, g.growth
                    ),
                ));
            }
        }
    }
    if outlines.iter().filter(|o| o.floor.is_some()).count() > 1 {
        return Err(Error::input(
            InputKind::Unsupported,
            "more than one driven plug (cylinder selection with a `min`) on the half-ellipsoid: \
             their sides and floors would cross; drive one plug",
        ));
    }
    // The dome over a point of the base (z >= 0).
    let dome_z = |x: f64, y: f64| c * (1.0 - (x / a).powi(2) - (y / b).powi(2)).max(0.0).sqrt();
    let r_e = |phi: f64| a * b / (b * phi.cos()).hypot(a * phi.sin());
    let mean_re = (0..NPHI)
        .map(|k| r_e(2.0 * std::f64::consts::PI * k as f64 / NPHI as f64))
        .sum::<f64>()
        / NPHI as f64;
    let u_o = r_o / mean_re;
    let radius_at = |phi: f64, u: f64| {
        if u <= u_o {
            r_o * u / u_o
        } else {
            r_o + (r_e(phi) - r_o) * (u - u_o) / (1.0 - u_o)
        }
    };
    let dome_point = |phi: f64, u: f64| {
        let r = radius_at(phi, u);
        let (x, y) = (r * phi.cos(), r * phi.sin());
        Vector3::new(x, y, dome_z(x, y))
    };
    // Arc length S(u) along the dome, averaged over meridians; the base continues it.
    let phis: Vec<f64> = (0..NPHI)
        .map(|k| 2.0 * std::f64::consts::PI * k as f64 / NPHI as f64)
        .collect();
    let mut s_dome = vec![0.0];
    let mut prev: Vec<Vector3<f64>> = phis.iter().map(|&p| dome_point(p, 0.0)).collect();
    for i in 1..=NU {
        let u = i as f64 / NU as f64;
        let cur: Vec<Vector3<f64>> = phis.iter().map(|&p| dome_point(p, u)).collect();
        let ds = cur
            .iter()
            .zip(&prev)
            .map(|(p, q)| (p - q).norm())
            .sum::<f64>()
            / NPHI as f64;
        s_dome.push(s_dome[i - 1] + ds);
        prev = cur;
    }
    let s_rim = s_dome[NU];
    let r_mean = 0.5 * (a + b);
    let s_end = s_rim + r_mean;
    let u_of = |s: f64| {
        let i = s_dome.partition_point(|&v| v <= s).clamp(1, NU);
        let (s0, s1) = (s_dome[i - 1], s_dome[i]);
        let f = if s1 > s0 { (s - s0) / (s1 - s0) } else { 0.0 };
        ((i - 1) as f64 + f.clamp(0.0, 1.0)) / NU as f64
    };
    let s_of_u = |u: f64| {
        let x = u * NU as f64;
        let i = (x.floor() as usize).min(NU - 1);
        s_dome[i] + (s_dome[i + 1] - s_dome[i]) * (x - i as f64)
    };
    let s_outline: Vec<f64> = outlines
        .iter()
        .map(|o| s_of_u(u_o * o.radius / r_o))
        .collect();
    let size_at = |s: f64| {
        outlines
            .iter()
            .zip(&s_outline)
            .filter_map(|(o, &so)| {
                o.grading
                    .map(|g| g.size + (g.growth - 1.0) * (s - so).abs())
            })
            .fold(h, f64::min)
    };
    let limit = 2_000_000.0;
    let finest = outlines
        .iter()
        .filter_map(|o| o.grading.map(|g| g.size))
        .fold(h, f64::min);
    if !(s_end / finest * (2.0 * std::f64::consts::PI * a / finest) <= limit * 50.0) {
        return Err(Error::input(
            InputKind::Limit,
            format!(
                "half-ellipsoid surface edge length {finest} m is too small for semi-axes \
             {semi_axes:?} m (millions of surface points); lengths are in metres"
            ),
        ));
    }
    // Ring levels (arc length S): fixed ones, and between them equal steps of int dS / H.
    let mut fixed = vec![0.0];
    fixed.extend(&s_outline);
    fixed.push(s_rim);
    fixed.push(s_end);
    let mut levels = vec![0.0];
    for w in fixed.windows(2) {
        let (lo, hi) = (w[0], w[1]);
        let n_int = 512;
        let mut cum = vec![0.0];
        for k in 0..n_int {
            let s0 = lo + (hi - lo) * k as f64 / n_int as f64;
            let s1 = lo + (hi - lo) * (k + 1) as f64 / n_int as f64;
            let mid = 0.5 * (s0 + s1);
            cum.push(cum[k] + (s1 - s0) / size_at(mid));
        }
        let total = cum[n_int];
        let n = total.round().max(1.0) as usize;
        for j in 1..n {
            let target = total * j as f64 / n as f64;
            let k = cum.partition_point(|&v| v <= target).clamp(1, n_int);
            let f = (target - cum[k - 1]) / (cum[k] - cum[k - 1]);
            levels.push(lo + (hi - lo) * ((k - 1) as f64 + f) / n_int as f64);
        }
        levels.push(hi);
    }

    let mut plc = DomePlc::default();
    let mut rings: Vec<Vec<usize>> = Vec::new();
    let ellipse = EllipseArc::new(a, b);
    let mut outline_rings: Vec<(usize, Vec<usize>)> = Vec::new();
    for &s in &levels {
        let target = size_at(s);
        let outline = s_outline
            .iter()
            .position(|&so| so == s)
            .filter(|_| s > 0.0 && s < s_rim);
        let ring: Vec<Vector3<f64>> = if s == 0.0 {
            vec![Vector3::new(0.0, 0.0, c)]
        } else if s == s_end {
            vec![Vector3::zeros()]
        } else if s >= s_rim {
            // The rim (s = s_rim) and the base rings: scaled copies of the base ellipse.
            let scale = if s == s_rim {
                1.0
            } else {
                1.0 - (s - s_rim) / r_mean
            };
            let m = ((scale * ellipse.perimeter() / target).round() as usize).max(6);
            ellipse
                .equal_arc(m)
                .into_iter()
                .map(|t| Vector3::new(a * scale * t.cos(), b * scale * t.sin(), 0.0))
                .collect()
        } else if let Some(k) = outline {
            let r = outlines[k].radius;
            let ring_at = |phi: f64| {
                let (x, y) = (r * phi.cos(), r * phi.sin());
                Vector3::new(x, y, dome_z(x, y))
            };
            equal_arc_ring(&ring_at, target)
        } else {
            let u = u_of(s);
            equal_arc_ring(&|phi| dome_point(phi, u), target)
        };
        let ids: Vec<usize> = ring
            .into_iter()
            .map(|p| {
                plc.points.push(p);
                plc.points.len() - 1
            })
            .collect();
        if let Some(k) = outline {
            outline_rings.push((k, ids.clone()));
        }
        rings.push(ids);
    }
    for w in rings.windows(2) {
        zip_rings(&w[0], &w[1], &mut plc.triangles);
    }
    // Plugs: the side (vertical quads under the outline's edges) and the floor.
    for (k, ring) in &outline_rings {
        let o = outlines[*k];
        let Some(floor) = o.floor else { continue };
        let lowest = ring
            .iter()
            .map(|&i| plc.points[i].z)
            .fold(f64::INFINITY, f64::min);
        if !(floor > 0.0 && floor < lowest) {
            return Err(Error::input(
                InputKind::Value,
                format!(
                "the driven plug of radius {} m with its floor at z = {floor} m: the floor must \
                 lie between the base (z = 0) and the lowest point of its outline on the dome \
                 (z = {lowest} m)",
                o.radius
            ),
            ));
        }
        let under: Vec<usize> = ring
            .iter()
            .map(|&i| {
                let p = plc.points[i];
                plc.points.push(Vector3::new(p.x, p.y, floor));
                plc.points.len() - 1
            })
            .collect();
        let m = ring.len();
        for j in 0..m {
            let j1 = (j + 1) % m;
            plc.inner_facets
                .push(vec![ring[j], ring[j1], under[j1], under[j]]);
        }
        plc.inner_facets.push(under.clone());
        let size = o.grading.map_or(h, |g| g.size);
        plc.plugs
            .push((Vector3::new(0.0, 0.0, 0.5 * (floor + lowest)), size));
    }
    Ok(plc)
}

/// Volume (m^3) enclosed by the closed, outward-oriented triangles `tris` over `points` (m):
/// the divergence theorem, a signed tetrahedron from the origin per triangle.
pub fn enclosed_volume(points: &[Vector3<f64>], tris: &[[usize; 3]]) -> f64 {
    tris.iter()
        .map(|t| points[t[0]].dot(&points[t[1]].cross(&points[t[2]])) / 6.0)
        .sum()
}

/// Panics unless every directed edge of `tris` occurs once and its reverse once (closed and
/// consistently oriented) and V - E + F = 2 over the points the triangles use (a sphere).
#[cfg(test)]
pub(crate) fn assert_closed_sphere(tris: &[[usize; 3]]) {
    let mut edges = std::collections::HashMap::new();
    for tri in tris {
        assert!(
            tri[0] != tri[1] && tri[1] != tri[2] && tri[0] != tri[2],
            "{tri:?}"
        );
        for k in 0..3 {
            *edges.entry((tri[k], tri[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    for (&(i, j), &n) in &edges {
        assert_eq!(n, 1, "edge {i}-{j} used {n} times in one direction");
        assert_eq!(edges.get(&(j, i)), Some(&1), "edge {i}-{j} has no twin");
    }
    let used: std::collections::HashSet<usize> = tris.iter().flatten().cloned().collect();
    assert_eq!(
        used.len() as i64 - (edges.len() / 2) as i64 + tris.len() as i64,
        2
    );
}

/// Refuses semi-axes (m) or a surface edge length `h` (m) that are not positive and finite.
pub(crate) fn check_half_ellipsoid(semi_axes: [f64; 3], h: f64) -> Result<()> {
    if !semi_axes.iter().all(|v| v.is_finite() && *v > 0.0) {
        return Err(Error::input(
            InputKind::Value,
            format!("half-ellipsoid semi-axes {semi_axes:?} m must be positive and finite"),
        ));
    }
    if !(h.is_finite() && h > 0.0) {
        return Err(Error::input(
            InputKind::Value,
            format!("half-ellipsoid surface edge length {h} m must be positive and finite"),
        ));
    }
    Ok(())
}

/// Points of the closed curve `at(phi)`, phi in [0, 2 pi), equally spaced in arc length about
/// `size` (m) apart (at least 6), the first at phi = 0.
fn equal_arc_ring(at: &dyn Fn(f64) -> Vector3<f64>, size: f64) -> Vec<Vector3<f64>> {
    let dphi = 2.0 * std::f64::consts::PI / NRING as f64;
    let mut cum = vec![0.0];
    let mut prev = at(0.0);
    for i in 1..=NRING {
        let p = at(i as f64 * dphi);
        cum.push(cum[i - 1] + (p - prev).norm());
        prev = p;
    }
    let total = cum[NRING];
    let m = ((total / size).round() as usize).max(6);
    (0..m)
        .map(|k| {
            if k == 0 {
                return at(0.0);
            }
            let target = total * k as f64 / m as f64;
            let i = cum.partition_point(|&v| v <= target).clamp(1, NRING);
            let f = (target - cum[i - 1]) / (cum[i] - cum[i - 1]);
            at(((i - 1) as f64 + f) * dphi)
        })
        .collect()
}

/// Arc length of the ellipse (a cos t, b sin t), t in [0, 2 pi], tabulated finely (Simpson's
/// rule on 4096 intervals) to place points equally spaced in arc length.
pub(crate) struct EllipseArc {
    /// Cumulative arc length at t_i = 2 pi i / N, i = 0..=N.
    s: Vec<f64>,
}

impl EllipseArc {
    const N: usize = 4096;

    pub(crate) fn new(a: f64, b: f64) -> Self {
        let dt = 2.0 * std::f64::consts::PI / Self::N as f64;
        let speed = |t: f64| (a * t.sin()).hypot(b * t.cos());
        let mut s = Vec::with_capacity(Self::N + 1);
        s.push(0.0);
        for i in 0..Self::N {
            // Simpson on each sub-interval.
            let t = i as f64 * dt;
            let ds = dt / 6.0 * (speed(t) + 4.0 * speed(t + 0.5 * dt) + speed(t + dt));
            s.push(s[i] + ds);
        }
        EllipseArc { s }
    }

    pub(crate) fn perimeter(&self) -> f64 {
        self.s[Self::N]
    }

    /// Parameters of `m` points equally spaced in arc length, the first at t = 0.
    pub(crate) fn equal_arc(&self, m: usize) -> Vec<f64> {
        let dt = 2.0 * std::f64::consts::PI / Self::N as f64;
        let total = self.perimeter();
        (0..m)
            .map(|k| {
                let target = total * k as f64 / m as f64;
                let i = self.s.partition_point(|&v| v <= target).clamp(1, Self::N);
                let (s0, s1) = (self.s[i - 1], self.s[i]);
                let f = if s1 > s0 {
                    (target - s0) / (s1 - s0)
                } else {
                    0.0
                };
                if k == 0 {
                    0.0
                } else {
                    (i as f64 - 1.0 + f) * dt
                }
            })
            .collect()
    }
}

/// Triangles between ring `u` and the next ring `l` (both in the same sense around the axis,
/// first points at arc-length fraction 0; a one-point ring is a pole). Each ring's edges are
/// taken in the order of their midpoints' fractions; an edge of `u` makes a triangle with the
/// current point of `l` and vice versa.
pub(crate) fn zip_rings(u: &[usize], l: &[usize], tris: &mut Vec<[usize; 3]>) {
    let (mu, ml) = (u.len(), l.len());
    let eu = if mu > 1 { mu } else { 0 };
    let el = if ml > 1 { ml } else { 0 };
    let (mut i, mut j) = (0usize, 0usize);
    while i < eu || j < el {
        let fu = (i as f64 + 0.5) / mu as f64;
        let fl = (j as f64 + 0.5) / ml as f64;
        let advance_u = j >= el || (i < eu && fu < fl);
        if advance_u {
            tris.push([u[i % mu], l[j % ml], u[(i + 1) % mu]]);
            i += 1;
        } else {
            tris.push([u[i % mu], l[j % ml], l[(j + 1) % ml]]);
            j += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BRAIN: [f64; 3] = [0.04625, 0.03125, 0.0285];

    fn plug() -> Outline {
        Outline {
            radius: 0.005,
            floor: Some(0.0275),
            grading: Some(Grading {
                size: 0.0005,
                growth: 1.25,
            }),
        }
    }

    /// Closed and consistently oriented (every directed edge once, its twin once), Euler
    /// characteristic 2, outward, on the shape, the outline a ring of points on the circle,
    /// graded there, and the plug's facets closed against the dome.
    #[test]
    fn outlined_surface_is_closed_on_the_shape_and_follows_the_outline() {
        let plc = half_ellipsoid_outlined(BRAIN, 0.004, &[plug()]).unwrap();
        let (p, t) = (&plc.points, &plc.triangles);
        assert_closed_sphere(t);
        let edges: Vec<(usize, usize)> = t
            .iter()
            .flat_map(|tri| (0..3).map(move |k| (tri[k], tri[(k + 1) % 3])))
            .collect();
        let on_surface: std::collections::HashSet<usize> = t.iter().flatten().cloned().collect();
        let v = enclosed_volume(p, t);
        let exact = 2.0 / 3.0 * std::f64::consts::PI * BRAIN[0] * BRAIN[1] * BRAIN[2];
        assert!(v > 0.99 * exact && v < exact, "{v} vs {exact}");
        let s = Vector3::from(BRAIN);
        for &i in &on_surface {
            let q = p[i];
            assert!(
                q.z == 0.0 || (q.component_div(&s).norm() - 1.0).abs() < 1e-14,
                "{q:?}"
            );
        }
        // The outline: surface points at r = 5 mm, about 0.5 mm apart.
        let ring: Vec<Vector3<f64>> = on_surface
            .iter()
            .map(|&i| p[i])
            .filter(|q| (q.x.hypot(q.y) - 0.005).abs() < 1e-15)
            .collect();
        let n = (2.0 * std::f64::consts::PI * 0.005 / 0.0005).round() as usize;
        assert!(
            ring.len().abs_diff(n) <= 1,
            "{} points on the outline",
            ring.len()
        );
        // Graded: edges from the outline within twice its 0.5 mm, the longest within twice h.
        let mut near = 0.0f64;
        let mut longest = 0.0f64;
        for &(i, j) in &edges {
            let l = (p[i] - p[j]).norm();
            longest = longest.max(l);
            if (p[i].x.hypot(p[i].y) - 0.005).abs() < 1e-15 {
                near = near.max(l);
            }
        }
        assert!(near < 2.0 * 0.0005, "edge at the outline {near}");
        assert!(
            longest > 0.003 && longest < 2.0 * 0.004,
            "longest edge {longest}"
        );
        // The plug: n side quads and the floor, every quad vertical and planar.
        assert_eq!(plc.inner_facets.len(), ring.len() + 1);
        for f in &plc.inner_facets[..ring.len()] {
            let (a, b, c, d) = (p[f[0]], p[f[1]], p[f[2]], p[f[3]]);
            assert_eq!((a.x, a.y), (d.x, d.y));
            assert_eq!((b.x, b.y), (c.x, c.y));
            assert_eq!((c.z, d.z), (0.0275, 0.0275));
        }
        assert_eq!(plc.plugs.len(), 1);
    }

    #[test]
    fn outlines_that_cannot_be_features_are_refused() {
        let mut o = plug();
        o.radius = 0.03;
        let e = half_ellipsoid_outlined(BRAIN, 0.004, &[o])
            .unwrap_err()
            .to_string();
        assert!(e.contains("0.8 x its smaller semi-axis"), "{e}");
        let mut o = plug();
        o.floor = Some(0.0284);
        let e = half_ellipsoid_outlined(BRAIN, 0.004, &[o])
            .unwrap_err()
            .to_string();
        assert!(e.contains("floor must lie between"), "{e}");
        let e = half_ellipsoid_outlined(
            BRAIN,
            0.004,
            &[
                plug(),
                Outline {
                    radius: 0.007,
                    ..plug()
                },
            ],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("more than one driven plug"), "{e}");
        let mut o = plug();
        o.grading = Some(Grading {
            size: 0.001,
            growth: 1.0,
        });
        assert!(half_ellipsoid_outlined(BRAIN, 0.004, &[o]).is_err());
    }
}
