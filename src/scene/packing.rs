//! `[packing]`: a random packing of grains in a rigid box, expanded into ordinary bodies and
//! obstacles before validation.
//!
//! The grains sit one per cell of a lattice (cell size: the largest diameter plus the gap), each
//! with a random radius, shape, orientation and offset inside its cell, so that no two overlap
//! and none touches a wall. The walls are the planes around the lattice. In 2D the grains are
//! disks and polygons (Tri3); in 3D balls and boxes (Tet4 or Hex8), every shape inside the ball
//! of its radius.
//!
//! Polygons are meshed finer than the finest disk: single-pass contact makes the finer mesh the
//! slave, and a polygon's corners must be slave nodes, or they would sink into the disks.

use super::error::SceneErrorKind::{Invalid, Reference};
use super::types::DEFAULT_SHARE;
use super::types::{BodySpec, Generator, Interpolation, MeshSpec, ObstacleShape, ObstacleSpec, PackingSpec, Scene};
use super::validate::{friction, length, names, Failure};
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
        [lo, hi] if lo > 0.0 && lo <= hi && hi.is_finite() => {
            length("packing.radius.0".into(), "the smallest radius", lo)?;
            length("packing.radius.1".into(), "the largest radius", hi)?;
        }
        _ => return bad("radius", format!("expected [min, max] with 0 < min <= max (got {:?}).", p.radius)),
    }
    if !matches!(p.dimension, 2 | 3) {
        return bad("dimension", format!("a packing is 2 (disks and polygons) or 3 (balls and boxes) dimensional (got {}).", p.dimension));
    }
    for (field, share, what) in [("polygons", p.polygons, "polygons"), ("polyhedra", p.polyhedra, "boxes")] {
        if share.is_some_and(|v| !(0.0..=1.0).contains(&v)) {
            return bad(field, format!("the share of {what} must lie in [0, 1] (got {}).", share.unwrap_or_default()));
        }
    }
    // A share for the other dimension would be ignored. The default is let through: scenes
    // resolved before the shares were optional (the logs restarts read) wrote both.
    let (foreign, field, own) = if p.dimension == 2 { (p.polyhedra, "polyhedra", "polygons") } else { (p.polygons, "polygons", "polyhedra") };
    if foreign.is_some_and(|v| v != DEFAULT_SHARE) {
        return bad(field, format!("`{field}` is a share of {}D grains; this packing is {}D (its share is `{own}`).", 5 - p.dimension, p.dimension));
    }
    match (p.dimension, p.element) {
        (_, None) | (2, Some(ElementKind::Tri3)) | (3, Some(ElementKind::Tet4 | ElementKind::Hex8)) => {}
        (2, Some(kind)) => return bad("element", format!("2D grains are tri3 (got {}).", kind.name())),
        (_, Some(kind)) => return bad("element", format!("3D grains are tet4 or hex8 (got {}).", kind.name())),
    }
    if p.divisions == 0 {
        return bad("divisions", "at least one cell per radius is needed.".into());
    }
    // A disk of n divisions has 8 n² triangles, a ball of Tet4 48 n³ tetrahedra (a box no more
    // than its ball); checked here, before any grain is meshed (a huge `divisions` overflowed
    // the mesh generator).
    let n = p.divisions as u128;
    let per_grain = if p.dimension == 2 { n.saturating_mul(n).saturating_mul(8) } else { n.saturating_mul(n).saturating_mul(n).saturating_mul(48) };
    let elements = (p.count as u128).saturating_mul(per_grain);
    if elements > s.limits.max_elements as u128 {
        let field = if p.count as u128 > s.limits.max_elements as u128 / per_grain.min(48) { "count" } else { "divisions" };
        let message = format!("{} grains of {} divisions make {elements} elements or more, more than limits.max_elements = {}; raise the limit (`--set limits.max_elements=N`) if you mean it.", p.count, p.divisions, s.limits.max_elements);
        return bad(field, message);
    }
    if !(p.gap >= 0.0 && p.gap.is_finite()) {
        return bad("gap", format!("the gap must be zero or positive (got {}).", p.gap));
    }
    if !p.wall_velocity.is_finite() {
        return bad("wall_velocity", "not a finite number.".into());
    }
    if p.wall_until.is_some_and(|t| !(t > 0.0 && t.is_finite())) {
        return bad("wall_until", format!("the time the wall stops must be positive and finite (got {}).", p.wall_until.unwrap_or_default()));
    }
    friction("packing.wall_friction".into(), p.wall_friction)?;
    if s.gravity.as_ref().is_some_and(|g| g.len() != p.dimension) {
        return Err((Invalid, "gravity".into(), format!("the packing is {}D: gravity needs {} components.", p.dimension, p.dimension)));
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
    let dim = p.dimension;
    let side = if dim == 2 { (p.count as Real).sqrt() } else { (p.count as Real).cbrt() };
    let columns = if p.columns > 0 { p.columns } else { side.ceil() as usize };
    // Layers along z (3D), then rows along y: the lattice fills x first, then z, then y (up).
    let layers = if dim == 3 { columns } else { 1 };
    let rows = p.count.div_ceil(columns * layers);
    let finest_disk = if dim == 2 { generate::disk([0.0, 0.0], r_min, p.divisions, ElementKind::Tri3).min_edge_length() } else { 0.0 };
    for i in 0..p.count {
        let name = grain_name(i, p.count);
        if s.body.contains_key(&name) {
            return Err((Invalid, "packing.count".into(), format!("the scene already has a body named `{name}`.")));
        }
        let r = rng.between(r_min, r_max);
        // Room to move inside the cell while keeping half the gap to its edges.
        let play = 0.5 * cell - r - r_max * p.gap;
        let lattice = [i % columns, i / (columns * layers), (i / columns) % layers];
        let mut center = [0.0; 3];
        for (k, c) in center.iter_mut().enumerate().take(dim) {
            *c = (lattice[k] as Real + 0.5) * cell + rng.between(-play, play);
        }
        let mesh = if dim == 2 { grain_2d(&p, &mut rng, [center[0], center[1]], r, finest_disk) } else { grain_3d(&p, &mut rng, center, r, r_min) };
        s.body.insert(name, BodySpec { material: p.material.clone(), mesh, initial_velocity: None, angular_velocity: None, formulation: None });
    }
    let size = [columns as Real * cell, rows as Real * cell, layers as Real * cell];
    let mut walls = vec![
        ("left", [0.0; 3], [1.0, 0.0, 0.0], 0.0, p.wall_velocity),
        ("right", [size[0], 0.0, 0.0], [-1.0, 0.0, 0.0], 0.0, 0.0),
        ("bottom", [0.0; 3], [0.0, 1.0, 0.0], p.wall_friction, 0.0),
        ("top", [0.0, size[1], 0.0], [0.0, -1.0, 0.0], p.wall_friction, 0.0),
    ];
    if dim == 3 {
        walls.push(("back", [0.0; 3], [0.0, 0.0, 1.0], 0.0, 0.0));
        walls.push(("front", [0.0, 0.0, size[2]], [0.0, 0.0, -1.0], 0.0, 0.0));
    }
    for (name, point, normal, friction, speed) in walls {
        if s.obstacle.contains_key(name) {
            return Err((Invalid, "packing".into(), format!("the packing makes the obstacle `{name}`, which the scene already has.")));
        }
        let mut velocity = vec![0.0; dim];
        velocity[0] = speed;
        s.obstacle.insert(
            name.to_string(),
            ObstacleSpec {
                shape: ObstacleShape::Plane,
                point: Some(point[..dim].to_vec()),
                normal: Some(normal[..dim].to_vec()),
                min: None,
                max: None,
                inside: None,
                points: None,
                friction: Some(friction),
                velocity: (speed != 0.0 && p.wall_until.is_none()).then_some(velocity.clone()),
                motion: p.wall_until.filter(|_| speed != 0.0).map(|until| vec![[vec![0.0], velocity.clone()].concat(), [vec![until], vec![0.0; dim]].concat()]),
                interpolation: p.wall_until.filter(|_| speed != 0.0).map(|_| Interpolation::Step),
                bodies: None,
            },
        );
    }
    Ok(())
}

