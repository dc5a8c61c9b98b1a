//! Hyperelastic materials in total Lagrangian form: energy W(E), stress S = dW/dE and the
//! consistent tangent dS/dE. Adding a model is one file implementing [`Hyperelastic`] plus an
//! entry in [`Model`].

mod blatz_ko;
pub mod decoupled;
mod lvf;
mod neo_hookean;
pub mod ogden;
pub mod rubber;
pub mod tensor;
pub mod viscous;

pub use blatz_ko::BlatzKo;
pub use decoupled::{Decoupled, IsochoricLaw};
pub use lvf::Lvf;
pub use neo_hookean::NeoHookean;
pub use ogden::Ogden;
pub use rubber::{ArrudaBoyce, Gent, MooneyRivlin, Yeoh};
pub use viscous::{BranchStep, Prony, Relaxation, Viscoelastic};

use crate::precision::Real;
use tensor::{Mat3, Tangent};

/// A hyperelastic law written in the Green-Lagrange strain E (3x3, symmetric).
///
/// Plane strain uses the same 3D law with E33 = E13 = E23 = 0.
pub trait Hyperelastic {
    /// Strain energy density per unit reference volume.
    fn energy(&self, e: &Mat3) -> Real;
    /// Second Piola-Kirchhoff stress `S = dW/dE`.
    fn stress(&self, e: &Mat3) -> Mat3;
    /// The stress (exactly as [`Hyperelastic::stress`] gives it) and the consistent tangent
    /// `dS/dE` in Voigt form (see [`tensor`]), from one evaluation of what they share.
    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent);
    /// The consistent tangent alone.
    fn tangent(&self, e: &Mat3) -> Tangent {
        self.stress_tangent(e).1
    }
}

/// The material models a scene can name.
#[derive(Debug, Clone, PartialEq)]
pub enum Model {
    BlatzKo(BlatzKo),
    Lvf(Lvf),
    NeoHookean(NeoHookean),
    MooneyRivlin(Decoupled<MooneyRivlin>),
    Yeoh(Decoupled<Yeoh>),
    Gent(Decoupled<Gent>),
    ArrudaBoyce(Decoupled<ArrudaBoyce>),
    Ogden(Ogden),
}

/// `$body` with `$m` bound to the model inside whichever variant `$model` is.
macro_rules! each_model {
    ($model:expr, $m:ident => $body:expr) => {
        match $model {
            Model::BlatzKo($m) => $body,
            Model::Lvf($m) => $body,
            Model::NeoHookean($m) => $body,
            Model::MooneyRivlin($m) => $body,
            Model::Yeoh($m) => $body,
            Model::Gent($m) => $body,
            Model::ArrudaBoyce($m) => $body,
            Model::Ogden($m) => $body,
        }
    };
}

impl Model {
    /// The name scenes use, and the material include of the GPU kernels (`material_<name>.wgsl`).
    pub fn name(&self) -> &'static str {
        match self {
            Model::BlatzKo(_) => "blatz_ko",
            Model::Lvf(_) => "lvf",
            Model::NeoHookean(_) => "neo_hookean",
            Model::MooneyRivlin(_) => "mooney_rivlin",
            Model::Yeoh(_) => "yeoh",
            Model::Gent(_) => "gent",
            Model::ArrudaBoyce(_) => "arruda_boyce",
            Model::Ogden(_) => "ogden",
        }
    }

    /// Every parameter in the order of the kernels' `MaterialParams`: G, K, a1..a6 (zero where
    /// the model has none). The decoupled models put their small-strain G first and their own
    /// parameters in a1.. (`shaders/include/material_<name>.wgsl` reads them there).
    pub fn parameters(&self) -> [Real; 8] {
        let g = self.bulk_shear().1;
        match self {
            Model::BlatzKo(m) => [m.g, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            Model::Lvf(m) => [m.g, m.k, m.a1, m.a2, m.a3, m.a4, m.a5, 0.0],
            Model::NeoHookean(m) => [m.g, m.k, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            Model::MooneyRivlin(m) => [g, m.k, m.law.c10, m.law.c01, 0.0, 0.0, 0.0, 0.0],
            Model::Yeoh(m) => [g, m.k, m.law.c10, m.law.c20, m.law.c30, 0.0, 0.0, 0.0],
            Model::Gent(m) => [g, m.k, m.law.jm, 0.0, 0.0, 0.0, 0.0, 0.0],
            Model::ArrudaBoyce(m) => [g, m.k, m.law.mu, m.law.lambda_m, 0.0, 0.0, 0.0, 0.0],
            Model::Ogden(m) => [g, m.k, m.mu[0], m.mu[1], m.mu[2], m.alpha[0], m.alpha[1], m.alpha[2]],
        }
    }

    /// What a non-finite stress means for this model beyond a bad state: a limit of the law.
    pub fn limit(&self) -> Option<&'static str> {
        match self {
            Model::Gent(_) => Some("the Gent model's limit Ī₁ - 3 = Jm is reached there: the rubber's chains are fully stretched (raise `Jm`, or load it less)"),
            _ => None,
        }
    }

    /// Small-strain bulk and shear moduli `(K, G)`.
    pub fn bulk_shear(&self) -> (Real, Real) {
        match self {
            Model::BlatzKo(m) => (5.0 * m.g / 3.0, m.g),
            Model::Lvf(m) => (m.k, m.g),
            Model::NeoHookean(m) => (m.k, m.g),
            Model::MooneyRivlin(m) => (m.k, m.law.shear_modulus()),
            Model::Yeoh(m) => (m.k, m.law.shear_modulus()),
            Model::Gent(m) => (m.k, m.law.shear_modulus()),
            Model::ArrudaBoyce(m) => (m.k, m.law.shear_modulus()),
            Model::Ogden(m) => (m.k, m.shear_modulus()),
        }
    }

    /// Small-strain (Young's modulus, Poisson ratio), used for wave speeds and time-step hints.
    pub fn small_strain_moduli(&self) -> (Real, Real) {
        let (k, g) = self.bulk_shear();
        let e = 9.0 * k * g / (3.0 * k + g);
        let nu = (3.0 * k - 2.0 * g) / (2.0 * (3.0 * k + g));
        (e, nu)
    }
}

impl Hyperelastic for Model {
    fn energy(&self, e: &Mat3) -> Real {
        each_model!(self, m => m.energy(e))
    }
    fn stress(&self, e: &Mat3) -> Mat3 {
        each_model!(self, m => m.stress(e))
    }
    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        each_model!(self, m => m.stress_tangent(e))
    }
}
