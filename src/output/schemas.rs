//! JSON schemas of the run-log channels (documented in doc/mcap.md), derived by schemars from
//! the types the run writes ([`super::messages`], [`RunSummary`], [`SavedState`]). Only what the
//! types cannot say is added here: the number of components of a vector, which is the scene's.

use super::messages::{BodiesMessage, BodyMessage, ContactMessage, ContactsMessage, EnergyMessage, ProbeMessage, ReactionMessage, RunMessage, SolverMessage};
use super::run_summary::RunSummary;
use crate::solver::SavedState;
use schemars::generate::SchemaSettings;
use schemars::JsonSchema;
use serde_json::{json, Value};

/// The schema of `T`, every nested type inline (Foxglove lists a channel's fields from it).
fn schema_of<T: JsonSchema>() -> Value {
    let generator = SchemaSettings::draft2020_12().with(|s| s.inline_subschemas = true).into_generator();
    serde_json::to_value(generator.into_root_schema_for::<T>()).expect("a schema is JSON")
}

/// `vector` (a schema) an array of exactly `dim` numbers.
fn sized(vector: &mut Value, dim: usize) {
    vector["minItems"] = json!(dim);
    vector["maxItems"] = json!(dim);
}

/// `schema` with each field of `vectors` an array of exactly `dim` numbers.
fn with_dim(mut schema: Value, vectors: &[&str], dim: usize) -> Value {
    for field in vectors {
        sized(&mut schema["properties"][*field], dim);
    }
    schema
}

/// The form [`super::messages::AngularMomentum`] takes in `dim`: the scalar z component in 2D,
/// a vector in 3D.
fn angular_momentum(schema: &mut Value, dim: usize) {
    let variant = schema["anyOf"].as_array().and_then(|v| v.get(if dim == 2 { 0 } else { 1 })).cloned();
    if let Some(variant) = variant {
        *schema = variant;
    }
}

pub fn run() -> Value {
    schema_of::<RunMessage>()
}

pub fn energy() -> Value {
    schema_of::<EnergyMessage>()
}

pub fn solver() -> Value {
    schema_of::<SolverMessage>()
}

/// In 2D the angular momentum is the scalar z component; in 3D a vector.
pub fn body(dim: usize) -> Value {
    let mut schema = with_dim(schema_of::<BodyMessage>(), &["center_of_mass", "linear_momentum"], dim);
    angular_momentum(&mut schema["properties"]["angular_momentum"], dim);
    schema
}

/// `/bodies`: the fields of [`body`] as arrays over the batched bodies.
pub fn bodies(dim: usize) -> Value {
    let mut schema = schema_of::<BodiesMessage>();
    for field in ["center_of_mass", "linear_momentum"] {
        sized(&mut schema["properties"][field]["items"], dim);
    }
    angular_momentum(&mut schema["properties"]["angular_momentum"]["items"], dim);
    schema
}

pub fn probe(dim: usize) -> Value {
    with_dim(schema_of::<ProbeMessage>(), &["position", "displacement", "velocity"], dim)
}

pub fn reaction(dim: usize) -> Value {
    with_dim(schema_of::<ReactionMessage>(), &["force"], dim)
}

pub fn contact() -> Value {
    schema_of::<ContactMessage>()
}

pub fn contacts() -> Value {
    schema_of::<ContactsMessage>()
}

/// The full state of a finished step, what `bifirst run --restart` continues from.
pub fn saved_state() -> Value {
    schema_of::<SavedState>()
}

/// The run's totals, written once when it ends (however it ends).
pub fn summary() -> Value {
    schema_of::<RunSummary>()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectors_take_the_scene_dimension_and_the_angular_momentum_its_form() {
        let body = body(2);
        assert_eq!(body["title"], "bifirst.Body");
        assert_eq!((body["properties"]["linear_momentum"]["minItems"].as_u64(), body["properties"]["linear_momentum"]["maxItems"].as_u64()), (Some(2), Some(2)));
        assert_eq!(body["properties"]["angular_momentum"]["type"], "number");
        assert_eq!(super::body(3)["properties"]["angular_momentum"]["type"], "array");
        let bodies = bodies(3);
        assert_eq!(bodies["title"], "bifirst.Bodies");
        assert_eq!(bodies["properties"]["center_of_mass"]["items"]["maxItems"].as_u64(), Some(3));
        assert_eq!(bodies["properties"]["angular_momentum"]["items"]["type"], "array");
        assert_eq!(super::bodies(2)["properties"]["angular_momentum"]["items"]["type"], "number");
        let energy = energy();
        let fields: Vec<&String> = energy["properties"].as_object().unwrap().keys().collect();
        assert!(fields.len() == 11 && fields.iter().any(|f| *f == "t") && fields.iter().any(|f| *f == "energy_balance_error"), "flattened: {fields:?}");
    }
}
