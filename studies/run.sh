#!/usr/bin/env bash
# Regenerates the committed study reports (issue 6). Each job is one `hytled sweep`; every file
# under studies/<study>/ is written by the program. Usage:
#   cargo build --release && studies/run.sh [JOB|STUDY ...]     (default: every job)
#   studies/run.sh --list                                        (the jobs)
# Environment: HYTLED (binary, default target/release/hytled), THREADS (threads per sweep,
# default all cores), JOBS (sweeps run at once, default 1; with JOBS > 1 give each sweep its own
# cores, e.g. JOBS=4 THREADS=2 on 8 cores, or the wall times of study 1 compete).
# Studies (a study name runs all its jobs): timestep incompressibility large-deformation
# irregular spin speed-accuracy fe-layers adaptive tets brain-convergence brain-compressible
# indentation brain-builtin pareto-tets (indentation-patches, patches-cylinders,
# meshless-patches: the mean-dilatation patches) static (issue 57: relaxation against the
# static solve).
set -euo pipefail
cd "$(dirname "$0")/.."
H=${HYTLED:-target/release/hytled}
T=()
[ -n "${THREADS:-}" ] && T=(--threads "$THREADS")
FE_HEX='fe-hex8=discretization.method=fe;discretization.element=hex8'
FE_TET4='fe-tet4=discretization.method=fe;discretization.element=tet4'
FE_ANP='fe-tet4-anp=discretization.method=fe;discretization.element=tet4-anp'
MLS='mls=discretization.method=meshless;discretization.basis=linear'
MMLS='mmls=discretization.method=meshless;discretization.basis=quadratic'
COUPLED='coupled=discretization.method=coupled;discretization.element=hex8'
CYL4='discretization.divisions=[4,2,8]'
LEVELS='discretization.divisions=[2,1,4],[4,2,8],[6,3,12],[8,4,16]'

sweep() { $H sweep "$@" "${T[@]}"; }

# Study 2: dt_factor 0.5-3.0 per method, dynamic; the largest stable factor.
timestep-cube() {
  sweep cases/cube-compression.toml --set solver.mode=dynamic --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary solver.dt_factor=0.5,0.9,1.0,1.1,1.2,1.3,1.35,1.4,1.5,1.75,2.0,2.25,2.5,3.0 \
    --out studies/timestep/cube-compression
}
timestep-cylinder() {
  sweep cases/cylinder-compression.toml --set solver.mode=dynamic --set discretization.fe_layers=1 \
    --set "$CYL4" --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary solver.dt_factor=0.5,0.9,1.0,1.1,1.2,1.3,1.35,1.4,1.5,1.75,2.0,2.25,2.5,3.0 \
    --out studies/timestep/cylinder-compression
}

# Study 3: nu 0.3-0.4999; the cube has an exact solution for every nu (exact = "uniaxial").
incompressibility-cube() {
  sweep cases/cube-compression.toml --set discretization.size=0.025 --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_TET4" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary material.poisson_ratio=0.3,0.45,0.49,0.499,0.4999 --out studies/incompressibility/cube
}
# The bonded cylinder (non-uniform: locking shows); the ABAQUS reference holds for nu = 0.49 only.
incompressibility-cylinder() {
  sweep cases/cylinder-compression.toml --set solver.mode=relaxation --set "$CYL4" \
    --set discretization.fe_layers=1 --set 'references={}' \
    --preset "$FE_HEX" --preset "$FE_TET4" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary material.poisson_ratio=0.3,0.45,0.49,0.499,0.4999 --out studies/incompressibility/cylinder
}

