//! Natural boundary conditions and body forces: gravity, point forces, dead tractions and
//! follower pressure, each scaled by a load curve. They enter the explicit update as the
//! external nodal force F_ext of u(n+1) = A M^-1 (F_ext - F_int) + ... (see
//! [`crate::solver::integrate`]).
//!
//! Surface loads act on faces of the body's boundary (triangles or bilinear quadrilaterals).
//! A face carries sparse interpolation rows: its corners' displacements from the nodal values
//! (FE faces: the corner node itself; meshless and blended faces: the shape functions at the
//! corner) and, at each Gauss point, the shape functions that spread the point's force over
//! the nodes: f_j = sum_g phi_j(X_g) t w_g, as EBCIEM integrates its boundary force (thesis
//! sect. 4.3). Rows sum to one (partition of unity), so a load's total force is the integral
//! of the traction whatever the discretization.

use nalgebra::Vector3;

use super::LoadCurve;
use crate::{Error, InputKind, Result};

use crate::quadrature::SparseRow;

/// Gauss rule of a triangle on the parametric triangle (0,0), (1,0), (0,1): three points at
/// (1/6, 1/6), (2/3, 1/6), (1/6, 2/3), weight 1/6 each (exact for quadratics; Strang and Fix).
const TRI_GAUSS: [([f64; 2], f64); 3] = [
    ([1.0 / 6.0, 1.0 / 6.0], 1.0 / 6.0),
    ([2.0 / 3.0, 1.0 / 6.0], 1.0 / 6.0),
    ([1.0 / 6.0, 2.0 / 3.0], 1.0 / 6.0),
];

/// 2 x 2 Gauss rule on [-1, 1]^2 (weights 1).
const QUAD_GAUSS: [([f64; 2], f64); 4] = {
    const A: f64 = 0.577_350_269_189_625_8; // 1 / sqrt(3)
    [
        ([-A, -A], 1.0),
        ([A, -A], 1.0),
        ([A, A], 1.0),
        ([-A, A], 1.0),
    ]
};

/// The Gauss rule of a face with `n` corners (3: triangle, 4: quadrilateral).
fn gauss_rule(n: usize) -> Result<&'static [([f64; 2], f64)]> {
    match n {
        3 => Ok(&TRI_GAUSS),
        4 => Ok(&QUAD_GAUSS),
        _ => Err(Error::input(
            InputKind::Mesh,
            format!("a face has 3 or 4 corners, not {n}"),
        )),
    }
}

/// Shape functions of the face's corners at parametric point (xi, eta): linear on the
/// triangle, bilinear on the quadrilateral (corners counterclockwise from (-1, -1)).
fn corner_weights(corners: usize, [xi, eta]: [f64; 2]) -> [f64; 4] {
    if corners == 3 {
        [1.0 - xi - eta, xi, eta, 0.0]
    } else {
        [
            0.25 * (1.0 - xi) * (1.0 - eta),
            0.25 * (1.0 + xi) * (1.0 - eta),
            0.25 * (1.0 + xi) * (1.0 + eta),
            0.25 * (1.0 - xi) * (1.0 + eta),
        ]
    }
}

/// d(corner weights)/dxi and /deta at (xi, eta).
fn corner_derivatives(corners: usize, [xi, eta]: [f64; 2]) -> ([f64; 4], [f64; 4]) {
    if corners == 3 {
        ([-1.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 1.0, 0.0])
    } else {
        (
            [
                -0.25 * (1.0 - eta),
                0.25 * (1.0 - eta),
                0.25 * (1.0 + eta),
                -0.25 * (1.0 + eta),
            ],
            [
                -0.25 * (1.0 - xi),
                -0.25 * (1.0 + xi),
                0.25 * (1.0 + xi),
                0.25 * (1.0 - xi),
            ],
        )
    }
}

/// One face of the body's boundary, outward oriented (corners counterclockwise seen from
/// outside), with the rows that give its deformed corners and spread its forces.
#[derive(Debug, Clone)]
pub struct Face {
    /// Reference corner positions, m (3 or 4).
    corners: Vec<Vector3<f64>>,
    /// Each corner's displacement from the nodal values.
    corner_rows: Vec<SparseRow>,
    /// Per Gauss point: parametric coordinates, weight, and the row spreading its force.
    gauss: Vec<([f64; 2], f64, SparseRow)>,
}

