//! The per-element kernel: deformation gradient, stress and consistent tangent at each
//! quadrature point, integrated into the element force vector and stiffness matrix.

use super::fbar::{fbar_force_tangent, fbar_gradients};
use super::{Formulation, GaussPoint};
use crate::material::tensor::{green_lagrange, to_voigt, von_mises, Mat3, Tangent, VOIGT};
use crate::material::viscous::relaxed_stress_tangent;
use crate::material::{Hyperelastic, Relaxation};
use crate::precision::Real;
use nalgebra::Vector6;
use thiserror::Error;

#[derive(Debug, Error, Clone, Copy, PartialEq)]
pub enum ElementError {
    #[error("inverted element (det F = {0:.3e})")]
    Inverted(Real),
    #[error("non-finite stress or tangent")]
    NonFinite,
}

/// Element results in local ordering `(node a, component i) -> a * dim + i`.
#[derive(Debug, Clone, Default)]
pub struct ElementOutput {
    /// Internal force `f_int`.
    pub force: Vec<Real>,
    /// Tangent stiffness `d f_int / d u`, row-major, `(nen * dim)²` entries.
    pub tangent: Vec<Real>,
    /// Scratch: strain-displacement columns `B` and `D B`, reused across calls.
    b: Vec<Vector6<Real>>,
    db: Vec<Vector6<Real>>,
}

/// Deformation gradient `F = I + Σ_a u_a ⊗ dN_a/dX` at one quadrature point.
pub(super) fn deformation_gradient(gp: &GaussPoint, u: &[[Real; 3]]) -> Mat3 {
    let mut f = Mat3::identity();
    for (ua, g) in u.iter().zip(&gp.dn_dx) {
        for i in 0..3 {
            for k in 0..3 {
                f[(i, k)] += ua[i] * g[k];
            }
        }
    }
    f
}

/// The gradient each quadrature point's stress sees: `F`, or `F̄` of the F-bar element.
pub fn point_gradients(points: &[GaussPoint], u: &[[Real; 3]], dim: usize, formulation: Formulation) -> Vec<Mat3> {
    match formulation {
        Formulation::Displacement => points.iter().map(|gp| deformation_gradient(gp, u)).collect(),
        Formulation::Fbar => fbar_gradients(points, u, dim),
    }
}

/// Internal force and tangent stiffness of one element; `u` holds its nodal displacements and
/// `relaxation` the viscoelastic history of its points, if its material has a Prony series.
#[allow(clippy::too_many_arguments)]
pub fn element_force_tangent<M: Hyperelastic>(material: &M, points: &[GaussPoint], u: &[[Real; 3]], dim: usize, formulation: Formulation, relaxation: Option<Relaxation>, with_tangent: bool, out: &mut ElementOutput) -> Result<(), ElementError> {
    if formulation == Formulation::Fbar {
        return fbar_force_tangent(material, points, u, dim, relaxation, with_tangent, out);
    }
    let nen = u.len();
    let ndof = nen * dim;
    out.force.clear();
    out.force.resize(ndof, 0.0);
    out.tangent.clear();
    if with_tangent {
        out.tangent.resize(ndof * ndof, 0.0);
    }
    out.b.resize(ndof, Vector6::zeros());
    out.db.resize(ndof, Vector6::zeros());
    for (q, gp) in points.iter().enumerate() {
        let f = deformation_gradient(gp, u);
        checked_determinant(&f)?;
        let e = green_lagrange(&f);
        let (s, d) = point_stress_tangent(material, &e, relaxation.map(|r| (r.c, r.point(q))), with_tangent);
        let fs = f * s;
        for (a, g) in gp.dn_dx.iter().enumerate() {
            for i in 0..dim {
                out.force[a * dim + i] += gp.dv * (fs[(i, 0)] * g[0] + fs[(i, 1)] * g[1] + fs[(i, 2)] * g[2]);
            }
        }
        let Some(d) = d else { continue };
        if !d.iter().all(|v| v.is_finite()) {
            return Err(ElementError::NonFinite);
        }
        // Nonlinear strain-displacement operator, engineering shear components.
        for (a, g) in gp.dn_dx.iter().enumerate() {
            for i in 0..dim {
                out.b[a * dim + i] = Vector6::from_fn(|r, _| {
                    let (k, l) = VOIGT[r];
                    if k == l {
                        f[(i, k)] * g[k]
                    } else {
                        f[(i, k)] * g[l] + f[(i, l)] * g[k]
                    }
                });
            }
        }
        // The quadrature weight is folded into `D B` and `S`, once per point.
        for (db, b) in out.db.iter_mut().zip(&out.b) {
            *db = d * b * gp.dv;
        }
        let s_dv = s * gp.dv;
        // The tangent is symmetric: only its upper triangle (row <= col) is integrated.
        for col in 0..ndof {
            let (bn, j) = (col / dim, col % dim);
            let gb = &gp.dn_dx[bn];
            let sgb = s_dv * nalgebra::Vector3::new(gb[0], gb[1], gb[2]);
            for row in 0..=col {
                let mut k = out.b[row].dot(&out.db[col]);
                if row % dim == j {
                    let ga = &gp.dn_dx[row / dim];
                    k += sgb[0] * ga[0] + sgb[1] * ga[1] + sgb[2] * ga[2];
                }
                out.tangent[row * ndof + col] += k;
            }
        }
    }
    finish(out, ndof, with_tangent)
}

