//! Checks that need no mesh: ranges, references between sections, vector lengths.
//! Checks that need the mesh (node sets, element quality, file contents) run at set-up.

use super::error::SceneErrorKind::{self, Invalid, Reference};
use super::types::*;
use crate::material::{Model, Rule};
use crate::precision::Real;

pub(super) type Failure = (SceneErrorKind, String, String);

fn fail(kind: SceneErrorKind, key: impl Into<String>, message: impl Into<String>) -> Result<(), Failure> {
    Err((kind, key.into(), message.into()))
}

/// The largest magnitude a coordinate, velocity, acceleration, density or modulus of a scene may
/// have: energies multiply such numbers with each other and with masses, and must stay finite in
/// f64 (a node at 1e300 or a gravity of 1e308 reached the log as `null`, or failed as an inverted
/// element).
pub const LARGEST_INPUT: Real = 1e100;

fn positive(key: String, what: &str, v: Real) -> Result<(), Failure> {
    if !(v > 0.0 && v.is_finite()) {
        fail(Invalid, key, format!("{what} must be positive and finite (got {v})."))
    } else if !(1.0 / LARGEST_INPUT..=LARGEST_INPUT).contains(&v) {
        fail(Invalid, key, format!("{what} is {v:e}, outside [{:e}, {LARGEST_INPUT:e}] (energies multiply such numbers and must stay finite).", 1.0 / LARGEST_INPUT))
    } else {
        Ok(())
    }
}

/// The smallest length a generated mesh or grain may have: contact geometry takes products of
/// up to four lengths (a facet normal's squared norm in 3D), which must stay normal f64 numbers
/// (grains of radius 1e-90 panicked in the contact frame; 1e-50⁴ = 1e-200).
pub const SMALLEST_LENGTH: Real = 1e-50;

/// A length: positive, within [[`SMALLEST_LENGTH`], [`LARGEST_INPUT`]].
pub(super) fn length(key: String, what: &str, v: Real) -> Result<(), Failure> {
    positive(key.clone(), what, v)?;
    if v < SMALLEST_LENGTH {
        return fail(Invalid, key, format!("{what} is {v:e}, below {SMALLEST_LENGTH:e} (contact geometry multiplies up to four lengths, which must stay above f64's smallest numbers)."));
    }
    Ok(())
}

/// A coefficient of either sign: finite, and within ±[`LARGEST_INPUT`].
fn bounded(key: String, what: &str, v: Real) -> Result<(), Failure> {
    if !v.is_finite() {
        fail(Invalid, key, format!("{what} is not a finite number (got {v})."))
    } else if v.abs() > LARGEST_INPUT {
        fail(Invalid, key, format!("{what} is {v:e}, beyond ±{LARGEST_INPUT:e} (energies multiply such numbers and must stay finite)."))
    } else {
        Ok(())
    }
}

fn finite_vec(key: &str, v: &[Real], len: Option<usize>) -> Result<(), Failure> {
    if let Some(n) = len {
        if v.len() != n {
            return fail(Invalid, key, format!("expected {n} components (the scene is {n}D), got {}.", v.len()));
        }
    }
    match v.iter().position(|x| !x.is_finite()) {
        Some(i) => fail(Invalid, format!("{key}.{i}"), "not a finite number."),
        None => Ok(()),
    }
}

/// Spatial dimension implied by a body's generator, if it has one.
pub(super) fn generator_dim(mesh: &MeshSpec) -> Option<usize> {
    mesh.generator.map(|g| match g {
        Generator::Rectangle | Generator::Disk | Generator::Annulus | Generator::Polygon => 2,
        Generator::Box | Generator::Ball => 3,
    })
}

