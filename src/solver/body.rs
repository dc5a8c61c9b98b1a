//! A deformable body at run time: mesh, material, lumped mass, constraints, state, and the
//! Newton solve of one theta-method step (paper eqs. 16-19).

use super::linear::{CholeskySolver, LinearError};
use super::PhaseTimes;
use crate::assembly::{scatter_add, DofMap, StiffnessPattern};
use crate::element::{element_energy, element_force_tangent, element_von_mises, ElementError, ElementOutput, ReferenceGeometry};
use crate::material::Model;
use crate::mesh::Mesh;
use crate::precision::Real;
use std::time::Instant;

/// Displacement, velocity and internal force of every dof.
#[derive(Debug, Clone)]
pub struct State {
    pub u: Vec<Real>,
    pub v: Vec<Real>,
    pub f_int: Vec<Real>,
}

/// A prescribed dof: its constant velocity and the boundary set that owns its reaction.
#[derive(Debug, Clone, Copy)]
pub struct Prescribed {
    pub dof: usize,
    pub velocity: Real,
    pub set: usize,
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
    #[error("body `{body}`: element {element}: {error}")]
    Element { body: String, element: usize, error: ElementError },
    #[error("body `{body}`: {error}")]
    Linear { body: String, error: String },
    #[error("body `{body}`: Newton did not converge in {iterations} iterations (residual {residual:.3e}, tolerance {tolerance:.3e})")]
    NotConverged { body: String, iterations: usize, residual: Real, tolerance: Real },
    #[error("body `{body}`: the residual is not finite")]
    NotFinite { body: String },
}

/// Outcome of a converged step of one body.
#[derive(Debug, Clone, Copy, Default)]
pub struct BodyStepStats {
    pub iterations: usize,
    pub residual: Real,
}

pub struct Body {
    pub name: String,
    pub mesh: Mesh,
    pub geometry: ReferenceGeometry,
    pub model: Model,
    pub dim: usize,
    /// Lumped mass of each dof.
    pub mass: Vec<Real>,
    pub dofs: DofMap,
    pub pattern: StiffnessPattern,
    pub prescribed: Vec<Prescribed>,
    pub state: State,
    /// The state of the step being solved, committed by [`Body::commit`].
    pub trial: State,
    /// Reaction at each prescribed dof (same order as `prescribed`) at the end of the trial step.
    pub reactions: Vec<Real>,
    /// Smallest edge length: the floor of the increment test.
    length_scale: Real,
    /// Largest dof mass: with `length_scale`, sets the residual floor below round-off.
    max_mass: Real,
    solver: CholeskySolver,
    values: Vec<Real>,
    element_out: ElementOutput,
}

impl Body {
    /// `initial_velocity(node) -> velocity` gives the free motion at t = 0; prescribed dofs start
    /// at their prescribed velocity.
    pub fn new(
        name: String,
        mesh: Mesh,
        geometry: ReferenceGeometry,
        model: Model,
        density: Real,
        prescribed: Vec<Prescribed>,
        initial_velocity: impl Fn([Real; 3]) -> [Real; 3],
    ) -> Result<Self, LinearError> {
        let dim = mesh.dim();
        let ndof = mesh.nodes.len() * dim;
        let nodal = geometry.lumped_masses(&mesh, density);
        let mass: Vec<Real> = (0..ndof).map(|d| nodal[d / dim]).collect();
        let mut is_prescribed = vec![false; ndof];
        for p in &prescribed {
            is_prescribed[p.dof] = true;
        }
        let dofs = DofMap::new(dim, &is_prescribed);
        let pattern = StiffnessPattern::new(&mesh, &dofs);
        let solver = CholeskySolver::new(&pattern)?;
        let mut v = vec![0.0; ndof];
        for (n, x) in mesh.nodes.iter().enumerate() {
            let w = initial_velocity(*x);
            v[n * dim..(n + 1) * dim].copy_from_slice(&w[..dim]);
        }
        for p in &prescribed {
            v[p.dof] = p.velocity;
        }
        let state = State { u: vec![0.0; ndof], v, f_int: vec![0.0; ndof] };
        let values = vec![0.0; pattern.nnz()];
        let reactions = vec![0.0; prescribed.len()];
        let length_scale = mesh.min_edge_length();
        let max_mass = mass.iter().cloned().fold(0.0, Real::max);
        Ok(Self {
            name,
            mesh,
            geometry,
            model,
            dim,
            mass,
            dofs,
            pattern,
            prescribed,
            trial: state.clone(),
            state,
            reactions,
            length_scale,
            max_mass,
            solver,
            values,
            element_out: ElementOutput::default(),
        })
    }

