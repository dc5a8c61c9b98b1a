//! `bifirst sweep`, `sweep-report`, `accuracy` and `stability`: a scene over a grid of variants.

use crate::cli::{args::*, progress::*};
use anyhow::Result;
use bifirst::backend::BackendRequest;
use bifirst::output::plot::{self, PlotOptions};
use bifirst::output::summary;
use bifirst::run::RunOptions;
use bifirst::stability::Budget;
use bifirst::sweep::{report, Report, SbatchOption, Shard, SlurmJob, Sweep};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicUsize, Ordering};

pub(crate) struct SweepArgs {
    pub(crate) grid: GridArgs,
    pub(crate) out: Option<PathBuf>,
    pub(crate) jobs: Option<usize>,
    pub(crate) trace: Option<[String; 3]>,
    pub(crate) backend: BackendRequest,
    pub(crate) json: bool,
    pub(crate) shard: Option<Shard>,
    pub(crate) index: Option<usize>,
    pub(crate) list: bool,
    pub(crate) slurm: Option<PathBuf>,
    pub(crate) sbatch: Vec<SbatchOption>,
    pub(crate) threads: Option<usize>,
}

pub(crate) fn sweep_command(args: SweepArgs) -> Result<ExitCode> {
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
pub(crate) fn slurm_command(sweep: &Sweep, out: &std::path::Path, script: &std::path::Path, args: &SweepArgs) -> Result<ExitCode> {
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

pub(crate) struct AccuracyArgs {
    pub(crate) grid: GridArgs,
    pub(crate) measure: Option<String>,
    pub(crate) out: Option<PathBuf>,
    pub(crate) repeat: u64,
    pub(crate) target: f64,
    pub(crate) backend: BackendRequest,
    pub(crate) json: bool,
}

pub(crate) fn accuracy_command(args: AccuracyArgs) -> Result<ExitCode> {
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

pub(crate) fn stability_command(grid: &GridArgs, out: Option<PathBuf>, budget: Budget, backend: BackendRequest, json: bool) -> Result<ExitCode> {
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
pub(crate) fn print_report(mut report: Report, json: bool, trace: Option<[String; 3]>) -> Result<ExitCode> {
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
