//! Finite-strain viscoelasticity: a Prony series on the isochoric stress (Simo 1987; Holzapfel,
//! "Nonlinear Solid Mechanics", 2000, §6.10), on any hyperelastic model.
//!
//! The model's own parameters are its instantaneous response. With `S̃ = Dev S` the isochoric
//! part of its stress (`Dev S = S - (S:C)/3 C⁻¹`, which is `S_iso` exactly for the models split
//! into `W_iso + U(J)`), each Prony term `(gᵢ, τᵢ)` adds an overstress `Qᵢ` relaxing as
//! `Q̇ᵢ + Qᵢ/τᵢ = gᵢ dS̃/dt`, and the stress is `S_vol + (1 - Σ gᵢ) S̃ + Σ Qᵢ`: the model's
//! stress for a sudden deformation, its volumetric part and `g∞ = 1 - Σ gᵢ` of its isochoric
//! part after a long hold (relaxation function `g(t) = g∞ + Σ gᵢ exp(-t/τᵢ)`, the convention of
//! Abaqus' `*VISCOELASTIC, TIME=PRONY`).
//!
//! Over a step of length `dt`, with `aᵢ = exp(-dt/τᵢ)` and `βᵢ = (1 - aᵢ) τᵢ/dt`, each branch
//! is integrated exactly for an `S̃` linear in time over the step (Taylor, Pister and Goudreau
//! 1970; Simo and Hughes, "Computational Inelasticity", §10.3),
//! `Qᵢ⁺ = aᵢ Qᵢ + gᵢ βᵢ (S̃⁺ - S̃)`, so that the step's stress is
//! `S⁺ = S(E⁺) - c S̃(E⁺) + H` with `c = Σ gᵢ (1 - βᵢ)` and the history
//! `H = Σ (aᵢ Qᵢ - gᵢ βᵢ S̃)` known at the step's start: the element kernels take `c` and each
//! quadrature point's `H` ([`relaxed_stress_tangent`]); the host advances `Qᵢ` once a step has
//! converged ([`Viscoelastic::advance`]), and books what the branches dissipated on that same
//! exact path, `∫ |Qᵢ|² / (2 gᵢ G τᵢ) dt`, never below zero whatever `τᵢ/dt` (the midpoint
//! rule used before booked the xi-weighted work of the overstress less the change of the
//! branches' energy, which went below zero once `τᵢ` was not large against `dt`).

use super::tensor::{odot, outer, right_cauchy_green, to_voigt, Mat3, Tangent, VOIGT, VOIGT_WEIGHT};
use crate::precision::Real;

/// One term of the relaxation function: relative modulus `g` and relaxation time `tau`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prony {
    pub g: Real,
    pub tau: Real,
}

/// What a point's branches did over a step ([`Viscoelastic::advance`]), per unit volume.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BranchStep {
    /// Work of the overstress.
    pub work: Real,
    /// What the branches dissipated (zero or positive).
    pub dissipated: Real,
}

/// A material's Prony series.
#[derive(Debug, Clone, PartialEq)]
pub struct Viscoelastic {
    pub terms: Vec<Prony>,
}

/// What a step's kernels need of a body's relaxation: `c` and each quadrature point's history
/// `H` (Voigt order, [`HISTORY`] reals per point, every element's points in order).
#[derive(Debug, Clone, Copy)]
pub struct Relaxation<'a> {
    pub c: Real,
    pub history: &'a [Real],
}

/// Reals of a point's history `H`.
pub const HISTORY: usize = 6;

impl<'a> Relaxation<'a> {
    /// The history of element `e`'s points.
    pub fn element(&self, e: usize, points_per_element: usize) -> Self {
        let n = points_per_element * HISTORY;
        Relaxation { c: self.c, history: &self.history[e * n..(e + 1) * n] }
    }

    /// The history of point `q` (of the element this was taken for).
    pub fn point(&self, q: usize) -> &'a [Real] {
        &self.history[q * HISTORY..(q + 1) * HISTORY]
    }
}

/// What a quadrature point keeps between steps: `S̃`, `E` and each term's `Qᵢ`, Voigt order.
const KEPT_S: usize = 0;
const KEPT_E: usize = 6;
const KEPT_Q: usize = 12;

impl Viscoelastic {
    /// Reals a quadrature point keeps between steps ([`Viscoelastic::advance`]).
    pub fn kept_per_point(&self) -> usize {
        KEPT_Q + HISTORY * self.terms.len()
    }

