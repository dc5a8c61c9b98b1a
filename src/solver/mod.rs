//! Time stepping: Jean's first-order theta method solved by Newton, body by body, with
//! automatic cut-back of failed steps; energies and per-body, probe and reaction quantities.

pub mod body;
pub mod linear;
mod setup;

pub use body::{Body, StepFailure};
pub use setup::build_simulation;

use crate::precision::Real;
use body::StepParams;

/// Wall-clock seconds spent per phase.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct PhaseTimes {
    pub elements: f64,
    pub assembly: f64,
    pub factorization: f64,
    pub solve: f64,
    pub contact: f64,
    pub total: f64,
}

/// A node set with a prescribed motion (its reaction goes to `/reaction/<name>`).
#[derive(Debug, Clone)]
pub struct BoundarySet {
    pub name: String,
    pub body: usize,
}

/// A probe: the node nearest to the requested point, and the elements around it.
#[derive(Debug, Clone)]
pub struct Probe {
    pub name: String,
    pub body: usize,
    pub node: usize,
    pub elements: Vec<usize>,
}

/// What one (possibly cut-back) step did.
#[derive(Debug, Clone, Default)]
pub struct StepReport {
    pub step: usize,
    pub t: Real,
    pub dt: Real,
    pub newton_iterations: usize,
    pub residual_norm: Real,
    pub cutbacks: usize,
    pub wall: PhaseTimes,
    /// One line per cut-back: why the step failed and the new time step.
    pub events: Vec<String>,
}

/// A step that could not be completed even after all cut-backs.
#[derive(Debug, Clone, thiserror::Error)]
#[error("step {step} at t = {t:.6e} failed after {cutbacks} cut-backs (dt = {dt:.3e}): {failure}")]
pub struct RunFailure {
    pub step: usize,
    pub t: Real,
    pub dt: Real,
    pub cutbacks: usize,
    pub failure: StepFailure,
    /// The partial report (cut-back events) of the failing step.
    pub report: StepReport,
}

/// Energies of the whole system at the current time.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct Energies {
    pub kinetic: Real,
    pub strain: Real,
    pub potential: Real,
    pub external_work: Real,
    pub friction_dissipation: Real,
    pub total: Real,
}

pub struct Simulation {
    pub dim: usize,
    pub bodies: Vec<Body>,
    pub sets: Vec<BoundarySet>,
    pub probes: Vec<Probe>,
    pub gravity: [Real; 3],
    pub t: Real,
    pub step: usize,
    pub end: Real,
    pub dt: Real,
    pub xi: Real,
    pub theta: Real,
    pub residual_tolerance: Real,
    pub increment_tolerance: Real,
    pub max_iterations: usize,
    pub max_cutbacks: usize,
    /// Cumulative work of the reactions of prescribed sets.
    pub external_work: Real,
}

impl Simulation {
    /// Number of steps to reach `end` (the last one is shortened if `end` is not a multiple).
    pub fn step_count(&self) -> usize {
        ((self.end / self.dt) - 1e-9).ceil().max(1.0) as usize
    }

    pub fn finished(&self) -> bool {
        self.step >= self.step_count()
    }

    /// Advances one scene step, halving the time step of a failed attempt up to `max_cutbacks`
    /// times (each half is itself retried the same way).
    pub fn advance(&mut self) -> Result<StepReport, RunFailure> {
        let started = std::time::Instant::now();
        let dt = self.dt.min(self.end - self.t).max(self.dt * 1e-9);
        let mut report = StepReport { step: self.step + 1, dt, ..Default::default() };
        let result = self.advance_by(dt, 0, &mut report);
        report.wall.total = started.elapsed().as_secs_f64();
        match result {
            Ok(()) => {
                self.step += 1;
                report.t = self.t;
                Ok(report)
            }
            Err((failure, sub_dt)) => Err(RunFailure { step: self.step + 1, t: self.t, dt: sub_dt, cutbacks: report.cutbacks, failure, report }),
        }
    }

    fn advance_by(&mut self, dt: Real, depth: usize, report: &mut StepReport) -> Result<(), (StepFailure, Real)> {
        match self.try_step(dt, report) {
            Ok(()) => Ok(()),
            Err(failure) if depth < self.max_cutbacks => {
                report.cutbacks += 1;
                report.events.push(format!("t = {:.6e}: {failure}; retrying with dt = {:.3e}", self.t, dt / 2.0));
                self.advance_by(dt / 2.0, depth + 1, report)?;
                self.advance_by(dt / 2.0, depth + 1, report)
            }
            Err(failure) => Err((failure, dt)),
        }
    }

    fn try_step(&mut self, dt: Real, report: &mut StepReport) -> Result<(), StepFailure> {
        let params = StepParams {
            dt,
            xi: self.xi,
            theta: self.theta,
            residual_tolerance: self.residual_tolerance,
            increment_tolerance: self.increment_tolerance,
            max_iterations: self.max_iterations,
        };
        let mut residual: Real = 0.0;
        for body in &mut self.bodies {
            let stats = body.solve_step(&params, &self.gravity, &mut report.wall)?;
            report.newton_iterations += stats.iterations;
            residual = residual.max(stats.residual);
        }
        for body in &mut self.bodies {
            self.external_work += body.reaction_work();
            body.commit();
        }
        self.t += dt;
        report.residual_norm = residual;
        Ok(())
    }

    pub fn energies(&self) -> Energies {
        let mut e = Energies { external_work: self.external_work, ..Default::default() };
        for b in &self.bodies {
            e.kinetic += b.kinetic_energy();
            e.strain += b.strain_energy();
            e.potential += b.potential_energy(&self.gravity);
        }
        e.total = e.kinetic + e.strain + e.potential;
        e
    }

    /// Net reaction force of each boundary set (components beyond `dim` are zero).
    pub fn reactions(&self) -> Vec<[Real; 3]> {
        let mut r = vec![[0.0; 3]; self.sets.len()];
        for b in &self.bodies {
            for (p, f) in b.prescribed.iter().zip(&b.reactions) {
                r[p.set][p.dof % b.dim] += f;
            }
        }
        r
    }
}

/// Mass, centre of mass, momenta and kinetic energy of a body.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct BodyMetrics {
    pub mass: Real,
    pub center_of_mass: [Real; 3],
    pub linear_momentum: [Real; 3],
    /// About the origin; in 2D only the z component is non-zero.
    pub angular_momentum: [Real; 3],
    pub kinetic: Real,
}

impl Body {
    pub fn metrics(&self) -> BodyMetrics {
        let dim = self.dim;
        let (mut mass, mut mx, mut p, mut l) = (0.0, [0.0; 3], [0.0; 3], [0.0; 3]);
        for n in 0..self.mesh.nodes.len() {
            let m = self.mass[n * dim];
            let x = self.position(n);
            let mut v = [0.0; 3];
            v[..dim].copy_from_slice(&self.state.v[n * dim..(n + 1) * dim]);
            mass += m;
            for i in 0..3 {
                mx[i] += m * x[i];
                p[i] += m * v[i];
            }
            l[0] += m * (x[1] * v[2] - x[2] * v[1]);
            l[1] += m * (x[2] * v[0] - x[0] * v[2]);
            l[2] += m * (x[0] * v[1] - x[1] * v[0]);
        }
        BodyMetrics { mass, center_of_mass: mx.map(|c| c / mass), linear_momentum: p, angular_momentum: l, kinetic: self.kinetic_energy() }
    }
}
