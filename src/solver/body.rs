//! A deformable body at run time: mesh, material, lumped mass, constraints, state, and the
//! Newton solve of one theta-method step (paper eqs. 16-19).

use super::linear::CholeskySolver;
use super::topology::Topology;
use crate::assembly::{element_out_stride, DofMap, GatherMap, StiffnessPattern};
use crate::cpu::{assemble_csr, assemble_residual, dispatch_element_force_tangent, element_energy, element_force_tangent};
use crate::element::{element_cell_fields, element_point_fields, element_von_mises, point_gradients, CellFields, ElementError, ElementOutput, Formulation, Patches, ReferenceGeometry};
use crate::gpu::types::{Coefficients, DofOut, DofStep};
use crate::gpu::types::{NewtonMember, NewtonState, StepSummary};
use crate::gpu::{ElementFailure, Evaluation, GpuError, Inverse, NewtonCall, StepEnd, StepStart, WorldBody};
use crate::gpu::{KeptIterate, KeptState};
use crate::material::tensor::green_lagrange;
use crate::material::viscous::HISTORY;
use crate::material::{BranchStep, Hyperelastic, Model, Relaxation, Viscoelastic};
use crate::mesh::Mesh;
use crate::policy::{PhaseTimes, REFACTOR_CONTRACTION};
use crate::precision::{same_bits, Real};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

mod device;

/// Displacement, velocity and internal force of every dof.
#[derive(Debug, Clone)]
pub struct State {
    pub u: Vec<Real>,
    pub v: Vec<Real>,
    pub f_int: Vec<Real>,
    /// Strain energy `Σ ∫ W dV`.
    pub strain: Real,
    /// `strain` was computed by `element_energy` at `u` (not set at t = 0 or by a restore).
    pub strain_at_u: bool,
    /// What each quadrature point of a viscoelastic body keeps between steps
    /// ([`Viscoelastic::advance`]); empty without a Prony series.
    pub viscous: Vec<Real>,
    /// What the Prony branches hold beyond `strain`: the work of their overstress less what they
    /// dissipated, summed over the steps ([`Viscoelastic::advance`]).
    pub branch_energy: Real,
}

/// A Newton criterion that a body's convergence test found unmet, kept as numbers: most
/// iterations are not converged yet, and wording each of them cost 3 % of a packing's run.
#[derive(Debug, Clone, Copy)]
pub(super) enum Unmet {
    Residual { residual: Real, tolerance: Real, setting: Real, scale: Real, floor: Real },
    Increment { du: Real, allowed: Real, setting: Real },
}

/// A prescribed dof: its velocity, constant until `until` (then zero: the dof holds), and the
/// boundary set that owns its reaction.
#[derive(Debug, Clone, Copy)]
pub struct Prescribed {
    pub dof: usize,
    pub velocity: Real,
    pub set: usize,
    pub until: Real,
}

impl Prescribed {
    /// How far the dof moves from `t` to `t + dt`.
    fn travel(&self, t: Real, dt: Real) -> Real {
        self.velocity * ((t + dt).min(self.until) - t.min(self.until))
    }

    /// The velocity just after time `t`.
    fn velocity_after(&self, t: Real) -> Real {
        if t < self.until {
            self.velocity
        } else {
            0.0
        }
    }
}

/// The assembly coefficients of a step: `ξ` on the stiffness, `c1 = 1/(θ dt²)` on the mass.
pub fn coefficients(p: &StepParams) -> Coefficients<Real> {
    Coefficients { factor: p.xi, c1: 1.0 / (p.theta * p.dt * p.dt), motion: 0.0 }
}

/// Theta-method and Newton parameters of a step.
#[derive(Debug, Clone, Copy)]
pub struct StepParams {
    pub dt: Real,
    pub xi: Real,
    pub theta: Real,
    pub residual_tolerance: Real,
    pub increment_tolerance: Real,
    pub max_iterations: usize,
}

