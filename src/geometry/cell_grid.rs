//! Buckets over a mesh's cells, so that the cells that may hold a point are found in constant
//! time: point location (probes, the shape functions at the Gauss points of a coupled body's
//! essential boundaries) scanned every cell for every point, which made the coupled set-up
//! grow with the square of the nodes (brain-indentation benchmark c5, 9,976 nodes: 77 s of its
//! 78 s of preparation, now 3 s).
//!
//! Cells are grouped in bands of sizes within a factor 2, each band a sparse grid of buckets
//! as large as its largest cell, so a graded mesh's small and large cells both land in a
//! few buckets each and a bucket holds a few cells.

use std::collections::HashMap;

use nalgebra::Vector3;

use super::Mesh;

/// Each cell is registered in the buckets its bounding box, padded by this fraction of its
/// largest extent, overlaps: [`crate::probe::Probe::locate`] accepts points up to 5 % of an
/// element outside it (in natural coordinates), which lie within that padding.
const PAD: f64 = 0.1;

/// Size bands at most (cells below the last band's size join it).
const MAX_BANDS: usize = 12;

/// One band: its bucket edge (m) and its buckets' cells, ascending.
#[derive(Debug, Clone)]
struct Band {
    step: f64,
    buckets: HashMap<[i64; 3], Vec<u32>>,
}

/// Buckets of cell ids, by cell size.
#[derive(Debug, Clone, Default)]
pub struct CellGrid {
    bands: Vec<Band>,
}

impl CellGrid {
    /// The buckets of `mesh`'s cells.
    pub fn new(mesh: &Mesh) -> Self {
        let boxes: Vec<(Vector3<f64>, Vector3<f64>)> = (0..mesh.num_cells())
            .map(|e| {
                let c = mesh.cell(e);
                let (lo, hi) = c.iter().fold(
                    (
                        Vector3::repeat(f64::INFINITY),
                        Vector3::repeat(f64::NEG_INFINITY),
                    ),
                    |(l, h), &i| (l.inf(&mesh.nodes[i]), h.sup(&mesh.nodes[i])),
                );
                let pad = PAD * (hi - lo).amax();
                (lo.add_scalar(-pad), hi.add_scalar(pad))
            })
            .collect();
        let size = |b: &(Vector3<f64>, Vector3<f64>)| (b.1 - b.0).amax();
        let largest = boxes.iter().map(size).fold(0.0, f64::max);
        if !(largest > 0.0 && largest.is_finite()) {
            return CellGrid::default();
        }
        let band_of = |s: f64| {
            if s > 0.0 {
                ((largest / s).log2().floor().max(0.0) as usize).min(MAX_BANDS - 1)
            } else {
                MAX_BANDS - 1
            }
        };
        let mut steps = [0.0f64; MAX_BANDS];
        for b in &boxes {
            let k = band_of(size(b));
            steps[k] = steps[k].max(size(b));
        }
        let mut bands: Vec<Band> = steps
            .iter()
            .map(|&step| Band {
                step,
                buckets: HashMap::new(),
            })
            .collect();
        // In cell order, so each bucket's cells are ascending.
        for (e, b) in boxes.iter().enumerate() {
            let band = &mut bands[band_of(size(b))];
            let (lo, hi) = (key(&b.0, band.step), key(&b.1, band.step));
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        band.buckets.entry([x, y, z]).or_default().push(e as u32);
                    }
                }
            }
        }
        bands.retain(|b| !b.buckets.is_empty());
        CellGrid { bands }
    }

    /// The cells whose padded bounding box may hold `x`, ascending.
    pub fn candidates(&self, x: &Vector3<f64>) -> Vec<u32> {
        let mut out: Vec<u32> = Vec::new();
        for b in &self.bands {
            if let Some(cells) = b.buckets.get(&key(x, b.step)) {
                out.extend_from_slice(cells);
            }
        }
        out.sort_unstable();
        out
    }
}

/// Bucket of `x` for bucket edge `step` (m); coordinates beyond the range of i64 buckets
/// saturate (no cell lies there).
fn key(x: &Vector3<f64>, step: f64) -> [i64; 3] {
    std::array::from_fn(|k| (x[k] / step).floor() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::box_tet;

    /// The grid finds the cell the full scan finds, for points inside, on faces and just
    /// outside a graded mesh, and nothing where the scan fails.
    #[test]
    fn located_cells_match_the_full_scan() {
        let mut mesh = box_tet(Vector3::zeros(), Vector3::new(0.1, 0.06, 0.04), [6, 4, 3]).unwrap();
        // Grade it: squeeze x towards 0 (cells of very different sizes).
        for p in &mut mesh.nodes {
            p.x = 0.1 * (p.x / 0.1).powi(3);
        }
        let grid = CellGrid::new(&mesh);
        let mut n = 0;
        for i in 0..40 {
            for j in 0..9 {
                let x = Vector3::new(
                    -0.002 + 0.104 * i as f64 / 39.0,
                    -0.001 + 0.062 * j as f64 / 8.0,
                    0.013 * (i % 4) as f64,
                );
                let what = || "p".to_string();
                let full = crate::probe::locate_among(&x, &mesh, 0..mesh.num_cells(), &what);
                let fast = crate::probe::locate_in_grid(&x, &mesh, &grid, &what);
                match (full, fast) {
                    (Ok(a), Ok(b)) => {
                        assert_eq!(a.element, b.element, "{x:?}");
                        assert_eq!(a.weights, b.weights);
                        n += 1;
                    }
                    (Err(_), Err(_)) => {}
                    (a, b) => panic!("{x:?}: scan {:?}, grid {:?}", a.is_ok(), b.is_ok()),
                }
            }
        }
        assert!(n > 250, "{n} points located");
    }
}
