//! The CPU twins of a device Newton iteration's own kernels (`shaders/newton_update.wgsl`,
//! `newton_judge.wgsl`, `newton_compact.wgsl`, `newton_contact.wgsl`), each the work of one workgroup, written as the
//! shader spreads it over its invocations so that the sums are taken in the same order. The
//! engine's CPU path solves with faer instead; these are the oracle of the parity tests.

use super::uzawa::{global, triple};
use crate::contact::uzawa::SETTLE;
use crate::gpu::types::{
    packed, packed_len, summary_len, Active, Coefficients, DofOut, DofState, DofStep, Inversion, MemberRange, NewtonMember, NewtonState, StepMotion, NEWTON_CONVERGED, NEWTON_FAILED, NEWTON_HOST, NEWTON_ITERATING, NEWTON_REFACTOR, NEWTON_WORKGROUP,
    NOT_FREE, NO_FAILURE, TALLY_LEN, TALLY_ROW,
};
use crate::gpu::uzawa_sweep::{NodeGather, UzawaJudgeState, UzawaLocal, UzawaProblem, JUDGE_CONVERGED, JUDGE_LIVE};
use crate::gpu::ContactLayout;
use crate::policy::{REFACTOR_CONTRACTION, TIGHTEN_AFTER, TIGHTEST_INNER, UZAWA_STALLS};
use crate::precision::Real;

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

/// Entry `f` of `K̄⁻¹ rhs` for a member whose `K̄⁻¹` (its lower triangle, [`packed`]) is at
/// `row.inverse_start`, as the shaders read it, summed in `rhs`'s order.
fn inverse_times(inverse: &[Real], row: &NewtonMember<Real>, f: usize, rhs: &[Real]) -> Real {
    let mut x = 0.0;
    for (j, r) in rhs.iter().enumerate() {
        x += inverse[row.inverse_start as usize + packed(j, f)] * r;
    }
    x
}

/// `newton_invert` for one listed member: its `K̄⁻¹` (lower triangle, [`packed`]) into its slot
/// of `inverse`, from its `K̄` values in `effective` (its diagonal only if `diagonal_only`, the
/// other entries from the member's stiffness `values`, where `members` places them) and its
/// pattern in `patterns`, by the shader's steps in the shader's order of every sum.
pub fn newton_invert(inverse: &mut [Real], newton: &[NewtonMember<Real>], effective: &[Real], (values, members): (&[Real], &[MemberRange]), patterns: &[u32], job: &Inversion) {
    let row = newton[job.member as usize];
    let n = row.free_count as usize;
    let slot = &mut inverse[row.inverse_start as usize..][..packed_len(n)];
    let (starts, rows) = (&patterns[job.pattern_start as usize..][..n + 1], &patterns[job.pattern_start as usize + n + 1..]);
    let own = members[job.member as usize].nonzero_start as usize;
    slot.fill(0.0);
    for j in 0..n {
        for k in starts[j] as usize..starts[j + 1] as usize {
            let i = rows[k] as usize;
            let value = if job.diagonal_only == 0 {
                effective[job.values_start as usize + k]
            } else if i == j {
                effective[job.values_start as usize + j]
            } else {
                values[own + k]
            };
            slot[packed(i, j)] = value;
        }
    }
    invert_in_place(slot, n);
}

/// `newton_invert`'s `refactor` for member `m` of the call's refactorisation list: its `K̄⁻¹`
/// from the stiffness values the tangent pass assembled (`values`, where `members` places them)
/// plus `c1` times the masses of its free dofs on the diagonal (`step`), over its pattern
/// (`pattern_of[m]` in `patterns`); its displacement into `u_factored`, one more refactorisation
/// in its state.
#[allow(clippy::too_many_arguments)]
pub fn newton_invert_refactor(
    inverse: &mut [Real],
    (newton, members, free_dofs): (&[NewtonMember<Real>], &[MemberRange], &[u32]),
    (values, step, c1): (&[Real], &[DofStep<Real>], Real),
    (patterns, pattern_of): (&[u32], &[u32]),
    (u, u_factored): (&[Real], &mut [Real]),
    state: &mut [NewtonState<Real>],
    m: usize,
) {
    let (row, range) = (newton[m], members[m]);
    let n = row.free_count as usize;
    let slot = &mut inverse[row.inverse_start as usize..][..packed_len(n)];
    let first = pattern_of[m] as usize;
    let (starts, rows) = (&patterns[first..][..n + 1], &patterns[first + n + 1..]);
    slot.fill(0.0);
    for j in 0..n {
        for k in starts[j] as usize..starts[j + 1] as usize {
            let i = rows[k] as usize;
            let mut value = values[range.nonzero_start as usize + k];
            if i == j {
                value += c1 * step[(range.dof_start + free_dofs[row.free_start as usize + j]) as usize].mass;
            }
            slot[packed(i, j)] = value;
        }
    }
    invert_in_place(slot, n);
    let dofs = range.dof_start as usize..(range.dof_start + range.dofs) as usize;
    u_factored[dofs.clone()].copy_from_slice(&u[dofs]);
    state[m].refactors += 1;
}