    /// Nodal displacements of element `e`, padded to 3 components, into `out`.
    fn gather_displacements(mesh: &Mesh, dim: usize, u: &[Real], e: usize, out: &mut Vec<[Real; 3]>) {
        out.clear();
        out.extend(mesh.element(e).iter().map(|&n| {
            let mut d = [0.0; 3];
            d[..dim].copy_from_slice(&u[n as usize * dim..(n as usize + 1) * dim]);
            d
        }));
    }

    fn element_displacements(&self, u: &[Real], e: usize) -> Vec<[Real; 3]> {
        let mut out = Vec::new();
        Self::gather_displacements(&self.mesh, self.dim, u, e, &mut out);
        out
    }

    /// Internal force at `u` into `f_int`; with `stiffness_factor`, also that multiple of the
    /// tangent into the CSC values (which are zeroed first).
    pub fn assemble(&mut self, u: &[Real], f_int: &mut [Real], stiffness_factor: Option<Real>, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        f_int.iter_mut().for_each(|f| *f = 0.0);
        if stiffness_factor.is_some() {
            self.values.iter_mut().for_each(|v| *v = 0.0);
        }
        let dim = self.dim;
        let mut ue = Vec::with_capacity(self.mesh.kind.nodes());
        for e in 0..self.mesh.element_count() {
            Self::gather_displacements(&self.mesh, dim, u, e, &mut ue);
            let t0 = Instant::now();
            element_force_tangent(&self.model, self.geometry.element_points(e), &ue, dim, stiffness_factor.is_some(), &mut self.element_out)
                .map_err(|error| StepFailure::Element { body: self.name.clone(), element: e, error })?;
            let t1 = Instant::now();
            for (a, &n) in self.mesh.element(e).iter().enumerate() {
                for i in 0..dim {
                    f_int[n as usize * dim + i] += self.element_out.force[a * dim + i];
                }
            }
            if let Some(factor) = stiffness_factor {
                scatter_add(&mut self.values, self.pattern.element_scatter(e), &self.element_out.tangent, factor);
            }
            times.elements += (t1 - t0).as_secs_f64();
            times.assembly += t1.elapsed().as_secs_f64();
        }
        Ok(())
    }

    /// Internal force of the current state (at set-up, and after the state is changed by hand).
    pub fn refresh_internal_force(&mut self) -> Result<(), StepFailure> {
        let u = std::mem::take(&mut self.state.u);
        let mut f = std::mem::take(&mut self.state.f_int);
        let result = self.assemble(&u, &mut f, None, &mut PhaseTimes::default());
        self.state.u = u;
        self.state.f_int = f;
        result
    }

    /// Solves one step of length `dt` from `state` into `trial` (not committed).
    ///
    /// Residual of eqs. (16)-(19), with `F = F_ext - F_int`:
    /// `g(u) = M (u - u_t - dt v_t) / (θ dt²) - (1-ξ) F_t - ξ F(u)`, zero at free dofs and equal
    /// to the reaction at prescribed dofs. Newton: `(ξ K + M/(θ dt²)) Δu = -g`.
    pub fn solve_step(&mut self, p: &StepParams, gravity: &[Real; 3], times: &mut PhaseTimes) -> Result<BodyStepStats, StepFailure> {
        let (dt, xi, theta) = (p.dt, p.xi, p.theta);
        let c1 = 1.0 / (theta * dt * dt);
        let dim = self.dim;
        let ndof = self.mass.len();
        let f_ext: Vec<Real> = (0..ndof).map(|d| self.mass[d] * gravity[d % dim]).collect();
        let mut u: Vec<Real> = (0..ndof).map(|d| self.state.u[d] + dt * self.state.v[d]).collect();
        for pr in &self.prescribed {
            u[pr.dof] = self.state.u[pr.dof] + dt * pr.velocity;
        }
        let mut f_int = std::mem::take(&mut self.trial.f_int);
        let mut g = vec![0.0; ndof];
        let mut rhs = vec![0.0; self.dofs.free_count];
        let length = self.length_scale;
        let floor = 1e-14 * c1 * self.max_mass * length;
        let mut last_increment = None;
        let mut iterations = 0;
        let result = loop {
            if let Err(e) = self.assemble(&u, &mut f_int, Some(xi), times) {
                break Err(e);
            }
            let (mut res2, mut scale2) = (0.0, 0.0);
            let mut step2: Real = 0.0;
            for d in 0..ndof {
                let inertia = c1 * self.mass[d] * (u[d] - self.state.u[d] - dt * self.state.v[d]);
                let f_t = f_ext[d] - self.state.f_int[d];
                let f_new = f_ext[d] - f_int[d];
                g[d] = inertia - (1.0 - xi) * f_t - xi * f_new;
                // The force scale spans all dofs: at equilibrium the free-dof forces nearly cancel,
                // while round-off follows the element forces, which the reactions reflect.
                scale2 += inertia * inertia + (xi * f_int[d]).powi(2) + ((1.0 - xi) * self.state.f_int[d]).powi(2) + f_ext[d] * f_ext[d];
                if self.dofs.free[d].is_some() {
                    res2 += g[d] * g[d];
                    step2 += (u[d] - self.state.u[d]).powi(2);
                }
            }
            let residual = res2.sqrt();
            if !residual.is_finite() {
                break Err(StepFailure::NotFinite { body: self.name.clone() });
            }
            let tolerance = p.residual_tolerance * scale2.sqrt() + floor;
            let increment_ok = last_increment.is_none_or(|du: Real| du <= p.increment_tolerance * step2.sqrt().max(1e-12 * length));
            if residual <= tolerance && increment_ok {
                break Ok(BodyStepStats { iterations, residual });
            }
            if iterations == p.max_iterations {
                break Err(StepFailure::NotConverged { body: self.name.clone(), iterations, residual, tolerance });
            }
            for (d, f) in self.dofs.free_pairs() {
                rhs[f] = -g[d];
            }
            if let Err(e) = self.factorize_effective(c1, times) {
                break Err(e);
            }
            self.solve_effective(&mut rhs, times);
            let mut du2 = 0.0;
            for (d, f) in self.dofs.free_pairs() {
                u[d] += rhs[f];
                du2 += rhs[f].powi(2);
            }
            last_increment = Some(du2.sqrt());
            iterations += 1;
        };
        let stats = match result {
            Ok(s) => s,
            Err(e) => {
                self.trial.f_int = f_int;
                return Err(e);
            }
        };
        let mut v = vec![0.0; ndof];
        for d in 0..ndof {
            v[d] = (u[d] - self.state.u[d] - dt * (1.0 - theta) * self.state.v[d]) / (theta * dt);
        }
        for (k, pr) in self.prescribed.iter().enumerate() {
            v[pr.dof] = pr.velocity;
            self.reactions[k] = g[pr.dof];
        }
        self.trial = State { u, v, f_int };
        Ok(stats)
    }

