//! `bifirst stability`: a scene run over a grid of stress variants (any scene keys: time step,
//! theta, speeds, stiffness, friction), one variant at a time, each classified as stable,
//! degraded, failed or too slow; a table, `stability.csv`, a map over the first two axes
//! (`stability.png`, [`map_png`]) and the largest stable value along each axis.

mod plot;

pub use plot::map_png;

use crate::backend::BackendRequest;
use crate::run::{run_scene, RunOptions, RunSummary, Silent, Stop, ENERGY_CREATED};
use crate::scene::{load_scene, LoadedScene};
use crate::sweep::{numbers_of, variants, StudyError, SweepAxis, Variant};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The overlap a stable run stays within, in element sizes (the contact bound of the step
/// control's default, whatever the scene sets).
pub const STABLE_OVERLAP: f64 = 0.01;

/// How a variant fared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Class {
    /// Finished, no energy created beyond `solver.max_energy_gain`, no step creating energy,
    /// overlap within [`STABLE_OVERLAP`], no step kept beyond the step control's bounds.
    Stable,
    /// Finished, with warnings (the row says which).
    Degraded,
    /// Over the budget of sweeps per step or wall time.
    TooSlow,
    /// Stopped early (the row says why).
    Failed,
}

impl Class {
    pub fn name(self) -> &'static str {
        match self {
            Class::Stable => "stable",
            Class::Degraded => "degraded",
            Class::TooSlow => "too slow",
            Class::Failed => "failed",
        }
    }
}

/// What a variant may cost before it is too slow.
#[derive(Debug, Clone, Copy)]
pub struct Budget {
    /// Uzawa sweeps per step, over the run.
    pub sweeps_per_step: f64,
    /// Wall seconds of the whole run: a run still going is stopped then.
    pub wall_s: f64,
}

/// One variant's outcome.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    pub index: usize,
    pub label: String,
    /// The variant's value of each axis, in axis order.
    pub values: Vec<String>,
    pub class: Class,
    /// The warnings of a degraded run, the reason of a failed or too slow one.
    pub reasons: Vec<String>,
    pub steps: usize,
    pub t_end: f64,
    pub wall_s: f64,
    pub sweeps_per_step: f64,
    pub cutbacks: usize,
    pub max_overlap_ratio: f64,
    pub energy_created: f64,
    pub log: PathBuf,
}

/// A validated grid of stress variants of a scene.
pub struct Study {
    pub name: String,
    pub axes: Vec<SweepAxis>,
    runs: Vec<(Variant, LoadedScene)>,
}

impl Study {
    /// Loads the scene with `sets` and validates every variant of the grid of `axes` before
    /// any runs.
    pub fn plan(scene: &Path, sets: &[String], axes: &[SweepAxis]) -> Result<Self, StudyError> {
        let base = load_scene(scene, sets).map_err(|source| StudyError::Scene { label: "base".into(), source: Box::new(source) })?;
        let mut runs = Vec::new();
        for variant in variants(&base.name, axes)? {
            let all: Vec<String> = sets.iter().chain(&variant.sets).cloned().collect();
            let loaded = load_scene(scene, &all).map_err(|source| StudyError::Scene { label: variant.label.clone(), source: Box::new(source) })?;
            runs.push((variant, loaded));
        }
        Ok(Self { name: base.name, axes: axes.to_vec(), runs })
    }

    pub fn variant_count(&self) -> usize {
        self.runs.len()
    }