/// `invert_in_place` of `newton_invert.wgsl`: `K̄⁻¹` in place of `K̄` (lower triangles, [`packed`]):
/// L, L⁻¹, then L⁻ᵀ L⁻¹, every sum in the shader's order.
fn invert_in_place(slot: &mut [Real], n: usize) {
    for k in 0..n {
        let d = slot[packed(k, k)].sqrt();
        slot[packed(k, k)] = d;
        let scale = 1.0 / d;
        for i in k + 1..n {
            slot[packed(i, k)] *= scale;
        }
        for i in k + 1..n {
            let lik = slot[packed(i, k)];
            for j in k + 1..i + 1 {
                slot[packed(i, j)] -= lik * slot[packed(j, k)];
            }
        }
    }
    let mut column = vec![0.0; n];
    for j in (0..n).rev() {
        for i in j + 1..n {
            column[i] = slot[packed(i, j)];
        }
        let p = 1.0 / slot[packed(j, j)];
        for i in j + 1..n {
            let mut x = 0.0;
            for k in j + 1..i + 1 {
                x += slot[packed(i, k)] * column[k];
            }
            slot[packed(i, j)] = -p * x;
        }
        slot[packed(j, j)] = p;
    }
    for i in 0..n {
        for j in 0..i + 1 {
            let mut x = 0.0;
            for k in i..n {
                x += slot[packed(k, i)] * slot[packed(k, j)];
            }
            column[j] = x;
        }
        for j in 0..i + 1 {
            slot[packed(i, j)] = column[j];
        }
    }
}

/// `newton_update` for member `m`: `Δu = K̄⁻¹ (f_c - g)` on its free dofs (`contact`: the
/// contact forces per dof), `u += Δu`, and the increment's norm and count into its state;
/// nothing unless it is still iterating.
#[allow(clippy::too_many_arguments)]
pub fn newton_update(inverse: &[Real], free_dofs: &[u32], newton: &[NewtonMember<Real>], state: &mut [NewtonState<Real>], dof_out: &[DofOut<Real>], u: &mut [Real], members: &[MemberRange], contact: &[Real], m: usize) {
    if state[m].status != NEWTON_ITERATING {
        return;
    }
    let dof_start = members[m].dof_start as usize;
    let row = newton[m];
    let n = row.free_count as usize;
    let free = &free_dofs[row.free_start as usize..][..n];
    let rhs: Vec<Real> = free.iter().map(|&k| contact[dof_start + k as usize] - dof_out[dof_start + k as usize].g).collect();
    let mut sum2 = [0.0; NEWTON_WORKGROUP];
    let mut moved = false;
    for (f, &k) in free.iter().enumerate() {
        let du = inverse_times(inverse, &row, f, &rhs);
        u[dof_start + k as usize] += du;
        sum2[f % NEWTON_WORKGROUP] += du * du;
        moved |= du != 0.0;
    }
    let s = &mut state[m];
    s.increment = reduce_sum(sum2).sqrt();
    s.iterations += 1;
    s.moved |= moved as u32;
}

