//! `bifirst sweep`: one scene run over a grid of `--set` values (`--over KEY=V1,V2,...`), the
//! variants in parallel, one MCAP log each; a share of the grid per machine (`--shard K/N`,
//! `--index I`, a Slurm job array) and a report over whatever logs a directory holds.

mod manifest;
mod report;
mod slurm;

pub use manifest::MANIFEST_FILE;
pub use report::{report, Report, ReportEntry};
pub use slurm::{SbatchOption, SlurmJob};

use crate::run::{run_scene, RunError, RunOptions, RunSummary, Silent, Stop};
use crate::scene::{load_scene, LoadedScene, SceneError};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("`--over {0}`: expected KEY=VALUE,VALUE,... with at least one value")]
    Over(String),
    #[error("`--over` key `{0}` is given twice")]
    RepeatedKey(String),
    #[error("`--shard {0}`: expected K/N with 0 <= K < N (variants K, K+N, K+2N, ... run)")]
    Shard(String),
    #[error("`--index {index}`: the sweep has {count} variants (0 to {})", count.saturating_sub(1))]
    Index { index: usize, count: usize },
    #[error("`--sbatch {0}`: expected KEY=VALUE or KEY, the key made of letters, digits and `-`, the value on one line")]
    Sbatch(String),
    #[error("`--sbatch {0}` needs a value (`--sbatch {0}=...`); only flags such as `exclusive` stand alone")]
    SbatchValue(String),
    #[error("variant {label}: {source}")]
    Scene { label: String, source: Box<SceneError> },
    #[error("cannot find the scene `{path}`: {source}")]
    ScenePath { path: PathBuf, source: std::io::Error },
    #[error("cannot write `{path}`: {source}")]
    Write { path: PathBuf, source: std::io::Error },
    #[error("cannot read `{path}`: {message}")]
    Read { path: PathBuf, message: String },
    #[error("`{path}` describes another sweep ({difference}); give this one its own `--out` directory, or remove the file")]
    OtherSweep { path: PathBuf, difference: String },
}

/// What stops a study that runs a grid's variants one at a time (`accuracy`, `stability`).
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error(transparent)]
    Sweep(#[from] SweepError),
    #[error("variant {label}: {source}")]
    Scene { label: String, source: Box<SceneError> },
    #[error("variant {label}: {source}")]
    Run { label: String, source: Box<RunError> },
    #[error("cannot write `{path}`: {source}")]
    Write { path: PathBuf, source: std::io::Error },
}

impl StudyError {
    /// A variant's run as a study reads it: its summary, and why it stopped if it stopped
    /// early; a run that left no summary (its log could not be written) stops the study.
    pub fn outcome(label: &str, result: Result<RunSummary, RunError>) -> Result<(RunSummary, Option<Stop>), Self> {
        match result {
            Ok(summary) => Ok((summary, None)),
            Err(RunError::Stopped { reason, summary }) => Ok((*summary, Some(reason))),
            Err(e) => Err(Self::Run { label: label.to_string(), source: Box::new(e) }),
        }
    }
}

/// One swept key and its values (TOML literals, as `--set` takes them).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SweepAxis {
    pub key: String,
    pub values: Vec<String>,
}

impl std::str::FromStr for SweepAxis {
    type Err = SweepError;

    /// `KEY=V1,V2,...`; commas inside brackets or quotes belong to a value (`v=[1,0],[2,0]`).
    fn from_str(spec: &str) -> Result<Self, SweepError> {
        let bad = || SweepError::Over(spec.to_string());
        let (key, list) = spec.split_once('=').ok_or_else(bad)?;
        let (mut values, mut depth, mut quoted, mut start) = (Vec::new(), 0i32, false, 0);
        for (i, c) in list.char_indices() {
            match c {
                '"' | '\'' => quoted = !quoted,
                '[' | '{' if !quoted => depth += 1,
                ']' | '}' if !quoted => depth -= 1,
                ',' if depth == 0 && !quoted => {
                    values.push(list[start..i].trim().to_string());
                    start = i + 1;
                }
                _ => {}
            }
        }
        values.push(list[start..].trim().to_string());
        let key = key.trim();
        if key.is_empty() || values.iter().any(String::is_empty) {
            return Err(bad());
        }
        Ok(Self { key: key.to_string(), values })
    }
}

/// One point of the grid: its place in grid order, its `--set` overrides, a label for plots and
/// a file stem.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Variant {
    pub index: usize,
    pub label: String,
    pub sets: Vec<String>,
    pub stem: String,
}

impl Variant {
    /// The value this variant gives `key` (as written in `--over`), or "" for a key it does
    /// not set.
    pub fn value(&self, key: &str) -> &str {
        self.sets.iter().find_map(|s| s.strip_prefix(key).and_then(|rest| rest.strip_prefix('='))).unwrap_or_default()
    }
}

