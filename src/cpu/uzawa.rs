//! The CPU twins of `shaders/uzawa_judge.wgsl` and `shaders/uzawa_solve.wgsl` (with their
//! includes `uzawa.wgsl` and `uzawa_nodal.wgsl`): the stopping rule of the device's Uzawa
//! iterations, and a problem's whole iterations in one workgroup, written as the shaders spread
//! them over a workgroup; and of `shaders/planar_unpack.wgsl`, the blocks those read. The
//! engine's CPU sweeps judge with [`crate::contact::uzawa::Judge`] on
//! [`crate::contact::uzawa::NodalMap::change`], the same rule; these are the oracle of the
//! parity tests.

use crate::contact::geometry::norm;
use crate::contact::uzawa::{gauss_seidel_point, Problem, SETTLE};
use crate::gpu::uzawa_sweep::{NodeGather, UzawaJudgeState, UzawaProblem, JUDGE_CONVERGED, JUDGE_LIVE, JUDGE_SPENT, JUDGE_WORKGROUP};
use crate::precision::Real;

/// `planar_unpack`: the first `blocks.len() / 9` blocks, 3 x 3 row-major, from their planar
/// upper-left 2 x 2 in `planar` (4 reals each), the third row and column zeros.
pub fn planar_unpack(planar: &[Real], blocks: &mut [Real]) {
    for (w, p) in blocks.chunks_exact_mut(9).zip(planar.chunks_exact(4)) {
        let zero = 0.0;
        w.copy_from_slice(&[p[0], p[1], zero, p[2], p[3], zero, zero, zero, zero]);
    }
}

/// `x` (in the contact frame of point `i`) in global coordinates.
pub(super) fn global(frames: &[Real], i: usize, x: [Real; 3]) -> [Real; 3] {
    let f = 9 * i;
    [0, 1, 2].map(|c| x[0] * frames[f + c] + x[1] * frames[f + 3 + c] + x[2] * frames[f + 6 + c])
}

/// Point `i`'s three reals of a flat array of them.
pub(super) fn triple(a: &[Real], i: usize) -> [Real; 3] {
    [a[3 * i], a[3 * i + 1], a[3 * i + 2]]
}

/// `nodal_extremes` of `uzawa_nodal.wgsl`: problem `p`'s largest change of a nodal force and
/// largest nodal force, from the reactions `r` and their changes `dr`.
fn nodal_extremes(p: &UzawaProblem<Real>, nodes: &NodeGather, r: &[Real], dr: &[Real]) -> (Real, Real) {
    let mut partial: [[Real; 2]; JUDGE_WORKGROUP] = [[0.0; 2]; JUDGE_WORKGROUP];
    for (lane, most) in partial.iter_mut().enumerate() {
        let mut n = p.node_start as usize + lane;
        while n < p.node_end as usize {
            let (mut d, mut a) = ([0.0; 3], [0.0; 3]);
            for e in nodes.start[n] as usize..nodes.start[n + 1] as usize {
                let (i, coef) = (nodes.points[e] as usize, nodes.coefs[e]);
                let (gd, ga) = (global(&nodes.frames, i, triple(dr, i)), global(&nodes.frames, i, triple(r, i)));
                for c in 0..3 {
                    d[c] += coef * gd[c];
                    a[c] += coef * ga[c];
                }
            }
            *most = [most[0].max(norm(d)), most[1].max(norm(a))];
            n += JUDGE_WORKGROUP;
        }
    }
    partial.iter().fold((0.0, 0.0), |(c, s), m| (c.max(m[0]), s.max(m[1])))
}

/// `judged` of `uzawa.wgsl`: the state after a sweep whose largest change of a nodal force is
/// `change` and largest nodal force `size` (the rule of
/// [`crate::contact::uzawa::Judge::after`]).
fn judged(p: &UzawaProblem<Real>, state: UzawaJudgeState<Real>, change: Real, size: Real) -> UzawaJudgeState<Real> {
    let mut s = state;
    s.iterations += 1;
    let scale = size.max(p.floor).max(Real::MIN_POSITIVE);
    // Before the first sweep the ratio is 0, as the CPU's change over an infinite one.
    let q = if s.previous >= 0.0 { change / s.previous } else { 0.0 };
    s.previous = change;
    let error = if q < 1.0 { change * q / (1.0 - q) } else { Real::MAX };
    // Far below the tolerance the ratio is round-off; a change that small is converged.
    let converged = change <= 1e-3 * p.tolerance * scale || (change <= p.tolerance * scale && error <= p.tolerance * scale);
    s.change = change / scale;
    if converged {
        s.status = JUDGE_CONVERGED;
    } else if s.iterations >= p.max_iterations {
        s.status = JUDGE_SPENT;
    }
    s
}

/// `uzawa_judge` for problem `k` (one workgroup), after a sweep that left the reactions `r`
/// and their changes `dr`: its new state; a problem that stops clears its points' `live`
/// flags. Nothing unless it is live.
pub fn uzawa_judge(problems: &[UzawaProblem<Real>], states: &mut [UzawaJudgeState<Real>], nodes: &NodeGather, r: &[Real], dr: &[Real], live: &mut [u32], k: usize) {
    if states[k].status != JUDGE_LIVE {
        return;
    }
    let p = &problems[k];
    let (change, size) = nodal_extremes(p, nodes, r, dr);
    states[k] = judged(p, states[k], change, size);
    if states[k].status != JUDGE_LIVE {
        live[p.point_start as usize..p.point_end as usize].iter_mut().for_each(|l| *l = 0);
    }
}

/// `uzawa_solve` for problem `k` (one workgroup), whose W, colours and points are `problem`'s:
/// up to `sweeps` Gauss-Seidel sweeps, colour by colour, each judged, until it stops. `r` and
/// `dr` hold every problem's points (3 reals each), this one's from `point_start`. Nothing
/// unless it is live.
#[allow(clippy::too_many_arguments)]
pub fn uzawa_solve(problem: &Problem, problems: &[UzawaProblem<Real>], states: &mut [UzawaJudgeState<Real>], nodes: &NodeGather, r: &mut [Real], dr: &mut [Real], sweeps: u32, k: usize) {
    if states[k].status != JUDGE_LIVE {
        return;
    }
    let p = &problems[k];
    let (settle, range) = (SETTLE * p.tolerance, 3 * p.point_start as usize..3 * p.point_end as usize);
    for _ in 0..sweeps {
        for c in 0..problem.colours.count() {
            for &i in problem.colours.colour(c) {
                let i = i as usize;
                let own: &mut [[Real; 3]] = bytemuck::cast_slice_mut(&mut r[range.clone()]);
                let (before, after) = (own[i], gauss_seidel_point(problem.w, &problem.local[i], i, own, settle, p.floor));
                own[i] = after;
                let changes: &mut [[Real; 3]] = bytemuck::cast_slice_mut(&mut dr[range.clone()]);
                changes[i] = [0, 1, 2].map(|a| after[a] - before[a]);
            }
        }
        let (change, size) = nodal_extremes(p, nodes, r, dr);
        states[k] = judged(p, states[k], change, size);
        if states[k].status != JUDGE_LIVE {
            break;
        }
    }
}