/// Why a step failed (it is then retried with a smaller time step).
#[derive(Debug, Clone, thiserror::Error)]
pub enum StepFailure {
    /// `limit`: what a non-finite stress means for the body's material ([`Model::limit`]).
    #[error("body `{body}`: element {element}: {error}{}", limit.map(|l| format!("; {l}")).unwrap_or_default())]
    Element { body: String, element: usize, error: ElementError, limit: Option<&'static str> },
    #[error("body `{body}`: {error}")]
    Linear { body: String, error: String },
    /// `bodies` names the bodies that iterated together (coupled by contact); `unmet` says which
    /// convergence criteria the last iteration still missed.
    #[error("{bodies}: Newton did not converge in {iterations} iterations ({unmet}); a residual that stalls above its tolerance while the increment has converged is round-off: raise solver.residual_tolerance; one that falls slowly needs solver.max_iterations or a smaller time.dt")]
    NotConverged { bodies: String, iterations: usize, unmet: String },
    #[error("body `{body}`: the residual is not finite")]
    NotFinite { body: String },
    #[error("body `{body}`: {error}")]
    Device { body: String, error: String },
    /// A step solved with the second contact pass thinned let a node through (depth over its
    /// element size); it is cut back instead.
    #[error("with the second contact pass thinned, a node went {ratio:.3} elements deep")]
    ThinnedPenetration { ratio: Real },
    /// The step ended with a node deeper inside another body (or behind an obstacle) than
    /// `solver.max_overlap` of its element: it is retried smaller.
    #[error("a node went {ratio:.3e} elements deep (solver.max_overlap = {bound:.3e})")]
    Overlap { ratio: Real, bound: Real },
    /// The step created energy (its numerical dissipation was negative) beyond
    /// `solver.max_step_energy_gain` of the energy scale: it is retried with θ = ξ = 1 if it
    /// had contact reactions (an impact), then smaller.
    #[error("the step created {gain:.3e} of the energy scale (solver.max_step_energy_gain = {bound:.3e})")]
    EnergyGain { gain: Real, bound: Real, contact: bool },
    /// The run's interrupt flag was set during the step: it is abandoned, not cut back.
    #[error("interrupted during the step")]
    Interrupted,
}

/// Energy terms of one body over a step (see doc/ARCHITECTURE.md, "Energy balance").
#[derive(Debug, Clone, Copy, Default)]
pub struct StepEnergy {
    /// `(θ - 1/2) Σ m (v - v_t)²`: the theta scheme's own dissipation.
    pub theta_dissipation: Real,
    /// `Δu · ((1-ξ) F_int,t + ξ F_int) - ΔW - ΔW_branches - D_viscous`: the xi weighting's
    /// deviation from the strain energy, the Prony branches' included.
    pub force_dissipation: Real,
    /// Work of the support reactions, `Σ R_c Δu_c`.
    pub support_work: Real,
    /// Work of the surface loads, `Σ f_load Δu`.
    pub load_work: Real,
    /// What the Prony branches dissipated along their exact path over the step
    /// ([`Viscoelastic::advance`]); never below zero.
    pub viscous_dissipation: Real,
}

/// A surface load (`[load.*]`) as nodal forces: dead (reference configuration), scaled in time
/// by a linear ramp.
#[derive(Debug, Clone)]
pub struct NodalLoad {
    /// Full nodal force per loaded dof.
    pub forces: Vec<(usize, Real)>,
    /// The load grows linearly from zero at t = 0 to full at t = `ramp` (0: full at once).
    pub ramp: Real,
}

impl NodalLoad {
    /// The share of the full load at time `t`.
    pub fn factor(&self, t: Real) -> Real {
        if self.ramp > 0.0 {
            (t / self.ramp).clamp(0.0, 1.0)
        } else {
            1.0
        }
    }
}

/// A deformable body: its definition, its committed state and the work of the step being solved.
pub struct Body {
    /// What does not change in a run.
    pub(super) def: Definition,
    /// The committed state.
    pub(super) committed: Committed,
    /// The step being solved: its trial state, the factorisation and what the residual and
    /// the tests of convergence are made of.
    pub(super) work: Workspace,
}

/// What does not change in a run: the mesh and what the kernels integrate, the material, the
/// masses, the dof numbering and the stiffness pattern, the prescribed dofs and the loads, and
/// the scales the tests of convergence take.
pub struct Definition {
    pub(super) name: String,
    pub(super) mesh: Mesh,
    /// The F-bar patches of an unstructured simplex mesh, which the element kernels integrate
    /// instead of the mesh's own elements ([`Body::elements`]).
    pub(super) patches: Option<Patches>,
    /// The geometry of what the element kernels integrate.
    pub(super) geometry: ReferenceGeometry,
    pub(super) model: Model,
    /// The material's Prony series, if it has one.
    pub(super) viscoelastic: Option<Viscoelastic>,
    /// How the elements take the volume change (F-bar for nearly incompressible materials).
    pub(super) formulation: Formulation,
    pub(super) dim: usize,
    /// Lumped mass of each dof.
    pub(super) mass: Vec<Real>,
    pub(super) dofs: Arc<DofMap>,
    pub(super) pattern: Arc<StiffnessPattern>,
    pub(super) prescribed: Vec<Prescribed>,
    /// Smallest edge length: the floor of the increment test.
    pub(super) length_scale: Real,
    /// Largest dof mass: with `length_scale`, sets the residual floor below round-off.
    pub(super) max_mass: Real,
    /// Largest element stiffness `(K + 4G/3) h^(dim-2)`: with `length_scale`, the round-off a
    /// stiff volumetric term leaves in the internal forces ([`Body::residual_floor`]).
    pub(super) stiffness_scale: Real,
    /// Which element results sum into each stiffness value and each dof.
    pub(super) gather: Arc<GatherMap>,
    /// The surface loads on this body (`[load.*]`), and their nodal forces in this step.
    pub(super) loads: Vec<NodalLoad>,
    /// Keep a factorisation across Newton iterations and steps while it contracts the residual
    /// fast enough ([`REFACTOR_CONTRACTION`]); `false` refactorises every iteration.
    pub(super) reuse_factorization: bool,
}

/// The committed state, and whether the device holds it.
pub struct Committed {
    pub(super) state: State,
    /// The committed state is the device's ([`crate::gpu::StepEnd::held`]): `state`'s vectors
    /// and strain energy are stale, and what the host books of it comes from this summary (its
    /// strain energy from the device's sum, [`crate::gpu::GpuWorld::held_strain`]), until
    /// [`Body::take_committed`] brings it back.
    pub(super) state_held: Option<StepSummary>,
    /// While the state (the trial) is held: its displacements are the host's all the same
    /// ([`crate::gpu::NewtonCall::positions`]).
    pub(super) state_positions: bool,
}

/// The step being solved: its trial state and reactions, the factorisation and the matrix
/// values, the element results, the parts of the residual, what the tests of convergence
/// keep between iterations, and whether the device holds the trial.
pub struct Workspace {
    /// When the step being solved ends.
    pub(super) step_end: Real,
    /// The step's relaxation `c` and each quadrature point's history `H` ([`Body::begin_step`]).
    pub(super) relaxation_c: Real,
    pub(super) history: Vec<Real>,
    /// The state of the step being solved, committed by [`Body::commit`].
    pub(super) trial: State,
    /// Reaction at each prescribed dof (same order as `prescribed`) at the end of the trial step.
    pub(super) reactions: Vec<Real>,
    pub(super) solver: CholeskySolver,
    pub(super) values: Vec<Real>,
    /// Every element's force and tangent (`element_out_stride` entries per element).
    pub(super) element_results: Vec<Real>,
    /// The step's start values of every dof, for `assemble_residual`.
    pub(super) step_inputs: Vec<DofStep<Real>>,
    pub(super) dof_out: Vec<DofOut<Real>>,
    /// What `dof_out` was last computed from on the CPU (forces only).
    pub(super) evaluated: EvaluatedAt,
    pub(super) f_ext: Vec<Real>,
    pub(super) f_load: Vec<Real>,
    /// Contact-free residual of the last evaluation, every dof.
    pub(super) g: Vec<Real>,
    /// Nodal forces of the current contact reactions, every dof.
    pub(super) contact_force: Vec<Real>,
    pub(super) force_scale: Real,
    pub(super) last_increment: Option<Real>,
    /// The trial displacements equal the committed ones: nothing of the body moved this step
    /// ([`Body::still`]).
    pub(super) still: bool,
    /// The criteria the last [`Body::converged`] found unmet ([`Body::unmet`] words them).
    pub(super) unmet: Vec<Unmet>,
    /// `c1 = 1/(θ dt²)` of the current factorisation; `None` when there is none.
    pub(super) factor_c1: Option<Real>,
    /// Counts the factorisations: what a device copy of `K̄⁻¹` was computed from.
    pub(super) factor_version: u64,
    /// Whether `values` hold `ξ K` at the current trial displacement.
    pub(super) tangent_current: bool,
    /// The displacement at which a device Newton call that handed the body back holds its
    /// tangent `ξ K`: a refactorisation there assembles the host's own on the CPU (not read
    /// back) and sends `K̄` by its diagonal ([`Body::refresh_factor`]).
    pub(super) device_tangent: Option<Vec<Real>>,
    /// Whether the factorisation was made where the device held its tangent (the last
    /// [`Body::refresh_factor`] took `device_tangent`).
    pub(super) factored_at_hand_back: bool,
    /// The coefficients of a factorisation the device made within a Newton call (version
    /// `factor_version`), which the host has not made yet: its own factor is the one before
    /// ([`Body::factorize_at`] makes it where the device did).
    pub(super) factor_on_device: Option<Coefficients<Real>>,
    /// Residual norm of the previous evaluation in this step, and the ratio of the last one to it.
    pub(super) previous_residual: Option<Real>,
    pub(super) contraction: Option<Real>,
    /// The step being solved ended on the device and stays there ([`crate::gpu::NewtonCall::keep`]):
    /// `trial`'s vectors are stale until [`Body::take_iterate`].
    pub(super) trial_held: Option<StepSummary>,
    pub(super) trial_positions: bool,
}

/// The inputs of a CPU evaluation whose results `Body::dof_out` still holds, and the strain
/// energy at its `u` when a device Newton call computed it.
#[derive(Debug, Default)]
pub(super) struct EvaluatedAt {
    valid: bool,
    u: Vec<Real>,
    inputs: Vec<DofStep<Real>>,
    coefficients: Coefficients<Real>,
    strain: Option<Real>,
}

impl EvaluatedAt {
    /// Whether these inputs are the recorded ones, bit for bit (`==` would take -0 for 0).
    fn holds(&self, u: &[Real], inputs: &[DofStep<Real>], coefficients: Coefficients<Real>) -> bool {
        self.valid && same_bits(&[coefficients], &[self.coefficients]) && same_bits(u, &self.u) && same_bits(inputs, &self.inputs)
    }

