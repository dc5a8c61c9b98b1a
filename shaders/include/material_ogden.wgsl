// Ogden: W = Σₚ (μₚ/αₚ)(λ̄₁^αₚ + λ̄₂^αₚ + λ̄₃^αₚ - 3) + K/2 (ln J)², μ₁..μ₃ in a1..a3 and
// α₁..α₃ in a4..a6 (a term with μ = 0 is absent). In the logarithms ℓₐ of the eigenvalues cₐ of
// C (λ̄ₐ^α = exp(α/2 (ℓₐ - ℓ̄))), with the eigenvectors from cyclic Jacobi rotations and the
// spectral tangent whose coinciding eigenvalues take their limit. CPU twin: `material::Ogden`
// (`material/ogden.rs`, which derives each term). `ln_real` and `exp_real` come from the
// precision prelude (Vulkan has neither in f64).

// Eigenvalues of symmetric C and its eigenvectors (the columns of n), from `jacobi_eigen`.
struct Eigen {
    c: vec3<real>,
    n: Mat3,
}

// WGSL matrices are column-major: a[col][row].
fn jacobi_eigen(c: Mat3) -> Eigen {
    var a = c;
    var v = identity3();
    for (var sweep = 0; sweep < 12; sweep++) {
        let off = abs(a[1][0]) + abs(a[2][0]) + abs(a[2][1]);
        if off == real(0.0) {
            break;
        }
        for (var pair = 0u; pair < 3u; pair++) {
            let p = select(0u, 1u, pair == 2u);
            let q = select(pair + 1u, 2u, pair == 2u);
            let apq = a[q][p];
            if abs(apq) <= real(1e-18) * (abs(a[p][p]) + abs(a[q][q])) {
                a[q][p] = real(0.0);
                a[p][q] = real(0.0);
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (real(2.0) * apq);
            let t = sign(theta) / (abs(theta) + sqrt(theta * theta + real(1.0)));
            let cs = real(1.0) / sqrt(t * t + real(1.0));
            let sn = t * cs;
            for (var k = 0u; k < 3u; k++) {
                let akp = a[p][k];
                let akq = a[q][k];
                a[p][k] = cs * akp - sn * akq;
                a[q][k] = sn * akp + cs * akq;
            }
            for (var k = 0u; k < 3u; k++) {
                let apk = a[k][p];
                let aqk = a[k][q];
                a[k][p] = cs * apk - sn * aqk;
                a[k][q] = sn * apk + cs * aqk;
            }
            for (var k = 0u; k < 3u; k++) {
                let vkp = v[p][k];
                let vkq = v[q][k];
                v[p][k] = cs * vkp - sn * vkq;
                v[q][k] = sn * vkp + cs * vkq;
            }
        }
    }
    return Eigen(vec3<real>(a[0][0], a[1][1], a[2][2]), v);
}

fn ogden_mu(p: u32) -> real {
    return select(select(material.a3, material.a2, p == 1u), material.a1, p == 0u);
}

fn ogden_alpha(p: u32) -> real {
    return select(select(material.a6, material.a5, p == 1u), material.a4, p == 0u);
}

// The eigen-decomposition of C, ∂W/∂ℓₐ (g), ∂²W/∂ℓₐ∂ℓᵦ (h, row-major) and W.
struct Principal {
    c: vec3<real>,
    n: Mat3,
    g: vec3<real>,
    h: array<real, 9>,
    energy: real,
}

fn principal(e: Mat3) -> Principal {
    let eig = jacobi_eigen(e * real(2.0) + identity3());
    let l = vec3<real>(ln_real(eig.c.x), ln_real(eig.c.y), ln_real(eig.c.z));
    let mean = (l.x + l.y + l.z) / real(3.0);
    let ln_j = real(0.5) * (l.x + l.y + l.z);
    var energy = real(0.5) * material.k * ln_j * ln_j;
    var g = vec3<real>(real(0.5) * material.k * ln_j);
    var h: array<real, 9>;
    for (var i = 0u; i < 9u; i++) {
        h[i] = real(0.25) * material.k;
    }
    for (var p = 0u; p < 3u; p++) {
        let mu = ogden_mu(p);
        let alpha = ogden_alpha(p);
        if mu == real(0.0) {
            continue;
        }
        let t = vec3<real>(exp_real(real(0.5) * alpha * (l.x - mean)), exp_real(real(0.5) * alpha * (l.y - mean)), exp_real(real(0.5) * alpha * (l.z - mean)));
        let sum = t.x + t.y + t.z;
        energy += mu / alpha * (sum - real(3.0));
        for (var a = 0u; a < 3u; a++) {
            g[a] += real(0.5) * mu * (t[a] - sum / real(3.0));
            for (var b = 0u; b < 3u; b++) {
                let diagonal = select(real(0.0), t[a], a == b);
                h[a * 3u + b] += real(0.25) * mu * alpha * (diagonal - (t[a] + t[b]) / real(3.0) + sum / real(9.0));
            }
        }
    }
    return Principal(eig.c, eig.n, g, h, energy);
}

// Sₐ = 2 ∂W/∂cₐ.
fn principal_stresses(pr: Principal) -> vec3<real> {
    return real(2.0) * pr.g / pr.c;
}

fn stress_of(pr: Principal) -> Mat3 {
    let s = principal_stresses(pr);
    var n = pr.n;
    var out = Mat3();
    for (var a = 0u; a < 3u; a++) {
        let na = n[a];
        out += outer_product(na, na) * s[a];
    }
    return out;
}

fn outer_product(x: vec3<real>, y: vec3<real>) -> Mat3 {
    return Mat3(x * y.x, x * y.y, x * y.z);
}

fn material_energy(e: Mat3) -> real {
    return principal(e).energy;
}

// S alone (Newton evaluations that need no tangent).
fn material_stress(e: Mat3) -> Mat3 {
    return stress_of(principal(e));
}

// S and dS/dE = Σₐᵦ 4 Wₐᵦ Mₐ⊗Mᵦ + Σₐ≠ᵦ Θₐᵦ Nₐ⊗Nᵦ⊗(Nₐ⊗Nᵦ + Nᵦ⊗Nₐ).
fn material_stress_tangent(e: Mat3) -> StressTangent {
    let pr = principal(e);
    let s = principal_stresses(pr);
    let c = pr.c;
    // Wₐᵦ = ∂²W/∂cₐ∂cᵦ and Θₐᵦ, row-major.
    var w: array<real, 9>;
    for (var a = 0u; a < 3u; a++) {
        for (var b = 0u; b < 3u; b++) {
            w[a * 3u + b] = pr.h[a * 3u + b] / (c[a] * c[b]) - select(real(0.0), pr.g[a] / (c[a] * c[a]), a == b);
        }
    }
    let scale = max(abs(c.x), max(abs(c.y), abs(c.z)));
    var theta: array<real, 9>;
    for (var a = 0u; a < 3u; a++) {
        for (var b = 0u; b < 3u; b++) {
            let gap = c[a] - c[b];
            // `ogden::COINCIDENT`.
            if abs(gap) <= real(1e-5) * scale {
                theta[a * 3u + b] = w[a * 4u] + w[b * 4u] - real(2.0) * w[a * 3u + b];
            } else {
                theta[a * 3u + b] = (s[a] - s[b]) / gap;
            }
        }
    }
    var n = pr.n;
    var d: Tangent;
    for (var r = 0u; r < 6u; r++) {
        let i = voigt_i(r);
        let j = voigt_j(r);
        for (var col = 0u; col < 6u; col++) {
            let k = voigt_i(col);
            let l = voigt_j(col);
            var sum = real(0.0);
            for (var a = 0u; a < 3u; a++) {
                for (var b = 0u; b < 3u; b++) {
                    let na = n[a];
                    let nb = n[b];
                    sum += real(4.0) * w[a * 3u + b] * na[i] * na[j] * nb[k] * nb[l];
                    if a != b {
                        sum += theta[a * 3u + b] * na[i] * nb[j] * (na[k] * nb[l] + nb[k] * na[l]);
                    }
                }
            }
            d[r * 6u + col] = sum;
        }
    }
    return StressTangent(stress_of(pr), d);
}
