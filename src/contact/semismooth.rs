//! A semi-smooth Newton solve of a contact problem, for the problems whose Gauss-Seidel sweeps
//! stall (jammed packings: strongly coupled points, the sweeps contracting at 0.9999).
//!
//! It solves the same law as the sweeps, de Saxcé's natural map at every point,
//! `F_i(r) = r_i - P_K(r_i - ρ_i ṽ_i)` with `v = v_free + shift n + W r` and
//! `ṽ = v + μ |v_t| n` (the fixed point of the Uzawa step is `F = 0`), by Newton's method on the
//! whole problem at once: `J Δr = -F` with a generalised Jacobian
//! `J_ij = δ_ij (I - D_i) + ρ_i D_i M_i W_ij`, where `D_i` is the Jacobian of the projection on
//! the cone at `τ_i` and `M_i = ∂ṽ/∂v`. `J` has the block pattern of `W`; it is factorised by
//! faer's sparse LU (the symbolic analysis once per solve), damped as Levenberg and Marquardt
//! do (`(J + λ I) Δ = -F`, λ raised until `|F|²` decreases); a solve that finds no descent, or
//! whose `|F|²` stalls on a plateau, gives up, and the caller goes on with its sweeps from the
//! last iterate (method.md, section 3; Acary, Brémond and Huber's comparison ranks this family
//! first in speed on the hard problems and Gauss-Seidel first in robustness, hence the pair).
//!
//! The solution is judged as the sweeps' is, on nodal forces ([`NodalMap`]): the natural-map
//! residual, the complementarity test of `solver::coupling`, and the last Newton step, each at
//! most `tolerance * max(largest nodal force, floor)`.

use super::law::{ContactLaw, Law};
use super::uzawa::{Delassus, Local, NodalMap};
use crate::precision::Real;
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Lu, SymbolicLu};
use faer::sparse::{Argsort, Pair, SparseColMat, SymbolicSparseColMat};
use std::sync::atomic::{AtomicBool, Ordering};

/// Newton iterations a solve may take.
pub const MAX_ITERATIONS: usize = 50;

/// A step is taken when it decreases `|F|²` by at least this share.
const ARMIJO: Real = 1e-4;

/// The smallest and largest damping `λ` of a step (relative to the unit diagonal of `J`).
const MIN_DAMPING: Real = 1e-10;
const MAX_DAMPING: Real = 1e2;

/// Steps in a row that each leave more than `SLOW` of `|F|²` end a solve.
const SLOW: Real = 0.5;
const SLOW_STEPS: usize = 6;

/// How a semi-smooth solve ended.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NewtonOutcome {
    pub iterations: usize,
    pub converged: bool,
    /// The natural-map residual at the end, in nodal forces, relative to their scale.
    pub residual: Real,
    /// Whether it stopped on a plateau of `|F|²` (see [`SLOW`]): a problem without a solution.
    pub plateau: bool,
}

/// The natural map at every point and, when `jacobian` is given, each point's `D_i` and
/// `D_i M_i` (row-major `3 x 3`, in the first `dim` rows and columns).
pub fn natural_map(w: &Delassus, local: &[Local], r: &[[Real; 3]], dim: usize, mut jacobian: Option<&mut Vec<([Real; 9], [Real; 9])>>) -> Vec<[Real; 3]> {
    if let Some(j) = jacobian.as_deref_mut() {
        j.clear();
    }
    (0..local.len())
        .map(|i| {
            let l = &local[i];
            let wr = w.row_times(i, r);
            let v = [l.v_free[0] + wr[0] + l.shift, l.v_free[1] + wr[1], l.v_free[2] + wr[2]];
            let tau = Law::predictor(r[i], v, l.mu, l.rho);
            let projected = Law::project(tau, l.mu).0;
            if let Some(j) = jacobian.as_deref_mut() {
                let d = Law::projection_jacobian(tau, l.mu, dim);
                j.push((d, times(&d, &Law::predictor_velocity_jacobian(v, l.mu))));
            }
            let mut f = [r[i][0] - projected[0], r[i][1] - projected[1], r[i][2] - projected[2]];
            f[dim..].iter_mut().for_each(|x| *x = 0.0);
            f
        })
        .collect()
}