    fn record(&mut self, u: &[Real], inputs: &[DofStep<Real>], coefficients: Coefficients<Real>) {
        self.u.clear();
        self.u.extend_from_slice(u);
        self.inputs.clear();
        self.inputs.extend_from_slice(inputs);
        self.coefficients = coefficients;
        self.valid = true;
        self.strain = None;
    }
}

/// Round-off per dof of the internal force, in units of `(K + 4G/3) h^(dim-1)`: a few ε (the
/// error of `J` times the few terms a node sums).
pub const STIFFNESS_ROUND_OFF: Real = 4.0 * Real::EPSILON;

impl Body {
    /// `initial_velocity(node) -> velocity` gives the free motion at t = 0; prescribed dofs start
    /// at their prescribed velocity. `topology` is built for its mesh and prescribed dofs, and
    /// shared with the bodies that have the same ([`Topology::key`]).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        name: String,
        mesh: Mesh,
        patches: Option<Patches>,
        geometry: ReferenceGeometry,
        model: Model,
        formulation: Formulation,
        density: Real,
        prescribed: Vec<Prescribed>,
        initial_velocity: impl Fn([Real; 3]) -> [Real; 3],
        topology: &Topology,
    ) -> Self {
        let dim = mesh.dim();
        let ndof = mesh.nodes.len() * dim;
        let nodal = geometry.lumped_masses(patches.as_ref().map_or(&mesh, |p| &p.cells), density);
        let mass: Vec<Real> = (0..ndof).map(|d| nodal[d / dim]).collect();
        let (dofs, pattern, gather) = (topology.dofs.clone(), topology.pattern.clone(), topology.gather.clone());
        let solver = CholeskySolver::with(topology.symbolic.clone());
        let mut v = vec![0.0; ndof];
        for (n, x) in mesh.nodes.iter().enumerate() {
            let w = initial_velocity(*x);
            v[n * dim..(n + 1) * dim].copy_from_slice(&w[..dim]);
        }
        for p in &prescribed {
            v[p.dof] = p.velocity_after(0.0);
        }
        let state = State { u: vec![0.0; ndof], v, f_int: vec![0.0; ndof], strain: 0.0, strain_at_u: false, viscous: Vec::new(), branch_energy: 0.0 };
        let values = vec![0.0; pattern.nnz()];
        let element_results = vec![0.0; geometry.volumes.len() * element_out_stride(pattern.element_dofs)];
        let reactions = vec![0.0; prescribed.len()];
        let length_scale = mesh.min_edge_length();
        let max_mass = mass.iter().cloned().fold(0.0, Real::max);
        let (k, g) = model.bulk_shear();
        let stiffness_scale = (k + 4.0 * g / 3.0) * length_scale.powi(dim as i32 - 2);
        Self {
            def: Definition { name, mesh, patches, geometry, model, viscoelastic: None, formulation, dim, mass, dofs, pattern, prescribed, length_scale, max_mass, stiffness_scale, gather, loads: Vec::new(), reuse_factorization: true },
            work: Workspace {
                step_end: 0.0,
                relaxation_c: 0.0,
                history: Vec::new(),
                trial: state.clone(),
                reactions,
                solver,
                values,
                element_results,
                step_inputs: vec![DofStep::default(); ndof],
                dof_out: vec![DofOut::default(); ndof],
                evaluated: EvaluatedAt::default(),
                f_ext: vec![0.0; ndof],
                f_load: Vec::new(),
                g: vec![0.0; ndof],
                contact_force: vec![0.0; ndof],
                force_scale: 0.0,
                last_increment: None,
                still: true,
                unmet: Vec::new(),
                factor_c1: None,
                factor_version: 0,
                tangent_current: false,
                device_tangent: None,
                factored_at_hand_back: false,
                factor_on_device: None,
                previous_residual: None,
                contraction: None,
                trial_held: None,
                trial_positions: false,
            },
            committed: Committed { state, state_held: None, state_positions: false },
        }
    }

    pub fn name(&self) -> &str {
        &self.def.name
    }

    pub fn mesh(&self) -> &Mesh {
        &self.def.mesh
    }

    /// The geometry of what the element kernels integrate.
    pub fn geometry(&self) -> &ReferenceGeometry {
        &self.def.geometry
    }

    pub fn model(&self) -> &Model {
        &self.def.model
    }

    /// How the elements take the volume change (F-bar for nearly incompressible materials).
    pub fn formulation(&self) -> Formulation {
        self.def.formulation
    }

    pub fn dim(&self) -> usize {
        self.def.dim
    }

    pub fn dofs(&self) -> &DofMap {
        &self.def.dofs
    }

    pub fn pattern(&self) -> &StiffnessPattern {
        &self.def.pattern
    }

    /// The committed state. While the device holds it, its vectors are stale
    /// ([`crate::solver::Simulation::sync_states`] brings them back).
    pub fn state(&self) -> &State {
        &self.committed.state
    }

    /// The state of the step being solved.
    pub fn trial(&self) -> &State {
        &self.work.trial
    }

    /// Puts the trial at displacements `u` (every dof), as a test of the body's response does.
    pub fn set_trial_displacements(&mut self, u: &[Real]) {
        self.work.trial.u.copy_from_slice(u);
    }

    /// Gives the body's material a Prony series: its points start relaxed, at rest.
    pub fn set_viscoelastic(&mut self, viscoelastic: Viscoelastic) {
        let points = self.def.geometry.points.len();
        self.committed.state.viscous = vec![0.0; points * viscoelastic.kept_per_point()];
        self.work.trial.viscous = self.committed.state.viscous.clone();
        self.work.history = vec![0.0; points * HISTORY];
        self.def.viscoelastic = Some(viscoelastic);
    }

    /// What the element kernels integrate: the body's mesh, or its F-bar patches.
    pub fn elements(&self) -> &Mesh {
        self.def.patches.as_ref().map_or(&self.def.mesh, |p| &p.cells)
    }

    /// `element_force_tangent` of every element at `u` on the CPU, into the element results
    /// (forces only without the tangent).
    fn cpu_elements(&mut self, u: &[Real], with_tangent: bool, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        let t0 = Instant::now();
        let elements = self.def.patches.as_ref().map_or(&self.def.mesh, |p| &p.cells);
        let relaxation = self.def.viscoelastic.as_ref().map(|_| Relaxation { c: self.work.relaxation_c, history: &self.work.history });
        let result = dispatch_element_force_tangent(&self.def.model, elements, &self.def.geometry, self.def.formulation, relaxation, u, with_tangent, &mut self.work.element_results).map_err(|(element, error)| self.element_error(element, error));
        times.elements += t0.elapsed().as_secs_f64();
        result
    }

    /// The failure of an element the GPU rejected, as its CPU twin words it.
    fn element_failure(&self, u: &[Real], failure: ElementFailure) -> StepFailure {
        let (element, fallback) = match failure {
            ElementFailure::Inverted(e) => (e, ElementError::Inverted(Real::NAN)),
            ElementFailure::NonFinite(e) => (e, ElementError::NonFinite),
        };
        let ue = self.elements().element_displacements(u, element);
        let relaxation = self.relaxation().map(|r| r.element(element, self.def.geometry.points_per_element));
        let error = element_force_tangent(&self.def.model, self.def.geometry.element_points(element), &ue, self.def.dim, self.def.formulation, relaxation, true, &mut ElementOutput::default()).err().unwrap_or(fallback);
        self.element_error(element, error)
    }