pub(super) fn validate(s: &Scene) -> Result<(), Failure> {
    validate_stepping(s)?;
    validate_sizes(s)?;
    validate_names(s)?;
    for (name, m) in &s.material {
        validate_material(&format!("material.{name}"), m)?;
    }
    let dim = validate_bodies(s)?;
    if let Some(g) = &s.gravity {
        finite_vec("gravity", g, dim)?;
    }
    validate_boundaries(s, dim)?;
    validate_contact(s, dim)?;
    for (name, o) in &s.obstacle {
        if s.boundary.contains_key(name) {
            fail(Invalid, format!("obstacle.{name}"), format!("a boundary set is also named `{name}`; both would log to /reaction/{name}."))?;
        }
        validate_obstacle(s, &format!("obstacle.{name}"), o, dim)?;
    }
    for (name, load) in &s.load {
        validate_load(s, &format!("load.{name}"), load, dim)?;
    }
    for (name, p) in &s.probe {
        let key = format!("probe.{name}");
        if !s.body.contains_key(&p.body) {
            fail(Reference, format!("{key}.body"), format!("unknown body `{}` (the scene defines: {}).", p.body, names(s.body.keys())))?;
        }
        finite_vec(&format!("{key}.point"), &p.point, dim)?;
    }
    Ok(())
}

/// The time stepping and the solver's tolerances and bounds.
fn validate_stepping(s: &Scene) -> Result<(), Failure> {
    let t = &s.time;
    positive("time.dt".into(), "the time step", t.dt)?;
    positive("time.end".into(), "the end time", t.end)?;
    if !(0.0..=1.0).contains(&t.xi) {
        fail(Invalid, "time.xi", format!("xi must lie in [0, 1] (got {}).", t.xi))?;
    }
    if !(t.theta > 0.0 && t.theta <= 1.0) {
        fail(Invalid, "time.theta", format!("theta must lie in (0, 1] (got {}); theta = 0 leaves the velocity undetermined.", t.theta))?;
    }
    positive("solver.residual_tolerance".into(), "the residual tolerance", s.solver.residual_tolerance)?;
    positive("solver.increment_tolerance".into(), "the increment tolerance", s.solver.increment_tolerance)?;
    for (key, v) in [("solver.max_overlap", s.solver.max_overlap), ("solver.max_step_energy_gain", s.solver.max_step_energy_gain), ("solver.max_energy_gain", s.solver.max_energy_gain)] {
        if v.is_nan() || v <= 0.0 {
            fail(Invalid, key, format!("the bound must be positive, or inf to turn it off (got {v})."))?;
        }
    }
    if s.solver.max_iterations == 0 {
        fail(Invalid, "solver.max_iterations", "at least one Newton iteration is needed.")?;
    }
    let steps = (t.end / t.dt).ceil();
    if steps > s.limits.max_steps as Real {
        let message = format!("{steps:.3e} steps to time.end = {}, more than limits.max_steps = {}; raise the limit (`--set limits.max_steps=N`) if you mean it.", t.end, s.limits.max_steps);
        fail(Invalid, "time.dt", message)?;
    }
    Ok(())
}

/// The steps and generated elements within the scene's limits, and the output cadences.
fn validate_sizes(s: &Scene) -> Result<(), Failure> {
    let mut elements: u128 = 0;
    for (name, b) in &s.body {
        let count = generated_elements(&b.mesh);
        elements = elements.saturating_add(count);
        if elements > s.limits.max_elements as u128 {
            let message = format!("the generated meshes have {elements} elements or more, more than limits.max_elements = {}; raise the limit (`--set limits.max_elements=N`) if you mean it.", s.limits.max_elements);
            fail(Invalid, format!("body.{name}.mesh.divisions"), message)?;
        }
    }
    if s.output.every == 0 {
        fail(Invalid, "output.every", "the output cadence must be at least 1 step.")?;
    }
    if s.output.vtu_every == Some(0) {
        fail(Invalid, "output.vtu_every", "the VTU cadence must be at least 1 step (leave out `output.vtu` for no VTU files).")?;
    }
    if s.output.bodies == BodyLog::Channels && s.body.len() > BodyLog::MAX_CHANNELS {
        let message = format!("`channels` gives each of the scene's {} bodies its own MCAP channel, and a log holds at most {} of them; use \"auto\" or \"batched\" (one `/bodies` message per step).", s.body.len(), BodyLog::MAX_CHANNELS);
        fail(Invalid, "output.bodies", message)?;
    }
    Ok(())
}

/// Every section's names fit for MCAP topics and file names.
fn validate_names(s: &Scene) -> Result<(), Failure> {
    let named = [("material", names_of(&s.material)), ("body", names_of(&s.body)), ("boundary", names_of(&s.boundary)), ("load", names_of(&s.load)), ("probe", names_of(&s.probe)), ("obstacle", names_of(&s.obstacle))];
    for (section, list) in named {
        // Names become MCAP topics and file names.
        if let Some(bad) = list.into_iter().find(|n| n.is_empty() || !n.chars().all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))) {
            fail(Invalid, format!("{section}.{bad}"), "names may only use letters, digits, `_`, `-` and `.` (they become MCAP topics and file names).")?;
        }
    }
    Ok(())
}

