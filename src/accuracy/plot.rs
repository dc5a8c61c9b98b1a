//! The PNG of a study: wall time against error on log scales, the Pareto front joined.

use super::Row;
use crate::output::plot::{register_font, PlotError, FAMILY};
use plotters::prelude::*;
use std::path::Path;

/// The smallest error drawn: an exact answer (error 0) sits at the bottom of the plot.
const ERROR_FLOOR: f64 = 1e-16;

/// Log-scale range around `values`, padded by a quarter decade.
fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values.filter(|v| v.is_finite() && *v > 0.0).fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !lo.is_finite() {
        return 1e-3..1.0;
    }
    let pad = 10f64.powf(0.25);
    (lo / pad)..(hi * pad).max(lo * pad * pad)
}

/// A tick label at 1, 2 and 5 times a power of ten, none elsewhere (log axes get many ticks).
fn nice(v: &f64) -> String {
    let exponent = v.log10().floor();
    let mantissa = v / 10f64.powf(exponent);
    if [1.0, 2.0, 5.0, 10.0].iter().any(|m| (mantissa - m).abs() < 1e-6 * m) {
        format!("{v:.0e}")
    } else {
        String::new()
    }
}

/// Draws every finished row as a point (the front filled and joined, the others hollow), each
/// labelled with its variant (or its index when there are many), and `target` as a dashed level.
pub fn pareto_png(path: &Path, title: &str, rows: &[Row], target: f64) -> Result<(), PlotError> {
    register_font();
    let draw_err = |e: &dyn std::fmt::Display| PlotError::Draw { path: path.into(), message: e.to_string() };
    let points: Vec<(&Row, f64, f64)> = rows.iter().filter(|r| r.status == "finished" && r.error.is_finite()).map(|r| (r, r.wall_s, r.error.max(ERROR_FLOOR))).collect();
    let x = log_range(points.iter().map(|p| p.1));
    let y = log_range(points.iter().map(|p| p.2).chain(std::iter::once(target)));
    let root = BitMapBackend::new(path, (900, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(&e))?;
    let mut chart = ChartBuilder::on(&root).caption(title, (FAMILY, 20)).margin(16).margin_right(150).x_label_area_size(45).y_label_area_size(80).build_cartesian_2d(x.clone().log_scale(), y.clone().log_scale()).map_err(|e| draw_err(&e))?;
    chart
        .configure_mesh()
        .x_desc("wall time per run (s)")
        .y_desc("error (largest relative error of the measure)")
        .label_style((FAMILY, 13))
        .x_labels(40)
        .y_labels(40)
        .x_label_formatter(&nice)
        .y_label_formatter(&nice)
        .draw()
        .map_err(|e| draw_err(&e))?;
    let (front_color, other_color) = (RGBColor(214, 39, 40), RGBColor(31, 119, 180));
    chart
        .draw_series(DashedLineSeries::new([(x.start, target), (x.end, target)], 6, 4, BLACK.mix(0.5).stroke_width(1)))
        .map_err(|e| draw_err(&e))?
        .label(format!("target {target:.0e}"))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5)));
    let mut front: Vec<(f64, f64)> = points.iter().filter(|p| p.0.pareto).map(|p| (p.1, p.2)).collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    chart.draw_series(LineSeries::new(front.iter().copied(), front_color.stroke_width(2))).map_err(|e| draw_err(&e))?.label("Pareto front").legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], front_color.stroke_width(2)));
    let many = points.len() > 12;
    for (row, t, e) in &points {
        let (color, filled) = if row.pareto { (front_color, true) } else { (other_color, false) };
        let style = if filled { color.filled() } else { color.stroke_width(2) };
        let text = if many { row.index.to_string() } else { row.label.clone() };
        chart.draw_series(std::iter::once(EmptyElement::at((*t, *e)) + Circle::new((0, 0), 5, style) + Text::new(text, (8, -14), (FAMILY, 12).into_font().color(&BLACK)))).map_err(|e| draw_err(&e))?;
    }
    chart.configure_series_labels().position(SeriesLabelPosition::UpperRight).label_font((FAMILY, 13)).background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(|e| draw_err(&e))?;
    root.present().map_err(|e| draw_err(&e))
}