    /// `element` is what the kernels integrate; a patch is named by its first simplex, so that
    /// the message points into the mesh the user gave.
    fn element_error(&self, element: usize, error: ElementError) -> StepFailure {
        let limit = if error == ElementError::NonFinite { self.def.model.limit() } else { None };
        let element = match &self.def.patches {
            Some(patches) => (0..self.def.mesh.element_count()).find(|&e| patches.slot(e).0 == element).unwrap_or(element),
            None => element,
        };
        StepFailure::Element { body: self.def.name.clone(), element, error, limit }
    }

    /// Starts a step of length `p.dt` from time `t`: external forces (gravity, and the surface
    /// loads), the predictor `u_t + dt v_t` (zero inertia residual) with the prescribed dofs at
    /// their final values, no contact force.
    pub fn begin_step(&mut self, p: &StepParams, gravity: &[Real; 3], t: Real) {
        let dim = self.def.dim;
        self.work.step_end = t + p.dt;
        self.work.trial_held = None;
        self.work.trial_positions = false;
        self.work.last_increment = None;
        self.work.previous_residual = None;
        self.work.contraction = None;
        self.work.device_tangent = None;
        if self.committed.state_held.is_some() {
            // The device begins the step from the state it holds (`step_begin`): the host's
            // vectors are stale, and it only marks the body as moving.
            self.work.still = false;
            self.work.evaluated.valid = false;
            return;
        }
        // The load of a step at the time the scheme weighs the step's end forces by (exact for
        // a linear ramp: (1 - ξ) λ_t + ξ λ_{t+dt}).
        let load_time = t + p.xi * p.dt;
        if !self.def.loads.is_empty() {
            self.work.f_load.clear();
            self.work.f_load.resize(self.def.mass.len(), 0.0);
            for load in &self.def.loads {
                let factor = load.factor(load_time);
                for &(dof, f) in &load.forces {
                    self.work.f_load[dof] += factor * f;
                }
            }
        }
        let mut still = true;
        for d in 0..self.def.mass.len() {
            self.work.f_ext[d] = self.def.mass[d] * gravity[d % dim] + self.work.f_load.get(d).copied().unwrap_or(0.0);
            let du = p.dt * self.committed.state.v[d];
            still &= du == 0.0;
            self.work.trial.u[d] = self.committed.state.u[d] + du;
            self.work.contact_force[d] = 0.0;
        }
        for pr in &self.def.prescribed {
            let travel = pr.travel(t, p.dt);
            still &= travel == 0.0;
            self.work.trial.u[pr.dof] = self.committed.state.u[pr.dof] + travel;
        }
        self.work.still = still;
        for (d, s) in self.work.step_inputs.iter_mut().enumerate() {
            *s = DofStep { mass: self.def.mass[d], u_pred: self.committed.state.u[d] + p.dt * self.committed.state.v[d], f_int_t: self.committed.state.f_int[d], f_ext: self.work.f_ext[d] };
        }
        if let Some(viscoelastic) = &self.def.viscoelastic {
            self.work.relaxation_c = viscoelastic.step_relaxation(p.dt);
            let kept = viscoelastic.kept_per_point();
            for (h, k) in self.work.history.chunks_mut(HISTORY).zip(self.committed.state.viscous.chunks(kept)) {
                viscoelastic.history(p.dt, k, h);
            }
        }
    }

    /// Assembles force (and, without factorisation reuse, `ξ K`) at the trial displacement and
    /// the contact-free residual `g(u) = M (u - u_t - dt v_t) / (θ dt²) - (1-ξ) F_t - ξ F(u)` at
    /// every dof, with the CPU kernels. [`Body::refresh_factor`] adds the tangent when it
    /// refactorises. A GPU world evaluates through [`Body::device_evaluation`] instead.
    pub fn evaluate(&mut self, p: &StepParams, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        self.evaluate_with(p, !self.def.reuse_factorization, times)
    }

    /// [`Body::evaluate`], with the stiffness values only if `with_tangent`.
    fn evaluate_with(&mut self, p: &StepParams, with_tangent: bool, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        let c = coefficients(p);
        // The same inputs, bit for bit, give the same results: a body at rest (a grain no
        // other touches yet) is not evaluated again every step. A viscoelastic body's stresses
        // relax even at rest.
        if !with_tangent && self.evaluation_holds(p) {
            self.reuse_evaluation(p);
            return Ok(());
        }
        let u = std::mem::take(&mut self.work.trial.u);
        let result = self.assemble_with(&u, c, with_tangent, times);
        self.work.trial.u = u;
        result?;
        if !with_tangent {
            self.work.evaluated.record(&self.work.trial.u, &self.work.step_inputs, c);
        }
        self.absorb_residual(p);
        Ok(())
    }

    /// Takes the internal force and residual of the last evaluation, and the force scale.
    fn absorb_residual(&mut self, p: &StepParams) {
        let xi = p.xi;
        let mut scale2 = 0.0;
        for (d, out) in self.work.dof_out.iter().enumerate() {
            self.work.trial.f_int[d] = out.f_int;
            self.work.g[d] = out.g;
            let inertia = out.g + (1.0 - xi) * (self.work.f_ext[d] - self.committed.state.f_int[d]) + xi * (self.work.f_ext[d] - out.f_int);
            // The force scale spans all dofs: at equilibrium the free-dof forces nearly cancel,
            // while round-off follows the element forces, which the reactions reflect.
            scale2 += inertia * inertia + (xi * out.f_int).powi(2) + ((1.0 - xi) * self.committed.state.f_int[d]).powi(2) + self.work.f_ext[d].powi(2);
        }
        self.work.force_scale = scale2.sqrt();
    }

    /// Whether a forces-only evaluation would repeat the last one's inputs bit for bit, so that
    /// its results are still there ([`Body::evaluate`] skips such an evaluation on the CPU; a
    /// GPU world's pass leaves the body out with [`Body::reuse_evaluation`]).
    pub fn evaluation_holds(&self, p: &StepParams) -> bool {
        self.def.viscoelastic.is_none() && self.work.evaluated.holds(&self.work.trial.u, &self.work.step_inputs, coefficients(p))
    }

    /// Takes the last evaluation's results again (see [`Body::evaluation_holds`]).
    pub fn reuse_evaluation(&mut self, p: &StepParams) {
        self.work.tangent_current = false;
        self.absorb_residual(p);
    }

    /// The f64 residual on the CPU for a device that evaluates tangents only (f32 kernels):
    /// [`Body::evaluate`] without a tangent whatever `reuse_factorization` says.
    pub fn evaluate_residual_on_cpu(&mut self, p: &StepParams, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        self.evaluate_with(p, false, times)
    }

    /// The kernels of one Newton evaluation at `u` on the CPU: element results, stiffness values
    /// (`ξ K`) and, with the step's inputs from [`Body::begin_step`], internal force and residual.
    pub fn assemble(&mut self, u: &[Real], coefficients: Coefficients<Real>, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        self.assemble_with(u, coefficients, true, times)
    }

