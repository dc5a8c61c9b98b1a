//! `bifirst plot`: PNG figures from one or more run logs, one line per run in every panel (so
//! that a sweep can be compared): energies, each probe, and the solver's effort per step.

mod contour;

pub use contour::contour_png;

use super::read::{ReadError, RunRecord};
use crate::contact::geometry::{dot, normalize, scale, sub};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// DejaVu Sans (licence beside this file): the bitmap backend draws text with a font it is given.
const FONT: &[u8] = include_bytes!("DejaVuSans.ttf");
pub(crate) const FAMILY: &str = "sans-serif";

const COLORS: [RGBColor; 10] =
    [RGBColor(31, 119, 180), RGBColor(255, 127, 14), RGBColor(44, 160, 44), RGBColor(214, 39, 40), RGBColor(148, 103, 189), RGBColor(140, 86, 75), RGBColor(227, 119, 194), RGBColor(127, 127, 127), RGBColor(188, 189, 34), RGBColor(23, 190, 207)];

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{0}")]
    Read(#[from] ReadError),
    #[error("cannot create `{path}`: {source}")]
    Create { path: PathBuf, source: std::io::Error },
    #[error("cannot draw `{path}`: {message}")]
    Draw { path: PathBuf, message: String },
    #[error("`{path}` logs no probe `{probe}` ({known})")]
    NoProbe { path: PathBuf, probe: String, known: String },
}

/// One panel: a quantity against time, one line per run.
pub(crate) struct Panel {
    pub(crate) title: String,
    pub(crate) x_label: String,
    pub(crate) y_label: String,
    pub(crate) lines: Vec<Vec<(f64, f64)>>,
}

impl Panel {
    /// `field` of `topic` against its `t`, for each run; `map` transforms each value.
    fn of(runs: &[RunRecord], title: &str, y_label: &str, topic: &str, value: impl Fn(&serde_json::Value) -> Option<f64>) -> Self {
        let lines = runs.iter().map(|r| r.messages(topic).iter().filter_map(|m| Some((m["t"].as_f64()?, value(m)?))).filter(|(t, v)| t.is_finite() && v.is_finite()).collect()).collect();
        Self { title: title.into(), x_label: "t".into(), y_label: y_label.into(), lines }
    }
}

pub(crate) fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The bundled font is valid TrueType; a failure here would show as missing text only.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT);
    });
}

/// A range that plotters can draw even for a constant or empty series (a spread below 1e-9 of
/// the values, such as round-off in a constant time step, counts as constant).
pub(crate) fn range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    let magnitude = lo.abs().max(hi.abs());
    if hi - lo <= 1e-9 * magnitude {
        let pad = if magnitude > 0.0 { 0.1 * magnitude } else { 1.0 };
        return (lo - pad)..(hi + pad);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad)..(hi + pad)
}

/// Tick labels that tell the ticks of a range apart: fixed-point for moderate magnitudes,
/// scientific otherwise.
pub(crate) fn tick_format(r: &std::ops::Range<f64>) -> impl Fn(&f64) -> String {
    let magnitude = r.start.abs().max(r.end.abs());
    let significant = ((magnitude / (r.end - r.start)).log10().ceil().max(0.0) as i32 + 2).min(12);
    let exponent = magnitude.log10().floor() as i32;
    move |v: &f64| {
        // A tick at zero computed as round-off (1e-20) reads as zero.
        let v = if v.abs() < 1e-9 * magnitude { &0.0 } else { v };
        if (-2..4).contains(&exponent) {
            format!("{v:.*}", (significant - 1 - exponent).clamp(0, 12) as usize)
        } else {
            format!("{v:.*e}", (significant - 1).max(0) as usize)
        }
    }
}

/// Height of one row of the legend strip under the title.
const LEGEND_ROW: u32 = 24;

