//! The contact problem of one Newton iteration, `v = v_free + W r` with the law of eq. (10) at
//! every point, solved by Uzawa iterations: every point takes its predictor/corrector step
//! from the same iterate (a Jacobi sweep, the same on the CPU and the GPU).
//!
//! `W` (the Delassus operator `H K̄⁻¹ Hᵀ / (θ dt)` in contact frames) is stored by blocks: one
//! `3 x 3` block for each pair of points that share a body.

use super::law::uzawa_step;
use crate::precision::Real;

/// Block-sparse Delassus operator.
#[derive(Debug, Clone, Default)]
pub struct Delassus {
    /// Per point (row), `(column point, block index)`.
    pub rows: Vec<Vec<(u32, u32)>>,
    /// `3 x 3` blocks, row-major, in contact frames.
    pub blocks: Vec<[Real; 9]>,
}

impl Delassus {
    pub fn block_mut(&mut self, index: u32) -> &mut [Real; 9] {
        &mut self.blocks[index as usize]
    }

    /// `W r` for point `i`.
    pub fn row_times(&self, i: usize, r: &[[Real; 3]]) -> [Real; 3] {
        let mut out = [0.0; 3];
        for &(j, b) in &self.rows[i] {
            let (w, rj) = (&self.blocks[b as usize], &r[j as usize]);
            for a in 0..3 {
                out[a] += w[3 * a] * rj[0] + w[3 * a + 1] * rj[1] + w[3 * a + 2] * rj[2];
            }
        }
        out
    }

    /// The Uzawa step of point `i`: `1 / Σ_j ‖W_ij‖_∞`. Its inverse bounds the response of the
    /// point to a unit reaction anywhere in its row, which keeps the Jacobi sweep stable.
    pub fn rho(&self, i: usize, dim: usize) -> Real {
        let mut sum = 0.0;
        for &(_, b) in &self.rows[i] {
            let w = &self.blocks[b as usize];
            sum += (0..dim).map(|a| (0..dim).map(|c| w[3 * a + c].abs()).sum::<Real>()).fold(0.0, Real::max);
        }
        if sum > 0.0 { 1.0 / sum } else { 0.0 }
    }
}

/// Per-point data of the local problem.
#[derive(Debug, Clone, Copy)]
pub struct Local {
    pub v_free: [Real; 3],
    pub shift: Real,
    pub mu: Real,
    pub rho: Real,
}

/// How the iterations ended.
#[derive(Debug, Clone, Copy, Default)]
pub struct Outcome {
    pub iterations: usize,
    pub converged: bool,
    /// Last `max |Δr| / max(max |r|, floor)`.
    pub change: Real,
}

/// Uzawa iterations from the reactions in `r` until the largest change is below
/// `tolerance * max(max |r|, floor)`, or `max_iterations`.
pub fn solve(w: &Delassus, local: &[Local], r: &mut [[Real; 3]], tolerance: Real, floor: Real, max_iterations: usize) -> Outcome {
    let n = local.len();
    let mut next = vec![[0.0; 3]; n];
    let mut outcome = Outcome::default();
    for it in 1..=max_iterations {
        let (mut change, mut size): (Real, Real) = (0.0, 0.0);
        for i in 0..n {
            let l = &local[i];
            let wr = w.row_times(i, r);
            let v = [l.v_free[0] + wr[0] + l.shift, l.v_free[1] + wr[1], l.v_free[2] + wr[2]];
            let (ri, _) = uzawa_step(r[i], v, l.mu, l.rho);
            next[i] = ri;
            let d = [ri[0] - r[i][0], ri[1] - r[i][1], ri[2] - r[i][2]];
            change = change.max((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt());
            size = size.max((ri[0] * ri[0] + ri[1] * ri[1] + ri[2] * ri[2]).sqrt());
        }
        r.copy_from_slice(&next);
        outcome = Outcome { iterations: it, converged: false, change: change / size.max(floor) };
        if change <= tolerance * size.max(floor) {
            outcome.converged = true;
            break;
        }
    }
    outcome
}
