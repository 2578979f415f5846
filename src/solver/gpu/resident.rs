//! The run's state on the device and the launches of one step.

use std::ffi::c_void;

use nalgebra::Vector3;

use super::{Arg, Backend, Kernel, Tables, BLOCK};
use crate::memory::Size;
use crate::{Error, InputKind, Result};

/// What the host reads back after a step: the smallest J and its point, the largest change
/// in the step and the largest displacement (m) over the nodes (predict.rs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepScalars {
    pub min_j: f64,
    pub p_min: usize,
    pub max_du: f64,
    pub max_u: f64,
}

/// Device addresses of the tables.
#[derive(Debug, Clone, Copy, Default)]
struct Addr {
    offsets: u64,
    nodes: u64,
    dphi: u64,
    weights: u64,
    mode: u64,
    aux: u64,
    point_mat: u64,
    mu: u64,
    kappa: u64,
    hg: u64,
    anp_list: u64,
    anp_off: u64,
    anp_pts: u64,
    anp_w: u64,
    inv_w: u64,
    pkey: u64,
    groups: u64,
    group_first: u64,
    gpoint: u64,
    ggroup: u64,
    group_t: u64,
    ent_off: u64,
    con_off: u64,
    pos: u64,
    mass: u64,
    mask: u64,
    dofs: u64,
    // State and scratch.
    f: u64,
    slot_force: u64,
    point_j: u64,
    node_j: u64,
    node_p: u64,
    gf: u64,
    gs: u64,
    gpk: u64,
    group_j: u64,
    blk_j: u64,
    blk_p: u64,
    narrow: u64,
    wide: u64,
    blk_du: u64,
    blk_u: u64,
    out: u64,
    amp: u64,
    dof_curve: u64,
    curve_more: u64,
    f_ext: u64,
    entry_force: u64,
    window: u64,
    win_buf: u64,
}

/// The model and the run's state resident on a device ([`super`]).
pub struct Resident {
    dev: Box<dyn Backend>,
    a: Addr,
    /// The three displacement buffers; `cur` = (u(n-1), u(n), u(n+1)) as indices into them.
    u: [u64; 3],
    cur: [usize; 3],
    n: u32,
    n_narrow: u32,
    n_wide: u32,
    n_anp: u32,
    n_pressure: u32,
    n_groups: u32,
    n_in_groups: u32,
    n_dofs: u32,
    n_entries: u32,
    /// The window's nodes (ascending; [`Self::set_window`]).
    window: Vec<u32>,
    /// [`StepScalars`] and the prescribed DOFs' work terms of the last step, as downloaded.
    out: Vec<f64>,
    /// Host copy of the window's packed values.
    win_host: Vec<f64>,
    /// The prescribed DOFs' distinct load curves and their values at the last step.
    curves: Vec<crate::bc::LoadCurve>,
    curve_values: Vec<f64>,
    profile: Option<Profile>,
}

/// Where device time goes (`HYTLED_GPU_PROFILE=1`): each launch and copy waits for the device
/// and is timed on the host, per kernel or copy; printed to stderr when the run ends. The
/// waits slow the run down: the figures are shares, not the run's speed.
#[derive(Default)]
struct Profile {
    seconds: std::collections::BTreeMap<&'static str, (f64, u64)>,
}

fn bytes<T: Copy>(v: &[T]) -> &[u8] {
    // SAFETY: plain numbers (u32, f64) reinterpreted as their bytes.
    unsafe { std::slice::from_raw_parts(v.as_ptr() as *const u8, std::mem::size_of_val(v)) }
}

fn bytes_mut<T: Copy>(v: &mut [T]) -> &mut [u8] {
    // SAFETY: as `bytes`; every bit pattern is a valid f64.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr() as *mut u8, std::mem::size_of_val(v)) }
}

fn blocks(n: u32) -> u32 {
    n.div_ceil(BLOCK).max(1)
}

/// Blocks of the wide point kernel (a warp per point), none for no points.
fn wide_blocks(n: u32) -> u32 {
    n.div_ceil(BLOCK / 32)
}

