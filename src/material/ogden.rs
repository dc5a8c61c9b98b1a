//! Ogden's rubber model through the principal stretches of C:
//! `W = Σₚ (μₚ/αₚ)(λ̄₁^αₚ + λ̄₂^αₚ + λ̄₃^αₚ - 3) + K/2 (ln J)²`, `λ̄ₐ = J^(-1/3) λₐ`, with up to
//! three terms (a term with μ = 0 is absent) and small-strain shear modulus `½ Σ μₚ αₚ`.
//!
//! Written in the logarithms `ℓₐ = ln cₐ` of the eigenvalues `cₐ = λₐ²` of C, where
//! `λ̄ₐ^α = exp(α/2 (ℓₐ - ℓ̄))`: the derivatives in ℓ are sums of exponentials, and those in c
//! follow by `∂/∂cₐ = (1/cₐ) ∂/∂ℓₐ`. The tangent is the spectral form (Simo and Taylor 1991)
//! `dS/dE = Σₐᵦ 4 Wₐᵦ Mₐ⊗Mᵦ + Σₐ≠ᵦ Θₐᵦ Nₐ⊗Nᵦ⊗(Nₐ⊗Nᵦ + Nᵦ⊗Nₐ)` with
//! `Θₐᵦ = (Sₐ - Sᵦ)/(cₐ - cᵦ)`; where two eigenvalues (nearly) coincide, as in the undeformed
//! state, Θ takes its limit `Wₐₐ + Wᵦᵦ - 2Wₐᵦ` (second-order accurate in the gap). The
//! eigenvectors come from cyclic Jacobi rotations, which need only square roots (the WGSL twin
//! `shaders/include/material_ogden.wgsl` has no f64 eigen-solver or `pow` to call).

use super::registry::{number, terms, Law, Parameter, Parameters, Rejected};
use super::tensor::{right_cauchy_green, Mat3, Tangent, VOIGT};
use super::Hyperelastic;
use crate::precision::Real;

/// Relative gap of two eigenvalues of C below which Θ takes its coincident limit: its
/// difference quotient would lose `ε / gap` of its digits, the limit `O(gap²)`.
pub const COINCIDENT: Real = 1e-5;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ogden {
    pub mu: [Real; 3],
    pub alpha: [Real; 3],
    pub k: Real,
}

impl Law for Ogden {
    const NAME: &'static str = "ogden";
    const PARAMETERS: &'static [Parameter] = &[Parameter::modulus("K"), Parameter::terms("mu"), Parameter::terms("alpha")];
    const WGSL: &'static str = include_str!("../../shaders/include/material_ogden.wgsl");
    // Ogden's three-term fit of Treloar's data (1972), in kPa.
    const EXAMPLE: &'static [(&'static str, &'static [Real])] = &[("mu", &[630.0, 1.2, -10.0]), ("alpha", &[1.3, 5.0, -2.0]), ("K", &[3000.0])];
    // Jacobi rotations (about 6 sweeps of 3), an exponential per stretch and term, and the
    // spectral tangent's 36 entries of 9 eigenvector products each.
    const FLOPS: (f64, f64, f64) = (4500.0, 2000.0, 1400.0);

    fn from_parameters(p: &Parameters) -> Self {
        Self { mu: terms(p, "mu"), alpha: terms(p, "alpha"), k: number(p, "K") }
    }
    /// As many exponents as moduli, none zero, and a positive small-strain shear modulus.
    fn check(p: &Parameters) -> Result<(), Rejected> {
        let len = |name| p.get(name).map_or(0, |v| v.as_slice().len());
        let reject = |parameter: &str, message: String| Err(Rejected { parameter: parameter.into(), message });
        if len("mu") != len("alpha") {
            return reject("alpha", format!("one exponent per term: `mu` has {} terms, `alpha` {}.", len("mu"), len("alpha")));
        }
        let m = Self::from_parameters(p);
        if let Some(t) = m.alpha[..len("alpha")].iter().position(|&a| a == 0.0) {
            return reject("alpha", format!("term {} has the exponent 0 (its energy μ/α (λ^α - 1) is undefined).", t + 1));
        }
        let g = m.shear_modulus();
        if g.is_nan() || g <= 0.0 {
            return reject("mu", format!("the small-strain shear modulus G = ½ Σ μₚ αₚ must be above zero (got {g})."));
        }
        Ok(())
    }
    /// G, K, then μ₁..₃ in a1..a3 and α₁..₃ in a4..a6.
    fn gpu_parameters(&self) -> [Real; 8] {
        let (m, a) = (self.mu, self.alpha);
        [self.shear_modulus(), self.k, m[0], m[1], m[2], a[0], a[1], a[2]]
    }
    fn bulk_shear(&self) -> (Real, Real) {
        (self.k, self.shear_modulus())
    }
}

