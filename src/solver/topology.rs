//! What a body's connectivity and prescribed dofs decide: the dof numbering, the stiffness
//! pattern, the gather map and the symbolic factorisation. Built once per distinct body and
//! shared (a packing of 100 000 grains has a handful of grain shapes): building them was most of
//! a packing's set-up, and holding one per grain most of its memory.

use super::body::Prescribed;
use super::linear::{CholeskySymbolic, LinearError};
use crate::assembly::{DofMap, GatherMap, StiffnessPattern};
use crate::mesh::{ElementKind, Mesh};
use crate::scene::OrderingChoice;
use std::sync::Arc;

#[derive(Clone)]
pub struct Topology {
    pub dofs: Arc<DofMap>,
    pub pattern: Arc<StiffnessPattern>,
    pub gather: Arc<GatherMap>,
    pub symbolic: Arc<CholeskySymbolic>,
}

/// Bodies with equal keys have equal topologies: the element kind, the connectivity and the
/// prescribed dofs.
pub type TopologyKey = (ElementKind, Vec<u32>, Vec<usize>);

impl Topology {
    pub fn new(mesh: &Mesh, prescribed: &[Prescribed], ordering: OrderingChoice) -> Result<Self, LinearError> {
        let dim = mesh.dim();
        let mut is_prescribed = vec![false; mesh.nodes.len() * dim];
        for p in prescribed {
            is_prescribed[p.dof] = true;
        }
        let dofs = DofMap::new(dim, &is_prescribed);
        let pattern = StiffnessPattern::new(mesh, &dofs);
        let coordinates: Vec<[crate::precision::Real; 3]> = dofs.free_pairs().map(|(d, _)| mesh.nodes[d / dim]).collect();
        let symbolic = CholeskySymbolic::new(&pattern, &coordinates, ordering)?;
        let gather = GatherMap::new(mesh, dim, &pattern);
        Ok(Self { dofs: Arc::new(dofs), pattern: Arc::new(pattern), gather: Arc::new(gather), symbolic: Arc::new(symbolic) })
    }

    /// The key under which the body may share its topology, or `None` when its symbolic
    /// factorisation depends on its node coordinates (nested dissection) and is its own.
    pub fn key(mesh: &Mesh, prescribed: &[Prescribed], ordering: OrderingChoice) -> Option<TopologyKey> {
        let mut fixed: Vec<usize> = prescribed.iter().map(|p| p.dof).collect();
        fixed.sort_unstable();
        fixed.dedup();
        let free = mesh.nodes.len() * mesh.dim() - fixed.len();
        CholeskySymbolic::pattern_only(free, ordering).then(|| (mesh.kind, mesh.connectivity.clone(), fixed))
    }
}