impl Resident {
    /// Copies `t` to the device `dev`, after checking that it fits in the device's free memory.
    pub fn new(mut dev: Box<dyn Backend>, t: &Tables) -> Result<Self> {
        let need = t.device_bytes();
        if let Some(free) = dev.free_memory() {
            if need > free {
                return Err(Error::input(
                    InputKind::Limit,
                    format!(
                        "--device gpu: the model needs {} of GPU memory and {} has {} free; use a \
                     coarser discretization, a GPU with more memory, or --device cpu",
                        Size(need as f64),
                        dev.describe(),
                        Size(free as f64)
                    ),
                ));
            }
        }
        let mut up = |v: &[u8]| -> Result<u64> {
            let p = dev.alloc(v.len().max(8))?;
            if !v.is_empty() {
                dev.upload(p, v)?;
            }
            Ok(p)
        };
        let n = t.num_nodes;
        let np = t.weights.len();
        let mut a = Addr {
            offsets: up(bytes(&t.offsets))?,
            narrow: up(bytes(&t.narrow))?,
            wide: up(bytes(&t.wide))?,
            nodes: up(bytes(&t.nodes))?,
            dphi: up(bytes(&t.dphi))?,
            weights: up(bytes(&t.weights))?,
            mode: up(bytes(&t.mode))?,
            aux: up(bytes(&t.aux))?,
            point_mat: up(bytes(&t.point_mat))?,
            mu: up(bytes(&t.mu))?,
            kappa: up(bytes(&t.kappa))?,
            hg: up(bytes(&t.hg))?,
            anp_list: up(bytes(&t.anp_list))?,
            anp_off: up(bytes(&t.anp_off))?,
            anp_pts: up(bytes(&t.anp_pts))?,
            anp_w: up(bytes(&t.anp_w))?,
            inv_w: up(bytes(&t.inv_w))?,
            pkey: up(bytes(&t.pkey))?,
            groups: up(bytes(&t.groups))?,
            group_first: up(bytes(&t.group_first))?,
            gpoint: up(bytes(&t.gpoint))?,
            ggroup: up(bytes(&t.ggroup))?,
            ent_off: up(bytes(&t.ent_off))?,
            con_off: up(bytes(&t.con_off))?,
            pos: up(bytes(&t.pos))?,
            mass: up(bytes(&t.mass))?,
            // Set by set_mask for each pass (with the late nodes).
            mask: up(bytes(&vec![0u32; n]))?,
            dofs: up(bytes(&t.dofs))?,
            ..Default::default()
        };
        a.amp = up(bytes(&t.amp))?;
        a.dof_curve = up(bytes(&t.dof_curve))?;
        // Initial values as the CPU evaluator's: J = 1, pressure 0.
        let npn = t.inv_w.len();
        a.node_j = up(bytes(&vec![1.0f64; npn]))?;
        a.node_p = up(bytes(&vec![0.0f64; npn]))?;
        let mut zeros = |count: usize| -> Result<u64> {
            let p = dev.alloc((8 * count).max(8))?;
            let z = vec![0u8; 8 * count];
            if count > 0 {
                dev.upload(p, &z)?;
            }
            Ok(p)
        };
        a.f = zeros(3 * n)?;
        a.slot_force = zeros(3 * t.nodes.len())?;
        a.point_j = zeros(np)?;
        a.gf = zeros(9 * t.in_groups)?;
        a.gs = zeros(3 * t.in_groups)?;
        a.gpk = zeros(9 * t.in_groups)?;
        a.group_j = zeros(t.groups.len() / 2)?;
        a.group_t = zeros(t.groups.len() / 2)?;
        // The min-J partials: the narrow kernel's blocks, then the wide kernel's.
        let (n_narrow, n_wide) = (t.narrow.len() as u32, t.wide.len() as u32);
        let bp = (blocks(n_narrow) + wide_blocks(n_wide)) as usize;
        let bn = blocks(n as u32) as usize;
        a.blk_j = zeros(bp)?;
        a.blk_p = zeros(bp)?;
        a.blk_du = zeros(bn)?;
        a.blk_u = zeros(bn)?;
        a.curve_more = zeros(t.curves.len())?;
        a.f_ext = zeros(3 * n)?;
        let n_entries = t.con_off.len() - 1;
        a.entry_force = zeros(3 * n_entries)?;
        a.out = zeros(4 + t.dofs.len())?;
        let u = [zeros(3 * n)?, zeros(3 * n)?, zeros(3 * n)?];
        Ok(Resident {
            dev,
            a,
            u,
            cur: [0, 1, 2],
            n: n as u32,
            n_narrow,
            n_wide,
            n_anp: t.anp_list.len() as u32,
            n_pressure: npn as u32,
            n_groups: (t.groups.len() / 2) as u32,
            n_in_groups: t.in_groups as u32,
            n_dofs: t.dofs.len() as u32,
            n_entries: n_entries as u32,
            window: Vec::new(),
            out: vec![0.0; 4 + t.dofs.len()],
            win_host: Vec::new(),
            curves: t.curves.clone(),
            curve_values: Vec::new(),
            profile: std::env::var_os("HYTLED_GPU_PROFILE").map(|_| Profile::default()),
        })
    }

