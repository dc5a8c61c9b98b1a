//! `[packing]`: a random packing of grains in a rigid box, expanded into ordinary bodies and
//! obstacles before validation.
//!
//! The grains sit one per cell of a lattice (cell size: the largest diameter plus the gap), each
//! with a random radius, shape, orientation and offset inside its cell, so that no two overlap
//! and none touches a wall. The walls are the planes around the lattice.
//!
//! Polygons are meshed finer than the finest disk: single-pass contact makes the finer mesh the
//! slave, and a polygon's corners must be slave nodes, or they would sink into the disks.

use super::error::SceneErrorKind::{Invalid, Reference};
use super::types::{BodySpec, Generator, MeshSpec, ObstacleShape, ObstacleSpec, PackingSpec, Scene};
use super::validate::{friction, names, Failure};
use crate::mesh::{generate, ElementKind};
use crate::precision::Real;
use std::f64::consts::TAU;

/// SplitMix64: a fixed algorithm, so that a seed gives the same packing whatever the versions
/// of the crates this one is built with.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> Real {
        (self.next() >> 11) as Real / (1u64 << 53) as Real
    }

    fn between(&mut self, lo: Real, hi: Real) -> Real {
        lo + (hi - lo) * self.unit()
    }
}

fn check(p: &PackingSpec, s: &Scene) -> Result<(), Failure> {
    let bad = |field: &str, message: String| Err((Invalid, format!("packing.{field}"), message));
    if p.count == 0 {
        return bad("count", "at least one grain is needed.".into());
    }
    if !s.material.contains_key(&p.material) {
        return Err((Reference, "packing.material".into(), format!("unknown material `{}` (the scene defines: {}).", p.material, names(s.material.keys()))));
    }
    match p.radius[..] {
        [lo, hi] if lo > 0.0 && lo <= hi && hi.is_finite() => {}
        _ => return bad("radius", format!("expected [min, max] with 0 < min <= max (got {:?}).", p.radius)),
    }
    if !(0.0..=1.0).contains(&p.polygons) {
        return bad("polygons", format!("the share of polygons must lie in [0, 1] (got {}).", p.polygons));
    }
    if p.divisions == 0 {
        return bad("divisions", "at least one cell per radius is needed.".into());
    }
    // A disk of n divisions has 8 n² triangles; checked here, before any grain is meshed (a
    // huge `divisions` overflowed the mesh generator).
    let n = p.divisions as u128;
    let elements = (p.count as u128).saturating_mul(n.saturating_mul(n).saturating_mul(8));
    if elements > s.limits.max_elements as u128 {
        let field = if p.count as u128 > s.limits.max_elements as u128 / 8 { "count" } else { "divisions" };
        let message = format!("{} grains of {} divisions make {elements} elements or more, more than limits.max_elements = {}; raise the limit (`--set limits.max_elements=N`) if you mean it.", p.count, p.divisions, s.limits.max_elements);
        return bad(field, message);
    }
    if !(p.gap >= 0.0 && p.gap.is_finite()) {
        return bad("gap", format!("the gap must be zero or positive (got {}).", p.gap));
    }
    if !p.wall_velocity.is_finite() {
        return bad("wall_velocity", "not a finite number.".into());
    }
    friction("packing.wall_friction".into(), p.wall_friction)?;
    if s.gravity.as_ref().is_some_and(|g| g.len() != 2) {
        return Err((Invalid, "gravity".into(), "a packing is 2D: gravity needs 2 components.".into()));
    }
    Ok(())
}

/// The body name of grain `i` (0-based), zero-padded so that names sort in grain order.
pub fn grain_name(i: usize, count: usize) -> String {
    let width = count.to_string().len().max(4);
    format!("grain_{:0width$}", i + 1)
}

/// Adds the packing's grains and walls to the scene.
pub(super) fn expand(s: &mut Scene) -> Result<(), Failure> {
    let Some(p) = s.packing.clone() else { return Ok(()) };
    check(&p, s)?;
    let mut rng = SplitMix64(p.seed);
    let [r_min, r_max] = [p.radius[0], p.radius[1]];
    let cell = 2.0 * r_max * (1.0 + p.gap);
    let columns = if p.columns > 0 { p.columns } else { (p.count as Real).sqrt().ceil() as usize };
    let rows = p.count.div_ceil(columns);
    let finest_disk = generate::disk([0.0, 0.0], r_min, p.divisions, ElementKind::Tri3).min_edge_length();
    for i in 0..p.count {
        let name = grain_name(i, p.count);
        if s.body.contains_key(&name) {
            return Err((Invalid, "packing.count".into(), format!("the scene already has a body named `{name}`.")));
        }
        let r = rng.between(r_min, r_max);
        // Room to move inside the cell while keeping half the gap to its edges.
        let play = 0.5 * cell - r - r_max * p.gap;
        let center = [(i % columns) as Real + 0.5, (i / columns) as Real + 0.5].map(|c| c * cell + rng.between(-play, play));
        let mesh = if rng.unit() < p.polygons {
            let sides = 3 + (rng.unit() * 4.0) as usize;
            let turn = rng.unit() * TAU;
            // Vertices on the circle, so the outline is convex; each angle jittered by at most a
            // quarter of the spacing, so no two vertices come close.
            let points: Vec<[Real; 2]> = (0..sides)
                .map(|k| {
                    let angle = turn + TAU * (k as Real + rng.between(-0.25, 0.25)) / sides as Real;
                    [center[0] + r * angle.cos(), center[1] + r * angle.sin()]
                })
                .collect();
            // Each fan triangle is split into n x n copies scaled by 1/n, so the finest edge at
            // n divisions is the finest at one over n: no mesh is built per trial (with a large
            // radius that loop built millions of elements for every n).
            let coarsest = generate::polygon(&points, 1).min_edge_length();
            let n = p.divisions.max((coarsest / finest_disk).floor() as usize + 1);
            let points = Some(points.iter().map(|q| q.to_vec()).collect());
            MeshSpec { generator: Some(Generator::Polygon), element: Some(ElementKind::Tri3), points, divisions: Some(vec![n]), ..Default::default() }
        } else {
            MeshSpec { generator: Some(Generator::Disk), element: Some(ElementKind::Tri3), center: Some(center.to_vec()), radius: Some(r), divisions: Some(vec![p.divisions]), ..Default::default() }
        };
        s.body.insert(name, BodySpec { material: p.material.clone(), mesh, initial_velocity: None, angular_velocity: None });
    }
    let (width, height) = (columns as Real * cell, rows as Real * cell);
    let walls = [
        ("left", [0.0, 0.0], [1.0, 0.0], 0.0, p.wall_velocity),
        ("right", [width, 0.0], [-1.0, 0.0], 0.0, 0.0),
        ("bottom", [0.0, 0.0], [0.0, 1.0], p.wall_friction, 0.0),
        ("top", [0.0, height], [0.0, -1.0], p.wall_friction, 0.0),
    ];
    for (name, point, normal, friction, speed) in walls {
        if s.obstacle.contains_key(name) {
            return Err((Invalid, "packing".into(), format!("the packing makes the obstacle `{name}`, which the scene already has.")));
        }
        s.obstacle.insert(
            name.to_string(),
            ObstacleSpec {
                shape: ObstacleShape::Plane,
                point: Some(point.to_vec()),
                normal: Some(normal.to_vec()),
                min: None,
                max: None,
                inside: None,
                points: None,
                friction: Some(friction),
                velocity: (speed != 0.0).then(|| vec![speed, 0.0]),
                motion: None,
                interpolation: None,
                bodies: None,
            },
        );
    }
    Ok(())
}
