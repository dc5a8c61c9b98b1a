//! `bifirst accuracy`: run time against error. A known-answer scene is run over a grid of
//! settings (scene keys such as `time.dt` or mesh divisions, and `backend`, `precision` and
//! `uzawa`), one variant after the other so that the timings do not compete; each run's error
//! against its closed form comes from the scene's measure ([`known_answers`]), and the variants
//! that no other beats on both time and error make the Pareto front.

mod known_answers;
mod plot;

pub use known_answers::{known_answer, ErrorTerm, KnownAnswer, KNOWN_ANSWERS};
pub use plot::pareto_png;

use crate::backend::BackendRequest;
use crate::run::{run_scene, Monitor, RunOptions};
use crate::scene::{load_scene, LoadedScene};
use crate::solver::Simulation;
use crate::sweep::{numbers_of, variants, StudyError, SweepAxis, Variant};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Debug, thiserror::Error)]
pub enum AccuracyError {
    #[error("no known answer named `{0}`; the measures are {names} (`--measure NAME` picks one for a scene of another name)", names = KNOWN_ANSWERS.map(|(n, _)| n).join(", "))]
    UnknownMeasure(String),
    #[error("measure `{measure}` needs {what} in the scene")]
    Parameter { measure: String, what: String },
    #[error("`--over {key}`: {message}")]
    RunKey { key: String, message: String },
    #[error("measure `{measure}`: the expected {quantity} is {value} with these parameters ({hint}); it has no error to measure")]
    Expected { measure: String, quantity: &'static str, value: f64, hint: &'static str },
    #[error("variant {label}: {source}")]
    Variant { label: String, source: Box<AccuracyError> },
    #[error(transparent)]
    Study(#[from] StudyError),
}

/// A grid over a known-answer scene, every variant validated.
pub struct Study {
    pub name: String,
    /// The measure's name (one of [`KNOWN_ANSWERS`]).
    pub measure: String,
    pub axes: Vec<SweepAxis>,
    runs: Vec<(Variant, LoadedScene, BackendRequest)>,
}

/// One variant's cost and error.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Row {
    pub index: usize,
    pub label: String,
    /// The variant's value of each axis, in axis order.
    pub values: Vec<String>,
    pub backend: String,
    pub precision: String,
    /// `finished`, `failed` or `interrupted`; only finished runs are on the front.
    pub status: String,
    /// Why a run stopped early.
    pub message: Option<String>,
    pub steps: usize,
    /// Median wall time over the repeats (the whole run: set-up, steps and log).
    pub wall_s: f64,
    pub wall_runs: Vec<f64>,
    pub errors: Vec<ErrorTerm>,
    /// The largest relative error of the terms: the run is as good as its worst quantity.
    pub error: f64,
    /// No other finished variant is as fast and as accurate, and better in one of the two.
    pub pareto: bool,
    pub log: PathBuf,
}

/// Feeds a run's states to the measure.
struct Observer<'a>(&'a mut dyn KnownAnswer);

impl Monitor for Observer<'_> {
    fn reads_states(&self) -> bool {
        true
    }
    fn state(&mut self, sim: &Simulation) {
        self.0.observe(sim);
    }
}

impl Study {
    /// Loads the scene with `sets`, picks its measure (`measure`, else the scene's name) and
    /// validates every variant of the grid of `axes`.
    pub fn plan(scene: &Path, measure: Option<&str>, sets: &[String], axes: &[SweepAxis], base: &BackendRequest) -> Result<Self, AccuracyError> {
        let loaded = load_scene(scene, sets).map_err(|source| StudyError::Scene { label: "base".into(), source: Box::new(source) })?;
        let measure = measure.unwrap_or(&loaded.name).to_string();
        known_answer(&measure, &loaded)?;
        let mut runs = Vec::new();
        for variant in variants(&loaded.name, axes).map_err(StudyError::from)? {
            let mut request = base.clone();
            let mut scene_sets = sets.to_vec();
            for set in &variant.sets {
                let (key, value) = set.split_once('=').expect("a variant's sets are KEY=VALUE");
                let bad = |message: String| AccuracyError::RunKey { key: key.to_string(), message };
                match key {
                    "backend" => request.choice = value.parse().map_err(bad)?,
                    "precision" => request.precision = Some(value.parse().map_err(bad)?),
                    "uzawa" => request.uzawa = value.parse().map_err(bad)?,
                    _ => scene_sets.push(set.clone()),
                }
            }
            let loaded = load_scene(scene, &scene_sets).map_err(|source| StudyError::Scene { label: variant.label.clone(), source: Box::new(source) })?;
            known_answer(&measure, &loaded).map_err(|e| AccuracyError::Variant { label: variant.label.clone(), source: Box::new(e) })?;
            runs.push((variant, loaded, request));
        }
        Ok(Self { name: loaded.name, measure, axes: axes.to_vec(), runs })
    }

