//! The `bifirst` command line: run (and restart), sweep (whole, sharded, as a Slurm array), sweep-report,
//! accuracy, stability, state, check, plot, summary, bench and info.

use anyhow::Result;
use bifirst::backend::{BackendChoice, BackendRequest, RoundPlacement, UzawaPlacement};
use bifirst::bench::{bench_devices, run_bench, BenchOptions};
use bifirst::output::plot::{self, PlotOptions};
use bifirst::output::{read_run, summary};
use bifirst::precision::Precision;
use bifirst::run::{run_scene, Monitor, RunError, RunOptions, RunSummary, Stop};
use bifirst::scene::load_scene;
use bifirst::solver::StepReport;
use bifirst::stability::Budget;
use bifirst::sweep::{report, Report, SbatchOption, Shard, SlurmJob, Sweep, SweepAxis};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Instant;

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
/// only wait on each other (2 000 made a 0.05 s run take 7 s; 100 000 took over a minute to
/// start).
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
        /// Print the report (the chosen step's measures and distributions) as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Print the version, build and compute backends.
    Info,
}

/// A scene and the grid of variants over it (`sweep`, `accuracy`, `stability`).
#[derive(clap::Args)]
struct GridArgs {
    scene: PathBuf,
    /// A scene key and its values, as `--set` takes them (several make a grid); commas inside
    /// brackets belong to a value (`--over body.b.initial_velocity=[1,0],[2,0]`).
    #[arg(long = "over", value_name = "KEY=V1,V2,...", required = true)]
    over: Vec<SweepAxis>,
    /// Overrides applied to every variant before its own.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
}

/// Where a run's kernels go (`run` and `sweep`).
#[derive(clap::Args)]
struct BackendArgs {
    /// Where the element and assembly kernels run: `auto` runs on the CPU, which was measured
    /// faster on every scene (`bifirst info` says why), unless `--adapter` names one; `gpu` takes
    /// a hardware GPU, else a software adapter (lavapipe, slow: CI's GPU path), with a notice.
    #[arg(long, default_value = "auto", value_parser = parse_backend)]
    backend: BackendChoice,
    /// A GPU adapter by name (case-insensitive substring; `bifirst info` lists them).
    #[arg(long, value_name = "NAME")]
    adapter: Option<String>,
    /// GPU kernel precision, f32 or f64 (default: f64 when the adapter has it).
    #[arg(long, value_parser = parse_precision)]
    precision: Option<Precision>,
    /// With the kernels on a GPU, where the Uzawa sweeps of the contact problems run: `auto`
    /// takes the device for large contact sets on a hardware GPU, `gpu` whenever it can
    /// (Gauss-Seidel in f64), `cpu` never.
    #[arg(long, default_value = "auto", value_parser = parse_uzawa)]
    uzawa: UzawaPlacement,
    /// With the kernels on a GPU, which Newton rounds evaluate on the device: `auto` the first
    /// of each step and those with enough elements to gain, the others on the CPU twins; `gpu`
    /// every round.
    #[arg(long, default_value = "auto", value_parser = parse_rounds)]
    rounds: RoundPlacement,
    /// With the kernels on a GPU, time every dispatch on the device and report the time by
    /// kernel (`kernel_times` of the summary); the timestamps cost a little device time.
    #[arg(long)]
    kernel_times: bool,
}

impl From<BackendArgs> for BackendRequest {
    fn from(a: BackendArgs) -> Self {
        BackendRequest { choice: a.backend, adapter: a.adapter, precision: a.precision, uzawa: a.uzawa, rounds: a.rounds, kernel_times: a.kernel_times }
    }
}

/// A progress bar on a terminal; otherwise plain lines about every 10% (at most every 2 s, at
/// least every 30 s).
struct Progress {
    quiet: bool,
    bar: Option<ProgressBar>,
    last_line: Instant,
    last_fraction: f64,
}

