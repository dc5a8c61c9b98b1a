//! The commands that read run logs back: `state`, `plot`, `grains` and `summary`.

use crate::cli::run::*;
use anyhow::Result;
use bifirst::output::plot::{self, PlotOptions};
use bifirst::output::{read_run, summary};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Reads every run given, saying on stderr which could not be read; the others are used (one
/// unreadable file does not hide the rest). Fails when none can be read.
pub(crate) fn read_runs<T>(runs: &[PathBuf], read: impl Fn(&std::path::Path) -> Result<T, bifirst::output::ReadError>) -> Result<(Vec<T>, bool)> {
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
pub(crate) fn read_status(failed: bool) -> ExitCode {
    if failed {
        ExitCode::from(2)
    } else {
        ExitCode::SUCCESS
    }
}

pub(crate) fn state_command(run: PathBuf, at: Option<f64>, contour: Option<PathBuf>, vtu: Option<PathBuf>) -> Result<ExitCode> {
    let (loaded, sim) = bifirst::run::simulation_at(&run, at)?;
    let energies = sim.energies();
    println!(
        "{}: state at t = {:.6e} (step {}), {}; energy: kinetic {:.6e}, strain {:.6e}, total {:.6e}",
        run.display(),
        sim.t(),
        sim.step(),
        bifirst::output::counted(sim.bodies().len(), "body", "bodies"),
        energies.kinetic,
        energies.strain,
        energies.total
    );
    let fields: Vec<_> = sim.bodies().iter().map(|b| b.cell_fields()).collect();
    if let Some(path) = contour {
        plot::contour_png(&sim, &fields, &format!("{}: von Mises stress at t = {:.4}", loaded.name, sim.t()), &path)?;
        println!("{}", path.display());
    }
    if let Some(dir) = vtu {
        bifirst::output::VtuSeries::create(&dir, &sim)?.write_frame(&sim, &fields)?;
        println!("{}", dir.display());
    }
    Ok(ExitCode::SUCCESS)
}

pub(crate) fn plot_command(runs: Vec<PathBuf>, out: Option<PathBuf>, trace: Option<[String; 3]>) -> Result<ExitCode> {
    let (records, failed) = read_runs(&runs, read_run)?;
    let out = out.unwrap_or_else(|| runs[0].with_file_name(format!("{}_plots", runs[0].file_stem().map_or("run".into(), |s| s.to_string_lossy()))));
    for file in plot::plot_runs(&records, &out, &PlotOptions { labels: None, trace })? {
        println!("{}", file.display());
    }
    Ok(read_status(failed))
}

pub(crate) fn grains_command(run: &Path, out: Option<PathBuf>, at: Option<f64>, window: Option<f64>, json: bool) -> Result<ExitCode> {
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
    let report = analyze(&networks, at, window, &out, tenths("measured"))?;
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
        if let Some(w) = &report.window {
            let off = 100.0 * (w.pressure / w.wall_pressure - 1.0);
            println!(
                "  means over {} from t = {:.6e}: Love-Weber stress {:?}, p = {:.4e} ({off:+.1} % of the mean wall pressure {:.4e}), q = {:.4e}, Z = {:.3}",
                n(w.steps, "logged step", "logged steps"),
                w.from,
                w.stress,
                w.pressure,
                w.wall_pressure,
                w.deviator,
                w.coordination
            );
            for wall in &w.walls {
                println!("    wall `{}`: {:.4e}", wall.name, wall.pressure);
            }
        }
        let d = &report.force_distribution;
        println!("  normal forces: mean {:.4e}, exponential tail decay {}", d.mean_normal_force, d.tail_decay.map_or("n/a (too few forces above the mean)".into(), |b| format!("{b:.3}")));
    }
    eprintln!("measured in {:.2} s; wrote {}", started.elapsed().as_secs_f64(), report.files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(", "));
    Ok(ExitCode::SUCCESS)
}

pub(crate) fn summary_command(runs: Vec<PathBuf>, json: bool) -> Result<ExitCode> {
    let (summaries, failed) = read_runs(&runs, |p| read_run(p).and_then(|r| summary::summarize(&r)))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summaries)?);
    } else {
        print!("{}", summary::table(&summaries));
    }
    Ok(read_status(failed))
}