/// Draws panels in a grid of `columns` into `path`; with several runs, a legend strip under the
/// title names them once, outside the panels, so that no data is hidden behind it.
pub(crate) fn figure(path: &Path, title: &str, names: &[String], panels: &[Panel], columns: usize) -> Result<(), PlotError> {
    register_font();
    let draw_err = |e: &dyn std::fmt::Display| PlotError::Draw { path: path.into(), message: e.to_string() };
    let rows = panels.len().div_ceil(columns);
    let width = 560 * columns as u32;
    // Legend entries flow left to right, wrapping at the figure's width.
    let entry_width = |name: &String| 40 + 8 * name.chars().count() as u32;
    let mut legend_rows: Vec<Vec<usize>> = vec![Vec::new()];
    let mut used = 0;
    for (i, name) in names.iter().enumerate().filter(|_| names.len() > 1) {
        if used + entry_width(name) > width - 40 && !legend_rows.last().expect("one row").is_empty() {
            legend_rows.push(Vec::new());
            used = 0;
        }
        used += entry_width(name);
        legend_rows.last_mut().expect("one row").push(i);
    }
    let legend_height = if names.len() > 1 { LEGEND_ROW * legend_rows.len() as u32 + 8 } else { 0 };
    let root = BitMapBackend::new(path, (width, 380 * rows as u32 + 50 + legend_height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(&e))?;
    let titled = root.titled(title, (FAMILY, 26)).map_err(|e| draw_err(&e))?;
    let (legend, body) = titled.split_vertically(legend_height);
    for (r, row) in legend_rows.iter().enumerate() {
        let y = (r as u32 * LEGEND_ROW + LEGEND_ROW / 2) as i32;
        let mut x = 20i32;
        for &i in row {
            let color = COLORS[i % COLORS.len()];
            legend.draw(&PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(3))).map_err(|e| draw_err(&e))?;
            legend.draw(&Text::new(names[i].clone(), (x + 30, y - 8), (FAMILY, 14).into_font().color(&BLACK))).map_err(|e| draw_err(&e))?;
            x += entry_width(&names[i]) as i32;
        }
    }
    for (area, panel) in body.split_evenly((rows, columns)).iter().zip(panels) {
        let x = range(panel.lines.iter().flatten().map(|p| p.0));
        let y = range(panel.lines.iter().flatten().map(|p| p.1));
        let (x_format, y_format) = (tick_format(&x), tick_format(&y));
        let mut chart = ChartBuilder::on(area).caption(&panel.title, (FAMILY, 18)).margin(12).x_label_area_size(40).y_label_area_size(80).build_cartesian_2d(x, y).map_err(|e| draw_err(&e))?;
        chart.configure_mesh().x_desc(panel.x_label.as_str()).y_desc(panel.y_label.as_str()).label_style((FAMILY, 13)).y_label_formatter(&y_format).x_label_formatter(&x_format).draw().map_err(|e| draw_err(&e))?;
        for (i, line) in panel.lines.iter().enumerate() {
            let color = COLORS[i % COLORS.len()];
            // One pixel wide: plotters' wide lines spike on near-vertical segments.
            chart.draw_series(LineSeries::new(line.iter().copied(), color)).map_err(|e| draw_err(&e))?;
        }
    }
    root.present().map_err(|e| draw_err(&e))
}

fn field(name: &'static str) -> impl Fn(&serde_json::Value) -> Option<f64> {
    move |m| m[name].as_f64()
}

/// Labels that tell runs apart: scene names, or file stems when scene names repeat (a sweep).
fn run_names(runs: &[RunRecord]) -> Vec<String> {
    let names: Vec<String> = runs.iter().map(RunRecord::name).collect();
    let unique = names.iter().collect::<std::collections::BTreeSet<_>>().len() == names.len();
    if unique {
        names
    } else {
        runs.iter().map(|r| r.path.file_stem().map_or_else(|| "run".into(), |s| s.to_string_lossy().into_owned())).collect()
    }
}

/// What to draw besides the standard figures, and how to name the runs.
#[derive(Debug, Clone, Default)]
pub struct PlotOptions {
    /// Legend entries, one per run (default: scene names, or file stems when they repeat).
    pub labels: Option<Vec<String>>,
    /// Probes `[B, C, D]`: draw B's path in the plane through the reference positions of B, C
    /// and D (the paper's Figure 5).
    pub trace: Option<[String; 3]>,
}

