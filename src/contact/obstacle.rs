//! Rigid obstacles: half-planes and half-spaces, boxes (solid or container), convex polygons and
//! one-sided polylines, fixed or moving with a prescribed velocity.

use super::geometry::{dot, norm, normalize, scale, sub, Vec3};
use crate::precision::Real;

/// A prescribed velocity history: piecewise constant (`step`) or piecewise linear between rows
/// `(t, v)`, held constant before the first row and after the last. No rows: fixed.
#[derive(Debug, Clone, Default)]
pub struct Motion {
    pub rows: Vec<(Real, Vec3)>,
    pub linear: bool,
}

impl Motion {
    pub fn velocity(&self, t: Real) -> Vec3 {
        let Some(first) = self.rows.first() else { return [0.0; 3] };
        if t <= first.0 {
            return first.1;
        }
        for w in self.rows.windows(2) {
            let ((t0, v0), (t1, v1)) = (w[0], w[1]);
            if t < t1 {
                if !self.linear {
                    return v0;
                }
                let s = (t - t0) / (t1 - t0);
                return [0, 1, 2].map(|i| v0[i] + s * (v1[i] - v0[i]));
            }
        }
        self.rows.last().expect("non-empty").1
    }

    /// `∫_0^t v`, exact for both interpolations.
    pub fn displacement(&self, t: Real) -> Vec3 {
        let mut knots: Vec<Real> = vec![0.0];
        knots.extend(self.rows.iter().map(|r| r.0).filter(|&s| s > 0.0 && s < t));
        knots.push(t);
        let mut d = [0.0; 3];
        for w in knots.windows(2) {
            let (a, b) = (w[0], w[1]);
            let v = if self.linear {
                let (va, vb) = (self.velocity(a), self.velocity(b));
                [0, 1, 2].map(|i| 0.5 * (va[i] + vb[i]))
            } else {
                self.velocity(a)
            };
            for i in 0..3 {
                d[i] += v[i] * (b - a);
            }
        }
        d
    }
}

/// A flat piece of an obstacle: its plane (a point and the normal on the free side) and, for
/// polyline segments, the segment it is limited to.
#[derive(Debug, Clone)]
pub struct Face {
    pub point: Vec3,
    pub normal: Vec3,
    /// `Some(b)`: a segment from `point` to `b` (2D polylines); `None`: the whole plane.
    pub segment_end: Option<Vec3>,
}

/// How a node meets the faces of an obstacle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// A convex solid: the node is kept out of the half-space of its face with the largest gap
    /// (valid for convex shapes: the solid lies behind every face plane).
    Solid,
    /// Independent walls: the node may touch several at once (container corners, polylines).
    Walls,
}

/// What an obstacle looks like at rest, for drawing it (contact only uses the faces).
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    Plane { point: Vec3, normal: Vec3 },
    Box { min: Vec3, max: Vec3 },
    Polygon(Vec<Vec3>),
    Polyline(Vec<Vec3>),
}

#[derive(Debug, Clone)]
pub struct Obstacle {
    pub name: String,
    pub shape: Shape,
    pub faces: Vec<Face>,
    pub mode: Mode,
    pub friction: Real,
    pub motion: Motion,
    /// Which bodies it touches (by index).
    pub bodies: Vec<bool>,
}

/// One face of an obstacle that a node may touch.
#[derive(Debug, Clone, Copy)]
pub struct Touch {
    pub face: u32,
    pub gap: Real,
    pub normal: Vec3,
    pub tangent: Option<Vec3>,
}

impl Obstacle {
    /// Half-plane (2D) or half-space (3D): bodies stay on the side `normal` points to.
    pub fn plane(point: Vec3, normal: Vec3) -> (Vec<Face>, Mode) {
        (vec![Face { point, normal: normalize(normal), segment_end: None }], Mode::Walls)
    }