impl Face {
    /// A face of a finite-element mesh: corners are nodes (`ids`, positions `x`), and the
    /// face's own linear or bilinear shape functions spread the forces.
    pub fn interpolating(ids: &[usize], x: &[Vector3<f64>]) -> Result<Self> {
        let n = ids.len();
        let rule = gauss_rule(n)?;
        let gauss = rule
            .iter()
            .map(|&(p, w)| {
                let nw = corner_weights(n, p);
                (
                    p,
                    w,
                    ids.iter().zip(nw).map(|(&i, f)| (i as u32, f)).collect(),
                )
            })
            .collect();
        Ok(Face {
            corners: ids.iter().map(|&i| x[i]).collect(),
            corner_rows: ids.iter().map(|&i| vec![(i as u32, 1.0)]).collect(),
            gauss,
        })
    }

    /// A face whose displacement field comes from shape functions that need not interpolate
    /// (meshless, blended): `shape(x)` gives the row at reference point x (m), used at the
    /// corners `x` and at the Gauss points.
    pub fn with_shape(
        x: &[Vector3<f64>],
        shape: &dyn Fn(&Vector3<f64>) -> Result<SparseRow>,
    ) -> Result<Self> {
        let n = x.len();
        let rule = gauss_rule(n)?;
        let gauss = rule
            .iter()
            .map(|&(p, w)| {
                let nw = corner_weights(n, p);
                let xg = x
                    .iter()
                    .zip(nw)
                    .fold(Vector3::zeros(), |a, (c, f)| a + c * f);
                Ok((p, w, shape(&xg)?))
            })
            .collect::<Result<_>>()?;
        Ok(Face {
            corners: x.to_vec(),
            corner_rows: x.iter().map(shape).collect::<Result<_>>()?,
            gauss,
        })
    }

    /// Reference area, m^2.
    pub fn area(&self) -> f64 {
        self.gauss
            .iter()
            .map(|(p, w, _)| area_vector(&self.corners, *p).norm() * w)
            .sum()
    }

    /// Corner positions (m) at nodal displacements `u` (m).
    fn deformed(&self, u: &[Vector3<f64>], out: &mut [Vector3<f64>; 4]) {
        for (k, (x, row)) in self.corners.iter().zip(&self.corner_rows).enumerate() {
            out[k] = row.iter().fold(*x, |a, &(j, f)| a + u[j as usize] * f);
        }
    }
}

/// x_xi x x_eta at parametric point `p` of the face with corners `c`: the area vector per
/// unit parametric area, outward.
fn area_vector(c: &[Vector3<f64>], p: [f64; 2]) -> Vector3<f64> {
    let (dxi, deta) = corner_derivatives(c.len(), p);
    let (mut a, mut b) = (Vector3::zeros(), Vector3::zeros());
    for (k, x) in c.iter().enumerate() {
        a += x * dxi[k];
        b += x * deta[k];
    }
    a.cross(&b)
}

/// What a load applies at full value (curve factor 1).
#[derive(Debug, Clone)]
pub enum LoadKind {
    /// Body force: acceleration g (m/s^2) on every node's lumped mass, f_i = m_i g.
    Gravity(Vector3<f64>),
    /// The force (N) at each of these points, spread by its row (FE nodes: the node alone;
    /// meshless nodes: the shape functions at the node, which do not interpolate).
    PointForce {
        rows: Vec<SparseRow>,
        force: Vector3<f64>,
    },
    /// Dead traction (Pa, force per reference area, fixed direction) on these faces.
    Traction {
        faces: Vec<Face>,
        traction: Vector3<f64>,
    },
    /// Follower pressure (Pa) on these faces, along the deformed inward normal: f = -p n da
    /// in the current configuration (positive pushes into the body).
    Pressure { faces: Vec<Face>, pressure: f64 },
}

/// A named load with its curve.
#[derive(Debug, Clone)]
pub struct Load {
    pub name: String,
    pub kind: LoadKind,
    pub curve: LoadCurve,
}

/// A load ready for the time loop: fixed loads as precomputed nodal forces, pressures by face.
#[derive(Debug, Clone)]
enum Prepared {
    Fixed {
        nodes: Vec<u32>,
        force: Vec<Vector3<f64>>,
        total: Vector3<f64>,
    },
    Pressure {
        faces: Vec<Face>,
        pressure: f64,
    },
}