/// `newton_judge` for member `m` after an evaluation: the test of `Body::converged` (the
/// residual `g - f_c`), and whether the member goes on iterating, converged, needs the host or
/// failed.
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
    contact: &[Real],
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
        let (g, du) = (dof_out[d].g - contact[d], u[d] - u_start[d]);
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
    let allowed = row.increment_tolerance * moved.max(row.increment_floor.max(coefficients.motion)) + row.round_off * size;
    let contraction = residual / s.residual.max(Real::MIN_POSITIVE);
    s.balanced = (residual <= tolerance) as u32;
    if residual <= tolerance && s.increment <= allowed {
        s.status = NEWTON_CONVERGED;
    } else if !residual.is_finite() || s.iterations >= row.budget || contraction > REFACTOR_CONTRACTION {
        s.status = NEWTON_HOST;
    }
    s.previous_residual = s.residual;
    s.residual = residual;
}

/// `newton_finish`: each listed member's strain energy, the sum of its elements' energies in
/// element order, and its internal forces packed per dof.
pub fn newton_finish(energy: &[Real], dof_out: &[DofOut<Real>], members: &[MemberRange], call: &[Active], member_energy: &mut [Real], forces: &mut [Real]) {
    for job in call {
        let m = job.member as usize;
        let range = members[m];
        let mut total = 0.0;
        for e in range.element_start..range.element_start + range.elements {
            total += energy[e as usize];
        }
        member_energy[m] = total;
        for d in range.dof_start..range.dof_start + range.dofs {
            forces[d as usize] = dof_out[d as usize].f_int;
        }
    }
}

/// What `newton_summary` reads: the step's motion and coefficients, the committed states (the
/// step's start) and their strain energies, the step inputs (masses), the reference position of
/// every dof, the iterate and its forces, the Newton states and the strain energies there.
pub struct SummaryInputs<'a> {
    pub motion: StepMotion<Real>,
    pub coefficients: Coefficients<Real>,
    pub committed: &'a [DofState<Real>],
    pub step: &'a [DofStep<Real>],
    pub reference: &'a [Real],
    pub u: &'a [Real],
    pub dof_out: &'a [DofOut<Real>],
    pub state: &'a [NewtonState<Real>],
    pub member_energy: &'a [Real],
    pub committed_energy: &'a [Real],
}

/// The largest f32 not above `x` (`f32_below` of `newton_summary.wgsl`).
pub fn f32_below(x: Real) -> f32 {
    let y = x as f32;
    if Real::from(y) <= x {
        y
    } else if y > 0.0 {
        f32::from_bits(y.to_bits() - 1)
    } else if y < 0.0 {
        f32::from_bits(y.to_bits() + 1)
    } else {
        -f32::MIN_POSITIVE
    }
}

/// The smallest f32 not below `x`.
pub fn f32_above(x: Real) -> f32 {
    -f32_below(-x)
}