    /// [`Body::assemble`], with the stiffness values only if `with_tangent`.
    fn assemble_with(&mut self, u: &[Real], coefficients: Coefficients<Real>, with_tangent: bool, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        self.work.tangent_current = false;
        self.work.evaluated.valid = false;
        self.cpu_elements(u, with_tangent, times)?;
        let t0 = Instant::now();
        if with_tangent {
            assemble_csr(&self.work.element_results, &self.def.gather.csr_start, &self.def.gather.csr, coefficients, &mut self.work.values);
        }
        self.work.tangent_current = with_tangent;
        assemble_residual(&self.work.element_results, &self.def.gather.dof_start, &self.def.gather.dof, coefficients, u, &self.work.step_inputs, &mut self.work.dof_out);
        times.assembly += t0.elapsed().as_secs_f64();
        Ok(())
    }

    /// Size of the forces of the last evaluation (the residual's scale).
    pub fn force_scale(&self) -> Real {
        self.work.force_scale
    }

    /// Smallest edge length of the mesh.
    pub fn length_scale(&self) -> Real {
        self.def.length_scale
    }

    /// Norm of the residual with contact, `g - f_c`, over the free dofs.
    pub fn residual_norm(&self) -> Real {
        debug_assert!(self.work.trial_held.is_none(), "a step end the device keeps has its residual there (GpuWorld::step_tally)");
        self.def.dofs.free_pairs().map(|(d, _)| (self.work.g[d] - self.work.contact_force[d]).powi(2)).sum::<Real>().sqrt()
    }

    /// Whether the last evaluation meets the Newton tolerances: the residual below
    /// `residual_tolerance` times the force scale (plus a round-off floor), and the last increment
    /// below `increment_tolerance` times the larger of the displacement over the step and
    /// `motion_scale` (how far the scene's fastest motion goes in a step: a body at rest has no
    /// displacement of its own to compare with).
    ///
    /// Also records how much the residual fell since the previous evaluation, which decides
    /// whether the factorisation is kept ([`Body::refresh_factor`]).
    pub fn converged(&mut self, p: &StepParams, motion_scale: Real) -> Result<bool, StepFailure> {
        if self.work.trial_held.is_some() {
            // The device judged it converged (`newton_judge`, this test's twin) and kept it.
            self.work.unmet.clear();
            return Ok(true);
        }
        let residual = self.residual_norm();
        if !residual.is_finite() {
            return Err(StepFailure::NotFinite { body: self.def.name.clone() });
        }
        self.work.contraction = self.work.previous_residual.map(|r0| residual / r0.max(Real::MIN_POSITIVE));
        self.work.previous_residual = Some(residual);
        let tolerance = self.residual_tolerance(p);
        let (mut step2, mut size2) = (0.0, 0.0);
        for (d, _) in self.def.dofs.free_pairs() {
            step2 += (self.work.trial.u[d] - self.committed.state.u[d]).powi(2);
            size2 += self.work.trial.u[d].powi(2);
        }
        // A body at rest changes its displacement by round-off only: an increment of the order
        // of the round-off of u itself counts as no change. The residual's round-off reaches
        // the increment amplified by the stiffness's spread, about K/G for a nearly
        // incompressible body (regression test `a_pressurised_tube_holds_its_load`: a Tri3 tube
        // at K/G = 5000, its load held, stalled at increments of 3 times the unscaled bound).
        let round_off = 1e3 * Real::EPSILON * size2.sqrt() * self.stiffness_spread();
        let allowed = p.increment_tolerance * step2.sqrt().max(self.increment_floor(motion_scale)) + round_off;
        let increment_ok = self.work.last_increment.is_none_or(|du| du <= allowed);
        self.work.unmet.clear();
        if residual > tolerance {
            self.work.unmet.push(Unmet::Residual { residual, tolerance, setting: p.residual_tolerance, scale: self.work.force_scale, floor: self.residual_floor(p) });
        }
        if let Some(du) = self.work.last_increment.filter(|_| !increment_ok) {
            self.work.unmet.push(Unmet::Increment { du, allowed, setting: p.increment_tolerance });
        }
        Ok(self.work.unmet.is_empty())
    }

    /// The residual's tolerance: `residual_tolerance` times the force scale, plus the floor
    /// below which only round-off remains ([`Body::residual_floor`]).
    fn residual_tolerance(&self, p: &StepParams) -> Real {
        p.residual_tolerance * self.work.force_scale + self.residual_floor(p)
    }

    /// The round-off floor of the residual. The inertia term `M (u - u_t - dt v_t) c1` is a
    /// difference of terms as large as `M u c1`: a body that has travelled far (a grain, many
    /// sizes from its start) carries their round-off (regression test
    /// `newton_converges_for_a_small_body_far_from_its_start`). The internal force of a nearly
    /// incompressible material is a sum of stresses `K (J - 1)` whose `J` is known to ε: each
    /// dof carries about `ε (K + 4G/3) h^(dim-1)` of round-off, `√n` of them over the body
    /// (regression test `newton_converges_at_k_over_g_one_hundred_thousand`: at K/G = 1e5 the
    /// residual stalled at 1.6e-8 against a tolerance of 1.3e-8).
    fn residual_floor(&self, p: &StepParams) -> Real {
        let [constant, per_travel, stiffness] = self.residual_floor_terms(p);
        let travel = self.work.trial.u.iter().fold(0.0, |m: Real, u| m.max(u.abs()));
        constant + per_travel * travel + stiffness
    }

    /// The terms of [`Body::residual_floor`]: the inertia's round-off at the body's size, the
    /// same per unit of travel (the largest |u|), and the stiff volumetric term's.
    fn residual_floor_terms(&self, p: &StepParams) -> [Real; 3] {
        let c1 = 1.0 / (p.theta * p.dt * p.dt);
        let free = (self.def.dofs.free_count as Real).sqrt();
        [1e-14 * c1 * self.def.max_mass * self.def.length_scale, 1e-13 * c1 * self.def.max_mass, STIFFNESS_ROUND_OFF * free * p.xi * self.def.stiffness_scale * self.def.length_scale]
    }

    /// The displacement over the step below which the increment's bound stops shrinking: how
    /// far the scene's fastest motion goes in a step, or a trillionth of the smallest edge.
    fn increment_floor(&self, motion_scale: Real) -> Real {
        motion_scale.max(1e-12 * self.def.length_scale)
    }

    /// How much the residual's round-off is amplified in the increment: about K/G for a nearly
    /// incompressible body, 1 for a compressible one.
    fn stiffness_spread(&self) -> Real {
        let (bulk, shear) = self.def.model.bulk_shear();
        (bulk / shear).max(1.0)
    }

    /// Whether the last convergence test found the residual within its tolerance (the
    /// increment may still be above its bound).
    pub fn balanced(&self) -> bool {
        self.work.unmet.iter().all(|u| matches!(u, Unmet::Increment { .. }))
    }

    /// The criteria the last convergence test found unmet (empty when it passed), worded for a
    /// failure message.
    pub fn unmet(&self) -> Vec<String> {
        let name = &self.def.name;
        self.work
            .unmet
            .iter()
            .map(|u| match *u {
                Unmet::Residual { residual, tolerance, setting, scale, floor } => {
                    format!("`{name}`: residual {residual:.3e} > {tolerance:.3e} = solver.residual_tolerance {setting:.1e} x force scale {scale:.3e} + round-off floor {floor:.3e}")
                }
                Unmet::Increment { du, allowed, setting } => format!("`{name}`: last increment {du:.3e} > {allowed:.3e} (solver.increment_tolerance {setting:.1e} of the step's displacement)"),
            })
            .collect()
    }

