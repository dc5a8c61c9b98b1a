//! The `bifirst` command line: run, check and info.

use anyhow::Result;
use bifirst::run::{run_scene, Monitor, RunError, RunSummary};
use bifirst::scene::load_scene;
use bifirst::solver::StepReport;
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(Parser)]
#[command(name = "bifirst", version, about = "Dynamic frictional contact between hyperelastic bodies (Bi-First)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene and write its MCAP run log.
    Run {
        scene: PathBuf,
        /// Output MCAP file (default: the scene's `output.mcap`, else `<scene name>.mcap`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a scene value before validation, e.g. `--set time.dt=0.005` (TOML literal).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
    },
    /// Validate a scene (and build its meshes) without running it.
    Check {
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
    },
    /// Print the version, build and compute backends.
    Info,
}

/// A progress bar on a terminal; plain lines about every 10% (and at most every 2 s) otherwise.
struct Progress {
    bar: Option<ProgressBar>,
    last_line: Instant,
    last_fraction: f64,
}

impl Monitor for Progress {
    fn started(&mut self, total: usize) {
        if std::io::stderr().is_terminal() {
            let bar = ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
            bar.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} steps  t = {msg}  [{elapsed_precise} < {eta}]").expect("valid template"));
            self.bar = Some(bar);
        }
    }
    fn step(&mut self, r: &StepReport, total: usize) {
        let fraction = r.step as f64 / total as f64;
        match &self.bar {
            Some(bar) => {
                bar.set_position(r.step as u64);
                bar.set_message(format!("{:.4e}", r.t));
            }
            None => {
                if fraction - self.last_fraction >= 0.1 - 1e-12 && self.last_line.elapsed().as_secs_f64() >= 2.0 || r.step == total {
                    eprintln!("step {}/{}  t = {:.4e}  newton {}  cut-backs {}", r.step, total, r.t, r.newton_iterations, r.cutbacks);
                    self.last_line = Instant::now();
                    self.last_fraction = fraction;
                }
            }
        }
    }
    fn warning(&mut self, message: &str) {
        match &self.bar {
            Some(bar) => bar.println(format!("warning: {message}")),
            None => eprintln!("warning: {message}"),
        }
    }
}

fn print_summary(s: &RunSummary) {
    eprintln!(
        "{}: {} steps to t = {:.6e}, {} Newton iterations, {} cut-backs, {:.2} s wall; dissipated by friction {:.4e}, numerically {:.4e}, energy balance error {:.1e}; log written to {}",
        s.scene,
        s.steps,
        s.t_end,
        s.newton_iterations,
        s.cutbacks,
        s.wall_s,
        s.energy.friction_dissipation,
        s.energy.numerical_dissipation,
        s.energy.energy_balance_error,
        s.output.display()
    );
}

fn run(scene: PathBuf, out: Option<PathBuf>, sets: Vec<String>) -> Result<ExitCode> {
    let loaded = load_scene(&scene, &sets)?;
    let out = out.or_else(|| loaded.scene.output.mcap.clone()).unwrap_or_else(|| PathBuf::from(format!("{}.mcap", loaded.name)));
    eprintln!("bifirst {}: scene `{}`, backend cpu, precision {}", env!("CARGO_PKG_VERSION"), loaded.name, bifirst::precision::PRECISION_NAME);
    let mut progress = Progress { bar: None, last_line: Instant::now(), last_fraction: 0.0 };
    let result = run_scene(&loaded, &out, &mut progress);
    if let Some(bar) = &progress.bar {
        bar.finish_and_clear();
    }
    match result {
        Ok(summary) => {
            print_summary(&summary);
            Ok(ExitCode::SUCCESS)
        }
        Err(RunError::Failed { failure, summary }) => {
            print_summary(&summary);
            eprintln!("error: {}", RunError::Failed { failure, summary: summary.clone() });
            Ok(ExitCode::FAILURE)
        }
        Err(e) => Err(e.into()),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run { scene, out, sets } => run(scene, out, sets),
        Command::Check { scene, sets } => load_scene(&scene, &sets).map_err(anyhow::Error::from).and_then(|loaded| {
            let sim = bifirst::solver::build_simulation(&loaded)?;
            let elements: usize = sim.bodies.iter().map(|b| b.mesh.element_count()).sum();
            let dofs: usize = sim.bodies.iter().map(|b| b.dofs.free_count).sum();
            println!("{}: valid, {}D, {} bodies, {} elements, {} free dofs, {} steps", loaded.name, sim.dim, sim.bodies.len(), elements, dofs, sim.step_count());
            Ok(ExitCode::SUCCESS)
        }),
        Command::Info => {
            println!("bifirst {}", env!("CARGO_PKG_VERSION"));
            println!("build: {} profile, rustc target {}-{}", if cfg!(debug_assertions) { "debug" } else { "release" }, std::env::consts::ARCH, std::env::consts::OS);
            println!("precision: {}", bifirst::precision::PRECISION_NAME);
            println!("backends: cpu (GPU backend not built yet)");
            Ok(ExitCode::SUCCESS)
        }
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