    /// The device, in words.
    pub fn describe(&self) -> String {
        self.dev.describe()
    }

    fn launch(&mut self, k: Kernel, grid: u32, args: &[Arg]) -> Result<()> {
        if self.profile.is_some() {
            self.dev.synchronize()?;
        }
        let t0 = std::time::Instant::now();
        self.launch_now(k, grid, args)?;
        if let Some(p) = self.profile.as_mut() {
            self.dev.synchronize()?;
            let e = p.seconds.entry(Kernel::NAMES[k as usize]).or_default();
            e.0 += t0.elapsed().as_secs_f64();
            e.1 += 1;
        }
        Ok(())
    }

    /// Whether `HYTLED_GPU_PROFILE` is set.
    pub fn profiling(&self) -> bool {
        self.profile.is_some()
    }

    /// Adds `secs` of host work to the profile under `what`.
    pub fn note(&mut self, what: &'static str, secs: f64) {
        if let Some(p) = self.profile.as_mut() {
            let e = p.seconds.entry(what).or_default();
            e.0 += secs;
            e.1 += 1;
        }
    }

    /// Times a copy when profiling.
    fn timed<T>(
        &mut self,
        what: &'static str,
        f: impl FnOnce(&mut Self) -> Result<T>,
    ) -> Result<T> {
        if self.profile.is_some() {
            self.dev.synchronize()?;
        }
        let t0 = std::time::Instant::now();
        let r = f(self)?;
        if let Some(p) = self.profile.as_mut() {
            self.dev.synchronize()?;
            let e = p.seconds.entry(what).or_default();
            e.0 += t0.elapsed().as_secs_f64();
            e.1 += 1;
        }
        Ok(r)
    }

    /// Launches without allocating (the time loop allocates nothing per step): the argument
    /// values and their addresses live on the stack.
    fn launch_now(&mut self, k: Kernel, grid: u32, args: &[Arg]) -> Result<()> {
        const MAX_ARGS: usize = 32;
        assert!(
            args.len() <= MAX_ARGS,
            "{} arguments for {:?}",
            args.len(),
            k
        );
        let mut vals = [Arg::U32(0); MAX_ARGS];
        vals[..args.len()].copy_from_slice(args);
        let mut params = [std::ptr::null_mut::<c_void>(); MAX_ARGS];
        for (p, a) in params.iter_mut().zip(vals.iter_mut()) {
            *p = match a {
                Arg::Ptr(p) => p as *mut u64 as *mut c_void,
                Arg::U32(v) => v as *mut u32 as *mut c_void,
                Arg::F64(v) => v as *mut f64 as *mut c_void,
            };
        }
        self.dev.launch(k, grid, &mut params[..args.len()])
    }

    /// Sets u(n-1), u(n), u(n+1) (m).
    pub fn set_state(
        &mut self,
        u_prev: &[Vector3<f64>],
        u: &[Vector3<f64>],
        u_next: &[Vector3<f64>],
    ) -> Result<()> {
        self.cur = [0, 1, 2];
        for (k, v) in [u_prev, u, u_next].into_iter().enumerate() {
            let flat: &[f64] = vector_flat(v);
            self.dev.upload(self.u[k], bytes(flat))?;
        }
        Ok(())
    }

