//! `bifirst summary`: the totals of one or more run logs as a table (or JSON).

use super::read::{ReadError, RunRecord};
use super::run_summary::energy_gain;
use crate::solver::Energies;
use serde_json::Value;

const PHASES: [&str; 7] = ["elements", "assembly", "transfer", "factorization", "solve", "contact", "contact_newton"];

/// The totals of one run log.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LogSummary {
    pub name: String,
    /// The log file, as given: two runs of one scene differ here.
    pub file: String,
    /// `cpu` or `gpu`, from `/run`.
    pub backend: String,
    /// `f64` or `f32`, from `/run`.
    pub precision: String,
    /// The GPU adapter, when the run used one.
    pub adapter: Option<String>,
    /// `finished`, `failed`, `interrupted`, or `incomplete` (no `/summary`: the process died).
    pub status: String,
    pub message: Option<String>,
    pub steps: u64,
    pub t_end: f64,
    pub cutbacks: u64,
    pub newton_iterations: u64,
    pub uzawa_iterations: u64,
    /// Semi-smooth Newton iterations of stalled contact problems (0 in logs written before them).
    pub contact_newton_iterations: u64,
    pub bodies_iterated: u64,
    /// Newton increments taken on the device (0 on the CPU, and in logs written before them).
    pub device_iterations: u64,
    pub factorizations: u64,
    /// Total energy at the end minus at the start.
    pub energy_drift: f64,
    /// `energy_drift` relative to the largest of the initial and final total energies.
    pub relative_energy_drift: f64,
    pub energy_balance_error: f64,
    /// Cumulative dissipation at the end: friction, and the viscoelastic branches (0 in logs
    /// written before viscoelasticity).
    pub friction_dissipation: f64,
    pub viscous_dissipation: f64,
    pub max_penetration: f64,
    /// Deepest node inside another body or an obstacle, and that depth in local element sizes.
    pub max_overlap: f64,
    pub max_overlap_ratio: f64,
    /// Steps that created energy (numerical dissipation below zero beyond a tolerance).
    pub energy_gain_steps: u64,
    /// Wall seconds per phase (`elements`, ..., `contact`, then `total`).
    pub wall_by_phase: Vec<(String, f64)>,
    pub probes: Vec<ProbeSummary>,
}

/// The extremes of a probe over the run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ProbeSummary {
    pub name: String,
    pub max_von_mises: f64,
    /// Per axis, the largest minus the smallest coordinate over the run (the motion's extent).
    pub position_range: Vec<f64>,
}

fn probe_summary(record: &RunRecord, name: String) -> ProbeSummary {
    let messages = record.messages(&format!("/probe/{name}"));
    let dim = messages.first().and_then(|m| m["position"].as_array()).map_or(0, Vec::len);
    let max_von_mises = messages.iter().map(|m| number(&m["von_mises"])).fold(0.0, f64::max);
    let position_range = (0..dim)
        .map(|i| {
            let (lo, hi) = messages.iter().map(|m| number(&m["position"][i])).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| (lo.min(x), hi.max(x)));
            hi - lo
        })
        .collect();
    ProbeSummary { name, max_von_mises, position_range }
}

