//! The CUDA backend through cudarc: the driver API and NVRTC, both loaded when first used
//! (cudarc's `dynamic-loading`), so hytled builds and runs without CUDA installed and only
//! `--device gpu` needs the driver (libcuda.so) and NVRTC (libnvrtc.so). cudarc is chosen for
//! that: it is maintained, needs no CUDA at build time, and compiles the kernels at run time
//! for whatever GPU is there.

use std::ffi::c_void;
use std::sync::Arc;

use cudarc::driver::{result, sys, CudaContext, CudaFunction, CudaModule};
use cudarc::nvrtc::{compile_ptx_with_opts, CompileOptions};

use super::{Backend, Kernel, BLOCK};
use crate::{Error, InputKind, Result};

/// Device 0 with the kernels loaded.
pub struct Cuda {
    ctx: Arc<CudaContext>,
    _module: Arc<CudaModule>,
    funcs: Vec<CudaFunction>,
    allocs: Vec<u64>,
    name: String,
    /// Page-locked host buffers the copies go through: uploads are queued from `up` (bump
    /// allocated, reset once the device has caught up), downloads land in `down`.
    up: Pinned,
    up_used: usize,
    down: Pinned,
}

/// Copies up to this many bytes go through the page-locked buffers; larger ones (the model's
/// tables, once) straight from pageable memory.
const STAGED: usize = 16 << 20;

/// A page-locked host buffer.
struct Pinned {
    ptr: *mut u8,
    len: usize,
}

impl Pinned {
    const fn empty() -> Self {
        Pinned {
            ptr: std::ptr::null_mut(),
            len: 0,
        }
    }

    /// At least `len` bytes; the old contents are dropped.
    fn reserve(&mut self, len: usize) -> Result<()> {
        if len <= self.len {
            return Ok(());
        }
        self.free();
        let len = len.next_power_of_two().max(1 << 16);
        // SAFETY: a plain page-locked allocation, freed in `free`.
        let p = unsafe { result::malloc_host(len, 0) }
            .map_err(|e| err("allocating page-locked host memory", e))?;
        self.ptr = p as *mut u8;
        self.len = len;
        Ok(())
    }

    fn free(&mut self) {
        if !self.ptr.is_null() {
            // SAFETY: allocated by malloc_host and not in use (callers synchronize first).
            let _ = unsafe { result::free_host(self.ptr as *mut c_void) };
            self.ptr = std::ptr::null_mut();
            self.len = 0;
        }
    }
}

// SAFETY: the buffers are owned by the backend and used from one thread at a time (&mut self).
unsafe impl Send for Cuda {}

fn err(what: &str, e: impl std::fmt::Display) -> Error {
    Error::input(InputKind::Unsupported, format!("--device gpu: {what}: {e}"))
}

/// The checks of [`Cuda::new`] before the context: the libraries load, the driver starts and
/// sees a GPU.
pub fn probe() -> Result<()> {
    // SAFETY: only probes whether the libraries can be loaded.
    if !unsafe { sys::is_culib_present() } {
        return Err(Error::input(
            InputKind::Unsupported,
            "--device gpu: no NVIDIA driver found (libcuda.so could not be loaded); install \
                 the NVIDIA driver, or run with --device cpu",
        ));
    }
    // SAFETY: as above.
    if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        return Err(Error::input(
            InputKind::Unsupported,
            "--device gpu: NVRTC, CUDA's run-time compiler, was not found (libnvrtc.so); \
                 install the CUDA toolkit or its nvrtc package and put the folder holding \
                 libnvrtc.so on LD_LIBRARY_PATH, or run with --device cpu",
        ));
    }
    result::init().map_err(|e| err("the NVIDIA driver failed to start", e))?;
    let count = result::device::get_count().map_err(|e| err("counting GPUs", e))?;
    if count < 1 {
        return Err(Error::input(
            InputKind::Unsupported,
            "--device gpu: the NVIDIA driver sees no GPU; run with --device cpu",
        ));
    }
    Ok(())
}