impl Monitor for Progress {
    fn backend(&mut self, description: &str) {
        if !self.quiet {
            eprintln!("backend: {description}");
        }
    }
    fn started(&mut self, total: usize) {
        if !self.quiet && std::io::stderr().is_terminal() {
            let bar = ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
            bar.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} steps  t = {msg}  [{elapsed_precise} < {eta}]").expect("valid template"));
            self.bar = Some(bar);
        }
    }
    fn step(&mut self, r: &StepReport, total: usize) {
        if self.quiet {
            return;
        }
        let fraction = r.step as f64 / total as f64;
        match &self.bar {
            Some(bar) => {
                bar.set_position(r.step as u64);
                bar.set_message(format!("{:.4e}", r.t));
            }
            None => {
                let since = self.last_line.elapsed().as_secs_f64();
                if fraction - self.last_fraction >= 0.1 - 1e-12 && since >= 2.0 || since >= 30.0 || r.step == total {
                    eprintln!("step {}/{}  t = {:.4e}  newton {}  cut-backs {}", r.step, total, r.t, r.newton_iterations, r.cutbacks);
                    self.last_line = Instant::now();
                    self.last_fraction = fraction;
                }
            }
        }
    }
    fn warning(&mut self, message: &str) {
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(bar) => bar.println(format!("warning: {message}")),
            None => eprintln!("warning: {message}"),
        }
    }
}

fn print_summary(s: &RunSummary) {
    eprintln!(
        "{}: {} steps to t = {:.6e}, {} Newton iterations, {} cut-backs, {:.2} s wall; dissipated by friction {:.4e}, viscosity {:.4e}, numerically {:.4e}, energy balance error {:.1e}; log written to {}",
        s.scene,
        s.steps,
        s.t_end,
        s.newton_iterations,
        s.cutbacks,
        s.wall_s,
        s.energy.friction_dissipation,
        s.energy.viscous_dissipation,
        s.energy.numerical_dissipation,
        s.energy.energy_balance_error,
        s.output.display()
    );
    if s.energy_gain_steps > 0 {
        eprintln!("warning: {} steps created energy (largest {:.3e} of the energy scale); see /log", s.energy_gain_steps, s.max_energy_gain);
    }
    if let Some(times) = &s.kernel_times {
        let total: f64 = times.kernels.iter().map(|k| k.seconds).sum();
        eprintln!("device time by kernel ({total:.4} s in all):");
        for k in &times.kernels {
            eprintln!("  {:<34} {:>10.4} s {:>5.1} % {:>9} dispatches", k.kernel, k.seconds, 100.0 * k.seconds / total.max(f64::MIN_POSITIVE), k.dispatches);
        }
        if times.untimed_dispatches > 0 {
            eprintln!("  and {} dispatches untimed (submissions longer than the clock's timestamps)", times.untimed_dispatches);
        }
    }
    if s.max_overlap_ratio > 0.01 {
        eprintln!("warning: a node ended {:.3e} inside another body or an obstacle ({:.1} % of its element); see /contact.max_overlap", s.max_overlap, 100.0 * s.max_overlap_ratio);
    }
}

/// Interrupts (SIGINT, SIGTERM, SIGHUP: a closed terminal or SSH session) set the first flag,
/// which abandons the step in progress at its next Newton iteration, cut-back or Uzawa sweep
/// and stops the run with its log closed properly; a second interrupt
/// exits at once. The second flag tells a hang-up apart (exit 129 instead of 130).
fn interrupt_flags() -> Result<(Arc<AtomicBool>, Arc<AtomicBool>)> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let (flag, hangup) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
    for (signal, code) in [(SIGINT, 130), (SIGTERM, 130), (SIGHUP, 129)] {
        signal_hook::flag::register_conditional_shutdown(signal, code, Arc::clone(&flag))?;
        signal_hook::flag::register(signal, Arc::clone(&flag))?;
    }
    signal_hook::flag::register(SIGHUP, Arc::clone(&hangup))?;
    Ok((flag, hangup))
}

