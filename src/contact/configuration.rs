//! The bodies at one instant, as the searches see them: every body's box and largest facet
//! first, which tell that most bodies of a packing are far from everything, and the node
//! positions only of the bodies something may touch. Built once per configuration and shared
//! by the overlap search at the end of a step and the detection that starts the next one.

use super::broad::Aabb;
use super::geometry::{bounds, edge_range, Vec3};
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
pub fn extent(surface: &Surface, x: impl Fn(usize) -> Vec3, scratch: &mut Vec<Vec3>) -> (Aabb, Real) {
    scratch.clear();
    scratch.extend((0..surface.nodes.len()).map(x));
    let mut p = [[0.0; 3]; 4];
    let largest = surface.local_facets.chunks_exact(surface.facet_nodes).map(|facet| {
        facet.iter().zip(&mut p).for_each(|(&k, p)| *p = scratch[k as usize]);
        edge_range(&p[..facet.len()]).1
    });
    let largest = largest.fold(0.0, Real::max);
    (bounds(scratch.iter().copied()), largest)
}