    /// Sets the constrained components (`mask`) and the late nodes (`late`: corrections
    /// move them after the update, so the update leaves them out of its largest change).
    pub fn set_mask(&mut self, mask: &[[bool; 3]], late: &[bool]) -> Result<()> {
        let words: Vec<u32> = mask
            .iter()
            .zip(late)
            .map(|(m, &l)| m[0] as u32 | (m[1] as u32) << 1 | (m[2] as u32) << 2 | (l as u32) << 3)
            .collect();
        self.dev.upload(self.a.mask, bytes(&words))
    }

    /// Sets u(n+1) (m): the host's corrections of the step.
    pub fn upload_next(&mut self, u_next: &[Vector3<f64>]) -> Result<()> {
        let dst = self.u[self.cur[2]];
        self.timed("copy u(n+1) to device", |r| {
            r.dev.upload(dst, bytes(vector_flat(u_next)))
        })
    }

    /// Sets the window: the nodes whose values the host's corrections read or write
    /// ([`Self::download_window`], [`Self::upload_window`]), ascending.
    pub fn set_window(&mut self, nodes: &[u32]) -> Result<()> {
        self.window = nodes.to_vec();
        self.win_host = vec![0.0; 12 * nodes.len()];
        let bytes_w = bytes(nodes);
        let w = self.dev.alloc(bytes_w.len().max(8))?;
        if !nodes.is_empty() {
            self.dev.upload(w, bytes_w)?;
        }
        self.a.window = w;
        self.a.win_buf = self.dev.alloc((8 * 12 * nodes.len()).max(8))?;
        Ok(())
    }

    /// The window's u(n+1), u(n), u(n-1) and f into the host copies (their other entries are
    /// left as they are).
    pub fn download_window(
        &mut self,
        u_next: &mut [Vector3<f64>],
        u: &mut [Vector3<f64>],
        u_prev: &mut [Vector3<f64>],
        f: &mut [Vector3<f64>],
    ) -> Result<()> {
        let nw = self.window.len();
        if nw == 0 {
            return Ok(());
        }
        let a = self.a;
        let [up, uc, un] = self.cur.map(|k| Arg::Ptr(self.u[k]));
        self.launch(
            Kernel::WindowGather,
            blocks(nw as u32),
            &[
                Arg::U32(nw as u32),
                Arg::Ptr(a.window),
                un,
                uc,
                up,
                Arg::Ptr(a.f),
                Arg::Ptr(a.win_buf),
            ],
        )?;
        let mut host = std::mem::take(&mut self.win_host);
        self.timed("copy window to host", |r| {
            r.dev.download(bytes_mut(&mut host), a.win_buf)
        })?;
        for (k, &i) in self.window.iter().enumerate() {
            let i = i as usize;
            for (q, target) in [&mut *u_next, &mut *u, &mut *u_prev, &mut *f]
                .into_iter()
                .enumerate()
            {
                let o = 3 * (q * nw + k);
                target[i] = Vector3::new(host[o], host[o + 1], host[o + 2]);
            }
        }
        self.win_host = host;
        Ok(())
    }

    /// The window's u(n+1) from the host copy back to the device.
    pub fn upload_window(&mut self, u_next: &[Vector3<f64>]) -> Result<()> {
        let nw = self.window.len();
        if nw == 0 {
            return Ok(());
        }
        let mut host = std::mem::take(&mut self.win_host);
        for (k, &i) in self.window.iter().enumerate() {
            host[3 * k..3 * k + 3].copy_from_slice(u_next[i as usize].as_slice());
        }
        let a = self.a;
        self.timed("copy window to device", |r| {
            r.dev.upload(a.win_buf, bytes(&host[..3 * nw]))
        })?;
        self.win_host = host;
        let un = Arg::Ptr(self.u[self.cur[2]]);
        self.launch(
            Kernel::WindowScatter,
            blocks(nw as u32),
            &[
                Arg::U32(nw as u32),
                Arg::Ptr(a.window),
                Arg::Ptr(a.win_buf),
                un,
            ],
        )
    }

    /// Copies u(n-1), u(n) or u(n+1) (`which` = 0, 1, 2) into `out`.
    pub fn download_u(&mut self, which: usize, out: &mut [Vector3<f64>]) -> Result<()> {
        let src = self.u[self.cur[which]];
        self.timed("copy u to host", |r| {
            r.dev.download(bytes_mut(vector_flat_mut(out)), src)
        })
    }