fn bench_command(options: BenchOptions, backend: BackendChoice, adapter: Option<String>, json: bool) -> Result<ExitCode> {
    bifirst::bench::check_filters(&options).map_err(anyhow::Error::msg)?;
    let devices = match backend {
        BackendChoice::Cpu => Vec::new(),
        BackendChoice::Gpu => bench_devices(adapter.as_deref())?,
        BackendChoice::Auto => bench_devices(adapter.as_deref()).unwrap_or_else(|e| {
            eprintln!("no GPU columns: {e}");
            Vec::new()
        }),
    };
    if !json {
        for d in &devices {
            eprintln!("device: {} in {}", d.adapter.line(), d.precision.name());
        }
        println!("{}", bifirst::bench::table_header());
    }
    let started = Instant::now();
    let progress = |case: &str| eprintln!("[{:6.1} s] {case}", started.elapsed().as_secs_f64());
    run_bench(
        &options,
        &devices,
        |row| {
            if json {
                println!("{}", serde_json::to_string(&row).expect("serializes"));
            } else {
                println!("{}", row.line());
            }
        },
        progress,
    )?;
    Ok(ExitCode::SUCCESS)
}

fn parse_backend(s: &str) -> Result<BackendChoice, String> {
    s.parse()
}

fn parse_uzawa(s: &str) -> Result<UzawaPlacement, String> {
    s.parse()
}

fn parse_rounds(s: &str) -> Result<RoundPlacement, String> {
    s.parse()
}

/// A finite number above zero.
fn parse_positive(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        Ok(x) => Err(format!("{x} is not a finite number above zero")),
        Err(e) => Err(e.to_string()),
    }
}

fn parse_precision(s: &str) -> Result<Precision, String> {
    s.parse()
}

struct RunArgs {
    backend: BackendRequest,
    scene: Option<PathBuf>,
    restart: Option<PathBuf>,
    at: Option<f64>,
    out: Option<PathBuf>,
    sets: Vec<String>,
    vtu: Option<PathBuf>,
    contour: Option<PathBuf>,
    quiet: bool,
    json: bool,
}

/// An error and its causes, each said once: many messages already name their cause, which
/// anyhow's `{:#}` would print again after them ("X: X").
fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if !text.contains(&part) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&part);
        }
    }
    text
}

/// Whether `a` and `b` name one file (through links, `..` or another spelling); false when
/// either does not exist.
/// Refuses, before any work, an output file that cannot be written (a directory, a path
/// through a file, a place not writable): the run would otherwise fail after its set-up.
fn check_output_file(path: &Path, what: &str) -> Result<()> {
    if path.is_dir() {
        anyhow::bail!("{what} `{}` is a directory; name a file", path.display());
    }
    check_output_dir_parent(path, what)?;
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| anyhow::anyhow!("cannot write {what} `{}`: cannot create `{}`: {e}", path.display(), parent.display()))?;
    }
    let existed = path.exists();
    std::fs::OpenOptions::new().append(true).create(true).open(path).map_err(|e| anyhow::anyhow!("cannot write {what} `{}`: {e}", path.display()))?;
    if !existed {
        std::fs::remove_file(path).map_err(|e| anyhow::anyhow!("cannot write {what} `{}`: {e}", path.display()))?;
    }
    Ok(())
}

/// Refuses an output directory that is a file, or lies below one.
fn check_output_dir(path: &Path, what: &str) -> Result<()> {
    if path.exists() && !path.is_dir() {
        anyhow::bail!("{what} `{}` is a file, not a directory; name a directory (it is created if missing)", path.display());
    }
    check_output_dir_parent(path, what)
}

/// The nearest existing folder above `path` must be a folder, not a file.
fn check_output_dir_parent(path: &Path, what: &str) -> Result<()> {
    if let Some(file) = path.ancestors().skip(1).find(|a| a.exists() && !a.is_dir()) {
        anyhow::bail!("cannot write {what} `{}`: `{}` is a file, not a directory", path.display(), file.display());
    }
    Ok(())
}

fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

/// Exit status of a run that finished but created more energy than `solver.max_energy_gain`.
const ENERGY_CREATED_EXIT: u8 = 3;

