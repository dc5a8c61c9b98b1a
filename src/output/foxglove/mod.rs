//! Foxglove messages in the run log: a 3D view of the run (`foxglove.SceneUpdate`) and log lines
//! (`foxglove.Log`), JSON-encoded against the official schemas kept beside this file (see the
//! README there for their source and licence).

use crate::contact::geometry::{dot, frame, norm, normalize, scale, sub, Vec3};
use crate::contact::obstacle::Shape;
use crate::contact::{Obstacle, Surface};
use crate::element::CellFields;
use crate::output::encode;
use crate::precision::Real;
use crate::solver::{Body, Simulation};
use rayon::prelude::*;
use serde_json::value::{to_raw_value, RawValue};
use serde_json::{json, Value};

/// `foxglove.SceneUpdate`, JSON schema from `@foxglove/schemas`.
pub const SCENE_UPDATE_SCHEMA: &str = include_str!("SceneUpdate.json");
/// `foxglove.Log`, JSON schema from `@foxglove/schemas`.
pub const LOG_SCHEMA: &str = include_str!("Log.json");

/// The frame every entity is drawn in.
const FRAME: &str = "world";

/// `foxglove.LogLevel`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    Info = 2,
    Warning = 3,
    Error = 4,
    Fatal = 5,
}

/// Simulated time as a Foxglove `time`.
pub fn timestamp(t: Real) -> Value {
    let ns = (t.max(0.0) * 1e9).round() as u64;
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

/// A `foxglove.Log` message.
pub fn log(t: Real, level: Level, message: &str) -> Value {
    json!({"timestamp": timestamp(t), "level": level as u8, "message": message, "name": "bifirst", "file": "", "line": 0})
}

fn point(x: Vec3) -> Value {
    json!({"x": x[0], "y": x[1], "z": x[2]})
}

/// A vertex of a body's boundary, in single precision: what the 3D panel draws with, and
/// 8 significant digits in the log instead of 17.
fn vertex(x: Vec3) -> Value {
    json!({"x": x[0] as f32, "y": x[1] as f32, "z": x[2] as f32})
}

fn color(c: [f32; 4]) -> Value {
    json!({"r": c[0], "g": c[1], "b": c[2], "a": c[3]})
}

fn pose(position: Vec3, orientation: [Real; 4]) -> Value {
    json!({"position": point(position), "orientation": {"x": orientation[0], "y": orientation[1], "z": orientation[2], "w": orientation[3]}})
}

const IDENTITY: [Real; 4] = [0.0, 0.0, 0.0, 1.0];
const GREY: [f32; 4] = [0.55, 0.55, 0.6, 0.6];
const RED: [f32; 4] = [0.9, 0.15, 0.1, 1.0];

/// An entity with every field of `foxglove.SceneEntity`, its primitive lists empty.
fn entity(t: Real, id: &str, metadata: &[(&str, String)]) -> serde_json::Map<String, Value> {
    let metadata: Vec<Value> = metadata.iter().map(|(k, v)| json!({"key": k, "value": v})).collect();
    let mut e = serde_json::Map::new();
    e.insert("timestamp".into(), timestamp(t));
    e.insert("frame_id".into(), json!(FRAME));
    e.insert("id".into(), json!(id));
    e.insert("lifetime".into(), json!({"sec": 0, "nsec": 0}));
    e.insert("frame_locked".into(), json!(false));
    e.insert("metadata".into(), json!(metadata));
    for list in ["arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"] {
        e.insert(list.into(), json!([]));
    }
    e
}

/// `LINE_LIST` (2) or `LINE_LOOP` (1) / `LINE_STRIP` (0) of one colour, a fixed 2 px wide on
/// screen; `indices` into `points` (empty: the points in order).
fn lines(kind: u8, points: Vec<Value>, indices: Vec<usize>, solid: [f32; 4]) -> Value {
    json!({
        "type": kind, "pose": pose([0.0; 3], IDENTITY), "thickness": 2.0, "scale_invariant": true,
        "points": points, "color": color(solid), "colors": [], "indices": indices,
    })
}

/// A triangle list of one colour; `indices` as for [`lines`].
fn triangles(points: Vec<Value>, indices: Vec<usize>, solid: [f32; 4]) -> Value {
    json!({"pose": pose([0.0; 3], IDENTITY), "points": points, "color": color(solid), "colors": [], "indices": indices})
}

/// Points of an obstacle, in full precision.
fn points(x: &[Vec3]) -> Vec<Value> {
    x.iter().map(|&p| point(p)).collect()
}

/// Colour levels of a body's boundary in the view: facets are grouped by level, one primitive
/// of one colour per level, instead of a colour for every vertex.
pub const COLOR_LEVELS: usize = 32;

/// Colour of `s` in [0, 1] on a viridis-like map (dark blue, teal, green, yellow).
pub fn colormap(s: Real) -> [f32; 4] {
    const STOPS: [[f32; 3]; 5] = [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]];
    let x = (s.clamp(0.0, 1.0) * 4.0) as f32;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2]), 1.0]
}

