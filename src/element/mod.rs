//! Total Lagrangian finite elements: reference geometry (computed once) and the per-element
//! kernel that evaluates internal force, tangent stiffness, strain energy and stresses.

mod fbar;
mod kernel;
mod patches;
pub mod shape;

pub use kernel::{element_cell_fields, element_energy, element_force_tangent, element_point_fields, element_stresses, element_von_mises, point_gradients, CellFields, ElementError, ElementOutput};
pub use patches::Patches;

use crate::mesh::{ElementKind, Mesh};
pub use crate::mesh::{CUBE_TETRAHEDRA, QUAD_TRIANGLES};
use crate::precision::Real;
use nalgebra::Matrix3;
use thiserror::Error;

/// How an element's volume change enters its energy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Formulation {
    /// Every quadrature point's own `F` (locks when `K/G` is large).
    #[default]
    Displacement,
    /// `F̄`: the element's mean dilatation with each point's distortion (`fbar.rs`); Quad4 and
    /// Hex8, the cells of generated Tri3 and Tet4 meshes ([`ReferenceGeometry::simplex_patches`]),
    /// and patches of other simplices ([`Patches`]).
    Fbar,
}

/// Above this small-strain K/G (Poisson's ratio 0.45), a body's `auto` formulation is F-bar
/// (simplices as patches): below it the displacement element's volumetric stiffening is under the
/// discretisation error (doc/results.md, "Nearly incompressible rubber").
pub const FBAR_ABOVE_K_OVER_G: Real = 10.0;

impl Formulation {
    /// Whether F-bar applies to an element kind of its own: it needs more than one quadrature
    /// point (simplices take it on the cells they split, or on [`Patches`]).
    pub fn fbar_applies(kind: ElementKind) -> bool {
        matches!(kind, ElementKind::Quad4 | ElementKind::Hex8)
    }

    pub fn name(self) -> &'static str {
        match self {
            Formulation::Displacement => "displacement",
            Formulation::Fbar => "fbar",
        }
    }
}

const CUBE_TETRAHEDRA_SLICES: [&[usize]; 6] = [&CUBE_TETRAHEDRA[0], &CUBE_TETRAHEDRA[1], &CUBE_TETRAHEDRA[2], &CUBE_TETRAHEDRA[3], &CUBE_TETRAHEDRA[4], &CUBE_TETRAHEDRA[5]];

/// Reference-configuration data of one quadrature point.
#[derive(Debug, Clone)]
pub struct GaussPoint {
    /// `dN_a/dX` for each node (z component 0 in 2D).
    pub dn_dx: Vec<[Real; 3]>,
    /// Quadrature weight times reference Jacobian determinant (volume, or area per unit thickness).
    pub dv: Real,
}

/// Reference geometry of every element of a mesh, with the lumped nodal masses.
#[derive(Debug, Clone)]
pub struct ReferenceGeometry {
    pub kind: ElementKind,
    /// `quadrature points per element` entries per element, flattened.
    pub points: Vec<GaussPoint>,
    pub points_per_element: usize,
    /// Reference volume of each element.
    pub volumes: Vec<Real>,
    /// Each element is an F-bar patch whose points are simplices (a point's gradients are
    /// non-zero at its simplex's nodes only).
    pub patched: bool,
}

#[derive(Debug, Error)]
#[error("element {element} is {what} in the reference configuration (Jacobian determinant {det:.3e})")]
pub struct BadReferenceElement {
    pub element: usize,
    pub what: &'static str,
    pub det: Real,
}

impl ReferenceGeometry {
    /// Computes shape-function gradients; rejects inverted or degenerate elements.
    pub fn new(mesh: &Mesh) -> Result<Self, BadReferenceElement> {
        let kind = mesh.kind;
        let dim = kind.dim();
        let rule = shape::quadrature(kind);
        let scale = mesh.min_edge_length().max(Real::MIN_POSITIVE).powi(dim as i32);
        let mut points = Vec::with_capacity(rule.len() * mesh.element_count());
        let mut volumes = Vec::with_capacity(mesh.element_count());
        for e in 0..mesh.element_count() {
            let nodes = mesh.element(e);
            let mut volume = 0.0;
            for qp in &rule {
                let dn_dxi = shape::gradients(kind, qp.xi);
                let mut jac = Matrix3::<Real>::identity();
                for r in 0..dim {
                    for c in 0..dim {
                        jac[(r, c)] = nodes.iter().zip(&dn_dxi).map(|(&n, g)| mesh.nodes[n as usize][r] * g[c]).sum();
                    }
                }
                let det = jac.determinant();
                if det.is_nan() || det <= 1e-10 * scale {
                    let what = if det < 0.0 { "inverted" } else { "degenerate" };
                    return Err(BadReferenceElement { element: e, what, det });
                }
                let inv_t = jac.try_inverse().expect("non-singular").transpose();
                let dn_dx = dn_dxi
                    .iter()
                    .map(|g| {
                        let v = inv_t * nalgebra::Vector3::new(g[0], g[1], g[2]);
                        [v[0], v[1], if dim == 3 { v[2] } else { 0.0 }]
                    })
                    .collect();
                let dv = qp.weight * det;
                volume += dv;
                points.push(GaussPoint { dn_dx, dv });
            }
            volumes.push(volume);
        }
        Ok(Self { kind, points, points_per_element: rule.len(), volumes, patched: false })
    }

