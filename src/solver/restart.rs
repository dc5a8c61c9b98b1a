//! The state a run continues from (`bifirst run --restart`): everything a step reads from the
//! steps before it, so that a restarted run repeats the uninterrupted one to round-off.

use super::Simulation;
use crate::contact::{Master, WarmStart};
use crate::precision::Real;
use serde::{Deserialize, Serialize};

/// A finished step's state: time, step, every body's state, the energy accumulators, the
/// contact reactions and rho (the next step's warm start) and the kept factorisations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[schemars(title = "bifirst.SavedState")]
pub struct SavedState {
    pub t: Real,
    pub step: usize,
    pub initial_energy: Real,
    pub external_work: Real,
    pub friction_dissipation: Real,
    /// Cumulative work of the viscoelastic overstress (absent in logs written before
    /// viscoelasticity: 0).
    #[serde(default)]
    pub viscous_dissipation: Real,
    pub numerical_dissipation: Real,
    pub contact_correction: Real,
    /// Step control: the cut-back level the next step starts at and the easy steps taken at
    /// it (absent in logs written before step control: level 0).
    #[serde(default)]
    pub step_level: usize,
    #[serde(default)]
    pub easy_steps: usize,
    /// The deepest overlap the last step left, in element sizes (step control's reference).
    #[serde(default)]
    pub last_overlap: Real,
    /// What the state was computed on (absent in logs written before restarts checked it).
    #[serde(default)]
    pub fingerprint: Option<Fingerprint>,
    pub bodies: Vec<SavedBody>,
    pub contact: Vec<SavedReaction>,
    pub obstacle_reactions: Vec<[Real; 3]>,
}

/// One body's state, by name.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct SavedBody {
    pub name: String,
    pub u: Vec<Real>,
    pub v: Vec<Real>,
    pub f_int: Vec<Real>,
    pub strain: Real,
    /// Reactions of the prescribed dofs.
    pub reactions: Vec<Real>,
    /// The effective stiffness of the factorisation the body keeps across steps, if any.
    pub factor: Option<SavedFactor>,
    /// What each quadrature point of a viscoelastic body keeps between steps (empty, or absent,
    /// without a Prony series).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub viscous: Vec<Real>,
    /// What the Prony branches hold beyond `strain` (absent without a Prony series, and in logs
    /// written before it was saved, whose restarts estimate it from `viscous`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub branch_energy: Option<Real>,
}

/// Hashes (FNV-1a, 16 hex digits) of what a saved state is only valid for, over every body in
/// order: a restart onto a changed mesh or material would run on with the forces and energies
/// of other bodies. Two hashes per state, not per body: a packing's log stays its size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Fingerprint {
    /// Element kinds, reference node coordinates and connectivity.
    pub mesh: String,
    /// Material models and parameters, element formulations and nodal masses (density).
    pub material: String,
}

impl Fingerprint {
    fn of(bodies: &[super::Body]) -> Self {
        let (mut mesh, mut material) = (Fnv::default(), Fnv::default());
        for body in bodies {
            mesh.bytes(body.def.mesh.kind.name().as_bytes());
            body.def.mesh.nodes.iter().flatten().for_each(|x| mesh.bytes(&x.to_le_bytes()));
            body.def.mesh.connectivity.iter().for_each(|i| mesh.bytes(&i.to_le_bytes()));
            material.bytes(format!("{:?} {:?}", body.def.model, body.def.formulation).as_bytes());
            if let Some(v) = &body.def.viscoelastic {
                material.bytes(format!(" {v:?}").as_bytes());
            }
            body.def.mass.iter().for_each(|m| material.bytes(&m.to_le_bytes()));
        }
        Self { mesh: mesh.hex(), material: material.hex() }
    }
}

/// FNV-1a, 64 bits: stable across builds and platforms, unlike the standard library's hasher.
struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    fn bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }

    fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// The values `K̄ = ξ K + c1 M` a kept factorisation was made from: factorised again on restart,
/// they give the factor the uninterrupted run would have reused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct SavedFactor {
    pub c1: Real,
    pub values: Vec<Real>,
}

/// A contact point's reaction and rho, under the point's identity across steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct SavedReaction {
    pub slave_body: u32,
    pub slave_node: u32,
    pub master: Master,
    /// The node's second point on that master, in a concave corner (absent: the first).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub corner: bool,
    pub r: [Real; 3],
    pub rho: Real,
}

