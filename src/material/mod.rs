//! Hyperelastic materials in total Lagrangian form: energy W(E), stress S = dW/dE and the
//! consistent tangent dS/dE. Adding a model is one file implementing [`Hyperelastic`] and
//! [`Law`] (with its WGSL include in `shaders/include/`) plus one line in the table below.

mod blatz_ko;
pub mod decoupled;
mod lvf;
mod neo_hookean;
pub mod ogden;
pub mod registry;
pub mod rubber;
mod svk;
pub mod tensor;
pub mod viscous;

pub use blatz_ko::BlatzKo;
pub use decoupled::{Decoupled, IsochoricLaw};
pub use lvf::Lvf;
pub use neo_hookean::NeoHookean;
pub use ogden::Ogden;
pub use registry::{Entry, Law, Parameter, Parameters, Rejected, Rule, Values};
pub use rubber::{ArrudaBoyce, Gent, MooneyRivlin, Yeoh};
pub use svk::Svk;
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

/// The registry: one line per model, `Variant(law type)`. The `Model` enum, its dispatch and
/// [`Model::ENTRIES`] (the scene's names and checks, the kernels' list) follow from it.
macro_rules! models {
    ($($variant:ident($law:ty)),* $(,)?) => {
        /// The material models a scene can name.
        #[derive(Debug, Clone, PartialEq)]
        pub enum Model {
            $($variant($law)),*
        }

        impl Model {
            /// Every model's row, in the table's order.
            pub const ENTRIES: &'static [Entry] = &[$(Entry::of::<$law>(|p| Model::$variant(<$law as Law>::from_parameters(p)))),*];

            /// The name scenes use, and the material of the GPU kernels' variants.
            pub fn name(&self) -> &'static str {
                match self {
                    $(Model::$variant(_) => <$law as Law>::NAME),*
                }
            }

            /// Every parameter in the order of the kernels' `MaterialParams` ([`Law::gpu_parameters`]).
            pub fn parameters(&self) -> [Real; 8] {
                match self {
                    $(Model::$variant(m) => m.gpu_parameters()),*
                }
            }

            /// What a non-finite stress means for this model beyond a bad state: a limit of the law.
            pub fn limit(&self) -> Option<&'static str> {
                match self {
                    $(Model::$variant(m) => m.limit()),*
                }
            }

            /// Small-strain bulk and shear moduli `(K, G)`.
            pub fn bulk_shear(&self) -> (Real, Real) {
                match self {
                    $(Model::$variant(m) => m.bulk_shear()),*
                }
            }
        }

        impl Hyperelastic for Model {
            fn energy(&self, e: &Mat3) -> Real {
                match self {
                    $(Model::$variant(m) => m.energy(e)),*
                }
            }
            fn stress(&self, e: &Mat3) -> Mat3 {
                match self {
                    $(Model::$variant(m) => m.stress(e)),*
                }
            }
            fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
                match self {
                    $(Model::$variant(m) => m.stress_tangent(e)),*
                }
            }
        }
    };
}

models! {
    BlatzKo(BlatzKo),
    Lvf(Lvf),
    NeoHookean(NeoHookean),
    MooneyRivlin(Decoupled<MooneyRivlin>),
    Yeoh(Decoupled<Yeoh>),
    Gent(Decoupled<Gent>),
    ArrudaBoyce(Decoupled<ArrudaBoyce>),
    Ogden(Ogden),
    Svk(Svk),
}

impl Model {
    /// The row of the model scenes call `name`.
    pub fn entry(name: &str) -> Option<&'static Entry> {
        Self::ENTRIES.iter().find(|e| e.name == name)
    }

    /// The model scenes call `name`, from parameters that passed its checks.
    pub fn from_parameters(name: &str, p: &Parameters) -> Option<Model> {
        Self::entry(name).map(|e| (e.build)(p))
    }

    /// The model `name` with its example parameters ([`Law::EXAMPLE`]).
    pub fn example(name: &str) -> Option<Model> {
        Self::entry(name).map(Entry::example_model)
    }

    /// This model's row of the registry.
    pub fn row(&self) -> &'static Entry {
        Self::entry(self.name()).expect("every model has its row in the table")
    }

    /// Small-strain (Young's modulus, Poisson ratio), used for wave speeds and time-step hints.
    pub fn small_strain_moduli(&self) -> (Real, Real) {
        let (k, g) = self.bulk_shear();
        let e = 9.0 * k * g / (3.0 * k + g);
        let nu = (3.0 * k - 2.0 * g) / (2.0 * (3.0 * k + g));
        (e, nu)
    }
}
