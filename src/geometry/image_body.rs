//! A body from a labelled image (a segmentation): the chosen labels' voxels as hexahedra, or
//! their surface, extracted and smoothed, for TetGen to fill.
//!
//! Both work on blocks of `block`^3 voxels (the discretization's size over the voxel
//! spacing), so the model's resolution follows the scene, not the scan. The surface is the
//! 0.5 level of the blocks' tissue fraction (partial volume, so a boundary between voxels is
//! found where it lies, not at the block centres), extracted by naive surface nets
//! (`fast-surface-nets`) and smoothed by Taubin's lambda|mu filter (which does not shrink the
//! body). Label-0 (or unchosen) holes inside the body are cavities; pieces of tissue apart from
//! the largest are dropped (they would float free), and said.

use nalgebra::Vector3;

use super::closed_surface::{check_closed_surface, ClosedSurface};
use super::image::Image;
use super::{ElementShape, Mesh};
use crate::{Error, InputKind, Result};

/// Which voxels are tissue: those whose label is in `labels` (all nonzero labels when empty).
pub fn tissue_mask(image: &Image, labels: &[i64]) -> Vec<bool> {
    image
        .values
        .iter()
        .map(|&v| {
            let l = v.round() as i64;
            if labels.is_empty() {
                l != 0
            } else {
                labels.contains(&l)
            }
        })
        .collect()
}

/// [`tissue_mask`] of a labelmap meant to hold a body, refused where it cannot: an image one
/// voxel thin along an axis (2-D), a chosen label that no voxel holds (the message lists those
/// it does hold), or no tissue at all. `what` names the image.
pub fn body_mask(image: &Image, labels: &[i64], what: &str) -> Result<Vec<bool>> {
    if image.dims.contains(&1) {
        return Err(Error::input(InputKind::Mesh, format!(
            "{what}: the image is {:?} voxels, one voxel thin: a 2-D image holds no body; use a 3-D labelmap",
            image.dims
        )));
    }
    let mut present: Vec<i64> = image.values.iter().map(|v| v.round() as i64).collect();
    present.sort_unstable();
    present.dedup();
    let missing: Vec<i64> = labels
        .iter()
        .copied()
        .filter(|l| present.binary_search(l).is_err())
        .collect();
    let nonzero: Vec<i64> = present.iter().copied().filter(|&l| l != 0).collect();
    let listed = || {
        let shown: Vec<String> = nonzero.iter().take(20).map(|l| l.to_string()).collect();
        let more = if nonzero.len() > 20 { ", ..." } else { "" };
        format!("[{}{more}]", shown.join(", "))
    };
    if !missing.is_empty() {
        return Err(Error::input(InputKind::Mesh, format!(
            "{what}: no voxel holds label(s) {missing:?}; the image's nonzero labels are {}: check the labels",
            listed()
        )));
    }
    if nonzero.is_empty() {
        return Err(Error::input(
            InputKind::Mesh,
            format!("{what}: every voxel is 0: the image holds no labelled tissue"),
        ));
    }
    Ok(tissue_mask(image, labels))
}

/// Blocks along each axis for `block` voxels a block.
fn blocks(image: &Image, block: usize) -> [usize; 3] {
    image.dims.map(|n| n.div_ceil(block))
}

/// Fraction of tissue voxels in each block (i fastest), over the voxels the block holds.
fn block_fraction(image: &Image, mask: &[bool], block: usize) -> Vec<f64> {
    let m = blocks(image, block);
    let mut count = vec![0u32; m[0] * m[1] * m[2]];
    let mut tissue = vec![0u32; count.len()];
    for k in 0..image.dims[2] {
        for j in 0..image.dims[1] {
            for i in 0..image.dims[0] {
                let b = i / block + m[0] * (j / block + m[1] * (k / block));
                count[b] += 1;
                if mask[image.index(i, j, k)] {
                    tissue[b] += 1;
                }
            }
        }
    }
    count
        .iter()
        .zip(&tissue)
        .map(|(&c, &t)| t as f64 / c.max(1) as f64)
        .collect()
}

/// World position (m) of a continuous voxel index.
fn world(image: &Image, ijk: Vector3<f64>) -> Vector3<f64> {
    image.world(&ijk)
}