/// `a b` of row-major `3 x 3` matrices.
fn times(a: &[Real; 9], b: &[Real; 9]) -> [Real; 9] {
    let mut out = [0.0; 9];
    for i in 0..3 {
        for k in 0..3 {
            out[3 * i + k] = (0..3).map(|j| a[3 * i + j] * b[3 * j + k]).sum();
        }
    }
    out
}

/// Every entry of `J + shift I` of [`natural_map`] at the point it was evaluated (`jacobian`
/// its per-point matrices), over the unknowns `dim i + a`, as `emit(row, column, value)`:
/// always the same entries in the same order, zero or not (the diagonal blocks, then each block
/// of `W`; repeated positions are summed), so that one pattern serves a whole solve.
fn jacobian_entries(w: &Delassus, local: &[Local], jacobian: &[([Real; 9], [Real; 9])], dim: usize, shift: Real, mut emit: impl FnMut(usize, usize, Real)) {
    for (i, row) in w.rows.iter().enumerate() {
        let (d, dm) = &jacobian[i];
        for a in 0..dim {
            for b in 0..dim {
                let identity = if a == b { 1.0 } else { 0.0 };
                emit(dim * i + a, dim * i + b, identity - d[3 * a + b] + shift * identity);
            }
        }
        for &(j, block) in row {
            let dmw = times(dm, &w.blocks[block as usize]);
            for a in 0..dim {
                for b in 0..dim {
                    emit(dim * i + a, dim * j as usize + b, local[i].rho * dmw[3 * a + b]);
                }
            }
        }
    }
}

/// The pattern of `J` in the order of [`jacobian_entries`], and its symbolic LU: made by a
/// solve's first step and kept for the others.
struct Pattern {
    symbolic: SymbolicSparseColMat<usize>,
    argsort: Argsort<usize>,
    lu: SymbolicLu<usize>,
}

impl Pattern {
    fn of(w: &Delassus, local: &[Local], jacobian: &[([Real; 9], [Real; 9])], dim: usize) -> Option<Self> {
        let n = local.len() * dim;
        let mut positions = Vec::with_capacity((w.blocks.len() + local.len()) * dim * dim);
        jacobian_entries(w, local, jacobian, dim, 0.0, |row, col, _| positions.push(Pair { row, col }));
        let (symbolic, argsort) = SymbolicSparseColMat::try_new_from_indices(n, n, &positions).ok()?;
        let lu = SymbolicLu::try_new(symbolic.as_ref()).ok()?;
        Some(Self { symbolic, argsort, lu })
    }
}

/// The Newton step `Δ` of `(J + λ I) Δ = -F`, or `None` when it cannot be factorised.
#[allow(clippy::too_many_arguments)]
fn newton_step(w: &Delassus, local: &[Local], jacobian: &[([Real; 9], [Real; 9])], f: &[[Real; 3]], dim: usize, damping: Real, pattern: &mut Option<Pattern>) -> Option<Vec<[Real; 3]>> {
    if pattern.is_none() {
        *pattern = Some(Pattern::of(w, local, jacobian, dim)?);
    }
    let pattern = pattern.as_ref()?;
    let mut values = Vec::new();
    jacobian_entries(w, local, jacobian, dim, damping, |_, _, value| values.push(value));
    let matrix = SparseColMat::<usize, Real>::new_from_argsort(pattern.symbolic.clone(), &pattern.argsort, &values).ok()?;
    let lu = Lu::try_new_with_symbolic(pattern.lu.clone(), matrix.as_ref()).ok()?;
    let n = local.len() * dim;
    let mut rhs = faer::Mat::<Real>::from_fn(n, 1, |k, _| -f[k / dim][k % dim]);
    lu.solve_in_place(rhs.as_mut());
    let step: Vec<[Real; 3]> = (0..local.len()).map(|i| std::array::from_fn(|a| if a < dim { rhs[(dim * i + a, 0)] } else { 0.0 })).collect();
    step.iter().all(|s| s.iter().all(|x| x.is_finite())).then_some(step)
}

