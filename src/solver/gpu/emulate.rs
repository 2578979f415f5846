//! The kernels on the CPU: [`super::KERNELS`] compiled as C++ by the system's g++ with a shim
//! that runs each block's threads one after another on the calling thread; where the kernel
//! synchronizes them, each is a fiber (`ucontext`) that `__syncthreads` switches out of, and
//! every fiber reaches the barrier before any goes past it. Device memory is host memory. It lets the tests check the kernels and
//! the GPU loop bitwise against the CPU path on machines with no GPU; it is far slower than
//! either and not meant for runs.

use std::ffi::c_void;
use std::path::PathBuf;
use std::process::Command;
use std::sync::{Mutex, OnceLock};

use super::{Backend, Kernel, BLOCK};
use crate::{Error, InputKind, Result};

const SHIM: &str = r#"
#include <cmath>
#include <cstring>
#include <cstddef>
#include <ucontext.h>
#include <vector>
#include <utility>
#include <type_traits>
struct EmuDim { unsigned x, y, z; };
static thread_local EmuDim threadIdx, blockIdx;
static EmuDim blockDim;
static void emu_sync();
#define __global__
#define __device__
#define __forceinline__ inline
#define __shared__ static
#define __syncthreads() emu_sync()
static inline long long __double_as_longlong(double x) { long long r; std::memcpy(&r, &x, 8); return r; }
static inline double __longlong_as_double(long long x) { double r; std::memcpy(&r, &x, 8); return r; }
using std::fabs; using std::cbrt;
"#;

const TAIL: &str = r#"
#include <functional>
template <typename... A, std::size_t... I>
static void emu_call(void (*f)(A...), void** p, std::index_sequence<I...>) {
    f(*static_cast<std::remove_reference_t<A>*>(p[I])...);
}
// The threads of a block that synchronizes, as fibers on the launching thread: a barrier
// switches back to the block's loop, which runs every fiber to the barrier (or its end)
// before resuming the first past it. 256 OS threads on a barrier cost a context switch each
// per barrier (81-86 s for a meshless case's 100 steps on 2 cores); a fiber switch is a
// register save.
struct EmuFibers {
    ucontext_t main;
    std::vector<ucontext_t> ctx;
    std::vector<std::vector<char>> stacks;
    std::vector<char> done;
    unsigned cur = 0;
    std::function<void(unsigned)> job;
};
static EmuFibers* emu_fibers() {
    static EmuFibers* f = new EmuFibers();
    return f;
}
static void emu_sync() {
    EmuFibers* f = emu_fibers();
    // Nothing read before the barrier (threadIdx, shared memory) may be kept past it.
    asm volatile("" ::: "memory");
    swapcontext(&f->ctx[f->cur], &f->main);
    asm volatile("" ::: "memory");
}
static void emu_fiber() {
    EmuFibers* f = emu_fibers();
    unsigned t = f->cur;
    f->job(t);
    f->done[t] = 1;
}
static void emu_block(unsigned block) {
    EmuFibers* f = emu_fibers();
    const std::size_t STACK = 256 * 1024;
    if (f->ctx.size() < block) {
        // getcontext once per fiber: a finished fiber's context is made again as it is.
        unsigned had = f->ctx.size();
        f->ctx.resize(block);
        f->stacks.resize(block);
        for (unsigned t = had; t < block; t++) {
            f->stacks[t].resize(STACK);
            getcontext(&f->ctx[t]);
        }
    }
    f->done.assign(block, 0);
    for (unsigned t = 0; t < block; t++) {
        f->ctx[t].uc_stack.ss_sp = f->stacks[t].data();
        f->ctx[t].uc_stack.ss_size = STACK;
        f->ctx[t].uc_link = &f->main;
        makecontext(&f->ctx[t], emu_fiber, 0);
    }
    for (bool live = true; live;) {
        live = false;
        for (unsigned t = 0; t < block; t++) {
            if (f->done[t]) continue;
            f->cur = t;
            threadIdx = EmuDim{t, 0, 0};
            swapcontext(&f->main, &f->ctx[t]);
            live = live || !f->done[t];
        }
    }
}
template <typename... A>
static void emu_run(void (*f)(A...), unsigned grid, unsigned block, void** p, bool sync) {
    blockDim = EmuDim{block, 1, 1};
    for (unsigned b = 0; b < grid; b++) {
        blockIdx = EmuDim{b, 0, 0};
        if (sync) {
            emu_fibers()->job = [=](unsigned) { emu_call(f, p, std::index_sequence_for<A...>{}); };
            emu_block(block);
        } else {
            for (unsigned t = 0; t < block; t++) {
                threadIdx = EmuDim{t, 0, 0};
                emu_call(f, p, std::index_sequence_for<A...>{});
            }
        }
    }
}
#define EMU(name, sync) extern "C" void emu_##name(unsigned g, unsigned b, void** p) { emu_run(name, g, b, p, sync); }
"#;