    /// One Newton increment with the current contact forces: solves `K̄ Δu = -(g - f_c)` with the
    /// last factorisation and adds it to the trial displacement.
    pub fn newton_step(&mut self, times: &mut PhaseTimes) {
        let mut rhs = vec![0.0; self.def.dofs.free_count];
        for (d, f) in self.def.dofs.free_pairs() {
            rhs[f] = self.work.contact_force[d] - self.work.g[d];
        }
        if !rhs.is_empty() {
            self.solve_effective(&mut rhs, times);
        }
        self.apply_increment(&rhs);
    }

    /// Adds a free-dof increment to the trial displacement and records its size.
    pub fn apply_increment(&mut self, du: &[Real]) {
        self.work.tangent_current = false;
        let mut du2 = 0.0;
        for (d, f) in self.def.dofs.free_pairs() {
            self.work.trial.u[d] += du[f];
            du2 += du[f] * du[f];
        }
        // Not `du2 == 0`: squares of the smallest increments underflow.
        self.work.still &= du.iter().all(|&du| du == 0.0);
        self.work.last_increment = Some(du2.sqrt());
    }

    /// Whether the trial displacements equal the committed ones (the predictor and every
    /// increment of the step left them where they were): what depends only on the body's
    /// configuration, such as its contact box, is as it was at the last commit. Meaningful
    /// between [`Body::begin_step`] and [`Body::commit`].
    pub fn still(&self) -> bool {
        self.work.still
    }

    /// Velocity of dof `d` implied by the trial displacement (eq. 15).
    pub fn trial_velocity(&self, p: &StepParams, d: usize) -> Real {
        (self.work.trial.u[d] - self.committed.state.u[d] - p.dt * (1.0 - p.theta) * self.committed.state.v[d]) / (p.theta * p.dt)
    }

    /// Ends a converged step whose strain energy at the trial displacement is `strain`: end
    /// velocities, support reactions `g - f_c` at the prescribed dofs, and the step's energy
    /// terms.
    pub fn finish_step(&mut self, p: &StepParams, strain: Real) -> StepEnergy {
        debug_assert!(self.work.trial_held.is_none(), "a step end the device keeps is booked from its sums (GpuWorld::step_tally)");
        let ndof = self.def.mass.len();
        let v: Vec<Real> = (0..ndof).map(|d| self.trial_velocity(p, d)).collect();
        self.work.trial.v = v;
        let (mut stopping, mut prescribed_theta_term) = (0.0, 0.0);
        for (k, pr) in self.def.prescribed.iter().enumerate() {
            self.work.trial.v[pr.dof] = pr.velocity_after(self.work.step_end);
            self.work.reactions[k] = self.work.g[pr.dof] - self.work.contact_force[pr.dof];
            // A dof that stops (`until`) is stopped by its support, which takes its kinetic
            // energy; the scheme's dissipation is that of the free dofs.
            let (v0, v1) = (self.committed.state.v[pr.dof], self.work.trial.v[pr.dof]);
            stopping += 0.5 * self.def.mass[pr.dof] * (v1 * v1 - v0 * v0);
            prescribed_theta_term += self.def.mass[pr.dof] * (v1 - v0).powi(2);
        }
        self.work.trial.strain = strain;
        self.work.trial.strain_at_u = true;
        let (mut theta_term, mut force_work, mut support_work) = (0.0, 0.0, 0.0);
        for d in 0..ndof {
            let du = self.work.trial.u[d] - self.committed.state.u[d];
            theta_term += self.def.mass[d] * (self.work.trial.v[d] - self.committed.state.v[d]).powi(2);
            force_work += du * ((1.0 - p.xi) * self.committed.state.f_int[d] + p.xi * self.work.trial.f_int[d]);
        }
        for (pr, r) in self.def.prescribed.iter().zip(&self.work.reactions) {
            support_work += r * (self.work.trial.u[pr.dof] - self.committed.state.u[pr.dof]);
        }
        support_work += stopping;
        // The step's load is one value over the step, so its work is exact.
        let load_work = self.work.f_load.iter().enumerate().map(|(d, f)| f * (self.work.trial.u[d] - self.committed.state.u[d])).sum();
        // The work of the overstress, xi-weighted as the forces are, is in `force_work`: beyond
        // its work along the branches' exact path (what they hold and dissipate), it is the
        // scheme's.
        let branches = self.advance_viscous(p);
        StepEnergy {
            theta_dissipation: (p.theta - 0.5) * (theta_term - prescribed_theta_term),
            force_dissipation: force_work - (self.work.trial.strain - self.committed.state.strain) - branches.work,
            support_work,
            load_work,
            viscous_dissipation: branches.dissipated,
        }
    }

    /// The Prony branches at the end of a converged step (`trial.viscous` from `state.viscous`,
    /// at each point's strain of the trial displacement), the work of their overstress and what
    /// they dissipated over it; what they hold grows by the difference.
    fn advance_viscous(&mut self, p: &StepParams) -> BranchStep {
        let Some(viscoelastic) = &self.def.viscoelastic else { return BranchStep::default() };
        let shear = self.def.model.bulk_shear().1;
        self.work.trial.viscous.clone_from(&self.committed.state.viscous);
        let elements = self.def.patches.as_ref().map_or(&self.def.mesh, |p| &p.cells);
        let per_element = self.def.geometry.points_per_element * viscoelastic.kept_per_point();
        let (geometry, model, u, dim, formulation) = (&self.def.geometry, &self.def.model, &self.work.trial.u, self.def.dim, self.def.formulation);
        let [work, dissipated] = self
            .work
            .trial
            .viscous
            .par_chunks_mut(per_element)
            .enumerate()
            .map(|(e, kept)| {
                let points = geometry.element_points(e);
                let gradients = point_gradients(points, &elements.element_displacements(u, e), dim, formulation);
                kept.chunks_mut(viscoelastic.kept_per_point())
                    .zip(points.iter().zip(gradients))
                    .map(|(k, (gp, f))| {
                        let strain = green_lagrange(&f);
                        let step = viscoelastic.advance(p.dt, k, &strain, &model.stress(&strain), shear);
                        [gp.dv * step.work, gp.dv * step.dissipated]
                    })
                    .fold([0.0; 2], |a, b| [a[0] + b[0], a[1] + b[1]])
            })
            .collect::<Vec<[Real; 2]>>()
            .iter()
            .fold([0.0; 2], |a, b| [a[0] + b[0], a[1] + b[1]]);
        self.work.trial.branch_energy = self.committed.state.branch_energy + work - dissipated;
        BranchStep { work, dissipated }
    }

    /// Estimates what the Prony branches hold from what the points kept
    /// ([`Viscoelastic::branch_energy`]), for a restore from a log that did not save it.
    pub fn refresh_branch_energy(&mut self) {
        let Some(viscoelastic) = &self.def.viscoelastic else { return };
        let (shear, kept) = (self.def.model.bulk_shear().1, viscoelastic.kept_per_point());
        // Summed as `advance_viscous` sums it (per element, then over elements), to the bit.
        let per_element = self.def.geometry.points_per_element;
        self.committed.state.branch_energy = self
            .def
            .geometry
            .points
            .chunks(per_element)
            .zip(self.committed.state.viscous.chunks(per_element * kept))
            .map(|(points, kept_e)| points.iter().zip(kept_e.chunks(kept)).fold(0.0, |sum, (gp, k)| sum + gp.dv * viscoelastic.branch_energy(k, shear)))
            .fold(0.0, |a, b| a + b);
    }

