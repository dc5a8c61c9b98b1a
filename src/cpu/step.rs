//! The CPU twins of the kernels that begin and commit a step on the device
//! (`shaders/step_begin.wgsl`, `step_commit.wgsl`), each the work of one member, written as the
//! shaders read.

use crate::gpu::types::{DofOut, DofState, DofStep, MemberRange, StepMotion};
use crate::precision::Real;

/// What `step_begin` sets a committed state up from, for the members whose `adopt_at` is the
/// pass's `epoch`: the device's last iterate (`u`) and forces, the host's velocities.
pub struct Adoption<'a> {
    pub dof_out: &'a [DofOut<Real>],
    pub adopted: &'a [Real],
    pub adopt_at: &'a [u32],
    pub epoch: u32,
}

/// `step_begin` for member `member` (its dofs `range`): per dof the predictor `u_t + dt v_t`
/// from the committed state (set up first from [`Adoption`] where the member adopts), into the
/// step inputs (mass and external force kept), the trial displacement and the start
/// displacement.
pub fn step_begin(motion: StepMotion<Real>, committed: &mut [DofState<Real>], step: &mut [DofStep<Real>], u: &mut [Real], (u_start, u_base): (&mut [Real], &mut [Real]), a: &Adoption, (member, range): (usize, MemberRange)) {
    for local in 0..range.dofs as usize {
        let d = range.dof_start as usize + local;
        let mut c = committed[d];
        if a.adopt_at[member] == a.epoch {
            c = DofState { u: u[d], v: a.adopted[d], f_int: a.dof_out[d].f_int };
            committed[d] = c;
        }
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