    /// Axis-aligned box; `inside`: a container whose walls face inwards.
    pub fn cuboid(min: Vec3, max: Vec3, dim: usize, inside: bool) -> (Vec<Face>, Mode) {
        let mut faces = Vec::new();
        for axis in 0..dim {
            for (corner, outward) in [(min, -1.0), (max, 1.0)] {
                let mut normal = [0.0; 3];
                normal[axis] = if inside { -outward } else { outward };
                faces.push(Face { point: corner, normal, segment_end: None });
            }
        }
        (faces, if inside { Mode::Walls } else { Mode::Solid })
    }

    /// Convex polygon (2D), bodies outside; the vertex order may be either way round.
    pub fn polygon(points: &[Vec3]) -> (Vec<Face>, Mode) {
        let n = points.len();
        let area: Real = (0..n)
            .map(|i| {
                let (a, b) = (points[i], points[(i + 1) % n]);
                a[0] * b[1] - b[0] * a[1]
            })
            .sum();
        let sign = if area > 0.0 { 1.0 } else { -1.0 };
        let faces = (0..n)
            .map(|i| {
                let d = sub(points[(i + 1) % n], points[i]);
                Face { point: points[i], normal: scale(normalize([d[1], -d[0], 0.0]), sign), segment_end: None }
            })
            .collect();
        (faces, Mode::Solid)
    }

    /// Open polyline (2D); bodies stay on its left (the normal is the direction turned +90°).
    pub fn polyline(points: &[Vec3]) -> (Vec<Face>, Mode) {
        let faces = points
            .windows(2)
            .map(|w| {
                let d = sub(w[1], w[0]);
                Face { point: w[0], normal: normalize([-d[1], d[0], 0.0]), segment_end: Some(w[1]) }
            })
            .collect();
        (faces, Mode::Walls)
    }

    /// Whether a node inside the box `(lo, hi)` can touch the obstacle (displaced by `offset`)
    /// within `margin` ([`Obstacle::touches`]): a face whose gap exceeds `margin` over the whole
    /// box (the gap is linear, so its least is at a corner) takes none of its nodes.
    pub fn may_touch(&self, (lo, hi): (Vec3, Vec3), offset: Vec3, margin: Real) -> bool {
        let far = |f: &Face| {
            let least: Real = (0..3).map(|i| (lo[i] - offset[i] - f.point[i]) * f.normal[i]).zip((0..3).map(|i| (hi[i] - offset[i] - f.point[i]) * f.normal[i])).map(|(a, b)| a.min(b)).sum();
            least > margin
        };
        match self.mode {
            // A node touches a solid only where every face's gap is within the margin.
            Mode::Solid => !self.faces.iter().any(far),
            Mode::Walls => !self.faces.iter().all(far),
        }
    }

    /// Faces that the node at `x` touches or may touch within `margin`, the obstacle being
    /// displaced by `offset`.
    pub fn touches(&self, x: Vec3, offset: Vec3, margin: Real, out: &mut Vec<Touch>) {
        out.clear();
        let local = sub(x, offset);
        let gap_of = |f: &Face| dot(sub(local, f.point), f.normal);
        match self.mode {
            Mode::Solid => {
                let (i, gap) = self.faces.iter().enumerate().map(|(i, f)| (i, gap_of(f))).max_by(|a, b| a.1.total_cmp(&b.1)).expect("faces");
                if gap <= margin {
                    out.push(Touch { face: i as u32, gap, normal: self.faces[i].normal, tangent: None });
                }
            }
            Mode::Walls => {
                for (i, f) in self.faces.iter().enumerate() {
                    let gap = gap_of(f);
                    if gap > margin {
                        continue;
                    }
                    if let Some(end) = f.segment_end {
                        let d = sub(end, f.point);
                        let s = dot(sub(local, f.point), d) / dot(d, d);
                        // A little beyond the ends so that a node cannot slip between two segments.
                        if !(-0.01..=1.01).contains(&s) || -gap > norm(d) {
                            continue;
                        }
                    }
                    out.push(Touch { face: i as u32, gap, normal: f.normal, tangent: f.segment_end.map(|e| sub(e, f.point)) });
                }
            }
        }
    }
}
