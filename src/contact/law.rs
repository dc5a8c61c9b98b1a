//! The local contact law of eq. (10): de Saxcé's bi-potential predictor and the projection onto
//! the Coulomb cone. Vectors are in the contact frame, normal first: `[n, t1, t2]` (in 2D the
//! third entry is unused and stays zero).

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

/// One Uzawa step at a contact point (the CPU twin of the `uzawa_step` kernel).
///
/// `v` is the relative velocity at the end of the step, with the normal component already
/// shifted by the gap term. Predictor `tau = r - rho (v_t + (v_n + mu |v_t|) n)`, corrector
/// `r = proj(tau, K_mu)`.
pub fn uzawa_step(r: [Real; 3], v: [Real; 3], mu: Real, rho: Real) -> ([Real; 3], Status) {
    let vt = tangential_norm(&v);
    let tau = [r[0] - rho * (v[0] + mu * vt), r[1] - rho * v[1], r[2] - rho * v[2]];
    project_on_cone(tau, mu)
}
