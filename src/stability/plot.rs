//! The stability map: one cell per value of the first axis (across) and of the second (up), in
//! the order given, coloured by the worst class over the other axes.

use super::{Class, Row};
use crate::output::plot::{register_font, PlotError, FAMILY};
use crate::sweep::SweepAxis;
use plotters::prelude::*;
use std::path::Path;

fn colour(class: Class) -> RGBColor {
    match class {
        Class::Stable => RGBColor(44, 160, 44),
        Class::Degraded => RGBColor(255, 160, 40),
        Class::TooSlow => RGBColor(150, 150, 150),
        Class::Failed => RGBColor(214, 39, 40),
    }
}

/// Draws the map of `rows` over the first two of `axes` (a single row of cells with one axis).
pub fn map_png(path: &Path, title: &str, axes: &[SweepAxis], rows: &[Row]) -> Result<(), PlotError> {
    register_font();
    let draw_err = |e: &dyn std::fmt::Display| PlotError::Draw { path: path.into(), message: e.to_string() };
    let x_values: &[String] = axes.first().map_or(&[], |a| &a.values);
    let y_values: Vec<String> = axes.get(1).map_or_else(|| vec![String::new()], |a| a.values.clone());
    let (nx, ny) = (x_values.len().max(1), y_values.len());
    let root = BitMapBackend::new(path, (180 + 110 * nx as u32, 160 + 70 * ny as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(&e))?;
    let label = |values: &[String]| {
        let values = values.to_vec();
        move |v: &f64| {
            let i = v.round();
            if (v - i).abs() < 1e-6 && i >= 0.0 {
                values.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        }
    };
    let mut chart =
        ChartBuilder::on(&root).caption(title, (FAMILY, 18)).margin(14).x_label_area_size(45).y_label_area_size(if axes.len() > 1 { 110 } else { 20 }).build_cartesian_2d(-0.5..nx as f64 - 0.5, -0.5..ny as f64 - 0.5).map_err(|e| draw_err(&e))?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(axes.first().map_or("", |a| a.key.as_str()))
        .y_desc(axes.get(1).map_or("", |a| a.key.as_str()))
        .x_labels(nx * 2 + 1)
        .y_labels(ny * 2 + 1)
        .x_label_formatter(&label(x_values))
        .y_label_formatter(&label(&y_values))
        .label_style((FAMILY, 12))
        .draw()
        .map_err(|e| draw_err(&e))?;
    for (i, x) in x_values.iter().enumerate() {
        for (j, y) in y_values.iter().enumerate() {
            let of = rows.iter().filter(|r| r.values.first() == Some(x) && (axes.len() < 2 || r.values.get(1) == Some(y)));
            let Some(worst) = of.map(|r| r.class).max() else { continue };
            let (cx, cy) = (i as f64, j as f64);
            chart.draw_series(std::iter::once(Rectangle::new([(cx - 0.48, cy - 0.48), (cx + 0.48, cy + 0.48)], colour(worst).filled()))).map_err(|e| draw_err(&e))?;
            chart.draw_series(std::iter::once(Text::new(worst.name().to_string(), (cx - 0.3, cy + 0.1), (FAMILY, 13).into_font().color(&BLACK)))).map_err(|e| draw_err(&e))?;
        }
    }
    root.present().map_err(|e| draw_err(&e))
}
