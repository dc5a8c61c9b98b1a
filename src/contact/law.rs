//! The local contact law behind one trait ([`ContactLaw`]): what the Uzawa sweeps, the
//! semi-smooth Newton solve and the kernels need of a law. Its one implementation is eq. (10),
//! de Saxcé's bi-potential predictor and the projection onto the Coulomb cone ([`Coulomb`]);
//! [`Law`] is the one place that picks the engine's. Vectors are in the contact frame, normal
//! first: `[n, t1, t2]` (in 2D the third entry is unused and stays zero).

use crate::precision::Real;

/// What the projection did at a contact point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// In the polar cone: the reaction is zero.
    Separated,
    /// Strictly inside the cone: the point sticks.
    Sticking,
    /// On the cone's surface: the point slides, `|r_t| = mu r_n`.
    Sliding,
}

impl Status {
    /// The code kernels and VTU files use: 0 separated, 1 sticking, 2 sliding.
    pub fn code(self) -> u32 {
        match self {
            Status::Separated => 0,
            Status::Sticking => 1,
            Status::Sliding => 2,
        }
    }

    /// The status of a [`Status::code`] (kernels write it as a `real`).
    pub fn from_code(code: u32) -> Self {
        match code {
            1 => Status::Sticking,
            2 => Status::Sliding,
            _ => Status::Separated,
        }
    }
}

fn tangential_norm(x: &[Real; 3]) -> Real {
    (x[1] * x[1] + x[2] * x[2]).sqrt()
}

/// A local contact law at a point, as a predictor and a projection (Uzawa's step is the
/// projection of the predictor), with the derivatives the semi-smooth Newton solve takes.
pub trait ContactLaw {
    /// The include of `shaders/include/` that gives the kernels the same step.
    const INCLUDE: &'static str;
    /// The predictor at reaction `r` and relative velocity `v` (its normal component shifted by
    /// the gap term), with the point's `rho`.
    fn predictor(r: [Real; 3], v: [Real; 3], mu: Real, rho: Real) -> [Real; 3];
    /// `∂ṽ/∂v` (row-major `3 x 3`) of the velocity `ṽ` the predictor takes, `tau = r - rho ṽ`.
    fn predictor_velocity_jacobian(v: [Real; 3], mu: Real) -> [Real; 9];
    /// The corrector: the projection onto the law's set of admissible reactions, and what it did.
    fn project(tau: [Real; 3], mu: Real) -> ([Real; 3], Status);
    /// A generalised Jacobian of [`ContactLaw::project`] at `tau` (row-major `3 x 3`, `dim`
    /// components used).
    fn projection_jacobian(tau: [Real; 3], mu: Real, dim: usize) -> [Real; 9];
    /// One Uzawa step: the projection of the predictor.
    fn step(r: [Real; 3], v: [Real; 3], mu: Real, rho: Real) -> ([Real; 3], Status) {
        Self::project(Self::predictor(r, v, mu, rho), mu)
    }
}

/// Coulomb friction in de Saxcé's bi-potential form (the paper's eq. (10)): the predictor
/// `tau = r - rho (v_t + (v_n + mu |v_t|) n)`, the Euclidean projection onto the cone
/// `K_mu = { |r_t| <= mu r_n }`.
pub struct Coulomb;

/// The engine's contact law, for the sweeps, the Newton solve and the kernels alike.
pub type Law = Coulomb;

impl ContactLaw for Coulomb {
    const INCLUDE: &'static str = "contact_law";

    fn predictor(r: [Real; 3], v: [Real; 3], mu: Real, rho: Real) -> [Real; 3] {
        let vt = tangential_norm(&v);
        [r[0] - rho * (v[0] + mu * vt), r[1] - rho * v[1], r[2] - rho * v[2]]
    }

    fn predictor_velocity_jacobian(v: [Real; 3], mu: Real) -> [Real; 9] {
        // The identity and, in the normal row, mu v_t / |v_t|.
        let mut m = [0.0; 9];
        for a in 0..3 {
            m[4 * a] = 1.0;
        }
        let vt = tangential_norm(&v);
        if vt > 0.0 {
            m[1] = mu * v[1] / vt;
            m[2] = mu * v[2] / vt;
        }
        m
    }

    fn project(tau: [Real; 3], mu: Real) -> ([Real; 3], Status) {
        project_on_cone(tau, mu)
    }

    /// At the cone's edges, one of the two sides.
    fn projection_jacobian(tau: [Real; 3], mu: Real, dim: usize) -> [Real; 9] {
        let mut d = [0.0; 9];
        let tt = tangential_norm(&tau);
        if mu == 0.0 {
            d[0] = if tau[0] > 0.0 { 1.0 } else { 0.0 };
            return d;
        }
        if tt <= mu * tau[0] {
            for a in 0..dim {
                d[4 * a] = 1.0;
            }
            return d;
        }
        if mu * tt <= -tau[0] {
            return d;
        }
        let s = 1.0 / (1.0 + mu * mu);
        let rn = (tau[0] + mu * tt) * s;
        let t = [0.0, tau[1] / tt, tau[2] / tt];
        d[0] = s;
        for b in 1..dim {
            d[b] = mu * t[b] * s;
        }
        for a in 1..dim {
            d[3 * a] = mu * t[a] * s;
            for b in 1..dim {
                let projector = if a == b { 1.0 } else { 0.0 } - t[a] * t[b];
                d[3 * a + b] = mu * mu * t[a] * t[b] * s + mu * rn * projector / tt;
            }
        }
        d
    }
}

/// Euclidean projection of `tau` onto `K_mu = { r : |r_t| <= mu r_n }`.
pub fn project_on_cone(tau: [Real; 3], mu: Real) -> ([Real; 3], Status) {
    let tn = tau[0];
    if mu == 0.0 {
        // Frictionless fast path: the cone is the normal half-line.
        return if tn > 0.0 { ([tn, 0.0, 0.0], Status::Sliding) } else { ([0.0; 3], Status::Separated) };
    }
    let tt = tangential_norm(&tau);
    if tt <= mu * tn {
        let status = if tn > 0.0 { Status::Sticking } else { Status::Separated };
        return (tau, status);
    }
    if mu * tt <= -tn {
        return ([0.0; 3], Status::Separated);
    }
    let rn = (tn + mu * tt) / (1.0 + mu * mu);
    let s = mu * rn / tt;
    ([rn, s * tau[1], s * tau[2]], Status::Sliding)
}

/// One Uzawa step at a contact point with the engine's [`Law`] (the CPU twin of the
/// `uzawa_step` kernel). `v` is the relative velocity at the end of the step, with the normal
/// component already shifted by the gap term.
pub fn uzawa_step(r: [Real; 3], v: [Real; 3], mu: Real, rho: Real) -> ([Real; 3], Status) {
    Law::step(r, v, mu, rho)
}
