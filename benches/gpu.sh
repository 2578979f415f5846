#!/bin/bash
# The GPU checks and figures of benches/README.md ("GPU"), on a machine with an NVIDIA GPU:
# the GPU-vs-CPU parity test, where the GPU's time goes (HYTLED_GPU_PROFILE), `hytled bench
# --device gpu` on the cylinder cases (2 and 16 threads), the 20k-node hex8 cylinder and the
# brain at the thesis's resolution, and the brain relaxed to steady state on the GPU.
#
#   cargo build --release && cargo test --release --no-run --test gpu
#   benches/gpu.sh DIR OUT   # DIR holds the binaries `hytled` and `gpu-test` (tests/gpu.rs)
#
# cudarc loads the driver (libcuda.so) and NVRTC (libnvrtc.so) at run time; where the toolkit
# has only a versioned libnvrtc.so.N, a link named libnvrtc.so is made for it here.
set -u
B=${1:-.devbin}
O=${2:-/tmp/hytled-gpu}
mkdir -p "$O"
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm,clocks.max.mem --format=csv | tee "$O/gpu.txt"
lib=$(ls /usr/local/cuda/lib64/libnvrtc.so* 2>/dev/null | head -1)
[ -z "$lib" ] && lib=$(find / -name 'libnvrtc.so*' -not -path '/proc/*' 2>/dev/null | head -1)
mkdir -p /tmp/nvrtc-link && ln -sf "$lib" /tmp/nvrtc-link/libnvrtc.so
export LD_LIBRARY_PATH=/tmp/nvrtc-link:$(dirname "$lib"):${LD_LIBRARY_PATH:-}
echo "NVRTC: $lib"
BRAIN=(cases/brain-indentation.toml --set discretization.method=meshless --set discretization.size=0.0028)
HEX20K=(cases/cylinder-compression.toml --set 'discretization.divisions=[14,6,34]')
step() { echo "== $1"; shift; timeout "$@"; echo "(exit $?)"; }
step "parity" 60 "$B/gpu-test" gpu_runs_match_the_cpu_bitwise --nocapture --test-threads 1 2>&1 | tee "$O/parity.txt"
step "cylinders" 80 "$B/hytled" bench --device gpu --threads 2,16 --repeat 3 2>&1 | tee "$O/bench-cylinders.txt"
step "hex8 20k" 40 "$B/hytled" bench "${HEX20K[@]}" --device gpu --threads 2,16 --repeat 3 2>&1 | tee "$O/bench-hex8-20k.txt"
step "brain" 50 "$B/hytled" bench "${BRAIN[@]}" --device gpu --threads 16 --steps 300 --repeat 1 2>&1 | tee "$O/bench-brain.txt"
step "brain steady state" 40 "$B/hytled" run "${BRAIN[@]}" --device gpu 2>&1 | tee "$O/brain-run.txt"
export HYTLED_GPU_PROFILE=1
step "profile: coupled" 40 "$B/hytled" bench cases/cylinder-compression.toml --set discretization.method=coupled --device gpu --threads 16 --steps 500 --repeat 1 2>&1 | tee "$O/profile-coupled.txt"
step "profile: brain" 45 "$B/hytled" bench "${BRAIN[@]}" --device gpu --threads 16 --steps 100 --repeat 1 2>&1 | tee "$O/profile-brain.txt"
step "profile: hex8 20k" 30 "$B/hytled" bench "${HEX20K[@]}" --device gpu --threads 16 --steps 1000 --repeat 1 2>&1 | tee "$O/profile-hex8.txt"