/// Writes `energies.png`, `solver.png`, `probe_<name>.png` (and `trace_<B>.png`) for the runs
/// into `out`; returns the files written.
pub fn plot_runs(runs: &[RunRecord], out: &Path, options: &PlotOptions) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(out).map_err(|source| PlotError::Create { path: out.into(), source })?;
    for r in runs {
        r.require("/energy")?;
    }
    let names = options.labels.clone().unwrap_or_else(|| run_names(runs));
    let mut written = Vec::new();

    let energy = |title: &str, key: &'static str| Panel::of(runs, title, "energy", "/energy", field(key));
    let balance = Panel::of(runs, "energy balance error", "log10 relative error", "/energy", |m| Some(m["energy_balance_error"].as_f64()?.max(1e-17).log10()));
    let panels = [
        energy("kinetic", "kinetic"),
        energy("strain", "strain"),
        energy("total (kinetic + strain + potential)", "total"),
        energy("friction dissipation", "friction_dissipation"),
        energy("viscous dissipation", "viscous_dissipation"),
        energy("numerical dissipation", "numerical_dissipation"),
        balance,
    ];
    let path = out.join("energies.png");
    figure(&path, "Energies", &names, &panels, 3)?;
    written.push(path);

    let solver = [
        Panel::of(runs, "Newton iterations per step", "iterations", "/solver", field("newton_iterations")),
        Panel::of(runs, "Uzawa sweeps per step", "sweeps", "/solver", field("uzawa_iterations")),
        Panel::of(runs, "wall time per step", "seconds", "/solver", |m| m["wall_s"]["total"].as_f64()),
        Panel::of(runs, "time step", "dt", "/solver", field("dt")),
    ];
    let path = out.join("solver.png");
    figure(&path, "Solver", &names, &solver, 2)?;
    written.push(path);

    let mut probes: Vec<String> = runs.iter().flat_map(|r| r.names_under("/probe/")).collect();
    probes.sort();
    probes.dedup();
    for probe in probes {
        let topic = format!("/probe/{probe}");
        let dim = runs.iter().find_map(|r| r.messages(&topic).first()).and_then(|m| m["position"].as_array()).map_or(2, Vec::len);
        let mut panels = vec![Panel::of(runs, "von Mises stress", "stress", &topic, field("von_mises"))];
        for (i, axis) in ["x", "y", "z"].iter().enumerate().take(dim) {
            panels.push(Panel::of(runs, &format!("position {axis}"), axis, &topic, move |m| m["position"][i].as_f64()));
        }
        let path = out.join(format!("probe_{probe}.png"));
        figure(&path, &format!("Probe {probe}"), &names, &panels, 2)?;
        written.push(path);
    }
    if let Some(probes) = &options.trace {
        let path = out.join(format!("trace_{}.png", probes[0]));
        let panel = trace_panel(runs, probes)?;
        figure(&path, &format!("Trace of {} in the plane {}{}{}", probes[0], probes[0], probes[1], probes[2]), &names, &[panel], 1)?;
        written.push(path);
    }
    Ok(written)
}

/// A probe's reference position (its position minus its displacement at the first message).
fn reference(run: &RunRecord, probe: &str) -> Result<[f64; 3], PlotError> {
    let topic = format!("/probe/{probe}");
    let Some(first) = run.messages(&topic).first() else {
        let probes = run.names_under("/probe/");
        let known = if probes.is_empty() { "it has none".to_string() } else { format!("it has {}", probes.join(", ")) };
        return Err(PlotError::NoProbe { path: run.path.clone(), probe: probe.into(), known });
    };
    let at = |field: &str, i: usize| first[field][i].as_f64().unwrap_or(0.0);
    Ok([0, 1, 2].map(|i| at("position", i) - at("displacement", i)))
}

/// B's displacement in the plane BCD: along BC, and along the in-plane perpendicular to BC
/// that points from D's side towards B.
fn trace_panel(runs: &[RunRecord], [b, c, d]: &[String; 3]) -> Result<Panel, PlotError> {
    let mut lines = Vec::new();
    for run in runs {
        let (b0, c0, d0) = (reference(run, b)?, reference(run, c)?, reference(run, d)?);
        let e1 = normalize(sub(c0, b0));
        let bd = sub(b0, d0);
        let e2 = normalize(sub(bd, scale(e1, dot(bd, e1))));
        let line = run
            .messages(&format!("/probe/{b}"))
            .iter()
            .filter_map(|m| {
                let p = [0, 1, 2].map(|i| m["position"][i].as_f64().unwrap_or(0.0));
                let u = sub(p, b0);
                let (s, n) = (dot(u, e1), dot(u, e2));
                (s.is_finite() && n.is_finite()).then_some((s, n))
            })
            .collect();
        lines.push(line);
    }
    Ok(Panel { title: format!("displacement of {b} in the plane {b}{c}{d}"), x_label: format!("along {b}{c}"), y_label: format!("across {b}{c}, towards {b}"), lines })
}