/// Eigenvalues and eigenvectors (columns) of a symmetric 3x3 matrix by cyclic Jacobi rotations
/// (`jacobi_eigen` of the WGSL twin).
pub fn jacobi_eigen(c: &Mat3) -> ([Real; 3], Mat3) {
    let mut a = *c;
    let mut v = Mat3::identity();
    for _sweep in 0..12 {
        let off = a[(0, 1)].abs() + a[(0, 2)].abs() + a[(1, 2)].abs();
        if off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            let apq = a[(p, q)];
            // Negligible against the diagonal: its eigenvalue shift would be below round-off.
            if apq.abs() <= 1e-18 * (a[(p, p)].abs() + a[(q, q)].abs()) {
                a[(p, q)] = 0.0;
                a[(q, p)] = 0.0;
                continue;
            }
            let theta = (a[(q, q)] - a[(p, p)]) / (2.0 * apq);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let cos = 1.0 / (t * t + 1.0).sqrt();
            let sin = t * cos;
            // A ← Rᵀ A R and V ← V R with R the rotation in the (p, q) plane.
            for k in 0..3 {
                let (akp, akq) = (a[(k, p)], a[(k, q)]);
                a[(k, p)] = cos * akp - sin * akq;
                a[(k, q)] = sin * akp + cos * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[(p, k)], a[(q, k)]);
                a[(p, k)] = cos * apk - sin * aqk;
                a[(q, k)] = sin * apk + cos * aqk;
            }
            for k in 0..3 {
                let (vkp, vkq) = (v[(k, p)], v[(k, q)]);
                v[(k, p)] = cos * vkp - sin * vkq;
                v[(k, q)] = sin * vkp + cos * vkq;
            }
        }
    }
    ([a[(0, 0)], a[(1, 1)], a[(2, 2)]], v)
}

/// What the energy, stress and tangent share at one strain: the eigen-decomposition of C and the
/// derivatives of W in the logarithms of its eigenvalues.
struct Principal {
    c: [Real; 3],
    n: Mat3,
    /// `∂W/∂ℓₐ`.
    g: [Real; 3],
    /// `∂²W/∂ℓₐ∂ℓᵦ`.
    h: [[Real; 3]; 3],
    energy: Real,
}

impl Ogden {
    pub fn shear_modulus(&self) -> Real {
        0.5 * (0..3).map(|p| self.mu[p] * self.alpha[p]).sum::<Real>()
    }

    fn principal(&self, e: &Mat3) -> Principal {
        let (c, n) = jacobi_eigen(&right_cauchy_green(e));
        let l = c.map(Real::ln);
        let mean = (l[0] + l[1] + l[2]) / 3.0;
        let ln_j = 0.5 * (l[0] + l[1] + l[2]);
        let mut energy = 0.5 * self.k * ln_j * ln_j;
        let mut g = [0.5 * self.k * ln_j; 3];
        let mut h = [[0.25 * self.k; 3]; 3];
        for p in 0..3 {
            let (mu, alpha) = (self.mu[p], self.alpha[p]);
            if mu == 0.0 {
                continue;
            }
            let t = l.map(|la| (0.5 * alpha * (la - mean)).exp());
            let sum = t[0] + t[1] + t[2];
            energy += mu / alpha * (sum - 3.0);
            for a in 0..3 {
                g[a] += 0.5 * mu * (t[a] - sum / 3.0);
                for b in 0..3 {
                    let diagonal = if a == b { t[a] } else { 0.0 };
                    h[a][b] += 0.25 * mu * alpha * (diagonal - (t[a] + t[b]) / 3.0 + sum / 9.0);
                }
            }
        }
        Principal { c, n, g, h, energy }
    }
}

impl Principal {
    /// `Sₐ = 2 ∂W/∂cₐ`.
    fn principal_stresses(&self) -> [Real; 3] {
        [0, 1, 2].map(|a| 2.0 * self.g[a] / self.c[a])
    }

    fn stress(&self) -> Mat3 {
        let s = self.principal_stresses();
        let mut out = Mat3::zeros();
        for a in 0..3 {
            let na = self.n.column(a);
            out += na * na.transpose() * s[a];
        }
        out
    }

    /// `Wₐᵦ = ∂²W/∂cₐ∂cᵦ`.
    fn second(&self) -> [[Real; 3]; 3] {
        let c = self.c;
        std::array::from_fn(|a| std::array::from_fn(|b| self.h[a][b] / (c[a] * c[b]) - if a == b { self.g[a] / (c[a] * c[a]) } else { 0.0 }))
    }

    fn tangent(&self) -> Tangent {
        let s = self.principal_stresses();
        let w = self.second();
        let n = &self.n;
        let scale = self.c[0].abs().max(self.c[1].abs()).max(self.c[2].abs());
        let theta: [[Real; 3]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|b| {
                let gap = self.c[a] - self.c[b];
                if gap.abs() <= COINCIDENT * scale {
                    w[a][a] + w[b][b] - 2.0 * w[a][b]
                } else {
                    (s[a] - s[b]) / gap
                }
            })
        });
        Tangent::from_fn(|r, col| {
            let (i, j) = VOIGT[r];
            let (k, l) = VOIGT[col];
            let mut d = 0.0;
            for a in 0..3 {
                for b in 0..3 {
                    d += 4.0 * w[a][b] * n[(i, a)] * n[(j, a)] * n[(k, b)] * n[(l, b)];
                    if a != b {
                        d += theta[a][b] * n[(i, a)] * n[(j, b)] * (n[(k, a)] * n[(l, b)] + n[(k, b)] * n[(l, a)]);
                    }
                }
            }
            d
        })
    }
}

impl Hyperelastic for Ogden {
    fn energy(&self, e: &Mat3) -> Real {
        self.principal(e).energy
    }
    fn stress(&self, e: &Mat3) -> Mat3 {
        self.principal(e).stress()
    }
    fn stress_tangent(&self, e: &Mat3) -> (Mat3, Tangent) {
        let p = self.principal(e);
        (p.stress(), p.tangent())
    }
}
