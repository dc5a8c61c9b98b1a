//! Interpenetration of the configuration itself: boundary nodes of a body inside an element of
//! another body, or behind an obstacle. Unlike the contact points' linearised gaps, this sees
//! every node, also those no contact point holds (a master's corner pressed into a slave's face,
//! an overlap deeper than the contact search): it refuses overlapping bodies at t = 0 and
//! measures the penetration after every step.

use super::broad::{self, intersect, Aabb};
use super::configuration::{Configuration, Fill};
use super::geometry::{add, bounds, cross, dot, edge_range, norm, scale, sub, Vec3};
use super::grid::Grid;
use super::obstacle::Touch;
use super::ContactModel;
use crate::mesh::{ElementKind, Mesh};
use crate::precision::Real;
use rayon::prelude::*;

/// What a node is inside of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Host {
    /// An element of another body.
    Body(u32),
    /// An obstacle.
    Obstacle(u32),
}

/// A boundary node inside another body or an obstacle.
#[derive(Debug, Clone, Copy)]
pub struct Overlap {
    pub body: u32,
    pub node: u32,
    pub host: Host,
    /// Distance from the node to the host's surface.
    pub depth: Real,
    /// The node's way out: the unit vector from the node to the nearest point of that surface.
    pub out: Vec3,
    /// The local element size: the shortest edge of the node's boundary facets and, in a body,
    /// of the element that holds it.
    pub size: Real,
}

impl Overlap {
    /// `depth / size`: the penetration in elements.
    pub fn ratio(&self) -> Real {
        self.depth / self.size
    }
}

/// The deepest penetration by ratio and by depth.
#[derive(Debug, Clone, Copy, Default)]
pub struct Worst {
    pub depth: Real,
    pub ratio: Real,
}

impl Worst {
    pub fn of(overlaps: &[Overlap]) -> Self {
        overlaps.iter().fold(Self::default(), |w, o| Self { depth: w.depth.max(o.depth), ratio: w.ratio.max(o.ratio()) })
    }
}

/// Every boundary node of every body that is inside an element of a body it can contact, or
/// behind an obstacle that touches it (obstacles displaced to time `t`), deeper than `1e-9` of
/// its element size. `meshes[b]` gives the connectivity, `config` the current boxes and, placed
/// by `fill` where a body's box meets another's or an obstacle, its nodes; `kept` holds the body
/// pairs whose boxes meet between calls (a default one to start afresh).
pub fn overlaps(model: &ContactModel, meshes: &[&Mesh], config: &mut Configuration, fill: &Fill<'_>, t: Real, kept: &mut broad::KeptPairs) -> Vec<Overlap> {
    OverlapSearch::new(model, config, t, kept).overlaps(model, meshes, config, fill)
}

/// An overlap search's broad phase, done: which bodies' nodes it places ([`OverlapSearch::needed`]),
/// so that a caller whose positions lie elsewhere (on a device) can fetch them first.
pub struct OverlapSearch<'k> {
    neighbours: &'k [Vec<u32>],
    meets_another: Vec<bool>,
    near_an_obstacle: Vec<bool>,
    offsets: Vec<Vec3>,
    pub needed: Vec<bool>,
}

