//! Small symmetric-tensor helpers shared by the material models.
//!
//! Fourth-order tensors are stored as 6x6 Voigt matrices in the order
//! (11, 22, 33, 12, 23, 13). A tangent `D` maps the engineering strain vector
//! (E11, E22, E33, 2E12, 2E23, 2E13) to the stress vector (S11, S22, S33, S12, S23, S13),
//! so `D[I][J] = dS_ij / dE_kl` with (k, l) the representative index pair of J.

use crate::precision::Real;
use nalgebra::{Matrix3, Matrix6, Vector6};

/// Index pairs of the Voigt components.
pub const VOIGT: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2)];

pub type Mat3 = Matrix3<Real>;
pub type Tangent = Matrix6<Real>;

/// Symmetric second-order tensor to its Voigt stress vector.
pub fn to_voigt(a: &Mat3) -> Vector6<Real> {
    Vector6::from_fn(|i, _| a[VOIGT[i]])
}

/// `(A ⊗ B)_ijkl = A_ij B_kl`.
pub fn outer(a: &Mat3, b: &Mat3) -> Tangent {
    Tangent::from_fn(|i, j| a[VOIGT[i]] * b[VOIGT[j]])
}

/// The symmetrised product `½(A_ik B_jl + A_il B_jk)`, symmetrised again over (i, j) so that
/// `odot(A, B)` is the derivative pattern of `X ↦ A X B`-type terms with minor symmetries.
pub fn odot(a: &Mat3, b: &Mat3) -> Tangent {
    Tangent::from_fn(|r, c| {
        let (i, j) = VOIGT[r];
        let (k, l) = VOIGT[c];
        0.25 * (a[(i, k)] * b[(j, l)] + a[(i, l)] * b[(j, k)] + a[(j, k)] * b[(i, l)] + a[(j, l)] * b[(i, k)])
    })
}

/// Symmetric identity `I_sym = odot(I, I)`.
pub fn identity4() -> Tangent {
    odot(&Mat3::identity(), &Mat3::identity())
}

/// Deviatoric projector `P = I_sym - (I ⊗ I)/3`.
pub fn deviatoric_projector() -> Tangent {
    let i = Mat3::identity();
    identity4() - outer(&i, &i) / 3.0
}

/// Deviatoric part of a second-order tensor.
pub fn dev(a: &Mat3) -> Mat3 {
    a - Mat3::identity() * (a.trace() / 3.0)
}

/// Right Cauchy-Green tensor `C = I + 2E` of a Green-Lagrange strain.
pub fn right_cauchy_green(e: &Mat3) -> Mat3 {
    e * 2.0 + Mat3::identity()
}

/// Weight of each Voigt entry in a full contraction `A : B`: a shear entry stands for two.
pub const VOIGT_WEIGHT: [Real; 6] = [1.0, 1.0, 1.0, 2.0, 2.0, 2.0];

/// Green-Lagrange strain `E = (FᵀF - I)/2`.
pub fn green_lagrange(f: &Mat3) -> Mat3 {
    (f.transpose() * f - Mat3::identity()) * 0.5
}

/// von Mises equivalent of the Cauchy stress `σ = F S Fᵀ / J`.
pub fn von_mises(f: &Mat3, s: &Mat3) -> Real {
    let sigma = f * s * f.transpose() / f.determinant();
    let d = dev(&sigma);
    (1.5 * d.component_mul(&d).sum()).sqrt()
}
