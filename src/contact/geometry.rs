//! Small vector helpers and the narrow phase: projecting a node onto a segment, a triangle or a
//! quadrilateral, which gives the gap, the contact frame and the weights of the facet's nodes.

use crate::precision::Real;

pub type Vec3 = [Real; 3];

pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub fn scale(a: Vec3, s: Real) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
pub fn dot(a: Vec3, b: Vec3) -> Real {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
pub fn norm(a: Vec3) -> Real {
    dot(a, a).sqrt()
}
pub fn normalize(a: Vec3) -> Vec3 {
    scale(a, 1.0 / norm(a))
}

/// The axis-aligned box `(min, max)` of some points.
pub fn bounds(points: impl IntoIterator<Item = Vec3>) -> (Vec3, Vec3) {
    points.into_iter().fold(([Real::INFINITY; 3], [Real::NEG_INFINITY; 3]), |(lo, hi), p| ([0, 1, 2].map(|i| lo[i].min(p[i])), [0, 1, 2].map(|i| hi[i].max(p[i]))))
}

/// The shortest and the longest distance between two of the points (the edges, and in a
/// quadrilateral or an element also the diagonals).
pub fn edge_range(p: &[Vec3]) -> (Real, Real) {
    let (mut shortest, mut longest) = (Real::INFINITY, 0.0 as Real);
    for (i, a) in p.iter().enumerate() {
        for b in &p[i + 1..] {
            let d = norm(sub(*a, *b));
            (shortest, longest) = (shortest.min(d), longest.max(d));
        }
    }
    (shortest, longest)
}

/// The largest squared distance between two of the `N` points of a facet: the square of
/// [`edge_range`]'s longest, without a root per pair (the searches take it for every facet of
/// thousands of bodies each step; the root of the largest square is the largest root).
pub fn longest_squared<const N: usize>(p: &[Vec3; N]) -> Real {
    let mut longest: Real = 0.0;
    for i in 0..N {
        for j in i + 1..N {
            let d = sub(p[i], p[j]);
            let d = dot(d, d);
            longest = if d > longest { d } else { longest };
        }
    }
    longest
}

/// Orthonormal frame `[n, t1, t2]` from a unit normal; `t1` follows `hint` when it is not
/// parallel to `n`. In 2D (`n[2] = 0`), `t1` is `n` turned by +90 degrees and `t2 = 0`.
pub fn frame(n: Vec3, hint: Option<Vec3>, dim: usize) -> [Vec3; 3] {
    if dim == 2 {
        return [n, [-n[1], n[0], 0.0], [0.0; 3]];
    }
    let along = |h: Vec3| {
        let t = sub(h, scale(n, dot(h, n)));
        let l = norm(t);
        (l > 1e-8 * norm(h)).then(|| scale(t, 1.0 / l))
    };
    let t1 = hint.and_then(along).unwrap_or_else(|| {
        let axis = if n[0].abs() < 0.6 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        along(axis).expect("an axis not parallel to n")
    });
    [n, t1, cross(n, t1)]
}

/// A node projected on a facet.
#[derive(Debug, Clone, Copy)]
pub struct Projection {
    /// Signed distance along the outward normal (negative: penetrated).
    pub gap: Real,
    pub normal: Vec3,
    /// A tangent direction of the facet (the frame's `t1` in 3D).
    pub tangent: Vec3,
    /// Weights of the facet's nodes at the projected point (sum 1).
    pub weights: [Real; 4],
}

/// Projection onto the segment `a -> b` whose outward normal is the direction turned clockwise;
/// `None` when the foot falls more than `tol` (relative) beyond an end.
pub fn on_segment(x: Vec3, a: Vec3, b: Vec3, tol: Real) -> Option<Projection> {
    let d = sub(b, a);
    let l2 = dot(d, d);
    let s = dot(sub(x, a), d) / l2;
    if !(-tol..=1.0 + tol).contains(&s) {
        return None;
    }
    let s = s.clamp(0.0, 1.0);
    let l = l2.sqrt();
    let normal = [d[1] / l, -d[0] / l, 0.0];
    Some(Projection { gap: dot(sub(x, a), normal), normal, tangent: scale(d, 1.0 / l), weights: [1.0 - s, s, 0.0, 0.0] })
}

/// Projection onto the triangle `a, b, c` (outward normal `(b - a) x (c - a)`); `None` when the
/// foot is outside by more than `tol` in barycentric coordinates.
pub fn on_triangle(x: Vec3, a: Vec3, b: Vec3, c: Vec3, tol: Real) -> Option<Projection> {
    let (e1, e2) = (sub(b, a), sub(c, a));
    let n = cross(e1, e2);
    let area2 = norm(n);
    let normal = scale(n, 1.0 / area2);
    let gap = dot(sub(x, a), normal);
    let p = sub(x, scale(normal, gap));
    let wb = dot(cross(sub(p, a), e2), normal) / area2;
    let wc = dot(cross(e1, sub(p, a)), normal) / area2;
    let wa = 1.0 - wb - wc;
    if wa < -tol || wb < -tol || wc < -tol {
        return None;
    }
    let w = [wa.max(0.0), wb.max(0.0), wc.max(0.0)];
    let sum = w[0] + w[1] + w[2];
    Some(Projection { gap, normal, tangent: normalize(e1), weights: [w[0] / sum, w[1] / sum, w[2] / sum, 0.0] })
}

/// Projection onto a quadrilateral `p[0..4]`, split into four triangles about its centroid (the
/// centroid's weight is shared equally by the four nodes); the closest accepted piece wins.
pub fn on_quad(x: Vec3, p: [Vec3; 4], tol: Real) -> Option<Projection> {
    let m = scale(add(add(p[0], p[1]), add(p[2], p[3])), 0.25);
    let mut best: Option<Projection> = None;
    for i in 0..4 {
        let j = (i + 1) % 4;
        if let Some(t) = on_triangle(x, m, p[i], p[j], tol) {
            if best.is_none_or(|b| t.gap.abs() < b.gap.abs()) {
                let mut weights = [0.25 * t.weights[0]; 4];
                weights[i] += t.weights[1];
                weights[j] += t.weights[2];
                best = Some(Projection { weights, ..t });
            }
        }
    }
    best
}
