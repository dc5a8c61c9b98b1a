//! JSON schemas of the run-log channels (documented in doc/mcap.md).

use serde_json::{json, Map, Value};

fn vector(dim: usize) -> Value {
    json!({"type": "array", "items": {"type": "number"}, "minItems": dim, "maxItems": dim})
}

fn object(title: &str, fields: &[(&str, Value)]) -> Value {
    let props: Map<String, Value> = fields.iter().map(|(k, v)| (k.to_string(), v.clone())).collect();
    let required: Vec<&str> = fields.iter().map(|(k, _)| *k).collect();
    json!({"title": title, "type": "object", "properties": props, "required": required})
}

fn number() -> Value {
    json!({"type": "number"})
}

fn integer() -> Value {
    json!({"type": "integer"})
}

pub fn run() -> Value {
    object(
        "bifirst.Run",
        &[
            ("version", json!({"type": "string"})),
            ("git_revision", json!({"type": ["string", "null"], "description": "commit the binary was built from, when known"})),
            ("scene_name", json!({"type": "string"})),
            ("scene", json!({"type": "string", "description": "resolved scene after --set, TOML"})),
            ("backend", json!({"type": "string"})),
            ("precision", json!({"type": "string"})),
            ("adapter", json!({"type": ["string", "null"]})),
        ],
    )
}

pub fn energy() -> Value {
    let f = ["t", "kinetic", "strain", "potential", "external_work", "friction_dissipation", "numerical_dissipation", "contact_correction", "total", "energy_balance_error"];
    object("bifirst.Energy", &f.map(|k| (k, number())))
}

/// Wall seconds by phase (`/solver.wall_s`, `/summary.wall_by_phase`).
fn wall_times() -> Value {
    let phases = ["elements", "assembly", "transfer", "factorization", "solve", "contact", "total"];
    object("bifirst.WallTimes", &phases.map(|k| (k, number())))
}

pub fn solver() -> Value {
    object(
        "bifirst.Solver",
        &[
            ("t", number()),
            ("step", integer()),
            ("dt", number()),
            ("newton_iterations", integer()),
            ("uzawa_iterations", integer()),
            ("bodies_iterated", json!({"type": "integer", "description": "body evaluations in the step, summed over Newton iterations (bodies that converged leave the loop)"})),
            ("factorizations", integer()),
            ("residual_norm", number()),
            ("cutbacks", integer()),
            ("wall_s", wall_times()),
            ("bytes_moved", json!({"type": "integer", "description": "bytes between host and GPU in the step (0 on the CPU)"})),
            ("device_submits", json!({"type": "integer", "description": "GPU queue submits in the step, one per device pass over all bodies (0 on the CPU)"})),
            ("status", json!({"type": "string", "enum": ["converged", "failed", "interrupted"]})),
            ("message", json!({"type": ["string", "null"]})),
        ],
    )
}

/// In 2D the angular momentum is the scalar z component; in 3D a vector.
pub fn body(dim: usize) -> Value {
    let angular = if dim == 2 { number() } else { vector(3) };
    object(
        "bifirst.Body",
        &[
            ("t", number()),
            ("mass", number()),
            ("center_of_mass", vector(dim)),
            ("linear_momentum", vector(dim)),
            ("angular_momentum", angular),
            ("kinetic", number()),
        ],
    )
}

pub fn probe(dim: usize) -> Value {
    object(
        "bifirst.Probe",
        &[("t", number()), ("position", vector(dim)), ("displacement", vector(dim)), ("velocity", vector(dim)), ("von_mises", number())],
    )
}

pub fn reaction(dim: usize) -> Value {
    object("bifirst.Reaction", &[("t", number()), ("force", vector(dim))])
}

pub fn contact() -> Value {
    object(
        "bifirst.Contact",
        &[
            ("t", number()),
            ("active", integer()),
            ("sticking", integer()),
            ("sliding", integer()),
            ("max_penetration", json!({"type": "number", "description": "deepest linearised end gap of the contact points"})),
            ("max_overlap", json!({"type": "number", "description": "deepest boundary node inside another body or behind an obstacle at the end of the step (point in element)"})),
            ("max_overlap_ratio", json!({"type": "number", "description": "the largest such depth over the local element size"})),
            ("normal_impulse", number()),
            ("friction_dissipation_step", number()),
        ],
    )
}

/// The full state of a finished step, what `bifirst run --restart` continues from.
pub fn saved_state() -> Value {
    let numbers = json!({"type": "array", "items": {"type": "number"}});
    let body = object(
        "bifirst.SavedBody",
        &[
            ("name", json!({"type": "string"})),
            ("u", numbers.clone()),
            ("v", numbers.clone()),
            ("f_int", numbers.clone()),
            ("strain", number()),
            ("reactions", numbers.clone()),
            ("factor", json!({"description": "values of the factorisation kept for the next step, with its c1, or null", "oneOf": [{"type": "null"}, object("bifirst.SavedFactor", &[("c1", number()), ("values", numbers.clone())])]})),
        ],
    );
    let master = json!({"description": "`{\"Body\": b}` or `{\"Obstacle\": {\"obstacle\": o, \"face\": f}}`", "type": "object"});
    let reaction = object("bifirst.SavedReaction", &[("slave_body", integer()), ("slave_node", integer()), ("master", master), ("r", vector(3)), ("rho", number())]);
    object(
        "bifirst.SavedState",
        &[
            ("t", number()),
            ("step", integer()),
            ("initial_energy", number()),
            ("external_work", number()),
            ("friction_dissipation", number()),
            ("numerical_dissipation", number()),
            ("contact_correction", number()),
            ("bodies", json!({"type": "array", "items": body})),
            ("contact", json!({"type": "array", "items": reaction})),
            ("obstacle_reactions", json!({"type": "array", "items": vector(3)})),
        ],
    )
}

/// The run's totals, written once when it ends (however it ends).
pub fn summary() -> Value {
    let energies = ["kinetic", "strain", "potential", "external_work", "friction_dissipation", "numerical_dissipation", "contact_correction", "total", "energy_balance_error"];
    object(
        "bifirst.Summary",
        &[
            ("scene", json!({"type": "string"})),
            ("status", json!({"type": "string", "enum": ["finished", "failed", "interrupted"]})),
            ("message", json!({"type": ["string", "null"]})),
            ("backend", json!({"type": "string"})),
            ("precision", json!({"type": "string"})),
            ("adapter", json!({"type": ["string", "null"]})),
            ("steps", integer()),
            ("t_end", number()),
            ("cutbacks", integer()),
            ("newton_iterations", integer()),
            ("uzawa_iterations", integer()),
            ("bodies_iterated", integer()),
            ("factorizations", integer()),
            ("max_penetration", number()),
            ("max_overlap", number()),
            ("max_overlap_ratio", number()),
            ("energy_gain_steps", json!({"type": "integer", "description": "steps whose numerical dissipation was negative beyond 1e-4 of the energy scale"})),
            ("max_energy_gain", number()),
            ("wall_s", number()),
            ("wall_by_phase", wall_times()),
            ("bytes_moved", integer()),
            ("device_submits", integer()),
            ("energy", object("bifirst.Energies", &energies.map(|k| (k, number())))),
            ("output", json!({"type": "string"})),
        ],
    )
}
