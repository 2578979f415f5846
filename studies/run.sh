#!/usr/bin/env bash
# Regenerates the committed study reports (issue 6). Each study is one or more `hytled sweep`
# runs; every file under studies/<study>/ is written by the program. Usage:
#   cargo build --release && studies/run.sh [study ...]     (default: all)
# Studies: timestep incompressibility large-deformation irregular spin speed-accuracy
set -euo pipefail
cd "$(dirname "$0")/.."
H=${HYTLED:-target/release/hytled}
FE_HEX='fe-hex8=discretization.method=fe;discretization.element=hex8'
FE_TET4='fe-tet4=discretization.method=fe;discretization.element=tet4'
FE_ANP='fe-tet4-anp=discretization.method=fe;discretization.element=tet4-anp'
MLS='mls=discretization.method=meshless;discretization.basis=linear'
MMLS='mmls=discretization.method=meshless;discretization.basis=quadratic'
COUPLED='coupled=discretization.method=coupled;discretization.element=hex8'
CYL4='discretization.divisions=[4,2,8]'

timestep() {
  # Study 2: dt_factor 0.5-3.0 per method, dynamic; the largest stable factor.
  for c in cube-compression cylinder-compression; do
    extra=(); [ "$c" = cylinder-compression ] && extra=(--set "$CYL4")
    $H sweep cases/$c.toml --set solver.mode=dynamic --set discretization.fe_layers=1 "${extra[@]}" \
      --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
      --vary solver.dt_factor=0.5,0.9,1.0,1.1,1.2,1.3,1.35,1.4,1.5,1.75,2.0,2.25,2.5,3.0 \
      --out studies/timestep/$c
  done
}

incompressibility() {
  # Study 3: nu 0.3-0.4999; the cube has an exact solution for every nu (exact = "uniaxial").
  $H sweep cases/cube-compression.toml --set discretization.size=0.025 --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_TET4" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary material.poisson_ratio=0.3,0.45,0.49,0.499,0.4999 --out studies/incompressibility/cube
  # The bonded cylinder (non-uniform: locking shows); ABAQUS reference exists for nu = 0.49 only.
  $H sweep cases/cylinder-compression.toml --set solver.mode=relaxation --set "$CYL4" \
    --set discretization.fe_layers=1 --set 'references={}' \
    --preset "$FE_HEX" --preset "$FE_TET4" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary material.poisson_ratio=0.3,0.45,0.49,0.499,0.4999 --out studies/incompressibility/cylinder
}

large_deformation() {
  # Study 4: the cylinder compressed by 20-80 % of its 0.1 m height, dynamic, at two step factors.
  # (The ABAQUS references hold for 20 % only: none here; the energy balance is the check.)
  $H sweep cases/cylinder-compression.toml --set "$CYL4" --set discretization.fe_layers=1 \
    --set 'references={}' \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary solver.dt_factor=0.9,0.3 \
    --vary boundaries.top.displacement.z=-0.02,-0.04,-0.06,-0.07,-0.08 \
    --out studies/large-deformation
}

irregular() {
  # Study 5: lattice clouds with jitter, and integration points per node (Horton 2010 figs. 3-5).
  $H sweep cases/cylinder-compression.toml --set solver.mode=relaxation \
    --set discretization.method=meshless --set discretization.cloud=lattice \
    --set discretization.size=0.0125 --set discretization.integration=grid \
    --vary discretization.jitter=0,0.1,0.2,0.3,0.4,0.45 --out studies/irregular/jitter
  $H sweep cases/cylinder-compression.toml --set solver.mode=dynamic \
    --set discretization.method=meshless --set discretization.cloud=lattice \
    --set discretization.size=0.0125 --set discretization.integration=grid \
    --vary discretization.point_ratio=0.5,1,1.5,2,3,4 --out studies/irregular/point-ratio
}

spin() {
  # Study 6: 20 s of free spin at 1 Hz (cases/cube-spin.toml): momentum and energy per method.
  $H sweep cases/cube-spin.toml --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary discretization.size=0.025,0.0125 --out studies/spin
}

speed_accuracy() {
  # Study 1: h-refinement per method, relaxation; the cheapest way to 1 % and 5 %.
  for c in cylinder-compression cylinder-extension cylinder-shear; do
    $H sweep cases/$c.toml --set solver.mode=relaxation --set discretization.fe_layers=1 \
      --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$MMLS" --preset "$COUPLED" \
      --vary 'discretization.divisions=[2,1,4],[4,2,8],[6,3,12],[8,4,16]' \
      --out studies/speed-accuracy/$c
  done
  $H sweep cases/cylinder-compression.toml --set solver.mode=dynamic --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$MLS" --preset "$COUPLED" \
    --vary 'discretization.divisions=[2,1,4],[4,2,8],[6,3,12]' \
    --out studies/speed-accuracy/cylinder-compression-dynamic
  $H sweep cases/cube-compression.toml --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$MMLS" --preset "$COUPLED" \
    --vary discretization.size=0.05,0.025,0.02,0.0125 --out studies/speed-accuracy/cube-compression
}

studies=("$@"); [ ${#studies[@]} -eq 0 ] && studies=(timestep incompressibility large_deformation irregular spin speed_accuracy)
for s in "${studies[@]}"; do echo "== study $s"; "${s//-/_}"; done
