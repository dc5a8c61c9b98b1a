//! Material models: stress against the energy, tangent against the stress (finite differences),
//! small-strain limits, and the LVF invariants against the paper's eq. (5) written with the
//! Lode angle.

#[path = "common/random.rs"]
mod common_random;

use bifirst::material::tensor::{green_lagrange, to_voigt, Mat3, Tangent, VOIGT};
use bifirst::material::{ArrudaBoyce, BlatzKo, Decoupled, Gent, Hyperelastic, Lvf, Model, MooneyRivlin, NeoHookean, Ogden, Svk, Yeoh};
use common_random::{random_f, rng};

fn models() -> Vec<(&'static str, Model)> {
    vec![
        ("blatz_ko", Model::BlatzKo(BlatzKo { g: 3.0 })),
        ("neo_hookean", Model::NeoHookean(NeoHookean { g: 2.0, k: 7.0 })),
        // The paper's Love-Laursen parameters, with a3 non-zero so its terms are exercised.
        ("lvf", Model::Lvf(Lvf { g: 5000.0, k: 3333.0, a1: 50.0, a2: 50.0, a3: 400.0, a4: 2000.0, a5: 100.0 })),
        // The decoupled rubber models, every term of their laws non-zero.
        ("mooney_rivlin", Model::MooneyRivlin(Decoupled { law: MooneyRivlin { c10: 1.5, c01: 0.4 }, k: 9.0 })),
        ("yeoh", Model::Yeoh(Decoupled { law: Yeoh { c10: 1.5, c20: -0.2, c30: 0.05 }, k: 9.0 })),
        ("gent", Model::Gent(Decoupled { law: Gent { g: 3.0, jm: 8.0 }, k: 9.0 })),
        ("arruda_boyce", Model::ArrudaBoyce(Decoupled { law: ArrudaBoyce { mu: 2.5, lambda_m: 1.8 }, k: 9.0 })),
        // Three terms, of both signs of α.
        ("ogden", Model::Ogden(Ogden { mu: [1.5, 0.02, -0.1], alpha: [1.3, 5.0, -2.0], k: 9.0 })),
        ("svk", Model::Svk(Svk { e: 7.0, nu: 0.3 })),
    ]
}

/// Perturbs Voigt component `j` of E by `h` (engineering shear: E_kl and E_lk by h/2 each).
fn perturb(e: &Mat3, j: usize, h: f64) -> Mat3 {
    let (k, l) = VOIGT[j];
    let mut p = *e;
    if k == l {
        p[(k, k)] += h;
    } else {
        p[(k, l)] += h / 2.0;
        p[(l, k)] += h / 2.0;
    }
    p
}

#[test]
fn stress_is_the_derivative_of_the_energy() {
    let mut r = rng(11);
    for (name, m) in models() {
        for _ in 0..50 {
            let e = green_lagrange(&random_f(&mut r));
            let s = to_voigt(&m.stress(&e));
            let h = 1e-6 * (1.0 + e.norm());
            // dW/dE_voigt: for a shear component this is S_kl (the h/2 split counts both halves).
            let fd = nalgebra::Vector6::from_fn(|j, _| (m.energy(&perturb(&e, j, h)) - m.energy(&perturb(&e, j, -h))) / (2.0 * h));
            let err = (fd - s).norm() / s.norm().max(1e-12 * m.small_strain_moduli().0);
            assert!(err < 1e-6, "{name}: |S - dW/dE| / |S| = {err:e}");
        }
    }
}

#[test]
fn tangent_is_the_derivative_of_the_stress() {
    let mut r = rng(12);
    for (name, m) in models() {
        for _ in 0..50 {
            let e = green_lagrange(&random_f(&mut r));
            let (s, d) = m.stress_tangent(&e);
            // The kernels take the stress from the same call as the tangent when they need both.
            assert_eq!(s, m.stress(&e), "{name}: stress_tangent's stress is the stress");
            let h = 1e-6 * (1.0 + e.norm());
            let fd = Tangent::from_fn(|i, j| (to_voigt(&m.stress(&perturb(&e, j, h)))[i] - to_voigt(&m.stress(&perturb(&e, j, -h)))[i]) / (2.0 * h));
            let err = (fd - d).norm() / d.norm();
            assert!(err < 1e-6, "{name}: |D - dS/dE| / |D| = {err:e}");
            assert!((d - d.transpose()).norm() <= 1e-10 * d.norm(), "{name}: tangent not symmetric");
        }
    }
}

