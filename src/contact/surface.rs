//! Boundary facets of a mesh, oriented with outward normals: segments (Tri3, Quad4), triangles
//! (Tet4) and quadrilaterals (Hex8). Found once at set-up: a facet is on the boundary when no
//! other element shares it.

use super::geometry::Vec3;
use crate::mesh::{ElementKind, Mesh};
use std::collections::HashMap;

/// Local facets of each element kind, ordered so that the normal points out of the element
/// (2D: counter-clockwise elements, outward normal = edge direction turned clockwise; 3D:
/// `(c - a) x (d - b)` or `(b - a) x (c - a)` points out).
fn local_facets(kind: ElementKind) -> &'static [&'static [usize]] {
    match kind {
        ElementKind::Tri3 => &[&[0, 1], &[1, 2], &[2, 0]],
        ElementKind::Quad4 => &[&[0, 1], &[1, 2], &[2, 3], &[3, 0]],
        ElementKind::Tet4 => &[&[0, 2, 1], &[0, 1, 3], &[1, 2, 3], &[0, 3, 2]],
        ElementKind::Hex8 => &[&[0, 3, 2, 1], &[4, 5, 6, 7], &[0, 1, 5, 4], &[1, 2, 6, 5], &[2, 3, 7, 6], &[3, 0, 4, 7]],
    }
}

/// The boundary of one body.
#[derive(Debug, Clone)]
pub struct Surface {
    /// Nodes per facet: 2 (segment), 3 (triangle) or 4 (quadrilateral).
    pub facet_nodes: usize,
    /// Facet connectivity, `facet_nodes` per facet, outward orientation.
    pub facets: Vec<u32>,
    /// Nodes on the boundary, sorted: the slave nodes of this body.
    pub nodes: Vec<u32>,
    /// The element each facet belongs to (for colouring the boundary by element stress).
    pub owners: Vec<u32>,
    /// `facets` as indices into `nodes`: a facet's points among the boundary nodes' alone.
    pub local_facets: Vec<u32>,
    /// The boundary nodes' reference positions, side by side (a pass over every body's boundary
    /// each step reads these instead of the whole mesh).
    pub reference: Vec<Vec3>,
}

impl Surface {
    pub fn of(mesh: &Mesh) -> Self {
        let local = local_facets(mesh.kind);
        let facet_nodes = local[0].len();
        let mut seen: HashMap<Vec<u32>, (usize, Vec<u32>, u32)> = HashMap::new();
        for e in 0..mesh.element_count() {
            let nodes = mesh.element(e);
            for f in local {
                let oriented: Vec<u32> = f.iter().map(|&a| nodes[a]).collect();
                let mut key = oriented.clone();
                key.sort_unstable();
                seen.entry(key).and_modify(|(count, ..)| *count += 1).or_insert((1, oriented, e as u32));
            }
        }
        let mut boundary: Vec<(Vec<u32>, u32)> = seen.into_values().filter(|(count, ..)| *count == 1).map(|(_, f, e)| (f, e)).collect();
        boundary.sort_unstable();
        let facets: Vec<u32> = boundary.iter().flat_map(|(f, _)| f.iter().copied()).collect();
        let owners = boundary.iter().map(|&(_, e)| e).collect();
        let mut nodes = facets.clone();
        nodes.sort_unstable();
        nodes.dedup();
        let local_facets = facets.iter().map(|n| nodes.binary_search(n).expect("a facet's node is a boundary node") as u32).collect();
        let reference = reference(&nodes, mesh);
        Self { facet_nodes, facets, nodes, owners, local_facets, reference }
    }

    /// The same boundary on another mesh of the same connectivity (a packing's grains of one
    /// shape share the boundary search of one of them).
    pub fn on(&self, mesh: &Mesh) -> Self {
        Self { reference: reference(&self.nodes, mesh), ..self.clone() }
    }

    pub fn facet_count(&self) -> usize {
        self.facets.len() / self.facet_nodes
    }

    pub fn facet(&self, f: usize) -> &[u32] {
        &self.facets[f * self.facet_nodes..(f + 1) * self.facet_nodes]
    }

    /// The points of facet `f` at the node positions `x`: a fixed array and the facet's node
    /// count (no allocation per facet in the searches that visit every facet each step).
    pub fn facet_points(&self, x: &[Vec3], f: usize) -> ([Vec3; 4], usize) {
        let mut p = [[0.0; 3]; 4];
        for (k, &n) in self.facet(f).iter().enumerate() {
            p[k] = x[n as usize];
        }
        (p, self.facet_nodes)
    }
}

/// The reference positions of `nodes` of `mesh`.
fn reference(nodes: &[u32], mesh: &Mesh) -> Vec<Vec3> {
    nodes.iter().map(|&n| mesh.nodes[n as usize]).collect()
}