/// The numbers an axis value holds: one for a number, each entry of an array of numbers (a
/// velocity); `None` for anything else.
pub fn numbers_of(value: &str) -> Option<Vec<f64>> {
    let v: toml::Value = toml::from_str(&format!("v = {value}")).ok().and_then(|t: toml::Table| t.get("v").cloned())?;
    let number = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    match &v {
        toml::Value::Array(items) => items.iter().map(number).collect(),
        other => number(other).map(|x| vec![x]),
    }
}

/// Every combination of the axes' values, the first axis varying slowest. Labels use the last
/// segment of each key (`friction=0.2`) unless two axes share it.
pub fn variants(scene_name: &str, axes: &[SweepAxis]) -> Result<Vec<Variant>, SweepError> {
    for (i, a) in axes.iter().enumerate() {
        if axes[..i].iter().any(|b| b.key == a.key) {
            return Err(SweepError::RepeatedKey(a.key.clone()));
        }
    }
    let short = |key: &str| key.rsplit('.').next().unwrap_or(key).to_string();
    let shorts: Vec<String> = axes.iter().map(|a| short(&a.key)).collect();
    let unique = shorts.iter().collect::<std::collections::BTreeSet<_>>().len() == shorts.len();
    let names: Vec<String> = if unique { shorts } else { axes.iter().map(|a| a.key.clone()).collect() };
    let mut grid: Vec<Vec<usize>> = vec![Vec::new()];
    for axis in axes {
        grid = grid.into_iter().flat_map(|prefix| (0..axis.values.len()).map(move |v| [prefix.clone(), vec![v]].concat())).collect();
    }
    Ok(grid
        .into_iter()
        .enumerate()
        .map(|(index, choice)| {
            let picked: Vec<(&SweepAxis, &String, &String)> = axes.iter().zip(&names).zip(choice).map(|((a, n), v)| (a, n, &a.values[v])).collect();
            let label = picked.iter().map(|(_, n, v)| format!("{n}={v}")).collect::<Vec<_>>().join(", ");
            let sets = picked.iter().map(|(a, _, v)| format!("{}={v}", a.key)).collect();
            let stem = std::iter::once(scene_name.to_string()).chain(picked.iter().map(|(_, n, v)| format!("{n}-{v}"))).collect::<Vec<_>>().join("_");
            Variant { index, label, sets, stem: sanitize(&stem) }
        })
        .collect())
}

/// Keeps file names portable: letters, digits, `.`, `_` and `-`; anything else becomes `_`.
fn sanitize(stem: &str) -> String {
    stem.chars().map(|c| if c.is_ascii_alphanumeric() || "._-".contains(c) { c } else { '_' }).collect()
}

/// A share of the grid for one machine: variants `k`, `k + n`, `k + 2n`, ...
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shard {
    pub k: usize,
    pub n: usize,
}

impl std::str::FromStr for Shard {
    type Err = SweepError;

    /// `K/N`, with `0 <= K < N`.
    fn from_str(spec: &str) -> Result<Self, SweepError> {
        let bad = || SweepError::Shard(spec.to_string());
        let (k, n) = spec.split_once('/').ok_or_else(bad)?;
        let (k, n): (usize, usize) = (k.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if k >= n {
            return Err(bad());
        }
        Ok(Self { k, n })
    }
}

impl Shard {
    /// The grid indices of this share of `count` variants.
    pub fn indices(self, count: usize) -> Vec<usize> {
        (self.k..count).step_by(self.n).collect()
    }
}

/// How one variant ended.
#[derive(Debug)]
pub struct VariantOutcome {
    pub variant: Variant,
    pub log: PathBuf,
    pub result: Result<RunSummary, RunError>,
}

impl VariantOutcome {
    /// The run summary, also for a run that stopped early (its log is still valid).
    pub fn summary(&self) -> Option<&RunSummary> {
        match &self.result {
            Ok(s) => Some(s),
            Err(RunError::Stopped { summary, .. }) => Some(summary),
            Err(_) => None,
        }
    }
}

/// A sweep's grid: the scene, the overrides every variant shares, and the variants.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sweep {
    pub name: String,
    /// The scene file, absolute: array tasks may start in another directory.
    pub scene: PathBuf,
    pub sets: Vec<String>,
    pub axes: Vec<SweepAxis>,
    pub variants: Vec<Variant>,
}

impl Sweep {
    /// The grid of `axes` over `scene` with `base_sets` applied first; the base scene is
    /// validated here, the variants' own values by [`Sweep::load`].
    pub fn plan(scene: &Path, base_sets: &[String], axes: &[SweepAxis]) -> Result<Self, SweepError> {
        let base = load_scene(scene, base_sets).map_err(|source| SweepError::Scene { label: "base".into(), source: Box::new(source) })?;
        let variants = variants(&base.name, axes)?;
        let scene = std::fs::canonicalize(scene).map_err(|source| SweepError::ScenePath { path: scene.into(), source })?;
        Ok(Self { name: base.name, scene, sets: base_sets.to_vec(), axes: axes.to_vec(), variants })
    }