#[test]
fn small_strain_limits_are_linear_elasticity() {
    let zero = Mat3::zeros();
    for (name, m) in models() {
        let (young, poisson) = m.small_strain_moduli();
        let c = m.tangent(&zero).try_inverse().expect("D(0) invertible");
        let e = 1.0 / c[(0, 0)];
        let nu = -c[(0, 1)] / c[(0, 0)];
        assert!((e - young).abs() <= 1e-10 * young, "{name}: E = {e}, expected {young}");
        assert!((nu - poisson).abs() <= 1e-10, "{name}: nu = {nu}, expected {poisson}");
        assert!(m.stress(&zero).norm() < 1e-12 * young && m.energy(&zero).abs() < 1e-12 * young, "{name}: not stress-free at E = 0");
    }
    // Blatz-Ko: Poisson 1/4 and Young 2.5 G; LVF: bulk K and shear G.
    let (e, nu) = Model::BlatzKo(BlatzKo { g: 3.0 }).small_strain_moduli();
    assert!((e - 7.5).abs() < 1e-12 && (nu - 0.25).abs() < 1e-12);
    let lvf = Lvf { g: 5000.0, k: 3333.0, a1: 50.0, a2: 50.0, a3: 0.0, a4: 2000.0, a5: 100.0 };
    let d = lvf.tangent(&zero);
    let bulk = (d[(0, 0)] + 2.0 * d[(0, 1)]) / 3.0;
    assert!((bulk - 3333.0).abs() < 1e-9 && (d[(3, 3)] - 5000.0).abs() < 1e-9, "LVF bulk {bulk}, shear {}", d[(3, 3)]);
}

/// Eq. (5) exactly as printed, with x = |E_d| cos θ, y = |E_d| sin θ from the Lode angle.
fn lvf_energy_eq5(m: &Lvf, e: &Mat3) -> f64 {
    let ed = e - Mat3::identity() * (e.trace() / 3.0);
    let norm = (ed * ed).trace().sqrt();
    let z = e.trace() / 3f64.sqrt();
    let (x, y) = if norm < 1e-14 {
        (0.0, 0.0)
    } else {
        let cos3 = (6f64.sqrt() * (ed * ed * ed).trace() / norm.powi(3)).clamp(-1.0, 1.0);
        let theta = cos3.acos() / 3.0;
        (norm * theta.cos(), norm * theta.sin())
    };
    let r2 = x * x + y * y;
    (m.g + m.a3 / 4.0 * z * z) * r2 + 1.5 * m.k * z * z + m.a1 / 3.0 * (x.powi(3) - 3.0 * x * y * y) + m.a2 / 3.0 * z.powi(3) + m.a4 / 4.0 * z.powi(4) + m.a5 / 4.0 * r2 * r2
}

#[test]
fn lvf_invariants_match_eq5_with_the_lode_angle() {
    let m = Lvf { g: 5000.0, k: 3333.0, a1: 50.0, a2: 50.0, a3: 400.0, a4: 2000.0, a5: 100.0 };
    let mut r = rng(13);
    for _ in 0..100 {
        let e = green_lagrange(&random_f(&mut r));
        let (a, b) = (m.energy(&e), lvf_energy_eq5(&m, &e));
        assert!((a - b).abs() <= 1e-11 * a.abs().max(1.0), "W = {a}, eq. (5) gives {b}");
    }
}

/// Regression: the paper's eq. (6) halves the a5 term, so it is not dW/dE; ours must be.
#[test]
fn lvf_a5_term_is_the_derivative_not_eq6() {
    let m = Lvf { g: 0.0, k: 0.0, a1: 0.0, a2: 0.0, a3: 0.0, a4: 0.0, a5: 100.0 };
    let e = Mat3::new(0.1, 0.02, 0.0, 0.02, -0.05, 0.0, 0.0, 0.0, -0.05);
    let ed = e - Mat3::identity() * (e.trace() / 3.0);
    let s2 = (ed * ed).trace();
    let ours = m.stress(&e);
    assert!((ours - ed * (m.a5 * s2)).norm() < 1e-14);
    assert!((ours - ed * (m.a5 / 2.0 * s2)).norm() > 1e-6);
}