/// Why a saved state does not fit a scene.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    #[error("the state has {saved} bodies, the scene {scene}")]
    BodyCount { saved: usize, scene: usize },
    #[error("body `{name}`: the state has {saved} dofs, the scene's mesh {scene} (the mesh must not change on restart)")]
    Dofs { name: String, saved: usize, scene: usize },
    #[error("the state's body {index} is `{saved}`, the scene's `{scene}`")]
    Name { index: usize, saved: String, scene: String },
    #[error("time.end = {end} is not after the state's t = {t}; continue with --set time.end=...")]
    Ended { end: Real, t: Real },
    #[error("body `{name}`: the saved factorisation does not fit ({message})")]
    Factor { name: String, message: String },
    #[error("the bodies' {what} differ from those of the run that saved the state; a restart continues the same bodies (start a new run to change them)")]
    Changed { what: &'static str },
    #[error("body `{name}`: the state keeps {saved} viscoelastic values, the scene's body {scene} (its Prony series must not change on restart)")]
    Viscous { name: String, saved: usize, scene: usize },
    #[error("the state's {what} is {value}: not a state a run can continue from")]
    BadValue { what: String, value: Real },
}

impl Simulation {
    /// The state after the last finished step.
    pub fn saved_state(&self) -> SavedState {
        assert!(self.bodies.iter().all(|b| b.held_state().is_none()), "the states are the host's (Simulation::sync_states)");
        assert!(self.bodies.iter().all(|b| !b.factor_on_device()), "the factorisations are the host's (Simulation::sync_factors)");
        SavedState {
            t: self.t,
            step: self.step,
            initial_energy: self.initial_energy,
            external_work: self.external_work,
            friction_dissipation: self.friction_dissipation,
            viscous_dissipation: self.viscous_dissipation,
            numerical_dissipation: self.numerical_dissipation,
            contact_correction: self.contact_correction,
            step_level: self.level,
            easy_steps: self.easy_steps,
            last_overlap: self.last_overlap,
            fingerprint: Some(Fingerprint::of(&self.bodies)),
            bodies: self
                .bodies
                .iter()
                .map(|b| SavedBody {
                    name: b.def.name.clone(),
                    u: b.committed.state.u.clone(),
                    v: b.committed.state.v.clone(),
                    f_int: b.committed.state.f_int.clone(),
                    strain: b.committed.state.strain,
                    reactions: b.work.reactions.clone(),
                    factor: b.kept_factor().map(|(c1, values)| SavedFactor { c1, values: values.to_vec() }),
                    viscous: b.committed.state.viscous.clone(),
                    branch_energy: b.def.viscoelastic.is_some().then_some(b.committed.state.branch_energy),
                })
                .collect(),
            contact: {
                let mut points: Vec<SavedReaction> = self.warm_start().into_iter().map(|((slave_body, slave_node, master, corner), (r, rho))| SavedReaction { slave_body, slave_node, master, corner, r, rho }).collect();
                points.sort_by_key(|c| (c.slave_body, c.slave_node, c.master, c.corner));
                points
            },
            obstacle_reactions: self.obstacle_reactions.clone(),
        }
    }

    /// Continues from `saved` instead of t = 0 (in place of [`Simulation::start`]), with the
    /// factorisations the run kept.
    pub fn restore(&mut self, saved: &SavedState) -> Result<(), RestoreError> {
        if self.end <= saved.t {
            return Err(RestoreError::Ended { end: self.end, t: saved.t });
        }
        self.load_state(saved)?;
        for (b, s) in self.bodies.iter_mut().zip(&saved.bodies) {
            if let Some(f) = &s.factor {
                b.restore_factor(f.c1, &f.values).map_err(|message| RestoreError::Factor { name: b.def.name.clone(), message })?;
            }
        }
        Ok(())
    }

