//! The F-bar element of nearly incompressible materials (Quad4, Hex8): the energy
//! `Π_e = Σ_q dV_q W(Ē(F̄_q))` with `F̄ = α F`, `α = (θ / J)^(1/n)`, `θ = Σ_q J_q dV_q / V_e`
//! the element's mean dilatation and `n` the dimension (in plane strain only the in-plane block
//! of F is scaled, so that `det F̄ = θ` in both). Each point keeps its own distortion while the
//! volume change is one per element, which removes volumetric locking; for an energy split
//! into isochoric and volumetric parts it is the mean-dilatation (Q1/P0) element of Simo,
//! Taylor and Pister (1985). The force and tangent are the first and second derivatives of
//! `Π_e`, so the tangent is symmetric and the energy balance stays exact (doc/method.md §7).

use super::kernel::{checked_determinant, deformation_gradient, finish, point_stress_tangent, ElementError, ElementOutput};
use super::GaussPoint;
use crate::material::tensor::{green_lagrange, Mat3, Tangent, VOIGT};
use crate::material::{Hyperelastic, Relaxation};
use crate::precision::Real;
use nalgebra::{Vector3, Vector6};

/// Each point's `F` and `J`, the element's mean dilatation `θ` and its deformed volume
/// `Σ_q J_q dV_q` (θ times the reference volume), or the first failure.
fn dilatation(points: &[GaussPoint], u: &[[Real; 3]]) -> Result<(Vec<Mat3>, Vec<Real>, Real, Real), ElementError> {
    let (mut volume, mut big_theta) = (0.0, 0.0);
    let mut fs = Vec::with_capacity(points.len());
    let mut js = Vec::with_capacity(points.len());
    for gp in points {
        let f = deformation_gradient(gp, u);
        let j = checked_determinant(&f)?;
        volume += gp.dv;
        big_theta += gp.dv * j;
        fs.push(f);
        js.push(j);
    }
    Ok((fs, js, big_theta / volume, big_theta))
}

/// `F̄ = α F` on the first `dim` rows and columns, and `α²` (`fbar_alpha` and `fbar_scale` of
/// `shaders/include/fbar.wgsl`).
fn bar(f: &Mat3, theta: Real, j: Real, dim: usize) -> (Mat3, Real) {
    let alpha = if dim == 2 { (theta / j).sqrt() } else { (theta / j).cbrt() };
    let alpha2 = alpha * alpha;
    let mut fbar = *f;
    for r in 0..dim {
        for c in 0..dim {
            fbar[(r, c)] *= alpha;
        }
    }
    (fbar, alpha2)
}

/// The gradient each point's stress sees: `F̄` (the element's mean dilatation, its own distortion).
pub(super) fn fbar_gradients(points: &[GaussPoint], u: &[[Real; 3]], dim: usize) -> Vec<Mat3> {
    match dilatation(points, u) {
        Ok((fs, js, theta, _)) => fs.iter().zip(&js).map(|(f, &j)| bar(f, theta, j, dim).0).collect(),
        // An inverted point has no F̄; its plain F says so to whoever reads it.
        Err(_) => points.iter().map(|gp| deformation_gradient(gp, u)).collect(),
    }
}

/// Internal force and tangent stiffness of one F-bar element (see the module comment).
pub(super) fn fbar_force_tangent<M: Hyperelastic>(material: &M, points: &[GaussPoint], u: &[[Real; 3]], dim: usize, relaxation: Option<Relaxation>, with_tangent: bool, out: &mut ElementOutput) -> Result<(), ElementError> {
    let nen = u.len();
    let ndof = nen * dim;
    let n = dim as Real;
    out.force.clear();
    out.force.resize(ndof, 0.0);
    out.tangent.clear();
    if with_tangent {
        out.tangent.resize(ndof * ndof, 0.0);
    }
    let (fs, js, theta, big_theta) = dilatation(points, u)?;
    let h = spatial_gradients(points, &fs, ndof, dim);
    let (theta_hat, theta_hess) = theta_derivatives(points, &js, &h, big_theta, ndof, dim, with_tangent);
    let mut beta = vec![0.0; ndof];
    let mut r_vec = vec![0.0; ndof];
    let mut bbar = vec![Vector6::<Real>::zeros(); ndof];
    let mut db = vec![Vector6::<Real>::zeros(); ndof];
    for (q, gp) in points.iter().enumerate() {
        let (f, hq) = (&fs[q], &h[q]);
        let (fbar, alpha2) = bar(f, theta, js[q], dim);
        let ebar = green_lagrange(&fbar);
        let (s, d) = point_stress_tangent(material, &ebar, relaxation.map(|r| (r.c, r.point(q))), with_tangent);
        let c = f.transpose() * f;
        // t = S̄ : C over the scaled block; β = d ln α / du; r = (F S̄ g_a)_i = S̄ : dE/du.
        let mut t = 0.0;
        for k in 0..dim {
            for l in 0..dim {
                t += s[(k, l)] * c[(k, l)];
            }
        }
        let f_s = f * s;
        for r in 0..ndof {
            let (a, i) = (r / dim, r % dim);
            let g = &gp.dn_dx[a];
            beta[r] = (theta_hat[r] - hq[r]) / n;
            r_vec[r] = f_s[(i, 0)] * g[0] + f_s[(i, 1)] * g[1] + f_s[(i, 2)] * g[2];
            out.force[r] += gp.dv * alpha2 * (r_vec[r] + t * beta[r]);
        }
        let Some(d) = d else { continue };
        if !d.iter().all(|v| v.is_finite()) {
            return Err(ElementError::NonFinite);
        }
        let point = PointTerms { gp, f, c: &c, s: &s, d: &d, alpha2, t, beta: &beta, r_vec: &r_vec, h: hq, theta_hat: &theta_hat, theta_hess: &theta_hess };
        add_point_tangent(&point, dim, &mut bbar, &mut db, &mut out.tangent);
    }
    finish(out, ndof, with_tangent)
}