/// The loads of a model: F_ext at any load fraction and displacement.
#[derive(Debug, Clone, Default)]
pub struct Loads {
    names: Vec<String>,
    curves: Vec<LoadCurve>,
    items: Vec<Prepared>,
    /// Nodes any load reaches, ascending: the entries `apply` clears and writes.
    touched: Vec<u32>,
    /// Each load's total force at the last `apply`, N.
    totals: Vec<Vector3<f64>>,
    /// Each load's factor on top of its curve ([`Self::set_factor`]; 1 as prepared).
    factors: Vec<f64>,
}

impl Loads {
    /// Prepares `loads` for a model of `mass.len()` nodes with lumped masses `mass` (kg).
    /// Errors name a load that reaches no node or a node out of range.
    pub fn new(loads: Vec<Load>, mass: &[f64]) -> Result<Self> {
        let n = mass.len();
        let mut out = Loads::default();
        let mut reached = vec![false; n];
        for l in loads {
            let bad = |i: usize| {
                Error::input(
                    InputKind::Value,
                    format!(
                        "load '{}' refers to node {i}, but the model has {n} nodes",
                        l.name
                    ),
                )
                .node(i)
            };
            let item = match l.kind {
                LoadKind::Gravity(g) => {
                    let force: Vec<Vector3<f64>> = mass.iter().map(|&m| g * m).collect();
                    let total = force.iter().sum();
                    Prepared::Fixed {
                        nodes: (0..n as u32).collect(),
                        force,
                        total,
                    }
                }
                LoadKind::PointForce { rows, force } => {
                    let (nodes, f) = spread(n, rows.iter().map(|row| (force, row))).map_err(bad)?;
                    Prepared::Fixed {
                        total: force * rows.len() as f64,
                        force: f,
                        nodes,
                    }
                }
                LoadKind::Traction { faces, traction } => {
                    // Each Gauss point's force: the traction times its reference area.
                    let at_points = faces.iter().flat_map(|f| {
                        f.gauss.iter().map(|(p, w, row)| {
                            (traction * (area_vector(&f.corners, *p).norm() * w), row)
                        })
                    });
                    let total = at_points.clone().map(|(fg, _)| fg).sum();
                    let (nodes, force) = spread(n, at_points).map_err(bad)?;
                    Prepared::Fixed {
                        force,
                        nodes,
                        total,
                    }
                }
                LoadKind::Pressure { faces, pressure } => {
                    for f in &faces {
                        for row in f.corner_rows.iter().chain(f.gauss.iter().map(|g| &g.2)) {
                            if let Some(&(j, _)) = row.iter().find(|e| e.0 as usize >= n) {
                                return Err(bad(j as usize));
                            }
                        }
                    }
                    Prepared::Pressure { faces, pressure }
                }
            };
            match &item {
                Prepared::Fixed { nodes, .. } => {
                    nodes.iter().for_each(|&j| reached[j as usize] = true)
                }
                Prepared::Pressure { faces, .. } => {
                    for f in faces {
                        for g in &f.gauss {
                            g.2.iter().for_each(|&(j, _)| reached[j as usize] = true);
                        }
                    }
                }
            }
            let empty = match &item {
                Prepared::Fixed { nodes, .. } => nodes.is_empty(),
                Prepared::Pressure { faces, .. } => faces.is_empty(),
            };
            if empty {
                return Err(Error::input(
                    InputKind::Selection,
                    format!(
                    "load '{}' acts on no node or face: check its selection (surface loads act on \
                     boundary faces whose corners are all selected)",
                    l.name
                ),
                )
                .key(format!("loads.{}", l.name)));
            }
            out.names.push(l.name);
            out.curves.push(l.curve);
            out.items.push(item);
        }
        out.touched = (0..n as u32).filter(|&j| reached[j as usize]).collect();
        out.totals = vec![Vector3::zeros(); out.items.len()];
        out.factors = vec![1.0; out.items.len()];
        Ok(out)
    }

