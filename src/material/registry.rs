//! What a material model is besides its law: the name scenes use, the parameters they set and
//! the checks on them, the GPU kernels' include and the packing of its parameters for them.
//! A model implements [`Law`]; the table in `material/mod.rs` (one line per model) makes of
//! it a [`super::Model`] variant and an [`Entry`] of [`super::Model::ENTRIES`], from which the
//! scene's checks, the set-up, the kernels' list and the benches follow.

use super::Hyperelastic;
use crate::precision::Real;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A parameter a model takes, by the name scenes give it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Parameter {
    pub name: &'static str,
    pub rule: Rule,
}

/// What a parameter's value must be.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rule {
    /// Required, positive and finite; messages call it "the modulus".
    Modulus,
    /// Required, positive and finite (a limit, a stretch).
    Positive,
    /// Required, finite (a ratio the model bounds in its check).
    Number,
    /// Optional, finite; zero when left out.
    Optional,
    /// Required, a list of one to three finite numbers, one per term of the law.
    Terms,
}

impl Parameter {
    pub const fn modulus(name: &'static str) -> Self {
        Self { name, rule: Rule::Modulus }
    }
    pub const fn positive(name: &'static str) -> Self {
        Self { name, rule: Rule::Positive }
    }
    pub const fn number(name: &'static str) -> Self {
        Self { name, rule: Rule::Number }
    }
    pub const fn optional(name: &'static str) -> Self {
        Self { name, rule: Rule::Optional }
    }
    pub const fn terms(name: &'static str) -> Self {
        Self { name, rule: Rule::Terms }
    }
}

/// A parameter given as one number or as a list (Ogden's terms).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum Values {
    One(Real),
    Many(Vec<Real>),
}

/// By hand, not `untagged`: a wrong entry (`mu = ["630"]`) is named with its position and type,
/// where the derived form said only that no variant matched.
impl<'de> Deserialize<'de> for Values {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct NumberOrList;
        impl<'de> serde::de::Visitor<'de> for NumberOrList {
            type Value = Values;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or a list of numbers")
            }
            fn visit_f64<E>(self, v: f64) -> Result<Values, E> {
                Ok(Values::One(v))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Values, E> {
                Ok(Values::One(v as Real))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Values, E> {
                Ok(Values::One(v as Real))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Values, A::Error> {
                let mut values = Vec::new();
                while let Some(v) = seq.next_element::<Real>()? {
                    values.push(v);
                }
                Ok(Values::Many(values))
            }
        }
        deserializer.deserialize_any(NumberOrList)
    }
}

impl Values {
    pub fn as_slice(&self) -> &[Real] {
        match self {
            Values::One(v) => std::slice::from_ref(v),
            Values::Many(v) => v,
        }
    }

    /// The value when there is exactly one.
    pub fn one(&self) -> Option<Real> {
        match self.as_slice() {
            [v] => Some(*v),
            _ => None,
        }
    }
}

/// A material's parameters by name, as a scene gives them.
pub type Parameters = BTreeMap<String, Values>;

/// The number a scene gave `name`, zero when it gave none.
pub fn number(p: &Parameters, name: &str) -> Real {
    p.get(name).and_then(Values::one).unwrap_or(0.0)
}

/// The terms a scene gave `name`, zero past the last (and all zero when it gave none).
pub fn terms(p: &Parameters, name: &str) -> [Real; 3] {
    let mut out = [0.0; 3];
    for (o, x) in out.iter_mut().zip(p.get(name).map(Values::as_slice).unwrap_or_default()) {
        *o = *x;
    }
    out
}

/// Parameters from `(name, values)` pairs: a model's example, a test's material.
pub fn parameters(pairs: &[(&str, &[Real])]) -> Parameters {
    pairs.iter().map(|&(name, v)| (name.to_string(), if v.len() == 1 { Values::One(v[0]) } else { Values::Many(v.to_vec()) })).collect()
}

/// A parameter a model's own check rejects, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Rejected {
    /// The parameter the message is about (`alpha`, or `mu.1` for a term).
    pub parameter: String,
    pub message: String,
}

/// A material model: its law ([`Hyperelastic`]) and what the scene, the set-up and the GPU
/// kernels need to know of it.
pub trait Law: Hyperelastic + Sized {
    /// The name scenes give (`model = "..."`).
    const NAME: &'static str;
    /// The parameters scenes give, in the order messages list them.
    const PARAMETERS: &'static [Parameter];
    /// The parameter that sets the bulk response: a K/G beyond what f64 resolves is reported on it.
    const BULK: &'static str = "K";
    /// `material_energy`, `material_stress` and `material_stress_tangent` in WGSL, reading
    /// `material` (`MaterialParams`) as [`Law::gpu_parameters`] packs it; a file of
    /// `shaders/include/`.
    const WGSL: &'static str;
    /// Whether [`Law::WGSL`] gives only `Ŵ(Ī₁, Ī₂)` and its derivatives, composed after
    /// `include/decoupled.wgsl`, which gives the stress and tangent.
    const DECOUPLED: bool = false;
    /// A typical parameter set in the scene's form: the benches' model and the GPU tests'.
    const EXAMPLE: &'static [(&'static str, &'static [Real])];
    /// Floating-point operations at one point, counted from [`Law::WGSL`] to about 20 %:
    /// (stress and tangent, stress alone, energy), for the bench's roofline.
    const FLOPS: (f64, f64, f64);
    /// The law from parameters that passed the rules and [`Law::check`].
    fn from_parameters(p: &Parameters) -> Self;
    /// Checks across parameters beyond each one's [`Rule`] (run after the rules passed).
    fn check(_p: &Parameters) -> Result<(), Rejected> {
        Ok(())
    }
    /// `MaterialParams` of the kernels: G, K, a1..a6 (the small-strain shear and bulk moduli
    /// first, as the shared kernel code reads them; zero where unused).
    fn gpu_parameters(&self) -> [Real; 8];
    /// Small-strain bulk and shear moduli `(K, G)`.
    fn bulk_shear(&self) -> (Real, Real);
    /// What a non-finite stress means for this model beyond a bad state: a limit of the law.
    fn limit(&self) -> Option<&'static str> {
        None
    }
}

/// A model's row of the registry, for code that knows the model by its name only.
#[derive(Clone, Copy)]
pub struct Entry {
    pub name: &'static str,
    pub parameters: &'static [Parameter],
    pub bulk: &'static str,
    pub wgsl: &'static str,
    pub decoupled: bool,
    pub example: &'static [(&'static str, &'static [Real])],
    pub flops: (f64, f64, f64),
    pub check: fn(&Parameters) -> Result<(), Rejected>,
    pub build: fn(&Parameters) -> super::Model,
}

impl Entry {
    /// The model with its example parameters ([`Law::EXAMPLE`]).
    pub fn example_model(&self) -> super::Model {
        (self.build)(&parameters(self.example))
    }

    pub const fn of<L: Law>(build: fn(&Parameters) -> super::Model) -> Self {
        Self { name: L::NAME, parameters: L::PARAMETERS, bulk: L::BULK, wgsl: L::WGSL, decoupled: L::DECOUPLED, example: L::EXAMPLE, flops: L::FLOPS, check: L::check, build }
    }
}
