//! Contact detection at the start of a step: rigid obstacles against every boundary node, and
//! body pairs through the broad phase (hash grid over facets) and the narrow phase (projection
//! of each slave node on the facets of the master body).

use super::broad;
use super::configuration::{Configuration, Fill};
use super::geometry::{self, frame, norm, sub, Projection, Vec3};
use super::grid::Grid;
use super::obstacle::Touch;
use super::{ContactModel, ContactPoint, Master, Status, Term};
use crate::precision::Real;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::sync::OnceLock;

/// How far beyond a facet's edge (relative) a projection is still accepted, so that a node
/// cannot slip between two neighbouring facets.
const EDGE_TOLERANCE: Real = 0.02;

fn point(slave_body: usize, slave_node: u32, master: Master, frame: [Vec3; 3], gap: Real, friction: Real) -> ContactPoint {
    let mut terms = [Term::default(); 5];
    terms[0] = Term { body: slave_body as u32, node: slave_node, coef: 1.0 };
    ContactPoint {
        slave_body: slave_body as u32,
        slave_node,
        master,
        terms,
        term_count: 1,
        second: false,
        corner: false,
        frame,
        gap,
        friction,
        predicted_gap: gap,
        obstacle_velocity: [[0.0; 3]; 2],
        obstacle_displacement: [0.0; 3],
        shift: 0.0,
        rho: 0.0,
        r: [0.0; 3],
        v: [0.0; 3],
        status: Status::Separated,
        end_gap: gap,
    }
}

/// Largest edge of a facet: a size for search boxes and for the penetration depth accepted.
fn facet_size(x: &[Vec3]) -> Real {
    geometry::edge_range(x).1
}

/// Projection onto a facet (segment, triangle or quadrilateral), its foot at most `tol`
/// (relative) beyond the edges.
fn project(x: Vec3, f: &[Vec3], tol: Real) -> Option<Projection> {
    match f.len() {
        2 => geometry::on_segment(x, f[0], f[1], tol),
        3 => geometry::on_triangle(x, f[0], f[1], f[2], tol),
        _ => geometry::on_quad(x, [f[0], f[1], f[2], f[3]], tol),
    }
}

/// How a master facet a node projects onto stands to the node's own surface.
enum Candidate {
    /// The facet faces the node's surface (their normals are opposed).
    Facing,
    /// It does not, and the node is over the facet itself: a coarse grain's corner, or an edge
    /// sliding along a face, has a normal square to or turned away from the facet it meets.
    /// Taken only when no facet of the master faces the node: where one does (the corner of a
    /// bar pressed on another's end, over the end of its side face with a zero gap), the askew
    /// facet would hold the node in the wrong direction.
    Askew,
    /// It does not, and the node is only over the band beyond its edges (`EDGE_TOLERANCE`):
    /// a corner on the extension of the master's side facets, never a contact.
    Extension,
}

impl Candidate {
    fn of(node_normal: Vec3, p: &Projection, within: impl FnOnce() -> bool) -> Self {
        if geometry::dot(node_normal, p.normal) < 0.0 {
            Self::Facing
        } else if within() {
            Self::Askew
        } else {
            Self::Extension
        }
    }
}

/// All contact points of the configuration (node boxes of every body; positions placed, by
/// `fill`, for the bodies something may touch) at time `t`, for a step of length `dt`. A point
/// is kept when its gap is at most `margin`. `kept` holds the broad phase's body pairs between
/// calls (a default one to start afresh): the points are the same either way.
#[allow(clippy::too_many_arguments)]
pub fn detect(model: &ContactModel, config: &mut Configuration, fill: &Fill<'_>, dim: usize, t: Real, dt: Real, margin: Real, kept: &mut broad::KeptPairs) -> Vec<ContactPoint> {
    Detection::new(model, config, t, dt, margin, kept).points(model, config, fill, dim, margin)
}

/// A detection's broad phase, done: which bodies' nodes its narrow phase places
/// ([`Detection::needed`]), so that a caller whose positions lie elsewhere (on a device) can
/// fetch them before [`Detection::points`].
pub struct Detection {
    walls: ObstacleSearch,
    pairs: PairSearch,
    pub needed: Vec<bool>,
}