    /// Scales load `name` by `factor` (its full value becomes `factor` x the prepared one;
    /// 1 restores it): a heavier or lighter gravity, a new pressure, between runs of one
    /// model. Errors naming the loads there are, or a factor that is not finite.
    pub fn set_factor(&mut self, name: &str, factor: f64) -> Result<()> {
        let k = self.index(name)?;
        if !factor.is_finite() {
            return Err(Error::input(
                InputKind::Value,
                format!("load '{name}': factor {factor} is not finite"),
            )
            .key(format!("loads.{name}"))
            .value(factor));
        }
        self.factors[k] = factor;
        Ok(())
    }

    /// The factor of load `name` ([`Self::set_factor`]).
    pub fn factor(&self, name: &str) -> Result<f64> {
        Ok(self.factors[self.index(name)?])
    }

    fn index(&self, name: &str) -> Result<usize> {
        self.names.iter().position(|n| n == name).ok_or_else(|| {
            Error::input(
                InputKind::Selection,
                format!(
                    "no load named '{name}'; the model's loads: {}",
                    if self.names.is_empty() {
                        "none".to_string()
                    } else {
                        self.names.join(", ")
                    }
                ),
            )
            .key(format!("loads.{name}"))
        })
    }

    /// No load at all.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Load names, in the order of [`Self::totals`].
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Each load's curve, in the order of [`Self::names`].
    pub fn curves(&self) -> &[LoadCurve] {
        &self.curves
    }

    /// Each load's total force at the last [`Self::apply`], N.
    pub fn totals(&self) -> &[Vector3<f64>] {
        &self.totals
    }

    /// External nodal forces F_ext (N) at load fraction `tau` and displacements `u` (m) into
    /// `out` (one entry per node; entries no load reaches are left as they are, so start from
    /// zeros). Serial, in a fixed order: the sums do not depend on the thread count.
    pub fn apply(&mut self, u: &[Vector3<f64>], tau: f64, out: &mut [Vector3<f64>]) {
        for &j in &self.touched {
            out[j as usize] = Vector3::zeros();
        }
        for (((item, curve), total), factor) in self
            .items
            .iter()
            .zip(&self.curves)
            .zip(&mut self.totals)
            .zip(&self.factors)
        {
            let s = curve.value(tau) * factor;
            match item {
                Prepared::Fixed {
                    nodes,
                    force,
                    total: t,
                } => {
                    for (&j, f) in nodes.iter().zip(force) {
                        out[j as usize] += f * s;
                    }
                    *total = t * s;
                }
                Prepared::Pressure { faces, pressure } => {
                    let p = pressure * s;
                    let mut sum = Vector3::zeros();
                    let mut x = [Vector3::zeros(); 4];
                    for f in faces {
                        f.deformed(u, &mut x);
                        let c = &x[..f.corners.len()];
                        for (pt, w, row) in &f.gauss {
                            let fg = area_vector(c, *pt) * (-p * w);
                            sum += fg;
                            for &(j, phi) in row {
                                out[j as usize] += fg * phi;
                            }
                        }
                    }
                    *total = sum;
                }
            }
        }
    }
}