/// The bodies: their materials, meshes and initial velocities. Returns the scene's dimension
/// where the generated meshes say it.
fn validate_bodies(s: &Scene) -> Result<Option<usize>, Failure> {
    if s.body.is_empty() {
        fail(Invalid, "body", "the scene has no body.")?;
    }
    let mut dim = None;
    for (name, b) in &s.body {
        let key = format!("body.{name}");
        if !s.material.contains_key(&b.material) {
            fail(Reference, format!("{key}.material"), format!("unknown material `{}` (the scene defines: {}).", b.material, names(s.material.keys())))?;
        }
        validate_mesh(&format!("{key}.mesh"), &b.mesh)?;
        if let Some(d) = generator_dim(&b.mesh) {
            match dim {
                Some(d0) if d0 != d => fail(Invalid, format!("{key}.mesh.generator"), format!("a {d}D body in a {d0}D scene."))?,
                _ => dim = Some(d),
            }
        }
        if let Some(v) = &b.initial_velocity {
            finite_vec(&format!("{key}.initial_velocity"), v, dim)?;
        }
        match (&b.angular_velocity, dim) {
            (Some(AngularVelocity::Spatial(w)), Some(2)) => fail(Invalid, format!("{key}.angular_velocity"), format!("in 2D the angular velocity is one number, got {} components.", w.len()))?,
            (Some(AngularVelocity::Planar(_)), Some(3)) => fail(Invalid, format!("{key}.angular_velocity"), "in 3D the angular velocity is a vector of 3 components.")?,
            (Some(AngularVelocity::Spatial(w)), _) => finite_vec(&format!("{key}.angular_velocity"), w, Some(3))?,
            _ => {}
        }
    }
    Ok(dim)
}

/// The boundary sets: their bodies, stop times, velocities and components.
fn validate_boundaries(s: &Scene, dim: Option<usize>) -> Result<(), Failure> {
    for (name, bc) in &s.boundary {
        let key = format!("boundary.{name}");
        if !s.body.contains_key(&bc.body) {
            fail(Reference, format!("{key}.body"), format!("unknown body `{}` (the scene defines: {}).", bc.body, names(s.body.keys())))?;
        }
        if let Some(until) = bc.until {
            positive(format!("{key}.until"), "the time the motion stops", until)?;
        }
        if let Some(v) = &bc.velocity {
            finite_vec(&format!("{key}.velocity"), v, dim)?;
        }
        if let Some(c) = &bc.components {
            if c.is_empty() {
                fail(Invalid, format!("{key}.components"), "no component is prescribed.")?;
            }
            if dim == Some(2) && c.contains(&Axis::Z) {
                fail(Invalid, format!("{key}.components"), "`z` in a 2D scene.")?;
            }
        }
    }
    Ok(())
}

fn validate_load(s: &Scene, key: &str, load: &LoadSpec, dim: Option<usize>) -> Result<(), Failure> {
    if !s.body.contains_key(&load.body) {
        fail(Reference, format!("{key}.body"), format!("unknown body `{}` (the scene defines: {}).", load.body, names(s.body.keys())))?;
    }
    match (&load.traction, load.pressure) {
        (Some(t), None) => finite_vec(&format!("{key}.traction"), t, dim)?,
        (None, Some(p)) if !p.is_finite() => fail(Invalid, format!("{key}.pressure"), "not a finite number.")?,
        (None, Some(_)) => {}
        _ => fail(Invalid, key, "a load is either a `traction` (a vector) or a `pressure` (a number).")?,
    }
    if !(load.ramp.is_finite() && load.ramp >= 0.0) {
        fail(Invalid, format!("{key}.ramp"), format!("the ramp time must be zero or a positive number (got {}).", load.ramp))?;
    }
    Ok(())
}

fn names_of<V>(map: &std::collections::BTreeMap<String, V>) -> Vec<&String> {
    map.keys().collect()
}

