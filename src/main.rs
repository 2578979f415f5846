//! hytled command-line interface (clap only; the work lives in the library).

use hytled::InputKind;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand, ValueEnum};

use hytled::error::exit;
use hytled::io::vtu::VtuFormat;
use hytled::simulation::{self, RunOptions};

/// Hybrid TLED finite-element / meshless solver for large soft-tissue deformation. SI units
/// throughout (m, kg, s, N, Pa, J).
#[derive(Parser)]
#[command(
    name = "hytled",
    version,
    about,
    after_help = "Exit codes: 0 success (a dynamic run completed, a relaxation converged); \
2 input error (scene, mesh, selection, flag, a discretization too large for the memory); 3 the solution diverged or a point inverted; \
4 relaxation not converged within solver.max_steps, or a static solve stopped short of the full load \
(solver.relaxation_fallback = false, or its relaxation failing too; the summary is still printed and written); \
5 a file could not be read or written; 130 stopped by Ctrl-C (SIGINT), 143 by SIGTERM (between two steps, \
summary.json says \"failed\" with error \"interrupted\"; a second signal ends at once); 1 anything else. With --json, a failed command prints \
{\"status\": \"failed\", \"error\", \"exit_code\", \"message\"} on stdout."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// `--device`.
#[derive(Clone, Copy, ValueEnum)]
enum DeviceArg {
    /// The CPU threads.
    Cpu,
    /// NVIDIA GPU 0 (CUDA driver and NVRTC loaded at run time); the same results bitwise.
    Gpu,
    /// The GPU kernels compiled for the CPU with g++ (tests and debugging; slow).
    #[value(hide = true)]
    Emulated,
}