# Study 4: the cylinder compressed by 20-80 % of its 0.1 m height and back (smooth-return curve,
# 3 s each way), dynamic, at two step factors. The ABAQUS references hold for 20 % one-way only:
# none here; the energy balance (scaled by the peak work) and the work left at the end are the check.
large-deformation() {
  sweep cases/cylinder-compression.toml --set "$CYL4" --set discretization.fe_layers=1 \
    --set 'references={}' --set boundaries.top.curve=smooth-return --set solver.duration=6.0 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary solver.dt_factor=0.9,0.3 \
    --vary boundaries.top.displacement.z=-0.02,-0.04,-0.06,-0.07,-0.08 \
    --out studies/large-deformation
}

# Study 5: lattice clouds with jitter and Halton clouds, and integration points per node
# (Horton 2010 figs. 3-5).
irregular-jitter() {
  sweep cases/cylinder-compression.toml --set solver.mode=relaxation --set discretization.size=0.0125 \
    --preset 'mls-lattice=discretization.method=meshless;discretization.cloud=lattice' \
    --preset 'coupled-lattice=discretization.method=coupled;discretization.cloud=lattice;discretization.fe_layers=1' \
    --vary discretization.jitter=0,0.1,0.2,0.3,0.4,0.45 --out studies/irregular/jitter
}
irregular-halton() {
  sweep cases/cylinder-compression.toml --set solver.mode=relaxation --set discretization.cloud=halton \
    --preset 'mls=discretization.method=meshless' \
    --preset 'coupled=discretization.method=coupled;discretization.fe_layers=1' \
    --vary discretization.size=0.0125,0.00625 --out studies/irregular/halton
}
irregular-point-ratio() {
  sweep cases/cylinder-compression.toml --set solver.mode=dynamic \
    --set discretization.method=meshless --set discretization.cloud=lattice \
    --set discretization.size=0.0125 --set discretization.integration=grid \
    --vary discretization.point_ratio=0.5,1,1.5,2,3,4 --out studies/irregular/point-ratio
}

# Study 6: 20 s of free spin at 1 Hz (cases/cube-spin.toml): momentum and energy per method.
spin() {
  sweep cases/cube-spin.toml --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary discretization.size=0.025,0.0125 --out studies/spin
}

# Issue 5: the coupled cylinder's error against the number of FE layers on the boundary.
fe-layers-compression() { fe_layers cylinder-compression; }
fe-layers-extension() { fe_layers cylinder-extension; }
fe-layers-shear() { fe_layers cylinder-shear; }
fe_layers() {
  sweep cases/$1.toml --set solver.mode=relaxation --set discretization.method=coupled \
    --vary discretization.fe_layers=1,2,3 --out studies/fe-layers/$1
}

# Study 1: h-refinement per method, relaxation (and dynamic); the cheapest way to 1 % and 5 %.
speed-accuracy-compression() { speed_accuracy_cylinder cylinder-compression; }
speed-accuracy-extension() { speed_accuracy_cylinder cylinder-extension; }
speed-accuracy-shear() { speed_accuracy_cylinder cylinder-shear; }
speed_accuracy_cylinder() {
  sweep cases/$1.toml --set solver.mode=relaxation --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$MMLS" --preset "$COUPLED" \
    --vary "$LEVELS" --out studies/speed-accuracy/$1
}
speed-accuracy-dynamic() {
  sweep cases/cylinder-compression.toml --set solver.mode=dynamic --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$COUPLED" \
    --vary 'discretization.divisions=[2,1,4],[4,2,8],[6,3,12],[8,4,16]' \
    --out studies/speed-accuracy/cylinder-compression-dynamic
}
speed-accuracy-cube() {
  sweep cases/cube-compression.toml --set discretization.fe_layers=1 \
    --preset "$FE_HEX" --preset "$FE_ANP" --preset "$MLS" --preset "$MMLS" --preset "$COUPLED" \
    --vary discretization.size=0.05,0.025,0.02,0.0125 --out studies/speed-accuracy/cube-compression
}