    /// Adds `c1 M` to the assembled `ξ K` and factorises `K̄ = ξ K + c1 M` (eq. 17).
    pub fn factorize_effective(&mut self, c1: Real, times: &mut PhaseTimes) -> Result<(), StepFailure> {
        for (d, f) in self.dofs.free_pairs() {
            self.values[self.pattern.diagonal[f] as usize] += c1 * self.mass[d];
        }
        let t0 = Instant::now();
        let result = self.solver.factorize(&self.values).map_err(|e| StepFailure::Linear { body: self.name.clone(), error: e.to_string() });
        times.factorization += t0.elapsed().as_secs_f64();
        result
    }

    /// Solves `K̄ x = rhs` in place (free dofs) with the last factorisation.
    pub fn solve_effective(&self, rhs: &mut [Real], times: &mut PhaseTimes) {
        let t0 = Instant::now();
        self.solver.solve(rhs);
        times.solve += t0.elapsed().as_secs_f64();
    }

    /// Work done by the reactions over the trial step: `Σ R_c (u_c - u_c,t)`.
    pub fn reaction_work(&self) -> Real {
        self.prescribed.iter().zip(&self.reactions).map(|(p, r)| r * (self.trial.u[p.dof] - self.state.u[p.dof])).sum()
    }

    pub fn commit(&mut self) {
        std::mem::swap(&mut self.state, &mut self.trial);
    }

    pub fn kinetic_energy(&self) -> Real {
        0.5 * self.mass.iter().zip(&self.state.v).map(|(m, v)| m * v * v).sum::<Real>()
    }

    pub fn strain_energy(&self) -> Real {
        (0..self.mesh.element_count())
            .map(|e| element_energy(&self.model, self.geometry.element_points(e), &self.element_displacements(&self.state.u, e)))
            .sum()
    }

    /// Current position of a node.
    pub fn position(&self, node: usize) -> [Real; 3] {
        let mut x = self.mesh.nodes[node];
        for i in 0..self.dim {
            x[i] += self.state.u[node * self.dim + i];
        }
        x
    }

    /// Gravity potential `-Σ m g·x`.
    pub fn potential_energy(&self, gravity: &[Real; 3]) -> Real {
        (0..self.mesh.nodes.len())
            .map(|n| {
                let x = self.position(n);
                -(0..self.dim).map(|i| self.mass[n * self.dim + i] * gravity[i] * x[i]).sum::<Real>()
            })
            .sum()
    }

    /// Mean von Mises stress of the given elements in the current state.
    pub fn von_mises(&self, elements: &[usize]) -> Real {
        let sum: Real = elements
            .iter()
            .map(|&e| element_von_mises(&self.model, self.geometry.element_points(e), &self.element_displacements(&self.state.u, e)))
            .sum();
        sum / elements.len().max(1) as Real
    }
}