/// `newton_summary`: per listed member (the kept members of a call), at `m * summary_len(dim)`
/// of `summary` what the host reads at the end of its step ([`crate::gpu::types::summary_len`]
/// says the layout), at `m * 2 dim` of `boxes` the box of its nodes in f32, rounded outward,
/// and at `m * TALLY_ROW` of `rows` what `newton_tally` sums ([`TALLY_ROW`]).
pub fn newton_summary(inputs: &SummaryInputs, members: &[MemberRange], call: &[Active], (summary, boxes, rows): (&mut [Real], &mut [f32], &mut [Real])) {
    let SummaryInputs { motion, coefficients, committed, step, reference, u, dof_out, state, member_energy, committed_energy } = *inputs;
    let dim = (motion.dim as usize).clamp(2, 3);
    let xi = coefficients.factor;
    for job in call {
        let m = job.member as usize;
        let range = members[m];
        let (mut kinetic, mut theta_term, mut force_work, mut speed2) = (0.0, 0.0, 0.0, 0.0);
        let (mut mx, mut p, mut l, mut lo, mut hi) = ([0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3]);
        for n in 0..range.dofs as usize / dim {
            let first = range.dof_start as usize + n * dim;
            let node_mass = step[first].mass;
            let (mut x, mut v, mut s2) = ([0.0; 3], [0.0; 3], 0.0);
            for i in 0..dim {
                let d = first + i;
                let c = committed[d];
                let mass = step[d].mass;
                let vi = (u[d] - c.u - motion.dt_explicit * c.v) / motion.theta_dt;
                kinetic += mass * vi * vi;
                theta_term += mass * (vi - c.v) * (vi - c.v);
                force_work += (u[d] - c.u) * ((1.0 - xi) * c.f_int + xi * dof_out[d].f_int);
                s2 += vi * vi;
                x[i] = reference[d] + u[d];
                v[i] = vi;
                mx[i] += mass * x[i];
                p[i] += mass * vi;
                if n == 0 || x[i] < lo[i] {
                    lo[i] = x[i];
                }
                if n == 0 || x[i] > hi[i] {
                    hi[i] = x[i];
                }
            }
            speed2 = Real::max(speed2, s2);
            let cross = [x[1] * v[2] - x[2] * v[1], x[2] * v[0] - x[0] * v[2], x[0] * v[1] - x[1] * v[0]];
            for i in 0..3 {
                l[i] += node_mass * cross[i];
            }
        }
        let head = m * summary_len(dim);
        summary[head] = Real::from(state[m].status + 4 * state[m].iterations);
        summary[head + 1] = 0.5 * kinetic;
        for i in 0..dim {
            summary[head + 2 + i] = mx[i];
            summary[head + 2 + dim + i] = p[i];
            boxes[m * 2 * dim + i] = f32_below(lo[i]);
            boxes[m * 2 * dim + dim + i] = f32_above(hi[i]);
        }
        if dim == 2 {
            summary[head + 2 + 2 * dim] = l[2];
        } else {
            summary[head + 2 + 2 * dim..head + 2 + 2 * dim + 3].copy_from_slice(&l);
        }
        let strain = member_energy[m];
        let row = &mut rows[m * TALLY_ROW..(m + 1) * TALLY_ROW];
        row.copy_from_slice(&[state[m].residual, strain, theta_term, force_work - (strain - committed_energy[m]), speed2]);
    }
}

/// `newton_tally`: over the members `call` lists (a call's kept members) that converged, what
/// the host books of them ([`TALLY_LEN`] reals: [`crate::gpu::types::StepTally::of`]), from
/// their rows of `newton_summary`, each lane's share summed as the shader's invocation sums it.
pub fn newton_tally(call: &[Active], state: &[NewtonState<Real>], rows: &[Real]) -> [Real; TALLY_LEN] {
    let (mut sums, mut speed2, mut residual) = ([[0.0; NEWTON_WORKGROUP]; 4], [0.0 as Real; NEWTON_WORKGROUP], [0.0 as Real; NEWTON_WORKGROUP]);
    for (k, job) in call.iter().enumerate() {
        let m = job.member as usize;
        if state[m].status != NEWTON_CONVERGED {
            continue;
        }
        let (lane, row) = (k % NEWTON_WORKGROUP, &rows[m * TALLY_ROW..(m + 1) * TALLY_ROW]);
        for (sum, value) in sums.iter_mut().zip([1.0, row[2], row[3], row[1]]) {
            sum[lane] += value;
        }
        speed2[lane] = speed2[lane].max(row[4]);
        residual[lane] = residual[lane].max(row[0]);
    }
    let [members, theta, force, strain] = sums.map(reduce_sum);
    [members, theta, force, strain, reduce_max(speed2), reduce_max(residual)]
}

/// `newton_compact`: the members of the call's list still iterating, in its order, into `jobs`;
/// returns their count (the dispatches' z). `left`: the count the last compaction returned
/// (the call's length before the first); none left, nothing changes.
pub fn newton_compact(call: &[Active], state: &[NewtonState<Real>], jobs: &mut [Active], left: usize) -> usize {
    if left == 0 {
        return 0;
    }
    compact(call, state, jobs, NEWTON_ITERATING)
}

/// `newton_compact`'s `host`: the members of the list the device hands back to the host, in
/// its order, into `jobs` (the list of the tangent passes that follow); returns their count.
pub fn newton_compact_host(call: &[Active], state: &[NewtonState<Real>], jobs: &mut [Active]) -> usize {
    compact(call, state, jobs, NEWTON_HOST)
}

/// `newton_compact`'s `refactor`: the members of the list that refactorise within the call, in
/// its order, into `jobs` (the list of the tangent passes and `newton_invert`'s `refactor`);
/// returns their count.
pub fn newton_compact_refactor(call: &[Active], state: &[NewtonState<Real>], jobs: &mut [Active]) -> usize {
    compact(call, state, jobs, NEWTON_REFACTOR)
}