/// The image's tissue as hexahedra, one per block of voxels more than half tissue, corners
/// on the voxel corners (so a body aligned with the blocks is reproduced exactly). Only the
/// largest face-connected piece is kept; the number of blocks dropped is returned too.
pub fn voxel_mesh(image: &Image, mask: &[bool], block: usize, what: &str) -> Result<(Mesh, usize)> {
    let m = blocks(image, block);
    let fraction = block_fraction(image, mask, block);
    let inside: Vec<bool> = fraction.iter().map(|&f| f > 0.5).collect();
    let cell = |i: usize, j: usize, k: usize| i + m[0] * (j + m[1] * k);
    // Largest face-connected piece.
    let mut piece = vec![usize::MAX; inside.len()];
    let mut sizes = Vec::new();
    for start in 0..inside.len() {
        if !inside[start] || piece[start] != usize::MAX {
            continue;
        }
        let id = sizes.len();
        let mut stack = vec![start];
        piece[start] = id;
        let mut size = 0usize;
        while let Some(c) = stack.pop() {
            size += 1;
            let (i, j, k) = (c % m[0], (c / m[0]) % m[1], c / (m[0] * m[1]));
            let mut visit = |ii: usize, jj: usize, kk: usize| {
                let n = cell(ii, jj, kk);
                if inside[n] && piece[n] == usize::MAX {
                    piece[n] = id;
                    stack.push(n);
                }
            };
            if i > 0 {
                visit(i - 1, j, k)
            }
            if i + 1 < m[0] {
                visit(i + 1, j, k)
            }
            if j > 0 {
                visit(i, j - 1, k)
            }
            if j + 1 < m[1] {
                visit(i, j + 1, k)
            }
            if k > 0 {
                visit(i, j, k - 1)
            }
            if k + 1 < m[2] {
                visit(i, j, k + 1)
            }
        }
        sizes.push(size);
    }
    let Some(largest) = (0..sizes.len()).max_by_key(|&p| sizes[p]) else {
        return Err(Error::input(InputKind::Mesh, format!(
            "{what}: no block of voxels is more than half tissue; check geometry.labels or use a smaller discretization.size"
        )));
    };
    let dropped: usize = sizes.iter().sum::<usize>() - sizes[largest];
    // Nodes at block corners: corner (I, J, K) at voxel index block * I - 0.5 (clipped to the
    // image's outer face).
    let corner = |a: usize, c: usize| ((block * c).min(image.dims[a]) as f64) - 0.5;
    let n = [m[0] + 1, m[1] + 1, m[2] + 1];
    let mut id = vec![usize::MAX; n[0] * n[1] * n[2]];
    let mut nodes = Vec::new();
    let mut cells = Vec::new();
    let reflected = image.axes().determinant() < 0.0;
    for k in 0..m[2] {
        for j in 0..m[1] {
            for i in 0..m[0] {
                if piece[cell(i, j, k)] != largest {
                    continue;
                }
                let corners = [
                    (i, j, k),
                    (i + 1, j, k),
                    (i + 1, j + 1, k),
                    (i, j + 1, k),
                    (i, j, k + 1),
                    (i + 1, j, k + 1),
                    (i + 1, j + 1, k + 1),
                    (i, j + 1, k + 1),
                ];
                let mut hex = corners.map(|(a, b, c)| {
                    let key = a + n[0] * (b + n[1] * c);
                    if id[key] == usize::MAX {
                        id[key] = nodes.len();
                        nodes.push(world(
                            image,
                            Vector3::new(corner(0, a), corner(1, b), corner(2, c)),
                        ));
                    }
                    id[key]
                });
                if reflected {
                    hex = [
                        hex[4], hex[5], hex[6], hex[7], hex[0], hex[1], hex[2], hex[3],
                    ];
                }
                cells.extend_from_slice(&hex);
            }
        }
    }
    Ok((
        Mesh {
            nodes,
            shape: ElementShape::Hex8,
            cells,
        },
        dropped,
    ))
}

/// What [`label_surface`] made besides the surface: pieces dropped and their tissue volume.
#[derive(Debug, Clone, Default)]
pub struct SurfaceReport {
    /// Pieces of tissue apart from the largest, dropped.
    pub islands: usize,
    /// Cavities kept inside the body.
    pub cavities: usize,
}