impl DeviceArg {
    /// The scene override that selects this device.
    fn set(self) -> String {
        let name = match self {
            DeviceArg::Cpu => "cpu",
            DeviceArg::Gpu => "gpu",
            DeviceArg::Emulated => "emulated",
        };
        format!("solver.device={name}")
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum VtuArg {
    Ascii,
    Binary,
    Appended,
}

impl From<VtuArg> for VtuFormat {
    fn from(v: VtuArg) -> Self {
        match v {
            VtuArg::Ascii => VtuFormat::Ascii,
            VtuArg::Binary => VtuFormat::Binary,
            VtuArg::Appended => VtuFormat::Appended,
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene and print a summary (or JSON).
    Run(RunArgs),
    /// Run a scene with each discretization (FE, coupled, meshless) and print one table of
    /// cost and error against the scene's references.
    Compare(CompareArgs),
    /// Run a scene once per combination of varied values (the speed/accuracy trade): one row
    /// per run with error vs reference, wall times, steps, dt, nodes, points and memory; a
    /// failed run is a row with its error. Writes sweep.csv/.md/.json and error plots to --out.
    Sweep(SweepArgs),
    /// Time whole runs: preprocessing, ms per step, ns per point-step, real-time factor, peak
    /// memory, bytes per point, thread scaling (and a check that every thread count gives
    /// bitwise the same result). Without SCENE: the Horton 2010 meshless cylinder (4,389 nodes,
    /// 2 points per node, 8 support nodes), one-point hex8 on the same nodes, and coupled.
    Bench(BenchArgs),
    /// Validate a scene (schema, selections, mesh, probes) without running it.
    Check(CheckArgs),
    /// Print a Markdown table from run summaries (files written by `run --json` or summary.json).
    Table(TableArgs),
    /// Convert a mesh file (.inp, .msh, .vtk, .vtu) with its named sets to .vtu or .inp.
    Convert(ConvertArgs),
    /// Mesh a scene's geometry and write it as VTU (default meshes/NAME-ELEMENT.vtu).
    Mesh(MeshArgs),
}

/// Arguments of `hytled run`.
#[derive(Args)]
struct RunArgs {
    /// Scene file (TOML), e.g. cases/cylinder-compression.toml.
    scene: PathBuf,
    /// Override a scene value by its dotted path, e.g. --set discretization.element=tet4-anp.
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    set: Vec<String>,
    /// Write VTU frames + .pvd, history.csv and summary.json to this directory.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print one JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long)]
    threads: Option<usize>,
    /// VTU encoding.
    #[arg(long, value_enum, default_value = "binary")]
    vtu_format: VtuArg,
    /// Seconds between plain progress lines on stderr (default 10 when stderr is not a
    /// terminal, e.g. batch jobs and logs; a terminal shows a bar instead).
    #[arg(long, value_name = "SECONDS")]
    progress_every: Option<f64>,
    /// Where the time loop runs (overrides the scene's solver.device): cpu or gpu (NVIDIA,
    /// bitwise the same results).
    #[arg(long, value_enum)]
    device: Option<DeviceArg>,
}

/// Arguments of `hytled compare`.
#[derive(Args)]
struct CompareArgs {
    scene: PathBuf,
    /// Comma-separated methods: fe, coupled, meshless.
    #[arg(long, default_value = "fe,coupled,meshless")]
    methods: String,
    /// Comma-separated solver modes to run each method in (relaxation, static, dynamic), e.g.
    /// --modes relaxation,static: wall time and force evaluations side by side (default: the
    /// scene's solver.mode).
    #[arg(long, value_name = "MODES")]
    modes: Option<String>,
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    set: Vec<String>,
    /// Print a JSON array of the per-method results instead of the table.
    #[arg(long)]
    json: bool,
    /// Write each run's outputs to DIR/METHOD (DIR/METHOD-MODE with --modes), plus
    /// compare.csv, compare.md, reactions.svg.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    #[arg(long, value_enum, default_value = "binary")]
    vtu_format: VtuArg,
    /// Where the time loop runs (overrides the scene's solver.device): cpu or gpu (NVIDIA,
    /// bitwise the same results).
    #[arg(long, value_enum)]
    device: Option<DeviceArg>,
}

/// Arguments of `hytled sweep`.
#[derive(Args)]
struct SweepArgs {
    scene: PathBuf,
    /// KEY.PATH=V1,V2,... (any --set path; repeat for a cartesian product), e.g.
    /// --vary discretization.method=fe,coupled --vary discretization.divisions=[4,2,8],[6,3,12]
    #[arg(long = "vary", value_name = "KEY.PATH=V1,V2,...")]
    vary: Vec<String>,
    /// A named group of overrides, NAME=key.path=v;key.path=v (repeat: the presets form one
    /// varied dimension, `preset`), e.g. --preset 'mmls=discretization.method=meshless;discretization.basis=quadratic'
    #[arg(long = "preset", value_name = "NAME=KEY.PATH=V;...")]
    preset: Vec<String>,
    /// Fixed overrides applied to every run.
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    set: Vec<String>,
    /// Run each combination N times and report the fastest (wall times only differ).
    #[arg(long, default_value_t = 1)]
    repeat: usize,
    /// Write sweep.csv, sweep.md, sweep.json, error_vs_time.svg and error_vs_spacing.svg.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write every run's full outputs (VTU, history) to DIR/runs/<id>, where <id> is a
    /// hash of the run's overrides; its summary.json and row.json go there always.
    #[arg(long)]
    keep_outputs: bool,
    /// Keep the runs DIR (--out) already holds and run only the missing and failed ones.
    #[arg(long)]
    resume: bool,
    /// Run N scenes at once, each on its share of the threads (peak memory is then not
    /// measured per run).
    #[arg(long, default_value_t = 1, value_name = "N")]
    jobs: usize,
    /// Print the rows as a JSON array instead of the table.
    #[arg(long)]
    json: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    #[arg(long, value_enum, default_value = "binary")]
    vtu_format: VtuArg,
    /// Where the time loop runs (overrides the scene's solver.device): cpu or gpu (NVIDIA,
    /// bitwise the same results).
    #[arg(long, value_enum)]
    device: Option<DeviceArg>,
}

/// Arguments of `hytled bench`.
#[derive(Args)]
struct BenchArgs {
    /// Scene files (default: the three cylinder cases).
    scenes: Vec<PathBuf>,
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    set: Vec<String>,
    /// Comma-separated thread counts (default: 1, powers of two, all cores).
    #[arg(long, value_delimiter = ',')]
    threads: Option<Vec<usize>>,
    /// Explicit time steps per run.
    #[arg(long, default_value_t = 2000)]
    steps: usize,
    /// Runs per thread count; the fastest is reported.
    #[arg(long, default_value_t = 3)]
    repeat: usize,
    /// Print the rows as JSON instead of the table.
    #[arg(long)]
    json: bool,
    /// Also time each case on this device after the CPU thread counts (gpu: one more row,
    /// whose "bitwise identical" compares it with the first CPU row).
    #[arg(long, value_enum)]
    device: Option<DeviceArg>,
}

/// Arguments of `hytled check`.
#[derive(Args)]
struct CheckArgs {
    scene: PathBuf,
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    set: Vec<String>,
}

/// Arguments of `hytled table`.
#[derive(Args)]
struct TableArgs {
    /// JSON summary files.
    #[arg(required = true)]
    summaries: Vec<PathBuf>,
}

/// Arguments of `hytled convert`.
#[derive(Args)]
struct ConvertArgs {
    /// Input mesh.
    input: PathBuf,
    /// Output mesh (.vtu or .inp).
    output: PathBuf,
    /// VTU encoding (ascii and binary read back with VTK readers and hytled).
    #[arg(long, value_enum, default_value = "binary")]
    vtu_format: VtuArg,
}

/// Arguments of `hytled mesh`.
#[derive(Args)]
struct MeshArgs {
    scene: PathBuf,
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    set: Vec<String>,
    /// Output file (.vtu).
    #[arg(long)]
    out: Option<PathBuf>,
    /// VTU encoding.
    #[arg(long, value_enum, default_value = "binary")]
    vtu_format: VtuArg,
    /// Also write the inputs of a mixed coupled scene made from this mesh: the outer
    /// `discretization.fe_layers` cell layers as FE_LAYER.inp and the interior-only nodes as
    /// CLOUD.csv (x,y,z in m).
    #[arg(long, num_args = 2, value_names = ["FE_LAYER.inp", "CLOUD.csv"])]
    split: Option<Vec<PathBuf>>,
}

/// An allocation that fails exits with a message and code 2, not an abort.
#[global_allocator]
static ALLOCATOR: hytled::memory::ExitOnOom = hytled::memory::ExitOnOom;

fn main() -> ExitCode {
    let cli = Cli::parse();
    let json = match &cli.command {
        Command::Run(a) => a.json,
        Command::Compare(a) => a.json,
        Command::Sweep(a) => a.json,
        Command::Bench(a) => a.json,
        _ => false,
    };
    hytled::memory::ExitOnOom::report_json(json);
    // Ctrl-C and SIGTERM stop a run between steps with a "failed: interrupted" summary.
    if let Err(e) = hytled::interrupt::install() {
        eprintln!("warning: Ctrl-C and SIGTERM will end runs without a summary: {e}");
    }
    match execute(cli.command) {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            eprintln!("error: {e}");
            if json {
                // Scripts reading stdout get an object in every case.
                let mut obj = e.to_json();
                obj["status"] = "failed".into();
                println!("{}", serde_json::to_string_pretty(&obj).unwrap_or_default());
            }
            ExitCode::from(e.exit_code())
        }
    }
}

/// Prints the preparation's stages (`log::info!` in the library) as progress lines on
/// stderr, with the seconds since the command started: meshing, shape functions and the
/// critical-step estimate take seconds to minutes on organ-scale scenes before the time
/// loop's own progress begins.
struct StageLines {
    start: std::time::Instant,
    level: log::Level,
}

impl log::Log for StageLines {
    fn enabled(&self, m: &log::Metadata) -> bool {
        m.level() <= self.level && m.target().starts_with("hytled")
    }
    fn log(&self, r: &log::Record) {
        if self.enabled(r.metadata()) {
            eprintln!(
                "progress: {} ({:.1} s elapsed)",
                r.args(),
                self.start.elapsed().as_secs_f64()
            );
        }
    }
    fn flush(&self) {}
}

fn show_stages() {
    // HYTLED_LOG=debug adds the solvers' diagnostic lines (each Newton iteration's residual,
    // factorizations, timings) to the stage lines.
    let level = match std::env::var("HYTLED_LOG").as_deref() {
        Ok("debug") => log::Level::Debug,
        Ok("trace") => log::Level::Trace,
        _ => log::Level::Info,
    };
    let logger = StageLines {
        start: std::time::Instant::now(),
        level,
    };
    // Once per process: the leaked box lives as long as the program.
    if log::set_logger(Box::leak(Box::new(logger))).is_ok() {
        log::set_max_level(level.to_level_filter());
    }
}

/// Starts the global thread pool with `--threads n`: at least 1, at most the machine's cores
/// (more would only add contention; a warning says so).
fn start_threads(threads: Option<usize>) -> hytled::Result<()> {
    let Some(n) = threads else { return Ok(()) };
    if n == 0 {
        return Err(hytled::Error::input(
            InputKind::Value,
            "--threads must be at least 1",
        ));
    }
    let cores = std::thread::available_parallelism().map_or(1, |c| c.get());
    let n = if n > cores {
        eprintln!("warning: --threads {n} is more than the {cores} cores here; using {cores}");
        cores
    } else {
        n
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
        .map_err(|e| {
            hytled::Error::input(InputKind::Value, format!("cannot start {n} threads: {e}"))
        })
}

fn execute(cmd: Command) -> hytled::Result<u8> {
    match cmd {
        Command::Run(a) => run(a),
        Command::Check(a) => check(a),
        Command::Convert(a) => convert(a),
        Command::Bench(a) => bench(a),
        Command::Compare(a) => compare(a),
        Command::Sweep(a) => sweep(a),
        Command::Table(a) => table(a),
        Command::Mesh(a) => mesh(a),
    }
}

/// `hytled run`; the exit code.
fn run(
    RunArgs {
        scene,
        set,
        out,
        json,
        threads,
        vtu_format,
        progress_every,
        device,
    }: RunArgs,
) -> hytled::Result<u8> {
    let mut set = set;
    set.extend(device.map(DeviceArg::set));
    start_threads(threads)?;
    if progress_every.is_some_and(|p| !(p >= 0.0 && p.is_finite())) {
        return Err(hytled::Error::input(
            InputKind::Value,
            "--progress-every must be a number of seconds, 0 or more",
        ));
    }
    let sc = hytled::scene::load(&scene, &set)?;
    let opts = RunOptions {
        out: out.clone(),
        progress: !json && std::io::stderr().is_terminal(),
        progress_lines: progress_every.or((!std::io::stderr().is_terminal()).then_some(10.0)),
        vtu_format: vtu_format.into(),
    };
    if opts.progress || opts.progress_lines.is_some() {
        show_stages();
    }
    let summary = simulation::run_scene(&sc, &opts)?;
    for w in &summary.warnings {
        eprintln!("warning: {}", hytled::error::tidy_exponents(w));
    }
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&summary).unwrap_or_default()
        );
    } else {
        print!("{}", summary.table());
        if let Some(dir) = out {
            println!("outputs written to {}", dir.display());
        }
    }
    if summary.status == "not converged" {
        // A static solve that fell back to relaxation ends as that relaxation does.
        match summary
            .statics
            .as_ref()
            .filter(|st| st.fallback_from.is_none())
        {
            Some(st) => eprintln!(
                "error: the static solve reached equilibrium up to {:.4} % of the load only (the \
                 warnings above say where it stopped); the results there are written: try \
                 solver.mode = \"relaxation\" or check the load and the constraints",
                100.0 * st.load_reached
            ),
            None => eprintln!(
                "error: relaxation did not converge in {} steps (solver.max_steps); the results \
                 are not in equilibrium: raise solver.max_steps or check the load and the \
                 constraints",
                summary.steps
            ),
        }
        return Ok(exit::NOT_CONVERGED);
    }
    Ok(exit::SUCCESS)
}

/// `hytled check`; the exit code.
fn check(CheckArgs { scene, set }: CheckArgs) -> hytled::Result<u8> {
    let sc = hytled::scene::load(&scene, &set)?;
    let mut prep = simulation::prepare(&sc)?;
    let (dt, p) = simulation::critical_step(&sc, &mut prep)?;
    for w in &prep.warnings {
        eprintln!("warning: {}", hytled::error::tidy_exponents(w));
    }
    println!("{}: valid", scene.display());
    println!(
        "  nodes {}, elements {}, integration points {} (total weight {:.6e} m^3)",
        prep.model.nodes().len(),
        prep.mesh.num_cells(),
        prep.model.points().len(),
        prep.model.points().total_weight()
    );
    if let Some(m) = prep.meshless() {
        let (mean, min, max) = m.support_statistics();
        let exact = m
            .exact_volume
            .map_or(String::new(), |v| format!("; exact volume {v:.6e} m^3"));
        println!(
            "  meshless: {}; {}; support {mean:.1} nodes per point (min {min}, max {max}); {} node(s) removed{exact}",
            m.cloud, m.integration, m.removed_nodes
        );
    }
    if let Some(c) = prep.coupled() {
        use hytled::coupling::regions::CellRole;
        let full = if c.full_rule_cells > 0 {
            format!(
                " ({} on the full rule next to a load concentrated on a few driven nodes)",
                c.full_rule_cells
            )
        } else {
            String::new()
        };
        println!(
            "  coupled: {} FE, {} transition{full} and {} meshless cells; points {} FE, {} transition, {} meshless",
            c.regions.cells(CellRole::Fe),
            c.regions.cells(CellRole::Transition),
            c.interior.num_cells(),
            c.fe_points,
            c.transition_points,
            c.meshless_points
        );
    }
    for b in prep.model.boundaries() {
        println!("  boundary {:<12} {} nodes", b.name, b.nodes.len());
    }
    for hytled::simulation::RegionPoints {
        name,
        points: count,
    } in &prep.regions
    {
        println!("  region {name:<14} {count} integration points");
    }
    for name in prep.model.loads().names() {
        println!("  load {name}");
    }
    if let Some(c) = prep.model.contact() {
        for (b, name) in c.names().enumerate() {
            println!(
                "  contact {name:<13} {} candidate surface points",
                c.candidates(b)
            );
        }
    }
    for pr in &prep.probes {
        match pr.element {
            Some(e) => println!("  probe {:<15} in element {e}", pr.name),
            None => println!(
                "  probe {:<15} interpolated from {} nodes",
                pr.name,
                pr.nodes.len()
            ),
        }
    }
    if let Some(hytled::simulation::MinDihedral {
        degrees: a,
        element: e,
    }) = prep.min_dihedral
    {
        println!("  min dihedral angle {a:.2} deg (element {e})");
    }
    println!(
        "  critical time step {dt:.4e} s (set by {p}); dt = {:.4e} s",
        dt * sc.solver.dt_factor
    );
    Ok(exit::SUCCESS)
}

/// `hytled convert`; the exit code.
fn convert(
    ConvertArgs {
        input,
        output,
        vtu_format,
    }: ConvertArgs,
) -> hytled::Result<u8> {
    let mut m = hytled::io::mesh_file::read_mesh(&input, None, 1.0)?;
    if hytled::scene::MeshFormat::from_path(&output) == Some(hytled::scene::MeshFormat::Inp) {
        let renamed = hytled::io::mesh_file::inp_safe_set_names(&mut m);
        m.warnings.extend(renamed);
    }
    for w in &m.warnings {
        eprintln!("warning: {}", hytled::error::tidy_exponents(w));
    }
    hytled::io::mesh_file::write_mesh_file(&output, &m, vtu_format.into())?;
    println!(
        "{} -> {}: {} nodes, {} cells, {} node sets, {} element sets, {} face sets",
        input.display(),
        output.display(),
        m.mesh.nodes.len(),
        m.mesh.num_cells(),
        m.node_sets.len(),
        m.element_sets.len(),
        m.face_sets.len()
    );
    Ok(exit::SUCCESS)
}

/// `hytled bench`; the exit code.
fn bench(
    BenchArgs {
        scenes,
        set,
        threads,
        steps,
        repeat,
        json,
        device,
    }: BenchArgs,
) -> hytled::Result<u8> {
    use hytled::bench;
    let cases = if scenes.is_empty() {
        bench::default_cases(&set)?
    } else {
        scenes
            .iter()
            .map(|p| {
                let scene = hytled::scene::load(p, &set)?;
                Ok(bench::BenchCase {
                    label: p.display().to_string(),
                    scene,
                })
            })
            .collect::<hytled::Result<Vec<_>>>()?
    };
    let opts = bench::BenchOptions {
        steps,
        threads: threads.unwrap_or_else(bench::default_threads),
        repeat,
        progress: true,
        device: match device {
            None | Some(DeviceArg::Cpu) => hytled::solver::Device::Cpu,
            Some(DeviceArg::Gpu) => hytled::solver::Device::Gpu,
            Some(DeviceArg::Emulated) => hytled::solver::Device::Emulated,
        },
    };
    // A missing GPU is said before minutes of CPU timings, not after them.
    if opts.device == hytled::solver::Device::Gpu {
        hytled::solver::gpu::probe()?;
    }
    let mut rows = Vec::new();
    for c in &cases {
        rows.extend(bench::run_case(c, &opts)?);
    }
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).unwrap_or_default()
        );
    } else {
        println!("{}", bench::table(&rows));
        println!("SI units; times are wall-clock seconds on this machine.");
    }
    Ok(exit::SUCCESS)
}