/// The members of `call` whose status is `wanted`, in order, into `jobs`; returns their count.
fn compact(call: &[Active], state: &[NewtonState<Real>], jobs: &mut [Active], wanted: u32) -> usize {
    let mut at = 0;
    for c in call.iter().filter(|c| state[c.member as usize].status == wanted) {
        jobs[at] = *c;
        at += 1;
    }
    at
}

/// Whether group `k` of a device call is still iterating (`iterating` of `newton_contact.wgsl`).
fn group_iterating(state: &[NewtonState<Real>], c: &ContactLayout, k: usize) -> bool {
    state[c.group_members[c.groups[k].member_start as usize] as usize].status == NEWTON_ITERATING
}

/// `newton_contact`'s `prepare` for group `k`: `x0 = K̄⁻¹(-g)` of every member, each point's free
/// velocity into `locals`, and its Uzawa state back to the first sweep.
#[allow(clippy::too_many_arguments)]
pub fn newton_contact_prepare(
    inverse: &[Real],
    free_dofs: &[u32],
    newton: &[NewtonMember<Real>],
    state: &[NewtonState<Real>],
    dof_out: &[DofOut<Real>],
    u: &[Real],
    members: &[MemberRange],
    x0: &mut [Real],
    u_base: &[Real],
    c: &ContactLayout,
    problems: &[UzawaProblem<Real>],
    nodes: &NodeGather,
    locals: &mut [UzawaLocal<Real>],
    uzawa_states: &mut [UzawaJudgeState<Real>],
    k: usize,
) {
    if !group_iterating(state, c, k) {
        return;
    }
    let grp = c.groups[k];
    for a in 0..grp.member_count as usize {
        let m = c.group_members[grp.member_start as usize + a] as usize;
        let row = newton[m];
        let n = row.free_count as usize;
        let dof_start = members[m].dof_start as usize;
        let free = &free_dofs[row.free_start as usize..][..n];
        let rhs: Vec<Real> = free.iter().map(|&j| -dof_out[dof_start + j as usize].g).collect();
        for (f, &j) in free.iter().enumerate() {
            x0[dof_start + j as usize] = inverse_times(inverse, &row, f, &rhs);
        }
    }
    let p = problems[k];
    for (i, local) in locals.iter_mut().enumerate().take(p.point_end as usize).skip(p.point_start as usize) {
        local.v_free = point_velocity(c, &nodes.frames, u, u_base, Some(x0), i);
        local.settle = SETTLE * p.tolerance;
    }
    uzawa_states[k] = UzawaJudgeState { status: JUDGE_LIVE, previous: -1.0, ..Default::default() };
}

/// `newton_contact`'s `forces` for group `k` (`problems` and `nodes` as the Uzawa kernels hold
/// them): the reactions `r` as contact forces per dof, their relative change and the solve's sweeps and outcome into `contact_states`.
#[allow(clippy::too_many_arguments)]
pub fn newton_contact_forces(
    state: &[NewtonState<Real>],
    contact: &mut [Real],
    c: &ContactLayout,
    problems: &[UzawaProblem<Real>],
    nodes: &NodeGather,
    uzawa_states: &[UzawaJudgeState<Real>],
    r: &[Real],
    contact_states: &mut [crate::gpu::types::ContactState<Real>],
    k: usize,
) {
    if !group_iterating(state, c, k) {
        return;
    }
    let p = problems[k];
    let (mut change, mut size): (Real, Real) = (0.0, 0.0);
    for n in p.node_start as usize..p.node_end as usize {
        let f = node_force(nodes, r, n);
        let d0 = c.node_dof[n] as usize;
        for (comp, &fc) in f.iter().enumerate().take(c.call.dim as usize) {
            change = change.max((fc - contact[d0 + comp]).abs());
            size = size.max(fc.abs());
            contact[d0 + comp] = fc;
        }
    }
    let s = &mut contact_states[k];
    let solved = uzawa_states[k];
    s.sweeps += solved.iterations;
    s.uzawa = solved.status;
    s.stalls = if solved.status == JUDGE_CONVERGED { 0 } else { s.stalls + 1 };
    s.change = change / size.max(p.floor).max(Real::MIN_POSITIVE);
}

