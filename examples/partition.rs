//! The communication a distributed hytled would need (docs/scale.md): each mesh's node graph
//! partitioned into P parts by METIS (`METIS_PartGraphKway`, the partitioner the design names),
//! each rank owning its nodes and computing every element that touches one of them (the
//! gather kernel, duplicated at the cut), so one step exchanges only the displacements of the
//! ghost nodes those elements reach (3 f64 each). Prints, per mesh and P: the largest part,
//! the duplicated elements, the ghost nodes and bytes per step (total and the busiest rank)
//! and the most neighbours of a rank. Run from the repository root:
//!
//!     cargo run --release --example partition [MESH.msh ...] [--parts 2,4,8,16,64] [--tet10]
//!
//! (default: meshes/brain-indentation-c1.msh ... c5.msh; `--tet10` adds the edge mid-nodes
//! of each 4-node tetrahedron first, as `discretization.element = "tet10"` does).

use std::path::PathBuf;

use metis_sys::idx_t;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut meshes: Vec<PathBuf> = Vec::new();
    let mut parts: Vec<usize> = vec![2, 4, 8, 16, 64];
    let mut quadratic = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--tet10" {
            quadratic = true;
        } else if a == "--parts" {
            let list = args.next().ok_or("--parts needs a list, e.g. 2,4,8")?;
            parts = list
                .split(',')
                .map(|p| p.trim().parse::<usize>())
                .collect::<Result<_, _>>()?;
        } else {
            meshes.push(a.into());
        }
    }
    if meshes.is_empty() {
        meshes = (1..=5)
            .map(|k| format!("meshes/brain-indentation-c{k}.msh").into())
            .collect();
    }
    println!(
        "| mesh | nodes | elements | P | largest part (nodes) | duplicated elements | ghost nodes | \
         bytes per step (all) | bytes per step (busiest rank) | neighbours (most) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for path in &meshes {
        let input = hytled::io::mesh_file::read_mesh(path, None, 1.0)?;
        let mut cells: Vec<Vec<usize>> = (0..input.mesh.num_cells())
            .map(|e| input.mesh.cell(e).to_vec())
            .collect();
        let mut n = input.mesh.nodes.len();
        if quadratic {
            let mut mid = std::collections::HashMap::new();
            for c in cells.iter_mut().filter(|c| c.len() == 4) {
                for (a, b) in [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)] {
                    let key = (c[a].min(c[b]), c[a].max(c[b]));
                    let id = *mid.entry(key).or_insert_with(|| {
                        n += 1;
                        n - 1
                    });
                    c.push(id);
                }
            }
        }
        let ne = cells.len();
        // Node graph: nodes sharing an element.
        let mut adj: Vec<Vec<u32>> = vec![Vec::new(); n];
        for e in 0..ne {
            let c = &cells[e];
            for &a in c {
                for &b in c {
                    if a != b {
                        adj[a].push(b as u32);
                    }
                }
            }
        }
        let mut xadj: Vec<idx_t> = vec![0];
        let mut adjncy: Vec<idx_t> = Vec::new();
        for list in adj.iter_mut() {
            list.sort_unstable();
            list.dedup();
            adjncy.extend(list.iter().map(|&j| j as idx_t));
            xadj.push(adjncy.len() as idx_t);
        }
        // Elements touching each node.
        let mut touching: Vec<Vec<u32>> = vec![Vec::new(); n];
        for e in 0..ne {
            for &a in &cells[e] {
                touching[a].push(e as u32);
            }
        }
        for &p in &parts {
            let part = kway(n, &mut xadj, &mut adjncy, p)?;
            let mut owned = vec![0usize; p];
            for &r in &part {
                owned[r] += 1;
            }
            let (mut computed, mut ghosts, mut busiest, mut neighbours) = (0usize, 0usize, 0, 0);
            let mut mark_e = vec![u32::MAX; ne];
            let mut mark_n = vec![u32::MAX; n];
            let mut mark_r = vec![u32::MAX; p];
            let mut members: Vec<Vec<usize>> = vec![Vec::new(); p];
            for (i, &r) in part.iter().enumerate() {
                members[r].push(i);
            }
            for (r, nodes) in members.iter().enumerate() {
                let tag = r as u32;
                let (mut g, mut nb) = (0usize, 0usize);
                for &i in nodes {
                    for &e in &touching[i] {
                        if mark_e[e as usize] == tag {
                            continue;
                        }
                        mark_e[e as usize] = tag;
                        computed += 1;
                        for &j in &cells[e as usize] {
                            if part[j] != r && mark_n[j] != tag {
                                mark_n[j] = tag;
                                g += 1;
                                if mark_r[part[j]] != tag {
                                    mark_r[part[j]] = tag;
                                    nb += 1;
                                }
                            }
                        }
                    }
                }
                ghosts += g;
                busiest = busiest.max(g);
                neighbours = neighbours.max(nb);
            }
            println!(
                "| {} | {n} | {ne} | {p} | {} | {:.2} % | {ghosts} | {} | {} | {neighbours} |",
                path.file_name()
                    .map_or_else(String::new, |f| f.to_string_lossy().into()),
                owned.iter().max().copied().unwrap_or(0),
                100.0 * (computed as f64 / ne as f64 - 1.0),
                ghosts * 24,
                busiest * 24,
            );
        }
    }
    Ok(())
}

/// METIS_PartGraphKway of the CSR graph into `p` parts (deterministic: METIS's fixed seed).
fn kway(
    n: usize,
    xadj: &mut [idx_t],
    adjncy: &mut [idx_t],
    p: usize,
) -> Result<Vec<usize>, Box<dyn std::error::Error>> {
    if p <= 1 {
        return Ok(vec![0; n]);
    }
    let mut nvtxs = idx_t::try_from(n)?;
    let mut ncon: idx_t = 1;
    let mut nparts = idx_t::try_from(p)?;
    let mut objval: idx_t = 0;
    let mut part = vec![0 as idx_t; n];
    let mut options = [0 as idx_t; metis_sys::METIS_NOPTIONS as usize];
    // SAFETY: xadj (n + 1 offsets) and adjncy (vertices below n) are METIS's CSR graph; part
    // holds n entries, options METIS_NOPTIONS; null weights mean unit weights; METIS keeps
    // no pointer.
    let status = unsafe {
        metis_sys::METIS_SetDefaultOptions(options.as_mut_ptr());
        metis_sys::METIS_PartGraphKway(
            &mut nvtxs,
            &mut ncon,
            xadj.as_mut_ptr(),
            adjncy.as_mut_ptr(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            &mut nparts,
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            options.as_mut_ptr(),
            &mut objval,
            part.as_mut_ptr(),
        )
    };
    if status != metis_sys::rstatus_et_METIS_OK {
        return Err(format!("METIS_PartGraphKway failed ({status})").into());
    }
    Ok(part.into_iter().map(|r| r as usize).collect())
}