/// `hytled compare`; the exit code.
fn compare(
    CompareArgs {
        scene,
        methods,
        modes,
        set,
        json,
        out,
        threads,
        vtu_format,
        device,
    }: CompareArgs,
) -> hytled::Result<u8> {
    let mut set = set;
    set.extend(device.map(DeviceArg::set));
    start_threads(threads)?;
    let methods = hytled::comparison::parse_methods(&methods)?;
    let modes = match modes {
        Some(m) => hytled::comparison::parse_modes(&m)?,
        None => Vec::new(),
    };
    // The preparation's stages (meshing, shape functions) as they happen.
    show_stages();
    let opts = hytled::comparison::CompareOptions {
        out,
        vtu_format: vtu_format.into(),
        progress: true,
        modes,
    };
    let rows = hytled::comparison::run_compare(&scene, &set, &methods, &opts)?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).map_err(|e| hytled::Error::input(
                InputKind::Value,
                format!("cannot serialise the comparison: {e}")
            ))?
        );
    } else {
        print!("{}", hytled::comparison::table(&rows));
    }
    for r in &rows {
        if let Some(s) = &r.summary {
            for w in &s.warnings {
                eprintln!(
                    "warning ({}): {}",
                    r.label(),
                    hytled::error::tidy_exponents(w)
                );
            }
        }
    }
    if rows.iter().all(|r| r.error.is_some()) {
        return Err(hytled::Error::input(
            InputKind::Value,
            "compare: every run failed",
        ));
    }
    Ok(exit::SUCCESS)
}

