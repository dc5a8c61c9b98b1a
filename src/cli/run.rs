//! `bifirst run`: one scene (or a restart) to its MCAP log, with the outputs checked before any
//! work and the exit status of a run that stopped or created energy.

use crate::cli::progress::*;
use anyhow::Result;
use bifirst::backend::BackendRequest;
use bifirst::run::{run_scene, RunError, RunOptions, RunSummary, Stop};
use bifirst::scene::load_scene;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::time::Instant;

pub(crate) struct RunArgs {
    pub(crate) backend: BackendRequest,
    pub(crate) scene: Option<PathBuf>,
    pub(crate) restart: Option<PathBuf>,
    pub(crate) at: Option<f64>,
    pub(crate) out: Option<PathBuf>,
    pub(crate) sets: Vec<String>,
    pub(crate) vtu: Option<PathBuf>,
    pub(crate) contour: Option<PathBuf>,
    pub(crate) quiet: bool,
    pub(crate) json: bool,
}

/// An error and its causes, each said once: many messages already name their cause, which
/// anyhow's `{:#}` would print again after them ("X: X").
pub(crate) fn error_text(e: &anyhow::Error) -> String {
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
pub(crate) fn check_output_file(path: &Path, what: &str) -> Result<()> {
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
pub(crate) fn check_output_dir(path: &Path, what: &str) -> Result<()> {
    if path.exists() && !path.is_dir() {
        anyhow::bail!("{what} `{}` is a file, not a directory; name a directory (it is created if missing)", path.display());
    }
    check_output_dir_parent(path, what)
}

/// The nearest existing folder above `path` must be a folder, not a file.
pub(crate) fn check_output_dir_parent(path: &Path, what: &str) -> Result<()> {
    if let Some(file) = path.ancestors().skip(1).find(|a| a.exists() && !a.is_dir()) {
        anyhow::bail!("cannot write {what} `{}`: `{}` is a file, not a directory", path.display(), file.display());
    }
    Ok(())
}

pub(crate) fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

/// Exit status of a run that finished but created more energy than `solver.max_energy_gain`.
pub(crate) const ENERGY_CREATED_EXIT: u8 = 3;

pub(crate) fn run(args: RunArgs) -> Result<ExitCode> {
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
