//! Essential boundary conditions on meshless nodes through the shared integrator: the
//! EBCIEM / SEBCIEM correction (thesis chapter 4) wrapped as a [`Corrector`].

use nalgebra::Vector3;
use std::sync::atomic::{AtomicBool, Ordering};

use super::discretize::MeshlessBuild;
use crate::bc::ebciem::{ebciem_columns, ComponentCorrection};
use crate::bc::{Boundary, LoadCurve};
use crate::geometry::quality;
use crate::quadrature::SparseRow;
use crate::solver::{keep_warm, Corrector, SharedMut};
use crate::{InputKind, Result};

/// One component's correction with its prescribed values.
struct Component {
    corr: ComponentCorrection,
    amplitude: Vec<f64>,
    curve: Vec<LoadCurve>,
    /// Where each constrained node's value comes from: (model boundary, the node's place in
    /// it), for [`Corrector::set_values`].
    sources: Vec<(usize, usize)>,
    /// Columns (indices into the constrained nodes) of each model boundary.
    columns: Vec<Vec<usize>>,
    target: Vec<f64>,
}

/// The inputs of a factored system (constrained nodes, rows of Phi, columns of V) and the
/// index of the component that holds it.
type BuiltSystem = (Vec<usize>, Vec<SparseRow>, Vec<SparseRow>, usize);

/// Corrections solved together: the components (x, y, z) of one group of constrained nodes
/// that share one system (SEBCIEM with every component constrained on the same nodes; one
/// solve with a column per component serves them), or a single component.
struct Item {
    comps: Vec<Component>,
    /// Right-hand sides of the solve, ne x components.
    rhs: Vec<f64>,
}

impl Item {
    /// Sets the targets at load fraction `tau` and applies the corrections.
    ///
    /// # Safety
    /// As [`ComponentCorrection::solve_shared`] for `u` and `nodal` (N vectors each).
    unsafe fn correct(&mut self, u: *mut f64, nodal: *mut f64, tau: f64, alpha: f64) {
        for c in self.comps.iter_mut() {
            for (k, t) in c.target.iter_mut().enumerate() {
                *t = c.amplitude[k] * c.curve[k].value(tau);
            }
        }
        match &mut self.comps[..] {
            [a] => ComponentCorrection::solve_shared(
                &mut [&mut a.corr],
                u,
                &[&a.target],
                &mut self.rhs,
                nodal,
                alpha,
            ),
            [a, b] => ComponentCorrection::solve_shared(
                &mut [&mut a.corr, &mut b.corr],
                u,
                &[&a.target, &b.target],
                &mut self.rhs,
                nodal,
                alpha,
            ),
            [a, b, c] => ComponentCorrection::solve_shared(
                &mut [&mut a.corr, &mut b.corr, &mut c.corr],
                u,
                &[&a.target, &b.target, &c.target],
                &mut self.rhs,
                nodal,
                alpha,
            ),
            _ => unreachable!("an item holds 1 to 3 components (MeshlessCorrector::from_parts)"),
        }
    }
}

/// EBCIEM / SEBCIEM for every constrained component of the meshless boundaries.
///
/// The constrained nodes of each component are split into independent groups: two groups
/// share no node in their shape-function rows or boundary-force columns, so their systems are
/// separate blocks of `Phi M^-1 V` and their corrections read and write disjoint nodes. The
/// groups (the two end faces of a compressed cylinder) are corrected in parallel: the first
/// half (lowest node ids) on the calling thread, which also takes the front of the time loop's
/// two-ended loops. Meshless cylinder, two threads: the correction went from 30-35 to 23-25 us
/// per step, the whole step from 0.201-0.204 to 0.189-0.195 ms.
pub struct MeshlessCorrector {
    items: Vec<Item>,
    alpha: f64,
    num_boundaries: usize,
    /// Constraint force of the last correction on every node, N (for the work).
    nodal: Vec<Vector3<f64>>,
    /// The nodes any constraint force reaches, ascending: the only entries of `nodal` that are
    /// ever non-zero, so each step clears and sums these alone instead of all N.
    forced: Vec<u32>,
    /// The static solve's constraint forces per boundary (N), reported until the next
    /// correction.
    static_reactions: Option<Vec<Vector3<f64>>>,
}