impl Detection {
    pub fn new(model: &ContactModel, config: &Configuration, t: Real, dt: Real, margin: Real, kept: &mut broad::KeptPairs) -> Self {
        // The boxes tell, without visiting any node, that most bodies of a packing are far from
        // every wall and every other body: only the others' nodes are placed and searched.
        let walls = ObstacleSearch::new(model, &config.boxes, t, dt, margin);
        let pairs = PairSearch::new(model, &config.boxes, &config.largest, margin, kept);
        let mut needed = vec![false; config.boxes.len()];
        for &(_, b) in &walls.candidates {
            needed[b as usize] = true;
        }
        for (s, masters) in pairs.masters.iter().enumerate() {
            needed[s] |= !masters.is_empty();
            for &m in masters {
                needed[m as usize] = true;
            }
        }
        Self { walls, pairs, needed }
    }

    /// The narrow phase: the needed bodies placed with `fill`, their contact points.
    pub fn points(self, model: &ContactModel, config: &mut Configuration, fill: &Fill<'_>, dim: usize, margin: Real) -> Vec<ContactPoint> {
        let needed = self.needed;
        config.nodes.place(|b| needed[b], fill);
        let mut points = self.walls.points(model, &config.nodes.positions, dim, margin);
        points.extend(self.pairs.points(model, &config.nodes.positions, dim, margin));
        points
    }
}

/// A facet lies flat on a master facet when their normals are this close to opposite (cosine,
/// about 25°).
const FLAT: Real = 0.9;

/// A second-pass point this deep (in the slave's facet sizes) is kept however it lies: the first
/// pass did not hold it.
const KEPT_DEPTH: Real = 0.001;

/// Drops the second-pass points whose slave node lies flat on the master: every facet around
/// the node faces the master's facet (normals nearly opposite), the node is on the master facet
/// of a first-pass point of the same pair, and it has not penetrated. There both passes
/// constrain nearly the same thing, and in a few configurations (a polygon pressed between two
/// disks in `grains_box`) the Uzawa iterations stall on how to split the reactions between
/// them. What stays of the second pass are the nodes the first pass cannot hold: the corners of
/// its master. The solver takes this when a step fails with both passes whole; it lets
/// penetrations of a fraction of an element through for that step (`FLAT`).
pub fn thin_second_pass(model: &ContactModel, positions: &[Vec<Vec3>], points: &mut Vec<ContactPoint>) {
    if !points.iter().any(|c| c.second) {
        return;
    }
    // First-pass points by the (body, node) of their master facets, with their slave body.
    let mut held: HashSet<(u32, u32, u32)> = HashSet::new();
    for c in points.iter().filter(|c| matches!(c.master, Master::Body(_)) && !c.second) {
        for t in &c.terms()[1..] {
            held.insert((t.body, t.node, c.slave_body));
        }
    }
    // Facets around each node, per body that has second-pass points.
    let mut around: HashMap<u32, HashMap<u32, Vec<usize>>> = HashMap::new();
    let lies_flat = |c: &ContactPoint, around: &mut HashMap<u32, HashMap<u32, Vec<usize>>>| {
        let surface = &model.surfaces[c.slave_body as usize];
        let facets = around.entry(c.slave_body).or_insert_with(|| {
            let mut map: HashMap<u32, Vec<usize>> = HashMap::new();
            for f in 0..surface.facet_count() {
                for &n in surface.facet(f) {
                    map.entry(n).or_default().push(f);
                }
            }
            map
        });
        let x = &positions[c.slave_body as usize];
        facets.get(&c.slave_node).is_some_and(|list| {
            let mut h = Real::INFINITY;
            let flat = list.iter().all(|&f| {
                let (p, count) = surface.facet_points(x, f);
                h = h.min(facet_size(&p[..count]));
                geometry::dot(geometry::normalize(facet_normal(&p[..count])), c.frame[0]) < -FLAT
            });
            flat && c.gap > -KEPT_DEPTH * h
        })
    };
    let mut keep = Vec::with_capacity(points.len());
    for c in points.iter() {
        let master = match c.master {
            Master::Body(m) => m,
            Master::Obstacle { .. } => u32::MAX,
        };
        let repeated = c.second && held.contains(&(c.slave_body, c.slave_node, master)) && lies_flat(c, &mut around);
        keep.push(!repeated);
    }
    let mut keep = keep.into_iter();
    points.retain(|_| keep.next().unwrap_or(true));
}

/// The obstacle side of a detection: each obstacle's motion over the step, and the (obstacle,
/// body) pairs whose box comes within the margin of it, obstacle by obstacle.
struct ObstacleSearch {
    /// Offset at `t`, velocity at `t` and `t + dt`, displacement over the step.
    motions: Vec<(Vec3, [Vec3; 2], Vec3)>,
    candidates: Vec<(u32, u32)>,
}

