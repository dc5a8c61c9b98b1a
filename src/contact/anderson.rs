//! Anderson acceleration of the Uzawa sweeps (Walker and Ni 2011, "type II"; Anderson 1965).
//!
//! A Gauss-Seidel sweep is a fixed-point map `r -> G(r)` that contracts linearly, slowly when the
//! points of a body are strongly coupled (large steps, stiff grains, the nearly redundant points
//! of two passes). From the last `m` sweeps, with residuals `f_k = G(r_k) - r_k`, Anderson's
//! step is `r_{k+1} = G(r_k) - ΔG γ`, `γ = argmin |f_k - ΔF γ|`, the combination of the recent
//! sweeps that the linearised map says is closest to the fixed point. Each mixed reaction is
//! projected back onto its Coulomb cone, so that the next sweep starts from admissible reactions.
//!
//! Safeguards, because the map is only piecewise linear (points open, close, stick and slide)
//! and nearly redundant points leave directions of `r` that the nodal forces do not see: a
//! mixed iterate whose sweep changes the nodal forces more than the sweep before it is rejected
//! ([`Anderson::reject`], by the caller, who judges the nodal forces) and the history restarts;
//! a least-squares problem too ill-conditioned to trust is not used.

use super::law::{ContactLaw, Law};
use crate::precision::Real;

/// Sweeps remembered: enough to capture the few slow modes of a contact problem, few enough that
/// the small least-squares problem stays well-conditioned and cheap next to a sweep.
pub const MEMORY: usize = 5;

/// The trust region's largest reach, in plain sweeps.
const MAX_REACH: Real = 1e4;

/// A least-squares problem whose normal matrix is this ill-conditioned (smallest pivot over
/// largest diagonal entry) is not trusted: the history is restarted.
const CONDITION: Real = 1e-14;

/// The history of recent sweeps of one contact problem.
#[derive(Debug, Default)]
pub struct Anderson {
    /// `G(r_k)` and `f_k`, oldest first, flattened over the points.
    outputs: Vec<Vec<Real>>,
    residuals: Vec<Vec<Real>>,
    /// `ΔF`: `f_{k+1} - f_k`, oldest first, and their inner products `gram[i][j] = Δ_i · Δ_j`
    /// (`j <= i`), each taken once, when `Δ_i` is made (recomputed every sweep, the normal
    /// matrix cost a twentieth of a jammed packing's run).
    deltas: Vec<Vec<Real>>,
    gram: Vec<Vec<Real>>,
    /// The longest step, in plain sweeps (`|f_k|`), a mixed iterate may take.
    reach: Real,
}

impl Anderson {
    pub fn new() -> Self {
        Self { reach: MAX_REACH, ..Default::default() }
    }

    /// Records the sweep from `start` to `swept` and overwrites `swept` with the accelerated
    /// iterate (projected onto the cones of `mu`). Returns whether it mixed (not on the first
    /// sweep after a restart, nor when the least-squares problem is not trusted).
    pub fn mix(&mut self, start: &[[Real; 3]], swept: &mut [[Real; 3]], mu: impl Fn(usize) -> Real) -> bool {
        if self.outputs.len() > MEMORY {
            self.outputs.remove(0);
            self.residuals.remove(0);
            self.deltas.remove(0);
            self.gram.remove(0);
            self.gram.iter_mut().for_each(|row| _ = row.remove(0));
        }
        self.outputs.push(swept.iter().flatten().copied().collect());
        self.residuals.push(swept.iter().flatten().zip(start.iter().flatten()).map(|(g, r)| g - r).collect());
        let m = self.residuals.len() - 1;
        if m == 0 {
            return false;
        }
        self.push_delta();
        let Some(gamma) = self.coefficients(m) else {
            // Keep only the newest sweep: the others no longer say anything usable.
            self.restart_from_newest();
            return false;
        };
        let step: Vec<Real> = (0..self.outputs[m].len()).map(|k| -gamma.iter().enumerate().map(|(j, g)| g * (self.outputs[j + 1][k] - self.outputs[j][k])).sum::<Real>()).collect();
        // Within the trust region: at most `reach` plain sweeps' worth of change.
        let length = step.iter().map(|x| x * x).sum::<Real>().sqrt();
        let residual = self.residuals[m].iter().map(|x| x * x).sum::<Real>().sqrt();
        let scale = if length > self.reach * residual { self.reach * residual / length } else { 1.0 };
        for ((x, g), d) in swept.iter_mut().flatten().zip(&self.outputs[m]).zip(&step) {
            *x = g + scale * d;
        }
        for (i, r) in swept.iter_mut().enumerate() {
            *r = Law::project(*r, mu(i)).0;
        }
        true
    }

