//! F-bar patches of an unstructured simplex mesh (a Gmsh file, a polygon's fan): neighbouring
//! triangles or tetrahedra grouped so that each group shares one volume change (de Souza Neto,
//! Pires and Owen 2005). A mesh from a generator has its cells for patches
//! ([`super::ReferenceGeometry::simplex_patches`]); this groups any other one.
//!
//! A patch is laid out as a cell of the kind the F-bar kernels already run (Quad4 for
//! triangles, Hex8 for tetrahedra): at most 4 or 8 nodes, one simplex per quadrature point. The
//! kernels, their WGSL twins and the assembly then take it unchanged.

use crate::mesh::{ElementKind, Mesh};
use std::collections::HashMap;

const NONE: u32 = u32::MAX;

/// The patches of a simplex mesh, and where each simplex went.
#[derive(Debug, Clone)]
pub struct Patches {
    /// The patches as cells (Quad4 for Tri3, Hex8 for Tet4). A patch with fewer nodes than its
    /// cell repeats its first node; the repeats have no gradient in any simplex, so they add
    /// nothing. The nodes are the simplex mesh's at set-up (their count and positions order
    /// the factorisation; the kernels read only the connectivity).
    pub cells: Mesh,
    /// Per simplex of the mesh, `patch * points_per_cell + point`: its patch and the quadrature
    /// point that stands for it.
    pub slots: Vec<u32>,
    pub points_per_cell: usize,
}

impl Patches {
    /// Groups face-neighbouring simplices greedily: from each simplex not yet taken (those with
    /// one free neighbour left first), a patch grows by the free neighbour that adds the fewest
    /// nodes (then the one with the fewest free neighbours of its own, so that none is
    /// stranded), while the patch fits its cell: 4 nodes and 2 triangles, or 8 nodes and 8
    /// tetrahedra.
    pub fn group(mesh: &Mesh) -> Self {
        let (cell_kind, simplices_per_cell) = match mesh.kind {
            ElementKind::Tri3 => (ElementKind::Quad4, 2),
            ElementKind::Tet4 => (ElementKind::Hex8, 8),
            other => panic!("patches group simplices, not {}", other.name()),
        };
        let points_per_cell = super::shape::quadrature(cell_kind).len();
        let max_nodes = cell_kind.nodes();
        let neighbours = face_neighbours(mesh);
        let count = mesh.element_count();
        let mut patch_of = vec![NONE; count];
        let mut slots = vec![0u32; count];
        let mut connectivity = Vec::with_capacity(count * max_nodes / 2);
        let mut patches = 0u32;
        let free_degree = |e: usize, patch_of: &[u32]| neighbours[e].iter().filter(|&&m| m != NONE && patch_of[m as usize] == NONE).count();
        // Seeds: simplices left with at most one free neighbour first (they would be stranded
        // next), then the mesh's order.
        let mut urgent: Vec<usize> = (0..count).filter(|&e| free_degree(e, &patch_of) <= 1).collect();
        urgent.reverse();
        let mut next = 0;
        loop {
            let seed = match urgent.pop() {
                Some(e) => e,
                None => {
                    while next < count && patch_of[next] != NONE {
                        next += 1;
                    }
                    if next == count {
                        break;
                    }
                    next
                }
            };
            if patch_of[seed] != NONE {
                continue;
            }
            let mut members = vec![seed];
            let mut nodes: Vec<u32> = mesh.element(seed).to_vec();
            patch_of[seed] = patches;
            while members.len() < simplices_per_cell {
                let best = members
                    .iter()
                    .flat_map(|&m| neighbours[m].iter().copied())
                    .filter(|&c| c != NONE && patch_of[c as usize] == NONE)
                    .map(|c| {
                        let added = mesh.element(c as usize).iter().filter(|n| !nodes.contains(n)).count();
                        (added, free_degree(c as usize, &patch_of), c)
                    })
                    .filter(|&(added, _, _)| nodes.len() + added <= max_nodes)
                    .min();
                let Some((_, _, c)) = best else { break };
                for &n in mesh.element(c as usize) {
                    if !nodes.contains(&n) {
                        nodes.push(n);
                    }
                }
                patch_of[c as usize] = patches;
                members.push(c as usize);
            }
            for (point, &m) in members.iter().enumerate() {
                slots[m] = patches * points_per_cell as u32 + point as u32;
            }
            for &m in &members {
                for &c in &neighbours[m] {
                    if c != NONE && patch_of[c as usize] == NONE && free_degree(c as usize, &patch_of) == 1 {
                        urgent.push(c as usize);
                    }
                }
            }
            let first = nodes[0];
            nodes.resize(max_nodes, first);
            connectivity.extend_from_slice(&nodes);
            patches += 1;
        }
        let cells = Mesh { kind: cell_kind, nodes: mesh.nodes.clone(), connectivity, node_sets: Default::default() };
        Self { cells, slots, points_per_cell }
    }

    /// The patch of simplex `e` and the point that stands for it.
    pub fn slot(&self, e: usize) -> (usize, usize) {
        let s = self.slots[e] as usize;
        (s / self.points_per_cell, s % self.points_per_cell)
    }
}

/// Per simplex, the simplices across each of its faces (`NONE` on the boundary).
fn face_neighbours(mesh: &Mesh) -> Vec<[u32; 4]> {
    let k = mesh.kind.nodes();
    let mut neighbours = vec![[NONE; 4]; mesh.element_count()];
    let mut open: HashMap<[u32; 3], (u32, usize)> = HashMap::with_capacity(mesh.element_count() * 2);
    for e in 0..mesh.element_count() {
        let nodes = mesh.element(e);
        for opposite in 0..k {
            let mut face = [NONE; 3];
            for (slot, &n) in face.iter_mut().zip(nodes.iter().enumerate().filter(|&(i, _)| i != opposite).map(|(_, n)| n)) {
                *slot = n;
            }
            face.sort_unstable();
            match open.remove(&face) {
                Some((other, their)) => {
                    neighbours[e][opposite] = other;
                    neighbours[other as usize][their] = e as u32;
                }
                None => {
                    open.insert(face, (e as u32, opposite));
                }
            }
        }
    }
    neighbours
}