/// `|F|²` over the used components.
fn merit(f: &[[Real; 3]]) -> Real {
    f.iter().map(|x| x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sum()
}

/// Semi-smooth Newton iterations from the reactions in `r` until the natural-map residual and
/// the last step are within `tolerance` of the nodal forces' scale (at least `floor`), or no
/// damping finds a descent, or `|F|²` reaches a plateau ([`SLOW`]), or `stop` is set. `r` holds
/// the last accepted iterate either way.
#[allow(clippy::too_many_arguments)]
pub fn semismooth_solve(w: &Delassus, local: &[Local], nodal: &NodalMap, r: &mut [[Real; 3]], dim: usize, tolerance: Real, floor: Real, stop: Option<&AtomicBool>) -> NewtonOutcome {
    let mut jacobian = Vec::with_capacity(local.len());
    let mut scratch = Vec::new();
    let mut f = natural_map(w, local, r, dim, Some(&mut jacobian));
    let judged = |f: &[[Real; 3]], r: &[[Real; 3]], scratch: &mut Vec<[[Real; 3]; 2]>| {
        let (residual, size) = nodal.change(f, r, scratch);
        (residual, size.max(floor).max(Real::MIN_POSITIVE))
    };
    let (residual, scale) = judged(&f, r, &mut scratch);
    let mut outcome = NewtonOutcome { residual: residual / scale, ..NewtonOutcome::default() };
    // Levenberg-Marquardt damping `(J + λ I) Δ = -F`: nearly redundant points (two passes over
    // faces lying on each other, a corner's second point) leave `J` nearly singular, and an
    // undamped step moves their ill-determined split by far more than the forces need, which
    // throws most points out of their regime (|F|² up 1e4-fold from a jammed cluster's swept
    // iterate). λ grows tenfold while a step does not decrease |F|², and falls a hundredfold
    // after one that does.
    let mut damping = MIN_DAMPING;
    let (mut pattern, mut slow) = (None, 0);
    let mut trial_jacobian = Vec::with_capacity(local.len());
    for it in 1..=MAX_ITERATIONS {
        if stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            break;
        }
        let before = merit(&f);
        let mut accepted = None;
        while damping <= MAX_DAMPING {
            if let Some(step) = newton_step(w, local, &jacobian, &f, dim, damping, &mut pattern) {
                let trial: Vec<[Real; 3]> = r.iter().zip(&step).map(|(x, d)| [x[0] + d[0], x[1] + d[1], x[2] + d[2]]).collect();
                // With its Jacobian: an accepted trial is the next iterate, evaluated once.
                let f_trial = natural_map(w, local, &trial, dim, Some(&mut trial_jacobian));
                if merit(&f_trial) <= (1.0 - ARMIJO) * before {
                    accepted = Some((trial, step, f_trial));
                    break;
                }
            }
            damping *= 10.0;
        }
        let Some((trial, moved, f_trial)) = accepted else {
            // No damping finds a descent: round-off at a solution, or a stationary point of
            // |F|² that is not one.
            outcome.converged = outcome.residual <= tolerance;
            outcome.plateau = !outcome.converged;
            break;
        };
        damping = (damping / 100.0).max(MIN_DAMPING);
        r.copy_from_slice(&trial);
        outcome.iterations = it;
        f = f_trial;
        std::mem::swap(&mut jacobian, &mut trial_jacobian);
        let (residual, scale) = judged(&f, r, &mut scratch);
        let (change, _) = nodal.change(&moved, r, &mut scratch);
        outcome.residual = residual / scale;
        if residual <= tolerance * scale && change <= tolerance * scale {
            outcome.converged = true;
            break;
        }
        // A problem without a solution (two points on the same nodes whose normals oppose,
        // each asking the other to give way) lowers |F|² slowly and never to zero; it is left
        // to the sweeps and the step's retries.
        slow = if merit(&f) > SLOW * before { slow + 1 } else { 0 };
        if slow >= SLOW_STEPS {
            outcome.plateau = true;
            break;
        }
    }
    outcome
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A problem of `n` points on one body (every pair coupled), symmetric positive definite `W`
    /// with dominant diagonal blocks, every friction regime, from a fixed generator.
    fn problem(n: usize, dim: usize, seed: u64) -> (Delassus, Vec<Local>, Vec<[Real; 3]>) {
        let mut state = seed;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as Real / (1u64 << 53) as Real) * 2.0 - 1.0
        };
        let m = n * dim;
        let a: Vec<Real> = (0..m * m).map(|_| next()).collect();
        // W = A Aᵀ / m + I.
        let entry = |p: usize, q: usize| (0..m).map(|k| a[p * m + k] * a[q * m + k]).sum::<Real>() / m as Real + if p == q { 1.0 } else { 0.0 };
        let mut w = Delassus { rows: vec![Vec::new(); n], ..Default::default() };
        for i in 0..n {
            for j in 0..n {
                let mut block = [0.0; 9];
                for x in 0..dim {
                    for y in 0..dim {
                        block[3 * x + y] = entry(dim * i + x, dim * j + y);
                    }
                }
                w.rows[i].push((j as u32, w.blocks.len() as u32));
                w.blocks.push(block);
            }
        }
        let local: Vec<Local> = (0..n)
            .map(|i| {
                let mut v_free = [next(), next(), if dim == 3 { next() } else { 0.0 }];
                v_free[0] -= 0.3;
                Local { v_free, shift: 0.0, mu: [0.0, 0.3, 0.8][i % 3], rho: 0.0 }
            })
            .collect();
        let mut local = local;
        for i in 0..n {
            local[i].rho = w.rho(i, dim, super::super::uzawa::Sweep::GaussSeidel);
        }
        let r = (0..n).map(|_| [next().abs(), 0.3 * next(), if dim == 3 { 0.3 * next() } else { 0.0 }]).collect();
        (w, local, r)
    }

    /// `J d` of the entries [`jacobian_entries`] gives (without damping).
    fn jacobian_times(w: &Delassus, local: &[Local], r: &[[Real; 3]], dim: usize, d: &[[Real; 3]]) -> Vec<Real> {
        let mut jacobian = Vec::new();
        natural_map(w, local, r, dim, Some(&mut jacobian));
        let mut out = vec![0.0; local.len() * dim];
        jacobian_entries(w, local, &jacobian, dim, 0.0, |row, col, value| out[row] += value * d[col / dim][col % dim]);
        out
    }

    #[test]
    fn the_semismooth_jacobian_matches_central_differences_of_the_natural_map() {
        for dim in [2, 3] {
            for seed in 1..20 {
                let (w, local, r) = problem(5, dim, seed);
                let (_, _, d) = problem(5, dim, seed + 1000);
                let h = 1e-7;
                let shifted = |s: Real| -> Vec<[Real; 3]> { r.iter().zip(&d).map(|(x, y)| [x[0] + s * y[0], x[1] + s * y[1], x[2] + s * y[2]]).collect() };
                let (fp, fm) = (natural_map(&w, &local, &shifted(h), dim, None), natural_map(&w, &local, &shifted(-h), dim, None));
                let jd = jacobian_times(&w, &local, &r, dim, &d);
                for i in 0..local.len() {
                    for a in 0..dim {
                        let fd = (fp[i][a] - fm[i][a]) / (2.0 * h);
                        assert!((fd - jd[dim * i + a]).abs() <= 1e-5 * (1.0 + fd.abs()), "dim {dim} seed {seed} point {i} component {a}: J d {} against {fd}", jd[dim * i + a]);
                    }
                }
            }
        }
    }
}
