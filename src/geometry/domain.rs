//! Built-in solid shapes described analytically (not by a mesh): the regions that meshless
//! node clouds and non-conforming background integration grids fill (Horton et al. 2010,
//! "A meshless Total Lagrangian explicit dynamics algorithm for surgical simulation",
//! Int. J. Numer. Meth. Biomed. Engng 26, sect. 2.2 and 3.2).
//!
//! Lengths are in metres, volumes in m^3.

use nalgebra::{Vector2, Vector3};

use super::shapes::check_box;
use crate::{Error, InputKind, Result};

/// A built-in solid shape. Lengths in m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Domain {
    /// The axis-aligned box [min, max] (m).
    Box {
        min: Vector3<f64>,
        max: Vector3<f64>,
    },
    /// The circular cylinder of radius `radius` (m) and height `height` (m): axis z, base at
    /// z = 0, top at z = height, centred on x = y = 0 (the cylinder of
    /// [`crate::geometry::shapes::cylinder_tet`]).
    Cylinder { radius: f64, height: f64 },
    /// The half-ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0 with `semi_axes` = (a, b, c)
    /// (m): flat elliptical base on z = 0 centred on x = y = 0, apex at (0, 0, c) (the shape of
    /// [`crate::geometry::tetgen::tetgen_half_ellipsoid`]).
    HalfEllipsoid { semi_axes: Vector3<f64> },
}

impl Domain {
    /// Checks that the shape is usable: box corners finite with min < max on every axis,
    /// cylinder radius and height, half-ellipsoid semi-axes positive and finite. Every generator that fills a domain
    /// calls this first, so that a bad scene value gives a message instead of NaN nodes.
    pub fn validate(&self) -> Result<()> {
        match *self {
            Domain::Box { min, max } => check_box(min, max),
            Domain::Cylinder { radius, height } => {
                if radius.is_finite() && radius > 0.0 && height.is_finite() && height > 0.0 {
                    Ok(())
                } else {
                    Err(Error::input(
                        InputKind::Value,
                        format!(
                        "cylinder radius {radius} m and height {height} m must be positive and \
                         finite"
                    ),
                    ))
                }
            }
            Domain::HalfEllipsoid { semi_axes } => {
                if semi_axes.iter().all(|v| v.is_finite() && *v > 0.0) {
                    Ok(())
                } else {
                    Err(Error::input(
                        InputKind::Value,
                        format!(
                            "half-ellipsoid semi-axes {:?} m must be positive and finite",
                            semi_axes.as_slice()
                        ),
                    ))
                }
            }
        }
    }

    /// True when `p` (m) is inside the solid or within `tol` (m) of its surface.
    pub fn contains(&self, p: &Vector3<f64>, tol: f64) -> bool {
        self.signed_distance(p) <= tol
    }

    /// Exact volume (m^3): (max - min) product for the box, pi R^2 H for the cylinder,
    /// 2/3 pi a b c for the half-ellipsoid.
    pub fn volume(&self) -> f64 {
        match *self {
            Domain::Box { min, max } => (max - min).product(),
            Domain::Cylinder { radius, height } => std::f64::consts::PI * radius * radius * height,
            Domain::HalfEllipsoid { semi_axes } => {
                2.0 / 3.0 * std::f64::consts::PI * semi_axes.product()
            }
        }
    }

    /// Axis-aligned bounding box (min, max) in m.
    pub fn bounds(&self) -> (Vector3<f64>, Vector3<f64>) {
        match *self {
            Domain::Box { min, max } => (min, max),
            Domain::Cylinder { radius, height } => (
                Vector3::new(-radius, -radius, 0.0),
                Vector3::new(radius, radius, height),
            ),
            Domain::HalfEllipsoid { semi_axes: s } => {
                (Vector3::new(-s.x, -s.y, 0.0), Vector3::new(s.x, s.y, s.z))
            }
        }
    }

