//! A 3-D image in space: voxel values on a grid and the map from voxel index to world
//! position (RAS, m, as 3D Slicer shows it), with the lookups the labelled-image bodies and
//! the warped images need. Files are read and written by [`crate::io::image`].

use nalgebra::{Matrix3, Matrix4, Vector3};

/// A 3-D image: voxel values and the map from voxel index to world position.
#[derive(Debug, Clone)]
pub struct Image {
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    /// Values, i fastest: voxel (i, j, k) at `i + dims[0] * (j + dims[1] * k)`.
    pub values: Vec<f64>,
    /// Voxel index (i, j, k, 1) to world (RAS, m): the voxel's centre.
    pub to_world: Matrix4<f64>,
}

impl Image {
    /// An image of `dims` voxels with the index-to-world map `to_world` (RAS, m), all `value`.
    pub fn filled(dims: [usize; 3], to_world: Matrix4<f64>, value: f64) -> Self {
        Image {
            dims,
            values: vec![value; dims[0] * dims[1] * dims[2]],
            to_world,
        }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Whether the image holds no voxel.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Linear index of voxel (i, j, k).
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// World position (RAS, m) of continuous voxel index `ijk`.
    pub fn world(&self, ijk: &Vector3<f64>) -> Vector3<f64> {
        (self.to_world * ijk.push(1.0)).xyz()
    }

    /// The 3x3 part of the map: column c is the step (m) from one voxel to the next along c.
    pub fn axes(&self) -> Matrix3<f64> {
        self.to_world.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// Voxel spacing along i, j, k, m.
    pub fn spacing(&self) -> [f64; 3] {
        let a = self.axes();
        [a.column(0).norm(), a.column(1).norm(), a.column(2).norm()]
    }

    /// The continuous voxel index of world point `x` (RAS, m).
    pub fn index_of(&self, x: &Vector3<f64>) -> Vector3<f64> {
        // Checked invertible on reading.
        let inv = self.axes().try_inverse().unwrap_or_else(Matrix3::zeros);
        inv * (x - self.to_world.fixed_view::<3, 1>(0, 3))
    }

    /// The value of the voxel nearest `x` (RAS, m); None outside the image.
    pub fn nearest(&self, x: &Vector3<f64>) -> Option<f64> {
        let c = self.index_of(x);
        let mut ijk = [0usize; 3];
        for a in 0..3 {
            let r = c[a].round();
            if !(r >= 0.0 && r < self.dims[a] as f64) {
                return None;
            }
            ijk[a] = r as usize;
        }
        Some(self.values[self.index(ijk[0], ijk[1], ijk[2])])
    }

    /// Trilinear interpolation at `x` (RAS, m); None outside the voxel centres' hull (half a
    /// voxel inside the image's outer faces).
    pub fn trilinear(&self, x: &Vector3<f64>) -> Option<f64> {
        let c = self.index_of(x);
        let mut base = [0usize; 3];
        let mut f = [0.0; 3];
        for a in 0..3 {
            let n = self.dims[a];
            if !(c[a] >= 0.0 && c[a] <= (n - 1) as f64) {
                return None;
            }
            let b = (c[a].floor() as usize).min(n.saturating_sub(2));
            base[a] = b;
            f[a] = if n == 1 { 0.0 } else { c[a] - b as f64 };
        }
        let mut v = 0.0;
        for corner in 0..8 {
            let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            let mut w = 1.0;
            let mut at = [0usize; 3];
            for a in 0..3 {
                w *= if d[a] == 1 { f[a] } else { 1.0 - f[a] };
                at[a] = (base[a] + d[a]).min(self.dims[a] - 1);
            }
            if w != 0.0 {
                v += w * self.values[self.index(at[0], at[1], at[2])];
            }
        }
        Some(v)
    }
}