    /// Each term with its step factors `(aᵢ, βᵢ)` and `xᵢ = dt/τᵢ`.
    fn factors(&self, dt: Real) -> impl Iterator<Item = (Prony, StepFactors)> + '_ {
        self.terms.iter().map(move |&p| (p, StepFactors::new(dt / p.tau)))
    }

    /// The step's `c = Σ gᵢ (1 - βᵢ)`: how much of `S̃(E⁺)` the branches do not carry.
    pub fn step_relaxation(&self, dt: Real) -> Real {
        self.factors(dt).map(|(p, f)| p.g * (1.0 - f.beta)).sum()
    }

    /// A point's history `H = Σ (aᵢ Qᵢ - gᵢ βᵢ S̃)` for a step of `dt`, from what it kept.
    pub fn history(&self, dt: Real, kept: &[Real], h: &mut [Real]) {
        h.fill(0.0);
        for (i, (p, f)) in self.factors(dt).enumerate() {
            let q = &kept[KEPT_Q + HISTORY * i..KEPT_Q + HISTORY * (i + 1)];
            for r in 0..HISTORY {
                h[r] += f.a * q[r] - p.g * f.beta * kept[KEPT_S + r];
            }
        }
    }

    /// Ends a converged step of `dt` at a point whose strain is `e` and whose model stress is
    /// `s`: `kept` (the step's start values) becomes the end values. Returns, per unit volume,
    /// the work of the overstress `S_v = Σ Qᵢ - (Σ gᵢ) S̃` (the stress less the model's) and what
    /// the branches dissipated, both along the exact path of each branch for `S̃` and `E` linear
    /// in time over the step. The dissipation is `Σ ∫ |Qᵢ(t)|² / (2 gᵢ G τᵢ) dt` (a Maxwell
    /// element of modulus `gᵢ G` per term): zero or positive for any `dt/τᵢ`; the rest of the
    /// work is what the branches hold.
    pub fn advance(&self, dt: Real, kept: &mut [Real], e: &Mat3, s: &Mat3, shear_modulus: Real) -> BranchStep {
        let s_iso = to_voigt(&isochoric_part(s, e));
        let e_new = to_voigt(e);
        let change: [Real; 6] = std::array::from_fn(|r| s_iso[r] - kept[KEPT_S + r]);
        let strain_change: [Real; 6] = std::array::from_fn(|r| e_new[r] - kept[KEPT_E + r]);
        let change2 = weighted_dot(&change, &change);
        let g_sum: Real = self.terms.iter().map(|t| t.g).sum();
        // The mean overstress over the step: the branches' means less (Σ gᵢ) S̃ at mid-step.
        let mut mean: [Real; 6] = std::array::from_fn(|r| -g_sum * (kept[KEPT_S + r] + 0.5 * change[r]));
        let mut dissipated = 0.0;
        for (i, (p, f)) in self.factors(dt).enumerate() {
            let q = &mut kept[KEPT_Q + HISTORY * i..KEPT_Q + HISTORY * (i + 1)];
            // Qᵢ(t) = A aₜ + B (1 - aₜ), A the start value, B = gᵢ τᵢ dS̃/dt = gᵢ ΔS̃ / xᵢ.
            let (a2, ab) = (weighted_dot(q, q), weighted_dot(q, &change));
            let integral = f.start_weight * a2 + p.g * f.cross_weight * ab + p.g * p.g * f.rate_weight * change2;
            // A sum of squares' integral: below zero only by round-off.
            dissipated += integral.max(0.0) / (2.0 * p.g * shear_modulus);
            for r in 0..HISTORY {
                mean[r] += f.beta * q[r] + p.g * f.ramp_mean * change[r];
                q[r] = f.a * q[r] + p.g * f.beta * change[r];
            }
        }
        kept[KEPT_S..KEPT_S + HISTORY].copy_from_slice(s_iso.as_slice());
        kept[KEPT_E..KEPT_E + HISTORY].copy_from_slice(e_new.as_slice());
        BranchStep { work: weighted_dot(&mean, &strain_change), dissipated }
    }

    /// An estimate of the energy a point's branches hold beyond what the model's instantaneous
    /// energy counts for them, `Σ (|Qᵢ|² - gᵢ² |S̃|²) / (4 gᵢ G)`, from what it kept; `G` is the
    /// model's small-strain shear modulus (a Maxwell element of modulus `gᵢ G` per term holding
    /// `|Qᵢ|²/(4 gᵢ G)`, against the `gᵢ W̃ ≈ gᵢ |S̃|²/(4G)` of the instantaneous energy). Exact at
    /// small strain only: a run sums the branches' work less their dissipation instead, and
    /// this serves restores from logs that did not save that sum.
    pub fn branch_energy(&self, kept: &[Real], shear_modulus: Real) -> Real {
        let norm2 = |v: &[Real]| weighted_dot(v, v);
        let s2 = norm2(&kept[KEPT_S..KEPT_S + HISTORY]);
        self.terms.iter().enumerate().map(|(i, p)| (norm2(&kept[KEPT_Q + HISTORY * i..KEPT_Q + HISTORY * (i + 1)]) - p.g * p.g * s2) / (4.0 * p.g * shear_modulus)).sum()
    }
}