/// The host memory standing for device memory; the kernels are built once per process
/// (`library`).
pub struct Emulator {
    lib: &'static libloading::Library,
    allocs: Vec<Vec<u64>>,
}

/// The kernels compiled with `g++` (C++20) into a shared library in the temporary folder, once
/// per process; the error where g++ is missing or fails.
fn library() -> Result<&'static libloading::Library> {
    static LIB: OnceLock<std::result::Result<libloading::Library, String>> = OnceLock::new();
    LIB.get_or_init(build)
        .as_ref()
        .map_err(|e| Error::input(InputKind::Unsupported, e.clone()))
}

fn build() -> std::result::Result<libloading::Library, String> {
    let dir = std::env::temp_dir().join(format!(
        "hytled-emu-{}-{}",
        std::process::id(),
        rand_suffix()
    ));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let src = dir.join("kernels.cpp");
    let mut text = String::from(SHIM);
    text.push_str(super::KERNELS);
    text.push_str(TAIL);
    for k in Kernel::ALL {
        text.push_str(&format!(
            "EMU({}, {})\n",
            Kernel::NAMES[k as usize],
            k.synchronizes()
        ));
    }
    std::fs::write(&src, text).map_err(|e| format!("{}: {e}", src.display()))?;
    let lib: PathBuf = dir.join("kernels.so");
    let out = Command::new("g++")
        .args(["-std=c++20", "-O2", "-ffp-contract=off", "-fPIC", "-shared"])
        .arg(&src)
        .arg("-o")
        .arg(&lib)
        .output()
        .map_err(|e| format!("the kernel emulation needs g++: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "g++ could not build the kernel emulation:\n{}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    // SAFETY: the library was built just now from the source above; its initializers only
    // set up statics.
    let l = unsafe { libloading::Library::new(&lib) }
        .map_err(|e| format!("loading the kernel emulation: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    l
}

/// One launch at a time in the process: the emulation's block state is global.
static LAUNCH: Mutex<()> = Mutex::new(());

impl Emulator {
    /// The emulation, building the kernels on first use.
    pub fn new() -> Result<Self> {
        Ok(Emulator {
            lib: library()?,
            allocs: Vec::new(),
        })
    }
}

fn rand_suffix() -> u64 {
    use std::time::{SystemTime, UNIX_EPOCH};
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

impl Backend for Emulator {
    fn alloc(&mut self, bytes: usize) -> Result<u64> {
        let mut v = vec![0u64; bytes.div_ceil(8).max(1)];
        let p = v.as_mut_ptr() as u64;
        self.allocs.push(v);
        Ok(p)
    }

    fn upload(&mut self, dst: u64, src: &[u8]) -> Result<()> {
        // SAFETY: `dst` is an allocation of this emulator at least `src.len()` long (the
        // caller's contract, as for device memory).
        unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), dst as *mut u8, src.len()) };
        Ok(())
    }

    fn download(&mut self, dst: &mut [u8], src: u64) -> Result<()> {
        // SAFETY: as `upload`.
        unsafe { std::ptr::copy_nonoverlapping(src as *const u8, dst.as_mut_ptr(), dst.len()) };
        Ok(())
    }

    fn launch(&mut self, kernel: Kernel, grid: u32, params: &mut [*mut c_void]) -> Result<()> {
        let name = format!("emu_{}", Kernel::NAMES[kernel as usize]);
        // SAFETY: the symbol is the wrapper EMU made for this kernel, with this signature;
        // the parameters point to values of the kernel's argument types (Resident's launches).
        let _one = LAUNCH.lock().unwrap_or_else(|e| e.into_inner());
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn(u32, u32, *mut *mut c_void)> =
                self.lib.get(name.as_bytes()).map_err(|e| {
                    Error::input(
                        InputKind::Unsupported,
                        format!("emulator kernel {name}: {e}"),
                    )
                })?;
            f(grid, BLOCK, params.as_mut_ptr());
        }
        Ok(())
    }

    fn synchronize(&mut self) -> Result<()> {
        Ok(())
    }

    fn free_memory(&self) -> Option<usize> {
        None
    }

    fn describe(&self) -> String {
        "the CPU emulation of the GPU kernels".into()
    }
}