fn run(args: RunArgs) -> Result<ExitCode> {
    let (loaded, state, out) = match (&args.restart, &args.scene) {
        (Some(log), _) => {
            let (loaded, state) = bifirst::run::restart_from(log, args.at, &args.sets)?;
            let out = args.out.clone().unwrap_or_else(|| log.with_file_name(format!("{}_restart.mcap", log.file_stem().map_or("run".into(), |s| s.to_string_lossy()))));
            if same_file(log, &out) {
                anyhow::bail!("--out `{}` is the log the run continues from, and would be emptied; write the continued run to another file", out.display());
            }
            if !args.quiet {
                eprintln!("restart: from t = {:.6e} (step {}) of {}", state.t, state.step, log.display());
            }
            (loaded, Some(state), out)
        }
        (None, Some(scene)) => {
            let loaded = load_scene(scene, &args.sets)?;
            let out = args.out.clone().or_else(|| loaded.scene.output.mcap.clone()).unwrap_or_else(|| PathBuf::from(format!("{}.mcap", loaded.name)));
            (loaded, None, out)
        }
        (None, None) => unreachable!("clap requires a scene or --restart"),
    };
    // A restarted run's VTU frames go beside the first run's, not over them.
    let vtu = match (&state, args.vtu) {
        (Some(_), None) => loaded.scene.output.vtu.as_ref().map(|dir| PathBuf::from(format!("{}_restart", dir.display()))),
        (_, vtu) => vtu.or_else(|| loaded.scene.output.vtu.clone()),
    };
    check_output_file(&out, "the log")?;
    if let Some(dir) = &vtu {
        check_output_dir(dir, "the VTU directory")?;
    }
    if let Some(png) = &args.contour {
        check_output_file(png, "the contour picture")?;
    }
    if !args.quiet {
        eprintln!("bifirst {}: scene `{}`", env!("CARGO_PKG_VERSION"), loaded.name);
    }
    let (interrupt, hangup) = interrupt_flags()?;
    let options = RunOptions { vtu, interrupt: Some(interrupt), backend: args.backend, contour: args.contour, restart: state };
    let mut progress = Progress { quiet: args.quiet, bar: None, last_line: Instant::now(), last_fraction: 0.0 };
    let result = run_scene(&loaded, &out, &options, &mut progress);
    if let Some(bar) = &progress.bar {
        bar.finish_and_clear();
    }
    let report = |s: &RunSummary| {
        if args.json {
            println!("{}", serde_json::to_string_pretty(s).expect("serializes"));
        }
        if !args.quiet {
            print_summary(s);
        }
    };
    match result {
        Ok(summary) if summary.status == bifirst::run::ENERGY_CREATED => {
            report(&summary);
            eprintln!("error: {}", summary.message.as_deref().unwrap_or_default());
            Ok(ExitCode::from(ENERGY_CREATED_EXIT))
        }
        Ok(summary) => {
            report(&summary);
            Ok(ExitCode::SUCCESS)
        }
        Err(RunError::Stopped { reason, summary }) => {
            report(&summary);
            let interrupted = matches!(reason, Stop::Interrupted);
            eprintln!("error: {}", RunError::Stopped { reason, summary });
            Ok(match (interrupted, hangup.load(Ordering::SeqCst)) {
                (true, true) => ExitCode::from(129),
                (true, false) => ExitCode::from(130),
                _ => ExitCode::FAILURE,
            })
        }
        // The scene was fine; writing its results failed (a full disk, say): a failed run, not
        // bad input.
        Err(e @ RunError::Output(_)) => {
            eprintln!("error: {e}");
            Ok(ExitCode::FAILURE)
        }
        Err(e) => Err(e.into()),
    }
}

/// `--trace` probes must be the scene's, known before any variant runs.
fn check_trace<V>(probes: &[String; 3], scene: &std::collections::BTreeMap<String, V>) -> Result<()> {
    if let Some(missing) = probes.iter().find(|p| !scene.contains_key(p.as_str())) {
        let known: Vec<&str> = scene.keys().map(String::as_str).collect();
        anyhow::bail!("--trace names the probe `{missing}`, which the scene does not define (its probes: {})", if known.is_empty() { "none".into() } else { known.join(", ") });
    }
    Ok(())
}

fn parse_trace(s: &str) -> Result<[String; 3], String> {
    let names: Vec<String> = s.split(',').map(|n| n.trim().to_string()).collect();
    <[String; 3]>::try_from(names).map_err(|_| "expected three probe names, `B,C,D`".to_string())
}