/// A disk, or a convex polygon of 3 to 6 vertices on its circle.
fn grain_2d(p: &PackingSpec, rng: &mut SplitMix64, center: [Real; 2], r: Real, finest_disk: Real) -> MeshSpec {
    if rng.unit() < p.polygons.unwrap_or(DEFAULT_SHARE) {
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
    }
}

/// A ball, or a box inscribed in the ball (random edge ratios, each half-edge at least half
/// the others') turned by a uniformly random rotation.
fn grain_3d(p: &PackingSpec, rng: &mut SplitMix64, center: [Real; 3], r: Real, r_min: Real) -> MeshSpec {
    let element = Some(p.element.unwrap_or(ElementKind::Tet4));
    if rng.unit() >= p.polyhedra.unwrap_or(DEFAULT_SHARE) {
        return MeshSpec { generator: Some(Generator::Ball), element, center: Some(center.to_vec()), radius: Some(r), divisions: Some(vec![p.divisions]), ..Default::default() };
    }
    let ratios = [0; 3].map(|_| rng.between(0.5, 1.0));
    let length = ratios.iter().map(|x| x * x).sum::<Real>().sqrt();
    let half = ratios.map(|x| r * x / length);
    // Cells no larger than a ball's of the smallest radius.
    let h = r_min / p.divisions as Real;
    let divisions = half.iter().map(|e| ((2.0 * e / h).ceil() as usize).max(1)).collect();
    MeshSpec {
        generator: Some(Generator::Box),
        element,
        origin: Some((0..3).map(|i| center[i] - half[i]).collect()),
        size: Some(half.iter().map(|e| 2.0 * e).collect()),
        divisions: Some(divisions),
        rotation: Some(random_rotation(rng).to_vec()),
        ..Default::default()
    }
}

/// A uniformly random rotation (Shoemake's random unit quaternion) as a rotation vector.
fn random_rotation(rng: &mut SplitMix64) -> [Real; 3] {
    let (u1, u2, u3) = (rng.unit(), rng.unit() * TAU, rng.unit() * TAU);
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let q = [a * u2.sin(), a * u2.cos(), b * u3.sin(), b * u3.cos()];
    // q = (x, y, z, w) with w >= 0 for the shorter of the two equal rotations.
    let sign = if q[3] < 0.0 { -1.0 } else { 1.0 };
    let (v, w) = ([q[0] * sign, q[1] * sign, q[2] * sign], q[3] * sign);
    let s = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if s == 0.0 {
        return [0.0; 3];
    }
    let angle = 2.0 * s.atan2(w);
    v.map(|c| c * angle / s)
}