    /// The point stage at u(n): ANP pressures, group stresses, every point's slot forces and J.
    pub fn points(&mut self) -> Result<()> {
        let a = self.a;
        let u = Arg::Ptr(self.u[self.cur[1]]);
        if self.n_anp > 0 {
            self.launch(
                Kernel::AnpPointJ,
                blocks(self.n_anp),
                &[
                    Arg::U32(self.n_anp),
                    Arg::Ptr(a.anp_list),
                    Arg::Ptr(a.offsets),
                    Arg::Ptr(a.nodes),
                    Arg::Ptr(a.dphi),
                    u,
                    Arg::Ptr(a.point_j),
                ],
            )?;
            self.launch(
                Kernel::AnpNodes,
                blocks(self.n_pressure),
                &[
                    Arg::U32(self.n_pressure),
                    Arg::Ptr(a.anp_off),
                    Arg::Ptr(a.anp_pts),
                    Arg::Ptr(a.anp_w),
                    Arg::Ptr(a.inv_w),
                    Arg::Ptr(a.point_mat),
                    Arg::Ptr(a.kappa),
                    Arg::Ptr(a.point_j),
                    Arg::Ptr(a.node_j),
                    Arg::Ptr(a.node_p),
                ],
            )?;
        }
        if self.n_groups > 0 {
            for phase in 0..5u32 {
                let n = if phase % 2 == 1 {
                    self.n_groups
                } else {
                    self.n_in_groups
                };
                self.launch(
                    Kernel::GroupStress,
                    blocks(n),
                    &[
                        Arg::U32(phase),
                        Arg::U32(n),
                        Arg::Ptr(a.groups),
                        Arg::Ptr(a.group_first),
                        Arg::Ptr(a.gpoint),
                        Arg::Ptr(a.ggroup),
                        Arg::Ptr(a.offsets),
                        Arg::Ptr(a.nodes),
                        Arg::Ptr(a.dphi),
                        Arg::Ptr(a.weights),
                        Arg::Ptr(a.point_mat),
                        Arg::Ptr(a.mu),
                        Arg::Ptr(a.kappa),
                        u,
                        Arg::Ptr(a.gf),
                        Arg::Ptr(a.gs),
                        Arg::Ptr(a.gpk),
                        Arg::Ptr(a.group_j),
                        Arg::Ptr(a.group_t),
                    ],
                )?;
            }
        }
        let nb = self.point_blocks() - wide_blocks(self.n_wide);
        if self.n_narrow > 0 {
            #[rustfmt::skip]
            let args = [
                Arg::U32(self.n_narrow), Arg::Ptr(a.narrow),
                Arg::Ptr(a.offsets), Arg::Ptr(a.nodes), Arg::Ptr(a.dphi), Arg::Ptr(a.weights),
                Arg::Ptr(a.mode), Arg::Ptr(a.aux), Arg::Ptr(a.point_mat), Arg::Ptr(a.mu),
                Arg::Ptr(a.kappa), Arg::Ptr(a.hg), Arg::Ptr(a.node_p), Arg::Ptr(a.pkey),
                Arg::Ptr(a.gpk), Arg::Ptr(a.gs), u, Arg::Ptr(a.pos), Arg::Ptr(a.slot_force),
                Arg::Ptr(a.point_j), Arg::Ptr(a.blk_j), Arg::Ptr(a.blk_p),
            ];
            self.launch(Kernel::PointForces, nb, &args)?;
        }
        if self.n_wide > 0 {
            // The wide kernel's min-J partials follow the narrow one's.
            #[rustfmt::skip]
            let args = [
                Arg::U32(self.n_wide), Arg::Ptr(a.wide), Arg::U32((self.n_anp > 0) as u32),
                Arg::Ptr(a.offsets), Arg::Ptr(a.nodes), Arg::Ptr(a.dphi), Arg::Ptr(a.weights),
                Arg::Ptr(a.mode), Arg::Ptr(a.aux), Arg::Ptr(a.point_mat), Arg::Ptr(a.mu),
                Arg::Ptr(a.kappa), Arg::Ptr(a.node_p), Arg::Ptr(a.pkey), Arg::Ptr(a.gpk),
                Arg::Ptr(a.gs), u, Arg::Ptr(a.pos), Arg::Ptr(a.slot_force), Arg::Ptr(a.point_j),
                Arg::Ptr(a.blk_j + 8 * nb as u64), Arg::Ptr(a.blk_p + 4 * nb as u64),
            ];
            self.launch(Kernel::PointForcesWide, wide_blocks(self.n_wide), &args)?;
        }
        self.launch(
            Kernel::EntrySums,
            blocks(self.n_entries),
            &[
                Arg::U32(self.n_entries),
                Arg::Ptr(a.con_off),
                Arg::Ptr(a.slot_force),
                Arg::Ptr(a.entry_force),
            ],
        )
    }

