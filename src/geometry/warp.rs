//! Results on an image's grid: the displacement field that warps a pre-operative image into
//! the deformed configuration, and the warped image (image-guided surgery's non-rigid
//! registration, Miller et al.; what 3D Slicer and ITK consume).
//!
//! Convention (ITK's displacement-field transform, a resampling transform): at each voxel
//! centre x of the grid, in the deformed configuration, the field holds d(x) = X - x, where X
//! is the reference (pre-operative) point that the body carried to x (x = X + u(X)). The warped
//! image is I_w(x) = I(x + d(x)) = I(X): the pre-operative image resampled by the transform.
//! Outside the deformed body d = 0 and I_w = I.

use nalgebra::Vector3;

use super::image::Image;
use super::{ElementShape, Mesh};
use crate::{Error, InputKind, Result};

/// The pull-back field d(x) = X - x (m, RAS) at the voxel centres of `grid` for the body
/// `mesh` (reference positions, m; tetrahedra, or hexahedra split into six tets) displaced by
/// `u` (m, one per mesh node), interpolated linearly in each deformed tet. Voxels the deformed
/// body does not cover get zero; the second value counts the voxels it covers.
///
/// Each deformed tet is rasterized over the voxels of its bounding box in index space (an
/// affine map keeps barycentric coordinates), so the cost is about the voxels the body covers.
pub fn pull_back(
    grid: &Image,
    mesh: &Mesh,
    u: &[Vector3<f64>],
) -> Result<(Vec<Vector3<f64>>, usize)> {
    if u.len() != mesh.nodes.len() {
        return Err(Error::input(
            InputKind::Value,
            format!(
                "{} displacements for {} mesh nodes",
                u.len(),
                mesh.nodes.len()
            ),
        ));
    }
    let tets = if mesh.shape == ElementShape::Hex8 {
        super::mesh::hex_to_tets(mesh.clone())
    } else {
        mesh.clone()
    };
    let n = grid.len();
    let mut d = vec![Vector3::zeros(); n];
    let mut covered = vec![false; n];
    // Deformed nodes in continuous voxel index.
    let index: Vec<Vector3<f64>> = tets
        .nodes
        .iter()
        .zip(u)
        .map(|(x, ui)| grid.index_of(&(x + ui)))
        .collect();
    let dims = grid.dims;
    for e in 0..tets.num_cells() {
        let c = tets.cell(e);
        let p: [Vector3<f64>; 4] = std::array::from_fn(|a| index[c[a]]);
        let m = nalgebra::Matrix3::from_columns(&[p[1] - p[0], p[2] - p[0], p[3] - p[0]]);
        let Some(inv) = m.try_inverse() else {
            continue; // a flat deformed tet covers no voxel centre
        };
        let (lo, hi) = p
            .iter()
            .fold((p[0], p[0]), |(l, h), q| (l.inf(q), h.sup(q)));
        let mut range = [(0usize, 0usize); 3];
        let mut empty = false;
        for a in 0..3 {
            let first = lo[a].ceil().max(0.0);
            let last = hi[a].floor().min(dims[a] as f64 - 1.0);
            if first > last {
                empty = true;
                break;
            }
            range[a] = (first as usize, last as usize);
        }
        if empty {
            continue;
        }
        let eps = 1e-12;
        for k in range[2].0..=range[2].1 {
            for j in range[1].0..=range[1].1 {
                for i in range[0].0..=range[0].1 {
                    let v = grid.index(i, j, k);
                    if covered[v] {
                        continue;
                    }
                    let l = inv * (Vector3::new(i as f64, j as f64, k as f64) - p[0]);
                    let l0 = 1.0 - l.x - l.y - l.z;
                    if l0 < -eps || l.iter().any(|&x| x < -eps) {
                        continue;
                    }
                    let disp = u[c[0]] * l0 + u[c[1]] * l.x + u[c[2]] * l.y + u[c[3]] * l.z;
                    d[v] = -disp;
                    covered[v] = true;
                }
            }
        }
    }
    let count = covered.iter().filter(|&&c| c).count();
    Ok((d, count))
}

/// The image warped by the pull-back field `d` (on its own grid): I_w(x) = I(x + d(x)),
/// trilinear, the nearest voxel just outside the voxel centres' hull, 0 farther out.
pub fn warp(image: &Image, d: &[Vector3<f64>]) -> Image {
    let mut out = image.clone();
    for k in 0..image.dims[2] {
        for j in 0..image.dims[1] {
            for i in 0..image.dims[0] {
                let v = image.index(i, j, k);
                if d[v] == Vector3::zeros() {
                    continue;
                }
                let x = image.world(&Vector3::new(i as f64, j as f64, k as f64)) + d[v];
                out.values[v] = image
                    .trilinear(&x)
                    .or_else(|| image.nearest(&x))
                    .unwrap_or(0.0);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Matrix4};

    /// A homogeneous deformation x = F X of a box mesh: the pull-back field is F^-1 x - x at
    /// every covered voxel (linear tets hold it exactly), zero elsewhere; the warp of a linear
    /// image is I(F^-1 x) exactly.
    #[test]
    fn a_homogeneous_deformation_pulls_back_exactly() {
        let mesh =
            crate::geometry::shapes::box_tet(Vector3::zeros(), Vector3::repeat(0.01), [3, 3, 3])
                .unwrap();
        let f = Matrix3::new(1.1, 0.05, 0.0, 0.0, 1.1, 0.0, 0.02, 0.0, 0.8);
        let u: Vec<Vector3<f64>> = mesh.nodes.iter().map(|x| f * x - x).collect();
        let mut map = Matrix4::identity() * 5e-4;
        map[(3, 3)] = 1.0;
        for a in 0..3 {
            map[(a, 3)] = -2e-3;
        }
        let mut image = Image::filled([40, 40, 40], map, 0.0);
        for k in 0..40 {
            for j in 0..40 {
                for i in 0..40 {
                    let x = image.world(&Vector3::new(i as f64, j as f64, k as f64));
                    let v = image.index(i, j, k);
                    image.values[v] = 3.0 + 100.0 * x.x - 50.0 * x.y + 20.0 * x.z;
                }
            }
        }
        let (d, covered) = pull_back(&image, &mesh, &u).unwrap();
        assert!(covered > 1000, "{covered}");
        let finv = f.try_inverse().unwrap();
        let warped = warp(&image, &d);
        let mut checked = 0;
        for k in 0..40 {
            for j in 0..40 {
                for i in 0..40 {
                    let x = image.world(&Vector3::new(i as f64, j as f64, k as f64));
                    let v = image.index(i, j, k);
                    let back = finv * x;
                    let inside = back.iter().all(|&c| (1e-9..=0.01 - 1e-9).contains(&c));
                    if inside {
                        assert!(
                            (d[v] - (back - x)).norm() < 1e-15,
                            "{} vs {}",
                            d[v],
                            back - x
                        );
                        let exact = 3.0 + 100.0 * back.x - 50.0 * back.y + 20.0 * back.z;
                        assert!((warped.values[v] - exact).abs() < 1e-12);
                        checked += 1;
                    } else if back.iter().any(|&c| !(-1e-9..=0.01 + 1e-9).contains(&c)) {
                        assert_eq!(d[v], Vector3::zeros());
                        assert_eq!(warped.values[v], image.values[v]);
                    }
                }
            }
        }
        assert!(checked > 1000);
    }
}