pub(super) fn names<'a>(it: impl Iterator<Item = &'a String>) -> String {
    let v: Vec<&str> = it.map(String::as_str).collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

fn validate_material(key: &str, m: &MaterialSpec) -> Result<(), Failure> {
    positive(format!("{key}.density"), "the density", m.density)?;
    let model = &m.model.0;
    let Some(entry) = Model::entry(model) else { return fail(Invalid, format!("{key}.model"), format!("there is no model `{model}`.")) };
    let takes = || entry.parameters.iter().map(|p| p.name).collect::<Vec<_>>().join(", ");
    if let Some(name) = m.parameters.keys().find(|name| !entry.parameters.iter().any(|p| p.name == name.as_str())) {
        return fail(Invalid, format!("{key}.{name}"), format!("`{name}` is not a parameter of the {model} model (it takes {}).", takes()));
    }
    for parameter in entry.parameters {
        let (name, at) = (parameter.name, format!("{key}.{}", parameter.name));
        let Some(values) = m.parameters.get(name) else {
            match parameter.rule {
                Rule::Optional => continue,
                Rule::Terms => return fail(Invalid, at, format!("the {model} model needs `{name}` (a list of one to three numbers, one per term).")),
                _ => return fail(Invalid, at, format!("the {model} model needs `{name}`.")),
            }
        };
        if parameter.rule == Rule::Terms {
            let v = values.as_slice();
            if v.is_empty() || v.len() > 3 {
                return fail(Invalid, at, format!("give one to three terms (got {}).", v.len()));
            }
            for (i, &x) in v.iter().enumerate() {
                bounded(format!("{at}.{i}"), &format!("term {} of `{name}`", i + 1), x)?;
            }
            continue;
        }
        let Some(v) = values.one() else { return fail(Invalid, at, format!("`{name}` of the {model} model is one number (lists are for models with terms, such as Ogden's).")) };
        match parameter.rule {
            Rule::Modulus => positive(at, &format!("the modulus {name}"), v)?,
            Rule::Positive => positive(at, &format!("the parameter {name}"), v)?,
            _ => bounded(at, &format!("the parameter {name}"), v)?,
        }
    }
    (entry.check)(&m.parameters).or_else(|r| fail(Invalid, format!("{key}.{}", r.parameter), r.message))?;
    if let Some(terms) = &m.viscoelastic {
        validate_prony(key, terms)?;
    }
    Ok(())
}

/// A Prony series: at least one term, each `g` above zero and `tau` above zero, and
/// `Σ g < 1` (a positive long-term modulus).
fn validate_prony(key: &str, terms: &[PronySpec]) -> Result<(), Failure> {
    if terms.is_empty() {
        return fail(Invalid, format!("{key}.viscoelastic"), "give at least one term `{ g = .., tau = .. }` (or leave `viscoelastic` out for an elastic material).");
    }
    for (i, t) in terms.iter().enumerate() {
        positive(format!("{key}.viscoelastic.{i}.g"), "the relative modulus g", t.g)?;
        positive(format!("{key}.viscoelastic.{i}.tau"), "the relaxation time tau", t.tau)?;
    }
    let sum: Real = terms.iter().map(|t| t.g).sum();
    if sum.is_nan() || sum >= 1.0 {
        return fail(Invalid, format!("{key}.viscoelastic"), format!("the relative moduli must sum to less than 1 (got Σ g = {sum}): 1 - Σ g is the share of the isochoric stress left after a long hold."));
    }
    Ok(())
}

fn validate_mesh(key: &str, m: &MeshSpec) -> Result<(), Failure> {
    let Some(generator) = m.generator else {
        if m.file.is_none() {
            return fail(Invalid, key, "a mesh needs either `generator` or `file`.");
        }
        for (field, set) in [
            ("element", m.element.is_some()),
            ("origin", m.origin.is_some()),
            ("size", m.size.is_some()),
            ("divisions", m.divisions.is_some()),
            ("center", m.center.is_some()),
            ("radius", m.radius.is_some()),
            ("radii", m.radii.is_some()),
            ("angle", m.angle.is_some()),
            ("points", m.points.is_some()),
            ("rotation", m.rotation.is_some()),
        ] {
            if set {
                fail(Invalid, format!("{key}.{field}"), "a mesh read from a file takes no generator parameters.")?;
            }
        }
        return Ok(());
    };
    if m.file.is_some() {
        return fail(Invalid, format!("{key}.file"), "give either `generator` or `file`, not both.");
    }
    if m.group.is_some() {
        return fail(Invalid, format!("{key}.group"), "a physical group selects elements of a mesh file; a generated mesh has none.");
    }
    let dim = generator_dim(m).expect("generator set");
    let Some(kind) = m.element else {
        return fail(Invalid, format!("{key}.element"), "a generated mesh needs `element` (tri3, quad4, tet4 or hex8).");
    };
    if kind.dim() != dim {
        fail(Invalid, format!("{key}.element"), format!("{} is a {}D element; this generator makes {dim}D meshes.", kind.name(), kind.dim()))?;
    }
    if let Some(w) = &m.rotation {
        if dim != 3 {
            fail(Invalid, format!("{key}.rotation"), "a rotation turns a 3D mesh (box or ball); place 2D meshes by their points.")?;
        }
        finite_vec(&format!("{key}.rotation"), w, Some(3))?;
    }
    validate_generator(key, m, generator, kind, dim)
}

/// The parameters of one generator.
fn validate_generator(key: &str, m: &MeshSpec, generator: Generator, kind: crate::mesh::ElementKind, dim: usize) -> Result<(), Failure> {
    let need = |field: &str, present: bool| if present { Ok(()) } else { fail(Invalid, format!("{key}.{field}"), format!("this generator needs `{field}`.")) };
    match generator {
        Generator::Rectangle | Generator::Box => {
            need("size", m.size.is_some())?;
            need("divisions", m.divisions.is_some())?;
            let size = m.size.as_deref().unwrap_or_default();
            finite_vec(&format!("{key}.size"), size, Some(dim))?;
            for (i, &l) in size.iter().enumerate() {
                length(format!("{key}.size.{i}"), "an edge length", l)?;
            }
            if let Some(o) = &m.origin {
                finite_vec(&format!("{key}.origin"), o, Some(dim))?;
            }
            let div = m.divisions.as_deref().unwrap_or_default();
            if div.len() != dim {
                fail(Invalid, format!("{key}.divisions"), format!("expected {dim} numbers of cells, got {}.", div.len()))?;
            }
            if let Some(i) = div.iter().position(|&n| n == 0) {
                fail(Invalid, format!("{key}.divisions.{i}"), "at least one cell is needed.")?;
            }
        }
        Generator::Disk | Generator::Ball => {
            need("radius", m.radius.is_some())?;
            length(format!("{key}.radius"), "the radius", m.radius.unwrap_or_default())?;
            if let Some(c) = &m.center {
                finite_vec(&format!("{key}.center"), c, Some(dim))?;
            }
            match m.divisions.as_deref() {
                Some([n]) if *n > 0 => {}
                _ => fail(Invalid, format!("{key}.divisions"), "a disk or ball takes one positive number of cells per radius, e.g. [4].")?,
            }
        }
        Generator::Annulus => {
            need("radii", m.radii.is_some())?;
            match m.radii.as_deref() {
                Some(&[a, b]) if a.is_finite() && b.is_finite() && 0.0 < a && a < b => {}
                _ => fail(Invalid, format!("{key}.radii"), "an annulus takes [inner, outer] radii with 0 < inner < outer.")?,
            }
            if let Some(angle) = m.angle {
                if !(angle > 0.0 && angle <= 360.0) {
                    fail(Invalid, format!("{key}.angle"), format!("the sector's opening must lie in (0, 360] degrees (got {angle})."))?;
                }
            }
            if let Some(c) = &m.center {
                finite_vec(&format!("{key}.center"), c, Some(2))?;
            }
            match m.divisions.as_deref() {
                Some([nr, nt]) if *nr > 0 && *nt > 0 => {}
                _ => fail(Invalid, format!("{key}.divisions"), "an annulus takes [radial, circumferential] numbers of cells, e.g. [8, 16].")?,
            }
        }
        Generator::Polygon => {
            if kind != crate::mesh::ElementKind::Tri3 {
                fail(Invalid, format!("{key}.element"), "the polygon generator makes tri3 meshes.")?;
            }
            need("points", m.points.is_some())?;
            outline(&format!("{key}.points"), m.points.as_deref().unwrap_or_default(), 3)?;
            if !convex(m.points.as_deref().unwrap_or_default()) {
                fail(Invalid, format!("{key}.points"), "the polygon is not convex.")?;
            }
            match m.divisions.as_deref() {
                Some([n]) if *n > 0 => {}
                _ => fail(Invalid, format!("{key}.divisions"), "a polygon takes one positive number of cells from its centre to its outline, e.g. [4].")?,
            }
        }
    }
    Ok(())
}

/// The number of elements a generator will make (0 for a mesh file, whose size is its own),
/// without overflow for absurd divisions.
fn generated_elements(m: &MeshSpec) -> u128 {
    let div: Vec<u128> = m.divisions.iter().flatten().map(|&n| n as u128).collect();
    let product = div.iter().fold(1u128, |p, &n| p.saturating_mul(n));
    let per_cell = match m.element {
        Some(crate::mesh::ElementKind::Tri3) => 2,
        Some(crate::mesh::ElementKind::Tet4) => 6,
        _ => 1,
    };
    match m.generator {
        None => 0,
        Some(Generator::Rectangle | Generator::Box | Generator::Annulus) => product.saturating_mul(per_cell),
        // A disk is a (2n) x (2n) grid mapped onto the circle; a polygon has n² triangles per edge.
        Some(Generator::Disk) => div.first().map_or(0, |&n| (2 * n).saturating_mul(2 * n).saturating_mul(per_cell)),
        Some(Generator::Ball) => div.first().map_or(0, |&n| (2 * n).saturating_mul(2 * n).saturating_mul(2 * n).saturating_mul(per_cell)),
        Some(Generator::Polygon) => div.first().map_or(0, |&n| n.saturating_mul(n).saturating_mul(m.points.as_ref().map_or(0, |p| p.len()) as u128)),
    }
}

/// At least `least` finite 2D points, no two consecutive ones equal.
fn outline(key: &str, points: &[Vec<Real>], least: usize) -> Result<(), Failure> {
    if points.len() < least {
        fail(Invalid, key, format!("at least {least} points are needed."))?;
    }
    for (i, p) in points.iter().enumerate() {
        finite_vec(&format!("{key}.{i}"), p, Some(2))?;
    }
    for i in 0..points.len().saturating_sub(1) {
        if points[i] == points[i + 1] {
            fail(Invalid, format!("{key}.{}", i + 1), "two consecutive points coincide.")?;
        }
    }
    Ok(())
}

pub(super) fn friction(key: String, mu: Real) -> Result<(), Failure> {
    if mu >= 0.0 && mu.is_finite() {
        Ok(())
    } else {
        fail(Invalid, key, format!("a friction coefficient must be zero or positive and finite (got {mu})."))
    }
}

fn validate_contact(s: &Scene, _dim: Option<usize>) -> Result<(), Failure> {
    let c = &s.contact;
    friction("contact.friction".into(), c.friction)?;
    positive("contact.tolerance".into(), "the contact tolerance", c.tolerance)?;
    if c.max_iterations == 0 {
        fail(Invalid, "contact.max_iterations", "at least one Uzawa iteration is needed.")?;
    }
    for (name, pair) in &c.pair {
        let key = format!("contact.pair.{name}");
        if pair.bodies.len() != 2 || pair.bodies[0] == pair.bodies[1] {
            fail(Invalid, format!("{key}.bodies"), "a pair names two different bodies.")?;
        }
        for (i, b) in pair.bodies.iter().enumerate() {
            if !s.body.contains_key(b) {
                fail(Reference, format!("{key}.bodies.{i}"), format!("unknown body `{b}` (the scene defines: {}).", names(s.body.keys())))?;
            }
        }
        if let Some(mu) = pair.friction {
            friction(format!("{key}.friction"), mu)?;
        }
        if let Some(slave) = &pair.slave {
            if !pair.bodies.contains(slave) {
                fail(Reference, format!("{key}.slave"), format!("`{slave}` is not one of the pair's bodies ({}).", pair.bodies.join(", ")))?;
            }
        }
    }
    Ok(())
}

fn validate_obstacle(s: &Scene, key: &str, o: &ObstacleSpec, dim: Option<usize>) -> Result<(), Failure> {
    let fields = [("point", o.point.is_some()), ("normal", o.normal.is_some()), ("min", o.min.is_some()), ("max", o.max.is_some()), ("inside", o.inside.is_some()), ("points", o.points.is_some())];
    let wanted: &[&str] = match o.shape {
        ObstacleShape::Plane => &["point", "normal"],
        ObstacleShape::Box => &["min", "max", "inside"],
        ObstacleShape::Polygon | ObstacleShape::Polyline => &["points"],
    };
    let optional = ["inside"];
    for (field, present) in fields {
        match (wanted.contains(&field), present) {
            (false, true) => fail(Invalid, format!("{key}.{field}"), format!("a {:?} obstacle takes {}.", o.shape, wanted.join(", ")).to_lowercase())?,
            (true, false) if !optional.contains(&field) => fail(Invalid, format!("{key}.{field}"), format!("this obstacle needs `{field}`."))?,
            _ => {}
        }
    }
    if let Some(p) = &o.point {
        finite_vec(&format!("{key}.point"), p, dim)?;
    }
    if let Some(n) = &o.normal {
        finite_vec(&format!("{key}.normal"), n, dim)?;
        if n.iter().all(|&x| x == 0.0) {
            fail(Invalid, format!("{key}.normal"), "the normal is zero.")?;
        }
    }
    if let (Some(lo), Some(hi)) = (&o.min, &o.max) {
        finite_vec(&format!("{key}.min"), lo, dim)?;
        finite_vec(&format!("{key}.max"), hi, Some(lo.len()))?;
        if let Some(i) = (0..lo.len()).find(|&i| hi[i] <= lo[i]) {
            fail(Invalid, format!("{key}.max.{i}"), format!("max must exceed min in every direction ({} <= {}).", hi[i], lo[i]))?;
        }
    }
    if let Some(points) = &o.points {
        if dim == Some(3) {
            fail(Invalid, format!("{key}.shape"), "polygons and polylines are 2D obstacles; use planes or boxes in 3D.")?;
        }
        outline(&format!("{key}.points"), points, if o.shape == ObstacleShape::Polygon { 3 } else { 2 })?;
        if o.shape == ObstacleShape::Polygon && !convex(points) {
            fail(Invalid, format!("{key}.points"), "the polygon is not convex; build a concave outline from polylines.")?;
        }
    }
    if let Some(mu) = o.friction {
        friction(format!("{key}.friction"), mu)?;
    }
    if o.velocity.is_some() && o.motion.is_some() {
        fail(Invalid, format!("{key}.motion"), "give either `velocity` or `motion`, not both.")?;
    }
    if o.interpolation.is_some() && o.motion.is_none() {
        fail(Invalid, format!("{key}.interpolation"), "`interpolation` applies to a `motion` table.")?;
    }
    if let Some(v) = &o.velocity {
        finite_vec(&format!("{key}.velocity"), v, dim)?;
    }
    if let Some(rows) = &o.motion {
        if rows.is_empty() {
            fail(Invalid, format!("{key}.motion"), "the motion table is empty.")?;
        }
        for (i, row) in rows.iter().enumerate() {
            let width = dim.map(|d| d + 1);
            finite_vec(&format!("{key}.motion.{i}"), row, None)?;
            if width.is_some_and(|w| row.len() != w) || row.len() < 3 {
                fail(Invalid, format!("{key}.motion.{i}"), "each row is [t, vx, vy] in 2D or [t, vx, vy, vz] in 3D.")?;
            }
            if i > 0 && row[0] <= rows[i - 1][0] {
                fail(Invalid, format!("{key}.motion.{i}"), "the times of the motion table must increase.")?;
            }
        }
    }
    if let Some(bodies) = &o.bodies {
        for (i, b) in bodies.iter().enumerate() {
            if !s.body.contains_key(b) {
                fail(Reference, format!("{key}.bodies.{i}"), format!("unknown body `{b}` (the scene defines: {}).", names(s.body.keys())))?;
            }
        }
    }
    Ok(())
}

/// Whether the closed polygon turns the same way at every vertex.
fn convex(points: &[Vec<Real>]) -> bool {
    let n = points.len();
    let turns: Vec<Real> = (0..n)
        .map(|i| {
            let (a, b, c) = (&points[i], &points[(i + 1) % n], &points[(i + 2) % n]);
            (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
        })
        .collect();
    turns.iter().all(|&t| t > 0.0) || turns.iter().all(|&t| t < 0.0)
}