/// `newton_contact`'s `delassus` for group `k`: the blocks of W its problem's rows list
/// (`row_start`, `row_entries`: `(column point, block)`), from the members' `K̄⁻¹` (at each
/// batch dof's free index, `free_of`), the terms and frames of the points and each column
/// point's friction in `locals`; then each point's
/// step length (into `locals` and `step_lengths`) and the problem's floor (into `locals` and
/// `problems`), in the shader's order of every sum.
#[allow(clippy::too_many_arguments)]
pub fn newton_contact_delassus(
    inverse: &[Real],
    (newton, free_of): (&[NewtonMember<Real>], &[u32]),
    c: &ContactLayout,
    problems: &mut [UzawaProblem<Real>],
    frames: &[Real],
    locals: &mut [UzawaLocal<Real>],
    (row_start, row_entries): (&[u32], &[[u32; 2]]),
    (blocks, step_lengths): (&mut [Real], &mut [Real]),
    k: usize,
) {
    let p = problems[k];
    let grp = c.groups[k];
    let dim = c.call.dim as usize;
    let mut largest: Real = 0.0;
    for i in p.point_start as usize..p.point_end as usize {
        let mut sum = 0.0;
        for &[j, b] in &row_entries[row_start[i] as usize..row_start[i + 1] as usize] {
            let j = j as usize;
            let mut w = [0.0; 9];
            for s in c.term_start[i] as usize..c.term_start[i + 1] as usize {
                let m = c.node_member[c.term_slots[s] as usize] as usize;
                let start = newton[m].inverse_start as usize;
                for t in c.term_start[j] as usize..c.term_start[j + 1] as usize {
                    if c.node_member[c.term_slots[t] as usize] as usize != m {
                        continue;
                    }
                    let coef = c.term_coefs[s] * c.term_coefs[t];
                    for q in 0..dim {
                        let fs = free_of[c.node_dof[c.term_slots[s] as usize] as usize + q];
                        if fs == NOT_FREE {
                            continue;
                        }
                        for x in 0..dim {
                            let ft = free_of[c.node_dof[c.term_slots[t] as usize] as usize + x];
                            if ft == NOT_FREE {
                                continue;
                            }
                            let kinv = coef * inverse[start + packed(fs as usize, ft as usize)];
                            for cc in 0..dim {
                                for a in 0..dim {
                                    w[3 * cc + a] += frames[9 * i + 3 * cc + q] * kinv * frames[9 * j + 3 * a + x];
                                }
                            }
                        }
                    }
                }
            }
            let columns = if locals[j].mu == 0.0 { 1 } else { dim };
            let mut norm: Real = 0.0;
            for (cc, out) in blocks[9 * b as usize..][..9].chunks_exact_mut(3).enumerate() {
                let mut row = 0.0;
                for (a, out) in out.iter_mut().enumerate() {
                    *out = if a < columns { w[3 * cc + a] / c.call.theta_dt } else { 0.0 };
                    row += out.abs();
                }
                norm = norm.max(row);
            }
            if grp.jacobi == 1 || j == i {
                sum += norm;
            }
        }
        let rho = if sum > 0.0 { 1.0 / sum } else { 0.0 };
        locals[i].rho = rho;
        step_lengths[i] = rho;
        largest = largest.max(rho);
    }
    let floor = grp.velocity_scale * largest;
    for local in &mut locals[p.point_start as usize..p.point_end as usize] {
        local.floor = floor;
    }
    problems[k].floor = floor;
}

