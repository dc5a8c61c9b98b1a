//! The `bifirst` command line: run (and restart), sweep (whole, sharded, as a Slurm array), sweep-report,
//! accuracy, stability, state, check, plot, summary, bench and info.

use bifirst::backend::BackendChoice;
use bifirst::bench::BenchOptions;
use bifirst::scene::load_scene;
use bifirst::stability::Budget;
use bifirst::sweep::{report, SbatchOption, Shard};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

mod cli;

use crate::cli::{args::*, bench::*, logs::*, run::*, studies::*};

#[derive(Parser)]
#[command(name = "bifirst", version, about = "Dynamic frictional contact between hyperelastic bodies (Bi-First)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Worker threads for the kernels, factorisations and Newton solves (default: every core;
    /// 1 to 1024). A sweep's jobs share one pool of this many threads.
    #[arg(long, global = true, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=MAX_THREADS))]
    threads: Option<u64>,
}

/// The most worker threads `--threads` starts: past the cores of the largest machines, threads
/// only wait on each other (doc/benchmarks.md, "Figures behind constants").
const MAX_THREADS: u64 = 1024;

/// The most runs per variant `accuracy --repeat` takes: a median needs a few, not millions.
const MAX_REPEAT: u64 = 1000;

#[derive(Subcommand)]
enum Command {
    /// Run a scene and write its MCAP run log.
    Run {
        /// The scene file (not with `--restart`, which takes the logged run's scene).
        #[arg(required_unless_present = "restart", conflicts_with = "restart")]
        scene: Option<PathBuf>,
        /// Continue the run logged in this MCAP from its last state (`/state`); `--set` changes
        /// the logged scene (`time.end`, `time.dt`, solver settings; not the meshes).
        #[arg(long, value_name = "RUN.mcap")]
        restart: Option<PathBuf>,
        /// With `--restart`: the last state at or before this time instead of the last one.
        #[arg(long, value_name = "T", requires = "restart")]
        at: Option<f64>,
        /// Output MCAP file (default: the scene's `output.mcap`, else `<scene name>.mcap`; with
        /// `--restart`, `<RUN>_restart.mcap`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a scene value before validation, e.g. `--set time.dt=0.005` (TOML literal).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Write VTU frames and `.pvd` series for ParaView into this directory.
        #[arg(long, value_name = "DIR")]
        vtu: Option<PathBuf>,
        /// Draw the von Mises contours of the final state into this PNG (2D scenes).
        #[arg(long, value_name = "FILE.png")]
        contour: Option<PathBuf>,
        /// No progress and no summary line; only errors.
        #[arg(long, short)]
        quiet: bool,
        /// Print the final summary as JSON on stdout.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// Run a scene over a grid of values (`--over KEY=V1,V2,...`, several make a grid), the
    /// variants in parallel, one MCAP log each, then overlaid plots and a summary table.
    Sweep {
        #[command(flatten)]
        grid: GridArgs,
        /// Directory for the logs (`<stem>.mcap`) and `plots/` (default: `<scene name>_sweep`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Variants run at the same time (default: the number of cores).
        #[arg(long)]
        jobs: Option<usize>,
        /// Probes `B,C,D`: also plot B's path in the plane BCD.
        #[arg(long, value_name = "B,C,D", value_parser = parse_trace)]
        trace: Option<[String; 3]>,
        #[command(flatten)]
        backend: BackendArgs,
        /// Print the report as JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Run only a share of the grid, variants K, K+N, K+2N, ... (0 <= K < N), e.g. one
        /// share per machine; `sweep-report DIR` merges the logs afterwards.
        #[arg(long, value_name = "K/N", conflicts_with = "index")]
        shard: Option<Shard>,
        /// Run only the variant with this index (`--list` shows them): what a job-array task runs.
        #[arg(long, value_name = "I")]
        index: Option<usize>,
        /// Print the variants (index, label, log path), without running them.
        #[arg(long, conflicts_with = "slurm")]
        list: bool,
        /// Write a Slurm job-array script, one array task per variant (`--threads` CPUs each),
        /// instead of running; submit it with `sbatch FILE`.
        #[arg(long, value_name = "FILE", conflicts_with_all = ["shard", "index"])]
        slurm: Option<PathBuf>,
        /// An `#SBATCH` directive for the script, e.g. `--sbatch partition=short --sbatch
        /// time=02:00:00 --sbatch mem=4G` (a key of the script's own replaces its default).
        #[arg(long, value_name = "KEY=VALUE", requires = "slurm")]
        sbatch: Vec<SbatchOption>,
    },
    /// The summary table and overlaid plots of a sweep directory's logs, whoever produced them
    /// (one machine, shards, a Slurm job array), naming the variants missing or not finished.
    SweepReport {
        dir: PathBuf,
        /// Print the report as JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Probes `B,C,D`: also plot B's path in the plane BCD.
        #[arg(long, value_name = "B,C,D", value_parser = parse_trace)]
        trace: Option<[String; 3]>,
    },
    /// Run time against error for a known-answer scene over a grid of settings (scene keys, and
    /// `backend`, `precision` and `uzawa`): a table, a CSV and a PNG with the Pareto front marked.
    Accuracy {
        #[command(flatten)]
        grid: GridArgs,
        /// The known answer to measure against (default: the scene's name).
        #[arg(long, value_name = "NAME")]
        measure: Option<String>,
        /// Directory for the logs, `accuracy.csv` and `accuracy.png` (default: `<scene name>_accuracy`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Runs per variant (1 to 1000); the median wall time is reported.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=MAX_REPEAT))]
        repeat: u64,
        /// The error to reach: the cheapest variant within it is named.
        #[arg(long, default_value_t = 0.01, value_parser = parse_positive)]
        target: f64,
        #[command(flatten)]
        backend: BackendArgs,
        /// Print the rows as JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Stress a scene over a grid of variants (any scene keys: time step, theta, speeds,
    /// stiffness, friction), one at a time: each is stable, degraded (finished with warnings),
    /// failed or too slow; a table, `stability.csv`, `stability.png` (a map over the first two
    /// axes) and the largest stable value along each axis. Exit 0 when every variant is stable.
    Stability {
        #[command(flatten)]
        grid: GridArgs,
        /// Directory for the logs, `stability.csv` and `stability.png` (default: `<scene name>_stability`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Uzawa sweeps per step above which a run is too slow.
        #[arg(long, default_value_t = 2000.0, value_parser = parse_positive)]
        max_sweeps: f64,
        /// Wall seconds after which a run still going is stopped as too slow.
        #[arg(long, default_value_t = 300.0, value_parser = parse_positive)]
        max_wall: f64,
        #[command(flatten)]
        backend: BackendArgs,
        /// Print the rows as JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Draw or export a state a run logged (`/state`): the last, or the last at or before `--at`.
    State {
        run: PathBuf,
        /// The last state at or before this time.
        #[arg(long, value_name = "T")]
        at: Option<f64>,
        /// Draw the von Mises contours of that state into this PNG (2D scenes).
        #[arg(long, value_name = "FILE.png")]
        contour: Option<PathBuf>,
        /// Write that state as VTU files (and `.pvd` series) for ParaView into this directory.
        #[arg(long, value_name = "DIR")]
        vtu: Option<PathBuf>,
    },
    /// Plot run logs into PNGs (energies, solver, probes); several logs are overlaid.
    Plot {
        #[arg(required = true)]
        runs: Vec<PathBuf>,
        /// Directory for the PNGs (default: `<first log without .mcap>_plots`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Probes `B,C,D`: also plot B's path in the plane BCD.
        #[arg(long, value_name = "B,C,D", value_parser = parse_trace)]
        trace: Option<[String; 3]>,
    },
    /// Print the totals of run logs as a table (one column per log).
    Summary {
        #[arg(required = true)]
        runs: Vec<PathBuf>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Validate a scene (and build its meshes) without running it.
    Check {
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
    },
    /// Benchmark every kernel: its CPU twin and, on a GPU adapter, the kernel in f64 and f32
    /// (time per call, throughput, bytes moved, error against the CPU in f64).
    Bench {
        /// About this many elements per case (4x as many contact points for `uzawa_step`).
        #[arg(long, default_value_t = 4096)]
        elements: usize,
        /// Only kernels whose name contains this.
        #[arg(long)]
        kernel: Option<String>,
        /// Only element rows whose element (`hex8`, `quad4+fbar`) contains this.
        #[arg(long)]
        element: Option<String>,
        /// Only element rows whose material (`blatz_ko`, `ogden`) contains this.
        #[arg(long)]
        material: Option<String>,
        /// `auto`: the GPU columns when an adapter exists; `gpu`: they are required; `cpu`: none.
        #[arg(long, default_value = "auto", value_parser = parse_backend)]
        backend: BackendChoice,
        /// A GPU adapter by name (case-insensitive substring).
        #[arg(long, value_name = "NAME")]
        adapter: Option<String>,
        /// Seconds of calls per measurement (at least three calls).
        #[arg(long, default_value_t = 0.5)]
        time: f64,
        /// Every element with every material (by default each element with the Blatz-Ko foam
        /// only, unless `--material` picks).
        #[arg(long)]
        all: bool,
        /// One JSON object per row instead of the table.
        #[arg(long)]
        json: bool,
    },
    /// Granular measures from a run's contact network (`/contacts`): solid fraction,
    /// coordination (with and without rattlers), sliding contacts, fabric, Love-Weber stress
    /// and the walls' pressures per logged step (`grains.csv`), the distribution of normal
    /// forces and contact orientations at one step (`grains.json`), and pictures: force chains,
    /// the time series, the force distribution, the orientation rose (doc/grains.md).
    Grains {
        run: PathBuf,
        /// Directory for `grains.csv`, `grains.json` and the PNGs (default: `<RUN>_grains`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// The step of the distributions and the force-chain picture: the last logged at or
        /// before this time (default: the last).
        #[arg(long, value_name = "T")]
        at: Option<f64>,
        /// Also the means of the Love-Weber stress, the walls' pressures and Z over the logged
        /// steps of this time before the chosen step (and at it): a driven packing's inertia
        /// stands between the two stresses at any one step, and falls off in the mean.
        #[arg(long, value_name = "T", value_parser = parse_positive)]
        window: Option<f64>,
        /// Print the report (the chosen step's measures and distributions) as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Print the version, build and compute backends.
    Info,
}

fn main() -> ExitCode {
    // Like other command-line tools, end quietly when the reader of stdout goes away
    // (`bifirst info | head -1`) instead of panicking in `println!`. Rust ignores SIGPIPE.
    // SAFETY: called before any thread starts; SIG_DFL is a valid disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Mesa's Vulkan device-select layer connects to the display server to order GPUs, and
    // complains on headless machines; bifirst ranks adapters itself. Set before any thread starts.
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
    let cli = Cli::parse();
    if let Some(threads) = cli.threads.map(|n| n as usize) {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        if threads > cores {
            eprintln!("warning: --threads {threads} is more than this machine's {cores} cores: the extra threads only wait on each other");
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(threads).build_global() {
            eprintln!("error: cannot start {threads} threads: {e}");
            return ExitCode::from(2);
        }
    }
    let result = match cli.command {
        Command::Run { scene, restart, at, out, sets, vtu, contour, quiet, json, backend } => run(RunArgs { backend: backend.into(), scene, restart, at, out, sets, vtu, contour, quiet, json }),
        Command::Sweep { grid, out, jobs, trace, backend, json, shard, index, list, slurm, sbatch } => {
            sweep_command(SweepArgs { grid, out, jobs, trace, backend: backend.into(), json, shard, index, list, slurm, sbatch, threads: cli.threads.map(|n| n as usize) })
        }
        Command::SweepReport { dir, json, trace } => report(&dir).map_err(anyhow::Error::from).and_then(|r| print_report(r, json, trace)),
        Command::Accuracy { grid, measure, out, repeat, target, backend, json } => accuracy_command(AccuracyArgs { grid, measure, out, repeat, target, backend: backend.into(), json }),
        Command::Stability { grid, out, max_sweeps, max_wall, backend, json } => stability_command(&grid, out, Budget { sweeps_per_step: max_sweeps, wall_s: max_wall }, backend.into(), json),
        Command::State { run, at, contour, vtu } => state_command(run, at, contour, vtu),
        Command::Plot { runs, out, trace } => plot_command(runs, out, trace),
        Command::Summary { runs, json } => summary_command(runs, json),
        Command::Check { scene, sets } => load_scene(&scene, &sets).map_err(anyhow::Error::from).and_then(|loaded| {
            let sim = bifirst::solver::build_simulation(&loaded)?;
            let elements: usize = sim.bodies().iter().map(|b| b.mesh().element_count()).sum();
            let dofs: usize = sim.bodies().iter().map(|b| b.dofs().free_count).sum();
            let n = |count: usize, one: &str, many: &str| bifirst::output::counted(count, one, many);
            println!("{}: valid, {}D, {}, {}, {} free dofs, {}", loaded.name, sim.dim(), n(sim.bodies().len(), "body", "bodies"), n(elements, "element", "elements"), dofs, n(sim.step_count(), "step", "steps"));
            // The largest bodies' factorisations: the fill decides the cost of a Newton iteration.
            let mut bodies: Vec<_> = sim.bodies().iter().collect();
            bodies.sort_by_key(|b| std::cmp::Reverse(b.dofs().free_count));
            for b in bodies.iter().take(3) {
                let (ordering, entries) = b.factor_report();
                println!("  body `{}`: {} free dofs, factor with {} ordering: {} entries", b.name(), b.dofs().free_count, ordering.name(), entries);
                let sets: Vec<String> = b.mesh().node_sets.iter().map(|(name, nodes)| format!("{name} ({})", nodes.len())).collect();
                println!("    node sets: {}", if sets.is_empty() { "none".to_string() } else { sets.join(", ") });
            }
            if bodies.len() > 3 {
                println!("  ... and {} more", n(bodies.len() - 3, "body", "bodies"));
            }
            for (name, bc) in &loaded.scene.boundary {
                println!("  boundary `{name}`: node set `{}` of body `{}`", bc.nodes, bc.body);
            }
            Ok(ExitCode::SUCCESS)
        }),
        Command::Bench { elements, kernel, element, material, backend, adapter, time, all, json } => bench_command(BenchOptions { elements, kernel, element, material, min_time: time, all }, backend, adapter, json),
        Command::Grains { run, out, at, window, json } => grains_command(&run, out, at, window, json),
        Command::Info => {
            println!("bifirst {} (git {})", env!("CARGO_PKG_VERSION"), bifirst::run::GIT_REVISION.unwrap_or("unknown"));
            println!("build: {} profile, rustc target {}-{}", if cfg!(debug_assertions) { "debug" } else { "release" }, std::env::consts::ARCH, std::env::consts::OS);
            println!("solver precision: {} (factorisation, time stepping, contact)", bifirst::precision::PRECISION_NAME);
            println!("WGSL kernels: {}", bifirst::gpu::shaders::SHADERS.iter().map(|(name, _)| *name).collect::<Vec<_>>().join(", "));
            println!("  `run --backend gpu` runs the element, assembly and energy kernels on the adapter (every body's first Newton round of a step, later rounds when large: `--rounds`), and the Uzawa sweeps of large contact sets (`--uzawa`); factorisations, solves and contact detection stay on the CPU");
            println!("  `run --backend auto` runs on the CPU: a hardware GPU {}", bifirst::backend::AUTO_REASON_GPU);
            println!("worker threads: {} (--threads)", rayon::current_num_threads());
            let adapters = bifirst::gpu::describe_adapters();
            if adapters.is_empty() {
                println!("GPU adapters: none (install mesa-vulkan-drivers for the lavapipe software adapter)");
            } else {
                println!("GPU adapters, best first:");
                for a in adapters {
                    println!("  {}  driver: {}", a.line(), a.driver);
                }
            }
            Ok(ExitCode::SUCCESS)
        }
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", error_text(&e));
            ExitCode::from(2)
        }
    }
}