/// How the boundary force of a corrected boundary is distributed (thesis chapter 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Imposition {
    /// Interpolated linearly over the triangulated boundary (EBCIEM, thesis sect. 4.3).
    Ebciem,
    /// Lumped at the constrained nodes (SEBCIEM, thesis sect. 4.3.1).
    Sebciem,
}

/// What building the corrector found worth a warning.
pub struct CorrectorReport {
    /// Constrained nodes on no boundary triangle, imposed with lumped (SEBCIEM) columns.
    pub lumped_nodes: usize,
}

impl MeshlessCorrector {
    /// Builds the per-component corrections for `boundaries` (all imposed by correction) with
    /// `method` (EBCIEM or SEBCIEM) and factors each system once.
    pub fn new(
        build: &MeshlessBuild,
        boundaries: &[Boundary],
        mass: &[f64],
        method: Imposition,
    ) -> Result<(Self, CorrectorReport)> {
        let n = build.nodes.len();
        // Boundary triangles of the background tets, in field-node ids (all vertices kept).
        let tris: Vec<[usize; 3]> = if method == Imposition::Ebciem
            && build.background.num_cells() > 0
        {
            quality::boundary_faces(&build.background)
                .map_err(|e| {
                    crate::Error::input(InputKind::Discretization, format!("background tets: {e}"))
                })?
                .into_iter()
                .filter_map(|f| {
                    let node = |v: usize| build.background_node[v];
                    let t = [node(f[0])?, node(f[1])?, node(f[2])?];
                    t.iter().all(|&i| i < n).then_some(t)
                })
                .collect()
        } else {
            Vec::new()
        };
        let shape = |x: &Vector3<f64>| -> Result<SparseRow> {
            build.shape_values(x, &|| "essential-boundary point".to_string())
        };
        Self::from_parts(&build.nodes, &tris, &shape, boundaries, mass, method)
    }

