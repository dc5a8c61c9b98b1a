//! The logs of a sweep directory, whoever produced them (one machine, shards, a Slurm array),
//! held against the grid recorded there: which variants finished, which failed, which are missing.

use super::{variants, Sweep, SweepError, MANIFEST_FILE};
use crate::output::summary::{summarize, LogSummary};
use crate::output::{read_run, RunRecord};
use std::path::{Path, PathBuf};

/// One variant of the grid (or, without a grid record, one log of the directory).
#[derive(Debug, serde::Serialize)]
pub struct ReportEntry {
    /// Its index in the grid; `None` for a directory without a grid record.
    pub index: Option<usize>,
    pub label: String,
    pub log: PathBuf,
    /// `finished`, `failed`, `interrupted` or `incomplete` (from the log), `missing` (no log),
    /// `unreadable`, or `mismatched` (the log's scene has other values than the variant's).
    pub status: String,
    pub message: Option<String>,
    pub summary: Option<LogSummary>,
    #[serde(skip)]
    pub record: Option<RunRecord>,
}

impl ReportEntry {
    pub fn finished(&self) -> bool {
        self.status == "finished"
    }
}

/// A sweep directory's variants, in grid order (else in file-name order).
#[derive(Debug, serde::Serialize)]
pub struct Report {
    pub dir: PathBuf,
    /// The scene's name, from the grid record.
    pub name: Option<String>,
    pub variants: Vec<ReportEntry>,
}

impl Report {
    /// Whether every variant finished.
    pub fn complete(&self) -> bool {
        self.variants.iter().all(ReportEntry::finished)
    }
}

/// A variant the directory should hold: its index, label, `--set`s and log.
type Expected = (Option<usize>, String, Vec<String>, PathBuf);

/// Reads every log of the grid recorded in `dir` ([`MANIFEST_FILE`]), or every `*.mcap` in `dir`
/// when it has no record.
pub fn report(dir: &Path) -> Result<Report, SweepError> {
    let read_dir = |e: std::io::Error| SweepError::Read { path: dir.into(), message: e.to_string() };
    let (name, expected): (Option<String>, Vec<Expected>) = match Sweep::read_manifest(dir)? {
        Some(sweep) => {
            check_grid(dir, &sweep)?;
            (Some(sweep.name.clone()), sweep.variants.iter().map(|v| (Some(v.index), v.label.clone(), v.sets.clone(), Sweep::log_path(dir, v))).collect())
        }
        None => {
            let mut logs: Vec<PathBuf> = std::fs::read_dir(dir).map_err(read_dir)?.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|x| x == "mcap") && p.is_file()).collect();
            logs.sort();
            if logs.is_empty() {
                return Err(SweepError::Read { path: dir.into(), message: format!("neither a sweep record ({MANIFEST_FILE}) nor any .mcap log") });
            }
            (None, logs.into_iter().map(|p| (None, p.file_stem().map_or_else(String::new, |s| s.to_string_lossy().into_owned()), Vec::new(), p)).collect())
        }
    };
    let variants = expected.into_iter().map(|(index, label, sets, log)| entry(index, label, &sets, log)).collect();
    Ok(Report { dir: dir.into(), name, variants })
}

/// Holds the recorded variants against those its axes give: an edited record could show one
/// variant's log under another's values, one log twice, or name a file outside `dir`.
fn check_grid(dir: &Path, sweep: &Sweep) -> Result<(), SweepError> {
    let bad = |message: String| SweepError::Read { path: dir.join(MANIFEST_FILE), message };
    let grid = variants(&sweep.name, &sweep.axes).map_err(|e| bad(e.to_string()))?;
    if grid.len() != sweep.variants.len() {
        return Err(bad(format!("it records {} variants, its axes give {}: it was edited", sweep.variants.len(), grid.len())));
    }
    if let Some((recorded, expected)) = sweep.variants.iter().zip(&grid).find(|(r, e)| r != e) {
        return Err(bad(format!("variant {} is recorded as `{}` in `{}.mcap`, its axes give `{}` in `{}.mcap`: it was edited", expected.index, recorded.label, recorded.stem, expected.label, expected.stem)));
    }
    Ok(())
}

/// The first `--set` of `sets` that the scene logged in `record`'s `/run` contradicts, as a
/// message: a log under another variant's name.
fn contradiction(record: &RunRecord, sets: &[String]) -> Option<String> {
    let logged: toml::Table = record.messages("/run").first()?["scene"].as_str()?.parse().ok()?;
    sets.iter().find_map(|set| {
        let (key, value) = set.split_once('=')?;
        let mut at = logged.get(key.split('.').next()?)?;
        for part in key.split('.').skip(1) {
            at = at.get(part)?;
        }
        let wanted: toml::Table = format!("v = {value}").parse().ok()?;
        (!same_value(at, wanted.get("v")?)).then(|| format!("its scene has {key} = {at}, not the grid's {value}: it is another variant's log"))
    })
}

/// TOML values equal as a scene reads them (an integer and a float of one value are the same).
fn same_value(a: &toml::Value, b: &toml::Value) -> bool {
    let number = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    match (a, b) {
        (toml::Value::Array(a), toml::Value::Array(b)) => a.len() == b.len() && a.iter().zip(b).all(|(a, b)| same_value(a, b)),
        _ => match (number(a), number(b)) {
            (Some(x), Some(y)) => x == y,
            _ => a == b,
        },
    }
}

fn entry(index: Option<usize>, label: String, sets: &[String], log: PathBuf) -> ReportEntry {
    let unreadable = |status: &str, message: String| ReportEntry { index, label: label.clone(), log: log.clone(), status: status.into(), message: Some(message), summary: None, record: None };
    if !log.exists() {
        return unreadable("missing", format!("no log `{}`", log.display()));
    }
    let read = read_run(&log).and_then(|record| summarize(&record).map(|summary| (record, summary)));
    match read {
        Ok((record, mut summary)) => match contradiction(&record, sets) {
            Some(message) => unreadable("mismatched", message),
            None => {
                summary.name = label.clone();
                ReportEntry { index, status: summary.status.clone(), message: summary.message.clone(), label, log, summary: Some(summary), record: Some(record) }
            }
        },
        Err(e) => unreadable("unreadable", e.to_string()),
    }
}