/// `point_velocity` of `newton_contact.wgsl`: point `i`'s relative velocity at the end of the
/// step in its contact frame, with the contact-free increments `x0` when given.
fn point_velocity(c: &ContactLayout, frames: &[Real], u: &[Real], u_base: &[Real], x0: Option<&[Real]>, i: usize) -> [Real; 3] {
    let tdt = c.call.theta_dt;
    let mut g = [-c.obstacle[3 * i], -c.obstacle[3 * i + 1], -c.obstacle[3 * i + 2]];
    for e in c.term_start[i] as usize..c.term_start[i + 1] as usize {
        let d0 = c.node_dof[c.term_slots[e] as usize] as usize;
        let coef = c.term_coefs[e];
        for (comp, g) in g.iter_mut().enumerate().take(c.call.dim as usize) {
            let d = d0 + comp;
            let mut v = (u[d] - u_base[d]) / tdt;
            if let Some(x0) = x0 {
                v += x0[d] / tdt;
            }
            *g += coef * v;
        }
    }
    let f = &frames[9 * i..9 * i + 9];
    [0, 1, 2].map(|a| f[3 * a] * g[0] + f[3 * a + 1] * g[1] + f[3 * a + 2] * g[2])
}

/// `node_force` of `newton_contact.wgsl`: the contact force on node slot `n`, its points'
/// reactions in global coordinates times their coefficients, in point order.
fn node_force(nodes: &NodeGather, r: &[Real], n: usize) -> [Real; 3] {
    let mut f = [0.0; 3];
    for e in nodes.start[n] as usize..nodes.start[n + 1] as usize {
        let i = nodes.points[e] as usize;
        let global = global(&nodes.frames, i, triple(r, i));
        for a in 0..3 {
            f[a] += nodes.coefs[e] * global[a];
        }
    }
    f
}

/// `newton_contact`'s `first_forces` for group `k`: the contact forces of the reactions `r` the
/// step starts from, per dof, before the test of a first evaluation.
pub fn newton_contact_first_forces(state: &[NewtonState<Real>], contact: &mut [Real], c: &ContactLayout, problems: &[UzawaProblem<Real>], nodes: &NodeGather, r: &[Real], k: usize) {
    if !group_iterating(state, c, k) {
        return;
    }
    let p = problems[k];
    for n in p.node_start as usize..p.node_end as usize {
        let f = node_force(nodes, r, n);
        let d0 = c.node_dof[n] as usize;
        for (comp, &fc) in f.iter().enumerate().take(c.call.dim as usize) {
            contact[d0 + comp] = fc;
        }
    }
}

/// `newton_contact`'s `first_judge` for group `k`, after `newton_judge` of a first evaluation:
/// converged when every member passed, every point is warm and the law holds at the trial
/// velocities (`ContactStep::complementarity`), the host's when a member needs it or failed,
/// else every member iterates; each point's Uzawa step from `r` is left in its `v_free`.
#[allow(clippy::too_many_arguments)]
pub fn newton_contact_first_judge(state: &mut [NewtonState<Real>], u: &[Real], u_base: &[Real], c: &ContactLayout, problems: &[UzawaProblem<Real>], nodes: &NodeGather, locals: &mut [UzawaLocal<Real>], r: &[Real], k: usize) {
    if k >= c.groups.len() {
        return;
    }
    let p = problems[k];
    let mut cold = false;
    for (i, local) in locals.iter_mut().enumerate().take(p.point_end as usize).skip(p.point_start as usize) {
        let ri = triple(r, i);
        let mut step = [0.0; 3];
        if local.rho == 0.0 {
            cold = true;
        } else {
            let mut v = point_velocity(c, &nodes.frames, u, u_base, None, i);
            v[0] += local.shift;
            let (next, _) = crate::contact::law::uzawa_step(ri, v, local.mu, local.rho);
            step = [0, 1, 2].map(|a| next[a] - ri[a]);
        }
        local.v_free = step;
    }
    let norm = |x: [Real; 3]| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    let (mut worst, mut size): (Real, Real) = (0.0, 0.0);
    for n in p.node_start as usize..p.node_end as usize {
        let mut d = [0.0; 3];
        for e in nodes.start[n] as usize..nodes.start[n + 1] as usize {
            let i = nodes.points[e] as usize;
            let step = global(&nodes.frames, i, locals[i].v_free);
            for comp in 0..3 {
                d[comp] += nodes.coefs[e] * step[comp];
            }
        }
        worst = worst.max(norm(d));
        size = size.max(norm(node_force(nodes, r, n)));
    }
    let complementarity = worst / size.max(p.floor).max(Real::MIN_POSITIVE);
    let grp = c.groups[k];
    let list = &c.group_members[grp.member_start as usize..][..grp.member_count as usize];
    let all_converged = list.iter().all(|&m| state[m as usize].status == NEWTON_CONVERGED);
    let to_host = list.iter().any(|&m| matches!(state[m as usize].status, NEWTON_HOST | NEWTON_FAILED));
    let verdict = if to_host {
        NEWTON_HOST
    } else if all_converged && !cold && complementarity <= grp.tolerance {
        NEWTON_CONVERGED
    } else {
        NEWTON_ITERATING
    };
    for &m in list {
        if state[m as usize].status != NEWTON_FAILED {
            state[m as usize].status = verdict;
        }
    }
}

