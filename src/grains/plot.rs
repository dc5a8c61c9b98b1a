//! The pictures of `bifirst grains`: the force chains at one step, the time series, the
//! distribution of normal forces and the rose of contact orientations.

use super::{container, equivalent_radius, ForceDistribution, Measures, Network, Networks, Other, ROSE_SECTORS};
use crate::output::plot::{figure, register_font, tick_format, Panel, PlotError, FAMILY};
use plotters::prelude::*;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

const CHAIN: RGBColor = RGBColor(200, 30, 30);
const OUTLINE: RGBColor = RGBColor(120, 120, 120);

/// Writes the four pictures into `out`; returns their paths.
pub fn pictures(networks: &Networks, at: &Network, rows: &[Measures], distribution: &ForceDistribution, rose: &[f64], out: &Path) -> Result<Vec<PathBuf>, PlotError> {
    let paths = [out.join("force_chains.png"), out.join("grains_series.png"), out.join("force_pdf.png"), out.join("rose.png")];
    force_chains(&paths[0], &format!("{}: force chains at t = {:.4e}{}", networks.scene, at.t, if at.dim == 3 { " (x-y projection)" } else { "" }), at)?;
    series(&paths[1], &networks.scene, rows)?;
    force_pdf(&paths[2], &format!("{}: normal forces at t = {:.4e}", networks.scene, at.t), distribution)?;
    orientation_rose(&paths[3], &format!("{}: contact orientations at t = {:.4e}", networks.scene, at.t), rose)?;
    Ok(paths.to_vec())
}

fn draw_error(path: &Path) -> impl Fn(&dyn std::fmt::Display) -> PlotError + '_ {
    move |e| PlotError::Draw { path: path.into(), message: e.to_string() }
}

/// Each grain as the circle of its volume (the x-y projection in 3D) and a bar between the
/// centres of each pair in contact (to the contact point for a wall), as wide as its normal
/// force against the largest: a grain's mean radius at most.
fn force_chains(path: &Path, title: &str, net: &Network) -> Result<(), PlotError> {
    register_font();
    let err = draw_error(path);
    let boxed = container(net);
    let radii: Vec<f64> = net.volumes.iter().map(|v| equivalent_radius(*v, net.dim)).collect();
    let mean_radius = radii.iter().sum::<f64>() / radii.len().max(1) as f64;
    let (x, y) = ((boxed[0][0] - mean_radius)..(boxed[0][1] + mean_radius), (boxed[1][0] - mean_radius)..(boxed[1][1] + mean_radius));
    let aspect = (y.end - y.start) / (x.end - x.start);
    let width = 1200u32;
    let height = ((width as f64 * aspect) as u32 + 60).clamp(300, 2400);
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root).caption(title, (FAMILY, 22)).margin(10).build_cartesian_2d(x, y).map_err(|e| err(&e))?;
    let circle = |c: [f64; 3], r: f64| -> Vec<(f64, f64)> { (0..=32).map(|k| 2.0 * PI * k as f64 / 32.0).map(|a| (c[0] + r * a.cos(), c[1] + r * a.sin())).collect() };
    chart.draw_series(net.centers.iter().zip(&radii).map(|(c, r)| PathElement::new(circle(*c, *r), OUTLINE))).map_err(|e| err(&e))?;
    let largest = net.contacts.iter().fold(0.0f64, |m, c| m.max(c.normal_force));
    let bar = |a: [f64; 3], b: [f64; 3], force: f64| -> Vec<(f64, f64)> {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let length = (dx * dx + dy * dy).sqrt().max(f64::MIN_POSITIVE);
        let half = 0.5 * mean_radius * force / largest;
        let (nx, ny) = (-dy / length * half, dx / length * half);
        vec![(a[0] + nx, a[1] + ny), (b[0] + nx, b[1] + ny), (b[0] - nx, b[1] - ny), (a[0] - nx, a[1] - ny)]
    };
    let bars = net.contacts.iter().filter(|c| c.normal_force > 0.0).map(|c| {
        let end = match c.other {
            Other::Body(b) => net.centers[b],
            Other::Obstacle(_) => c.point,
        };
        Polygon::new(bar(net.centers[c.body], end, c.normal_force), CHAIN.filled())
    });
    chart.draw_series(bars).map_err(|e| err(&e))?;
    let walls = boxed.iter().take(2).collect::<Vec<_>>();
    let frame = vec![(walls[0][0], walls[1][0]), (walls[0][1], walls[1][0]), (walls[0][1], walls[1][1]), (walls[0][0], walls[1][1]), (walls[0][0], walls[1][0])];
    chart.draw_series(std::iter::once(PathElement::new(frame, BLACK.stroke_width(2)))).map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))
}

