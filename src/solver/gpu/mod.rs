//! The explicit time loop on an NVIDIA GPU (`--device gpu`, scene `solver.device = "gpu"`).
//!
//! The model's points, slots, masses and constraints are copied to the device once; the
//! displacements u(n-1), u(n), u(n+1), the internal forces and every per-point and per-node
//! scratch array stay there. Each step runs the point stage (ANP nodal pressures,
//! mean-dilatation group stresses, the point kernels: a thread per point of up to 8 slots, a
//! warp per larger point), the chunk entries' sums, the nodal sums fused with the
//! central-difference update, the prescribed values and their work terms, and one reduction;
//! the host reads back the step's four numbers and the work terms, and the fields only on the
//! steps that record a row or frame, estimate relaxation's rate or update the step. The
//! loop's logic (load steps, relaxation, divergence and inversion tests, messages) is the CPU's
//! ([`super::integrate`]) unchanged. EBCIEM / SEBCIEM corrections and contact run on the host
//! on copies of the nodes they touch ([`crate::solver::Corrector::window`]); loads and damping
//! on copies of the whole field.
//!
//! Same answers: the kernels ([`KERNELS`], compiled at run time by NVRTC with `--fmad=false`)
//! repeat the CPU's operations in the CPU's order, and each buffer entry of the CPU's force
//! chunks ([`super::chunks`]) is summed over its slots in the order the CPU adds them
//! ([`super::Forces::contribution_order`]), so forces, displacements, reactions and step
//! counts are bitwise the CPU's (tests/gpu.rs; the same kernels also run on the CPU through
//! [`emulate`], so the tests check them on machines without a GPU).
//!
//! Not on the GPU yet (the run stops at the start with a message saying so): materials other
//! than neo-Hookean, and damped dynamics together with corrections or contact.

#[cfg(feature = "gpu")]
mod cuda;
pub mod emulate;
mod resident;
mod tables;

pub use resident::{Resident, StepScalars};
pub use tables::Tables;

use std::ffi::c_void;

use crate::Result;

/// The kernels' CUDA C source.
pub const KERNELS: &str = include_str!("kernels.cu");

/// Threads per block of every kernel (BLOCK in the source).
pub const BLOCK: u32 = 256;

/// The kernels, in the order [`Kernel::NAMES`] lists them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(usize)]
pub enum Kernel {
    AnpPointJ,
    AnpNodes,
    GroupStress,
    PointForces,
    PointForcesWide,
    EntrySums,
    NodeForces,
    Update,
    Dofs,
    WindowGather,
    WindowScatter,
    FinishReduce,
}

impl Kernel {
    /// Every kernel.
    pub const ALL: [Kernel; 12] = [
        Kernel::AnpPointJ,
        Kernel::AnpNodes,
        Kernel::GroupStress,
        Kernel::PointForces,
        Kernel::PointForcesWide,
        Kernel::EntrySums,
        Kernel::NodeForces,
        Kernel::Update,
        Kernel::Dofs,
        Kernel::WindowGather,
        Kernel::WindowScatter,
        Kernel::FinishReduce,
    ];

    /// Function names in the source, indexed by the enum.
    pub const NAMES: [&'static str; 12] = [
        "anp_point_j",
        "anp_nodes",
        "group_stress",
        "point_forces",
        "point_forces_wide",
        "entry_sums",
        "node_forces",
        "update",
        "dofs",
        "window_gather",
        "window_scatter",
        "finish_reduce",
    ];

    /// Whether the kernel synchronizes the threads of a block (the emulator then runs a
    /// block's threads side by side).
    pub fn synchronizes(self) -> bool {
        matches!(
            self,
            Kernel::PointForces | Kernel::PointForcesWide | Kernel::Update | Kernel::FinishReduce
        )
    }
}

/// One kernel argument, passed by value.
#[derive(Debug, Clone, Copy)]
pub enum Arg {
    /// A device address.
    Ptr(u64),
    U32(u32),
    F64(f64),
}

/// Where the kernels run: a CUDA device, or the CPU emulation of the tests.
pub trait Backend: Send {
    /// Allocates `bytes` (at least 8) of device memory, 8-byte aligned; returns its address.
    fn alloc(&mut self, bytes: usize) -> Result<u64>;
    /// Copies `src` to device address `dst`, ordered before the launches that follow (it may
    /// complete later; `src` may be reused as soon as this returns).
    fn upload(&mut self, dst: u64, src: &[u8]) -> Result<()>;
    /// Copies device address `src` into `dst`, after all work launched before.
    fn download(&mut self, dst: &mut [u8], src: u64) -> Result<()>;
    /// Waits for all work launched so far.
    fn synchronize(&mut self) -> Result<()>;
    /// Launches `kernel` on `grid` blocks of [`BLOCK`] threads. `params[i]` points to the
    /// value of argument i.
    fn launch(&mut self, kernel: Kernel, grid: u32, params: &mut [*mut c_void]) -> Result<()>;
    /// Device memory free now, bytes (None: unknown).
    fn free_memory(&self) -> Option<usize>;
    /// The device, in words.
    fn describe(&self) -> String;
}

/// Whether `--device gpu` can run here: the driver and NVRTC load and the driver sees a GPU
/// (the errors of [`cuda`], without compiling the kernels).
pub fn probe() -> Result<()> {
    #[cfg(feature = "gpu")]
    {
        cuda::probe()
    }
    #[cfg(not(feature = "gpu"))]
    {
        cuda().map(|_| ())
    }
}

/// The CUDA device 0, with the kernels compiled for it; a clear error where there is no
/// driver, no NVRTC or no device.
pub fn cuda() -> Result<Box<dyn Backend>> {
    #[cfg(feature = "gpu")]
    {
        Ok(Box::new(cuda::Cuda::new()?))
    }
    #[cfg(not(feature = "gpu"))]
    {
        Err(crate::Error::input(
            crate::InputKind::Unsupported,
            "--device gpu: this hytled was built without the `gpu` feature; build it with \
             `cargo build --release` (the feature is on by default) or run with --device cpu",
        ))
    }
}