impl ObstacleSearch {
    fn new(model: &ContactModel, boxes: &[broad::Aabb], t: Real, dt: Real, margin: Real) -> Self {
        let bodies = boxes.len();
        // Once per obstacle, not once per body: a motion is a table.
        let motions: Vec<(Vec3, [Vec3; 2], Vec3)> = model
            .obstacles
            .iter()
            .map(|o| {
                let offset = o.motion.displacement(t);
                (offset, [o.motion.velocity(t), o.motion.velocity(t + dt)], sub(o.motion.displacement(t + dt), offset))
            })
            .collect();
        let candidates = (0..model.obstacles.len() * bodies)
            .into_par_iter()
            .filter(|&k| {
                let (o, b) = (k / bodies, k % bodies);
                let obstacle = &model.obstacles[o];
                obstacle.bodies[b] && obstacle.may_touch(boxes[b], motions[o].0, margin)
            })
            .map(|k| ((k / bodies) as u32, (k % bodies) as u32))
            .collect();
        Self { motions, candidates }
    }

    /// The points of the candidates' boundary nodes, the candidates in parallel, in their order.
    fn points(&self, model: &ContactModel, positions: &[Vec<Vec3>], dim: usize, margin: Real) -> Vec<ContactPoint> {
        let found: Vec<Vec<ContactPoint>> = self
            .candidates
            .par_iter()
            .map(|&(o, b)| {
                let (o, b) = (o as usize, b as usize);
                let obstacle = &model.obstacles[o];
                let (offset, velocity, displacement) = self.motions[o];
                let (mut points, mut touches): (Vec<ContactPoint>, Vec<Touch>) = Default::default();
                for &node in &model.surfaces[b].nodes {
                    obstacle.touches(positions[b][node as usize], offset, margin, &mut touches);
                    for touch in &touches {
                        let master = Master::Obstacle { obstacle: o as u32, face: touch.face };
                        let mut p = point(b, node, master, frame(touch.normal, touch.tangent, dim), touch.gap, obstacle.friction);
                        p.obstacle_velocity = velocity;
                        p.obstacle_displacement = displacement;
                        points.push(p);
                    }
                }
                points
            })
            .collect();
        found.into_iter().flatten().collect()
    }
}

/// Masters with more facets than this get a hash grid of them; smaller ones are scanned.
const SCANNED_FACETS: usize = 32;

/// A master body's facets for the node search of a step: their boxes grown by how far off a
/// node can be and still make a point with them, and, on large masters, a grid of those boxes.
struct MasterFacets {
    /// `(min, max, size)` per facet, the box grown.
    boxes: Vec<(Vec3, Vec3, Real)>,
    grid: Option<Grid>,
}

impl MasterFacets {
    fn new(surface: &super::Surface, x: &[Vec3], dim: usize, margin: Real) -> Self {
        let boxes = match surface.facet_nodes {
            2 => facet_boxes::<2>(&surface.facets, x, dim, margin),
            3 => facet_boxes::<3>(&surface.facets, x, dim, margin),
            _ => facet_boxes::<4>(&surface.facets, x, dim, margin),
        };
        let grid = (boxes.len() > SCANNED_FACETS).then(|| {
            let cell = boxes.iter().map(|b| b.2).sum::<Real>() / boxes.len() as Real + 2.0 * margin;
            Grid::new(boxes.iter().enumerate().map(|(f, &(lo, hi, _))| (f as u32, lo, hi)), cell)
        });
        Self { boxes, grid }
    }

    /// `f(facet, size)` for each facet whose grown box holds `x`.
    fn candidates(&self, x: Vec3, mut f: impl FnMut(usize, Real)) {
        let mut visit = |k: usize| {
            let (lo, hi, size) = self.boxes[k];
            if (0..3).all(|i| lo[i] <= x[i] && x[i] <= hi[i]) {
                f(k, size);
            }
        };
        match &self.grid {
            Some(grid) => grid.query(x).iter().for_each(|&k| visit(k as usize)),
            None => (0..self.boxes.len()).for_each(visit),
        }
    }
}