    pub fn variant_count(&self) -> usize {
        self.runs.len()
    }

    /// Runs every variant `repeat` times into `out_dir/<stem>.mcap`, one at a time; `repeated`
    /// sees each run of a variant repeated more than once (its label, the run's number from 1,
    /// `repeat`, its wall time) and `done` each row as it is measured. The rows come back in
    /// grid order with the front marked. When `interrupt` is set, the run in progress stops and
    /// no other starts: the rows so far come back.
    pub fn run(&self, out_dir: &Path, repeat: usize, interrupt: Option<Arc<AtomicBool>>, mut repeated: impl FnMut(&str, usize, usize, f64), mut done: impl FnMut(&Row)) -> Result<Vec<Row>, AccuracyError> {
        let interrupted = || interrupt.as_ref().is_some_and(|f| f.load(std::sync::atomic::Ordering::SeqCst));
        std::fs::create_dir_all(out_dir).map_err(|source| StudyError::Write { path: out_dir.into(), source })?;
        let mut rows = Vec::new();
        for (variant, loaded, request) in &self.runs {
            let log = out_dir.join(format!("{}.mcap", variant.stem));
            let options = RunOptions { vtu: None, interrupt: interrupt.clone(), backend: request.clone(), contour: None, restart: None };
            let mut walls = Vec::new();
            let mut first = None;
            let repeat = repeat.max(1);
            for k in 0..repeat {
                let mut measure = known_answer(&self.measure, loaded)?;
                let result = run_scene(loaded, &log, &options, &mut Observer(measure.as_mut()));
                let (summary, stop) = StudyError::outcome(&variant.label, result)?;
                let message = stop.map(|reason| reason.to_string());
                walls.push(summary.wall_s);
                if repeat > 1 {
                    repeated(&variant.label, k + 1, repeat, summary.wall_s);
                }
                first.get_or_insert((summary, message, measure.errors()));
                if interrupted() {
                    break;
                }
            }
            let (summary, message, errors) = first.expect("one run or more");
            let error = row_error(&errors);
            let values = self.axes.iter().map(|a| variant.value(&a.key).to_string()).collect();
            let row = Row {
                index: variant.index,
                label: variant.label.clone(),
                values,
                backend: summary.backend.clone(),
                precision: summary.precision.clone(),
                status: summary.status.clone(),
                message,
                steps: summary.steps,
                wall_s: median(&walls),
                wall_runs: walls,
                errors,
                error,
                pareto: false,
                log,
            };
            done(&row);
            rows.push(row);
            if interrupted() {
                break;
            }
        }
        mark_front(&mut rows);
        Ok(rows)
    }
}

/// A row's error: the largest of its terms; NaN if any is NaN (`f64::max` would drop it and
/// put a run without a measurable answer on the front).
fn row_error(errors: &[ErrorTerm]) -> f64 {
    errors.iter().map(|e| e.error).fold(0.0, |a: f64, e| if a.is_nan() || e.is_nan() { f64::NAN } else { a.max(e) })
}

fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Errors that agree to this relative difference are equal: the CPU and a GPU in f64 or f32
/// give the same answer to round-off, and the faster of the two should win.
const SAME_ERROR: f64 = 1e-6;