    /// Makes sure a factorisation fit for the next Newton increment is there: refactorises
    /// when there is none for this time step (`c1` changes with `dt`), when reuse is off, or
    /// when the last iteration reduced the residual less than [`REFACTOR_CONTRACTION`]; else the
    /// last one is kept, across iterations and steps. Returns whether it refactorised.
    pub fn refresh_factor(&mut self, p: &StepParams, times: &mut PhaseTimes) -> Result<bool, StepFailure> {
        let c1 = coefficients(p).c1;
        if !self.needs_factorization(p) {
            return Ok(false);
        }
        let at_hand_back = self.holds_device_tangent();
        self.work.device_tangent = None;
        if !self.work.tangent_current {
            let u = std::mem::take(&mut self.work.trial.u);
            let result = self.assemble_with(&u, coefficients(p), true, times);
            self.work.trial.u = u;
            result?;
        }
        self.factorize_effective(c1, times)?;
        self.work.factored_at_hand_back = at_hand_back;
        Ok(true)
    }

    /// A device Newton call made the body's `K̄⁻¹` anew within the call, `refactors` times, at
    /// a step's `coefficients` (`NewtonState::refactors`): a new version of its factorisation,
    /// counted as the host counts its own, which the host makes only when it needs it
    /// ([`Body::factorize_at`]).
    pub fn note_device_factorization(&mut self, coefficients: Coefficients<Real>) {
        self.work.factor_version += 1;
        self.work.factor_on_device = Some(coefficients);
        self.work.factored_at_hand_back = false;
    }

    /// Whether the device holds a factorisation the host has not made yet
    /// ([`Body::note_device_factorization`]).
    pub fn factor_on_device(&self) -> bool {
        self.work.factor_on_device.is_some()
    }

    /// The host's factorisation where the device made the body's last one within a Newton
    /// call (`u`, `GpuWorld::factored_at`), from its own tangent there, as
    /// [`Body::refresh_factor`] would have at that iterate: its later increments and W use what
    /// the device's did (the two tangents of the same displacements agree to round-off). Not
    /// counted again; the body's evaluation is left as it is.
    pub fn factorize_at(&mut self, u: &[Real], times: &mut PhaseTimes) -> Result<(), StepFailure> {
        let c = self.work.factor_on_device.expect("a factorisation the device made");
        self.cpu_elements(u, true, times)?;
        let t0 = Instant::now();
        assemble_csr(&self.work.element_results, &self.def.gather.csr_start, &self.def.gather.csr, c, &mut self.work.values);
        times.assembly += t0.elapsed().as_secs_f64();
        self.factorize_effective(c.c1, times)
    }

    /// Whether [`Body::refresh_factor`] would refactorise now.
    pub fn needs_factorization(&self, p: &StepParams) -> bool {
        !(self.factor_kept_for(p) && self.work.contraction.is_none_or(|r| r <= REFACTOR_CONTRACTION))
    }

    /// Whether the body keeps factorisations and holds one for this step's `c1`.
    fn factor_kept_for(&self, p: &StepParams) -> bool {
        self.def.reuse_factorization && self.work.factor_c1 == Some(coefficients(p).c1)
    }

    /// Whether the body has free dofs and no factorisation for this step's `c1` (the first step,
    /// a cut-back, a grain that never iterated, or no reuse of factorisations): if it iterates,
    /// it factorises first, at the iterate about to be evaluated.
    pub fn lacks_factor(&self, p: &StepParams) -> bool {
        self.def.dofs.free_count > 0 && !self.factor_kept_for(p)
    }

    /// Whether [`Body::refresh_factor`] needs a tangent it does not have: a GPU world computes
    /// those of all such bodies in one pass first. Where a device Newton call handed the body
    /// back, the device holds its tangent, and the host assembles its own, which it would
    /// otherwise read: the device's values stay there for `K̄`.
    pub fn needs_tangent(&self, p: &StepParams) -> bool {
        self.needs_factorization(p) && !self.work.tangent_current && !self.holds_device_tangent()
    }

    /// Whether a device Newton call holds a tangent ([`Body::finish_device_newton`]) at the
    /// trial displacement, bit for bit.
    fn holds_device_tangent(&self) -> bool {
        self.work.device_tangent.as_ref().is_some_and(|u| same_bits(u, &self.work.trial.u))
    }

    /// Adds `c1 M` to the assembled `ξ K` and factorises `K̄ = ξ K + c1 M` (eq. 17).
    pub fn factorize_effective(&mut self, c1: Real, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        for (d, f) in self.def.dofs.free_pairs() {
            self.work.values[self.def.pattern.diagonal[f] as usize] += c1 * self.def.mass[d];
        }
        // The values now hold K̄, not ξ K.
        self.work.tangent_current = false;
        self.work.factor_c1 = None;
        self.work.factor_on_device = None;
        let t0 = Instant::now();
        let result = self.work.solver.factorize(&self.work.values).map_err(|e| StepFailure::Linear { body: self.def.name.clone(), error: self.factor_failure(e) });
        times.factorization += t0.elapsed().as_secs_f64();
        self.work.factor_version += 1;
        self.work.factored_at_hand_back = false;
        self.work.factor_c1 = result.is_ok().then_some(c1);
        result
    }

    /// What a failed factorisation of `K̄` says of this body's material: the likely reasons,
    /// with its model and `K/G`.
    fn factor_failure(&self, error: super::linear::LinearError) -> String {
        let (k, g) = self.def.model.bulk_shear();
        match error {
            super::linear::LinearError::NotPositiveDefinite => format!(
                "{error} (material model {}, K/G = {:.3e}): either the material's tangent stopped being positive at this deformation (parameters stable only near the reference state, such as a Yeoh or Ogden set that loses convexity, or an element close to inverting), or K/G is too large for f64 (the shear terms drown in the volumetric ones' round-off): check the parameters, or lower K/G",
                self.def.model.name(),
                k / g
            ),
            other => other.to_string(),
        }
    }

    /// The coefficient `c1` and the values `K̄` of the factorisation kept for the next step, if
    /// any (what a restart must factorise again to repeat the run).
    pub fn kept_factor(&self) -> Option<(Real, &[Real])> {
        debug_assert!(self.work.factor_on_device.is_none(), "the host's factorisation is behind the device's (Body::factorize_at)");
        let c1 = self.work.factor_c1.filter(|_| self.def.reuse_factorization && !self.work.tangent_current)?;
        Some((c1, &self.work.values))
    }

    /// Factorises the saved `K̄` (from [`Body::kept_factor`]) as the kept factorisation.
    pub fn restore_factor(&mut self, c1: Real, values: &[Real]) -> Result<(), String> {
        if values.len() != self.work.values.len() {
            return Err(format!("{} values for a pattern of {}", values.len(), self.work.values.len()));
        }
        self.work.values.copy_from_slice(values);
        self.work.tangent_current = false;
        self.work.factor_on_device = None;
        self.work.factor_version += 1;
        self.work.factored_at_hand_back = false;
        self.work.solver.factorize(&self.work.values).map_err(|e| e.to_string())?;
        self.work.factor_c1 = Some(c1);
        Ok(())
    }

    /// The fill-reducing ordering of the factorisation and the entries of its factor.
    pub fn factor_report(&self) -> (super::ordering::Ordering, usize) {
        (self.work.solver.ordering(), self.work.solver.factor_entries())
    }

