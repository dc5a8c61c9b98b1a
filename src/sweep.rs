//! `bifirst sweep`: one scene run over a grid of `--set` values (`--over KEY=V1,V2,...`), the
//! variants in parallel, one MCAP log each.

use crate::run::{run_scene, RunError, RunOptions, RunSummary, Silent};
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
    #[error("variant {label}: {source}")]
    Scene { label: String, source: SceneError },
    #[error("cannot create the sweep directory `{path}`: {source}")]
    Create { path: PathBuf, source: std::io::Error },
}

/// One swept key and its values (TOML literals, as `--set` takes them).
#[derive(Debug, Clone, PartialEq)]
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

/// One point of the grid: its `--set` overrides, a label for plots and a file stem.
#[derive(Debug, Clone, PartialEq)]
pub struct Variant {
    pub label: String,
    pub sets: Vec<String>,
    pub stem: String,
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
        .map(|choice| {
            let picked: Vec<(&SweepAxis, &String, &String)> = axes.iter().zip(&names).zip(choice).map(|((a, n), v)| (a, n, &a.values[v])).collect();
            let label = picked.iter().map(|(_, n, v)| format!("{n}={v}")).collect::<Vec<_>>().join(", ");
            let sets = picked.iter().map(|(a, _, v)| format!("{}={v}", a.key)).collect();
            let stem = std::iter::once(scene_name.to_string()).chain(picked.iter().map(|(_, n, v)| format!("{n}-{v}"))).collect::<Vec<_>>().join("_");
            Variant { label, sets, stem: sanitize(&stem) }
        })
        .collect())
}

/// Keeps file names portable: letters, digits, `.`, `_` and `-`; anything else becomes `_`.
fn sanitize(stem: &str) -> String {
    stem.chars().map(|c| if c.is_ascii_alphanumeric() || "._-".contains(c) { c } else { '_' }).collect()
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
            Ok(s) | Err(RunError::Stopped { summary: s, .. }) => Some(s),
            Err(_) => None,
        }
    }
}

/// A sweep ready to run: every variant's scene loaded and validated up front, so that a bad
/// value is reported before any run starts.
pub struct Sweep {
    pub name: String,
    runs: Vec<(Variant, LoadedScene)>,
}

impl Sweep {
    /// Loads `scene` once per variant with `base_sets` then the variant's overrides.
    pub fn load(scene: &Path, base_sets: &[String], axes: &[SweepAxis]) -> Result<Self, SweepError> {
        let base = load_scene(scene, base_sets).map_err(|source| SweepError::Scene { label: "base".into(), source })?;
        let runs = variants(&base.name, axes)?
            .into_iter()
            .map(|variant| {
                let sets: Vec<String> = base_sets.iter().chain(&variant.sets).cloned().collect();
                match load_scene(scene, &sets) {
                    Ok(loaded) => Ok((variant, loaded)),
                    Err(source) => Err(SweepError::Scene { label: variant.label, source }),
                }
            })
            .collect::<Result<_, _>>()?;
        Ok(Self { name: base.name, runs })
    }

    pub fn variants(&self) -> impl Iterator<Item = &Variant> {
        self.runs.iter().map(|(v, _)| v)
    }

    /// Runs every variant into `out_dir/<stem>.mcap`, at most `jobs` at a time; `done` is
    /// called as each finishes. Outcomes come back in grid order.
    pub fn run(&self, out_dir: &Path, options: &RunOptions, jobs: usize, done: impl Fn(&VariantOutcome) + Sync) -> Result<Vec<VariantOutcome>, SweepError> {
        std::fs::create_dir_all(out_dir).map_err(|source| SweepError::Create { path: out_dir.into(), source })?;
        let next = AtomicUsize::new(0);
        let outcomes: Mutex<Vec<Option<VariantOutcome>>> = Mutex::new((0..self.runs.len()).map(|_| None).collect());
        std::thread::scope(|scope| {
            for _ in 0..jobs.clamp(1, self.runs.len().max(1)) {
                scope.spawn(|| loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some((variant, loaded)) = self.runs.get(i) else { break };
                    let log = out_dir.join(format!("{}.mcap", variant.stem));
                    let result = run_scene(loaded, &log, options, &mut Silent);
                    let outcome = VariantOutcome { variant: variant.clone(), log, result };
                    done(&outcome);
                    outcomes.lock().expect("no run panics while holding the lock")[i] = Some(outcome);
                });
            }
        });
        Ok(outcomes.into_inner().expect("not poisoned").into_iter().map(|o| o.expect("every variant ran")).collect())
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
    }
}