/// The measures against time, one panel each.
fn series(path: &Path, scene: &str, rows: &[Measures]) -> Result<(), PlotError> {
    let panel = |title: &str, value: &dyn Fn(&Measures) -> f64| Panel { title: title.into(), x_label: "t".into(), y_label: title.into(), lines: vec![rows.iter().map(|r| (r.t, value(r))).filter(|(t, v)| t.is_finite() && v.is_finite()).collect()] };
    let panels = [
        panel("solid fraction", &|r| r.solid_fraction),
        panel("coordination Z", &|r| r.coordination),
        panel("Z without rattlers", &|r| r.coordination_without_rattlers),
        panel("sliding fraction", &|r| r.sliding_fraction),
        panel("Love-Weber pressure p", &|r| r.pressure),
        panel("mean wall pressure", &|r| r.wall_pressure),
        panel("deviator q", &|r| r.deviator),
        panel("fabric anisotropy", &|r| r.fabric_anisotropy),
    ];
    figure(path, &format!("{scene}: granular measures"), &[scene.to_string()], &panels, 2)
}

/// The density of `f / <f>` on a log scale, with the fitted exponential tail.
fn force_pdf(path: &Path, title: &str, d: &ForceDistribution) -> Result<(), PlotError> {
    register_font();
    let err = draw_error(path);
    let filled: Vec<(f64, f64)> = d.bins.iter().filter(|b| b[1] > 0.0).map(|b| (b[0], b[1])).collect();
    let x = 0.0..d.bins.last().map_or(1.0, |b| b[0] + 0.5);
    let (lo, hi) = filled.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
    let y = if filled.is_empty() { 0.01..1.0 } else { (0.5 * lo)..(2.0 * hi) };
    let root = BitMapBackend::new(path, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let x_format = tick_format(&x);
    let mut chart = ChartBuilder::on(&root).caption(title, (FAMILY, 20)).margin(12).x_label_area_size(40).y_label_area_size(70).build_cartesian_2d(x.clone(), y.log_scale()).map_err(|e| err(&e))?;
    chart.configure_mesh().x_desc("f / <f>").y_desc("probability density").label_style((FAMILY, 13)).x_label_formatter(&x_format).draw().map_err(|e| err(&e))?;
    chart.draw_series(filled.iter().map(|&p| Circle::new(p, 4, RGBColor(31, 119, 180).filled()))).map_err(|e| err(&e))?;
    if let (Some(beta), Some(amplitude)) = (d.tail_decay, d.tail_amplitude) {
        let line: Vec<(f64, f64)> = (0..=50).map(|k| 1.0 + (x.end - 1.0) * k as f64 / 50.0).map(|f| (f, amplitude * (-beta * f).exp())).filter(|p| p.1 >= 0.5 * lo).collect();
        chart.draw_series(LineSeries::new(line, RGBColor(214, 39, 40).stroke_width(2))).map_err(|e| err(&e))?.label(format!("exp(-{beta:.2} f/<f>)")).legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RGBColor(214, 39, 40)));
        chart.configure_series_labels().background_style(WHITE).border_style(BLACK).label_font((FAMILY, 14)).draw().map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))
}

/// Each sector's share as a wedge, and its mirror (a normal has no sign).
fn orientation_rose(path: &Path, title: &str, rose: &[f64]) -> Result<(), PlotError> {
    register_font();
    let err = draw_error(path);
    let largest = rose.iter().fold(0.0f64, |m, r| m.max(*r)).max(f64::MIN_POSITIVE);
    let root = BitMapBackend::new(path, (700, 740)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let span = -1.1..1.1;
    let mut chart = ChartBuilder::on(&root).caption(title, (FAMILY, 18)).margin(12).build_cartesian_2d(span.clone(), span).map_err(|e| err(&e))?;
    let sector = PI / ROSE_SECTORS as f64;
    for half in [0.0, PI] {
        chart
            .draw_series(rose.iter().enumerate().map(|(k, share)| {
                let r = share / largest;
                let (a0, a1) = (half + k as f64 * sector, half + (k + 1) as f64 * sector);
                let mut wedge = vec![(0.0, 0.0)];
                wedge.extend((0..=8).map(|j| a0 + (a1 - a0) * j as f64 / 8.0).map(|a| (r * a.cos(), r * a.sin())));
                Polygon::new(wedge, RGBColor(31, 119, 180).mix(0.7).filled())
            }))
            .map_err(|e| err(&e))?;
    }
    let ring: Vec<(f64, f64)> = (0..=64).map(|k| 2.0 * PI * k as f64 / 64.0).map(|a| (a.cos(), a.sin())).collect();
    chart.draw_series(std::iter::once(PathElement::new(ring, BLACK))).map_err(|e| err(&e))?;
    chart.draw_series([PathElement::new(vec![(-1.05, 0.0), (1.05, 0.0)], BLACK), PathElement::new(vec![(0.0, -1.05), (0.0, 1.05)], BLACK)]).map_err(|e| err(&e))?;
    chart.draw_series(std::iter::once(Text::new(format!("outer ring: {:.1} % per {:.0}° sector", 100.0 * largest, 180.0 / ROSE_SECTORS as f64), (-1.05, -1.07), (FAMILY, 14)))).map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))
}