/// The stress and (if wanted) the tangent at one point, from one material call, relaxed by the
/// step's viscoelastic `(c, H)` of the point if there is one.
pub(super) fn point_stress_tangent<M: Hyperelastic>(material: &M, e: &Mat3, relaxation: Option<(Real, &[Real])>, with_tangent: bool) -> (Mat3, Option<Tangent>) {
    let (s, d) = if with_tangent {
        let (s, d) = material.stress_tangent(e);
        (s, Some(d))
    } else {
        (material.stress(e), None)
    };
    match relaxation {
        Some((c, h)) => relaxed_stress_tangent(&s, d.as_ref(), e, c, h),
        None => (s, d),
    }
}

/// Fills the lower triangle of the tangent from its integrated upper one, and rejects a
/// non-finite force.
pub(super) fn finish(out: &mut ElementOutput, ndof: usize, with_tangent: bool) -> Result<(), ElementError> {
    if with_tangent {
        for col in 0..ndof {
            for row in col + 1..ndof {
                out.tangent[row * ndof + col] = out.tangent[col * ndof + row];
            }
        }
    }
    if !out.force.iter().all(|v| v.is_finite()) {
        return Err(ElementError::NonFinite);
    }
    Ok(())
}

/// `det F`, or why the point fails: a state that is not finite is not an inverted element.
pub(super) fn checked_determinant(f: &Mat3) -> Result<Real, ElementError> {
    let det = f.determinant();
    if det.is_nan() {
        return Err(ElementError::NonFinite);
    }
    if det.is_nan() || det <= 0.0 {
        return Err(ElementError::Inverted(det));
    }
    Ok(det)
}

/// Strain energy of one element.
pub fn element_energy<M: Hyperelastic>(material: &M, points: &[GaussPoint], u: &[[Real; 3]], dim: usize, formulation: Formulation) -> Real {
    match formulation {
        Formulation::Displacement => points.iter().map(|gp| gp.dv * material.energy(&green_lagrange(&deformation_gradient(gp, u)))).sum(),
        Formulation::Fbar => points.iter().zip(fbar_gradients(points, u, dim)).map(|(gp, f)| gp.dv * material.energy(&green_lagrange(&f))).sum(),
    }
}

/// Volume-averaged von Mises stress of the Cauchy stress over the element's quadrature points.
pub fn element_von_mises<M: Hyperelastic>(material: &M, points: &[GaussPoint], u: &[[Real; 3]], dim: usize, formulation: Formulation) -> Real {
    let (mut sum, mut vol) = (0.0, 0.0);
    for (gp, f) in points.iter().zip(point_gradients(points, u, dim, formulation)) {
        let s = material.stress(&green_lagrange(&f));
        sum += gp.dv * von_mises(&f, &s);
        vol += gp.dv;
    }
    sum / vol
}

/// Volume averages over one element of the quantities written for viewing (VTU cell data,
/// colours of the 3D view).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellFields {
    /// Cauchy stress `σ = F S Fᵀ / J`, row-major 3×3.
    pub cauchy: [Real; 9],
    pub von_mises: Real,
    /// Volume ratio `J = det F`.
    pub jacobian: Real,
}

/// Volume-averaged Cauchy stress, von Mises stress and `J` of one element.
pub fn element_cell_fields<M: Hyperelastic>(material: &M, points: &[GaussPoint], u: &[[Real; 3]], dim: usize, formulation: Formulation) -> CellFields {
    let (mut cauchy, mut vm, mut jacobian, mut vol) = ([0.0; 9], 0.0, 0.0, 0.0);
    for (gp, f) in points.iter().zip(element_point_fields(material, points, u, dim, formulation)) {
        cauchy.iter_mut().zip(&f.cauchy).for_each(|(c, v)| *c += gp.dv * v);
        vm += gp.dv * f.von_mises;
        jacobian += gp.dv * f.jacobian;
        vol += gp.dv;
    }
    CellFields { cauchy: cauchy.map(|c| c / vol), von_mises: vm / vol, jacobian: jacobian / vol }
}

/// [`CellFields`] at each quadrature point of one element (each simplex of an F-bar patch).
pub fn element_point_fields<M: Hyperelastic>(material: &M, points: &[GaussPoint], u: &[[Real; 3]], dim: usize, formulation: Formulation) -> Vec<CellFields> {
    point_gradients(points, u, dim, formulation)
        .iter()
        .map(|f| {
            let s = material.stress(&green_lagrange(f));
            let j = f.determinant();
            let cauchy = f * s * f.transpose() / j;
            CellFields { cauchy: std::array::from_fn(|k| cauchy[(k / 3, k % 3)]), von_mises: von_mises(f, &s), jacobian: j }
        })
        .collect()
}

/// Second Piola-Kirchhoff stress at each quadrature point, Voigt order (for closed-form checks).
pub fn element_stresses<M: Hyperelastic>(material: &M, points: &[GaussPoint], u: &[[Real; 3]], dim: usize, formulation: Formulation) -> Vec<Vector6<Real>> {
    point_gradients(points, u, dim, formulation).iter().map(|f| to_voigt(&material.stress(&green_lagrange(f)))).collect()
}