# Issue 8: adaptive integration of the meshless cylinder over the tolerance (MLS and MMLS,
# radius supports, EBCIEM; base rule 4 points per tet, bisection, up to 3 levels).
adaptive-compression() { adaptive_cylinder cylinder-compression; }
adaptive-extension() { adaptive_cylinder cylinder-extension; }
adaptive-shear() { adaptive_cylinder cylinder-shear; }
adaptive_cylinder() {
  sweep cases/$1.toml --set solver.mode=relaxation --set "$CYL4" \
    --set discretization.integration=adaptive --preset "$MLS" --preset "$MMLS" \
    --vary discretization.tolerance=0.5,0.1,0.05,0.01,0.005 --out studies/adaptive/$1
}

# Issue 21: the three cylinder cases on unstructured tets against the SfePy reference
# (docs/reference.md): a Gmsh series (meshes/make_gmsh_cylinders.py: 1,982 / 4,208 / 8,743 /
# 17,917 nodes) and a TetGen series (mesher = "tetgen", size 12 / 9 / 7 mm: 2,697 / 4,386 /
# 8,314 nodes); fe tet4-anp, meshless MLS and MMLS (one point per tet, radius supports,
# EBCIEM), coupled with one FE layer around the essential faces (the unstructured-tet
# default) and one point per transition tet (the default when the study ran; now `full`),
# linear MLS or an MMLS interior.
MLS1='mls=discretization.method=meshless;discretization.basis=linear;discretization.tet_rule=1'
MMLS1='mmls=discretization.method=meshless;discretization.basis=quadratic;discretization.tet_rule=1'
COUPLED_TET='coupled=discretization.method=coupled;discretization.transition_rule=interior'
COUPLED_MMLS='coupled-mmls=discretization.method=coupled;discretization.basis=quadratic;discretization.transition_rule=interior'
GMSH='geometry.mesh=../meshes/cylinder-gmsh-h75.msh,../meshes/cylinder-gmsh-h57.msh,../meshes/cylinder-gmsh-h43.msh,../meshes/cylinder-gmsh-h33.msh'
tets-gmsh-compression() { tets_gmsh compression; }
tets-gmsh-extension() { tets_gmsh extension; }
tets-gmsh-shear() { tets_gmsh shear; }
tets_gmsh() {
  sweep cases/tet-cylinder-$1.toml "${TET_PRESETS[@]}" --vary "$GMSH" --out studies/tets/gmsh-$1
}
# fe tet4-anp again after its own stable-step bound and lane kernel (the sweeps above ran
# before them; their other presets do not use ANP points).
tets-anp-gmsh-compression() { tets_anp_gmsh compression; }
tets-anp-gmsh-extension() { tets_anp_gmsh extension; }
tets-anp-gmsh-shear() { tets_anp_gmsh shear; }
tets_anp_gmsh() {
  sweep cases/tet-cylinder-$1.toml --preset "$FE_ANP" --vary "$GMSH" --out studies/tets/anp-gmsh-$1
}
# The Gmsh series again with the global step estimate (solver.time_step = "global", now the
# default; fe tet4-anp keeps its own bound) and the coupled defaults for unstructured tets that
# followed the study (one point per transition tet); `coupled-tpp3` merges about three interior
# tets into each point; `coupled-full` has four points per transition tet.
COUPLED_FULL='coupled-full=discretization.method=coupled;discretization.transition_rule=full'
COUPLED_TPP3='coupled-tpp3=discretization.method=coupled;discretization.tets_per_point=3'
tets-global-gmsh-compression() { tets_global compression; }
tets-global-gmsh-extension() { tets_global extension; }
tets-global-gmsh-shear() { tets_global shear; }
tets_global() {
  sweep cases/tet-cylinder-$1.toml --preset "$FE_ANP" --preset "$MLS1" --preset "$MMLS1" \
    --preset 'coupled=discretization.method=coupled' --preset "$COUPLED_TPP3" \
    --preset "$COUPLED_FULL" --vary "$GMSH" \
    --out studies/tets/global-gmsh-$1
}
# The TetGen series meshes the built-in cylinder; its references are set to SfePy's.
tets-tetgen-compression() { tets_tetgen compression tetgen "${TET_PRESETS[@]}"; }
tets-tetgen-extension() { tets_tetgen extension tetgen "${TET_PRESETS[@]}"; }
tets-tetgen-shear() { tets_tetgen shear tetgen "${TET_PRESETS[@]}"; }
tets-anp-tetgen-compression() { tets_tetgen compression anp-tetgen --preset "$FE_ANP"; }
tets-anp-tetgen-extension() { tets_tetgen extension anp-tetgen --preset "$FE_ANP"; }
tets-anp-tetgen-shear() { tets_tetgen shear anp-tetgen --preset "$FE_ANP"; }
TET_PRESETS=(--preset "$FE_ANP" --preset "$MLS1" --preset "$MMLS1" --preset "$COUPLED_TET"
  --preset "$COUPLED_MMLS")
