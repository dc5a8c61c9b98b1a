//! The LVF model of Lainé, Vallée and Fortuné, paper eqs. (4)-(5).
//!
//! With `s2 = tr(E_d²)`, `s3 = tr(E_d³)` and `z = tr(E)/√3`, eq. (5) reads
//! `W = (G + a3 z²/4) s2 + 3K/2 z² + a1 √6/3 s3 + a2/3 z³ + a4/4 z⁴ + a5/4 s2²`
//! (using `x² + y² = s2` and `x³ - 3xy² = √6 s3`, so no Lode angle is needed).
//!
//! Eq. (5) is the definition: S and the tangent are derived from it. The paper's eq. (6) drops
//! the a3 terms and halves the a5 term; that stress is not the derivative of the energy and would
//! break energy conservation, so it is not used (see doc/ARCHITECTURE.md).

use super::registry::{number, Law, Parameter, Parameters};
use super::tensor::{dev, deviatoric_projector, odot, outer, Mat3, Tangent};
use super::Hyperelastic;
use crate::precision::Real;

#[derive(Debug, Clone, PartialEq)]
pub struct Lvf {
    pub g: Real,
    pub k: Real,
    pub a1: Real,
    pub a2: Real,
    pub a3: Real,
    pub a4: Real,
    pub a5: Real,
}

impl Law for Lvf {
    const NAME: &'static str = "lvf";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("G"), Parameter::modulus("K"), Parameter::optional("a1"), Parameter::optional("a2"), Parameter::optional("a3"), Parameter::optional("a4"), Parameter::optional("a5")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_lvf.wgsl");
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("G", &[5000.0]), ("K", &[3333.0]), ("a1", &[50.0]), ("a2", &[50.0]), ("a3", &[10.0]), ("a4", &[2000.0]), ("a5", &[100.0])];
    const FLOPS: (f64, f64, f64) = (700.0, 120.0, 90.0);

    fn from_parameters(p: &Parameters) -> Self {
        let a = |name| number(p, name);
        Self { g: a("G"), k: a("K"), a1: a("a1"), a2: a("a2"), a3: a("a3"), a4: a("a4"), a5: a("a5") }
    }
    fn gpu_parameters(&self) -> [Real; 8] {
        [self.g, self.k, self.a1, self.a2, self.a3, self.a4, self.a5, 0.0]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        (self.k, self.g)
    }
}

const SQRT3: Real = 1.732_050_807_568_877_2;
const SQRT6: Real = 2.449_489_742_783_178;

impl Hyperelastic for Lvf {
    fn energy(&self, e: &Mat3) -> Real {
        let ed = dev(e);
        let ed2 = ed * ed;
        let (s2, s3, z) = (ed2.trace(), (ed2 * ed).trace(), e.trace() / SQRT3);
        (self.g + 0.25 * self.a3 * z * z) * s2 + 1.5 * self.k * z * z + self.a1 * SQRT6 / 3.0 * s3 + self.a2 / 3.0 * z.powi(3) + 0.25 * self.a4 * z.powi(4) + 0.25 * self.a5 * s2 * s2
    }

    fn stress(&self, e: &Mat3) -> Mat3 {
        self.stress_of(&Invariants::of(e))
    }

    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        let inv = Invariants::of(e);
        let Invariants { ed, s2, z, .. } = inv;
        let i = Mat3::identity();
        let p = deviatoric_projector();
        let iz = i / SQRT3; // dz/dE
        let dw_ds2 = self.g + 0.25 * self.a3 * z * z + 0.5 * self.a5 * s2;
        let d2w_dz2 = 0.5 * self.a3 * s2 + 3.0 * self.k + 2.0 * self.a2 * z + 3.0 * self.a4 * z * z;
        let d2w_dzds2 = 0.5 * self.a3 * z;
        let d2w_ds2ds2 = 0.5 * self.a5;
        let ded = ed * 2.0; // ds2/dE
                            // d dev(Ed²)/dE = I⊙Ed + Ed⊙I - 2/3 (Ed⊗I + I⊗Ed)
        let d_dev_ed2 = odot(&i, &ed) * 2.0 - (outer(&ed, &i) + outer(&i, &ed)) * (2.0 / 3.0);
        let d = p * (2.0 * dw_ds2) + outer(&ded, &ded) * d2w_ds2ds2 + (outer(&ded, &iz) + outer(&iz, &ded)) * d2w_dzds2 + outer(&iz, &iz) * d2w_dz2 + d_dev_ed2 * (self.a1 * SQRT6);
        (self.stress_of(&inv), d)
    }
}

/// `Ed`, `Ed²`, `s2 = tr(Ed²)` and `z = tr(E)/√3`: what the stress and the tangent share.
#[derive(Clone, Copy)]
struct Invariants {
    ed: Mat3,
    ed2: Mat3,
    s2: Real,
    z: Real,
}

impl Invariants {
    fn of(e: &Mat3) -> Self {
        let ed = dev(e);
        let ed2 = ed * ed;
        Self { ed, ed2, s2: ed2.trace(), z: e.trace() / SQRT3 }
    }
}

impl Lvf {
    fn stress_of(&self, inv: &Invariants) -> Mat3 {
        let Invariants { ed, ed2, s2, z } = *inv;
        // dW/dz and dW/ds2; ds2/dE = 2 Ed, dz/dE = I/√3, ds3/dE = 3 dev(Ed²).
        let dw_dz = 0.5 * self.a3 * z * s2 + 3.0 * self.k * z + self.a2 * z * z + self.a4 * z.powi(3);
        let dw_ds2 = self.g + 0.25 * self.a3 * z * z + 0.5 * self.a5 * s2;
        ed * (2.0 * dw_ds2) + Mat3::identity() * (dw_dz / SQRT3) + dev(&ed2) * (self.a1 * SQRT6)
    }
}
