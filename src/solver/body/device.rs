//! What the device rounds ask of a body (`solver/lockstep.rs`, `gpu::world`): its share of the
//! device world, its evaluations and Newton calls on the device and taking their results back,
//! the inverse of its factorisation the device iterates with, and whether it may iterate there.
//! The host's own Newton step is in `body.rs`.

use super::*;

impl Body {
    /// The step's viscoelastic relaxation, if the body has a Prony series.
    pub fn relaxation(&self) -> Option<Relaxation<'_>> {
        self.def.viscoelastic.as_ref().map(|_| Relaxation { c: self.work.relaxation_c, history: &self.work.history })
    }

    /// What the GPU world uploads of the body.
    pub fn world_body(&self) -> WorldBody<'_> {
        WorldBody { mesh: self.elements(), geometry: &self.def.geometry, model: &self.def.model, formulation: self.def.formulation, pattern: &self.def.pattern, gather: &self.def.gather, dofs: &self.def.dofs, viscous: self.def.viscoelastic.is_some() }
    }

    /// The step's start values of every dof (after [`Body::begin_step`]).
    pub fn step_inputs(&self) -> &[DofStep<Real>] {
        &self.work.step_inputs
    }

    /// What the device takes at the start of the body's step ([`crate::gpu::GpuWorld::begin_step`]).
    pub fn step_start(&self, body: usize) -> StepStart<'_> {
        assert!(self.committed.state_held.is_none() || self.may_step_on_device(), "a body whose state the device keeps steps there");
        StepStart { body, inputs: &self.work.step_inputs, u: &self.committed.state.u, on_device: self.may_step_on_device() }
    }

    /// The committed state the device follows after a kept step ([`crate::gpu::GpuWorld::commit_step`]).
    pub fn step_end(&self, body: usize) -> StepEnd<'_> {
        StepEnd { body, u: &self.committed.state.u, v: &self.committed.state.v, f_int: &self.committed.state.f_int, strain: self.committed.state.strain, on_device: self.may_step_on_device(), held: self.committed.state_held.is_some() }
    }

    /// Whether the device may begin and commit the body's steps from the state it keeps: its
    /// step inputs then follow from that state alone (no surface loads, whose forces change
    /// with time; no prescribed dofs, which move by their own rule; no Prony series, whose
    /// history the host advances).
    pub fn may_step_on_device(&self) -> bool {
        self.def.loads.is_empty() && self.def.prescribed.is_empty() && self.def.viscoelastic.is_none()
    }

    /// A device failure of an evaluation that involved this body.
    pub fn device_failure(&self, error: &GpuError) -> StepFailure {
        StepFailure::Device { body: self.def.name.clone(), error: error.to_string() }
    }

    /// The body's share of a GPU world evaluation at the trial displacement: the tangent if
    /// `tangent`, the residual if `residual`. Finish with [`Body::finish_device_evaluation`].
    pub fn device_evaluation(&mut self, body: usize, tangent: bool, residual: bool) -> Evaluation<'_> {
        self.work.tangent_current = false;
        self.work.evaluated.valid = false;
        Evaluation { body, u: &self.work.trial.u, tangent, values: &mut self.work.values, dof_out: residual.then_some(&mut self.work.dof_out[..]), failure: None }
    }

    /// Takes the results of a GPU world evaluation (see [`Body::device_evaluation`]). A residual
    /// the device did not compute (f32 kernels) is computed here in f64 by the CPU twins, so
    /// that Newton converges to the same answer and the f32 tangent only changes how fast.
    pub fn finish_device_evaluation(&mut self, p: &StepParams, failure: Option<ElementFailure>, tangent: bool, residual: bool) -> Result<(), StepFailure> {
        if let Some(failure) = failure {
            return Err(self.element_failure(&self.work.trial.u, failure));
        }
        self.work.tangent_current = tangent;
        if residual {
            if !tangent {
                self.work.evaluated.record(&self.work.trial.u, &self.work.step_inputs, coefficients(p));
            }
            self.absorb_residual(p);
        }
        Ok(())
    }

    /// Per dof, `u_t + dt (1 - θ) v_t`: the trial velocity is `(u - base) / θdt` (a device
    /// that takes the increments of a group in contact computes it so).
    pub fn trial_velocity_base(&self, p: &StepParams) -> Vec<Real> {
        self.committed.state.u.iter().zip(&self.committed.state.v).map(|(u, v)| u + p.dt * (1.0 - p.theta) * v).collect()
    }

    /// Whether the next increments can be taken on the device ([`crate::gpu::GpuWorld::newton`]):
    /// the body has free dofs and keeps a factorisation fit for them.
    pub fn iterates_on_device(&self, p: &StepParams) -> bool {
        self.def.dofs.free_count > 0 && !self.needs_factorization(p)
    }

    /// Whether the body's factorisation is one for this step's `c1` that the next increment may
    /// use, right after [`Body::refresh_factor`] (which keeps or renews it): its next increment
    /// can be taken on the device.
    pub fn factor_fit(&self, p: &StepParams) -> bool {
        self.def.dofs.free_count > 0 && self.factor_kept_for(p)
    }

    /// Which factorisation the body holds (a new number for each).
    pub fn factor_version(&self) -> u64 {
        self.work.factor_version
    }

    /// What the device needs to make `K̄⁻¹` of the kept factorisation: where it `inverts` one
    /// of this size, the values factorised, `K̄`, while the body holds them (no newer tangent:
    /// [`Body::kept_factor`]); else `K̄⁻¹` ([`Body::effective_inverse`]).
    pub fn device_inverse(&mut self, inverts: bool, times: &mut PhaseTimes) -> Inverse {
        debug_assert!(self.work.factor_on_device.is_none(), "the device holds this version");
        if inverts && !self.work.tangent_current {
            if self.work.factored_at_hand_back {
                Inverse::AtHandBack(self.work.values.clone())
            } else {
                Inverse::Effective(self.work.values.clone())
            }
        } else {
            Inverse::Dense(self.effective_inverse(times))
        }
    }

    /// `K̄⁻¹` of the free dofs of the kept factorisation, its lower triangle row by row
    /// (`gpu::types::packed`), for a device that applies it: a dense inverse of the values
    /// factorised, which the body holds while it has no newer tangent ([`Body::kept_factor`]);
    /// else, or if the dense factorisation fails, the factor's solves of the identity's columns,
    /// entry `(i, j)`, `i >= j`, from column `j` (`K̄` is symmetric).
    pub fn effective_inverse(&mut self, times: &mut PhaseTimes) -> Vec<Real> {
        if !self.work.tangent_current {
            let t0 = Instant::now();
            let dense = self.work.solver.dense_inverse(&self.work.values);
            times.solve += t0.elapsed().as_secs_f64();
            if let Some(inverse) = dense {
                return inverse;
            }
        }
        let n = self.def.dofs.free_count;
        let mut x = vec![0.0; n * n];
        for f in 0..n {
            x[f * n + f] = 1.0;
        }
        self.solve_effective(&mut x, times);
        crate::gpu::types::pack_lower(n, |i, j| x[j * n + i])
    }

    /// The body's share of device Newton iterations from its evaluated iterate: the tolerances
    /// of [`Body::converged`] (the parts that do not change while it iterates; the scene's
    /// motion, the increment bound's floor, is the call's `Coefficients::motion`), on from the
    /// `taken` iterations of its step (at most `solver.max_iterations` in all), `inverse` when
    /// the device does not hold this factorisation's;
    /// `evaluated`: the trial displacement's evaluation is the body's (else the device evaluates
    /// it first).
    pub fn newton_call(&mut self, body: usize, p: &StepParams, taken: usize, inverse: Option<Inverse>, evaluated: bool) -> NewtonCall<'_> {
        let [constant, per_travel, stiffness] = self.residual_floor_terms(p);
        let member = NewtonMember {
            budget: p.max_iterations as u32,
            residual_tolerance: p.residual_tolerance,
            floor: constant + stiffness,
            floor_per_travel: per_travel,
            increment_tolerance: p.increment_tolerance,
            // The scene's motion, which grows while grains fall, is the call's (`Coefficients`):
            // the member's own row stays the same from step to step and is not uploaded again.
            increment_floor: self.increment_floor(0.0),
            round_off: 1e3 * Real::EPSILON * self.stiffness_spread(),
            ..NewtonMember::default()
        };
        let residual = evaluated.then(|| self.residual_norm());
        if !evaluated {
            self.work.evaluated.valid = false;
        }
        NewtonCall {
            body,
            taken: taken as u32,
            factor: self.work.factor_version,
            inverse,
            member,
            residual,
            u: &mut self.work.trial.u,
            dof_out: &mut self.work.dof_out,
            u_start: &self.committed.state.u,
            inputs: &self.work.step_inputs,
            contact_force: Some(&self.work.contact_force),
            keep: false,
            positions: false,
            summary: None,
            outcome: NewtonState::default(),
            strain_energy: None,
            failure: None,
            tangent_held: false,
        }
    }

    /// Takes the end of device Newton iterations ([`Body::newton_call`]): the last iterate and
    /// its evaluation, as if the host had taken the increments, so that the next convergence
    /// test ([`Body::converged`], the host's word) sees the last increment and the residual
    /// before the last. A call that evaluated the body first and stopped there took no increment:
    /// the test then sees a first evaluation.
    /// Where the device holds the tangent at this iterate ([`NewtonCall::tangent_held`]), a
    /// refactorisation here sends its `K̄` by its diagonal ([`Inverse::AtHandBack`]).
    pub fn finish_device_newton(&mut self, p: &StepParams, outcome: &NewtonState<Real>, strain_energy: Option<Real>, failure: Option<ElementFailure>, tangent_held: bool, summary: Option<(StepSummary, bool)>) -> Result<(), StepFailure> {
        if let Some((summary, positions)) = summary {
            // Converged and kept on the device: the host's vectors are not the step's (but for
            // the displacements, when they came back).
            self.work.trial_held = Some(summary);
            self.work.trial_positions = positions;
            self.work.still = false;
            self.work.tangent_current = false;
            self.work.evaluated.valid = false;
            return Ok(());
        }
        self.work.device_tangent = tangent_held.then(|| self.work.trial.u.clone());
        if let Some(failure) = failure {
            return Err(self.element_failure(&self.work.trial.u, failure));
        }
        self.work.tangent_current = false;
        self.work.still &= outcome.moved == 0;
        if outcome.iterations > 0 {
            self.work.last_increment = Some(outcome.increment);
            self.work.previous_residual = Some(outcome.previous_residual);
        }
        self.work.evaluated.record(&self.work.trial.u, &self.work.step_inputs, coefficients(p));
        self.work.evaluated.strain = strain_energy;
        self.absorb_residual(p);
        Ok(())
    }

    /// After a kept device Newton call that did not converge (its iterate came back, its
    /// residuals computed from the host's stale step inputs): the committed state the device
    /// held (`states`, [`crate::gpu::GpuWorld::read_kept`]) is the host's again, the step's
    /// inputs follow from it as `step_begin` computed them, and the residuals from those.
    pub fn take_committed_mid_step(&mut self, p: &StepParams, kept: &KeptState) {
        self.take_committed(kept);
        for (d, s) in self.work.step_inputs.iter_mut().enumerate() {
            *s = DofStep { mass: self.def.mass[d], u_pred: self.committed.state.u[d] + p.dt * self.committed.state.v[d], f_int_t: self.committed.state.f_int[d], f_ext: self.work.f_ext[d] };
        }
        let c = coefficients(p);
        for (d, out) in self.work.dof_out.iter_mut().enumerate() {
            out.g = self.work.step_inputs[d].residual(c, self.work.trial.u[d], out.f_int);
        }
    }

    /// The strain energy at the trial displacement when a device Newton call left it there
    /// ([`Body::finish_device_newton`]) and the displacement has not changed since, bit for bit.
    pub fn evaluated_strain_energy(&self) -> Option<Real> {
        self.work.evaluated.strain.filter(|_| self.work.evaluated.valid && same_bits(&self.work.trial.u, &self.work.evaluated.u))
    }
}
