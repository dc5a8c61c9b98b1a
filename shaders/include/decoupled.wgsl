// Decoupled hyperelasticity W = Ŵ(Ī₁, Ī₂) + K/2 (ln J)², through the invariants (I₁, I₂, I₃) of
// C with Vᵢ = ∂Iᵢ/∂C (V₁ = I, V₂ = I₁ I - C, V₃ = I₃ C⁻¹):
//   S = 2 Σ Wᵢ Vᵢ,  dS/dE = 4 [Σ Wᵢⱼ Vᵢ⊗Vⱼ + W₂ (I⊗I - 𝕀) + W₃ I₃ (C⁻¹⊗C⁻¹ - C⁻¹⊙C⁻¹)].
// The model's include (`material_<name>.wgsl`) gives `isochoric_energy` and
// `isochoric_derivatives` of Ŵ. CPU twin: `material::Decoupled`.

// First and second derivatives of Ŵ in (Ī₁, Ī₂).
struct Isochoric {
    d1: real,
    d2: real,
    d11: real,
    d12: real,
    d22: real,
}

// What the stress and the tangent share at one strain; a = J^(-2/3), b = J^(-4/3).
struct Kinematics {
    c: Mat3,
    ci: Mat3,
    i1: real,
    i3: real,
    a: real,
    b: real,
    i1b: real,
    i2b: real,
    ln_i3: real,
}

fn kinematics(e: Mat3) -> Kinematics {
    let c = e * real(2.0) + identity3();
    let i1 = trace3(c);
    let i2 = real(0.5) * (i1 * i1 - trace3(c * c));
    let i3 = determinant(c);
    let a = inverse_cbrt_real(i3);
    let b = a * a;
    return Kinematics(c, inverse3(c), i1, i3, a, b, a * i1, b * i2, ln_real(i3));
}

// W₁, W₂, W₃: the derivatives of W in (I₁, I₂, I₃); U = K/8 (ln I₃)² in I₃.
// (One reciprocal of I₃ and no other division: an f64 division is a dozen instructions on a GPU.)
fn decoupled_first(k: Kinematics, d: Isochoric) -> vec3<real> {
    let third = real(1.0) / (real(3.0) * k.i3);
    let p = -k.i1b * third;
    let q = real(-2.0) * k.i2b * third;
    let u1 = real(0.75) * material.k * k.ln_i3 * third;
    return vec3<real>(d.d1 * k.a, d.d2 * k.b, d.d1 * p + d.d2 * q + u1);
}

fn decoupled_stress_of(k: Kinematics, w: vec3<real>) -> Mat3 {
    return (identity3() * (w.x + w.y * k.i1) - k.c * w.y + k.ci * (w.z * k.i3)) * real(2.0);
}

fn material_energy(e: Mat3) -> real {
    let k = kinematics(e);
    return isochoric_energy(k.i1b, k.i2b) + material.k / real(8.0) * k.ln_i3 * k.ln_i3;
}

// S alone (Newton evaluations that need no tangent).
fn material_stress(e: Mat3) -> Mat3 {
    let k = kinematics(e);
    return decoupled_stress_of(k, decoupled_first(k, isochoric_derivatives(k.i1b, k.i2b)));
}

fn material_stress_tangent(e: Mat3) -> StressTangent {
    let k = kinematics(e);
    let d = isochoric_derivatives(k.i1b, k.i2b);
    let w = decoupled_first(k, d);
    let i3 = k.i3;
    let third = real(1.0) / (real(3.0) * i3);
    let p = -k.i1b * third;
    let q = real(-2.0) * k.i2b * third;
    // ∂a/∂I₃, ∂b/∂I₃; I₁ ∂²a/∂I₃², I₂ ∂²b/∂I₃²; ∂²U/∂I₃².
    let da = -k.a * third;
    let db = real(-2.0) * k.b * third;
    let i1_dda = real(4.0) * k.i1b * third * third;
    let i2_ddb = real(10.0) * k.i2b * third * third;
    let u2 = real(2.25) * material.k * (real(1.0) - k.ln_i3) * third * third;
    let w11 = d.d11 * k.a * k.a;
    let w12 = d.d12 * k.a * k.b;
    let w22 = d.d22 * k.b * k.b;
    let w13 = k.a * (d.d11 * p + d.d12 * q) + d.d1 * da;
    let w23 = k.b * (d.d12 * p + d.d22 * q) + d.d2 * db;
    let w33 = d.d11 * p * p + real(2.0) * d.d12 * p * q + d.d22 * q * q + d.d1 * i1_dda + d.d2 * i2_ddb + u2;
    let v1 = identity3();
    let v2 = v1 * k.i1 - k.c;
    let v3 = k.ci * i3;
    var t: Tangent;
    add_outer(&t, v1, v1, real(4.0) * (w11 + w.y));
    add_odot(&t, v1, v1, real(-4.0) * w.y);
    add_outer(&t, v2, v2, real(4.0) * w22);
    add_outer(&t, v3, v3, real(4.0) * w33);
    add_outer(&t, v1, v2, real(4.0) * w12);
    add_outer(&t, v2, v1, real(4.0) * w12);
    add_outer(&t, v1, v3, real(4.0) * w13);
    add_outer(&t, v3, v1, real(4.0) * w13);
    add_outer(&t, v2, v3, real(4.0) * w23);
    add_outer(&t, v3, v2, real(4.0) * w23);
    add_outer(&t, k.ci, k.ci, real(4.0) * w.z * i3);
    add_odot(&t, k.ci, k.ci, real(-4.0) * w.z * i3);
    return StressTangent(decoupled_stress_of(k, w), t);
}