# tets_tetgen CASE OUT PRESETS...: SfePy's reaction component, reaction and probe u_x per case.
tets_tetgen() {
  local refs
  case $1 in
    compression) refs=(z -6.92 0.00699) ;;
    extension) refs=(z 4.664 -0.005083) ;;
    shear) refs=(x 1.115 0.009506) ;;
  esac
  local c=$1 out=$2
  shift 2
  sweep cases/cylinder-$c.toml --set solver.mode=relaxation --set discretization.mesher=tetgen \
    --set discretization.element=tet4-anp --set "references.force.quantity=reaction.top.${refs[0]}" \
    --set "references.force.value=${refs[1]}" --set "references.probe_ux.value=${refs[2]}" \
    --set 'references.force.source=SfePy (docs/reference.md)' \
    --set 'references.probe_ux.source=SfePy (docs/reference.md)' \
    "$@" --vary discretization.size=0.012,0.009,0.007 --out studies/tets/$out-$c
}

# Issue 21, item 5: the brain indentation refined per method (no published reference: the
# indenter force's convergence is the check). fe tet4-anp (the scene's default), meshless MLS,
# coupled with the scene's surface layer (two tet4-anp layers, four points per transition tet)
# and with the unstructured-tet defaults (one layer around the essential boundaries, one point
# per transition tet), TetGen size 6 / 4.5 / 3.5 mm; fe alone at 2.5 mm (27,968 nodes).
brain-convergence() {
  sweep cases/brain-indentation.toml --preset "$FE_ANP" \
    --preset 'meshless=discretization.method=meshless' \
    --preset 'coupled-surface=discretization.method=coupled' \
    --preset 'coupled-essential=discretization.method=coupled;discretization.fe_region=essential;discretization.fe_layers=1;discretization.transition_rule=interior' \
    --vary discretization.size=0.006,0.0045,0.0035 --out studies/brain-convergence
}
brain-convergence-fine() {
  sweep cases/brain-indentation.toml --preset "$FE_ANP" --vary discretization.size=0.0025 \
    --out studies/brain-convergence-fine
}

# The brain indentation with compressible tissue (nu = 0.3): does the methods' spread at
# nu = 0.49 come from near-incompressibility (volumetric locking in the transition layer) or
# from the driven footprint? fe, meshless, coupled with the scene's surface layer, and coupled
# around the essential boundaries with four and with one point per transition tet.
brain-compressible() {
  sweep cases/brain-indentation.toml --set material.poisson_ratio=0.3 --preset "$FE_ANP" \
    --preset 'meshless=discretization.method=meshless' \
    --preset 'coupled-surface=discretization.method=coupled' \
    --preset 'coupled-essential-full=discretization.method=coupled;discretization.fe_region=essential;discretization.fe_layers=1;discretization.transition_rule=full' \
    --preset 'coupled-essential=discretization.method=coupled;discretization.fe_region=essential;discretization.fe_layers=1;discretization.transition_rule=interior' \
    --vary discretization.size=0.006,0.0045,0.0035,0.0025 --out studies/brain-compressible
}

