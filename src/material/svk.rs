//! Saint Venant-Kirchhoff: Hooke's law on the Green-Lagrange strain,
//! `W = λ/2 (tr E)² + μ tr(E²)`, `S = λ tr(E) I + 2μ E`, `dS/dE = λ I⊗I + 2μ I⊙I`, with
//! `λ = Eν/((1+ν)(1-2ν))`, `μ = E/(2(1+ν))` from Young's modulus and Poisson's ratio. The
//! classic model to compare against: exact at small strain, but it softens in compression
//! (its stress vanishes again as J -> 0), so it suits moderate strains only.

use super::registry::{number, Law, Parameter, Parameters, Rejected};
use super::tensor::{odot, outer, Mat3, Tangent};
use super::Hyperelastic;
use crate::precision::Real;

#[derive(Debug, Clone, PartialEq)]
pub struct Svk {
    /// Young's modulus.
    pub e: Real,
    /// Poisson's ratio.
    pub nu: Real,
}

impl Svk {
    /// Lamé's `(λ, μ)`.
    pub fn lame(&self) -> (Real, Real) {
        let (e, nu) = (self.e, self.nu);
        (e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), e / (2.0 * (1.0 + nu)))
    }
}

impl Hyperelastic for Svk {
    fn energy(&self, e: &Mat3) -> Real {
        let (lambda, mu) = self.lame();
        let t = e.trace();
        0.5 * lambda * t * t + mu * (e * e).trace()
    }

    fn stress(&self, e: &Mat3) -> Mat3 {
        let (lambda, mu) = self.lame();
        Mat3::identity() * (lambda * e.trace()) + e * (2.0 * mu)
    }

    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        let (lambda, mu) = self.lame();
        let i = Mat3::identity();
        (self.stress(e), outer(&i, &i) * lambda + odot(&i, &i) * (2.0 * mu))
    }
}

impl Law for Svk {
    const NAME: &'static str = "svk";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("E"), Parameter::number("nu")];
    const BULK: &'static str = "nu";
    const WGSL: &'static str = include_str!("../../shaders/include/material_svk.wgsl");
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("E", &[2600.0]), ("nu", &[0.3])];
    // The stress: a trace and a scaled sum; the tangent two constant 6x6 terms.
    const FLOPS: (f64, f64, f64) = (200.0, 30.0, 30.0);

    fn from_parameters(p: &Parameters) -> Self {
        Self { e: number(p, "E"), nu: number(p, "nu") }
    }
    /// A positive-definite law: `-1 < ν < 1/2` (positive shear and bulk moduli).
    fn check(p: &Parameters) -> Result<(), Rejected> {
        let nu = number(p, "nu");
        if !(nu > -1.0 && nu < 0.5) {
            return Err(Rejected { parameter: "nu".into(), message: format!("Poisson's ratio must lie in (-1, 1/2) (got {nu}): at 1/2 the bulk modulus is infinite, at -1 the shear modulus.") });
        }
        Ok(())
    }
    /// G, K, then λ in a1.
    fn gpu_parameters(&self) -> [Real; 8] {
        let (k, g) = self.bulk_shear();
        [g, k, self.lame().0, 0.0, 0.0, 0.0, 0.0, 0.0]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        let (lambda, mu) = self.lame();
        (lambda + 2.0 * mu / 3.0, mu)
    }
}