/// Marks the finished rows that no other finished row beats on both time and error.
pub fn mark_front(rows: &mut [Row]) {
    let eligible = |r: &Row| r.status == "finished" && r.error.is_finite();
    let points: Vec<Option<(f64, f64)>> = rows.iter().map(|r| eligible(r).then_some((r.wall_s, r.error))).collect();
    let at_most = |a: f64, b: f64| a <= b + SAME_ERROR * b.abs();
    let below = |a: f64, b: f64| a < b - SAME_ERROR * b.abs();
    for (i, row) in rows.iter_mut().enumerate() {
        let Some((t, e)) = points[i] else { continue };
        row.pareto = !points.iter().enumerate().any(|(j, p)| j != i && p.is_some_and(|(tj, ej)| tj <= t && at_most(ej, e) && (tj < t || below(ej, e))));
    }
}

/// The cheapest finished row with an error at most `target`.
pub fn cheapest_within(rows: &[Row], target: f64) -> Option<&Row> {
    rows.iter().filter(|r| r.status == "finished" && r.error <= target).min_by(|a, b| a.wall_s.total_cmp(&b.wall_s))
}

/// A swept value as a number: a number, or the largest entry of an array (mesh divisions).
fn numeric(value: &str) -> Option<f64> {
    numbers_of(value)?.into_iter().reduce(f64::max)
}

/// Along each numeric axis, with the other axes fixed, the slope of log(error) against
/// log(value) between neighbouring values: the observed order of convergence (about p for an
/// error that goes as dt^p; about -p against mesh divisions).
pub fn convergence_slopes(axes: &[SweepAxis], rows: &[Row]) -> Vec<(String, String, f64)> {
    let mut slopes = Vec::new();
    for (a, axis) in axes.iter().enumerate() {
        if axis.values.len() < 2 || axis.values.iter().any(|v| numeric(v).is_none()) {
            continue;
        }
        for (i, row) in rows.iter().enumerate() {
            // The next row along this axis: same values elsewhere, the next value here.
            let position = axis.values.iter().position(|v| *v == row.values[a]);
            let Some(next_value) = position.and_then(|p| axis.values.get(p + 1)) else { continue };
            let next = rows[i + 1..].iter().find(|r| r.values[a] == *next_value && r.values.iter().enumerate().all(|(k, v)| k == a || *v == row.values[k]));
            let Some(next) = next.filter(|n| n.status == "finished" && row.status == "finished") else { continue };
            let (v0, v1) = (numeric(&row.values[a]).unwrap_or(f64::NAN), numeric(next_value).unwrap_or(f64::NAN));
            let slope = (next.error / row.error).ln() / (v1 / v0).ln();
            if !slope.is_finite() {
                continue;
            }
            let others: Vec<String> = row.values.iter().enumerate().filter(|(k, _)| *k != a).map(|(k, v)| format!("{}={v}", axes[k].key)).collect();
            let between = format!("{} -> {}{}", row.values[a], next_value, if others.is_empty() { String::new() } else { format!(" ({})", others.join(", ")) });
            slopes.push((axis.key.clone(), between, slope));
        }
    }
    slopes
}

/// The rows as CSV: one line per variant, each error term's computed, expected and relative
/// error.
pub fn csv(axes: &[SweepAxis], rows: &[Row]) -> String {
    let terms: Vec<&str> = rows.first().map_or_else(Vec::new, |r| r.errors.iter().map(|e| e.quantity).collect());
    let mut header: Vec<String> = vec!["index".into()];
    header.extend(axes.iter().map(|a| a.key.clone()));
    header.extend(["backend", "precision", "status", "steps", "wall_s", "error", "pareto"].map(String::from));
    for t in &terms {
        header.extend([t.to_string(), format!("{t} expected"), format!("{t} error")]);
    }
    let quote = |s: &str| if s.contains([',', '"']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() };
    let mut out = header.iter().map(|h| quote(h)).collect::<Vec<_>>().join(",") + "\n";
    for r in rows {
        let mut cells: Vec<String> = vec![r.index.to_string()];
        cells.extend(r.values.iter().map(|v| quote(v)));
        cells.extend([r.backend.clone(), r.precision.clone(), quote(&r.status), r.steps.to_string(), format!("{:.6e}", r.wall_s), format!("{:.6e}", r.error), r.pareto.to_string()]);
        for e in &r.errors {
            cells.extend([format!("{:.9e}", e.computed), format!("{:.9e}", e.expected), format!("{:.6e}", e.error)]);
        }
        out += &(cells.join(",") + "\n");
    }
    out
}

