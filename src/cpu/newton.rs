//! The CPU twins of a device Newton iteration's own kernels (`shaders/newton_update.wgsl`,
//! `newton_judge.wgsl`, `newton_compact.wgsl`), each the work of one workgroup, written as the
//! shader spreads it over its invocations so that the sums are taken in the same order. The
//! engine's CPU path solves with faer instead; these are the oracle of the parity tests.

use crate::gpu::types::{Active, Coefficients, DofOut, DofStep, MemberRange, NewtonMember, NewtonState, NEWTON_CONVERGED, NEWTON_FAILED, NEWTON_HOST, NEWTON_ITERATING, NEWTON_WORKGROUP, NO_FAILURE};
use crate::precision::Real;
use crate::solver::REFACTOR_CONTRACTION;

/// The sum of one value per invocation by halves, as `reduce_sum` of `newton.wgsl`.
fn reduce_sum(mut partial: [Real; NEWTON_WORKGROUP]) -> Real {
    let mut half = NEWTON_WORKGROUP / 2;
    while half > 0 {
        for lane in 0..half {
            partial[lane] += partial[lane + half];
        }
        half /= 2;
    }
    partial[0]
}

/// The largest of one value per invocation (`reduce_max`).
fn reduce_max(partial: [Real; NEWTON_WORKGROUP]) -> Real {
    partial.into_iter().fold(0.0, Real::max)
}

/// `newton_update` for member `m`: `Δu = K̄⁻¹ (-g)` on its free dofs, `u += Δu`, and the
/// increment's norm and count into its state; nothing unless it is still iterating.
#[allow(clippy::too_many_arguments)]
pub fn newton_update(inverse: &[Real], free_dofs: &[u32], newton: &[NewtonMember<Real>], state: &mut [NewtonState<Real>], dof_out: &[DofOut<Real>], u: &mut [Real], members: &[MemberRange], m: usize) {
    if state[m].status != NEWTON_ITERATING {
        return;
    }
    let dof_start = members[m].dof_start as usize;
    let row = newton[m];
    let n = row.free_count as usize;
    let free = &free_dofs[row.free_start as usize..][..n];
    let rhs: Vec<Real> = free.iter().map(|&k| -dof_out[dof_start + k as usize].g).collect();
    let mut sum2 = [0.0; NEWTON_WORKGROUP];
    let mut moved = false;
    for (f, &k) in free.iter().enumerate() {
        // Column f as row f (K̄⁻¹ is symmetric), as the shader reads it.
        let mut du = 0.0;
        for (j, r) in rhs.iter().enumerate() {
            du += inverse[row.inverse_start as usize + j * n + f] * r;
        }
        u[dof_start + k as usize] += du;
        sum2[f % NEWTON_WORKGROUP] += du * du;
        moved |= du != 0.0;
    }
    let s = &mut state[m];
    s.increment = reduce_sum(sum2).sqrt();
    s.iterations += 1;
    s.moved |= moved as u32;
}

/// `newton_judge` for member `m` after an evaluation: the test of `Body::converged`, and
/// whether the member goes on iterating, converged, needs the host or failed.
#[allow(clippy::too_many_arguments)]
pub fn newton_judge(
    free_dofs: &[u32],
    newton: &[NewtonMember<Real>],
    state: &mut [NewtonState<Real>],
    dof_out: &[DofOut<Real>],
    u: &[Real],
    u_start: &[Real],
    step: &[DofStep<Real>],
    coefficients: Coefficients<Real>,
    failure: &[u32],
    members: &[MemberRange],
    m: usize,
) {
    if state[m].status != NEWTON_ITERATING {
        return;
    }
    let range = members[m];
    let row = newton[m];
    let xi = coefficients.factor;
    let (mut scale2, mut travel) = ([0.0; NEWTON_WORKGROUP], [0.0 as Real; NEWTON_WORKGROUP]);
    for k in 0..range.dofs as usize {
        let d = range.dof_start as usize + k;
        let (out, s) = (dof_out[d], step[d]);
        let inertia = out.g + (1.0 - xi) * (s.f_ext - s.f_int_t) + xi * (s.f_ext - out.f_int);
        let (a, b) = (xi * out.f_int, (1.0 - xi) * s.f_int_t);
        scale2[k % NEWTON_WORKGROUP] += inertia * inertia + a * a + b * b + s.f_ext * s.f_ext;
        travel[k % NEWTON_WORKGROUP] = travel[k % NEWTON_WORKGROUP].max(u[d].abs());
    }
    let (mut residual2, mut step2, mut size2) = ([0.0; NEWTON_WORKGROUP], [0.0; NEWTON_WORKGROUP], [0.0; NEWTON_WORKGROUP]);
    for f in 0..row.free_count as usize {
        let d = range.dof_start as usize + free_dofs[row.free_start as usize + f] as usize;
        let (g, du) = (dof_out[d].g, u[d] - u_start[d]);
        residual2[f % NEWTON_WORKGROUP] += g * g;
        step2[f % NEWTON_WORKGROUP] += du * du;
        size2[f % NEWTON_WORKGROUP] += u[d] * u[d];
    }
    let scale = reduce_sum(scale2).sqrt();
    let most = reduce_max(travel);
    let residual = reduce_sum(residual2).sqrt();
    let moved = reduce_sum(step2).sqrt();
    let size = reduce_sum(size2).sqrt();
    let s = &mut state[m];
    if failure[2 * m] != NO_FAILURE || failure[2 * m + 1] != NO_FAILURE {
        s.status = NEWTON_FAILED;
        return;
    }
    let tolerance = row.residual_tolerance * scale + row.floor + row.floor_per_travel * most;
    let allowed = row.increment_tolerance * moved.max(row.increment_floor) + row.round_off * size;
    let contraction = residual / s.residual.max(Real::MIN_POSITIVE);
    if residual <= tolerance && s.increment <= allowed {
        s.status = NEWTON_CONVERGED;
    } else if !residual.is_finite() || s.iterations >= row.budget || contraction > REFACTOR_CONTRACTION {
        s.status = NEWTON_HOST;
    }
    s.previous_residual = s.residual;
    s.residual = residual;
}

/// `newton_compact`: the members of the call's list still iterating, in its order, into `jobs`;
/// returns their count (the dispatches' z).
pub fn newton_compact(call: &[Active], state: &[NewtonState<Real>], jobs: &mut [Active]) -> usize {
    let mut at = 0;
    for c in call.iter().filter(|c| state[c.member as usize].status == NEWTON_ITERATING) {
        jobs[at] = *c;
        at += 1;
    }
    at
}