/// The surface of the image's tissue: the 0.5 level of the tissue fraction on blocks of
/// `block` voxels, by surface nets, smoothed by `smoothing` Taubin iterations (lambda 0.5,
/// mu -0.53), checked closed, oriented and not crossing itself; with `cavities`, the closed
/// holes inside (ventricles) are kept as cavities, else only the outer surface (a skull's
/// inner wall). `what` names the image.
pub fn label_surface(
    image: &Image,
    mask: &[bool],
    block: usize,
    smoothing: usize,
    cavities: bool,
    what: &str,
) -> Result<(ClosedSurface, SurfaceReport)> {
    use fast_surface_nets::ndshape::{RuntimeShape, Shape};
    let m = blocks(image, block);
    let fraction = block_fraction(image, mask, block);
    const PAD: usize = 2;
    let p = m.map(|v| v + 2 * PAD);
    let too_big = p.iter().any(|&v| v > u32::MAX as usize / 4) || p[0] * p[1] * p[2] > 1 << 28;
    if too_big {
        return Err(Error::input(InputKind::Limit, format!(
            "{what}: {m:?} blocks are too many for the surface extraction; raise discretization.size"
        )));
    }
    let shape = RuntimeShape::<u32, 3>::new([p[0] as u32, p[1] as u32, p[2] as u32]);
    let mut sdf = vec![0.5f32; p[0] * p[1] * p[2]];
    for k in 0..m[2] {
        for j in 0..m[1] {
            for i in 0..m[0] {
                let at = shape.linearize([(i + PAD) as u32, (j + PAD) as u32, (k + PAD) as u32]);
                sdf[at as usize] = (0.5 - fraction[i + m[0] * (j + m[1] * k)]) as f32;
            }
        }
    }
    let filled = remove_ambiguities(&mut sdf, p);
    if filled > 0 {
        log::info!("{what}: {filled} block sample(s) set inside to keep the surface manifold");
    }
    let mut buffer = fast_surface_nets::SurfaceNetsBuffer::default();
    fast_surface_nets::surface_nets(
        &sdf,
        &shape,
        [0; 3],
        [p[0] as u32 - 1, p[1] as u32 - 1, p[2] as u32 - 1],
        &mut buffer,
    );
    if buffer.indices.is_empty() {
        return Err(Error::input(
            InputKind::Mesh,
            format!(
            "{what}: the chosen labels hold no tissue at this resolution; check geometry.labels"
        ),
        ));
    }
    // Block-sample index -> voxel index: sample (I) sits at the centre of block I.
    let centre = (block as f64 - 1.0) / 2.0;
    let mut points: Vec<Vector3<f64>> = buffer
        .positions
        .iter()
        .map(|q| {
            let v = Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64);
            v.map(|x| (x - PAD as f64) * block as f64 + centre)
        })
        .collect();
    let mut triangles: Vec<[usize; 3]> = buffer
        .indices
        .chunks_exact(3)
        .map(|t| [t[0] as usize, t[1] as usize, t[2] as usize])
        .collect();
    let report = keep_main_body(&points, &mut triangles, cavities);
    taubin(&mut points, &triangles, smoothing);
    // Tissue at the image's border: the padding puts the surface half a block past the last
    // block's centre, which lies past the image where the block does not divide it; the body
    // stops at the image's outer voxel faces (issue 56: it grew past the image).
    let last = image.dims.map(|n| n as f64 - 0.5);
    for v in points.iter_mut() {
        for a in 0..3 {
            v[a] = v[a].clamp(-0.5, last[a]);
        }
    }
    let points: Vec<Vector3<f64>> = points.into_iter().map(|v| world(image, v)).collect();
    let surface = check_closed_surface(what, points, triangles).map_err(|e| {
        Error::input(
            InputKind::Mesh,
            format!(
            "{e}\n(the surface was extracted from the image's labels at {block} voxel(s) a block: \
             a thin bridge of tissue makes such a fault; a larger discretization.size or \
             geometry.smoothing, or a cleaned segmentation, avoids it)"
        ),
        )
    })?;
    Ok((surface, report))
}