/// The rows as a text table, the front marked with `*`.
pub fn table(rows: &[Row]) -> String {
    let terms: Vec<&str> = rows.first().map_or_else(Vec::new, |r| r.errors.iter().map(|e| e.quantity).collect());
    let mut header = vec!["#".to_string(), "variant".into(), "backend".into(), "status".into(), "steps".into(), "wall s".into()];
    header.extend(terms.iter().map(|t| format!("{t} err")));
    header.extend(["error".into(), "front".into()]);
    let mut lines = vec![header];
    for r in rows {
        let mut cells = vec![r.index.to_string(), r.label.clone(), format!("{} {}", r.backend, r.precision), r.status.clone(), r.steps.to_string(), format!("{:.3}", r.wall_s)];
        cells.extend(r.errors.iter().map(|e| format!("{:.3e}", e.error)));
        cells.extend([format!("{:.3e}", r.error), if r.pareto { "*".into() } else { String::new() }]);
        lines.push(cells);
    }
    let widths: Vec<usize> = (0..lines[0].len()).map(|c| lines.iter().map(|l| l.get(c).map_or(0, |s| s.chars().count())).max().unwrap_or(0)).collect();
    let mut out: String = lines.iter().map(|l| l.iter().zip(&widths).enumerate().map(|(c, (s, w))| if c == 1 || c == 3 { format!("{s:<w$}") } else { format!("{s:>w$}") }).collect::<Vec<_>>().join("  ").trim_end().to_string() + "\n").collect();
    for r in rows {
        if let Some(message) = &r.message {
            out += &format!("variant {} ({}): {message}\n", r.index, r.label);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(wall_s: f64, error: f64, status: &str) -> Row {
        Row { index: 0, label: String::new(), values: vec![], backend: "cpu".into(), precision: "f64".into(), status: status.into(), message: None, steps: 1, wall_s, wall_runs: vec![wall_s], errors: vec![], error, pareto: false, log: PathBuf::new() }
    }

    #[test]
    fn the_front_keeps_what_nothing_beats_on_both_time_and_error() {
        let mut rows = vec![row(1.0, 0.1, "finished"), row(2.0, 0.01, "finished"), row(3.0, 0.05, "finished"), row(0.5, 1e-9, "failed"), row(2.0, 0.01, "finished"), row(4.0, 0.01 * (1.0 - 1e-9), "finished")];
        mark_front(&mut rows);
        assert_eq!(rows.iter().map(|r| r.pareto).collect::<Vec<_>>(), [true, true, false, false, true, false], "a tie stays on the front; a failed run never is; the same error to round-off at more cost is off it");
        assert_eq!(cheapest_within(&rows, 0.02).map(|r| r.wall_s), Some(2.0));
        assert!(cheapest_within(&rows, 1e-3).is_none());
    }

    /// Caught: a NaN error term was dropped by `f64::max` and its variant put on the front.
    #[test]
    fn a_nan_error_term_keeps_its_row_off_the_front() {
        let term = |error: f64| ErrorTerm { quantity: "q", computed: 1.0, expected: 1.0, error };
        assert_eq!(row_error(&[term(0.1), term(0.3)]), 0.3);
        let error = row_error(&[term(f64::NAN), term(0.1)]);
        assert!(error.is_nan());
        let mut rows = vec![row(1.0, error, "finished"), row(2.0, 0.2, "finished")];
        mark_front(&mut rows);
        assert_eq!(rows.iter().map(|r| r.pareto).collect::<Vec<_>>(), [false, true]);
    }

    #[test]
    fn swept_values_read_as_numbers() {
        assert_eq!(numeric("5e-5"), Some(5e-5));
        assert_eq!(numeric("[200, 1]"), Some(200.0));
        assert_eq!(numeric("\"f32\""), None);
    }
}