    /// Loads and validates the scenes of the variants at `indices`, so that a bad value is
    /// reported before any of them runs.
    pub fn load(&self, indices: &[usize]) -> Result<Vec<(Variant, LoadedScene)>, SweepError> {
        indices
            .iter()
            .map(|&index| {
                let variant = self.variants.get(index).ok_or(SweepError::Index { index, count: self.variants.len() })?;
                let sets: Vec<String> = self.sets.iter().chain(&variant.sets).cloned().collect();
                match load_scene(&self.scene, &sets) {
                    Ok(loaded) => Ok((variant.clone(), loaded)),
                    Err(source) => Err(SweepError::Scene { label: variant.label.clone(), source: Box::new(source) }),
                }
            })
            .collect()
    }

    /// Where a variant's log goes in `out_dir`, whichever machine runs it.
    pub fn log_path(out_dir: &Path, variant: &Variant) -> PathBuf {
        out_dir.join(format!("{}.mcap", variant.stem))
    }

    /// Creates `out_dir` and records the grid there ([`MANIFEST_FILE`]), so that a report can
    /// name the variants whose logs are missing. A share of the grid (`whole = false`) refuses a
    /// directory that records another grid; a whole sweep replaces the record.
    pub fn prepare(&self, out_dir: &Path, whole: bool) -> Result<(), SweepError> {
        std::fs::create_dir_all(out_dir).map_err(|source| SweepError::Write { path: out_dir.into(), source })?;
        self.write_manifest(out_dir, whole)
    }

    /// Runs the loaded variants into `out_dir/<stem>.mcap`, at most `jobs` at a time; `done` is
    /// called as each finishes. Outcomes come back in the order given.
    pub fn run(runs: &[(Variant, LoadedScene)], out_dir: &Path, options: &RunOptions, jobs: usize, done: impl Fn(&VariantOutcome) + Sync) -> Vec<VariantOutcome> {
        let next = AtomicUsize::new(0);
        let outcomes: Mutex<Vec<Option<VariantOutcome>>> = Mutex::new((0..runs.len()).map(|_| None).collect());
        std::thread::scope(|scope| {
            for _ in 0..jobs.clamp(1, runs.len().max(1)) {
                scope.spawn(|| loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some((variant, loaded)) = runs.get(i) else { break };
                    let log = Self::log_path(out_dir, variant);
                    let result = run_scene(loaded, &log, options, &mut Silent);
                    let outcome = VariantOutcome { variant: variant.clone(), log, result };
                    done(&outcome);
                    outcomes.lock().expect("no run panics while holding the lock")[i] = Some(outcome);
                });
            }
        });
        outcomes.into_inner().expect("not poisoned").into_iter().map(|o| o.expect("every variant ran")).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn over_splits_at_top_level_commas_only() {
        let axis: SweepAxis = "body.b.initial_velocity=[1.0, 0.0],[2.0,0.0], \"a,b\"".parse().unwrap();
        assert_eq!(axis.values, ["[1.0, 0.0]", "[2.0,0.0]", "\"a,b\""]);
        assert!("contact.friction".parse::<SweepAxis>().is_err());
        assert!("contact.friction=0,,1".parse::<SweepAxis>().is_err());
    }

    #[test]
    fn grid_is_the_product_with_the_first_axis_slowest() {
        let axes = ["contact.friction=0,0.5".parse().unwrap(), "time.dt=0.01,0.005,0.0025".parse().unwrap()];
        let v = variants("s", &axes).unwrap();
        assert_eq!(v.len(), 6);
        assert_eq!(v[1].sets, ["contact.friction=0", "time.dt=0.005"]);
        assert_eq!(v[1].label, "friction=0, dt=0.005");
        assert_eq!(v[5].stem, "s_friction-0.5_dt-0.0025");
        let same_tail = ["material.a.G=1,2".parse().unwrap(), "material.b.G=3".parse().unwrap()];
        assert_eq!(variants("s", &same_tail).unwrap()[0].label, "material.a.G=1, material.b.G=3");
        assert!(matches!(variants("s", &[axes[0].clone(), axes[0].clone()]), Err(SweepError::RepeatedKey(_))));
        assert_eq!(v.iter().map(|v| v.index).collect::<Vec<_>>(), [0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn shards_split_the_grid_without_gaps_or_repeats() {
        let shard = |s: &str| s.parse::<Shard>();
        assert_eq!(shard("1/3").unwrap().indices(7), [1, 4]);
        assert_eq!(shard("0/3").unwrap().indices(7), [0, 3, 6]);
        let mut all: Vec<usize> = (0..4).flat_map(|k| Shard { k, n: 4 }.indices(10)).collect();
        all.sort_unstable();
        assert_eq!(all, (0..10).collect::<Vec<_>>());
        for bad in ["3/3", "1", "a/2", "1/0", "-1/2"] {
            assert!(shard(bad).is_err(), "{bad}");
        }
    }
}