    /// The min-J partials the point kernels write.
    fn point_blocks(&self) -> u32 {
        let nb = if self.n_narrow > 0 {
            blocks(self.n_narrow)
        } else {
            0
        };
        nb + wide_blocks(self.n_wide)
    }

    /// The smallest J of the last point stage and its point.
    pub fn min_j(&mut self) -> Result<(f64, usize)> {
        let s = self.reduce(false, false)?;
        Ok((s.min_j, s.p_min))
    }

    /// The step's scalars (with the update's partials where `with_update`) and, with `terms`
    /// = (kind, dt, dt_prev), the prescribed DOFs' work terms and largest u(n+1) (see
    /// dof_terms in the kernels): one download.
    fn reduce(&mut self, with_update: bool, terms: bool) -> Result<StepScalars> {
        let a = self.a;
        let nu = if with_update { blocks(self.n) } else { 0 };
        let nd = if terms { self.n_dofs } else { 0 };
        let un = Arg::Ptr(self.u[self.cur[2]]);
        self.launch(
            Kernel::FinishReduce,
            1,
            &[
                Arg::U32(self.point_blocks()),
                Arg::Ptr(a.blk_j),
                Arg::Ptr(a.blk_p),
                Arg::U32(nu),
                Arg::Ptr(a.blk_du),
                Arg::Ptr(a.blk_u),
                Arg::U32(nd),
                Arg::Ptr(a.dofs),
                un,
                Arg::Ptr(a.out),
            ],
        )?;
        let mut out = std::mem::take(&mut self.out);
        let len = 4 + nd as usize;
        self.timed("copy step scalars to host", |r| {
            r.dev.download(bytes_mut(&mut out[..len]), a.out)
        })?;
        self.out = out;
        let o = &self.out;
        Ok(StepScalars {
            min_j: o[0],
            p_min: if o[1] >= u32::MAX as f64 {
                usize::MAX
            } else {
                o[1] as usize
            },
            max_du: o[2],
            max_u: o[3],
        })
    }

    /// The prescribed DOFs' work terms of the last [`Self::update`] with terms, J.
    pub fn dof_terms(&self) -> &[f64] {
        &self.out[4..4 + self.n_dofs as usize]
    }

    /// The nodal forces of the last point stage into `f` (N), kept on the device for the
    /// update.
    pub fn gather(&mut self, f: &mut [Vector3<f64>]) -> Result<()> {
        let a = self.a;
        self.launch(
            Kernel::NodeForces,
            blocks(self.n),
            &[
                Arg::U32(self.n),
                Arg::Ptr(a.ent_off),
                Arg::Ptr(a.entry_force),
                Arg::Ptr(a.f),
            ],
        )?;
        self.download_f(f)
    }

    /// The nodal forces on the device (of the last update or gather) into `f`, N.
    pub fn download_f(&mut self, f: &mut [Vector3<f64>]) -> Result<()> {
        let src = self.a.f;
        self.timed("copy f to host", |r| {
            r.dev.download(bytes_mut(vector_flat_mut(f)), src)
        })
    }