# Issue 40: the indentation benchmark (cases/brain-indentation-benchmark.toml: the plug driven
# on conforming Gmsh meshes graded at its rim, meshes/make_gmsh_brain_indentation.py; the
# docs/reference.md SfePy force at 1-5 mm through load stages). fe tet4-anp and tet10, the coupled
# method with its tet4-anp layer (the unstructured-tet defaults: one layer around the essential
# boundaries, linear MLS), with a quadratic layer, and with a quadratic layer and the MMLS
# interior, on levels c1-c4; fe tet4-anp alone on c5. These studies are of relaxation (the
# case is static by default since issue 57).
BI='../meshes/brain-indentation'
indentation() {
  sweep cases/brain-indentation-benchmark.toml --set solver.mode=relaxation --preset "$FE_ANP" \
    --preset 'fe-tet10=discretization.method=fe;discretization.element=tet10' \
    --preset 'coupled-tet4-anp=discretization.method=coupled;discretization.element=tet4-anp' \
    --preset 'coupled-tet10=discretization.method=coupled;discretization.element=tet10' \
    --preset 'coupled-tet10-mmls=discretization.method=coupled;discretization.element=tet10;discretization.basis=quadratic' \
    --vary "geometry.mesh=$BI-c1.msh,$BI-c2.msh,$BI-c3.msh,$BI-c4.msh" --out studies/indentation
}
# Issue 40, mean-dilatation patches: the coupled defaults (tet4-anp layer, linear MLS interior
# whose points share their mean J over patches of 8 interior tets) level by level against each
# point's own J and with FE layers along the whole surface, the patch size on c4, and the tet
# cylinders (Gmsh series) both ways.
PATCH1='discretization.mean_dilatation_patch=1'
indentation-patches() {
  sweep cases/brain-indentation-benchmark.toml --set solver.mode=relaxation \
    --preset 'coupled=discretization.method=coupled;discretization.element=tet4-anp' \
    --preset "coupled-patch1=discretization.method=coupled;discretization.element=tet4-anp;$PATCH1" \
    --preset 'coupled-surface=discretization.method=coupled;discretization.element=tet4-anp;discretization.fe_region=surface;discretization.fe_layers=2' \
    --vary "geometry.mesh=$BI-c2.msh,$BI-c3.msh,$BI-c4.msh,$BI-c5.msh" \
    --out studies/indentation-patches/levels
  sweep cases/brain-indentation-benchmark.toml --set solver.mode=relaxation \
    --set discretization.method=coupled --set discretization.element=tet4-anp \
    --set "geometry.mesh=$BI-c4.msh" --vary discretization.mean_dilatation_patch=1,4,6,8,12,16 \
    --out studies/indentation-patches/size
}
GMSH_STEM='../meshes/cylinder-gmsh'
patches-cylinders() {
  for c in compression extension shear; do
    sweep "cases/tet-cylinder-$c.toml" \
      --preset 'coupled=discretization.method=coupled' \
      --preset "coupled-patch1=discretization.method=coupled;$PATCH1" \
      --vary "geometry.mesh=$GMSH_STEM-h75.msh,$GMSH_STEM-h57.msh,$GMSH_STEM-h43.msh,$GMSH_STEM-h33.msh" \
      --out "studies/indentation-patches/cylinder-$c"
  done
}
# Issue 40, the Pareto front on unstructured tets: every method with its defaults (meshless one
# point per tet), fe tet10 among them, on the first three Gmsh cylinders (h33 with tet10 is
# about 130,000 nodes). The benchmark's front is the `indentation` sweep.
FE_TET10='fe-tet10=discretization.method=fe;discretization.element=tet10'
pareto-tets-compression() { pareto_tets compression; }
pareto-tets-extension() { pareto_tets extension; }
pareto-tets-shear() { pareto_tets shear; }
pareto_tets() {
  sweep cases/tet-cylinder-$1.toml --preset "$FE_ANP" --preset "$FE_TET10" --preset "$MLS1" \
    --preset "$MMLS1" --preset 'coupled=discretization.method=coupled' \
    --vary "geometry.mesh=$GMSH_STEM-h75.msh,$GMSH_STEM-h57.msh,$GMSH_STEM-h43.msh" \
    --out "studies/pareto-tets/$1"
}
# Issue 40, mean-dilatation patches for pure meshless (default 8 on a tet mesh's vertices):
# MLS with four points per tet, patches of 8 against each point its own J, on the tet cylinders,
# the benchmark, and the structured hexahedral cylinder where they stay off.
meshless-patches() {
  for c in compression extension shear; do
    sweep "cases/tet-cylinder-$c.toml" --set discretization.method=meshless \
      --vary discretization.mean_dilatation_patch=1,8 \
      --vary "geometry.mesh=$GMSH_STEM-h75.msh,$GMSH_STEM-h57.msh" \
      --out "studies/meshless-patches/tet-cylinder-$c"
  done
  for c in compression shear; do
    sweep "cases/cylinder-$c.toml" --set discretization.method=meshless \
      --vary discretization.mean_dilatation_patch=1,8 --out "studies/meshless-patches/cylinder-$c"
  done
  sweep cases/brain-indentation-benchmark.toml --set solver.mode=relaxation --set discretization.method=meshless \
    --set discretization.element=tet4-anp --vary discretization.mean_dilatation_patch=1,8 \
    --vary "geometry.mesh=$BI-c2.msh,$BI-c3.msh,$BI-c4.msh" \
    --out studies/meshless-patches/indentation
}
indentation-fine() {
  sweep cases/brain-indentation-benchmark.toml --set solver.mode=relaxation --preset "$FE_ANP" \
    --vary "geometry.mesh=$BI-c5.msh" --out studies/indentation-fine
}
# Issue 40, built-in shapes honour their loads: the TetGen half-ellipsoid with the plug (or the
# tool's rim) as a mesh feature, graded there (discretization.refine), refined level by level.
# The first preset is each case's default.
ref() { echo "discretization.size=$1;discretization.refine=[{near=\"indenter\",size=$2}]"; }
brain-builtin-indentation() {
  sweep cases/brain-indentation.toml \
    --preset "default-8-2mm=$(ref 0.008 0.002)" --preset "h6-1mm=$(ref 0.006 0.001)" \
    --preset "h6-0.5mm=$(ref 0.006 0.0005)" --preset "h4-0.5mm=$(ref 0.004 0.0005)" \
    --preset "tet4-anp-8-2mm=$(ref 0.008 0.002);discretization.element=tet4-anp" \
    --out studies/brain-builtin-indentation
}
brain-builtin-contact() {
  sweep cases/brain-contact.toml \
    --preset 'default-4mm=discretization.size=0.004' --preset "h4-1mm=$(ref 0.004 0.001)" \
    --preset "h4-0.5mm=$(ref 0.004 0.0005)" --preset "h3-0.5mm=$(ref 0.003 0.0005)" \
    --preset "h3-0.3mm=$(ref 0.003 0.0003)" \
    --preset 'fe-tet4-anp-4mm=discretization.size=0.004;discretization.method=fe' \
    --out studies/brain-builtin-contact
}