fn number(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

fn count(v: &Value) -> u64 {
    v.as_u64().unwrap_or(0)
}

/// The logged steps that created energy, by the run's own rule ([`energy_gain`]); with
/// `output.every` > 1, each logged interval counts as a step.
fn energy_gain_steps(energy: &[Value]) -> u64 {
    let Some(first) = energy.first() else { return 0 };
    let e0 = number(&first["total"]);
    energy
        .windows(2)
        .filter(|w| {
            let after = Energies { total: number(&w[1]["total"]), external_work: number(&w[1]["external_work"]), numerical_dissipation: number(&w[1]["numerical_dissipation"]), ..Default::default() };
            energy_gain(e0, &after, number(&w[0]["numerical_dissipation"])).is_some()
        })
        .count() as u64
}

/// Sums the logged steps when the run has no `/summary` (a killed process).
fn from_steps(record: &RunRecord) -> (Value, &'static str) {
    let solver = record.messages("/solver");
    let sum = |field: &str| solver.iter().map(|m| count(&m[field])).sum::<u64>();
    let phase = |p: &str| solver.iter().map(|m| number(&m["wall_s"][p])).sum::<f64>();
    let mut wall = serde_json::Map::new();
    for p in PHASES.iter().chain(&["total"]) {
        wall.insert(p.to_string(), phase(p).into());
    }
    let last = solver.last();
    let first = record.messages("/run").first().map_or(0, |m| count(&m["first_step"]));
    let summary = serde_json::json!({
        "steps": last.map_or(0, |m| count(&m["step"]).saturating_sub(first)),
        "t_end": last.map_or(0.0, |m| number(&m["t"])),
        "cutbacks": sum("cutbacks"),
        "newton_iterations": sum("newton_iterations"),
        "uzawa_iterations": sum("uzawa_iterations"),
        "contact_newton_iterations": sum("contact_newton_iterations"),
        "bodies_iterated": sum("bodies_iterated"),
        "device_iterations": sum("device_iterations"),
        "factorizations": sum("factorizations"),
        "max_penetration": record.series("/contact", "max_penetration").into_iter().fold(0.0, f64::max),
        "max_overlap": record.series("/contact", "max_overlap").into_iter().fold(0.0, f64::max),
        "max_overlap_ratio": record.series("/contact", "max_overlap_ratio").into_iter().fold(0.0, f64::max),
        "energy_gain_steps": energy_gain_steps(record.messages("/energy")),
        "wall_by_phase": wall,
        "message": Value::Null,
    });
    (summary, "incomplete")
}

/// The totals of a run log: its `/summary` message, else the sums of its logged steps.
pub fn summarize(record: &RunRecord) -> Result<LogSummary, ReadError> {
    let energy = record.require("/energy")?;
    let (s, status) = match record.messages("/summary").last() {
        Some(s) => (s.clone(), s["status"].as_str().unwrap_or("unknown")),
        None => from_steps(record),
    };
    let (first, last) = (&energy[0], &energy[energy.len() - 1]);
    let (e0, e1) = (number(&first["total"]), number(&last["total"]));
    let drift = e1 - e0;
    let wall = &s["wall_by_phase"];
    let run = record.messages("/run").first().cloned().unwrap_or(Value::Null);
    let text = |key: &str| run[key].as_str().unwrap_or("unknown").to_string();
    Ok(LogSummary {
        name: record.name(),
        file: record.path.display().to_string(),
        backend: text("backend"),
        precision: text("precision"),
        adapter: run["adapter"].as_str().map(String::from),
        status: status.to_string(),
        message: s["message"].as_str().map(String::from),
        steps: count(&s["steps"]),
        t_end: number(&s["t_end"]),
        cutbacks: count(&s["cutbacks"]),
        newton_iterations: count(&s["newton_iterations"]),
        uzawa_iterations: count(&s["uzawa_iterations"]),
        contact_newton_iterations: count(&s["contact_newton_iterations"]),
        bodies_iterated: count(&s["bodies_iterated"]),
        device_iterations: count(&s["device_iterations"]),
        factorizations: count(&s["factorizations"]),
        energy_drift: drift,
        relative_energy_drift: drift / e0.abs().max(e1.abs()).max(f64::MIN_POSITIVE),
        energy_balance_error: number(&last["energy_balance_error"]),
        friction_dissipation: number(&last["friction_dissipation"]),
        viscous_dissipation: last["viscous_dissipation"].as_f64().unwrap_or(0.0),
        max_penetration: number(&s["max_penetration"]),
        max_overlap: number(&s["max_overlap"]),
        max_overlap_ratio: number(&s["max_overlap_ratio"]),
        energy_gain_steps: count(&s["energy_gain_steps"]),
        wall_by_phase: PHASES.iter().chain(&["total"]).map(|p| (p.to_string(), number(&wall[*p]))).collect(),
        probes: record.names_under("/probe/").into_iter().map(|name| probe_summary(record, name)).collect(),
    })
}

/// A table with one column per run.
pub fn table(runs: &[LogSummary]) -> String {
    let per_step = |r: &LogSummary, n: u64| if r.steps > 0 { format!("{n} ({:.2}/step)", n as f64 / r.steps as f64) } else { n.to_string() };
    let mut rows: Vec<(String, Vec<String>)> = vec![
        ("run".into(), runs.iter().map(|r| r.name.clone()).collect()),
        ("file".into(), runs.iter().map(|r| r.file.clone()).collect()),
        ("backend, precision".into(), runs.iter().map(|r| format!("{} {}", r.backend, r.precision)).collect()),
        ("status".into(), runs.iter().map(|r| r.status.clone()).collect()),
        ("steps".into(), runs.iter().map(|r| r.steps.to_string()).collect()),
        ("t end".into(), runs.iter().map(|r| format!("{:.6e}", r.t_end)).collect()),
        ("cut-backs".into(), runs.iter().map(|r| r.cutbacks.to_string()).collect()),
        ("Newton iterations".into(), runs.iter().map(|r| per_step(r, r.newton_iterations)).collect()),
        ("Uzawa sweeps".into(), runs.iter().map(|r| per_step(r, r.uzawa_iterations)).collect()),
        ("contact Newton iterations".into(), runs.iter().map(|r| per_step(r, r.contact_newton_iterations)).collect()),
        ("bodies iterated".into(), runs.iter().map(|r| per_step(r, r.bodies_iterated)).collect()),
        ("device Newton increments".into(), runs.iter().map(|r| per_step(r, r.device_iterations)).collect()),
        ("factorisations".into(), runs.iter().map(|r| per_step(r, r.factorizations)).collect()),
        // Not a drift in every run: friction, a moving wall or a support change the energy on purpose.
        ("total energy, end - start".into(), runs.iter().map(|r| format!("{:.4e} ({:+.2e} rel.)", r.energy_drift, r.relative_energy_drift)).collect()),
        ("energy balance error".into(), runs.iter().map(|r| format!("{:.2e}", r.energy_balance_error)).collect()),
        ("dissipated: friction, viscous".into(), runs.iter().map(|r| format!("{:.4e}, {:.4e}", r.friction_dissipation, r.viscous_dissipation)).collect()),
        ("max penetration".into(), runs.iter().map(|r| format!("{:.3e}", r.max_penetration)).collect()),
        ("steps creating energy".into(), runs.iter().map(|r| r.energy_gain_steps.to_string()).collect()),
        ("max overlap".into(), runs.iter().map(|r| format!("{:.3e} ({:.2}% of h)", r.max_overlap, 100.0 * r.max_overlap_ratio)).collect()),
    ];
    for (i, phase) in PHASES.iter().chain(&["total"]).enumerate() {
        let label = if *phase == "total" { "wall s, steps total".to_string() } else { format!("wall s, {phase}") };
        let cells = runs
            .iter()
            .map(|r| {
                let (value, total) = (r.wall_by_phase[i].1, r.wall_by_phase[PHASES.len()].1);
                if *phase == "total" || total <= 0.0 {
                    format!("{value:.3}")
                } else {
                    format!("{value:.3} ({:.0}%)", 100.0 * value / total)
                }
            })
            .collect();
        rows.push((label, cells));
    }
    let mut probes: Vec<&str> = runs.iter().flat_map(|r| r.probes.iter().map(|p| p.name.as_str())).collect();
    probes.sort_unstable();
    probes.dedup();
    for name in probes {
        let of = |r: &LogSummary| r.probes.iter().find(|p| p.name == name).cloned();
        let cell = |r: &LogSummary, f: &dyn Fn(&ProbeSummary) -> String| of(r).map_or_else(|| "-".into(), |p| f(&p));
        rows.push((format!("probe {name}, max von Mises"), runs.iter().map(|r| cell(r, &|p| format!("{:.4e}", p.max_von_mises))).collect()));
        let range = |p: &ProbeSummary| format!("[{}]", p.position_range.iter().map(|x| format!("{x:.3e}")).collect::<Vec<_>>().join(", "));
        rows.push((format!("probe {name}, motion range"), runs.iter().map(|r| cell(r, &range)).collect()));
    }
    let label_width = rows.iter().map(|(l, _)| l.len()).max().unwrap_or(0);
    let widths: Vec<usize> = (0..runs.len()).map(|c| rows.iter().map(|(_, cells)| cells[c].len()).max().unwrap_or(0)).collect();
    let mut out = String::new();
    for (label, cells) in &rows {
        out.push_str(&format!("{label:<label_width$}"));
        for (cell, w) in cells.iter().zip(&widths) {
            out.push_str(&format!("  {cell:>w$}"));
        }
        out.push('\n');
    }
    for r in runs.iter().filter(|r| r.adapter.is_some()) {
        out.push_str(&format!("{}: adapter {}\n", r.file, r.adapter.as_deref().unwrap_or_default()));
    }
    for r in runs.iter().filter(|r| r.message.is_some()) {
        out.push_str(&format!("{}: {}\n", r.file, r.message.as_deref().unwrap_or_default()));
    }
    out
}