    /// As [`MeshlessCorrector::new`] for any discretization: `nodes` (m), the boundary
    /// triangles of the body in node ids (EBCIEM boundary integrals; empty for SEBCIEM) and
    /// `shape(x)`, the shape-function values at x.
    pub fn from_parts(
        nodes_x: &[Vector3<f64>],
        tris: &[[usize; 3]],
        shape: &dyn Fn(&Vector3<f64>) -> Result<SparseRow>,
        boundaries: &[Boundary],
        mass: &[f64],
        method: Imposition,
    ) -> Result<(Self, CorrectorReport)> {
        let n = nodes_x.len();
        let mut comps: Vec<Component> = Vec::new();
        let mut lumped_nodes = 0;
        // The inputs of each system factored so far, and the component that holds it.
        let mut built: Vec<BuiltSystem> = Vec::new();
        for c in 0..3 {
            // Constrained nodes of this component, first boundary wins (conflicts were checked
            // by the direct constraints of the same boundaries).
            let mut owner = vec![usize::MAX; n];
            let mut nodes = Vec::new();
            for (b, bd) in boundaries.iter().enumerate() {
                if bd.components[c].is_none() {
                    continue;
                }
                for &i in &bd.nodes {
                    if owner[i] == usize::MAX {
                        owner[i] = b;
                        nodes.push(i);
                    }
                }
            }
            if nodes.is_empty() {
                continue;
            }
            nodes.sort_unstable();
            let phi_rows: Vec<SparseRow> = nodes
                .iter()
                .map(|&i| shape(&nodes_x[i]))
                .collect::<Result<_>>()?;
            let v_cols = if method == Imposition::Ebciem {
                let ctris = essential_triangles(tris, boundaries, c, n);
                let mut in_tri = vec![false; n];
                for t in &ctris {
                    for &i in t {
                        in_tri[i] = true;
                    }
                }
                let tri_nodes: Vec<usize> = nodes.iter().cloned().filter(|&i| in_tri[i]).collect();
                let cols = if tri_nodes.is_empty() {
                    Vec::new()
                } else {
                    ebciem_columns(&tri_nodes, nodes_x, &ctris, shape)?
                };
                let mut it = cols.into_iter();
                nodes
                    .iter()
                    .zip(&phi_rows)
                    .map(|(&i, row)| {
                        if in_tri[i] {
                            it.next().unwrap_or_default()
                        } else {
                            lumped_nodes += 1;
                            row.clone()
                        }
                    })
                    .collect()
            } else {
                phi_rows.clone()
            };
            let sources: Vec<(usize, usize)> = nodes
                .iter()
                .map(|&i| {
                    let b = &boundaries[owner[i]];
                    // Per-node values: the node's place in its boundary (uniform values
                    // need none).
                    let k = match b.node_values {
                        Some(_) => b.nodes.iter().position(|&j| j == i).unwrap_or(0),
                        None => 0,
                    };
                    (owner[i], k)
                })
                .collect();
            let amplitude: Vec<f64> = sources
                .iter()
                .map(|&(b, k)| boundaries[b].value(k, c).unwrap_or(0.0))
                .collect();
            let curve: Vec<LoadCurve> = nodes
                .iter()
                .map(|&i| boundaries[owner[i]].curve.clone())
                .collect();
            for members in independent_groups(n, &phi_rows, &v_cols) {
                let mut columns = vec![Vec::new(); boundaries.len()];
                for (k, &m) in members.iter().enumerate() {
                    columns[owner[nodes[m]]].push(k);
                }
                let ne = members.len();
                let g_nodes: Vec<usize> = members.iter().map(|&m| nodes[m]).collect();
                let g_phi: Vec<SparseRow> = members.iter().map(|&m| phi_rows[m].clone()).collect();
                let g_v: Vec<SparseRow> = members.iter().map(|&m| v_cols[m].clone()).collect();
                // x, y and z of a boundary share one system (SEBCIEM and EBCIEM): factor it once.
                let same = built
                    .iter()
                    .find(|(n, p, v, _)| *n == g_nodes && *p == g_phi && *v == g_v)
                    .map(|b| b.3);
                let corr = match same {
                    Some(k) => comps[k].corr.for_component(c),
                    None => {
                        let corr = ComponentCorrection::new(
                            c,
                            g_nodes.clone(),
                            g_phi.clone(),
                            g_v.clone(),
                            mass,
                        )?;
                        built.push((g_nodes, g_phi, g_v, comps.len()));
                        corr
                    }
                };
                comps.push(Component {
                    corr,
                    amplitude: members.iter().map(|&m| amplitude[m]).collect(),
                    curve: members.iter().map(|&m| curve[m].clone()).collect(),
                    sources: members.iter().map(|&m| sources[m]).collect(),
                    columns,
                    target: vec![0.0; ne],
                });
            }
        }
        let mut forced: Vec<u32> = comps
            .iter()
            .flat_map(|c| c.corr.forced_nodes().map(|j| j as u32))
            .collect();
        forced.sort_unstable();
        forced.dedup();
        // Components of one group with one system share a solve.
        let mut items: Vec<Item> = Vec::new();
        for comp in comps {
            match items
                .iter_mut()
                .find(|it| it.comps[0].corr.same_system(&comp.corr))
            {
                Some(it) => it.comps.push(comp),
                None => items.push(Item {
                    comps: vec![comp],
                    rhs: Vec::new(),
                }),
            }
        }
        for it in items.iter_mut() {
            it.rhs = vec![0.0; it.comps[0].target.len() * it.comps.len()];
        }
        Ok((
            MeshlessCorrector {
                items,
                alpha: 1.0,
                num_boundaries: boundaries.len(),
                nodal: vec![Vector3::zeros(); n],
                forced,
                static_reactions: None,
            },
            CorrectorReport { lumped_nodes },
        ))
    }