/// `h_a = F⁻ᵀ dN_a/dX` at every point, per dof: the spatial gradients, `δJ/J = Σ_a δu_a · h_a`.
fn spatial_gradients(points: &[GaussPoint], fs: &[Mat3], ndof: usize, dim: usize) -> Vec<Vec<Real>> {
    points
        .iter()
        .zip(fs)
        .map(|(gp, f)| {
            let inv_t = f.try_inverse().expect("det F > 0").transpose();
            let h: Vec<Vector3<Real>> = gp.dn_dx.iter().map(|g| inv_t * Vector3::new(g[0], g[1], g[2])).collect();
            (0..ndof).map(|r| h[r / dim][r % dim]).collect()
        })
        .collect()
}

/// `θ̂ = (dθ/du) / θ` and, with the tangent, `(d²θ/du²) / θ` (row-major), with the entries of
/// node pairs whose components differ.
fn theta_derivatives(points: &[GaussPoint], js: &[Real], h: &[Vec<Real>], big_theta: Real, ndof: usize, dim: usize, with_tangent: bool) -> (Vec<Real>, Vec<Real>) {
    let mut theta_hat = vec![0.0; ndof];
    for ((gp, j), hq) in points.iter().zip(js).zip(h) {
        for (t, hr) in theta_hat.iter_mut().zip(hq) {
            *t += gp.dv * j * hr / big_theta;
        }
    }
    let mut theta_hess = Vec::new();
    if with_tangent {
        theta_hess.resize(ndof * ndof, 0.0);
        for ((gp, j), hq) in points.iter().zip(js).zip(h) {
            let w = gp.dv * j / big_theta;
            for r in 0..ndof {
                let (a, i) = (r / dim, r % dim);
                for c in 0..ndof {
                    let (b, jj) = (c / dim, c % dim);
                    theta_hess[r * ndof + c] += w * (hq[r] * hq[c] - hq[a * dim + jj] * hq[b * dim + i]);
                }
            }
        }
    }
    (theta_hat, theta_hess)
}

/// What one point adds to the tangent: its `F`, `C`, stress `S̄` and tangent `D`, `α²`,
/// `t = S̄ : C`, `β = d ln α / du`, `r = S̄ : dE/du`, its spatial gradients, and the element's
/// `θ̂` and `(d²θ/du²) / θ`.
struct PointTerms<'a> {
    gp: &'a GaussPoint,
    f: &'a Mat3,
    c: &'a Mat3,
    s: &'a Mat3,
    d: &'a Tangent,
    alpha2: Real,
    t: Real,
    beta: &'a [Real],
    r_vec: &'a [Real],
    h: &'a [Real],
    theta_hat: &'a [Real],
    theta_hess: &'a [Real],
}

/// Adds one point's share to the upper triangle of `tangent`; `bbar` and `db` are workspace of
/// one `Vector6` per dof.
fn add_point_tangent(p: &PointTerms, dim: usize, bbar: &mut [Vector6<Real>], db: &mut [Vector6<Real>], tangent: &mut [Real]) {
    let PointTerms { gp, f, c, s, d, alpha2, t, beta, r_vec, h: hq, theta_hat, theta_hess } = *p;
    let ndof = beta.len();
    let n = dim as Real;
    // B̄ = dĒ/du = α² (B + c βᵀ), c = C in engineering Voigt form over the scaled block.
    let c_voigt = Vector6::from_fn(|k, _| {
        let (p, m) = VOIGT[k];
        if p >= dim || m >= dim {
            0.0
        } else if p == m {
            c[(p, m)]
        } else {
            2.0 * c[(p, m)]
        }
    });
    for r in 0..ndof {
        let (a, i) = (r / dim, r % dim);
        let g = &gp.dn_dx[a];
        let b = Vector6::from_fn(|k, _| {
            let (p, m) = VOIGT[k];
            if p == m {
                f[(i, p)] * g[p]
            } else {
                f[(i, p)] * g[m] + f[(i, m)] * g[p]
            }
        });
        bbar[r] = (b + c_voigt * beta[r]) * alpha2;
    }
    for (dbr, br) in db.iter_mut().zip(bbar.iter()) {
        *dbr = d * br * gp.dv;
    }
    let w = gp.dv * alpha2;
    for col in 0..ndof {
        let (bn, jj) = (col / dim, col % dim);
        let gb = &gp.dn_dx[bn];
        let sgb = s * Vector3::new(gb[0], gb[1], gb[2]);
        for row in 0..=col {
            let (a, i) = (row / dim, row % dim);
            // d²(ln α)/du², from ln θ and ln J.
            let beta2 = (theta_hess[row * ndof + col] - theta_hat[row] * theta_hat[col] + hq[a * dim + jj] * hq[bn * dim + i]) / n;
            let mut k = bbar[row].dot(&db[col]) + w * (t * (2.0 * beta[row] * beta[col] + beta2) + 2.0 * (beta[row] * r_vec[col] + r_vec[row] * beta[col]));
            if i == jj {
                let ga = &gp.dn_dx[a];
                k += w * (sgb[0] * ga[0] + sgb[1] * ga[1] + sgb[2] * ga[2]);
            }
            tangent[row * ndof + col] += k;
        }
    }
}
