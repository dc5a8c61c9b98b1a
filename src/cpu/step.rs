//! The CPU twins of the kernels that begin and commit a step on the device
//! (`shaders/step_begin.wgsl`, `step_commit.wgsl`), each the work of one member, written as the
//! shaders read.

use crate::gpu::types::{DofOut, DofState, DofStep, MemberRange, StepMotion};
use crate::precision::Real;

/// `step_begin` for member `range`: per dof the predictor `u_t + dt v_t` from the committed
/// state, into the step inputs (mass and external force kept), the trial displacement and the
/// start displacement.
pub fn step_begin(motion: StepMotion<Real>, committed: &[DofState<Real>], step: &mut [DofStep<Real>], u: &mut [Real], (u_start, u_base): (&mut [Real], &mut [Real]), range: MemberRange) {
    for local in 0..range.dofs as usize {
        let d = range.dof_start as usize + local;
        let c = committed[d];
        let u_pred = c.u + motion.dt * c.v;
        step[d].u_pred = u_pred;
        step[d].f_int_t = c.f_int;
        u[d] = u_pred;
        u_start[d] = c.u;
        u_base[d] = c.u + motion.dt_explicit * c.v;
    }
}

/// `step_commit` for member `member` (its dofs `range`): per dof the theta rule's velocity from
/// the committed state and the step's last iterate, and the new committed state; its strain
/// energy, the member's.
pub fn step_commit(motion: StepMotion<Real>, (committed, committed_energy): (&mut [DofState<Real>], &mut [Real]), (u, dof_out, member_energy): (&[Real], &[DofOut<Real>], &[Real]), member: usize, range: MemberRange) {
    committed_energy[member] = member_energy[member];
    for local in 0..range.dofs as usize {
        let d = range.dof_start as usize + local;
        let c = committed[d];
        let v = (u[d] - c.u - motion.dt_explicit * c.v) / motion.theta_dt;
        committed[d] = DofState { u: u[d], v, f_int: dof_out[d].f_int };
    }
}