/// `(min, max, size)` of each facet (`N` nodes each, at `x`): its box grown by how far off a node
/// can be and still make a point with it, off its plane by `reach`, beyond its sides by
/// `EDGE_TOLERANCE` (a 2D scene's boxes stay flat in z, so that each takes one layer of grid
/// cells), and its largest edge (or diagonal). Built for thousands of masters a step in a packing.
fn facet_boxes<const N: usize>(facets: &[u32], x: &[Vec3], dim: usize, margin: Real) -> Vec<(Vec3, Vec3, Real)> {
    facets
        .chunks_exact(N)
        .map(|facet| {
            let p: [Vec3; N] = std::array::from_fn(|i| x[facet[i] as usize]);
            let (mut lo, mut hi) = (p[0], p[0]);
            for x in &p[1..] {
                for c in 0..3 {
                    lo[c] = if x[c] < lo[c] { x[c] } else { lo[c] };
                    hi[c] = if x[c] > hi[c] { x[c] } else { hi[c] };
                }
            }
            let size = geometry::longest_squared(&p).sqrt();
            let r = margin.max(0.5 * size) + EDGE_TOLERANCE * size;
            for c in 0..dim {
                (lo[c], hi[c]) = (lo[c] - r, hi[c] + r);
            }
            (lo, hi, size)
        })
        .collect()
}

/// Slave nodes against master facets, searched only inside the body pairs whose boxes come
/// within reach of each other ([`broad::neighbours`]), the slaves in parallel. The result is
/// that of a search of every node against every facet, less the points of nodes outside their
/// master's box: the same points in the same order.
struct PairSearch {
    /// Each body's box grown by how far off it a node can still make a point with it.
    grown_boxes: Vec<broad::Aabb>,
    /// Per slave, the masters its nodes are searched against.
    masters: Vec<Vec<u32>>,
}

impl PairSearch {
    fn new(model: &ContactModel, boxes: &[broad::Aabb], largest: &[Real], margin: Real, kept: &mut broad::KeptPairs) -> Self {
        if !model.pairs.any() {
            return Self { grown_boxes: Vec::new(), masters: vec![Vec::new(); boxes.len()] };
        }
        // A point's foot is on its facet or at most `EDGE_TOLERANCE` of an edge beyond its
        // sides, and its node either in front of the facet by at most the margin or behind it,
        // inside the master and so inside its box: a body's box grown by the margin and that
        // band of its largest facet holds every node that can make a point with it, so that two
        // bodies whose grown boxes do not meet are not searched. (A node behind a facet but
        // outside the master's box has gone past a thin corner of the master: it is not in it.)
        // Growing by half a facet, the depth a point may have, as this did before, placed most
        // grains of a loose packing for nothing: each placement read a grain's displacements
        // back from a device every step.
        let grown_boxes: Vec<broad::Aabb> = boxes.iter().zip(largest).map(|(&b, &size)| broad::grown(b, margin + EDGE_TOLERANCE * size)).collect();
        // Bodies move a fraction of a facet per step: a skin of half the largest facet keeps
        // the pairs for several steps of the fastest body without many more pairs to test.
        let skin = 0.5 * largest.iter().copied().fold(0.0, Real::max);
        let near = kept.near(&grown_boxes, skin, |a, b| model.pairs.mu(a, b).is_some());
        // The masters each slave's nodes are searched against: those whose grown box takes some
        // of the slave's nodes, which needs the slave's box to meet it (and then the grown boxes
        // meet, which is what the kept pairs hold).
        let masters = near.par_iter().enumerate().map(|(s, list)| list.iter().copied().filter(|&m| model.pairs.friction(s, m as usize).is_some() && broad::intersect(boxes[s], grown_boxes[m as usize])).collect()).collect();
        Self { grown_boxes, masters }
    }

