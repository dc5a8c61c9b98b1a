//! Compressible Neo-Hookean:
//! `W = G/2 (tr C - 3) - G ln J + λ/2 (ln J)²`, `λ = K - 2G/3`.

use super::registry::{number, Law, Parameter, Parameters};
use super::tensor::{odot, outer, right_cauchy_green, Mat3, Tangent};
use super::Hyperelastic;
use crate::precision::Real;

#[derive(Debug, Clone, PartialEq)]
pub struct NeoHookean {
    /// Shear modulus G.
    pub g: Real,
    /// Bulk modulus K.
    pub k: Real,
}

impl NeoHookean {
    fn lambda(&self) -> Real {
        self.k - 2.0 * self.g / 3.0
    }
}

impl Hyperelastic for NeoHookean {
    fn energy(&self, e: &Mat3) -> Real {
        let c = right_cauchy_green(e);
        let ln_j = 0.5 * c.determinant().ln();
        0.5 * self.g * (c.trace() - 3.0) - self.g * ln_j + 0.5 * self.lambda() * ln_j * ln_j
    }

    fn stress(&self, e: &Mat3) -> Mat3 {
        let (ln_j, ci) = log_volume_and_inverse(e);
        (Mat3::identity() - ci) * self.g + ci * (self.lambda() * ln_j)
    }

    /// `dS/dE = λ C⁻¹⊗C⁻¹ + 2(G - λ ln J) C⁻¹⊙C⁻¹`.
    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        let (ln_j, ci) = log_volume_and_inverse(e);
        let d = outer(&ci, &ci) * self.lambda() + odot(&ci, &ci) * (2.0 * (self.g - self.lambda() * ln_j));
        ((Mat3::identity() - ci) * self.g + ci * (self.lambda() * ln_j), d)
    }
}

impl Law for NeoHookean {
    const NAME: &'static str = "neo_hookean";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("G"), Parameter::modulus("K")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_neo_hookean.wgsl");
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("G", &[1000.0]), ("K", &[3000.0])];
    const FLOPS: (f64, f64, f64) = (350.0, 140.0, 110.0);

    fn from_parameters(p: &Parameters) -> Self {
        Self { g: number(p, "G"), k: number(p, "K") }
    }
    fn gpu_parameters(&self) -> [Real; 8] {
        [self.g, self.k, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        (self.k, self.g)
    }
}

/// `ln J` and `C⁻¹`: what the stress and the tangent share.
fn log_volume_and_inverse(e: &Mat3) -> (Real, Mat3) {
    let c = right_cauchy_green(e);
    let ln_j = 0.5 * c.determinant().ln();
    (ln_j, c.try_inverse().unwrap_or_else(|| Mat3::from_element(Real::NAN)))
}