    pub fn element_points(&self, e: usize) -> &[GaussPoint] {
        &self.points[e * self.points_per_element..(e + 1) * self.points_per_element]
    }

    /// Row-sum lumped nodal masses `m_a = ρ ∫ N_a dV` (the row sums of the consistent mass;
    /// positive for all four linear elements).
    pub fn lumped_masses(&self, mesh: &Mesh, density: Real) -> Vec<Real> {
        let values: Vec<Vec<Real>> = shape::quadrature(self.kind).iter().map(|qp| shape::values(self.kind, qp.xi)).collect();
        let mut m = vec![0.0; mesh.nodes.len()];
        for e in 0..mesh.element_count() {
            let nodes = mesh.element(e);
            match self.patched {
                // A linear simplex integrates each of its shape functions to its volume over its
                // node count.
                true => {
                    for gp in self.element_points(e) {
                        let simplex_nodes = gp.dn_dx.iter().filter(|g| g.iter().any(|&c| c != 0.0)).count();
                        for (&node, g) in nodes.iter().zip(&gp.dn_dx) {
                            if g.iter().any(|&c| c != 0.0) {
                                m[node as usize] += density * gp.dv / simplex_nodes as Real;
                            }
                        }
                    }
                }
                false => {
                    for (gp, n) in self.element_points(e).iter().zip(&values) {
                        for (&node, na) in nodes.iter().zip(n) {
                            m[node as usize] += density * na * gp.dv;
                        }
                    }
                }
            }
        }
        m
    }

    /// The geometry of a Quad4 or Hex8 mesh whose cells are patches of the simplices they split
    /// into (two triangles, six Kuhn tetrahedra: [`QUAD_TRIANGLES`], [`CUBE_TETRAHEDRA`], the
    /// generators' splits): each "quadrature point" is one simplex, its constant gradients
    /// over the cell's nodes and its volume; the cell's remaining points have no volume. The
    /// kernels then compute the Tri3 or Tet4 body exactly, and F-bar on it averages the volume
    /// change over each patch (de Souza Neto, Pires and Owen 2005, "F-bar-based linear
    /// triangles and tetrahedra").
    pub fn simplex_patches(mesh: &Mesh) -> Result<Self, BadReferenceElement> {
        let (kind, split): (ElementKind, &[&[usize]]) = match mesh.kind {
            ElementKind::Quad4 => (ElementKind::Tri3, &[&QUAD_TRIANGLES[0], &QUAD_TRIANGLES[1]]),
            ElementKind::Hex8 => (ElementKind::Tet4, &CUBE_TETRAHEDRA_SLICES),
            other => panic!("simplex patches are cells of quad4 or hex8, not {}", other.name()),
        };
        let per_element = shape::quadrature(mesh.kind).len();
        let cell_nodes = mesh.kind.nodes();
        let mut points = Vec::with_capacity(per_element * mesh.element_count());
        let mut volumes = Vec::with_capacity(mesh.element_count());
        for e in 0..mesh.element_count() {
            let cell = mesh.element(e);
            let mut volume = 0.0;
            for local in split {
                let simplex = Mesh { kind, nodes: local.iter().map(|&a| mesh.nodes[cell[a] as usize]).collect(), connectivity: (0..local.len() as u32).collect(), node_sets: Default::default() };
                let one = Self::new(&simplex).map_err(|bad| BadReferenceElement { element: e, ..bad })?;
                let gp = &one.points[0];
                let mut dn_dx = vec![[0.0; 3]; cell_nodes];
                for (k, &a) in local.iter().enumerate() {
                    dn_dx[a] = gp.dn_dx[k];
                }
                volume += gp.dv;
                points.push(GaussPoint { dn_dx, dv: gp.dv });
            }
            for _ in split.len()..per_element {
                points.push(GaussPoint { dn_dx: vec![[0.0; 3]; cell_nodes], dv: 0.0 });
            }
            volumes.push(volume);
        }
        Ok(Self { kind: mesh.kind, points, points_per_element: per_element, volumes, patched: true })
    }

    /// The geometry of unstructured simplices grouped into [`Patches`], from the simplices' own
    /// geometry: each patch's points are its simplices' gradients on the patch's nodes.
    pub fn grouped(simplices: &Self, mesh: &Mesh, patches: &Patches) -> Self {
        let cells = &patches.cells;
        let cell_nodes = cells.kind.nodes();
        let per_cell = patches.points_per_cell;
        let mut points = vec![GaussPoint { dn_dx: vec![[0.0; 3]; cell_nodes], dv: 0.0 }; per_cell * cells.element_count()];
        let mut volumes = vec![0.0; cells.element_count()];
        for e in 0..mesh.element_count() {
            let (patch, point) = patches.slot(e);
            let cell = cells.element(patch);
            let gp = &simplices.element_points(e)[0];
            let target = &mut points[patch * per_cell + point];
            for (&node, g) in mesh.element(e).iter().zip(&gp.dn_dx) {
                let local = cell.iter().position(|&n| n == node).expect("a patch holds its simplices' nodes");
                target.dn_dx[local] = *g;
            }
            target.dv = gp.dv;
            volumes[patch] += gp.dv;
        }
        Self { kind: cells.kind, points, points_per_element: per_cell, volumes, patched: true }
    }
}