    /// Signed distance to the surface, negative inside, zero on it (m). Used to keep generated
    /// nodes off / on the surface. Box and cylinder: exact (Euclidean) both inside and outside,
    /// also near edges and rims.
    ///
    /// Half-ellipsoid: an approximation, max(-z, (|(x/a, y/b, z/c)| - 1) min(a, b, c)), the
    /// base half-space combined with the scaled-radius distance of the ellipsoid. Both terms
    /// are 1-Lipschitz and vanish on their surfaces, so the value has the right sign, is zero
    /// exactly on the surface, and never exceeds the Euclidean distance in magnitude (a lower
    /// bound, tight when a, b and c are nearly equal).
    pub fn signed_distance(&self, p: &Vector3<f64>) -> f64 {
        match *self {
            Domain::Box { min, max } => {
                let centre = (min + max) * 0.5;
                let half = (max - min) * 0.5;
                // Per-axis distance beyond the slab; positive components are outside.
                let q = (p - centre).abs() - half;
                let outside = q.sup(&Vector3::zeros()).norm();
                let inside = q.max().min(0.0);
                outside + inside
            }
            Domain::Cylinder { radius, height } => {
                let half = 0.5 * height;
                // The cylinder is a 2-D box in (r, z): the same construction in two dimensions.
                let q = Vector2::new(p.x.hypot(p.y) - radius, (p.z - half).abs() - half);
                let outside = q.sup(&Vector2::zeros()).norm();
                let inside = q.max().min(0.0);
                outside + inside
            }
            Domain::HalfEllipsoid { semi_axes: s } => {
                let scaled = p.component_div(&s).norm();
                let dome = (scaled - 1.0) * s.min();
                dome.max(-p.z)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Domain {
        Domain::Box {
            min: Vector3::new(0.0, 0.0, 0.0),
            max: Vector3::new(0.1, 0.2, 0.3),
        }
    }

    #[test]
    fn box_volume_bounds_distance() {
        let d = unit_box();
        assert!((d.volume() - 0.006).abs() < 1e-15);
        assert_eq!(d.bounds(), (Vector3::zeros(), Vector3::new(0.1, 0.2, 0.3)));
        // Centre: nearest face is x = 0 or x = 0.1, 0.05 away.
        let c = Vector3::new(0.05, 0.1, 0.15);
        assert!((d.signed_distance(&c) + 0.05).abs() < 1e-15);
        // On a face, on an edge, at a corner.
        assert!(d.signed_distance(&Vector3::new(0.0, 0.1, 0.1)).abs() < 1e-15);
        assert!(d.signed_distance(&Vector3::new(0.1, 0.2, 0.1)).abs() < 1e-15);
        assert!(d.signed_distance(&Vector3::new(0.1, 0.2, 0.3)).abs() < 1e-15);
        // Outside a face, outside an edge (Euclidean), outside a corner.
        assert!((d.signed_distance(&Vector3::new(0.13, 0.1, 0.1)) - 0.03).abs() < 1e-15);
        let e = d.signed_distance(&Vector3::new(0.13, 0.24, 0.1));
        assert!((e - 0.05).abs() < 1e-15);
        let k = d.signed_distance(&Vector3::new(-0.01, -0.02, -0.02));
        assert!((k - 0.03).abs() < 1e-15);
        assert!(d.contains(&c, 0.0));
        assert!(d.contains(&Vector3::new(0.1, 0.2, 0.3), 0.0));
        assert!(!d.contains(&Vector3::new(0.1 + 1e-9, 0.1, 0.1), 1e-12));
        assert!(d.contains(&Vector3::new(0.1 + 1e-13, 0.1, 0.1), 1e-12));
        assert!(d.validate().is_ok());
    }

    #[test]
    fn cylinder_volume_bounds_distance() {
        let d = Domain::Cylinder {
            radius: 0.05,
            height: 0.2,
        };
        let v = std::f64::consts::PI * 0.05 * 0.05 * 0.2;
        assert!((d.volume() - v).abs() < 1e-18);
        assert_eq!(
            d.bounds(),
            (
                Vector3::new(-0.05, -0.05, 0.0),
                Vector3::new(0.05, 0.05, 0.2)
            )
        );
        // Axis point at mid-height: radius is the nearest.
        assert!((d.signed_distance(&Vector3::new(0.0, 0.0, 0.1)) + 0.05).abs() < 1e-15);
        // Near the base on the axis: the cap is the nearest.
        assert!((d.signed_distance(&Vector3::new(0.0, 0.0, 0.01)) + 0.01).abs() < 1e-15);
        // On the lateral surface, on a cap, on the rim.
        let (s, c) = 0.7f64.sin_cos();
        let lat = Vector3::new(0.05 * c, 0.05 * s, 0.13);
        assert!(d.signed_distance(&lat).abs() < 1e-15);
        assert!(d.signed_distance(&Vector3::new(0.01, 0.02, 0.2)).abs() < 1e-15);
        assert!(
            d.signed_distance(&Vector3::new(0.05 * c, 0.05 * s, 0.0))
                .abs()
                < 1e-15
        );
        // Outside the rim: Euclidean distance in (r, z).
        let o = Vector3::new(0.08 * c, 0.08 * s, 0.24);
        assert!((d.signed_distance(&o) - 0.05).abs() < 1e-15);
        assert!(d.contains(&lat, 1e-12));
        assert!(!d.contains(&Vector3::new(0.04, 0.04, 0.1), 1e-12));
        assert!(d.validate().is_ok());
    }

    #[test]
    fn half_ellipsoid_volume_bounds_distance() {
        let (a, b, c) = (0.04625, 0.03125, 0.0285);
        let d = Domain::HalfEllipsoid {
            semi_axes: Vector3::new(a, b, c),
        };
        let v = 2.0 / 3.0 * std::f64::consts::PI * a * b * c;
        assert!((d.volume() - v).abs() < 1e-18);
        assert_eq!(
            d.bounds(),
            (Vector3::new(-a, -b, 0.0), Vector3::new(a, b, c))
        );
        assert!(d.validate().is_ok());
        // Inside: negative. Just above the base centre: the base is the nearest, exactly.
        assert!(d.signed_distance(&Vector3::new(0.01, -0.01, 0.01)) < 0.0);
        assert!((d.signed_distance(&Vector3::new(0.0, 0.0, 0.002)) + 0.002).abs() < 1e-15);
        // On the surface: zero (apex, rim, a dome point, base points).
        let (st, ct) = 0.6f64.sin_cos();
        let (sp, cp) = 2.3f64.sin_cos();
        for p in [
            Vector3::new(0.0, 0.0, c),
            Vector3::new(a, 0.0, 0.0),
            Vector3::new(a * cp, b * sp, 0.0),
            Vector3::new(a * st * cp, b * st * sp, c * ct),
            Vector3::new(0.01, 0.01, 0.0),
        ] {
            assert!(d.signed_distance(&p).abs() < 1e-15, "{p:?}");
            assert!(d.contains(&p, 1e-12));
        }
        // Outside: positive, below the base, beyond the dome, never above the true distance.
        let below = Vector3::new(0.0, 0.0, -0.003);
        assert!((d.signed_distance(&below) - 0.003).abs() < 1e-15);
        let above = Vector3::new(0.0, 0.0, c + 0.002);
        let e = d.signed_distance(&above);
        assert!(e > 0.0 && e <= 0.002 + 1e-15, "{e}");
        let side = Vector3::new(a + 0.001, 0.0, 0.0001);
        assert!(d.signed_distance(&side) > 0.0 && d.signed_distance(&side) <= 0.001 + 1e-15);
        assert!(!d.contains(&side, 1e-12));
        // Centre of the base plane, on the axis near the apex: inside.
        assert!(d.signed_distance(&Vector3::new(0.0, 0.0, c - 0.001)) < 0.0);
        for s in [
            Vector3::new(0.0, 1.0, 1.0),
            Vector3::new(1.0, -1.0, 1.0),
            Vector3::new(1.0, 1.0, f64::NAN),
            Vector3::new(f64::INFINITY, 1.0, 1.0),
        ] {
            assert!(Domain::HalfEllipsoid { semi_axes: s }.validate().is_err());
        }
    }

    #[test]
    fn invalid_shapes_are_refused() {
        let bad_box = Domain::Box {
            min: Vector3::new(0.0, 0.0, 0.0),
            max: Vector3::new(0.1, 0.0, 0.1),
        };
        assert!(bad_box.validate().is_err());
        for (r, h) in [
            (0.0, 1.0),
            (1.0, -1.0),
            (f64::NAN, 1.0),
            (1.0, f64::INFINITY),
        ] {
            let c = Domain::Cylinder {
                radius: r,
                height: h,
            };
            assert!(c.validate().is_err(), "{r} {h}");
        }
    }
}
