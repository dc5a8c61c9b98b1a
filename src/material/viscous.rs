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
//! Over a step of length `dt`, with `ξᵢ = exp(-dt/(2τᵢ))` (the midpoint rule of the
//! convolution, exact for a rate constant over the step),
//! `Qᵢ⁺ = ξᵢ² Qᵢ + gᵢ ξᵢ (S̃⁺ - S̃)`, so that the step's stress is
//! `S⁺ = S(E⁺) - c S̃(E⁺) + H` with `c = Σ gᵢ (1 - ξᵢ)` and the history
//! `H = Σ (ξᵢ² Qᵢ - gᵢ ξᵢ S̃)` known at the step's start: the element kernels take `c` and each
//! quadrature point's `H` ([`relaxed_stress_tangent`]); the host advances `Qᵢ` once a step has
//! converged ([`Viscoelastic::advance`]).

use super::tensor::{odot, outer, right_cauchy_green, to_voigt, Mat3, Tangent, VOIGT, VOIGT_WEIGHT};
use crate::precision::Real;

/// One term of the relaxation function: relative modulus `g` and relaxation time `tau`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prony {
    pub g: Real,
    pub tau: Real,
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

    /// `ξᵢ = exp(-dt/(2τᵢ))` of each term.
    fn weights(&self, dt: Real) -> impl Iterator<Item = (Prony, Real)> + '_ {
        self.terms.iter().map(move |&p| (p, (-0.5 * dt / p.tau).exp()))
    }

    /// The step's `c = Σ gᵢ (1 - ξᵢ)`: how much of `S̃(E⁺)` the branches do not carry.
    pub fn step_relaxation(&self, dt: Real) -> Real {
        self.weights(dt).map(|(p, xi)| p.g * (1.0 - xi)).sum()
    }

    /// A point's history `H = Σ (ξᵢ² Qᵢ - gᵢ ξᵢ S̃)` for a step of `dt`, from what it kept.
    pub fn history(&self, dt: Real, kept: &[Real], h: &mut [Real]) {
        h.fill(0.0);
        for (i, (p, xi)) in self.weights(dt).enumerate() {
            let q = &kept[KEPT_Q + HISTORY * i..KEPT_Q + HISTORY * (i + 1)];
            for r in 0..HISTORY {
                h[r] += xi * xi * q[r] - p.g * xi * kept[KEPT_S + r];
            }
        }
    }

    /// Ends a converged step of `dt` at a point whose strain is `e` and whose model stress is
    /// `s`: `kept` (the step's start values) becomes the end values. Returns the density of the
    /// overstress' work over the step, `((1-ξ) S_v + ξ S_v⁺) : (E⁺ - E)` with `S_v = Σ Qᵢ -
    /// (Σ gᵢ) S̃` (the stress less the model's), weighted as the scheme weighs the forces.
    pub fn advance(&self, dt: Real, force_weight: Real, kept: &mut [Real], e: &Mat3, s: &Mat3) -> Real {
        let s_iso = to_voigt(&isochoric_part(s, e));
        let e_new = to_voigt(e);
        let g_sum: Real = self.terms.iter().map(|t| t.g).sum();
        let overstress = |kept: &[Real], r: usize| (0..self.terms.len()).map(|i| kept[KEPT_Q + HISTORY * i + r]).sum::<Real>() - g_sum * kept[KEPT_S + r];
        let before: [Real; 6] = std::array::from_fn(|r| overstress(kept, r));
        for (i, (p, xi)) in self.weights(dt).enumerate() {
            for r in 0..HISTORY {
                let change = s_iso[r] - kept[KEPT_S + r];
                let q = &mut kept[KEPT_Q + HISTORY * i + r];
                *q = xi * xi * *q + p.g * xi * change;
            }
        }
        let mut work = 0.0;
        for r in 0..HISTORY {
            kept[KEPT_S + r] = s_iso[r];
            let after = overstress(kept, r);
            work += VOIGT_WEIGHT[r] * ((1.0 - force_weight) * before[r] + force_weight * after) * (e_new[r] - kept[KEPT_E + r]);
            kept[KEPT_E + r] = e_new[r];
        }
        work
    }

    /// The energy a point's branches hold beyond what the model's instantaneous energy counts
    /// for them, `Σ (|Qᵢ|² - gᵢ² |S̃|²) / (4 gᵢ G)`, from what it kept; `G` is the model's
    /// small-strain shear modulus. Each branch is taken as a Maxwell element of modulus `gᵢ G`
    /// holding `|Qᵢ|²/(4 gᵢ G)`, against the `gᵢ W̃ ≈ gᵢ |S̃|²/(4G)` of the instantaneous energy:
    /// exact at small strain, an estimate at finite strain (the energy balance closes either
    /// way: what this misses is counted in the dissipation).
    pub fn branch_energy(&self, kept: &[Real], shear_modulus: Real) -> Real {
        let norm2 = |v: &[Real]| (0..HISTORY).map(|r| VOIGT_WEIGHT[r] * v[r] * v[r]).sum::<Real>();
        let s2 = norm2(&kept[KEPT_S..KEPT_S + HISTORY]);
        self.terms
            .iter()
            .enumerate()
            .map(|(i, p)| (norm2(&kept[KEPT_Q + HISTORY * i..KEPT_Q + HISTORY * (i + 1)]) - p.g * p.g * s2) / (4.0 * p.g * shear_modulus))
            .sum()
    }
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
