//! Von Mises contours of a 2D state as a PNG: every element filled by its stress on the viridis
//! map of the 3D view, the bodies' outlines and the rigid obstacles in grey, and a colour bar.

use super::{register_font, PlotError, FAMILY};
use crate::contact::obstacle::{Obstacle, Shape};
use crate::element::CellFields;
use crate::output::foxglove::colormap;
use crate::precision::Real;
use crate::solver::Simulation;
use plotters::prelude::*;
use std::path::Path;

const OUTLINE: RGBColor = RGBColor(40, 40, 40);
const OBSTACLE: RGBColor = RGBColor(120, 120, 120);

fn viridis(s: Real) -> RGBColor {
    let [r, g, b, _] = colormap(s);
    RGBColor((r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8)
}

/// The obstacle's lines at time `t`, planes drawn across the view `[lo, hi]`.
fn obstacle_lines(o: &Obstacle, t: Real, lo: [Real; 2], hi: [Real; 2]) -> Vec<Vec<(f64, f64)>> {
    let d = o.motion.displacement(t);
    let at = |p: &[Real; 3]| (p[0] + d[0], p[1] + d[1]);
    match &o.shape {
        Shape::Plane { point, normal } => {
            let (p, tangent) = (at(point), (-normal[1], normal[0]));
            // Long enough to cross the view from any point in it; clipped below.
            let reach = 2.0 * (hi[0] - lo[0]).hypot(hi[1] - lo[1]) + (p.0 - lo[0]).abs().max((p.1 - lo[1]).abs());
            vec![vec![(p.0 - reach * tangent.0, p.1 - reach * tangent.1), (p.0 + reach * tangent.0, p.1 + reach * tangent.1)]]
        }
        Shape::Box { min, max } => {
            let (a, b) = (at(min), at(max));
            vec![vec![a, (b.0, a.1), b, (a.0, b.1), a]]
        }
        Shape::Polygon(points) => {
            let mut line: Vec<(f64, f64)> = points.iter().map(at).collect();
            line.push(line[0]);
            vec![line]
        }
        Shape::Polyline(points) => vec![points.iter().map(at).collect()],
    }
}

/// The part of the segment `a`-`b` inside the rectangle `[lo, hi]` (Liang-Barsky), if any:
/// plotters would draw what lies outside the view along its border.
fn clip(a: (f64, f64), b: (f64, f64), lo: [Real; 2], hi: [Real; 2]) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a.0 - lo[0]), (dx, hi[0] - a.0), (-dy, a.1 - lo[1]), (dy, hi[1] - a.1)] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    (t0 < t1).then_some(((a.0 + t0 * dx, a.1 + t0 * dy), (a.0 + t1 * dx, a.1 + t1 * dy)))
}

