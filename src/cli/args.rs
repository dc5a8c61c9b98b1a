//! Scene-independent command-line arguments and their parsers: the grid of a study, the backend,
//! positive numbers, the probes a trace follows.

use anyhow::Result;
use bifirst::backend::{BackendChoice, BackendRequest, RoundPlacement, UzawaPlacement};
use bifirst::precision::Precision;
use bifirst::sweep::SweepAxis;
use std::path::PathBuf;

/// A scene and the grid of variants over it (`sweep`, `accuracy`, `stability`).
#[derive(clap::Args)]
pub(crate) struct GridArgs {
    pub(crate) scene: PathBuf,
    /// A scene key and its values, as `--set` takes them (several make a grid); commas inside
    /// brackets belong to a value (`--over body.b.initial_velocity=[1,0],[2,0]`).
    #[arg(long = "over", value_name = "KEY=V1,V2,...", required = true)]
    pub(crate) over: Vec<SweepAxis>,
    /// Overrides applied to every variant before its own.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub(crate) sets: Vec<String>,
}

/// Where a run's kernels go (`run` and `sweep`).
#[derive(clap::Args)]
pub(crate) struct BackendArgs {
    /// Where the element and assembly kernels run: `auto` runs on the CPU, which was measured
    /// faster on every scene (`bifirst info` says why), unless `--adapter` names one; `gpu` takes
    /// a hardware GPU, else a software adapter (lavapipe, slow: CI's GPU path), with a notice.
    #[arg(long, default_value = "auto", value_parser = parse_backend)]
    pub(crate) backend: BackendChoice,
    /// A GPU adapter by name (case-insensitive substring; `bifirst info` lists them).
    #[arg(long, value_name = "NAME")]
    pub(crate) adapter: Option<String>,
    /// GPU kernel precision, f32 or f64 (default: f64 when the adapter has it).
    #[arg(long, value_parser = parse_precision)]
    pub(crate) precision: Option<Precision>,
    /// With the kernels on a GPU, where the Uzawa sweeps of the contact problems run: `auto`
    /// takes the device for large contact sets on a hardware GPU, `gpu` whenever it can
    /// (Gauss-Seidel in f64), `cpu` never.
    #[arg(long, default_value = "auto", value_parser = parse_uzawa)]
    pub(crate) uzawa: UzawaPlacement,
    /// With the kernels on a GPU, which Newton rounds evaluate on the device: `auto` the first
    /// of each step and those with enough elements to gain, the others on the CPU twins; `gpu`
    /// every round.
    #[arg(long, default_value = "auto", value_parser = parse_rounds)]
    pub(crate) rounds: RoundPlacement,
    /// With the kernels on a GPU, time every dispatch on the device and report the time by
    /// kernel (`kernel_times` of the summary); the timestamps cost a little device time.
    #[arg(long)]
    pub(crate) kernel_times: bool,
}

impl From<BackendArgs> for BackendRequest {
    fn from(a: BackendArgs) -> Self {
        BackendRequest { choice: a.backend, adapter: a.adapter, precision: a.precision, uzawa: a.uzawa, rounds: a.rounds, kernel_times: a.kernel_times }
    }
}

pub(crate) fn parse_backend(s: &str) -> Result<BackendChoice, String> {
    s.parse()
}

pub(crate) fn parse_uzawa(s: &str) -> Result<UzawaPlacement, String> {
    s.parse()
}

pub(crate) fn parse_rounds(s: &str) -> Result<RoundPlacement, String> {
    s.parse()
}

/// A finite number above zero.
pub(crate) fn parse_positive(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        Ok(x) => Err(format!("{x} is not a finite number above zero")),
        Err(e) => Err(e.to_string()),
    }
}

pub(crate) fn parse_precision(s: &str) -> Result<Precision, String> {
    s.parse()
}

/// `--trace` probes must be the scene's, known before any variant runs.
pub(crate) fn check_trace<V>(probes: &[String; 3], scene: &std::collections::BTreeMap<String, V>) -> Result<()> {
    if let Some(missing) = probes.iter().find(|p| !scene.contains_key(p.as_str())) {
        let known: Vec<&str> = scene.keys().map(String::as_str).collect();
        anyhow::bail!("--trace names the probe `{missing}`, which the scene does not define (its probes: {})", if known.is_empty() { "none".into() } else { known.join(", ") });
    }
    Ok(())
}

pub(crate) fn parse_trace(s: &str) -> Result<[String; 3], String> {
    let names: Vec<String> = s.split(',').map(|n| n.trim().to_string()).collect();
    <[String; 3]>::try_from(names).map_err(|_| "expected three probe names, `B,C,D`".to_string())
}
