//! The isochoric energies of the rubber models users fit to test data (doc/scene.md gives each
//! with its parameters and a published set). Each is a [`Decoupled`](super::Decoupled) model with
//! `U = K/2 (ln J)²`. GPU twins: `shaders/include/material_<name>.wgsl`.

use super::decoupled::{Decoupled, Isochoric, IsochoricLaw};
use super::registry::{number, Law, Parameter, Parameters, Rejected};
use crate::precision::Real;

/// Mooney-Rivlin: `Ŵ = C10 (Ī₁ - 3) + C01 (Ī₂ - 3)`, `G = 2 (C10 + C01)`.
#[derive(Debug, Clone, PartialEq)]
pub struct MooneyRivlin {
    pub c10: Real,
    pub c01: Real,
}

impl IsochoricLaw for MooneyRivlin {
    fn energy(&self, i1: Real, i2: Real) -> Real {
        self.c10 * (i1 - 3.0) + self.c01 * (i2 - 3.0)
    }
    fn derivatives(&self, _i1: Real, _i2: Real) -> Isochoric {
        Isochoric { d1: self.c10, d2: self.c01, ..Default::default() }
    }
}

/// Yeoh: `Ŵ = C10 (Ī₁ - 3) + C20 (Ī₁ - 3)² + C30 (Ī₁ - 3)³`, `G = 2 C10`.
#[derive(Debug, Clone, PartialEq)]
pub struct Yeoh {
    pub c10: Real,
    pub c20: Real,
    pub c30: Real,
}

impl IsochoricLaw for Yeoh {
    fn energy(&self, i1: Real, _i2: Real) -> Real {
        let x = i1 - 3.0;
        x * (self.c10 + x * (self.c20 + x * self.c30))
    }
    fn derivatives(&self, i1: Real, _i2: Real) -> Isochoric {
        let x = i1 - 3.0;
        Isochoric { d1: self.c10 + x * (2.0 * self.c20 + 3.0 * x * self.c30), d11: 2.0 * self.c20 + 6.0 * x * self.c30, ..Default::default() }
    }
}

/// Gent: `Ŵ = -(G Jm / 2) ln(1 - (Ī₁ - 3) / Jm)`, defined while `Ī₁ - 3 < Jm` (the chains'
/// limit); beyond, every value is `Real::MAX`, so that the element's stress is not finite and
/// the step fails naming the limit ([`super::Model::limit`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Gent {
    pub g: Real,
    pub jm: Real,
}

impl Gent {
    /// `1 - (Ī₁ - 3) / Jm`, the distance to the limit.
    fn reserve(&self, i1: Real) -> Real {
        1.0 - (i1 - 3.0) / self.jm
    }
}

impl IsochoricLaw for Gent {
    fn energy(&self, i1: Real, _i2: Real) -> Real {
        let r = self.reserve(i1);
        if r.is_nan() || r <= 0.0 {
            return Real::MAX;
        }
        -0.5 * self.g * self.jm * r.ln()
    }
    fn derivatives(&self, i1: Real, _i2: Real) -> Isochoric {
        let r = self.reserve(i1);
        if r.is_nan() || r <= 0.0 {
            return Isochoric { d1: Real::MAX, d2: 0.0, d11: Real::MAX, d12: 0.0, d22: 0.0 };
        }
        Isochoric { d1: 0.5 * self.g / r, d11: 0.5 * self.g / (self.jm * r * r), ..Default::default() }
    }
}

/// The coefficients of the Arruda-Boyce series (the inverse Langevin function's expansion).
pub const ARRUDA_BOYCE: [Real; 5] = [0.5, 1.0 / 20.0, 11.0 / 1050.0, 19.0 / 7000.0, 519.0 / 673750.0];

/// Arruda-Boyce (eight-chain), its five-term series:
/// `Ŵ = μ Σᵢ Cᵢ / λm^(2i-2) (Ī₁ⁱ - 3ⁱ)`, `G = μ (1 + 3/(5λm²) + 99/(175λm⁴) + ...)`.
#[derive(Debug, Clone, PartialEq)]
pub struct ArrudaBoyce {
    pub mu: Real,
    pub lambda_m: Real,
}

impl ArrudaBoyce {
    /// `μ Cᵢ / λm^(2i-2)`, i = 1..5.
    fn terms(&self) -> [Real; 5] {
        let inv2 = 1.0 / (self.lambda_m * self.lambda_m);
        let mut scale = self.mu;
        ARRUDA_BOYCE.map(|c| {
            let t = scale * c;
            scale *= inv2;
            t
        })
    }
}

impl IsochoricLaw for ArrudaBoyce {
    fn energy(&self, i1: Real, _i2: Real) -> Real {
        let (mut w, mut x, mut three) = (0.0, 1.0, 1.0);
        for beta in self.terms() {
            x *= i1;
            three *= 3.0;
            w += beta * (x - three);
        }
        w
    }
    fn derivatives(&self, i1: Real, _i2: Real) -> Isochoric {
        let (mut d1, mut d11) = (0.0, 0.0);
        // Σ i βᵢ Ī₁^(i-1) and Σ i (i-1) βᵢ Ī₁^(i-2), by powers kept from term to term.
        let (mut x, mut x_before) = (1.0, 0.0);
        for (i, beta) in self.terms().into_iter().enumerate() {
            let n = (i + 1) as Real;
            d1 += n * beta * x;
            d11 += n * (n - 1.0) * beta * x_before;
            x_before = x;
            x *= i1;
        }
        Isochoric { d1, d11, ..Default::default() }
    }
}

