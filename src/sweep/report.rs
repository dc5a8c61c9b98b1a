//! The logs of a sweep directory, whoever produced them (one machine, shards, a Slurm array),
//! held against the grid recorded there: which variants finished, which failed, which are missing.

use super::{Sweep, SweepError, MANIFEST_FILE};
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
    /// `finished`, `failed`, `interrupted` or `incomplete` (from the log), `missing` (no log) or
    /// `unreadable`.
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

/// Reads every log of the grid recorded in `dir` ([`MANIFEST_FILE`]), or every `*.mcap` in `dir`
/// when it has no record.
pub fn report(dir: &Path) -> Result<Report, SweepError> {
    let read_dir = |e: std::io::Error| SweepError::Read { path: dir.into(), message: e.to_string() };
    let (name, expected): (Option<String>, Vec<(Option<usize>, String, PathBuf)>) = match Sweep::read_manifest(dir)? {
        Some(sweep) => (Some(sweep.name.clone()), sweep.variants.iter().map(|v| (Some(v.index), v.label.clone(), Sweep::log_path(dir, v))).collect()),
        None => {
            let mut logs: Vec<PathBuf> = std::fs::read_dir(dir).map_err(read_dir)?.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|x| x == "mcap") && p.is_file()).collect();
            logs.sort();
            if logs.is_empty() {
                return Err(SweepError::Read { path: dir.into(), message: format!("neither a sweep record ({MANIFEST_FILE}) nor any .mcap log") });
            }
            (None, logs.into_iter().map(|p| (None, p.file_stem().map_or_else(String::new, |s| s.to_string_lossy().into_owned()), p)).collect())
        }
    };
    let variants = expected.into_iter().map(|(index, label, log)| entry(index, label, log)).collect();
    Ok(Report { dir: dir.into(), name, variants })
}

fn entry(index: Option<usize>, label: String, log: PathBuf) -> ReportEntry {
    let unreadable = |status: &str, message: String| ReportEntry { index, label: label.clone(), log: log.clone(), status: status.into(), message: Some(message), summary: None, record: None };
    if !log.exists() {
        return unreadable("missing", format!("no log `{}`", log.display()));
    }
    let read = read_run(&log).and_then(|record| summarize(&record).map(|summary| (record, summary)));
    match read {
        Ok((record, mut summary)) => {
            summary.name = label.clone();
            ReportEntry { index, status: summary.status.clone(), message: summary.message.clone(), label, log, summary: Some(summary), record: Some(record) }
        }
        Err(e) => unreadable("unreadable", e.to_string()),
    }
}