# Issue 57: relaxation and the static solve side by side (`--vary solver.mode`), wall time and
# force evaluations: the benchmark at c1-c4 (fe tet10), and c5 apart (many minutes each way),
# then the committed steady scenes, the contact scenes (brain-contact converges statically but
# slower; the MNI skull stops: its row is the static solve's error) and brain-indentation on a
# TetGen mesh graded to 0.6 mm at the plug's rim (33,007 nodes; the static solve stops there).
MODES='solver.mode=relaxation,static'
static-indentation() {
  sweep cases/brain-indentation-benchmark.toml --vary "$MODES" \
    --vary "geometry.mesh=$BI-c1.msh,$BI-c2.msh,$BI-c3.msh,$BI-c4.msh" \
    --out studies/static/indentation
}
static-benchmark-c5() {
  sweep cases/brain-indentation-benchmark.toml --vary "$MODES" --vary "geometry.mesh=$BI-c5.msh" \
    --out studies/static/indentation-c5
}
static_scene() { sweep "cases/$1.toml" --vary "$MODES" --out "studies/static/$1"; }
static-brain-shift() { static_scene brain-shift; }
static-cube() { static_scene cube-compression; }
static-tet-cylinder-compression() { static_scene tet-cylinder-compression; }
static-tet-cylinder-extension() { static_scene tet-cylinder-extension; }
static-tet-cylinder-shear() { static_scene tet-cylinder-shear; }
static-cylinder-mixed() { static_scene cylinder-mixed; }
static-brain-indentation() { static_scene brain-indentation; }
static-brain-contact() { static_scene brain-contact; }
static-mni-brain-shift() { static_scene mni-brain-shift; }
static-rim-fine() {
  sweep cases/brain-indentation.toml --vary "$MODES" \
    --set 'discretization.refine=[{ near = "indenter", size = 0.0006, growth = 1.25 }]' \
    --out studies/static/brain-indentation-rim-0.6mm
}