/// `hytled sweep`; the exit code.
fn sweep(
    SweepArgs {
        scene,
        vary,
        preset,
        set,
        repeat,
        out,
        keep_outputs,
        resume,
        jobs,
        json,
        threads,
        vtu_format,
        device,
    }: SweepArgs,
) -> hytled::Result<u8> {
    let mut set = set;
    set.extend(device.map(DeviceArg::set));
    start_threads(threads)?;
    if repeat == 0 {
        return Err(hytled::Error::input(
            InputKind::Value,
            "--repeat 0: give at least 1 run per combination",
        ));
    }
    if keep_outputs && out.is_none() {
        return Err(hytled::Error::input(
            InputKind::Value,
            "--keep-outputs needs --out DIR to write the runs to",
        ));
    }
    if resume && out.is_none() {
        return Err(hytled::Error::input(
            InputKind::Value,
            "--resume needs --out DIR, the folder of the sweep to go on with",
        ));
    }
    if jobs == 0 {
        return Err(hytled::Error::input(
            InputKind::Value,
            "--jobs 0: give at least 1 run at a time",
        ));
    }
    let varies = vary
        .iter()
        .map(|v| hytled::sweep::parse_vary(v))
        .collect::<hytled::Result<Vec<_>>>()?;
    let mut presets = std::collections::BTreeMap::new();
    for p in &preset {
        let (name, sets) = hytled::sweep::parse_preset(p)?;
        if presets.insert(name.clone(), sets).is_some() {
            return Err(hytled::Error::input(
                InputKind::Value,
                format!("--preset {name} is given twice"),
            ));
        }
    }
    let opts = hytled::sweep::SweepOptions {
        presets,
        out,
        repeat,
        keep_outputs,
        vtu_format: vtu_format.into(),
        progress: true,
        resume,
        jobs,
    };
    let rows = hytled::sweep::run_sweep(&scene, &set, &varies, &opts)?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rows).map_err(|e| hytled::Error::input(
                InputKind::Value,
                format!("cannot serialise the sweep: {e}")
            ))?
        );
    } else {
        let dims = hytled::sweep::dimensions(&varies, &opts.presets);
        print!("{}", hytled::sweep::table(&dims, &rows));
    }
    if rows.iter().all(|r| r.error.is_some()) {
        return Err(hytled::Error::input(
            InputKind::Value,
            "sweep: every run failed",
        ));
    }
    Ok(exit::SUCCESS)
}