impl<'k> OverlapSearch<'k> {
    pub fn new(model: &ContactModel, config: &Configuration, t: Real, kept: &'k mut broad::KeptPairs) -> Self {
        let bodies = config.boxes.len();
        let can_touch = |a: usize, b: usize| model.pairs.mu(a, b).is_some();
        // Only a node inside another body's box can be inside that body, and only elements in the
        // box of a body that can touch theirs can hold such a node: in a packing that leaves the
        // rims of the grains (the search cost a quarter of a step with every element).
        let body_boxes = &config.boxes;
        // A skin of a quarter of the smallest body keeps the pairs while the bodies move less.
        let skin = 0.25 * body_boxes.iter().map(|(lo, hi)| (0..3).map(|i| hi[i] - lo[i]).fold(0.0, Real::max)).fold(Real::INFINITY, Real::min);
        // A superset of the pairs whose boxes meet: every test below is against the boxes themselves.
        let neighbours = kept.near(body_boxes, if skin.is_finite() { skin } else { 0.0 }, can_touch);
        // Whether a body's box meets another's: only then can it hold or put a node in another body.
        let meets_another: Vec<bool> = neighbours.par_iter().enumerate().map(|(b, list)| list.iter().any(|&o| intersect(body_boxes[b], body_boxes[o as usize]))).collect();
        let offsets: Vec<Vec3> = model.obstacles.iter().map(|o| o.motion.displacement(t)).collect();
        // The obstacles each body's box reaches (few: the walls next to it).
        let near_an_obstacle: Vec<bool> = (0..bodies).into_par_iter().map(|s| model.obstacles.iter().enumerate().any(|(o, obstacle)| obstacle.bodies[s] && obstacle.may_touch(body_boxes[s], offsets[o], 0.0))).collect();
        let needed = meets_another.iter().zip(&near_an_obstacle).map(|(&a, &b)| a || b).collect();
        Self { neighbours, meets_another, near_an_obstacle, offsets, needed }
    }

    /// The search: the needed bodies placed with `fill`, their overlaps.
    pub fn overlaps(self, model: &ContactModel, meshes: &[&Mesh], config: &mut Configuration, fill: &Fill<'_>) -> Vec<Overlap> {
        let Self { neighbours, meets_another, near_an_obstacle, offsets, needed } = self;
        let bodies = meshes.len();
        let can_touch = |a: usize, b: usize| model.pairs.mu(a, b).is_some();
        config.nodes.place(|b| needed[b], fill);
        let body_boxes = &config.boxes;
        let offsets = &offsets[..];
        let near_obstacles = |s: usize| model.obstacles.iter().enumerate().filter(move |(o, obstacle)| obstacle.bodies[s] && obstacle.may_touch(body_boxes[s], offsets[*o], 0.0));
        let positions = &config.nodes.positions;
        // The elements in reach of another body, the bodies in parallel, in body order.
        let neighbours = &neighbours;
        let (ids, boxes): (Vec<(u32, u32)>, Vec<Aabb>) = meshes
            .par_iter()
            .enumerate()
            .filter(|(m, _)| meets_another[*m])
            .flat_map_iter(|(m, mesh)| {
                (0..mesh.element_count()).filter_map(move |e| {
                    let (lo, hi) = bounds(mesh.element(e).iter().map(|&n| positions[m][n as usize]));
                    neighbours[m].iter().any(|&s| intersect((lo, hi), body_boxes[s as usize])).then_some(((m as u32, e as u32), (lo, hi)))
                })
            })
            .unzip();
        let grid = (!ids.is_empty()).then(|| {
            let cell = boxes.iter().map(|(lo, hi)| (0..3).map(|i| hi[i] - lo[i]).fold(0.0, Real::max)).sum::<Real>() / boxes.len() as Real;
            Grid::new(boxes.iter().enumerate().map(|(i, &(lo, hi))| (i as u32, lo, hi)), cell.max(Real::MIN_POSITIVE))
        });
        let dim = meshes.first().map_or(2, |m| m.dim());
        (0..bodies)
            .into_par_iter()
            .flat_map_iter(|s| {
                let surface = &model.surfaces[s];
                // Computed for the bodies that have a node to measure (few, in a packing).
                let mut sizes: Option<Vec<Real>> = None;
                let mut found = Vec::new();
                let mut touches: Vec<Touch> = Vec::new();
                if !near_an_obstacle[s] && !meets_another[s] {
                    return found;
                }
                let near: Vec<(usize, &super::Obstacle)> = near_obstacles(s).collect();
                for &node in &surface.nodes {
                    let x = positions[s][node as usize];
                    let mut own = || sizes.get_or_insert_with(|| node_sizes(surface, &positions[s]))[node as usize];
                    for &(o, obstacle) in &near {
                        obstacle.touches(x, offsets[o], 0.0, &mut touches);
                        if let Some(deepest) = touches.iter().min_by(|a, b| a.gap.total_cmp(&b.gap)) {
                            let (depth, size) = (-deepest.gap, own());
                            if depth > 1e-9 * size {
                                found.push(Overlap { body: s as u32, node, host: Host::Obstacle(o as u32), depth, out: deepest.normal, size });
                            }
                        }
                    }
                    let Some(grid) = &grid else { continue };
                    if !neighbours[s].iter().any(|&m| intersect((x, x), body_boxes[m as usize])) {
                        continue;
                    }
                    let mut best: Option<Overlap> = None;
                    for &id in grid.query(x) {
                        let (m, e) = ids[id as usize];
                        let (lo, hi) = boxes[id as usize];
                        if !can_touch(s, m as usize) || (0..dim).any(|i| x[i] < lo[i] || x[i] > hi[i]) {
                            continue;
                        }
                        if best.is_some_and(|b| b.host == Host::Body(m)) {
                            continue;
                        }
                        let mesh = meshes[m as usize];
                        let element: Vec<Vec3> = mesh.element(e as usize).iter().map(|&n| positions[m as usize][n as usize]).collect();
                        if !inside(mesh.kind, &element, x) {
                            continue;
                        }
                        let (depth, out) = to_surface(&model.surfaces[m as usize], &positions[m as usize], x);
                        let size = own().min(edge_range(&element).0);
                        if depth > 1e-9 * size && best.is_none_or(|b| depth / size > b.ratio()) {
                            best = Some(Overlap { body: s as u32, node, host: Host::Body(m), depth, out, size });
                        }
                    }
                    found.extend(best);
                }
                found
            })
            .collect()
    }
}