    /// Rejects the last mixed iterate: `r` takes the last plain sweep's reactions back and the
    /// history restarts from them.
    pub fn reject(&mut self, r: &mut [[Real; 3]]) {
        let last = self.outputs.pop().expect("a mixed iterate follows a recorded sweep");
        for (x, v) in r.iter_mut().flatten().zip(last) {
            *x = v;
        }
        self.outputs.clear();
        self.residuals.clear();
        self.deltas.clear();
        self.gram.clear();
        self.reach = (self.reach / 4.0).max(1.0);
    }

    /// Keeps only the newest sweep.
    fn restart_from_newest(&mut self) {
        let m = self.outputs.len() - 1;
        self.outputs.drain(..m);
        self.residuals.drain(..m);
        self.deltas.clear();
        self.gram.clear();
    }

    /// Records `Δ` of the two newest residuals and its inner products with the earlier ones.
    fn push_delta(&mut self) {
        let m = self.residuals.len() - 1;
        let delta: Vec<Real> = self.residuals[m].iter().zip(&self.residuals[m - 1]).map(|(a, b)| a - b).collect();
        self.deltas.push(delta);
        let newest = &self.deltas[m - 1];
        let row = self.deltas.iter().map(|d| newest.iter().zip(d).fold(0.0, |s, (a, b)| s + a * b)).collect();
        self.gram.push(row);
    }

    /// Widens the trust region after a mixed iterate was kept.
    pub fn accept(&mut self) {
        self.reach = (self.reach * 2.0).min(MAX_REACH);
    }

    /// `γ = argmin |f_m - ΔF γ|` by the normal equations (m is small), `None` when they are
    /// too ill-conditioned.
    fn coefficients(&self, m: usize) -> Option<Vec<Real>> {
        let newest = &self.residuals[m];
        let mut b: Vec<Real> = self.deltas.iter().map(|d| d.iter().zip(newest).fold(0.0, |s, (a, b)| s + a * b)).collect();
        let mut a = vec![0.0; m * m];
        for i in 0..m {
            for j in 0..=i {
                (a[i * m + j], a[j * m + i]) = (self.gram[i][j], self.gram[i][j]);
            }
        }
        let scale = (0..m).map(|i| a[i * m + i]).fold(0.0, Real::max);
        if scale == 0.0 {
            return None;
        }
        // Cholesky in place.
        for j in 0..m {
            let mut d = a[j * m + j];
            for k in 0..j {
                d -= a[j * m + k] * a[j * m + k];
            }
            if d <= CONDITION * scale {
                return None;
            }
            let d = d.sqrt();
            a[j * m + j] = d;
            for i in j + 1..m {
                let mut s = a[i * m + j];
                for k in 0..j {
                    s -= a[i * m + k] * a[j * m + k];
                }
                a[i * m + j] = s / d;
            }
        }
        for i in 0..m {
            let mut s = b[i];
            for k in 0..i {
                s -= a[i * m + k] * b[k];
            }
            b[i] = s / a[i * m + i];
        }
        for i in (0..m).rev() {
            let mut s = b[i];
            for k in i + 1..m {
                s -= a[k * m + i] * b[k];
            }
            b[i] = s / a[i * m + i];
        }
        Some(b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a linear contraction with one slow mode, Anderson reaches the fixed point in a few
    /// steps where the plain iteration needs hundreds.
    #[test]
    fn anderson_accelerates_a_slow_linear_contraction() {
        // G(r) = A r + c with eigenvalues 0.99 and 0.5 (normal components only, mu = 0 keeps r_n >= 0).
        let fixed = [[2.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let map = |r: &[[Real; 3]]| -> Vec<[Real; 3]> {
            let e = [r[0][0] - fixed[0][0], r[1][0] - fixed[1][0]];
            let (s, d) = (0.5 * (e[0] + e[1]), 0.5 * (e[0] - e[1]));
            let (s, d) = (0.99 * s, 0.5 * d);
            vec![[fixed[0][0] + s + d, 0.0, 0.0], [fixed[1][0] + s - d, 0.0, 0.0]]
        };
        let steps_to = |accelerate: bool| {
            let mut r = vec![[5.0, 0.0, 0.0], [4.0, 0.0, 0.0]];
            let mut aa = Anderson::new();
            for k in 1..=2000 {
                let mut next = map(&r);
                if accelerate {
                    aa.mix(&r, &mut next, |_| 0.0);
                }
                r = next;
                if (r[0][0] - 2.0).abs() + (r[1][0] - 1.0).abs() < 1e-10 {
                    return k;
                }
            }
            usize::MAX
        };
        let (plain, accelerated) = (steps_to(false), steps_to(true));
        assert!(plain > 1000, "plain iteration took {plain}");
        assert!(accelerated < 10, "Anderson took {accelerated}");
    }
}
