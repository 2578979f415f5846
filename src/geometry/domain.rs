//! Built-in solid shapes described analytically (not by a mesh): the regions that meshless
//! node clouds and non-conforming background integration grids fill (Horton et al. 2010,
//! "A meshless Total Lagrangian explicit dynamics algorithm for surgical simulation",
//! Int. J. Numer. Meth. Biomed. Engng 26, sect. 2.2 and 3.2).
//!
//! Lengths are in metres, volumes in m^3.

use nalgebra::{Vector2, Vector3};

use super::shapes::check_box;
use crate::{Error, Result};

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
}

impl Domain {
    /// Checks that the shape is usable: box corners finite with min < max on every axis,
    /// cylinder radius and height positive and finite. Every generator that fills a domain
    /// calls this first, so that a bad scene value gives a message instead of NaN nodes.
    pub fn validate(&self) -> Result<()> {
        match *self {
            Domain::Box { min, max } => check_box(min, max),
            Domain::Cylinder { radius, height } => {
                if radius.is_finite() && radius > 0.0 && height.is_finite() && height > 0.0 {
                    Ok(())
                } else {
                    Err(Error::Input(format!(
                        "cylinder radius {radius} m and height {height} m must be positive and \
                         finite"
                    )))
                }
            }
        }
    }

    /// True when `p` (m) is inside the solid or within `tol` (m) of its surface.
    pub fn contains(&self, p: &Vector3<f64>, tol: f64) -> bool {
        self.signed_distance(p) <= tol
    }

    /// Exact volume (m^3): (max - min) product for the box, pi R^2 H for the cylinder.
    pub fn volume(&self) -> f64 {
        match *self {
            Domain::Box { min, max } => (max - min).product(),
            Domain::Cylinder { radius, height } => std::f64::consts::PI * radius * radius * height,
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
        }
    }

    /// Signed distance to the surface, negative inside (m). Used to keep generated nodes off /
    /// on the surface. Exact (Euclidean) both inside and outside, also near edges and rims.
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