/// Per node, the shortest edge of the boundary facets around it (infinite off the boundary).
fn node_sizes(surface: &super::Surface, x: &[Vec3]) -> Vec<Real> {
    let mut sizes = vec![Real::INFINITY; x.len()];
    for f in 0..surface.facet_count() {
        let (p, len) = surface.facet_points(x, f);
        let h = edge_range(&p[..len]).0;
        for &n in surface.facet(f) {
            sizes[n as usize] = sizes[n as usize].min(h);
        }
    }
    sizes
}

/// Whether `x` is inside the element with nodes `p` or on its boundary (up to round-off; a node
/// on the surface has no depth and is not counted): triangles and tetrahedra by barycentric
/// coordinates, quadrilaterals and hexahedra split into those.
fn inside(kind: ElementKind, p: &[Vec3], x: Vec3) -> bool {
    match kind {
        ElementKind::Tri3 => in_triangle(p[0], p[1], p[2], x),
        ElementKind::Quad4 => in_triangle(p[0], p[1], p[2], x) || in_triangle(p[0], p[2], p[3], x),
        ElementKind::Tet4 => in_tetrahedron([p[0], p[1], p[2], p[3]], x),
        // Six tetrahedra about the diagonal 0-6.
        ElementKind::Hex8 => [[1, 2], [2, 3], [3, 7], [7, 4], [4, 5], [5, 1]].iter().any(|&[a, b]| in_tetrahedron([p[0], p[a], p[b], p[6]], x)),
    }
}

/// Barycentric coordinates this far below zero still count as on the element.
const ROUND_OFF: Real = 1e-12;

fn in_triangle(a: Vec3, b: Vec3, c: Vec3, x: Vec3) -> bool {
    let area = |p: Vec3, q: Vec3, r: Vec3| (q[0] - p[0]) * (r[1] - p[1]) - (r[0] - p[0]) * (q[1] - p[1]);
    let total = area(a, b, c);
    let w = [area(x, b, c), area(a, x, c), area(a, b, x)].map(|w| w / total);
    w.iter().all(|&w| w >= -ROUND_OFF)
}