ALL=(speed-accuracy-compression speed-accuracy-extension speed-accuracy-shear speed-accuracy-dynamic
  speed-accuracy-cube timestep-cube timestep-cylinder incompressibility-cube
  incompressibility-cylinder large-deformation irregular-jitter irregular-halton
  irregular-point-ratio spin fe-layers-compression fe-layers-extension fe-layers-shear
  adaptive-compression adaptive-extension adaptive-shear
  tets-gmsh-compression tets-gmsh-extension tets-gmsh-shear
  tets-tetgen-compression tets-tetgen-extension tets-tetgen-shear
  tets-anp-gmsh-compression tets-anp-gmsh-extension tets-anp-gmsh-shear
  tets-anp-tetgen-compression tets-anp-tetgen-extension tets-anp-tetgen-shear
  tets-global-gmsh-compression tets-global-gmsh-extension tets-global-gmsh-shear
  brain-convergence brain-convergence-fine brain-compressible indentation indentation-fine
  indentation-patches patches-cylinders brain-builtin-indentation brain-builtin-contact
  pareto-tets-compression pareto-tets-extension pareto-tets-shear meshless-patches
  static-indentation static-benchmark-c5 static-brain-shift static-cube static-tet-cylinder-compression
  static-tet-cylinder-extension static-tet-cylinder-shear static-cylinder-mixed
  static-brain-indentation static-brain-contact static-mni-brain-shift static-rim-fine)

if [ "${1:-}" = --list ]; then printf '%s\n' "${ALL[@]}"; exit 0; fi
# A study name stands for its jobs.
jobs=()
for a in "${@:-${ALL[@]}}"; do
  matched=0
  for j in "${ALL[@]}"; do
    if [ "$j" = "$a" ] || [[ "$j" == "$a"-* ]]; then jobs+=("$j"); matched=1; fi
  done
  [ $matched = 1 ] || { echo "unknown job or study '$a' (studies/run.sh --list)" >&2; exit 2; }
done
run_job() { echo "== $1 (start $(date +%T))"; "$1" > /dev/null; echo "== $1 done $(date +%T)"; }
if [ "${JOBS:-1}" -gt 1 ]; then
  pids=()
  for j in "${jobs[@]}"; do
    while [ "$(jobs -rp | wc -l)" -ge "$JOBS" ]; do wait -n || true; done
    run_job "$j" &
    pids+=($!)
  done
  status=0
  for p in "${pids[@]}"; do wait "$p" || status=1; done
  exit $status
else
  for j in "${jobs[@]}"; do run_job "$j"; done
fi