/// `hytled table`; the exit code.
fn table(TableArgs { summaries }: TableArgs) -> hytled::Result<u8> {
    let mut vals = Vec::new();
    for p in &summaries {
        let text = std::fs::read_to_string(p).map_err(|e| hytled::Error::io(p, e))?;
        let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
            hytled::Error::input(
                InputKind::Format,
                format!("{}: not a JSON run summary: {e}", p.display()),
            )
        })?;
        vals.push(v);
    }
    print!("{}", hytled::report::markdown_table(&vals));
    Ok(exit::SUCCESS)
}

/// `hytled mesh`; the exit code.
fn mesh(
    MeshArgs {
        scene,
        set,
        out,
        vtu_format,
        split,
    }: MeshArgs,
) -> hytled::Result<u8> {
    let sc = hytled::scene::load(&scene, &set)?;
    let mesh = simulation::build_mesh(&sc)?;
    let path = out.unwrap_or_else(|| {
        PathBuf::from(format!(
            "meshes/{}-{}.vtu",
            sc.name.clone().unwrap_or_default(),
            hytled::fe::ElementKind::from(sc.discretization.element).name()
        ))
    });
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| hytled::Error::io(dir, e))?;
    }
    hytled::io::vtu::write_mesh(&path, &mesh, vec![], vec![], vtu_format.into())?;
    println!(
        "{}: {} nodes, {} elements",
        path.display(),
        mesh.nodes.len(),
        mesh.num_cells()
    );
    if let Some(d) = hytled::geometry::quality::min_dihedral_angle(&mesh) {
        println!(
            "min dihedral angle {:.2} deg (element {})",
            d.degrees, d.element
        );
    }
    if let Some(paths) = split {
        let (fe_path, cloud_path) = (&paths[0], &paths[1]);
        let (n_fe, n_cloud) = hytled::coupling::regions::write_split_inputs(
            &mesh,
            sc.discretization.fe_layers(),
            fe_path,
            cloud_path,
        )?;
        println!(
            "{}: FE layer ({} layer(s)), {n_fe} nodes; {}: {n_cloud} interior nodes",
            fe_path.display(),
            sc.discretization.fe_layers(),
            cloud_path.display()
        );
    }
    Ok(exit::SUCCESS)
}