fn in_tetrahedron(p: [Vec3; 4], x: Vec3) -> bool {
    let volume = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| dot(sub(b, a), cross(sub(c, a), sub(d, a)));
    let total = volume(p[0], p[1], p[2], p[3]);
    let w = [volume(x, p[1], p[2], p[3]), volume(p[0], x, p[2], p[3]), volume(p[0], p[1], x, p[3]), volume(p[0], p[1], p[2], x)].map(|w| w / total);
    w.iter().all(|&w| w >= -ROUND_OFF)
}

/// Distance from `x` to the nearest point of a body's boundary, and the unit vector towards it.
fn to_surface(surface: &super::Surface, positions: &[Vec3], x: Vec3) -> (Real, Vec3) {
    let mut best = (Real::INFINITY, [0.0; 3]);
    for f in 0..surface.facet_count() {
        let (p, count) = surface.facet_points(positions, f);
        let closest = match count {
            2 => on_segment(x, p[0], p[1]),
            3 => on_triangle(x, p[0], p[1], p[2]),
            _ => {
                let (a, b) = (on_triangle(x, p[0], p[1], p[2]), on_triangle(x, p[0], p[2], p[3]));
                if norm(sub(a, x)) <= norm(sub(b, x)) {
                    a
                } else {
                    b
                }
            }
        };
        let d = norm(sub(closest, x));
        if d < best.0 {
            best = (d, if d > 0.0 { scale(sub(closest, x), 1.0 / d) } else { [0.0; 3] });
        }
    }
    best
}

fn on_segment(x: Vec3, a: Vec3, b: Vec3) -> Vec3 {
    let d = sub(b, a);
    let s = (dot(sub(x, a), d) / dot(d, d)).clamp(0.0, 1.0);
    add(a, scale(d, s))
}

/// The closest point of triangle `abc` to `x` (Ericson, Real-Time Collision Detection, 5.1.5).
fn on_triangle(x: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(x, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(x, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return add(a, scale(ab, d1 / (d1 - d3)));
    }
    let cp = sub(x, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return add(a, scale(ac, d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return add(b, scale(sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let denom = 1.0 / (va + vb + vc);
    add(a, add(scale(ab, vb * denom), scale(ac, vc * denom)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_points_on_a_triangle_cover_its_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let close = |p: Vec3, q: Vec3| assert!(norm(sub(p, q)) < 1e-14, "{p:?} vs {q:?}");
        close(on_triangle([0.2, 0.2, 1.0], a, b, c), [0.2, 0.2, 0.0]);
        close(on_triangle([-1.0, -1.0, 0.0], a, b, c), a);
        close(on_triangle([0.5, -1.0, 0.0], a, b, c), [0.5, 0.0, 0.0]);
        close(on_triangle([1.0, 1.0, 0.0], a, b, c), [0.5, 0.5, 0.0]);
        close(on_triangle([2.0, -0.5, 0.0], a, b, c), b);
    }

    #[test]
    fn a_point_is_inside_every_kind_of_element_that_holds_it() {
        let square = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        assert!(inside(ElementKind::Quad4, &square, [0.9, 0.8, 0.0]) && !inside(ElementKind::Quad4, &square, [1.1, 0.5, 0.0]));
        assert!(inside(ElementKind::Tri3, &square[..3], [0.9, 0.1, 0.0]) && !inside(ElementKind::Tri3, &square[..3], [0.1, 0.9, 0.0]));
        let mut cube: Vec<Vec3> = square.to_vec();
        cube.extend(square.iter().map(|p| [p[0], p[1], 1.0]));
        for x in [[0.1, 0.2, 0.9], [0.9, 0.9, 0.1], [0.5, 0.5, 0.5], [0.05, 0.9, 0.5]] {
            assert!(inside(ElementKind::Hex8, &cube, x), "{x:?}");
        }
        assert!(!inside(ElementKind::Hex8, &cube, [0.5, 0.5, 1.01]));
        let tet = [cube[0], cube[1], cube[3], cube[4]];
        assert!(inside(ElementKind::Tet4, &tet, [0.1, 0.1, 0.1]) && !inside(ElementKind::Tet4, &tet, [0.5, 0.5, 0.5]));
    }
}