/// Writes the contours of the current state of a 2D simulation to `path`; `fields` are the
/// bodies' element fields ([`crate::solver::Body::cell_fields`]).
pub fn contour_png(sim: &Simulation, fields: &[Vec<CellFields>], title: &str, path: &Path) -> Result<(), PlotError> {
    let draw_err = |e: &dyn std::fmt::Display| PlotError::Draw { path: path.into(), message: e.to_string() };
    if sim.dim() != 2 {
        return Err(PlotError::Draw { path: path.into(), message: "contour plots are drawn for 2D scenes; open the VTU files in ParaView for 3D".into() });
    }
    register_font();
    let (mut lo, mut hi) = ([Real::INFINITY; 2], [Real::NEG_INFINITY; 2]);
    for b in sim.bodies() {
        for n in 0..b.mesh().nodes.len() {
            let x = b.position(n);
            for i in 0..2 {
                lo[i] = lo[i].min(x[i]);
                hi[i] = hi[i].max(x[i]);
            }
        }
    }
    let pad = 0.04 * (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let (lo, hi) = (lo.map(|v| v - pad), hi.map(|v| v + pad));
    let vm_max = fields.iter().flatten().map(|f| f.von_mises).fold(0.0, Real::max).max(Real::MIN_POSITIVE);

    let plot_width = 1100u32;
    let plot_height = ((plot_width as Real - 120.0) * (hi[1] - lo[1]) / (hi[0] - lo[0]) + 110.0).clamp(300.0, 1400.0) as u32;
    let root = BitMapBackend::new(path, (plot_width + 170, plot_height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| draw_err(&e))?;
    let (left, right) = root.split_horizontally(plot_width);
    let mut chart = ChartBuilder::on(&left).caption(title, (FAMILY, 22)).margin(14).x_label_area_size(46).y_label_area_size(70).build_cartesian_2d(lo[0]..hi[0], lo[1]..hi[1]).map_err(|e| draw_err(&e))?;
    chart.configure_mesh().disable_mesh().x_desc("x").y_desc("y").label_style((FAMILY, 13)).draw().map_err(|e| draw_err(&e))?;
    for (b, body_fields) in sim.bodies().iter().zip(fields) {
        let polygons = (0..b.mesh().element_count()).map(|e| {
            let corners: Vec<(f64, f64)> = b.mesh().element(e).iter().map(|&n| b.position(n as usize)).map(|x| (x[0], x[1])).collect();
            Polygon::new(corners, viridis(body_fields[e].von_mises / vm_max).filled())
        });
        chart.draw_series(polygons).map_err(|e| draw_err(&e))?;
    }
    if let Some(contact) = &sim.contact() {
        for (surface, b) in contact.surfaces.iter().zip(sim.bodies()) {
            let segments = (0..surface.facet_count()).map(|f| PathElement::new(surface.facet(f).iter().map(|&n| b.position(n as usize)).map(|x| (x[0], x[1])).collect::<Vec<_>>(), OUTLINE));
            chart.draw_series(segments).map_err(|e| draw_err(&e))?;
        }
        for o in &contact.obstacles {
            for line in obstacle_lines(o, sim.t(), lo, hi) {
                let visible = line.windows(2).filter_map(|w| clip(w[0], w[1], lo, hi));
                chart.draw_series(visible.map(|(a, b)| PathElement::new(vec![a, b], OBSTACLE.stroke_width(3)))).map_err(|e| draw_err(&e))?;
            }
        }
    }

    // The colour bar: 0 at the bottom, the largest element stress at the top.
    let mut bar = ChartBuilder::on(&right).margin_top(60).margin_bottom(60).margin_right(10).y_label_area_size(90).caption("von Mises", (FAMILY, 16)).build_cartesian_2d(0.0..1.0, 0.0..vm_max).map_err(|e| draw_err(&e))?;
    bar.configure_mesh().disable_mesh().disable_x_axis().label_style((FAMILY, 13)).y_label_formatter(&|v| format!("{v:.3e}")).draw().map_err(|e| draw_err(&e))?;
    let steps = 200;
    bar.draw_series((0..steps).map(|k| {
        let (a, b) = (k as Real / steps as Real, (k + 1) as Real / steps as Real);
        Rectangle::new([(0.0, a * vm_max), (1.0, b * vm_max)], viridis(a).filled())
    }))
    .map_err(|e| draw_err(&e))?;
    root.present().map_err(|e| draw_err(&e))
}

#[cfg(test)]
mod tests {
    use super::clip;

    #[test]
    fn obstacle_lines_are_clipped_to_the_view() {
        let (lo, hi) = ([0.0, 0.0], [1.0, 1.0]);
        assert_eq!(clip((-1.0, 0.5), (2.0, 0.5), lo, hi), Some(((0.0, 0.5), (1.0, 0.5))));
        assert_eq!(clip((5.0, -1.0), (5.0, 2.0), lo, hi), None, "a wall right of the view is not drawn on its border");
        assert_eq!(clip((0.2, 0.2), (0.4, 0.6), lo, hi), Some(((0.2, 0.2), (0.4, 0.6))));
    }
}