/// A term's factors over a step of `x = dt/τ`: the decay `a = exp(-x)`, the mean `β = (1 - a)/x`
/// of `aₜ` over the step, the mean `(1 - β)/x` of `(1 - aₜ)/x`, and the integrals over the step
/// (in units of `τ`) of `aₜ²`, `2 aₜ (1 - aₜ) / x` and `(1 - aₜ)² / x²` that give a branch's
/// dissipation.
#[derive(Debug, Clone, Copy)]
struct StepFactors {
    a: Real,
    beta: Real,
    ramp_mean: Real,
    start_weight: Real,
    cross_weight: Real,
    rate_weight: Real,
}

impl StepFactors {
    fn new(x: Real) -> Self {
        let one_minus_a = -(-x).exp_m1();
        StepFactors {
            a: (-x).exp(),
            beta: if x > 0.0 { one_minus_a / x } else { 1.0 },
            ramp_mean: ramp_mean(x),
            start_weight: -(-2.0 * x).exp_m1() / 2.0,
            cross_weight: if x > 0.0 { one_minus_a * one_minus_a / x } else { 0.0 },
            rate_weight: ramp_weight(x),
        }
    }
}

/// `∫₀ˣ (1 - e⁻ˢ)² ds / x²`, with `∫₀ˣ (1 - e⁻ˢ)² ds = x - 2 (1 - e⁻ˣ) + (1 - e⁻²ˣ)/2`, by
/// its series where that form cancels (`x/3 - x²/4 + ...`, coefficients `(-1)ⁿ (2 - 2ⁿ⁻¹)/n!`
/// of `xⁿ⁻²`).
fn ramp_weight(x: Real) -> Real {
    if x < 1e-2 {
        let (mut sum, mut power, mut factorial) = (0.0, 1.0, 2.0);
        for n in 3..=9 {
            power *= x;
            factorial *= n as Real;
            let sign = if n % 2 == 0 { 1.0 } else { -1.0 };
            sum += sign * (2.0 - (1u64 << (n - 1)) as Real) / factorial * power;
        }
        sum
    } else {
        (x + 2.0 * (-x).exp_m1() - (-2.0 * x).exp_m1() / 2.0) / (x * x)
    }
}

/// `(1 - β)/x = (x - 1 + e⁻ˣ)/x²`, by its series `Σ (-x)ᵏ/(k + 2)!` where that form cancels.
fn ramp_mean(x: Real) -> Real {
    if x < 1e-2 {
        let (mut sum, mut term) = (0.0, 0.5);
        for k in 0..8 {
            sum += term;
            term *= -x / (k + 3) as Real;
        }
        sum
    } else {
        (x + (-x).exp_m1()) / (x * x)
    }
}

/// `a : b` of two symmetric tensors in Voigt order (a shear entry counting twice).
fn weighted_dot(a: &[Real], b: &[Real]) -> Real {
    (0..HISTORY).map(|r| VOIGT_WEIGHT[r] * a[r] * b[r]).sum()
}

/// The symmetric tensor of a Voigt vector.
fn symmetric(v: &[Real]) -> Mat3 {
    Mat3::new(v[0], v[3], v[5], v[3], v[1], v[4], v[5], v[4], v[2])
}

/// `C = I + 2E` and its inverse (NaN where it has none, as the stresses are then).
fn cauchy_green_and_inverse(e: &Mat3) -> (Mat3, Mat3) {
    let c = right_cauchy_green(e);
    (c, c.try_inverse().unwrap_or(Mat3::from_element(Real::NAN)))
}

/// `S : C`.
fn double_dot(s: &Mat3, c: &Mat3) -> Real {
    s.component_mul(c).sum()
}

/// The isochoric part of a stress, `Dev S = S - (S:C)/3 C⁻¹` (Holzapfel (6.86)).
pub fn isochoric_part(s: &Mat3, e: &Mat3) -> Mat3 {
    let (c, ci) = cauchy_green_and_inverse(e);
    s - ci * (double_dot(s, &c) / 3.0)
}