    /// The components' corrections, in the order they were built (x, y, z; groups in order).
    fn comps(&self) -> impl Iterator<Item = &Component> {
        self.items.iter().flat_map(|it| it.comps.iter())
    }

    /// Largest |interpolated - prescribed| over the constrained nodes at load fraction `tau`, m.
    pub fn max_error(&self, u: &[Vector3<f64>], tau: f64) -> f64 {
        let mut worst = 0.0f64;
        let mut vals = Vec::new();
        for c in self.comps() {
            c.corr.interpolate(u, &mut vals);
            for (k, v) in vals.iter().enumerate() {
                let t = c.amplitude[k] * c.curve[k].value(tau);
                worst = worst.max((v - t).abs());
            }
        }
        worst
    }
}

/// Splits the constrained nodes (indices k into `phi_rows` and `v_cols`) into groups joined by
/// shared nodes: k and l belong to one group when row k of Phi or column k of V reaches a node
/// that row l or column l reaches. Groups are listed by their smallest member, members
/// ascending.
fn independent_groups(n: usize, phi_rows: &[SparseRow], v_cols: &[SparseRow]) -> Vec<Vec<usize>> {
    let ne = phi_rows.len();
    let mut parent: Vec<usize> = (0..ne).collect();
    fn root(parent: &mut [usize], mut k: usize) -> usize {
        while parent[k] != k {
            parent[k] = parent[parent[k]];
            k = parent[k];
        }
        k
    }
    let mut first = vec![usize::MAX; n];
    for (k, (row, col)) in phi_rows.iter().zip(v_cols).enumerate() {
        for &(j, _) in row.iter().chain(col) {
            let j = j as usize;
            if first[j] == usize::MAX {
                first[j] = k;
            } else {
                let (a, b) = (root(&mut parent, k), root(&mut parent, first[j]));
                // The smaller index becomes the root, so a group's root is its smallest member.
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    let mut group_of = vec![usize::MAX; ne];
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for k in 0..ne {
        let r = root(&mut parent, k);
        if group_of[r] == usize::MAX {
            group_of[r] = groups.len();
            groups.push(Vec::new());
        }
        groups[group_of[r]].push(k);
    }
    groups
}

/// The boundary triangles that carry component `c`'s EBCIEM boundary force: those whose three
/// vertices all belong to one boundary that constrains `c`.
///
/// Three constrained vertices are not enough: a triangle whose vertices lie on two different
/// boundaries crosses the free surface between them. The convex hull of a cloud on a curved
/// surface has such triangles: on a cylinder, where the nodes of the lateral surface are
/// irregular, hull faces join a node of the top rim to two nodes of the bottom rim across the
/// whole height (jittered lattice, h = 0.0125 m: faces of 5.9e-4 m^2 on the free lateral
/// surface), and integrating the caps' constraint force over them made the correction act on
/// the free surface and the run invert within 400 steps.
fn essential_triangles(
    tris: &[[usize; 3]],
    boundaries: &[Boundary],
    c: usize,
    n: usize,
) -> Vec<[usize; 3]> {
    let mut member = vec![false; n];
    let mut keep = vec![false; tris.len()];
    for bd in boundaries.iter().filter(|b| b.components[c].is_some()) {
        for &i in &bd.nodes {
            member[i] = true;
        }
        for (k, t) in tris.iter().enumerate() {
            keep[k] |= t.iter().all(|&i| member[i]);
        }
        for &i in &bd.nodes {
            member[i] = false;
        }
    }
    tris.iter()
        .zip(&keep)
        .filter(|(_, &k)| k)
        .map(|(t, _)| *t)
        .collect()
}

impl Corrector for MeshlessCorrector {
    fn correct(&mut self, u: &mut [Vector3<f64>], tau: f64, alpha: f64) {
        self.alpha = alpha;
        self.static_reactions = None;
        for &j in &self.forced {
            self.nodal[j as usize] = Vector3::zeros();
        }
        assert!(
            u.len() == self.nodal.len(),
            "MeshlessCorrector::correct: {} displacements for {} nodes",
            u.len(),
            self.nodal.len()
        );
        let base = SharedMut(u.as_mut_ptr() as *mut f64);
        let nodal = SharedMut(self.nodal.as_mut_ptr() as *mut f64);
        // SAFETY: u and nodal hold N vectors (asserted, `new`) and are borrowed mutably here.
        // Items write disjoint f64s: items of different components write different components,
        // and items of one component are different groups, whose rows of Phi and columns of V
        // share no node (`independent_groups`). Each item's arithmetic is fixed, so the result
        // does not depend on which thread runs it.
        let correct = |it: &mut Item| unsafe { it.correct(base.get(), nodal.get(), tau, alpha) };
        match self.items.len() {
            0 => {}
            1 => keep_warm(|| correct(&mut self.items[0])),
            len => {
                // Two halves of the items (the two end faces of a cylinder), each on its own
                // thread; whichever finishes first spins until the other does, so neither
                // worker falls asleep before the next step's point stage.
                let (a, b) = self.items.split_at_mut(len / 2);
                let done = AtomicBool::new(false);
                rayon::join(
                    || {
                        a.iter_mut().for_each(correct);
                        done.store(true, Ordering::Release);
                    },
                    || {
                        b.iter_mut().for_each(correct);
                        while !done.load(Ordering::Acquire) {
                            std::hint::spin_loop();
                        }
                    },
                );
            }
        }
    }

    fn reaction(&self, b: usize) -> Vector3<f64> {
        if let Some(r) = &self.static_reactions {
            return r.get(b).copied().unwrap_or_else(Vector3::zeros);
        }
        let mut r = Vector3::zeros();
        if b >= self.num_boundaries {
            return r;
        }
        for c in self.comps() {
            r[c.corr.component()] += c.corr.constraint_force(&c.columns[b], self.alpha);
        }
        r
    }

    fn work(&self, u_next: &[Vector3<f64>], u_prev: &[Vector3<f64>]) -> f64 {
        // In ascending node order, like a sum over all nodes whose other terms are zero.
        self.forced
            .iter()
            .map(|&j| {
                let j = j as usize;
                self.nodal[j].dot(&(u_next[j] - u_prev[j])) * 0.5
            })
            .sum()
    }

    fn set_values(&mut self, boundaries: &[Boundary]) -> Result<()> {
        if boundaries.len() != self.num_boundaries {
            return Err(crate::Error::input(InputKind::Discretization, format!(
                "the meshless corrections were built for {} boundaries, not {}; prepare the model again",
                self.num_boundaries,
                boundaries.len()
            )));
        }
        for it in self.items.iter_mut() {
            for c in it.comps.iter_mut() {
                let comp = c.corr.component();
                for (m, &(b, k)) in c.sources.iter().enumerate() {
                    let bd = &boundaries[b];
                    c.amplitude[m] = bd.value(k, comp).ok_or_else(|| {
                        crate::Error::input(
                            InputKind::Discretization,
                            format!(
                            "boundary '{}': component {} is no longer prescribed; its meshless \
                             correction was built for it: prepare the model again",
                            bd.name,
                            ["x", "y", "z"][comp]
                        ),
                        )
                    })?;
                    c.curve[m] = bd.curve.clone();
                }
            }
        }
        Ok(())
    }

    fn linear_constraints(&self, tau: f64) -> Option<Vec<crate::solver::LinearConstraint>> {
        let mut out = Vec::new();
        for c in self.comps() {
            for (k, &(b, _)) in c.sources.iter().enumerate() {
                out.push(crate::solver::LinearConstraint {
                    row: c.corr.phi_row(k),
                    spread: (!c.corr.is_lumped()).then(|| c.corr.v_column(k)),
                    axis: c.corr.component(),
                    target: c.amplitude[k] * c.curve[k].value(tau),
                    boundary: b,
                });
            }
        }
        Some(out)
    }

    fn set_reactions(&mut self, per_boundary: &[Vector3<f64>]) {
        self.static_reactions = Some(per_boundary.to_vec());
    }

    fn touched(&self) -> &[u32] {
        // The correction adds M^-1 V y, which reaches exactly the row nodes of V.
        &self.forced
    }

    fn window(&self) -> Option<Vec<u32>> {
        let mut w: Vec<u32> = self
            .comps()
            .flat_map(|c| c.corr.touched_nodes())
            .chain(self.forced.iter().copied())
            .collect();
        w.sort_unstable();
        w.dedup();
        Some(w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 4 x 4 x 6 lattice (spacing 1 m) with Shepard shape functions of radius 1.5 m: the
    /// bottom (z = 0) and top (z = 5) layers reach disjoint nodes.
    fn lattice() -> (
        Vec<Vector3<f64>>,
        impl Fn(&Vector3<f64>) -> Result<SparseRow>,
    ) {
        let nodes: Vec<Vector3<f64>> = (0..6)
            .flat_map(|z| (0..4).flat_map(move |y| (0..4).map(move |x| (x, y, z))))
            .map(|(x, y, z)| Vector3::new(x as f64, y as f64, z as f64))
            .collect();
        let pos = nodes.clone();
        let shape = move |x: &Vector3<f64>| -> Result<SparseRow> {
            let w: Vec<(u32, f64)> = pos
                .iter()
                .enumerate()
                .filter_map(|(j, p)| {
                    let d = (p - x).norm() / 1.5;
                    (d < 1.0).then_some((j as u32, (1.0 - d) * (1.0 - d)))
                })
                .collect();
            let sum: f64 = w.iter().map(|e| e.1).sum();
            Ok(w.into_iter().map(|(j, v)| (j, v / sum)).collect())
        };
        (nodes, shape)
    }

    /// The lattice's bottom layer fixed in x, y, z and its top layer moved in z (-0.1 m) and
    /// held in x.
    fn faces(nodes: &[Vector3<f64>]) -> [Boundary; 2] {
        let on = |z: f64| -> Vec<usize> { (0..nodes.len()).filter(|&i| nodes[i].z == z).collect() };
        [
            Boundary::uniform("bottom", on(0.0), [Some(0.0); 3], LoadCurve::Smooth),
            boundary("top", on(5.0), Some(-0.1)),
        ]
    }

    fn random_field(n: usize, mut seed: u64) -> Vec<Vector3<f64>> {
        let mut r = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        (0..n).map(|_| Vector3::new(r(), r(), r()) * 1e-3).collect()
    }

    #[test]
    fn groups_join_constrained_nodes_through_shared_nodes_only() {
        let row = |ids: &[u32]| -> SparseRow { ids.iter().map(|&j| (j, 1.0)).collect() };
        // 0 and 2 meet at node 5 through Phi; 1 and 3 at node 8 through V (only); 4 is alone.
        let phi = vec![row(&[0, 5]), row(&[1]), row(&[5, 6]), row(&[7]), row(&[9])];
        let v = vec![row(&[0]), row(&[1, 8]), row(&[6]), row(&[7, 8]), row(&[9])];
        assert_eq!(
            independent_groups(10, &phi, &v),
            vec![vec![0, 2], vec![1, 3], vec![4]]
        );
    }

    #[test]
    fn grouped_correction_matches_one_system_on_any_thread_count() {
        let (nodes, shape) = lattice();
        // x and z have two groups each.
        let b = faces(&nodes);
        let on = |z: f64| -> Vec<usize> { (0..nodes.len()).filter(|&i| nodes[i].z == z).collect() };
        let mass: Vec<f64> = (0..nodes.len()).map(|i| 1.0 + 0.01 * i as f64).collect();
        let u0 = random_field(nodes.len(), 99);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let (mut corr, _) = MeshlessCorrector::from_parts(
                    &nodes,
                    &[],
                    &shape,
                    &b,
                    &mass,
                    Imposition::Sebciem,
                )
                .unwrap();
                // Bottom: x, y, z in one solve; top: x and z in another.
                assert_eq!(corr.items.len(), 2);
                let mut u = u0.clone();
                corr.correct(&mut u, 0.5, 1e-6);
                let r: Vec<Vector3<f64>> = (0..2).map(|k| corr.reaction(k)).collect();
                (u, r, corr.nodal.clone())
            })
        };
        let one = run(1);
        for threads in [2, 3] {
            assert!(run(threads) == one, "{threads} threads differ from one");
        }
        // The same as one system per component over all its constrained nodes.
        let mut want = u0.clone();
        let top_z = -0.1 * LoadCurve::Smooth.value(0.5);
        for c in 0..3 {
            let mut ids: Vec<usize> = on(0.0);
            if c != 1 {
                ids.extend(on(5.0));
            }
            let rows: Vec<SparseRow> = ids.iter().map(|&i| shape(&nodes[i]).unwrap()).collect();
            let target: Vec<f64> = ids
                .iter()
                .map(|&i| {
                    if c == 2 && nodes[i].z == 5.0 {
                        top_z
                    } else {
                        0.0
                    }
                })
                .collect();
            let mut full = ComponentCorrection::sebciem(c, ids, rows, &mass).unwrap();
            full.correct(&mut want, &target);
        }
        let err = one
            .0
            .iter()
            .zip(&want)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).norm()));
        assert!(
            err < 1e-15,
            "grouped and whole corrections differ by {err:e} m"
        );
    }

    fn boundary(name: &str, nodes: Vec<usize>, z: Option<f64>) -> Boundary {
        Boundary::uniform(name, nodes, [Some(0.0), None, z], LoadCurve::Smooth)
    }

    #[test]
    fn essential_triangles_lie_on_one_boundary() {
        // Nodes 0-2 on the top, 3-5 on the bottom, 6 free; [0, 3, 4] joins both faces across
        // the free surface between them and carries no boundary force.
        let b = [
            boundary("top", vec![0, 1, 2], Some(-0.02)),
            boundary("bottom", vec![3, 4, 5], None),
        ];
        let tris = [[0, 1, 2], [3, 4, 5], [0, 3, 4], [0, 1, 6]];
        assert_eq!(
            essential_triangles(&tris, &b, 0, 7),
            vec![[0, 1, 2], [3, 4, 5]]
        );
        // Only "top" constrains z.
        assert_eq!(essential_triangles(&tris, &b, 2, 7), vec![[0, 1, 2]]);
        assert!(essential_triangles(&tris, &b, 1, 7).is_empty());
    }

    #[test]
    fn correction_changes_only_the_nodes_it_reports_as_touched() {
        // The two middle layers lie outside every constrained node's support.
        let (nodes, shape) = lattice();
        let b = faces(&nodes);
        let mass = vec![1.0; nodes.len()];
        let (mut corr, _) =
            MeshlessCorrector::from_parts(&nodes, &[], &shape, &b, &mass, Imposition::Sebciem)
                .unwrap();
        let touched = corr.touched().to_vec();
        assert!(
            touched.windows(2).all(|w| w[0] < w[1]),
            "ascending, no repeats"
        );
        let u0 = random_field(nodes.len(), 12345);
        let mut u = u0.clone();
        corr.correct(&mut u, 1.0, 1e-6);
        let mut moved = 0;
        for (i, (a, b)) in u.iter().zip(&u0).enumerate() {
            if touched.binary_search(&(i as u32)).is_ok() {
                moved += usize::from(a != b);
            } else {
                assert_eq!(a, b, "node {i} changed but is not reported as touched");
            }
        }
        assert!(
            moved > 0 && touched.len() < nodes.len(),
            "{moved} moved, {} touched",
            touched.len()
        );
    }
}
