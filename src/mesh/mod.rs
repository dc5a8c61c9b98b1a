//! Meshes: nodes, elements of one kind, and named node sets.

pub mod generate;
pub mod gmsh;

use crate::precision::Real;
use std::collections::BTreeMap;

/// The two triangles a quadrilateral cell `[0, 1, 2, 3]` splits into (counter-clockwise).
pub const QUAD_TRIANGLES: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];

/// The six tetrahedra of the Kuhn split of a hexahedral cell along its diagonal 0-6, each a path
/// 0 -> a -> b -> 6 through the cube, ordered for a positive volume.
pub const CUBE_TETRAHEDRA: [[usize; 4]; 6] = [[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]];

/// Element kinds, all isoparametric with linear shape functions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ElementKind {
    Tri3,
    Quad4,
    Tet4,
    Hex8,
}

impl ElementKind {
    pub fn dim(self) -> usize {
        match self {
            ElementKind::Tri3 | ElementKind::Quad4 => 2,
            ElementKind::Tet4 | ElementKind::Hex8 => 3,
        }
    }
    pub fn nodes(self) -> usize {
        match self {
            ElementKind::Tri3 => 3,
            ElementKind::Quad4 | ElementKind::Tet4 => 4,
            ElementKind::Hex8 => 8,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            ElementKind::Tri3 => "tri3",
            ElementKind::Quad4 => "quad4",
            ElementKind::Tet4 => "tet4",
            ElementKind::Hex8 => "hex8",
        }
    }
}

/// A single-kind mesh. Coordinates are stored with 3 components; 2D meshes have z = 0.
#[derive(Debug, Clone)]
pub struct Mesh {
    pub kind: ElementKind,
    pub nodes: Vec<[Real; 3]>,
    /// Connectivity, `kind.nodes()` indices per element, flattened.
    pub connectivity: Vec<u32>,
    /// Named node sets (faces of generated meshes, physical groups of Gmsh meshes), sorted indices.
    pub node_sets: BTreeMap<String, Vec<u32>>,
}

impl Mesh {
    pub fn dim(&self) -> usize {
        self.kind.dim()
    }
    pub fn element_count(&self) -> usize {
        self.connectivity.len() / self.kind.nodes()
    }
    pub fn element(&self, e: usize) -> &[u32] {
        let n = self.kind.nodes();
        &self.connectivity[e * n..(e + 1) * n]
    }

    /// The nodal displacements of element `e` from `u` (`dim` per node), padded to 3 components.
    pub fn element_displacements(&self, u: &[Real], e: usize) -> Vec<[Real; 3]> {
        let mut out = Vec::with_capacity(self.kind.nodes());
        self.element_displacements_into(u, e, &mut out);
        out
    }

    /// [`Mesh::element_displacements`] into a reused buffer (the per-element hot loop).
    pub fn element_displacements_into(&self, u: &[Real], e: usize, out: &mut Vec<[Real; 3]>) {
        let dim = self.dim();
        out.clear();
        // Component by component: a slice copy of 2 or 3 values is a call to memmove, which
        // was 4 % of a grain run.
        out.extend(self.element(e).iter().map(|&n| {
            let mut d = [0.0; 3];
            for (i, di) in d.iter_mut().enumerate().take(dim) {
                *di = u[n as usize * dim + i];
            }
            d
        }));
    }
    /// Adds the set `all` and sorts and deduplicates every set.
    pub(crate) fn finish_sets(&mut self) {
        self.node_sets.insert("all".into(), (0..self.nodes.len() as u32).collect());
        for set in self.node_sets.values_mut() {
            set.sort_unstable();
            set.dedup();
        }
    }
    /// Smallest edge length over all elements (a length scale for tolerances).
    pub fn min_edge_length(&self) -> Real {
        let mut h = Real::INFINITY;
        for e in 0..self.element_count() {
            let nodes = self.element(e);
            for (a, &i) in nodes.iter().enumerate() {
                for &j in &nodes[a + 1..] {
                    let (p, q) = (self.nodes[i as usize], self.nodes[j as usize]);
                    let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                    h = h.min(d);
                }
            }
        }
        h
    }
}