/// Makes every grid cell's inside corners one edge-connected group, and its outside corners
/// one (returns how many samples it set inside). Surface nets puts one vertex in each cell the
/// surface crosses; where a cell's corners fall in two inside (or two outside) groups (two
/// voxels meeting at an edge or a corner: a thin bridge), two sheets would share that vertex
/// and the surface would not be manifold, which TetGen cannot fill. Such cells get their
/// outside corners set just inside (tissue closes the gap), repeated until none is left; the
/// values stay close to zero, so the surface moves by a fraction of a block there only.
fn remove_ambiguities(sdf: &mut [f32], p: [usize; 3]) -> usize {
    const JUST_INSIDE: f32 = -1e-3;
    let at = |x: usize, y: usize, z: usize| x + p[0] * (y + p[1] * z);
    let groups = |inside: [bool; 8], want: bool| -> usize {
        let mut parent: [usize; 8] = std::array::from_fn(|i| i);
        fn root(parent: &mut [usize; 8], mut i: usize) -> usize {
            while parent[i] != i {
                i = parent[i];
            }
            i
        }
        for a in 0..8 {
            for bit in [1, 2, 4] {
                let b = a | bit;
                if b != a && inside[a] == want && inside[b] == want {
                    let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
                    parent[ra] = rb;
                }
            }
        }
        (0..8)
            .filter(|&i| inside[i] == want && root(&mut parent, i) == i)
            .count()
    };
    let mut changed_total = 0;
    loop {
        let mut changed = 0;
        for z in 0..p[2] - 1 {
            for y in 0..p[1] - 1 {
                for x in 0..p[0] - 1 {
                    let idx: [usize; 8] = std::array::from_fn(|i| {
                        at(x + (i & 1), y + ((i >> 1) & 1), z + ((i >> 2) & 1))
                    });
                    let inside = idx.map(|i| sdf[i] < 0.0);
                    let n_in = inside.iter().filter(|&&b| b).count();
                    if n_in < 2 || n_in > 6 {
                        continue;
                    }
                    if groups(inside, true) > 1 || groups(inside, false) > 1 {
                        for (k, &i) in idx.iter().enumerate() {
                            if !inside[k] {
                                sdf[i] = JUST_INSIDE;
                                changed += 1;
                            }
                        }
                    }
                }
            }
        }
        changed_total += changed;
        if changed == 0 {
            return changed_total;
        }
    }
}

/// Keeps the largest piece of the surface and, with `cavities`, the pieces inside it, in the
/// surface-nets orientation (every piece faces the same way relative to the tissue).
fn keep_main_body(
    points: &[Vector3<f64>],
    triangles: &mut Vec<[usize; 3]>,
    cavities: bool,
) -> SurfaceReport {
    let piece = super::closed_surface::pieces_of(points.len(), triangles);
    let mut pieces: Vec<Vec<usize>> = vec![Vec::new(); piece.iter().max().map_or(0, |&p| p + 1)];
    for (k, &p) in piece.iter().enumerate() {
        pieces[p].push(k);
    }
    let volume = |members: &[usize]| {
        let tris: Vec<[usize; 3]> = members.iter().map(|&k| triangles[k]).collect();
        super::dome::enclosed_volume(points, &tris)
    };
    let list: Vec<(Vec<usize>, f64)> = pieces
        .into_iter()
        .map(|m| {
            let v = volume(&m);
            (m, v)
        })
        .collect();
    let Some(main) = (0..list.len()).max_by(|&a, &b| list[a].1.abs().total_cmp(&list[b].1.abs()))
    else {
        return SurfaceReport::default();
    };
    let sign = list[main].1.signum();
    let main_faces: Vec<&[usize]> = list[main].0.iter().map(|&k| &triangles[k][..]).collect();
    let mut keep = vec![false; triangles.len()];
    let mut report = SurfaceReport::default();
    for (p, (members, v)) in list.iter().enumerate() {
        let kept = if p == main {
            true
        } else if v.signum() == sign {
            report.islands += 1;
            false
        } else if !cavities {
            false
        } else {
            // A cavity: kept when inside the main body.
            let x = points[triangles[members[0]][0]];
            let w = super::winding::winding_number(&x, points, main_faces.iter().copied());
            let inside = w.abs() > 0.5;
            if inside {
                report.cavities += 1;
            } else {
                report.islands += 1;
            }
            inside
        };
        if kept {
            for &k in members {
                keep[k] = true;
            }
        }
    }
    let mut k = 0;
    triangles.retain(|_| {
        k += 1;
        keep[k - 1]
    });
    report
}