    /// Solves `K̄ x = rhs` in place (free dofs) with the last factorisation, for one or more
    /// column-major right-hand sides.
    pub fn solve_effective(&mut self, rhs: &mut [Real], times: &mut PhaseTimes) {
        debug_assert!(self.work.factor_on_device.is_none(), "the host's factorisation is behind the device's (Body::factorize_at)");
        let t0 = Instant::now();
        self.work.solver.solve_columns(rhs, self.def.dofs.free_count);
        times.solve += t0.elapsed().as_secs_f64();
    }

    pub fn commit(&mut self) {
        match self.work.trial_held.take() {
            Some(held) => {
                self.committed.state_held = Some(held);
                self.committed.state_positions = self.work.trial_positions;
                if self.work.trial_positions {
                    std::mem::swap(&mut self.committed.state.u, &mut self.work.trial.u);
                }
            }
            None => {
                std::mem::swap(&mut self.committed.state, &mut self.work.trial);
                self.committed.state_held = None;
            }
        }
    }

    /// The step's end, if the device keeps it ([`Body::trial_held`]).
    pub fn held_end(&self) -> Option<&StepSummary> {
        self.work.trial_held.as_ref()
    }

    /// The committed state, if the device keeps it ([`Body::state_held`]).
    pub fn held_state(&self) -> Option<&StepSummary> {
        self.committed.state_held.as_ref()
    }

    /// Whether the host's committed displacements are current (the rest of the state may be
    /// held on the device).
    pub fn positions_current(&self) -> bool {
        self.committed.state_held.is_none() || self.committed.state_positions
    }

    /// Whether the host's trial displacements are current (the rest of the step's end may be
    /// held on the device).
    pub fn trial_positions_current(&self) -> bool {
        self.work.trial_held.is_none() || self.work.trial_positions
    }

    /// Takes back the committed state the device kept, with its strain energy (from
    /// [`crate::gpu::GpuWorld::read_kept`]).
    pub fn take_committed(&mut self, kept: &KeptState) {
        self.committed.state_held.take().expect("a committed state the device keeps");
        for (d, s) in kept.states.iter().enumerate() {
            (self.committed.state.u[d], self.committed.state.v[d], self.committed.state.f_int[d]) = (s.u, s.v, s.f_int);
        }
        self.committed.state.strain = kept.strain;
        self.committed.state.strain_at_u = true;
    }

    /// Takes back the step's end the device kept: its iterate `u` and internal forces `f_int`
    /// ([`crate::gpu::GpuWorld::read_kept`]), evaluated as if the host had taken them. The
    /// step's inputs must be the host's ([`Body::begin_step`] from a committed state it holds).
    pub fn take_iterate(&mut self, p: &StepParams, kept: &KeptIterate) {
        self.work.trial_held.take().expect("a step end the device keeps");
        let KeptIterate { u, f_int, strain } = kept;
        self.work.trial.u.copy_from_slice(u);
        let c = coefficients(p);
        for (d, out) in self.work.dof_out.iter_mut().enumerate() {
            *out = DofOut { f_int: f_int[d], g: self.work.step_inputs[d].residual(c, u[d], f_int[d]) };
        }
        self.work.evaluated.record(&self.work.trial.u, &self.work.step_inputs, c);
        self.work.evaluated.strain = Some(*strain);
        self.absorb_residual(p);
    }

    pub fn kinetic_energy(&self) -> Real {
        if let Some(held) = &self.committed.state_held {
            return held.kinetic;
        }
        0.5 * self.def.mass.iter().zip(&self.committed.state.v).map(|(m, v)| m * v * v).sum::<Real>()
    }

    /// The model's strain energy and what the Prony branches hold beyond it; `None` while the
    /// device keeps the committed state (its energy is in [`crate::gpu::GpuWorld::held_strain`]).
    pub fn strain_energy(&self) -> Option<Real> {
        self.committed.state_held.is_none().then_some(self.committed.state.strain + self.committed.state.branch_energy)
    }

    /// Strain energy at the trial displacement, `element_energy` on the CPU (the state's when
    /// the body has not moved: the same displacement, bit for bit, has the same energy).
    pub fn trial_strain_energy(&self) -> Real {
        if let Some(strain) = self.unmoved_strain_energy() {
            return strain;
        }
        let elements = self.elements();
        (0..elements.element_count()).map(|e| element_energy(&self.def.model, self.def.geometry.element_points(e), &elements.element_displacements(&self.work.trial.u, e), self.def.dim, self.def.formulation)).sum()
    }

    /// The state's strain energy when the trial displacement is the state's, bit for bit (a
    /// GPU world then need not compute it again).
    pub fn unmoved_strain_energy(&self) -> Option<Real> {
        (self.committed.state.strain_at_u && same_bits(&self.work.trial.u, &self.committed.state.u)).then_some(self.committed.state.strain)
    }

    /// Current position of a node.
    pub fn position(&self, node: usize) -> [Real; 3] {
        debug_assert!(self.positions_current(), "the committed displacements are on the device");
        super::displaced(self.def.mesh.nodes[node], &self.committed.state.u, node, self.def.dim)
    }

    /// Gravity potential `-Σ m g·x`.
    pub fn potential_energy(&self, gravity: &[Real; 3]) -> Real {
        if let Some(held) = &self.committed.state_held {
            return -(0..self.def.dim).map(|i| gravity[i] * held.mass_moment[i]).sum::<Real>();
        }
        (0..self.def.mesh.nodes.len())
            .map(|n| {
                let x = self.position(n);
                -(0..self.def.dim).map(|i| self.def.mass[n * self.def.dim + i] * gravity[i] * x[i]).sum::<Real>()
            })
            .sum()
    }

    /// Mean von Mises stress of the given elements in the current state.
    pub fn von_mises(&self, elements: &[usize]) -> Real {
        let sum: Real = elements
            .iter()
            .map(|&e| match &self.def.patches {
                Some(patches) => {
                    let (patch, point) = patches.slot(e);
                    self.patch_point_fields(patch)[point].von_mises
                }
                None => element_von_mises(&self.def.model, self.def.geometry.element_points(e), &self.def.mesh.element_displacements(&self.committed.state.u, e), self.def.dim, self.def.formulation),
            })
            .sum();
        sum / elements.len().max(1) as Real
    }

    /// Stress and volume ratio of every element of the mesh at the committed state (a patched
    /// simplex's are its own point's, with its patch's volume change).
    pub fn cell_fields(&self) -> Vec<CellFields> {
        match &self.def.patches {
            Some(patches) => {
                let per_patch: Vec<Vec<CellFields>> = (0..patches.cells.element_count()).map(|p| self.patch_point_fields(p)).collect();
                (0..self.def.mesh.element_count())
                    .map(|e| {
                        let (patch, point) = patches.slot(e);
                        per_patch[patch][point]
                    })
                    .collect()
            }
            None => (0..self.def.mesh.element_count()).map(|e| element_cell_fields(&self.def.model, self.def.geometry.element_points(e), &self.def.mesh.element_displacements(&self.committed.state.u, e), self.def.dim, self.def.formulation)).collect(),
        }
    }

    fn patch_point_fields(&self, patch: usize) -> Vec<CellFields> {
        element_point_fields(&self.def.model, self.def.geometry.element_points(patch), &self.elements().element_displacements(&self.committed.state.u, patch), self.def.dim, self.def.formulation)
    }
}
