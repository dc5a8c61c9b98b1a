// Symmetric-tensor helpers shared by the material includes. CPU twin: `material::tensor`.
// WGSL matrices are column-major: `m[k][i]` is the entry m_ik. Fourth-order tensors are 6x6
// Voigt matrices in the order (11, 22, 33, 12, 23, 13), row-major in an array of 36.

alias Mat3 = mat3x3<real>;
alias Tangent = array<real, 36>;

// The stress and the tangent of one material call (`material_stress_tangent`).
struct StressTangent {
    s: Mat3,
    d: Tangent,
}

// The material's parameters; unused ones are zero (`gpu::MaterialParams`).
struct MaterialParams {
    g: real,
    k: real,
    a1: real,
    a2: real,
    a3: real,
    a4: real,
    a5: real,
    a6: real,
}

// The index pair (i, j) of Voigt entry r: (0,0) (1,1) (2,2) (0,1) (1,2) (0,2). Arithmetic, not
// a private table: a GPU would keep a dynamically indexed table in per-invocation memory.
fn voigt_i(r: u32) -> u32 {
    return select(select(0u, 1u, r == 4u), r, r < 3u);
}

fn voigt_j(r: u32) -> u32 {
    return select(select(2u, 1u, r == 3u), r, r < 3u);
}

// The Voigt entry of the index pair (k, l), either order: the inverse of `voigt_i`, `voigt_j`.
fn voigt_of(k: u32, l: u32) -> u32 {
    let sum = k + l;
    return select(select(select(5u, 4u, sum == 3u), 3u, sum == 1u), k, k == l);
}

fn at(m: Mat3, i: u32, k: u32) -> real {
    return m[k][i];
}

fn identity3() -> Mat3 {
    let o = real(1.0);
    let z = real(0.0);
    return Mat3(o, z, z, z, o, z, z, z, o);
}

fn trace3(a: Mat3) -> real {
    return a[0][0] + a[1][1] + a[2][2];
}

fn dev(a: Mat3) -> Mat3 {
    return a - identity3() * (trace3(a) * real(0.3333333333333333));
}

// `E = (FᵀF - I)/2`.
fn green_lagrange(f: Mat3) -> Mat3 {
    return (transpose(f) * f - identity3()) * real(0.5);
}

// Inverse by cofactors (WGSL has no `inverse`); NaN for a singular matrix, as on the CPU.
fn inverse3(m: Mat3) -> Mat3 {
    let c0 = cross(m[1], m[2]);
    let c1 = cross(m[2], m[0]);
    let c2 = cross(m[0], m[1]);
    let det = dot(m[0], c0);
    return transpose(Mat3(c0, c1, c2)) * (real(1.0) / det);
}

// `t += s (A ⊗ B)`, `(A ⊗ B)_ijkl = A_ij B_kl`, accumulated in place (no second 36-entry
// array alive: in f64 that would not fit a GPU's registers).
fn add_outer(t: ptr<function, Tangent>, a: Mat3, b: Mat3, s: real) {
    for (var r = 0u; r < 6u; r++) {
        let sa = s * at(a, voigt_i(r), voigt_j(r));
        for (var c = 0u; c < 6u; c++) {
            (*t)[r * 6u + c] += sa * at(b, voigt_i(c), voigt_j(c));
        }
    }
}

// `t += s (A ⊙ B)`, `(A ⊙ B)_ijkl = ¼(A_ik B_jl + A_il B_jk + A_jk B_il + A_jl B_ik)`, in place.
fn add_odot(t: ptr<function, Tangent>, a: Mat3, b: Mat3, s: real) {
    for (var r = 0u; r < 6u; r++) {
        let i = voigt_i(r);
        let j = voigt_j(r);
        for (var c = 0u; c < 6u; c++) {
            let k = voigt_i(c);
            let l = voigt_j(c);
            (*t)[r * 6u + c] += s * real(0.25) * (at(a, i, k) * at(b, j, l) + at(a, i, l) * at(b, j, k) + at(a, j, k) * at(b, i, l) + at(a, j, l) * at(b, i, k));
        }
    }
}

// The Cauchy stress `σ = F S Fᵀ / J` and its von Mises equivalent.
fn von_mises(f: Mat3, s: Mat3) -> real {
    let sigma = f * s * transpose(f) * (real(1.0) / determinant(f));
    let d = dev(sigma);
    var sum = real(0.0);
    for (var k = 0u; k < 3u; k++) {
        sum += dot(d[k], d[k]);
    }
    return sqrt(real(1.5) * sum);
}