/// The stress and tangent of a step's relaxation at one point (`relax` of
/// `shaders/include/viscous.wgsl`): `S - c Dev S + H` and `D - c d(Dev S)/dE`, with
/// `d(Dev S)/dE = D - ⅓ C⁻¹ ⊗ (C:D + 2S) + ⅔ (S:C) C⁻¹ ⊙ C⁻¹` taken symmetric. For the models
/// split into `W_iso + U(J)` it is symmetric already (`Dev S = S_iso` whatever E); for the others
/// (Blatz-Ko, LVF, the compressible Neo-Hookean) its symmetric part is a tangent Newton
/// converges with, as it does with a kept factorisation.
pub fn relaxed_stress_tangent(s: &Mat3, d: Option<&Tangent>, e: &Mat3, c: Real, h: &[Real]) -> (Mat3, Option<Tangent>) {
    let (cg, ci) = cauchy_green_and_inverse(e);
    let t = double_dot(s, &cg);
    let relaxed = s * (1.0 - c) + ci * (c * t / 3.0) + symmetric(h);
    let tangent = d.map(|d| {
        // X = C:D + 2S, a shear entry of C counting twice in the contraction.
        let xv: [Real; 6] = std::array::from_fn(|col| (0..6).map(|r| VOIGT_WEIGHT[r] * cg[VOIGT[r]] * d[(r, col)]).sum::<Real>() + 2.0 * s[VOIGT[col]]);
        let x = symmetric(&xv);
        d * (1.0 - c) + (outer(&ci, &x) + outer(&x, &ci)) * (c / 6.0) - odot(&ci, &ci) * (2.0 * c * t / 3.0)
    });
    (relaxed, tangent)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `advance`'s closed-form integrals against midpoint sums of the exact branch path, from
    /// `dt/τ` of 1e-6 (the series) to 1e3: the dissipation `∫ |Q|²/(2 g G τ) dt` and the
    /// overstress' mean over the step.
    #[test]
    fn a_branch_step_dissipates_what_its_exact_path_does() {
        let shear = 3.0;
        let e1 = Mat3::new(0.01, 0.002, 0.0, 0.002, -0.004, 0.001, 0.0, 0.001, 0.003);
        let e2 = Mat3::new(0.03, -0.001, 0.002, -0.001, 0.01, 0.0, 0.002, 0.0, -0.02);
        let stress = |e: &Mat3| e * (2.0 * shear) + Mat3::identity() * (5.0 * e.trace());
        for x in [1e-6, 1e-3, 0.05, 1.0, 7.0, 1e3] {
            let (dt, g) = (0.01, 0.4);
            let visco = Viscoelastic { terms: vec![Prony { g, tau: dt / x }] };
            let mut kept = vec![0.0; visco.kept_per_point()];
            // A first step from rest leaves a branch stress to start from.
            visco.advance(dt * 3.0, &mut kept, &e1, &stress(&e1), shear);
            let (start_q, start_s): (Vec<Real>, Vec<Real>) = (kept[KEPT_Q..KEPT_Q + 6].to_vec(), kept[KEPT_S..KEPT_S + 6].to_vec());
            let step = visco.advance(dt, &mut kept, &e2, &stress(&e2), shear);
            let end_s = to_voigt(&isochoric_part(&stress(&e2), &e2));
            let strain_change = to_voigt(&(e2 - e1));
            let (pieces, tau) = (200_000, dt / x);
            let (mut dissipated, mut work) = (0.0, 0.0);
            for k in 0..pieces {
                let t = dt * (k as Real + 0.5) / pieces as Real;
                let decay = (-t / tau).exp();
                let s_t: Vec<Real> = (0..6).map(|r| start_s[r] + (end_s[r] - start_s[r]) * t / dt).collect();
                let q: Vec<Real> = (0..6).map(|r| start_q[r] * decay + g * tau * (end_s[r] - start_s[r]) / dt * (1.0 - decay)).collect();
                dissipated += weighted_dot(&q, &q) / (2.0 * g * shear * tau) * dt / pieces as Real;
                let overstress: Vec<Real> = (0..6).map(|r| q[r] - g * s_t[r]).collect();
                work += weighted_dot(&overstress, strain_change.as_slice()) / pieces as Real;
            }
            let close = |a: Real, b: Real| (a - b).abs() <= 1e-6 * b.abs().max(1e-12);
            assert!(step.dissipated >= 0.0 && close(step.dissipated, dissipated), "x = {x}: dissipated {} against {dissipated}", step.dissipated);
            assert!(close(step.work, work), "x = {x}: work {} against {work}", step.work);
        }
    }
}