    /// One update to u(n+1) with coefficients (A, B, C) (nodal sums first unless `gathered`),
    /// net of `f_ext` (N) where given, then the prescribed values at load fraction `tau`, and
    /// the step's scalars; with `terms` = (kind, dt, dt_prev) also the prescribed
    /// DOFs' work terms ([`Self::dof_terms`]) and their u(n+1) in the largest displacement.
    pub fn update(
        &mut self,
        (ca, cb, cc): (f64, f64, f64),
        gathered: bool,
        tau: f64,
        f_ext: Option<&[Vector3<f64>]>,
        terms: Option<(u32, f64, f64)>,
    ) -> Result<StepScalars> {
        let a = self.a;
        let mut curve_values = std::mem::take(&mut self.curve_values);
        curve_values.clear();
        curve_values.extend(self.curves.iter().map(|c| c.value(tau)));
        if let Some(fe) = f_ext {
            self.timed("copy f_ext to device", |r| {
                r.dev.upload(a.f_ext, bytes(vector_flat(fe)))
            })?;
        }
        let [up, u, un] = self.cur.map(|k| Arg::Ptr(self.u[k]));
        self.launch(
            Kernel::Update,
            blocks(self.n),
            &[
                Arg::U32(self.n),
                Arg::U32(gathered as u32),
                Arg::Ptr(a.ent_off),
                Arg::Ptr(a.entry_force),
                Arg::Ptr(a.f),
                Arg::U32(f_ext.is_some() as u32),
                Arg::Ptr(a.f_ext),
                Arg::Ptr(a.mass),
                Arg::Ptr(a.mask),
                Arg::F64(ca),
                Arg::F64(cb),
                Arg::F64(cc),
                u,
                up,
                un,
                Arg::Ptr(a.blk_du),
                Arg::Ptr(a.blk_u),
            ],
        )?;
        if self.n_dofs > 0 {
            let c = |i: usize| Arg::F64(curve_values.get(i).copied().unwrap_or(0.0));
            if curve_values.len() > 4 {
                self.timed("copy curve values to device", |r| {
                    r.dev.upload(a.curve_more, bytes(&curve_values[4..]))
                })?;
            }
            let (kind, dt, dt_prev) = terms.unwrap_or((3, 0.0, 0.0));
            self.launch(
                Kernel::Dofs,
                blocks(self.n_dofs),
                &[
                    Arg::U32(self.n_dofs),
                    Arg::Ptr(a.dofs),
                    Arg::Ptr(a.amp),
                    Arg::Ptr(a.dof_curve),
                    c(0),
                    c(1),
                    c(2),
                    c(3),
                    Arg::Ptr(a.curve_more),
                    Arg::Ptr(a.mass),
                    Arg::Ptr(a.f),
                    un,
                    u,
                    up,
                    Arg::U32(kind),
                    Arg::F64(dt),
                    Arg::F64(dt_prev),
                    Arg::Ptr(a.out),
                ],
            )?;
        }
        self.curve_values = curve_values;
        self.reduce(true, terms.is_some())
    }

    /// After a step: u(n-1) <- u(n), u(n) <- u(n+1); the old u(n-1) becomes the next target.
    pub fn rotate(&mut self) {
        let [p, c, n] = self.cur;
        self.cur = [c, n, p];
    }
}

fn vector_flat(v: &[Vector3<f64>]) -> &[f64] {
    // SAFETY: Vector3<f64> is three contiguous f64 (nalgebra's array storage).
    unsafe { std::slice::from_raw_parts(v.as_ptr() as *const f64, 3 * v.len()) }
}

fn vector_flat_mut(v: &mut [Vector3<f64>]) -> &mut [f64] {
    // SAFETY: as `vector_flat`.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr() as *mut f64, 3 * v.len()) }
}

impl Drop for Resident {
    fn drop(&mut self) {
        if let Some(p) = &self.profile {
            let total: f64 = p.seconds.values().map(|v| v.0).sum();
            eprintln!("GPU profile (HYTLED_GPU_PROFILE; each launch and copy waited for):");
            eprintln!(
                "{:32} {:>8} {:>12} {:>10} {:>7}",
                "kernel or copy", "calls", "total (s)", "per call (us)", "share"
            );
            let mut rows: Vec<_> = p.seconds.iter().collect();
            rows.sort_by(|a, b| b.1 .0.total_cmp(&a.1 .0));
            for (name, (t, c)) in rows {
                eprintln!(
                    "{name:32} {c:>8} {t:>12.4} {:>10.1} {:>6.1} %",
                    1e6 * t / (*c).max(1) as f64,
                    100.0 * t / total.max(1e-300)
                );
            }
        }
    }
}