    /// Runs every variant into `out_dir/<stem>.mcap`, one at a time (their wall times do not
    /// compete), each stopped at the wall budget; `done` sees each row. Stops early, with the
    /// rows so far, when `interrupt` is set.
    pub fn run(&self, out_dir: &Path, budget: Budget, backend: &BackendRequest, interrupt: Option<Arc<AtomicBool>>, mut done: impl FnMut(&Row)) -> Result<Vec<Row>, StudyError> {
        std::fs::create_dir_all(out_dir).map_err(|source| StudyError::Write { path: out_dir.into(), source })?;
        let mut rows = Vec::new();
        for (variant, loaded) in &self.runs {
            if interrupt.as_ref().is_some_and(|f| f.load(Ordering::SeqCst)) {
                break;
            }
            let log = out_dir.join(format!("{}.mcap", variant.stem));
            let (flag, over_time, watchdog) = watch(budget.wall_s, interrupt.clone());
            let options = RunOptions { vtu: None, interrupt: Some(flag.clone()), backend: backend.clone(), contour: None, restart: None };
            let result = run_scene(loaded, &log, &options, &mut Silent);
            // Ends the watchdog.
            flag.store(true, Ordering::SeqCst);
            watchdog.join().expect("the watchdog does not panic");
            let (summary, stop) = StudyError::outcome(&variant.label, result)?;
            let values = self.axes.iter().map(|a| variant.value(&a.key).to_string()).collect();
            let (class, reasons) = classify(&summary, stop.as_ref(), over_time.load(Ordering::SeqCst), budget);
            let row = Row {
                index: variant.index,
                label: variant.label.clone(),
                values,
                class,
                reasons,
                steps: summary.steps,
                t_end: summary.t_end,
                wall_s: summary.wall_s,
                sweeps_per_step: summary.uzawa_iterations as f64 / summary.steps.max(1) as f64,
                cutbacks: summary.cutbacks,
                max_overlap_ratio: summary.max_overlap_ratio,
                energy_created: summary.energy_created,
                log,
            };
            done(&row);
            rows.push(row);
        }
        Ok(rows)
    }
}