/// Nodal forces of point forces `(force, row)` spread by their rows on `n` nodes: the nodes
/// they reach (ascending) and each one's force, N. Errs with the first node id out of range.
fn spread<'a>(
    n: usize,
    forces: impl Iterator<Item = (Vector3<f64>, &'a SparseRow)>,
) -> std::result::Result<(Vec<u32>, Vec<Vector3<f64>>), usize> {
    let mut acc = vec![Vector3::zeros(); n];
    let mut hit = vec![false; n];
    for (f, row) in forces {
        for &(j, phi) in row {
            let j = j as usize;
            if j >= n {
                return Err(j);
            }
            acc[j] += f * phi;
            hit[j] = true;
        }
    }
    let nodes: Vec<u32> = (0..n as u32).filter(|&j| hit[j as usize]).collect();
    let force = nodes.iter().map(|&j| acc[j as usize]).collect();
    Ok((nodes, force))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unit square z = 0 as one quad and as two triangles, outward along +z.
    fn square() -> Vec<Vector3<f64>> {
        vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(1.0, 1.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
        ]
    }

    /// A uniform traction on a bilinear quad gives a quarter of the force at each corner (the
    /// one-point hexahedron's nodal forces under a homogeneous stress), on triangles a third
    /// of each triangle's; both total the traction times the area.
    #[test]
    fn uniform_traction_spreads_consistently() {
        let x = square();
        let t = Vector3::new(0.0, 0.0, 100.0);
        let quad = Face::interpolating(&[0, 1, 2, 3], &x).unwrap();
        assert!((quad.area() - 1.0).abs() < 1e-15);
        let mut l = Loads::new(
            vec![Load {
                name: "t".into(),
                kind: LoadKind::Traction {
                    faces: vec![quad],
                    traction: t,
                },
                curve: LoadCurve::Constant,
            }],
            &[1.0; 4],
        )
        .unwrap();
        let mut f = vec![Vector3::zeros(); 4];
        l.apply(&[Vector3::zeros(); 4], 1.0, &mut f);
        for fi in &f {
            assert!((fi - t / 4.0).norm() < 1e-12, "{fi}");
        }
        assert!((l.totals()[0] - t).norm() < 1e-12);
        let tris = vec![
            Face::interpolating(&[0, 1, 2], &x).unwrap(),
            Face::interpolating(&[0, 2, 3], &x).unwrap(),
        ];
        let mut l = Loads::new(
            vec![Load {
                name: "t".into(),
                kind: LoadKind::Traction {
                    faces: tris,
                    traction: t,
                },
                curve: LoadCurve::Constant,
            }],
            &[1.0; 4],
        )
        .unwrap();
        l.apply(&[Vector3::zeros(); 4], 1.0, &mut f);
        let want = [2.0, 1.0, 2.0, 1.0].map(|k| t * (k / 6.0));
        for (fi, w) in f.iter().zip(want) {
            assert!((fi - w).norm() < 1e-12, "{fi} vs {w}");
        }
    }

    /// Follower pressure acts on the deformed face: a square stretched to 2 x 1 and turned to
    /// face +x carries -p times its deformed area along +x; the curve scales it.
    #[test]
    fn pressure_follows_the_deformed_face() {
        let x = square();
        let face = Face::interpolating(&[0, 1, 2, 3], &x).unwrap();
        // New positions: (0,0,0), (0,2,0), (0,2,1), (0,0,1): normal +x, area 2.
        let target = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(0.0, 2.0, 0.0),
            Vector3::new(0.0, 2.0, 1.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        let u: Vec<Vector3<f64>> = (0..4).map(|k| target[k] - x[k]).collect();
        let mut l = Loads::new(
            vec![Load {
                name: "p".into(),
                kind: LoadKind::Pressure {
                    faces: vec![face],
                    pressure: 10.0,
                },
                curve: LoadCurve::Ramp,
            }],
            &[1.0; 4],
        )
        .unwrap();
        let mut f = vec![Vector3::zeros(); 4];
        l.apply(&u, 0.5, &mut f);
        let total: Vector3<f64> = f.iter().sum();
        assert!(
            (total - Vector3::new(-10.0, 0.0, 0.0)).norm() < 1e-12,
            "{total}"
        );
        assert!((l.totals()[0] - total).norm() < 1e-12);
    }

    /// Gravity puts m_i g on every node; a point force its value on the node of its row.
    #[test]
    fn gravity_and_nodal_forces() {
        let g = Vector3::new(0.0, 0.0, -9.81);
        let mut l = Loads::new(
            vec![
                Load {
                    name: "g".into(),
                    kind: LoadKind::Gravity(g),
                    curve: LoadCurve::Constant,
                },
                Load {
                    name: "f".into(),
                    kind: LoadKind::PointForce {
                        rows: vec![vec![(1, 1.0)]],
                        force: Vector3::new(1.0, 0.0, 0.0),
                    },
                    curve: LoadCurve::Constant,
                },
            ],
            &[2.0, 3.0],
        )
        .unwrap();
        let mut f = vec![Vector3::zeros(); 2];
        l.apply(&[Vector3::zeros(); 2], 1.0, &mut f);
        assert_eq!(f[0], g * 2.0);
        assert_eq!(f[1], g * 3.0 + Vector3::new(1.0, 0.0, 0.0));
        assert!((l.totals()[0] - g * 5.0).norm() < 1e-12);
        let e = Loads::new(
            vec![Load {
                name: "tip".into(),
                kind: LoadKind::PointForce {
                    rows: vec![],
                    force: Vector3::x(),
                },
                curve: LoadCurve::Constant,
            }],
            &[1.0],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("'tip'") && e.contains("no node"), "{e}");
    }
}