/// Rotation taking +x onto the unit vector `d`, as a quaternion `[x, y, z, w]`.
fn rotation_from_x(d: Vec3) -> [Real; 4] {
    let w = 1.0 + d[0];
    if w < 1e-9 {
        return [0.0, 0.0, 1.0, 0.0];
    }
    let q = [0.0, -d[2], d[1], w];
    let n = (q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    q.map(|c| c / n)
}

/// Builds the 3D view of a simulation. Colour and arrow scales only grow over a run, so that
/// frames can be compared.
pub struct View {
    dim: usize,
    /// Each body's boundary (the contact surfaces when the scene has contact).
    surfaces: Vec<Surface>,
    /// Diagonal of the bodies' initial bounding box: the size of planes and arrows.
    extent: Real,
    centre: Vec3,
    von_mises_max: Real,
    force_max: Real,
}

impl View {
    pub fn new(sim: &Simulation) -> Self {
        let (mut lo, mut hi) = ([Real::INFINITY; 3], [Real::NEG_INFINITY; 3]);
        for b in sim.bodies() {
            for x in &b.mesh().nodes {
                for i in 0..3 {
                    lo[i] = lo[i].min(x[i]);
                    hi[i] = hi[i].max(x[i]);
                }
            }
        }
        let extent = norm(sub(hi, lo)).max(Real::EPSILON);
        let centre = [0, 1, 2].map(|i| 0.5 * (lo[i] + hi[i]));
        let surfaces = match &sim.contact() {
            Some(c) => c.surfaces.clone(),
            None => sim.bodies().iter().map(|b| Surface::of(b.mesh())).collect(),
        };
        Self { dim: sim.dim(), surfaces, extent, centre, von_mises_max: 0.0, force_max: 0.0 }
    }

    /// The scene at the committed state, encoded for the log; `fields` are each body's
    /// [`CellFields`]. The bodies' entities are built and encoded in parallel (a packing has
    /// thousands of bodies) and the message holds them verbatim.
    pub fn scene_update(&mut self, sim: &Simulation, fields: &[Vec<CellFields>]) -> Vec<u8> {
        let t = sim.t();
        let frame_max = fields.iter().flatten().map(|f| f.von_mises).fold(0.0, Real::max);
        self.von_mises_max = self.von_mises_max.max(frame_max);
        let raw = |entity: Value| to_raw_value(&entity).expect("an entity serializes");
        let mut entities: Vec<Box<RawValue>> = sim.bodies().par_iter().zip(&self.surfaces).zip(fields).map(|((body, surface), fields)| raw(self.body(t, body, surface, fields))).collect();
        if let Some(contact) = &sim.contact() {
            entities.extend(contact.obstacles.iter().map(|o| raw(self.obstacle(t, o))));
            entities.push(raw(self.contact_forces(sim)));
        }
        #[derive(serde::Serialize)]
        struct SceneUpdate {
            deletions: [Value; 0],
            entities: Vec<Box<RawValue>>,
        }
        encode(&SceneUpdate { deletions: [], entities })
    }

    /// The deformed boundary, each facet coloured by its element's von Mises stress on
    /// [`COLOR_LEVELS`] levels: one primitive per level used, each node once in it and the
    /// facets as indices (a node is shared by two segments in 2D, about six triangles in 3D).
    fn body(&self, t: Real, body: &Body, surface: &Surface, fields: &[CellFields]) -> Value {
        let scale_max = self.von_mises_max.max(Real::MIN_POSITIVE);
        #[derive(Clone, Default)]
        struct Level {
            index_of: std::collections::HashMap<u32, usize>,
            points: Vec<Value>,
            indices: Vec<usize>,
        }
        let mut levels = vec![Level::default(); COLOR_LEVELS];
        for f in 0..surface.facet_count() {
            let s = fields[surface.owners[f] as usize].von_mises / scale_max;
            let level = &mut levels[(s.clamp(0.0, 1.0) * (COLOR_LEVELS - 1) as Real).round() as usize];
            let nodes = surface.facet(f);
            let corners: &[usize] = match nodes.len() {
                2 => &[0, 1],
                3 => &[0, 1, 2],
                _ => &[0, 1, 2, 0, 2, 3],
            };
            for &k in corners {
                let n = nodes[k];
                let next = level.points.len();
                let i = *level.index_of.entry(n).or_insert(next);
                if i == next {
                    level.points.push(vertex(body.position(n as usize)));
                }
                level.indices.push(i);
            }
        }
        let primitives: Vec<Value> = levels
            .into_iter()
            .enumerate()
            .filter(|(_, l)| !l.points.is_empty())
            .map(|(k, l)| {
                let c = colormap(k as Real / (COLOR_LEVELS - 1) as Real);
                if self.dim == 2 {
                    lines(2, l.points, l.indices, c)
                } else {
                    triangles(l.points, l.indices, c)
                }
            })
            .collect();
        let metadata = [("von_mises_max", format!("{:e}", self.von_mises_max)), ("colormap", format!("viridis: 0 to von_mises_max in {COLOR_LEVELS} levels"))];
        let mut e = entity(t, &format!("body/{}", body.name()), &metadata);
        e.insert(if self.dim == 2 { "lines" } else { "triangles" }.into(), Value::Array(primitives));
        Value::Object(e)
    }

    /// Contact forces on the slave nodes as arrows ending at the node, longest = 10% of the
    /// scene's size at the largest force seen so far.
    fn contact_forces(&mut self, sim: &Simulation) -> Value {
        let forces: Vec<(Vec3, Vec3)> = sim.contact_points().iter().map(|c| (sim.bodies()[c.slave_body as usize].position(c.slave_node as usize), c.force())).filter(|(_, f)| norm(*f) > 0.0).collect();
        self.force_max = forces.iter().map(|(_, f)| norm(*f)).fold(self.force_max, Real::max);
        let arrows: Vec<Value> = forces
            .iter()
            .map(|&(x, f)| {
                let length = 0.1 * self.extent * norm(f) / self.force_max;
                let d = normalize(f);
                let head = length.min(0.02 * self.extent);
                json!({
                    "pose": pose(sub(x, scale(d, length)), rotation_from_x(d)),
                    "shaft_length": length - head, "shaft_diameter": 0.004 * self.extent,
                    "head_length": head, "head_diameter": 0.01 * self.extent, "color": color(RED),
                })
            })
            .collect();
        let mut e = entity(sim.t(), "contact_forces", &[("force_max", format!("{:e}", self.force_max)), ("count", forces.len().to_string())]);
        e.insert("arrows".into(), json!(arrows));
        Value::Object(e)
    }

    /// A rigid obstacle at its current position: lines in 2D, a square, box or edges in 3D.
    fn obstacle(&self, t: Real, o: &Obstacle) -> Value {
        let offset = o.motion.displacement(t);
        let moved = |x: Vec3| [x[0] + offset[0], x[1] + offset[1], x[2] + offset[2]];
        let mut e = entity(t, &format!("obstacle/{}", o.name), &[]);
        match &o.shape {
            Shape::Plane { point, normal } => {
                // Centred on the foot of the scene's centre, as wide as the scene.
                let n = normalize(*normal);
                let foot = sub(self.centre, scale(n, dot(sub(self.centre, *point), n)));
                let [_, t1, t2] = frame(n, None, self.dim);
                let c = |a: Real, b: Real| moved([0, 1, 2].map(|i| foot[i] + self.extent * (a * t1[i] + b * t2[i])));
                if self.dim == 2 {
                    e.insert("lines".into(), json!([lines(0, points(&[c(-1.0, 0.0), c(1.0, 0.0)]), vec![], GREY)]));
                } else {
                    let square = [c(-1.0, -1.0), c(1.0, -1.0), c(1.0, 1.0), c(-1.0, -1.0), c(1.0, 1.0), c(-1.0, 1.0)];
                    e.insert("triangles".into(), json!([triangles(points(&square), vec![], GREY)]));
                }
            }
            Shape::Box { min, max } => {
                let corner = |k: usize| moved([0, 1, 2].map(|i| if k >> i & 1 == 1 { max[i] } else { min[i] }));
                if self.dim == 2 {
                    e.insert("lines".into(), json!([lines(1, points(&[corner(0), corner(1), corner(3), corner(2)]), vec![], GREY)]));
                } else {
                    // The 12 edges: corners that differ in one bit.
                    let edges: Vec<Vec3> = (0..8).flat_map(|k| (0..3).filter(move |i| k >> i & 1 == 0).flat_map(move |i| [k, k | 1 << i])).map(corner).collect();
                    e.insert("lines".into(), json!([lines(2, points(&edges), vec![], GREY)]));
                }
            }
            Shape::Polygon(corners) => {
                e.insert("lines".into(), json!([lines(1, corners.iter().map(|&p| point(moved(p))).collect(), vec![], GREY)]));
            }
            Shape::Polyline(corners) => {
                e.insert("lines".into(), json!([lines(0, corners.iter().map(|&p| point(moved(p))).collect(), vec![], GREY)]));
            }
        }
        Value::Object(e)
    }
}
