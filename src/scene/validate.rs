//! Checks that need no mesh: ranges, references between sections, vector lengths.
//! Checks that need the mesh (node sets, element quality, file contents) run at set-up.

use super::error::SceneErrorKind::{self, Invalid, Reference};
use super::types::*;
use crate::precision::Real;

type Failure = (SceneErrorKind, String, String);

fn fail(kind: SceneErrorKind, key: impl Into<String>, message: impl Into<String>) -> Result<(), Failure> {
    Err((kind, key.into(), message.into()))
}

fn positive(key: String, what: &str, v: Real) -> Result<(), Failure> {
    if v > 0.0 && v.is_finite() {
        Ok(())
    } else {
        fail(Invalid, key, format!("{what} must be positive and finite (got {v})."))
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
        Generator::Rectangle | Generator::Disk => 2,
        Generator::Box => 3,
    })
}

pub(super) fn validate(s: &Scene) -> Result<(), Failure> {
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
    if s.solver.max_iterations == 0 {
        fail(Invalid, "solver.max_iterations", "at least one Newton iteration is needed.")?;
    }
    if s.output.every == 0 {
        fail(Invalid, "output.every", "the output cadence must be at least 1 step.")?;
    }
    for (name, m) in &s.material {
        validate_material(&format!("material.{name}"), m)?;
    }
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
            (Some(AngularVelocity::Spatial(w)), Some(2)) => {
                fail(Invalid, format!("{key}.angular_velocity"), format!("in 2D the angular velocity is one number, got {} components.", w.len()))?
            }
            (Some(AngularVelocity::Planar(_)), Some(3)) => fail(Invalid, format!("{key}.angular_velocity"), "in 3D the angular velocity is a vector of 3 components.")?,
            (Some(AngularVelocity::Spatial(w)), _) => finite_vec(&format!("{key}.angular_velocity"), w, Some(3))?,
            _ => {}
        }
    }
    if let Some(g) = &s.gravity {
        finite_vec("gravity", g, dim)?;
    }
    for (name, bc) in &s.boundary {
        let key = format!("boundary.{name}");
        if !s.body.contains_key(&bc.body) {
            fail(Reference, format!("{key}.body"), format!("unknown body `{}` (the scene defines: {}).", bc.body, names(s.body.keys())))?;
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
    for (name, p) in &s.probe {
        let key = format!("probe.{name}");
        if !s.body.contains_key(&p.body) {
            fail(Reference, format!("{key}.body"), format!("unknown body `{}` (the scene defines: {}).", p.body, names(s.body.keys())))?;
        }
        finite_vec(&format!("{key}.point"), &p.point, dim)?;
    }
    Ok(())
}

fn names<'a>(it: impl Iterator<Item = &'a String>) -> String {
    let v: Vec<&str> = it.map(String::as_str).collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

fn validate_material(key: &str, m: &MaterialSpec) -> Result<(), Failure> {
    positive(format!("{key}.density"), "the density", m.density)?;
    let (required, allowed): (&[&str], &[&str]) = match m.model {
        ModelName::BlatzKo => (&["G"], &["G"]),
        ModelName::NeoHookean => (&["G", "K"], &["G", "K"]),
        ModelName::Lvf => (&["G", "K"], &["G", "K", "a1", "a2", "a3", "a4", "a5"]),
    };
    let params = [("G", m.G), ("K", m.K), ("a1", m.a1), ("a2", m.a2), ("a3", m.a3), ("a4", m.a4), ("a5", m.a5)];
    let model = serde_json::to_value(m.model).ok().and_then(|v| v.as_str().map(str::to_owned)).unwrap_or_default();
    for (p, v) in params {
        match v {
            Some(_) if !allowed.contains(&p) => fail(Invalid, format!("{key}.{p}"), format!("`{p}` is not a parameter of the {model} model (it takes {}).", allowed.join(", ")))?,
            None if required.contains(&p) => fail(Invalid, format!("{key}.{p}"), format!("the {model} model needs `{p}`."))?,
            Some(v) if required.contains(&p) => positive(format!("{key}.{p}"), &format!("the modulus {p}"), v)?,
            Some(v) if !v.is_finite() => fail(Invalid, format!("{key}.{p}"), "not a finite number.")?,
            _ => {}
        }
    }
    Ok(())
}

fn validate_mesh(key: &str, m: &MeshSpec) -> Result<(), Failure> {
    let Some(generator) = m.generator else {
        if m.file.is_none() {
            return fail(Invalid, key, "a mesh needs either `generator` or `file`.");
        }
        for (field, set) in [("element", m.element.is_some()), ("origin", m.origin.is_some()), ("size", m.size.is_some()), ("divisions", m.divisions.is_some()), ("center", m.center.is_some()), ("radius", m.radius.is_some())] {
            if set {
                fail(Invalid, format!("{key}.{field}"), "a mesh read from a file takes no generator parameters.")?;
            }
        }
        return Ok(());
    };
    if m.file.is_some() {
        return fail(Invalid, format!("{key}.file"), "give either `generator` or `file`, not both.");
    }
    let dim = generator_dim(m).expect("generator set");
    let Some(kind) = m.element else {
        return fail(Invalid, format!("{key}.element"), "a generated mesh needs `element` (tri3, quad4, tet4 or hex8).");
    };
    if kind.dim() != dim {
        fail(Invalid, format!("{key}.element"), format!("{} is a {}D element; this generator makes {dim}D meshes.", kind.name(), kind.dim()))?;
    }
    let need = |field: &str, present: bool| if present { Ok(()) } else { fail(Invalid, format!("{key}.{field}"), format!("this generator needs `{field}`.")) };
    match generator {
        Generator::Rectangle | Generator::Box => {
            need("size", m.size.is_some())?;
            need("divisions", m.divisions.is_some())?;
            let size = m.size.as_deref().unwrap_or_default();
            finite_vec(&format!("{key}.size"), size, Some(dim))?;
            for (i, &l) in size.iter().enumerate() {
                positive(format!("{key}.size.{i}"), "an edge length", l)?;
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
        Generator::Disk => {
            need("radius", m.radius.is_some())?;
            positive(format!("{key}.radius"), "the radius", m.radius.unwrap_or_default())?;
            if let Some(c) = &m.center {
                finite_vec(&format!("{key}.center"), c, Some(2))?;
            }
            match m.divisions.as_deref() {
                Some([n]) if *n > 0 => {}
                _ => fail(Invalid, format!("{key}.divisions"), "a disk takes one positive number of cells per radius, e.g. [4].")?,
            }
        }
    }
    Ok(())
}
