//! Blatz-Ko foam rubber, paper eqs. (2)-(3):
//! `W = G/2 (I2/I3 + 2 sqrt(I3) - 5)`, `S = G (sqrt(I3) C⁻¹ - C⁻²)`, `C = 2E + I`.

use super::registry::{number, Law, Parameter, Parameters};
use super::tensor::{odot, outer, right_cauchy_green, Mat3, Tangent};
use super::Hyperelastic;
use crate::precision::Real;

#[derive(Debug, Clone, PartialEq)]
pub struct BlatzKo {
    /// Shear modulus G.
    pub g: Real,
}

impl Hyperelastic for BlatzKo {
    fn energy(&self, e: &Mat3) -> Real {
        let c = right_cauchy_green(e);
        let i3 = c.determinant();
        // I2 = ((tr C)² - tr(C²)) / 2
        let i2 = 0.5 * (c.trace().powi(2) - (c * c).trace());
        0.5 * self.g * (i2 / i3 + 2.0 * i3.sqrt() - 5.0)
    }

    fn stress(&self, e: &Mat3) -> Mat3 {
        let (j, ci, ci2) = inverse_powers(e);
        (ci * j - ci2) * self.g
    }

    /// `dS/dE = 2 dS/dC = 2G [ J/2 C⁻¹⊗C⁻¹ - J C⁻¹⊙C⁻¹ + C⁻¹⊙C⁻² + C⁻²⊙C⁻¹ ]`.
    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        let (j, ci, ci2) = inverse_powers(e);
        let d = (outer(&ci, &ci) * (0.5 * j) - odot(&ci, &ci) * j + odot(&ci, &ci2) + odot(&ci2, &ci)) * (2.0 * self.g);
        ((ci * j - ci2) * self.g, d)
    }
}

impl Law for BlatzKo {
    const NAME: &'static str = "blatz_ko";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("G")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_blatz_ko.wgsl");
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("G", &[1000.0])];
    // Stress alone: C, C⁻¹ by cofactors, √det C, C⁻², their combination.
    const FLOPS: (f64, f64, f64) = (600.0, 150.0, 80.0);

    fn from_parameters(p: &Parameters) -> Self {
        Self { g: number(p, "G") }
    }
    fn gpu_parameters(&self) -> [Real; 8] {
        [self.g, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    }
    /// The Blatz-Ko foam's small-strain Poisson ratio is 1/4: K = 5G/3.
    fn bulk_shear(&self) -> (Real, Real) {
        (5.0 * self.g / 3.0, self.g)
    }
}

/// `J = √det C`, `C⁻¹` and `C⁻²`: what the stress and the tangent share.
fn inverse_powers(e: &Mat3) -> (Real, Mat3, Mat3) {
    let c = right_cauchy_green(e);
    let j = c.determinant().sqrt();
    let ci = c.try_inverse().unwrap_or_else(|| Mat3::from_element(Real::NAN));
    (j, ci, ci * ci)
}