#[test]
fn closed_form_principal_stresses() {
    // Principal stretches: Blatz-Ko S_i = G (J/λ_i² - 1/λ_i⁴); Neo-Hookean S_i = G(1 - 1/λ_i²) + λ ln J / λ_i².
    let l = [1.3, 0.8, 1.1];
    let f = Mat3::from_diagonal(&nalgebra::Vector3::new(l[0], l[1], l[2]));
    let e = green_lagrange(&f);
    let j = l[0] * l[1] * l[2];
    let bk = BlatzKo { g: 3.0 }.stress(&e);
    let nh = NeoHookean { g: 2.0, k: 7.0 }.stress(&e);
    let lam = 7.0 - 2.0 * 2.0 / 3.0;
    for i in 0..3 {
        let li2 = l[i] * l[i];
        assert!((bk[(i, i)] - 3.0 * (j / li2 - 1.0 / (li2 * li2))).abs() < 1e-12);
        assert!((nh[(i, i)] - (2.0 * (1.0 - 1.0 / li2) + lam * j.ln() / li2)).abs() < 1e-12);
    }
    // LVF under pure dilatation E = εI: S = z (3K + a2 z + a4 z²) / √3 I with z = √3 ε.
    let m = Lvf { g: 5000.0, k: 3333.0, a1: 50.0, a2: 50.0, a3: 400.0, a4: 2000.0, a5: 100.0 };
    let eps = 0.07;
    let z = 3f64.sqrt() * eps;
    let s = m.stress(&(Mat3::identity() * eps));
    let expected = z * (3.0 * m.k + m.a2 * z + m.a4 * z * z) / 3f64.sqrt();
    assert!((s - Mat3::identity() * expected).norm() < 1e-10 * expected);
}

/// Ogden's stress and tangent go through the eigenvectors of C, which are arbitrary where two
/// stretches coincide: the tangent's limit there (and near it, on either side of the switch at
/// `ogden::COINCIDENT`) must still be the derivative of the stress, as at the undeformed state.
#[test]
fn ogden_tangent_holds_where_stretches_coincide() {
    let m = Model::Ogden(Ogden { mu: [1.5, 0.02, -0.1], alpha: [1.3, 5.0, -2.0], k: 9.0 });
    let mut r = rng(13);
    for gap in [0.0, 1e-9, 1e-6, 2e-5, 1e-3] {
        for three in [false, true] {
            // Principal stretches (1.2, 1.2 + gap, 0.9 or 1.2 + 2 gap) in a random frame.
            let q = nalgebra::Rotation3::from_scaled_axis(nalgebra::Vector3::from_fn(|_, _| rand::Rng::random_range(&mut r, -3.0..3.0))).into_inner();
            let third = if three { 1.2 + 2.0 * gap } else { 0.9 };
            let f = q * Mat3::from_diagonal(&nalgebra::Vector3::new(1.2, 1.2 + gap, third)) * q.transpose();
            let e = green_lagrange(&f);
            let (s, d) = m.stress_tangent(&e);
            let h = 1e-6;
            let fd = Tangent::from_fn(|i, j| (to_voigt(&m.stress(&perturb(&e, j, h)))[i] - to_voigt(&m.stress(&perturb(&e, j, -h)))[i]) / (2.0 * h));
            let err = (fd - d).norm() / d.norm();
            assert!(err < 1e-6, "gap {gap:e}, three equal {three}: |D - dS/dE| / |D| = {err:e}");
            let fd_s = nalgebra::Vector6::from_fn(|j, _| (m.energy(&perturb(&e, j, h)) - m.energy(&perturb(&e, j, -h))) / (2.0 * h));
            assert!((fd_s - to_voigt(&s)).norm() < 1e-7 * to_voigt(&s).norm(), "gap {gap:e}: stress");
        }
    }
}

/// Saint Venant-Kirchhoff is Hooke's law in E: its small-strain moduli are the scene's E and ν,
/// and at any strain its stress is linear in E (uniaxial strain: S₁₁ = (λ + 2μ) ε, S₂₂ = λ ε),
/// which the rubber models are not.
#[test]
fn svk_is_hookes_law_on_the_green_lagrange_strain() {
    let m = Svk { e: 2600.0, nu: 0.3 };
    let (young, poisson) = Model::Svk(m.clone()).small_strain_moduli();
    assert!((young - 2600.0).abs() < 1e-9 && (poisson - 0.3).abs() < 1e-12, "E = {young}, ν = {poisson}");
    let (lambda, mu) = (2600.0 * 0.3 / (1.3 * 0.4), 2600.0 / 2.6);
    for eps in [1e-6, 0.1, 0.5, -0.3] {
        let e = Mat3::from_diagonal(&nalgebra::Vector3::new(eps, 0.0, 0.0));
        let s = m.stress(&e);
        assert!((s[(0, 0)] - (lambda + 2.0 * mu) * eps).abs() <= 1e-12 * lambda, "ε = {eps}: S11 = {}", s[(0, 0)]);
        assert!((s[(1, 1)] - lambda * eps).abs() <= 1e-12 * lambda && (s[(2, 2)] - lambda * eps).abs() <= 1e-12 * lambda, "ε = {eps}: S22 = {}", s[(1, 1)]);
        assert!((m.energy(&e) - 0.5 * (lambda + 2.0 * mu) * eps * eps).abs() <= 1e-12 * lambda, "ε = {eps}: W = {}", m.energy(&e));
    }
}