    fn points(&self, model: &ContactModel, positions: &[Vec<Vec3>], dim: usize, margin: Real) -> Vec<ContactPoint> {
        let (surfaces, masters, grown_boxes) = (&model.surfaces, &self.masters, &self.grown_boxes);
        // A master's facets, made when a slave node first comes within its grown box (in a
        // loose packing most neighbours' boxes meet without a node in reach).
        let facets: Vec<OnceLock<MasterFacets>> = (0..surfaces.len()).map(|_| OnceLock::new()).collect();
        let found: Vec<Vec<ContactPoint>> = (0..surfaces.len())
            .into_par_iter()
            .map(|s| {
                let mut points = Vec::new();
                if masters[s].is_empty() {
                    return points;
                }
                // The slave's node normals, when a node first projects on a master facet.
                let mut normals: Option<Vec<Vec3>> = None;
                // Best facet per master body for the current node, among this slave's masters: one
                // that faces the node's own surface, else one that does not (`Candidate`).
                let mut best: Vec<[Option<Found>; 2]> = vec![[None, None]; masters[s].len()];
                // Every facing facet of the current node, by master (in 3D also every askew one
                // it lies over): a second one holds it in a concave corner (2D) or edge (3D) of
                // the master ([`concave`]). In 3D the facet across a dent's edge can be askew to a
                // node pressed along the other one: unheld, the node slid over the edge and into
                // it (`grains_3d` at ten times the wall speed, with `nearer_askew`).
                let mut facing: Vec<(usize, usize, Projection)> = Vec::new();
                let mut xs: Vec<Vec3> = Vec::with_capacity(4);
                for &node in &surfaces[s].nodes {
                    let x = positions[s][node as usize];
                    for (k, &m) in masters[s].iter().enumerate() {
                        let m = m as usize;
                        if !broad::intersect((x, x), grown_boxes[m]) {
                            continue;
                        }
                        facets[m].get_or_init(|| MasterFacets::new(&surfaces[m], &positions[m], dim, margin)).candidates(x, |f, size| {
                            let facet = surfaces[m].facet(f);
                            xs.clear();
                            xs.extend(facet.iter().map(|&n| positions[m][n as usize]));
                            let Some(p) = project(x, &xs, EDGE_TOLERANCE) else { return };
                            // Penetrations deeper than half a facet are the far side of the master body.
                            if p.gap > margin || p.gap < -0.5 * size {
                                return;
                            }
                            let normal = normals.get_or_insert_with(|| node_normals(&surfaces[s], &positions[s]))[node as usize];
                            let tier = match Candidate::of(normal, &p, || project(x, &xs, 0.0).is_some()) {
                                Candidate::Facing => {
                                    facing.push((k, f, p));
                                    0
                                }
                                Candidate::Askew => {
                                    if dim == 3 {
                                        facing.push((k, f, p));
                                    }
                                    1
                                }
                                Candidate::Extension => return,
                            };
                            let slot = &mut best[k][tier];
                            if slot.as_ref().is_none_or(|found| p.gap.abs() < found.p.gap.abs()) {
                                *slot = Some(Found { f, p, size });
                            }
                        });
                    }
                    for (k, &m) in masters[s].iter().enumerate() {
                        let m = m as usize;
                        let [first, askew] = std::mem::take(&mut best[k]);
                        let first = first.filter(|a| dim == 2 || askew.as_ref().is_none_or(|b| !nearer_askew(a, b, &surfaces[m], &positions[m])));
                        let held_facing = first.is_some();
                        let Some(Found { f, p, .. }) = first.or(askew) else { continue };
                        let mu = model.pairs.friction(s, m).expect("pair checked");
                        let second = model.pairs.second(s, m);
                        points.push(body_point(s, node, m, surfaces[m].facet(f), &p, dim, mu, second));
                        if !held_facing {
                            continue;
                        }
                        let corner = facing.iter().filter(|(kk, g, _)| *kk == k && *g != f && concave(surfaces[m].facet(f), surfaces[m].facet(*g), &p.normal, &positions[m])).min_by(|a, b| a.2.gap.abs().total_cmp(&b.2.gap.abs()));
                        if let Some(&(_, g, q)) = corner {
                            let mut c = body_point(s, node, m, surfaces[m].facet(g), &q, dim, mu, second);
                            c.corner = true;
                            points.push(c);
                        }
                    }
                    facing.clear();
                }
                points
            })
            .collect();
        found.into_iter().flatten().collect()
    }
}

/// A master facet a node projects onto, and its size.
#[derive(Clone, Copy)]
struct Found {
    f: usize,
    p: Projection,
    size: Real,
}

/// How much nearer (relative to its size) the plane of an askew facet a node lies over must
/// be than that of the nearest facing facet for the askew one to hold the node: well beyond
/// round-off and the sweeps' tolerance, so that the corner of a bar pressed flush on another's
/// end (on the plane of the end's side facet) stays held by the end. At 1e-3 the 3D packing
/// below took five times as long (doc/benchmarks.md).
const NEARER_ASKEW: Real = 1e-2;

