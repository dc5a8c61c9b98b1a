//! Decoupled hyperelasticity, the form of the rubber models fitted to test data:
//! `W = Ŵ(Ī₁, Ī₂) + U(J)`, `Ī₁ = J^(-2/3) I₁`, `Ī₂ = J^(-4/3) I₂`, `U = K/2 (ln J)²` (so that
//! `U''(1) = K`). A model gives only `Ŵ` and its derivatives ([`IsochoricLaw`]); the stress and
//! tangent follow through the invariants `(I₁, I₂, I₃)` of C, with `Vᵢ = ∂Iᵢ/∂C`
//! (`V₁ = I`, `V₂ = I₁ I - C`, `V₃ = I₃ C⁻¹`):
//! `S = 2 Σ Wᵢ Vᵢ`,
//! `dS/dE = 4 [Σ Wᵢⱼ Vᵢ⊗Vⱼ + W₂ (I⊗I - 𝕀) + W₃ I₃ (C⁻¹⊗C⁻¹ - C⁻¹⊙C⁻¹)]`.
//! GPU twin: `shaders/include/decoupled.wgsl`.

use super::tensor::{identity4, odot, outer, right_cauchy_green, Mat3, Tangent};
use super::Hyperelastic;
use crate::precision::Real;

/// First and second derivatives of `Ŵ` in `(Ī₁, Ī₂)`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Isochoric {
    pub d1: Real,
    pub d2: Real,
    pub d11: Real,
    pub d12: Real,
    pub d22: Real,
}

/// The isochoric energy `Ŵ(Ī₁, Ī₂)` of a decoupled model.
pub trait IsochoricLaw {
    fn energy(&self, i1: Real, i2: Real) -> Real;
    fn derivatives(&self, i1: Real, i2: Real) -> Isochoric;
    /// Small-strain shear modulus, `2 (Ŵ₁ + Ŵ₂)` at `Ī₁ = Ī₂ = 3`.
    fn shear_modulus(&self) -> Real {
        let d = self.derivatives(3.0, 3.0);
        2.0 * (d.d1 + d.d2)
    }
}

/// A decoupled model: an isochoric law and the bulk modulus of `U = K/2 (ln J)²`.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoupled<L> {
    pub law: L,
    pub k: Real,
}

/// What the stress and the tangent share at one strain.
struct Kinematics {
    c: Mat3,
    ci: Mat3,
    i1: Real,
    i3: Real,
    /// `J^(-2/3)` and `J^(-4/3)`.
    a: Real,
    b: Real,
    /// `Ī₁`, `Ī₂`.
    i1b: Real,
    i2b: Real,
    ln_i3: Real,
}

fn kinematics(e: &Mat3) -> Kinematics {
    let c = right_cauchy_green(e);
    let i1 = c.trace();
    let i2 = 0.5 * (i1 * i1 - (c * c).trace());
    let i3 = c.determinant();
    let a = 1.0 / i3.cbrt();
    let b = a * a;
    Kinematics { c, ci: c.try_inverse().unwrap_or_else(|| Mat3::from_element(Real::NAN)), i1, i3, a, b, i1b: a * i1, i2b: b * i2, ln_i3: i3.ln() }
}

impl<L: IsochoricLaw> Decoupled<L> {
    /// `Wᵢ`, the derivatives of W in `(I₁, I₂, I₃)`, and the isochoric derivatives.
    fn first(&self, k: &Kinematics) -> ([Real; 3], Isochoric) {
        let d = self.law.derivatives(k.i1b, k.i2b);
        // ∂Ī₁/∂I₃ and ∂Ī₂/∂I₃; U = K/8 (ln I₃)² in I₃.
        let (p, q) = (-k.i1b / (3.0 * k.i3), -2.0 * k.i2b / (3.0 * k.i3));
        let u1 = self.k * k.ln_i3 / (4.0 * k.i3);
        ([d.d1 * k.a, d.d2 * k.b, d.d1 * p + d.d2 * q + u1], d)
    }

    fn stress_of(&self, k: &Kinematics, w: &[Real; 3]) -> Mat3 {
        (Mat3::identity() * (w[0] + w[1] * k.i1) - k.c * w[1] + k.ci * (w[2] * k.i3)) * 2.0
    }
}

impl<L: IsochoricLaw> Hyperelastic for Decoupled<L> {
    fn energy(&self, e: &Mat3) -> Real {
        let k = kinematics(e);
        self.law.energy(k.i1b, k.i2b) + self.k / 8.0 * k.ln_i3 * k.ln_i3
    }

    fn stress(&self, e: &Mat3) -> Mat3 {
        let k = kinematics(e);
        let (w, _) = self.first(&k);
        self.stress_of(&k, &w)
    }

    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        let k = kinematics(e);
        let (w, d) = self.first(&k);
        let i3 = k.i3;
        let (p, q) = (-k.i1b / (3.0 * i3), -2.0 * k.i2b / (3.0 * i3));
        // ∂a/∂I₃, ∂b/∂I₃; I₁ ∂²a/∂I₃², I₂ ∂²b/∂I₃²; ∂²U/∂I₃².
        let (da, db) = (-k.a / (3.0 * i3), -2.0 * k.b / (3.0 * i3));
        let (i1_dda, i2_ddb) = (4.0 * k.i1b / (9.0 * i3 * i3), 10.0 * k.i2b / (9.0 * i3 * i3));
        let u2 = self.k * (1.0 - k.ln_i3) / (4.0 * i3 * i3);
        let w11 = d.d11 * k.a * k.a;
        let w12 = d.d12 * k.a * k.b;
        let w22 = d.d22 * k.b * k.b;
        let w13 = k.a * (d.d11 * p + d.d12 * q) + d.d1 * da;
        let w23 = k.b * (d.d12 * p + d.d22 * q) + d.d2 * db;
        let w33 = d.d11 * p * p + 2.0 * d.d12 * p * q + d.d22 * q * q + d.d1 * i1_dda + d.d2 * i2_ddb + u2;
        let v1 = Mat3::identity();
        let v2 = v1 * k.i1 - k.c;
        let v3 = k.ci * i3;
        let mut t = outer(&v1, &v1) * (w11 + w[1]) - identity4() * w[1] + outer(&v2, &v2) * w22 + outer(&v3, &v3) * w33;
        t += (outer(&v1, &v2) + outer(&v2, &v1)) * w12 + (outer(&v1, &v3) + outer(&v3, &v1)) * w13 + (outer(&v2, &v3) + outer(&v3, &v2)) * w23;
        t += (outer(&k.ci, &k.ci) - odot(&k.ci, &k.ci)) * (w[2] * i3);
        (self.stress_of(&k, &w), t * 4.0)
    }
}