impl Cuda {
    pub fn new() -> Result<Self> {
        probe()?;
        let ctx = CudaContext::new(0).map_err(|e| err("opening GPU 0", e))?;
        let name = ctx.name().unwrap_or_else(|_| "GPU 0".into());
        let opts = CompileOptions {
            fmad: Some(false),
            prec_div: Some(true),
            prec_sqrt: Some(true),
            ftz: Some(false),
            name: Some("hytled_kernels.cu".into()),
            ..Default::default()
        };
        let ptx = compile_ptx_with_opts(super::KERNELS, opts)
            .map_err(|e| err("NVRTC could not compile the kernels", format!("{e:?}")))?;
        let module = ctx
            .load_module(ptx)
            .map_err(|e| err("loading the kernels", e))?;
        let funcs = Kernel::NAMES
            .iter()
            .map(|n| {
                module
                    .load_function(n)
                    .map_err(|e| err(&format!("kernel {n}"), e))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Cuda {
            ctx,
            _module: module,
            funcs,
            allocs: Vec::new(),
            name,
            up: Pinned::empty(),
            up_used: 0,
            down: Pinned::empty(),
        })
    }

    fn bind(&self) -> Result<()> {
        self.ctx
            .bind_to_thread()
            .map_err(|e| err("binding the GPU context", e))
    }
}

impl Drop for Cuda {
    fn drop(&mut self) {
        if self.bind().is_ok() {
            let _ = result::ctx::synchronize();
            self.up.free();
            self.down.free();
            for &p in &self.allocs {
                // SAFETY: each address came from malloc_sync and is freed once.
                let _ = unsafe { result::free_sync(p) };
            }
        }
    }
}

impl Backend for Cuda {
    fn alloc(&mut self, bytes: usize) -> Result<u64> {
        self.bind()?;
        // SAFETY: a plain device allocation, freed in Drop.
        let p = unsafe { result::malloc_sync(bytes.max(8)) }.map_err(|e| {
            err(
                &format!(
                    "allocating {} on the GPU",
                    crate::memory::Size(bytes as f64)
                ),
                e,
            )
        })?;
        self.allocs.push(p);
        Ok(p)
    }

    fn upload(&mut self, dst: u64, src: &[u8]) -> Result<()> {
        self.bind()?;
        if src.len() > STAGED {
            // Large copies (the model's tables, once) go straight from pageable memory.
            self.synchronize()?;
            // SAFETY: dst is an allocation of at least src.len() bytes.
            return unsafe { result::memcpy_htod_sync(dst, src) }
                .map_err(|e| err("copying to the GPU", e));
        }
        let len = src.len().next_multiple_of(8);
        if self.up_used + len > self.up.len {
            // The queued copies still read the buffer: wait for them before reusing it.
            self.synchronize()?;
            self.up.reserve(len)?;
        }
        // SAFETY: the staging range [up_used, up_used + src.len()) lies inside `up` and no
        // queued copy reads it (the bump offset only returns to 0 after a synchronization).
        unsafe {
            let stage = std::slice::from_raw_parts_mut(self.up.ptr.add(self.up_used), src.len());
            stage.copy_from_slice(src);
            result::memcpy_htod_async(dst, &*stage, std::ptr::null_mut())
                .map_err(|e| err("copying to the GPU", e))?;
        }
        self.up_used += len;
        Ok(())
    }

    fn download(&mut self, dst: &mut [u8], src: u64) -> Result<()> {
        self.bind()?;
        if dst.len() > STAGED {
            self.up_used = 0;
            // SAFETY: src is an allocation of at least dst.len() bytes; the copy waits for
            // the work launched before.
            return unsafe { result::memcpy_dtoh_sync(dst, src) }
                .map_err(|e| err("copying from the GPU (a kernel may have failed)", e));
        }
        self.down.reserve(dst.len())?;
        // SAFETY: `down` holds at least dst.len() bytes; src is an allocation at least that
        // long. The copy on the legacy default stream waits for everything launched before.
        unsafe {
            let stage = std::slice::from_raw_parts_mut(self.down.ptr, dst.len());
            result::memcpy_dtoh_sync(stage, src)
                .map_err(|e| err("copying from the GPU (a kernel may have failed)", e))?;
            dst.copy_from_slice(stage);
        }
        // Everything queued before has completed.
        self.up_used = 0;
        Ok(())
    }

    fn synchronize(&mut self) -> Result<()> {
        self.bind()?;
        result::ctx::synchronize()
            .map_err(|e| err("waiting for the GPU (a kernel may have failed)", e))?;
        self.up_used = 0;
        Ok(())
    }

    fn launch(&mut self, kernel: Kernel, grid: u32, params: &mut [*mut c_void]) -> Result<()> {
        self.bind()?;
        let f = &self.funcs[kernel as usize];
        // SAFETY: the parameters match the kernel's signature (Resident's launches) and point
        // to live values; every address is a live allocation of this context.
        unsafe {
            result::launch_kernel(
                f.cu_function(),
                (grid, 1, 1),
                (BLOCK, 1, 1),
                0,
                std::ptr::null_mut(),
                params,
            )
        }
        .map_err(|e| err(&format!("launching {}", Kernel::NAMES[kernel as usize]), e))
    }

    fn free_memory(&self) -> Option<usize> {
        self.bind().ok()?;
        result::mem_get_info().ok().map(|(free, _)| free)
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}
