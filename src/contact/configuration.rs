//! The bodies at one instant, as the searches see them: every body's box and largest facet
//! first, which tell that most bodies of a packing are far from everything, and the node
//! positions only of the bodies something may touch. Built once per configuration and shared
//! by the overlap search at the end of a step and the detection that starts the next one.

use super::broad::Aabb;
use super::geometry::{self, Vec3};
use super::{ContactModel, Surface};
use crate::precision::Real;
use rayon::prelude::*;

/// Writes body `b`'s node positions over the vector (all nodes, in node order).
pub type Fill<'a> = dyn Fn(usize, &mut Vec<Vec3>) + Sync + 'a;

/// Per body: the box of its boundary nodes, its largest facet, and its node positions where
/// placed.
#[derive(Debug, Clone, Default)]
pub struct Configuration {
    /// A body's region lies inside the box of its boundary (unless an element is inverted), so
    /// this box serves the overlap search as well as the node-facet search.
    pub boxes: Vec<Aabb>,
    /// Largest edge (or diagonal) of each body's facets: how far beyond the box a node can
    /// still make a point with the body.
    pub largest: Vec<Real>,
    pub nodes: Nodes,
}

/// Node positions per body, valid where placed (the buffers of the others are kept for reuse).
#[derive(Debug, Clone, Default)]
pub struct Nodes {
    pub positions: Vec<Vec<Vec3>>,
    pub placed: Vec<bool>,
}

impl Configuration {
    /// A configuration with every body placed at `positions`.
    pub fn new(model: &ContactModel, positions: Vec<Vec<Vec3>>) -> Self {
        let (boxes, largest) = model.surfaces.par_iter().zip(&positions).map_init(Vec::new, |scratch, (surface, x)| extent(surface, |k| x[surface.nodes[k] as usize], scratch)).unzip();
        let placed = vec![true; positions.len()];
        Self { boxes, largest, nodes: Nodes { positions, placed } }
    }
}

impl Nodes {
    /// Forgets every body's positions (keeping the buffers) for a configuration of `bodies`.
    pub fn unplace(&mut self, bodies: usize) {
        self.positions.resize_with(bodies, Vec::new);
        self.placed.clear();
        self.placed.resize(bodies, false);
    }

    /// Places the bodies that `needed` names and are not placed yet, with `fill`.
    pub fn place(&mut self, needed: impl Fn(usize) -> bool + Sync, fill: &Fill<'_>) {
        self.positions.par_iter_mut().zip(&mut self.placed).enumerate().filter(|(b, (_, placed))| !**placed && needed(*b)).for_each(|(b, (x, placed))| {
            fill(b, x);
            *placed = true;
        });
    }
}

/// The box of a body's boundary nodes and its facets' largest edge (or diagonal), `x(k)` giving
/// the position of boundary node `k` (the `k`-th of `surface.nodes`); `scratch` holds them.
/// Run on every body each step: one pass for the box, squared lengths compared and one square
/// root per body (the same number as the largest of the lengths: the root is monotonic and
/// correctly rounded).
pub fn extent(surface: &Surface, x: impl Fn(usize) -> Vec3, scratch: &mut Vec<Vec3>) -> (Aabb, Real) {
    let (mut lo, mut hi) = ([Real::INFINITY; 3], [Real::NEG_INFINITY; 3]);
    scratch.clear();
    scratch.extend((0..surface.nodes.len()).map(|k| {
        let p = x(k);
        for i in 0..3 {
            lo[i] = if p[i] < lo[i] { p[i] } else { lo[i] };
            hi[i] = if p[i] > hi[i] { p[i] } else { hi[i] };
        }
        p
    }));
    let facets = &surface.local_facets;
    let longest = match surface.facet_nodes {
        2 => longest_squared::<2>(facets, scratch),
        3 => longest_squared::<3>(facets, scratch),
        _ => longest_squared::<4>(facets, scratch),
    };
    ((lo, hi), longest.sqrt())
}

/// The largest squared edge (or diagonal) of the facets (`N` points each) at `x`.
fn longest_squared<const N: usize>(facets: &[u32], x: &[Vec3]) -> Real {
    facets.chunks_exact(N).map(|facet| geometry::longest_squared::<N>(&std::array::from_fn(|i| x[facet[i] as usize]))).fold(0.0, |a, d| if d > a { d } else { a })
}