struct SweepArgs {
    grid: GridArgs,
    out: Option<PathBuf>,
    jobs: Option<usize>,
    trace: Option<[String; 3]>,
    backend: BackendRequest,
    json: bool,
    shard: Option<Shard>,
    index: Option<usize>,
    list: bool,
    slurm: Option<PathBuf>,
    sbatch: Vec<SbatchOption>,
    threads: Option<usize>,
}

fn sweep_command(args: SweepArgs) -> Result<ExitCode> {
    let sweep = Sweep::plan(&args.grid.scene, &args.grid.sets, &args.grid.over)?;
    let out = args.out.clone().unwrap_or_else(|| PathBuf::from(format!("{}_sweep", sweep.name)));
    let count = sweep.variants.len();
    if let Some(script) = &args.slurm {
        return slurm_command(&sweep, &out, script, &args);
    }
    let indices = match (args.shard, args.index) {
        (Some(shard), _) => shard.indices(count),
        (None, Some(index)) => vec![index],
        (None, None) => (0..count).collect(),
    };
    let whole = args.shard.is_none() && args.index.is_none();
    if args.list {
        for v in indices.iter().filter_map(|&i| sweep.variants.get(i)) {
            println!("{}\t{}\t{}", v.index, v.label, Sweep::log_path(&out, v).display());
        }
        return Ok(ExitCode::SUCCESS);
    }
    let runs = sweep.load(&indices)?;
    if let (Some(probes), Some((_, first))) = (&args.trace, runs.first()) {
        check_trace(probes, &first.scene.probe)?;
    }
    sweep.prepare(&out, whole)?;
    let jobs = args.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())).clamp(1, runs.len().max(1));
    let share = if whole { String::new() } else { format!(" ({} of them here)", runs.len()) };
    eprintln!("bifirst {}: sweep of `{}`, {count} variants{share}, {jobs} at a time, into {}", env!("CARGO_PKG_VERSION"), sweep.name, out.display());
    let options = RunOptions { vtu: None, interrupt: Some(interrupt_flags()?.0), backend: args.backend, contour: None, restart: None };
    let finished = AtomicUsize::new(0);
    let outcomes = Sweep::run(&runs, &out, &options, jobs, |o| {
        let n = finished.fetch_add(1, Ordering::Relaxed) + 1;
        let head = format!("[{n}/{}] variant {} ({})", runs.len(), o.variant.index, o.variant.label);
        match (o.summary(), &o.result) {
            (Some(s), _) => eprintln!("{head}: {} ({} steps, {:.1} s, backend {}{}) -> {}", s.status, s.steps, s.wall_s, s.backend, s.adapter.as_ref().map_or(String::new(), |a| format!(" on {a}")), o.log.display()),
            (None, Err(e)) => eprintln!("{head}: error: {e}"),
            (None, Ok(_)) => unreachable!("a finished run has a summary"),
        }
    });
    if whole {
        return print_report(report(&out)?, args.json, args.trace);
    }
    eprintln!("when every share has run: bifirst sweep-report {}", out.display());
    let failed = outcomes.iter().filter(|o| o.result.is_err()).count();
    if failed > 0 {
        eprintln!("error: {failed} of {} variants did not finish", outcomes.len());
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// `sweep --slurm FILE`: every variant validated, the grid recorded in the sweep directory, the
/// job-array script written.
fn slurm_command(sweep: &Sweep, out: &std::path::Path, script: &std::path::Path, args: &SweepArgs) -> Result<ExitCode> {
    sweep.load(&(0..sweep.variants.len()).collect::<Vec<_>>())?;
    sweep.prepare(out, true)?;
    let job = SlurmJob { sweep, out_dir: std::fs::canonicalize(out)?, exe: std::env::current_exe().and_then(std::fs::canonicalize)?, threads: args.threads.unwrap_or(1).max(1), run_args: args.backend.args(), sbatch: args.sbatch.clone() };
    std::fs::write(script, job.script()).map_err(|e| anyhow::anyhow!("cannot write `{}`: {e}", script.display()))?;
    eprintln!("wrote {}: a Slurm job array of {} tasks (one variant each, {} CPUs each)", script.display(), sweep.variants.len(), job.threads);
    eprintln!("submit:      sbatch {}", script.display());
    eprintln!("then merge:  {}", job.merge_command());
    eprintln!("  or queue the merge behind the array: sbatch --dependency=afterany:JOB_ID --wrap \"{}\"", job.merge_command());
    Ok(ExitCode::SUCCESS)
}

struct AccuracyArgs {
    grid: GridArgs,
    measure: Option<String>,
    out: Option<PathBuf>,
    repeat: u64,
    target: f64,
    backend: BackendRequest,
    json: bool,
}

fn accuracy_command(args: AccuracyArgs) -> Result<ExitCode> {
    use bifirst::accuracy::{cheapest_within, convergence_slopes, csv, pareto_png, table, Study};
    let study = Study::plan(&args.grid.scene, args.measure.as_deref(), &args.grid.sets, &args.grid.over, &args.backend)?;
    let out = args.out.unwrap_or_else(|| PathBuf::from(format!("{}_accuracy", study.name)));
    let count = study.variant_count();
    eprintln!("bifirst {}: accuracy of `{}` against `{}`, {count} variants one at a time ({} runs each), into {}", env!("CARGO_PKG_VERSION"), study.name, study.measure, args.repeat, out.display());
    let interrupt = interrupt_flags()?.0;
    let repeated = |label: &str, k: usize, n: usize, wall: f64| eprintln!("  {label}: run {k}/{n} in {wall:.3} s");
    let rows = study.run(&out, args.repeat as usize, Some(interrupt), repeated, |r| eprintln!("[{}/{count}] {}: {} in {:.3} s, error {:.3e}", r.index + 1, r.label, r.status, r.wall_s, r.error))?;
    let csv_path = out.join("accuracy.csv");
    std::fs::write(&csv_path, csv(&study.axes, &rows)).map_err(|e| anyhow::anyhow!("cannot write `{}`: {e}", csv_path.display()))?;
    let png = out.join("accuracy.png");
    let measure = if study.measure == study.name { String::new() } else { format!(" (measure {})", study.measure) };
    pareto_png(&png, &format!("{}{measure}: wall time against error", study.name), &rows, args.target)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        print!("{}", table(&rows));
        for (key, between, slope) in convergence_slopes(&study.axes, &rows) {
            // + 0.0: equal errors give -0 along a falling axis.
            println!("order along {key}, {between}: d log(error) / d log(value) = {:.2}", slope + 0.0);
        }
        match cheapest_within(&rows, args.target) {
            Some(r) => println!("cheapest within {:.1e}: variant {} ({}), {:.3} s, error {:.3e}", args.target, r.index, r.label, r.wall_s, r.error),
            None => println!("no variant reached an error of {:.1e}", args.target),
        }
    }
    eprintln!("table: {}\nplot: {}", csv_path.display(), png.display());
    Ok(if rows.len() == count && rows.iter().all(|r| r.status == "finished") { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

fn stability_command(grid: &GridArgs, out: Option<PathBuf>, budget: Budget, backend: BackendRequest, json: bool) -> Result<ExitCode> {
    use bifirst::stability::{csv, largest_stable, map_png, table, Class, Study};
    let study = Study::plan(&grid.scene, &grid.sets, &grid.over)?;
    let out = out.unwrap_or_else(|| PathBuf::from(format!("{}_stability", study.name)));
    let count = study.variant_count();
    eprintln!("bifirst {}: stability of `{}`, {count} variants one at a time (budget {} sweeps per step, {} s each), into {}", env!("CARGO_PKG_VERSION"), study.name, budget.sweeps_per_step, budget.wall_s, out.display());
    let interrupt = interrupt_flags()?.0;
    let rows = study.run(&out, budget, &backend, Some(interrupt), |r| eprintln!("[{}/{count}] {}: {} in {:.2} s {}", r.index + 1, r.label, r.class.name(), r.wall_s, r.reasons.join("; ")))?;
    let csv_path = out.join("stability.csv");
    std::fs::write(&csv_path, csv(&study.axes, &rows)).map_err(|e| anyhow::anyhow!("cannot write `{}`: {e}", csv_path.display()))?;
    let png = out.join("stability.png");
    map_png(&png, &format!("{}: stability", study.name), &study.axes, &rows)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        print!("{}", table(&study.axes, &rows));
        for (key, value) in largest_stable(&study.axes, &rows) {
            match value {
                Some(v) => println!("largest stable {key}: {v}"),
                None => println!("no value of {key} is stable for every variant"),
            }
        }
    }
    eprintln!("table: {}\nmap: {}", csv_path.display(), png.display());
    Ok(if rows.len() == count && rows.iter().all(|r| r.class == Class::Stable) { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// The summary table (or JSON) and the overlaid plots of a sweep directory; fails when a variant
/// is missing or did not finish.
fn print_report(mut report: Report, json: bool, trace: Option<[String; 3]>) -> Result<ExitCode> {
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        let summaries: Vec<_> = report.variants.iter().filter_map(|e| e.summary.clone()).collect();
        if !summaries.is_empty() {
            print!("{}", summary::table(&summaries));
        }
        let unfinished: Vec<_> = report.variants.iter().filter(|e| !e.finished()).collect();
        println!("{} of {} variants finished", report.variants.len() - unfinished.len(), report.variants.len());
        for e in unfinished {
            let index = e.index.map_or(String::new(), |i| format!("variant {i}, "));
            let message = e.message.as_ref().filter(|m| **m != e.status).map_or(String::new(), |m| format!(": {m}"));
            println!("  {index}{}: {}{message}", e.label, e.status);
        }
    }
    let labels = report.variants.iter().filter(|e| e.record.is_some()).map(|e| e.label.clone()).collect();
    let records: Vec<_> = report.variants.iter_mut().filter_map(|e| e.record.take()).collect();
    if !records.is_empty() {
        for file in plot::plot_runs(&records, &report.dir.join("plots"), &PlotOptions { labels: Some(labels), trace })? {
            eprintln!("plot: {}", file.display());
        }
    }
    Ok(if report.complete() { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// Reads every run given, saying on stderr which could not be read; the others are used (one
/// unreadable file does not hide the rest). Fails when none can be read.
fn read_runs<T>(runs: &[PathBuf], read: impl Fn(&std::path::Path) -> Result<T, bifirst::output::ReadError>) -> Result<(Vec<T>, bool)> {
    let mut good = Vec::new();
    let mut failed = false;
    for path in runs {
        match read(path) {
            Ok(record) => good.push(record),
            Err(e) => {
                eprintln!("error: {e}");
                failed = true;
            }
        }
    }
    if good.is_empty() {
        anyhow::bail!("none of the {} file(s) could be read", runs.len());
    }
    Ok((good, failed))
}

/// Success, or the bad-input status when some of the files given could not be read.
fn read_status(failed: bool) -> ExitCode {
    if failed {
        ExitCode::from(2)
    } else {
        ExitCode::SUCCESS
    }
}

fn state_command(run: PathBuf, at: Option<f64>, contour: Option<PathBuf>, vtu: Option<PathBuf>) -> Result<ExitCode> {
    let (loaded, sim) = bifirst::run::simulation_at(&run, at)?;
    let energies = sim.energies();
    println!(
        "{}: state at t = {:.6e} (step {}), {}; energy: kinetic {:.6e}, strain {:.6e}, total {:.6e}",
        run.display(),
        sim.t,
        sim.step,
        bifirst::output::counted(sim.bodies.len(), "body", "bodies"),
        energies.kinetic,
        energies.strain,
        energies.total
    );
    let fields: Vec<_> = sim.bodies.iter().map(|b| b.cell_fields()).collect();
    if let Some(path) = contour {
        plot::contour_png(&sim, &fields, &format!("{}: von Mises stress at t = {:.4}", loaded.name, sim.t), &path)?;
        println!("{}", path.display());
    }
    if let Some(dir) = vtu {
        bifirst::output::VtuSeries::create(&dir, &sim)?.write_frame(&sim, &fields)?;
        println!("{}", dir.display());
    }
    Ok(ExitCode::SUCCESS)
}

fn plot_command(runs: Vec<PathBuf>, out: Option<PathBuf>, trace: Option<[String; 3]>) -> Result<ExitCode> {
    let (records, failed) = read_runs(&runs, read_run)?;
    let out = out.unwrap_or_else(|| runs[0].with_file_name(format!("{}_plots", runs[0].file_stem().map_or("run".into(), |s| s.to_string_lossy()))));
    for file in plot::plot_runs(&records, &out, &PlotOptions { labels: None, trace })? {
        println!("{}", file.display());
    }
    Ok(read_status(failed))
}

fn grains_command(run: &Path, out: Option<PathBuf>, at: Option<f64>, json: bool) -> Result<ExitCode> {
    use bifirst::grains::{analyze, read_networks};
    let out = out.unwrap_or_else(|| run.with_file_name(format!("{}_grains", run.file_stem().map_or("run".into(), |s| s.to_string_lossy()))));
    check_output_dir(&out, "the output directory")?;
    eprintln!("reading the contact network of {}", run.display());
    // A line per tenth of a long log's steps.
    let tenths = |what: &'static str| {
        move |k: usize, n: usize| {
            if n > 10 && (k.is_multiple_of(n / 10) || k == n) {
                eprintln!("  {what} {k}/{n} steps");
            }
        }
    };
    let networks = read_networks(run, tenths("parsed"))?;
    let started = Instant::now();
    let report = analyze(&networks, at, &out, tenths("measured"))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        let m = &report.at;
        let n = |count: usize, one: &str, many: &str| bifirst::output::counted(count, one, many);
        println!("{} ({}D, {}, {}): at t = {:.6e}", report.scene, report.dim, n(m.grains, "grain", "grains"), n(report.steps, "logged step", "logged steps"), m.t);
        println!("  solid fraction {:.4}, container volume {:.4e}", m.solid_fraction, m.container_volume);
        println!("  contacts {} ({} with walls), coordination Z = {:.3}, without {} rattlers Z = {:.3}, sliding {:.1} %", m.contacts, m.wall_contacts, m.coordination, m.rattlers, m.coordination_without_rattlers, 100.0 * m.sliding_fraction);
        println!("  fabric {:?}, anisotropy {:.4}", m.fabric, m.fabric_anisotropy);
        println!("  Love-Weber stress {:?}: p = {:.4e}, q = {:.4e}; mean wall pressure {:.4e}", m.stress, m.pressure, m.deviator, m.wall_pressure);
        for w in &m.walls {
            println!("    wall `{}`: {:.4e}", w.name, w.pressure);
        }
        let d = &report.force_distribution;
        println!("  normal forces: mean {:.4e}, exponential tail decay {}", d.mean_normal_force, d.tail_decay.map_or("n/a (too few forces above the mean)".into(), |b| format!("{b:.3}")));
    }
    eprintln!("measured in {:.2} s; wrote {}", started.elapsed().as_secs_f64(), report.files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "));
    Ok(ExitCode::SUCCESS)
}

fn summary_command(runs: Vec<PathBuf>, json: bool) -> Result<ExitCode> {
    let (summaries, failed) = read_runs(&runs, |p| read_run(p).and_then(|r| summary::summarize(&r)))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summaries)?);
    } else {
        print!("{}", summary::table(&summaries));
    }
    Ok(read_status(failed))
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
            let elements: usize = sim.bodies.iter().map(|b| b.mesh.element_count()).sum();
            let dofs: usize = sim.bodies.iter().map(|b| b.dofs.free_count).sum();
            let n = |count: usize, one: &str, many: &str| bifirst::output::counted(count, one, many);
            println!("{}: valid, {}D, {}, {}, {} free dofs, {}", loaded.name, sim.dim, n(sim.bodies.len(), "body", "bodies"), n(elements, "element", "elements"), dofs, n(sim.step_count(), "step", "steps"));
            // The largest bodies' factorisations: the fill decides the cost of a Newton iteration.
            let mut bodies: Vec<_> = sim.bodies.iter().collect();
            bodies.sort_by_key(|b| std::cmp::Reverse(b.dofs.free_count));
            for b in bodies.iter().take(3) {
                let (ordering, entries) = b.factor_report();
                println!("  body `{}`: {} free dofs, factor with {} ordering: {} entries", b.name, b.dofs.free_count, ordering.name(), entries);
                let sets: Vec<String> = b.mesh.node_sets.iter().map(|(name, nodes)| format!("{name} ({})", nodes.len())).collect();
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
        Command::Grains { run, out, at, json } => grains_command(&run, out, at, json),
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