    /// Puts the bodies, time, step, energies and reactions of `saved` in place: enough to draw
    /// or export that state; [`Simulation::restore`] also brings back the factorisations.
    pub fn load_state(&mut self, saved: &SavedState) -> Result<(), RestoreError> {
        if saved.bodies.len() != self.bodies.len() {
            return Err(RestoreError::BodyCount { saved: saved.bodies.len(), scene: self.bodies.len() });
        }
        for (index, (b, s)) in self.bodies.iter().zip(&saved.bodies).enumerate() {
            if b.def.name != s.name {
                return Err(RestoreError::Name { index, saved: s.name.clone(), scene: b.def.name.clone() });
            }
            let n = b.committed.state.u.len();
            if [s.u.len(), s.v.len(), s.f_int.len()].iter().any(|&len| len != n) || s.reactions.len() != b.work.reactions.len() {
                return Err(RestoreError::Dofs { name: b.def.name.clone(), saved: s.u.len(), scene: n });
            }
            if s.viscous.len() != b.committed.state.viscous.len() {
                return Err(RestoreError::Viscous { name: b.def.name.clone(), saved: s.viscous.len(), scene: b.committed.state.viscous.len() });
            }
        }
        if let Some(saved) = &saved.fingerprint {
            let scene = Fingerprint::of(&self.bodies);
            if saved.mesh != scene.mesh {
                return Err(RestoreError::Changed { what: "meshes (element kinds, node coordinates or connectivity)" });
            }
            if saved.material != scene.material {
                return Err(RestoreError::Changed { what: "materials, formulations or densities" });
            }
        }
        check_values(saved)?;
        if let Some(world) = &mut self.world {
            world.forget_committed();
        }
        for (b, s) in self.bodies.iter_mut().zip(&saved.bodies) {
            (b.committed.state_held, b.work.trial_held) = (None, None);
            b.committed.state.u.clone_from(&s.u);
            b.committed.state.v.clone_from(&s.v);
            b.committed.state.f_int.clone_from(&s.f_int);
            b.committed.state.strain = s.strain;
            b.committed.state.strain_at_u = false;
            b.committed.state.viscous.clone_from(&s.viscous);
            match s.branch_energy {
                Some(e) => b.committed.state.branch_energy = e,
                None => b.refresh_branch_energy(),
            }
            b.work.reactions.clone_from(&s.reactions);
        }
        self.committed = None;
        self.t = saved.t;
        self.step = saved.step;
        self.first_step = (saved.t, saved.step);
        self.initial_energy = saved.initial_energy;
        self.external_work = saved.external_work;
        self.friction_dissipation = saved.friction_dissipation;
        self.viscous_dissipation = saved.viscous_dissipation;
        self.numerical_dissipation = saved.numerical_dissipation;
        self.contact_correction = saved.contact_correction;
        (self.level, self.easy_steps, self.last_overlap) = (saved.step_level, saved.easy_steps, saved.last_overlap);
        self.obstacle_reactions.clone_from(&saved.obstacle_reactions);
        self.restored_warm_start = Some(saved.contact.iter().map(|c| ((c.slave_body, c.slave_node, c.master, c.corner), (c.r, c.rho))).collect());
        // Finite values can still overflow the energies (a velocity of 1e308).
        let energies = self.energies();
        for (what, value) in [("kinetic energy", energies.kinetic), ("strain energy", energies.strain), ("total energy", energies.total)] {
            if !value.is_finite() {
                return Err(RestoreError::BadValue { what: what.into(), value });
            }
        }
        Ok(())
    }

    /// The reactions and rho the next step starts its Uzawa sweeps from, by point identity.
    pub(super) fn warm_start(&self) -> WarmStart {
        match &self.restored_warm_start {
            Some(warm) => warm.clone(),
            None => self.contact_points.iter().map(|c| (c.key(), (c.r, c.rho))).collect(),
        }
    }
}

/// Refuses a state with a negative or non-finite time, or any non-finite value.
fn check_values(saved: &SavedState) -> Result<(), RestoreError> {
    let bad = |what: String, value: Real| Err(RestoreError::BadValue { what, value });
    if !saved.t.is_finite() || saved.t < 0.0 {
        return bad("time t".into(), saved.t);
    }
    let scalars = [
        ("initial_energy", saved.initial_energy),
        ("external_work", saved.external_work),
        ("friction_dissipation", saved.friction_dissipation),
        ("viscous_dissipation", saved.viscous_dissipation),
        ("numerical_dissipation", saved.numerical_dissipation),
        ("contact_correction", saved.contact_correction),
        ("last_overlap", saved.last_overlap),
    ];
    if let Some((what, value)) = scalars.into_iter().find(|(_, x)| !x.is_finite()) {
        return bad(what.into(), value);
    }
    for b in &saved.bodies {
        let fields = [("u", &b.u), ("v", &b.v), ("f_int", &b.f_int), ("reactions", &b.reactions), ("viscous", &b.viscous)];
        for (field, values) in fields {
            if let Some((i, &x)) = values.iter().enumerate().find(|(_, x)| !x.is_finite()) {
                return bad(format!("body `{}` {field}[{i}]", b.name), x);
            }
        }
        if !b.strain.is_finite() {
            return bad(format!("body `{}` strain", b.name), b.strain);
        }
        if let Some((i, &x)) = b.factor.iter().flat_map(|f| std::iter::once(&f.c1).chain(&f.values)).enumerate().find(|(_, x)| !x.is_finite()) {
            return bad(format!("body `{}` factor value {i}", b.name), x);
        }
    }
    if let Some(c) = saved.contact.iter().find(|c| !(c.rho.is_finite() && c.r.iter().all(|x| x.is_finite()))) {
        return bad(format!("contact reaction at node {} of body {}", c.slave_node, c.slave_body), c.r.iter().copied().find(|x| !x.is_finite()).unwrap_or(c.rho));
    }
    if let Some(r) = saved.obstacle_reactions.iter().flatten().find(|x| !x.is_finite()) {
        return bad("obstacle reaction".into(), *r);
    }
    Ok(())
}