/// `newton_contact`'s `judge` for group `k`: one verdict for all its members, its problem
/// solved tighter when only the increments are left, and where the group may, its members whose
/// residual contracted too slowly refactorising within the call.
pub fn newton_contact_judge(newton: &[NewtonMember<Real>], state: &mut [NewtonState<Real>], c: &ContactLayout, problems: &mut [UzawaProblem<Real>], contact_states: &mut [crate::gpu::types::ContactState<Real>], k: usize) {
    let grp = c.groups[k];
    let list = &c.group_members[grp.member_start as usize..][..grp.member_count as usize];
    let lead = list[0] as usize;
    let contracts_slowly = |s: &NewtonState<Real>| s.residual > REFACTOR_CONTRACTION * s.previous_residual.max(Real::MIN_POSITIVE);
    let (mut all_converged, mut all_balanced, mut to_host, mut slow) = (true, true, false, false);
    for &m in list {
        let s = state[m as usize];
        all_converged &= s.status == NEWTON_CONVERGED;
        all_balanced &= s.balanced == 1;
        let lost = s.status == NEWTON_HOST && (grp.refactor == 0 || !s.residual.is_finite());
        to_host |= lost || s.status == NEWTON_FAILED;
        slow |= contracts_slowly(&s);
    }
    let cs = contact_states[k];
    let settled = cs.change <= grp.tolerance && cs.uzawa == JUDGE_CONVERGED;
    let iterations = state[lead].iterations;
    let verdict = if to_host {
        NEWTON_HOST
    } else if all_converged && settled {
        NEWTON_CONVERGED
    } else if cs.uzawa == JUDGE_LIVE || cs.stalls as usize >= UZAWA_STALLS || iterations >= newton[lead].budget || (slow && grp.refactor == 0) {
        NEWTON_HOST
    } else {
        if iterations as usize >= TIGHTEN_AFTER && settled && all_balanced {
            let p = &mut problems[k];
            p.tolerance = (0.1 * p.tolerance).max(TIGHTEST_INNER * grp.tolerance);
            contact_states[k].tightened += 1;
        }
        NEWTON_ITERATING
    };
    for &m in list {
        let s = &mut state[m as usize];
        if s.status != NEWTON_FAILED {
            s.status = if verdict == NEWTON_ITERATING && contracts_slowly(s) { NEWTON_REFACTOR } else { verdict };
        }
    }
}

/// `newton_contact`'s `rebuild` for group `k`: where a member refactorised within the call, W,
/// the step lengths and the floor again ([`newton_contact_delassus`]), and those members
/// iterating again; returns whether it built W.
#[allow(clippy::too_many_arguments)]
pub fn newton_contact_rebuild(
    inverse: &[Real],
    (newton, free_of): (&[NewtonMember<Real>], &[u32]),
    state: &mut [NewtonState<Real>],
    c: &ContactLayout,
    problems: &mut [UzawaProblem<Real>],
    frames: &[Real],
    locals: &mut [UzawaLocal<Real>],
    rows: (&[u32], &[[u32; 2]]),
    out: (&mut [Real], &mut [Real]),
    k: usize,
) -> bool {
    let grp = c.groups[k];
    let list = &c.group_members[grp.member_start as usize..][..grp.member_count as usize];
    if !list.iter().any(|&m| state[m as usize].status == NEWTON_REFACTOR) {
        return false;
    }
    newton_contact_delassus(inverse, (newton, free_of), c, problems, frames, locals, rows, out, k);
    for &m in list {
        if state[m as usize].status == NEWTON_REFACTOR {
            state[m as usize].status = NEWTON_ITERATING;
        }
    }
    true
}