/// A run's own interrupt flag, set by a watchdog thread at `wall_s` (then `over_time` is set
/// too) or when the command's `interrupt` is; setting the flag also ends the watchdog.
fn watch(wall_s: f64, interrupt: Option<Arc<AtomicBool>>) -> (Arc<AtomicBool>, Arc<AtomicBool>, std::thread::JoinHandle<()>) {
    let (flag, over_time) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
    let (f, o) = (flag.clone(), over_time.clone());
    // A budget that is no number (NaN) is no budget.
    let deadline = Instant::now() + Duration::from_secs_f64(if wall_s.is_nan() { 1e9 } else { wall_s.clamp(0.0, 1e9) });
    let handle = std::thread::spawn(move || {
        while !f.load(Ordering::SeqCst) {
            if Instant::now() >= deadline {
                o.store(true, Ordering::SeqCst);
                f.store(true, Ordering::SeqCst);
            } else if interrupt.as_ref().is_some_and(|i| i.load(Ordering::SeqCst)) {
                f.store(true, Ordering::SeqCst);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    });
    (flag, over_time, handle)
}

/// The class of a run and why: failed (stopped for a reason other than the budget), too slow
/// (stopped at the wall budget, or over the sweeps per step), degraded (finished with
/// warnings), else stable.
pub fn classify(s: &RunSummary, stop: Option<&Stop>, over_time: bool, budget: Budget) -> (Class, Vec<String>) {
    if over_time {
        return (Class::TooSlow, vec![format!("still running at the wall budget of {} s (t = {:.4e}, {} steps)", budget.wall_s, s.t_end, s.steps)]);
    }
    if let Some(stop) = stop {
        return (Class::Failed, vec![stop.to_string()]);
    }
    let sweeps = s.uzawa_iterations as f64 / s.steps.max(1) as f64;
    if sweeps > budget.sweeps_per_step {
        return (Class::TooSlow, vec![format!("{sweeps:.0} Uzawa sweeps per step, over the budget of {}", budget.sweeps_per_step)]);
    }
    let mut warnings = Vec::new();
    if s.status == ENERGY_CREATED {
        warnings.push(format!("created {:.3e} of the energy scale", s.energy_created));
    }
    if s.energy_gain_steps > 0 {
        warnings.push(format!("{} steps created energy (largest {:.3e})", s.energy_gain_steps, s.max_energy_gain));
    }
    if s.max_overlap_ratio > STABLE_OVERLAP {
        warnings.push(format!("overlap {:.2} % of an element", 100.0 * s.max_overlap_ratio));
    }
    if s.kept_beyond_bounds > 0 {
        warnings.push(format!("{} sub-steps kept beyond the step control's bounds at the smallest step", s.kept_beyond_bounds));
    }
    if warnings.is_empty() {
        (Class::Stable, warnings)
    } else {
        (Class::Degraded, warnings)
    }
}

/// A value's size for ordering an axis: the number, or the Euclidean norm of an array of numbers
/// (an initial velocity); `None` for anything else.
pub fn magnitude(value: &str) -> Option<f64> {
    match numbers_of(value)?.as_slice() {
        [x] => Some(*x),
        xs => Some(xs.iter().map(|x| x * x).sum::<f64>().sqrt()),
    }
}

/// For each axis, the largest value at which every variant is stable (by [`magnitude`], else
/// the last such value in the order given), or `None` when no value is.
pub fn largest_stable(axes: &[SweepAxis], rows: &[Row]) -> Vec<(String, Option<String>)> {
    axes.iter()
        .enumerate()
        .map(|(a, axis)| {
            let stable = |v: &String| {
                let of: Vec<&Row> = rows.iter().filter(|r| &r.values[a] == v).collect();
                !of.is_empty() && of.iter().all(|r| r.class == Class::Stable)
            };
            let candidates: Vec<&String> = axis.values.iter().filter(|v| stable(v)).collect();
            let best = if axis.values.iter().all(|v| magnitude(v).is_some()) { candidates.into_iter().max_by(|x, y| magnitude(x).unwrap_or(0.0).total_cmp(&magnitude(y).unwrap_or(0.0))) } else { candidates.into_iter().last() };
            (axis.key.clone(), best.cloned())
        })
        .collect()
}

/// The rows as a table for the terminal.
pub fn table(axes: &[SweepAxis], rows: &[Row]) -> String {
    let mut out = String::new();
    let keys: Vec<&str> = axes.iter().map(|a| a.key.as_str()).collect();
    out.push_str(&format!("{:>4}  {:<40} {:<9} {:>7} {:>9} {:>9} {:>9} {:>10}  {}\n", "#", keys.join(", "), "class", "steps", "wall s", "sweeps/st", "overlap%", "E created", "why"));
    for r in rows {
        out.push_str(&format!(
            "{:>4}  {:<40} {:<9} {:>7} {:>9.2} {:>9.1} {:>9.3} {:>10.2e}  {}\n",
            r.index,
            r.values.join(", "),
            r.class.name(),
            r.steps,
            r.wall_s,
            r.sweeps_per_step,
            100.0 * r.max_overlap_ratio,
            r.energy_created,
            r.reasons.join("; ")
        ));
    }
    out
}

/// The rows as CSV: one column per axis, then the outcome.
pub fn csv(axes: &[SweepAxis], rows: &[Row]) -> String {
    let quote = |s: &str| format!("\"{}\"", s.replace('"', "\"\""));
    let mut out = String::from("index,");
    for a in axes {
        out.push_str(&quote(&a.key));
        out.push(',');
    }
    out.push_str("class,steps,t_end,wall_s,sweeps_per_step,cutbacks,max_overlap_ratio,energy_created,reasons,log\n");
    for r in rows {
        out.push_str(&format!("{},", r.index));
        for v in &r.values {
            out.push_str(&quote(v));
            out.push(',');
        }
        out.push_str(&format!(
            "{},{},{:e},{:.6},{:.3},{},{:e},{:e},{},{}\n",
            r.class.name(),
            r.steps,
            r.t_end,
            r.wall_s,
            r.sweeps_per_step,
            r.cutbacks,
            r.max_overlap_ratio,
            r.energy_created,
            quote(&r.reasons.join("; ")),
            quote(&r.log.display().to_string())
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magnitude_orders_numbers_and_velocities() {
        assert_eq!(magnitude("2.5e-3"), Some(2.5e-3));
        assert_eq!(magnitude("4"), Some(4.0));
        assert_eq!(magnitude("[-3.0, 4.0]"), Some(5.0));
        assert_eq!(magnitude("\"tri3\""), None);
    }
}