/// Taubin's lambda|mu smoothing (1995) with the umbrella Laplacian: a shrinking step (lambda
/// 0.5) then an inflating one (mu -0.53) per iteration, which smooths the voxel staircase
/// without shrinking the body.
fn taubin(points: &mut [Vector3<f64>], triangles: &[[usize; 3]], iterations: usize) {
    if iterations == 0 {
        return;
    }
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); points.len()];
    for t in triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            neighbours[a].push(b);
            neighbours[b].push(a);
        }
    }
    for n in neighbours.iter_mut() {
        n.sort_unstable();
        n.dedup();
    }
    let mut next = points.to_vec();
    for _ in 0..iterations {
        for factor in [0.5, -0.53] {
            for (i, n) in neighbours.iter().enumerate() {
                if n.is_empty() {
                    continue;
                }
                let mean = n.iter().map(|&j| points[j]).sum::<Vector3<f64>>() / n.len() as f64;
                next[i] = points[i] + (mean - points[i]) * factor;
            }
            points.copy_from_slice(&next);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix4;

    /// A 12^3 image of 1 mm voxels with label 1 on voxels 2..10 (an 8 mm cube) and a label-0
    /// hole of 2^3 voxels in the middle.
    fn box_image(to_world: Matrix4<f64>) -> Image {
        let mut im = Image::filled([12, 12, 12], to_world, 0.0);
        for k in 2..10 {
            for j in 2..10 {
                for i in 2..10 {
                    let n = im.index(i, j, k);
                    im.values[n] = 1.0;
                }
            }
        }
        im
    }

    fn mm() -> Matrix4<f64> {
        let mut m = Matrix4::identity() * 1e-3;
        m[(3, 3)] = 1.0;
        m
    }

    /// Voxels as hexahedra: the cube exactly, on an oblique reflected map too (rotated, with
    /// positive volumes), in blocks of 1 and 2 voxels.
    #[test]
    fn voxels_make_the_labelled_box_exactly() {
        let mut reflected = crate::io::image::tests::oblique();
        reflected.column_mut(0).neg_mut();
        for (map, s) in [(mm(), 1e-3), (reflected, 1e-3)] {
            let im = box_image(map);
            let mask = tissue_mask(&im, &[]);
            for block in [1, 2] {
                let (mesh, dropped) = voxel_mesh(&im, &mask, block, "box.nii").unwrap();
                assert_eq!(dropped, 0);
                assert_eq!(mesh.num_cells(), 512 / block.pow(3));
                let mut volume = 0.0;
                for e in 0..mesh.num_cells() {
                    let c = mesh.cell(e);
                    let x: [Vector3<f64>; 8] = std::array::from_fn(|a| mesh.nodes[c[a]]);
                    let v = (x[1] - x[0]).cross(&(x[3] - x[0])).dot(&(x[4] - x[0]));
                    assert!(v > 0.0, "element {e} inverted");
                    volume += v;
                }
                let sp = im.spacing();
                let expect = 512.0 * sp[0] * sp[1] * sp[2];
                assert!(
                    (volume - expect).abs() < 1e-12 * expect / s,
                    "{volume} vs {expect}"
                );
            }
        }
    }

    /// The surface of the labelled box with a hole: closed, one cavity, and the material's
    /// volume within a voxel layer's share (the edges and corners are rounded by the surface
    /// nets and the smoothing); without smoothing the flat faces lie on the voxel faces.
    #[test]
    fn the_surface_of_a_labelled_box_with_a_hole() {
        let mut im = box_image(mm());
        for k in 5..7 {
            for j in 5..7 {
                for i in 5..7 {
                    let n = im.index(i, j, k);
                    im.values[n] = 0.0;
                }
            }
        }
        let mask = tissue_mask(&im, &[1]);
        let (s, r) = label_surface(&im, &mask, 1, 0, true, "box.nii").unwrap();
        assert_eq!((r.cavities, r.islands), (0 + 1, 0));
        assert_eq!(s.holes.len(), 1);
        // Face centres on the voxel faces (x = 1.5 mm and 9.5 mm).
        let on_face = s
            .points
            .iter()
            .filter(|p| (p.x - 1.5e-3).abs() < 1e-12 && (p.y - 5.5e-3).abs() < 2e-3)
            .count();
        assert!(on_face > 0);
        let exact = (512.0 - 8.0) * 1e-9;
        let v = s.volume();
        assert!((v - exact).abs() / exact < 0.1, "{v} vs {exact}");
        let (s2, _) = label_surface(&im, &mask, 1, 10, true, "box.nii").unwrap();
        assert!((s2.volume() - exact).abs() / exact < 0.1, "{}", s2.volume());
    }

    /// An island apart from the body is dropped and counted.
    #[test]
    fn islands_are_dropped() {
        let mut im = box_image(mm());
        let n = im.index(0, 0, 0);
        im.values[n] = 1.0;
        let mask = tissue_mask(&im, &[]);
        let (_, r) = label_surface(&im, &mask, 1, 2, true, "box.nii").unwrap();
        assert_eq!(r.islands, 1);
        let (_, dropped) = voxel_mesh(&im, &mask, 1, "box.nii").unwrap();
        assert_eq!(dropped, 1);
    }
}