/// The decoupled models share their kinematics (C, C², C⁻¹, a cube root, a logarithm and nine
/// 6x6 outer products); their isochoric laws add a few dozen.
const DECOUPLED_FLOPS: (f64, f64, f64) = (950.0, 250.0, 160.0);

impl Law for Decoupled<MooneyRivlin> {
    const NAME: &'static str = "mooney_rivlin";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("K"), Parameter::optional("C10"), Parameter::optional("C01")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_mooney_rivlin.wgsl");
    const DECOUPLED: bool = true;
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("C10", &[400.0]), ("C01", &[100.0]), ("K", &[3000.0])];
    const FLOPS: (f64, f64, f64) = DECOUPLED_FLOPS;

    fn from_parameters(p: &Parameters) -> Self {
        Decoupled { law: MooneyRivlin { c10: number(p, "C10"), c01: number(p, "C01") }, k: number(p, "K") }
    }
    /// Drucker stability at small strain: a positive shear modulus.
    fn check(p: &Parameters) -> Result<(), Rejected> {
        let (c10, c01) = (number(p, "C10"), number(p, "C01"));
        if (c10 + c01).is_nan() || c10 + c01 <= 0.0 {
            return Err(Rejected { parameter: "C10".into(), message: format!("the small-strain shear modulus G = 2 (C10 + C01) must be above zero (C10 = {c10}, C01 = {c01}).") });
        }
        Ok(())
    }
    fn gpu_parameters(&self) -> [Real; 8] {
        [self.law.shear_modulus(), self.k, self.law.c10, self.law.c01, 0.0, 0.0, 0.0, 0.0]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        (self.k, self.law.shear_modulus())
    }
}

impl Law for Decoupled<Yeoh> {
    const NAME: &'static str = "yeoh";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("K"), Parameter::positive("C10"), Parameter::optional("C20"), Parameter::optional("C30")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_yeoh.wgsl");
    const DECOUPLED: bool = true;
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("C10", &[500.0]), ("C20", &[-50.0]), ("C30", &[5.0]), ("K", &[3000.0])];
    const FLOPS: (f64, f64, f64) = DECOUPLED_FLOPS;

    fn from_parameters(p: &Parameters) -> Self {
        Decoupled { law: Yeoh { c10: number(p, "C10"), c20: number(p, "C20"), c30: number(p, "C30") }, k: number(p, "K") }
    }
    fn gpu_parameters(&self) -> [Real; 8] {
        [self.law.shear_modulus(), self.k, self.law.c10, self.law.c20, self.law.c30, 0.0, 0.0, 0.0]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        (self.k, self.law.shear_modulus())
    }
}

impl Law for Decoupled<Gent> {
    const NAME: &'static str = "gent";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("G"), Parameter::modulus("K"), Parameter::positive("Jm")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_gent.wgsl");
    const DECOUPLED: bool = true;
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("G", &[1000.0]), ("Jm", &[20.0]), ("K", &[3000.0])];
    const FLOPS: (f64, f64, f64) = DECOUPLED_FLOPS;

    fn from_parameters(p: &Parameters) -> Self {
        Decoupled { law: Gent { g: number(p, "G"), jm: number(p, "Jm") }, k: number(p, "K") }
    }
    fn gpu_parameters(&self) -> [Real; 8] {
        [self.law.shear_modulus(), self.k, self.law.jm, 0.0, 0.0, 0.0, 0.0, 0.0]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        (self.k, self.law.shear_modulus())
    }
    fn limit(&self) -> Option<&'static str> {
        Some("the Gent model's limit Ī₁ - 3 = Jm is reached there: the rubber's chains are fully stretched (raise `Jm`, or load it less)")
    }
}

impl Law for Decoupled<ArrudaBoyce> {
    const NAME: &'static str = "arruda_boyce";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("K"), Parameter::positive("mu"), Parameter::positive("lambda_m")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_arruda_boyce.wgsl");
    const DECOUPLED: bool = true;
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("mu", &[900.0]), ("lambda_m", &[2.5]), ("K", &[3000.0])];
    const FLOPS: (f64, f64, f64) = DECOUPLED_FLOPS;

    fn from_parameters(p: &Parameters) -> Self {
        Decoupled { law: ArrudaBoyce { mu: number(p, "mu"), lambda_m: number(p, "lambda_m") }, k: number(p, "K") }
    }
    fn check(p: &Parameters) -> Result<(), Rejected> {
        let lambda_m = number(p, "lambda_m");
        if lambda_m <= 1.0 {
            return Err(Rejected { parameter: "lambda_m".into(), message: format!("the locking stretch must be above 1 (got {lambda_m}).") });
        }
        Ok(())
    }
    fn gpu_parameters(&self) -> [Real; 8] {
        [self.law.shear_modulus(), self.k, self.law.mu, self.law.lambda_m, 0.0, 0.0, 0.0, 0.0]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        (self.k, self.law.shear_modulus())
    }
}
