//! Hyperelastic materials in total Lagrangian form: energy W(E), stress S = dW/dE and the
//! consistent tangent dS/dE. Adding a model is one file implementing [`Hyperelastic`] plus an
//! entry in [`Model`].

mod blatz_ko;
mod lvf;
mod neo_hookean;
pub mod tensor;

pub use blatz_ko::BlatzKo;
pub use lvf::Lvf;
pub use neo_hookean::NeoHookean;

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
}

impl Model {
    /// The name scenes use, and the material include of the GPU kernels (`material_<name>.wgsl`).
    pub fn name(&self) -> &'static str {
        match self {
            Model::BlatzKo(_) => "blatz_ko",
            Model::Lvf(_) => "lvf",
            Model::NeoHookean(_) => "neo_hookean",
        }
    }

    /// Every parameter in the order of the kernels' `MaterialParams`: G, K, a1..a5 (zero where
    /// the model has none).
    pub fn parameters(&self) -> [Real; 7] {
        match self {
            Model::BlatzKo(m) => [m.g, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            Model::Lvf(m) => [m.g, m.k, m.a1, m.a2, m.a3, m.a4, m.a5],
            Model::NeoHookean(m) => [m.g, m.k, 0.0, 0.0, 0.0, 0.0, 0.0],
        }
    }

    /// Small-strain bulk and shear moduli `(K, G)`.
    pub fn bulk_shear(&self) -> (Real, Real) {
        match self {
            Model::BlatzKo(m) => (5.0 * m.g / 3.0, m.g),
            Model::Lvf(m) => (m.k, m.g),
            Model::NeoHookean(m) => (m.k, m.g),
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
        match self {
            Model::BlatzKo(m) => m.energy(e),
            Model::Lvf(m) => m.energy(e),
            Model::NeoHookean(m) => m.energy(e),
        }
    }
    fn stress(&self, e: &Mat3) -> Mat3 {
        match self {
            Model::BlatzKo(m) => m.stress(e),
            Model::Lvf(m) => m.stress(e),
            Model::NeoHookean(m) => m.stress(e),
        }
    }
    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        match self {
            Model::BlatzKo(m) => m.stress_tangent(e),
            Model::Lvf(m) => m.stress_tangent(e),
            Model::NeoHookean(m) => m.stress_tangent(e),
        }
    }
}