/// Whether the askew facet `askew` a node lies over is nearer the node than the facing facet
/// `facing`, by [`NEARER_ASKEW`], where the two do not meet concavely: the 3D choice of the
/// facet that holds a node (in 2D the facing one holds it). Near a grain's convex edge or
/// vertex the facing facet's plane no longer bounds the master: a node inside a box's corner,
/// held by the facing facet whose plane it was 1.3e-2 behind, went in through the askew one,
/// 2.4e-3 away, unheld (`grains_3d`, 64 grains at ten times the wall speed: a sub-step kept at
/// the smallest step with a node 1.29 % of an element deep).
fn nearer_askew(facing: &Found, askew: &Found, surface: &super::Surface, x: &[Vec3]) -> bool {
    askew.p.gap.abs() + NEARER_ASKEW * askew.size < facing.p.gap.abs() && !concave(surface.facet(facing.f), surface.facet(askew.f), &facing.p.normal, x)
}

/// The point of slave node `node` of body `s` on the facet `facet` of body `m`, projected as `p`.
#[allow(clippy::too_many_arguments)]
fn body_point(s: usize, node: u32, m: usize, facet: &[u32], p: &Projection, dim: usize, mu: Real, second: bool) -> ContactPoint {
    let mut c = point(s, node, Master::Body(m as u32), frame(p.normal, Some(p.tangent), dim), p.gap, mu);
    for (k, &n) in facet.iter().enumerate() {
        c.terms[1 + k] = Term { body: m as u32, node: n, coef: -p.weights[k] };
    }
    c.term_count = 1 + facet.len();
    c.second = second;
    c
}

/// A corner is concave when it turns by more than this (sine of the angle, about 11.5°). Below
/// it the two segments are nearly one line: a node held by one sinks little through the other,
/// and a second, nearly parallel point only slows the Uzawa sweeps; the corners that let nodes
/// through turned by 20° and more (doc/benchmarks.md, "Contact below the elements").
const CONCAVE: Real = 0.2;

/// Whether facets `a` (outward unit normal `normal`) and `b` of one body meet concavely: they
/// share a node, and the nodes of `b` off `a` lie outside `a`'s plane (2D: line); in 3D also
/// those of `a` off `b` outside `b`'s plane. There the outside of the body is the intersection
/// of the two facets' outsides, and a node in the corner must be held by both: held by the
/// nearer alone, it sank through the other (2D: grains pressed into the dented side of a
/// neighbour, 2.9 % of an element at any step). In 3D the test in both directions takes the
/// concave edges and the facets that meet at a single node with each beyond the other (the
/// inside of a dent's corner), not a saddle, where one facet's nodes lie on both sides of the
/// other's plane and a node held on one stays out of the other.
fn concave(a: &[u32], b: &[u32], normal: &Vec3, x: &[Vec3]) -> bool {
    let Some(&shared) = b.iter().find(|n| a.contains(n)) else { return false };
    let o = x[shared as usize];
    let beyond = |facet: &[u32], plane: &[u32], normal: Vec3| {
        facet.iter().filter(|n| !plane.contains(n)).all(|&n| {
            let d = sub(x[n as usize], o);
            geometry::dot(d, normal) > CONCAVE * norm(d)
        })
    };
    if a.len() == 2 {
        return beyond(b, a, *normal);
    }
    let mut points = [[0.0; 3]; 4];
    for (p, &n) in points.iter_mut().zip(b) {
        *p = x[n as usize];
    }
    beyond(b, a, *normal) && beyond(a, b, geometry::normalize(facet_normal(&points[..b.len()])))
}

/// Outward normal of a facet, scaled by its area (length in 2D).
pub fn facet_normal(p: &[Vec3]) -> Vec3 {
    match p.len() {
        2 => {
            let d = sub(p[1], p[0]);
            [d[1], -d[0], 0.0]
        }
        3 => geometry::scale(geometry::cross(sub(p[1], p[0]), sub(p[2], p[0])), 0.5),
        _ => geometry::scale(geometry::cross(sub(p[2], p[0]), sub(p[3], p[1])), 0.5),
    }
}

/// Outward normal at each boundary node: the normalised sum of its facets' area-weighted
/// normals (zero for nodes off the boundary).
fn node_normals(surface: &super::Surface, x: &[Vec3]) -> Vec<Vec3> {
    let mut normals = vec![[0.0; 3]; x.len()];
    for f in 0..surface.facet_count() {
        let (p, len) = surface.facet_points(x, f);
        let n = facet_normal(&p[..len]);
        for &k in surface.facet(f) {
            normals[k as usize] = geometry::add(normals[k as usize], n);
        }
    }
    normals.into_iter().map(|n| if norm(n) > 0.0 { geometry::normalize(n) } else { n }).collect()
}
